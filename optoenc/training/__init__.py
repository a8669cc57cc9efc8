"""Running: everything a training run is made of, one domain.

* :mod:`optoenc.training.run`: :func:`build` the parts of a run,
  :func:`fit`, :func:`evaluate`, :func:`verify`, :func:`load_encoder`;
* :mod:`optoenc.training.module`: the LightningModule (augmentation ->
  encoder -> noise -> decoder);
* :mod:`optoenc.training.epoch_loop`: a fixed encoder's epoch of precomputed
  embeddings stepped through in one Lightning step (manual optimisation);
* :mod:`optoenc.training.seeding`: the per-batch seeds every loop draws from;
* :mod:`optoenc.training.adversary`: privacy-aware training (the encoder
  against a reconstruction adversary, ``privacy.adversary_weight``);
* :mod:`optoenc.training.callbacks`: per-epoch metrics, checkpoints, the
  finite-loss guard;
* :mod:`optoenc.training.loaders`: epoch samplers, batched loaders and the
  one batched :func:`~optoenc.training.loaders.encode`;
* :mod:`optoenc.training.cache`: the embedding cache, keyed by content;
* :mod:`optoenc.training.augment_once`: augmentations drawn once and cached;
* :mod:`optoenc.training.resume`: resuming, interruption and its markers;
* :mod:`optoenc.training.allocator`: glibc's malloc set to keep freed memory
  (the command line's and sweep cells' processes);
* :mod:`optoenc.training.rundir`: run directories and atomic writes (a
  foundation module: it imports only :mod:`optoenc.errors`, and every layer
  uses it).

``from optoenc.training import fit`` reads as it did when this was one
module: the names of :mod:`optoenc.training.run` are re-exported here, and
imported on first use, so that importing a leaf such as
``optoenc.training.rundir`` stays light (no Lightning, no plugin host).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs
    from .run import Parts, _logger, build, checkpoint_path, evaluate, fit, load_encoder, verify

__all__ = ["Parts", "build", "fit", "evaluate", "checkpoint_path", "load_encoder", "verify"]

#: name -> submodule of this package that defines it (``_logger``: used by tests and DDP workers)
_LAZY = {name: "run" for name in (*__all__, "_logger")}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
