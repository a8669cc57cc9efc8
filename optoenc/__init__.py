"""optoenc: differentiable optical encoders trained end to end with digital decoders.

``import optoenc`` is light: it loads neither torch nor any plugin. The public
names below are imported on first access.

Modules that moved into a domain folder keep their old import path
(:data:`MOVED`): ``import optoenc.rundir`` gives the very module object
``optoenc.training.rundir`` (so monkeypatching either name patches both, and
checkpoints pickled under an old path still load). No file is left at an old
path; new code imports the new one.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

__version__ = "0.1.0"

#: public name -> module that defines it
_LAZY = {
    "OpticalEncoder": "optoenc.encoders.base",
    "EncoderConfig": "optoenc.encoders.base",
    "MaskEncoder": "optoenc.encoders.mask",
    "Decoder": "optoenc.decoders",
    "DecoderConfig": "optoenc.decoders",
    "Dataset": "optoenc.datasets.base",
    "DatasetConfig": "optoenc.datasets.base",
    "Splits": "optoenc.datasets.base",
    "Split": "optoenc.datasets.base",
    "Augmentation": "optoenc.augment",
    "SceneConfig": "optoenc.encoders.geometry",
    "SensorConfig": "optoenc.encoders.geometry",
    "FidelityConfig": "optoenc.fidelity.knobs",
    "Knobs": "optoenc.fidelity.knobs",
    "Settings": "optoenc.settings",
    "setting": "optoenc.settings",
    "hookimpl": "optoenc.plugins.hookspecs",
    "get_registry": "optoenc.plugins",
    "register_plugin": "optoenc.plugins",
    "ConfigError": "optoenc.errors",
    "DataError": "optoenc.errors",
    "PluginError": "optoenc.errors",
    "PhysicsError": "optoenc.errors",
    "OptoencError": "optoenc.errors",
    "build_encoder": "optoenc.config",
    "RunConfig": "optoenc.config",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'optoenc' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)


#: Old module path -> its module now (the regroup by domain, issue 9). The old path is an alias:
#: the same module object, imported on first use by :class:`_MovedFinder`.
MOVED = {
    "optoenc.augment_once": "optoenc.training.augment_once",
    "optoenc.autofidelity": "optoenc.fidelity.auto",
    "optoenc.bench.auto": "optoenc.fidelity.choose",
    "optoenc.bench_optics": "optoenc.bench.optics",
    "optoenc.builtins": "optoenc.plugins.builtins",
    "optoenc.cache": "optoenc.training.cache",
    "optoenc.callbacks": "optoenc.training.callbacks",
    "optoenc.docs": "optoenc.plugins.docs",
    "optoenc.encoders.constants": "optoenc.devices",
    "optoenc.geometry": "optoenc.encoders.geometry",
    "optoenc.hookspecs": "optoenc.plugins.hookspecs",
    "optoenc.imaging": "optoenc.encoders.imaging",
    "optoenc.listing": "optoenc.plugins.listing",
    "optoenc.loaders": "optoenc.training.loaders",
    "optoenc.module": "optoenc.training.module",
    "optoenc.pictures": "optoenc.training.pictures",
    "optoenc.psf_files": "optoenc.encoders.psf_files",
    "optoenc.registry": "optoenc.plugins.registry",
    "optoenc.resume": "optoenc.training.resume",
    "optoenc.rundir": "optoenc.training.rundir",
}


class _Alias:
    """Loader of an old module path: the module at its new path, imported once."""

    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec) -> Any:
        return importlib.import_module(self.new)

    def exec_module(self, module) -> None:
        pass  # already executed under its new name

    def get_code(self, fullname: str):  # ``python -m <old path>`` runs the new module as __main__
        return compile(f"import runpy\nrunpy.run_module({self.new!r}, run_name='__main__', alter_sys=True)\n",
                       f"<{fullname}: moved to {self.new}>", "exec")


class _MovedFinder:
    """``sys.meta_path`` finder for the old paths of :data:`MOVED` (first, so that no stray file shadows them)."""

    @staticmethod
    def find_spec(fullname: str, path=None, target=None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        from importlib.util import spec_from_loader

        return spec_from_loader(fullname, _Alias(new))


if not any(getattr(f, "__name__", None) == "_MovedFinder" for f in sys.meta_path):
    sys.meta_path.insert(0, _MovedFinder)
