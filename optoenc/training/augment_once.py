"""The paper's robustness protocol: one transformed dataset, drawn once per example and kept.

With ``trainer.augment_draw=once`` every example gets its own transform,
drawn once from a generator seeded by (run seed, split) and the same in
every epoch, for train, validation and test alike (the paper simulated one
transformed dataset per transformation). The draws are the ``(N, n_random)``
uniforms of :class:`optoenc.augment.Compose`, stored beside the labels. A
fixed encoder then sees a fixed dataset: its embeddings are computed once,
in chunks (the canvases of a whole dataset would not fit in memory), and
cached like any other. ``trainer.augment_draw=epoch`` (the default) redraws
every transform every epoch instead.
"""

from __future__ import annotations

import hashlib

import torch

from ..augment import Compose, to_canvas
from ..errors import ConfigError
from . import cache

__all__ = ["draws", "encode_transformed", "DRAW_MODES"]

#: ``trainer.augment_draw`` values.
DRAW_MODES = ("epoch", "once")
_SPLIT_SALT = {"train": 1, "val": 2, "test": 3}


def draws(augs, n: int, seed: int, split: str) -> torch.Tensor:
    """``(n, n_random)`` float64 uniforms for ``split``: a fixed function of (seed, split, example index)."""
    for a in augs:
        if not getattr(type(a), "n_random", 0):
            raise ConfigError(
                "trainer.augment_draw", "once",
                f"augmentation {a.name!r} declares no n_random (its randomness cannot be stored); use 'epoch'",
            )
    g = torch.Generator().manual_seed(seed * 1_000_003 + 7919 * _SPLIT_SALT.get(split, 9))
    return torch.rand(n, Compose(augs).n_random, generator=g, dtype=torch.float64)


@torch.no_grad()
def encode_transformed(encoder, augs, canvas, images: torch.Tensor, u: torch.Tensor, batch_size: int,
                       progress=None) -> torch.Tensor:
    """Noise-free embeddings of ``images`` after their stored transforms ``u``, in chunks, eval mode."""
    comp = Compose(list(augs))
    was = encoder.training
    encoder.eval()
    out = []
    try:
        for i in range(0, len(images), batch_size):
            c = comp(to_canvas(images[i : i + batch_size], canvas), canvas, encoder.scene_config.object_height,
                     u[i : i + batch_size])
            out.append(encoder.measure(c, height=canvas.height))
            if progress is not None:
                progress(len(out[-1]))
    finally:
        encoder.train(was)
    return torch.cat(out)


def token(augs, canvas, u: dict[str, torch.Tensor]) -> str:
    """What, beyond the encoder and the dataset, a transformed dataset's embeddings depend on."""
    from ..settings import to_dict

    h = hashlib.sha256(repr([(a.name, to_dict(a.config)) for a in augs]).encode())
    h.update(repr(canvas).encode())
    for k in sorted(u):
        h.update(k.encode() + cache.tensor_digest(u[k]).encode())
    return h.hexdigest()
