"""optoenc: differentiable optical encoders trained end to end with digital decoders.

``import optoenc`` is light: it loads neither torch nor any plugin. The public
names below are imported on first access. A library user starts with
:func:`build_encoder` (docs/library.md)::

    import optoenc

    enc = optoenc.build_encoder("learned_slm", sensor={"embedding": [6, 8]}, fidelity={"preset": "fast"})
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> module that defines it
_LAZY = {
    "OpticalEncoder": "optoenc.encoders.base",
    "EncoderConfig": "optoenc.encoders.base",
    "MaskEncoder": "optoenc.encoders.mask",
    "SceneOperator": "optoenc.encoders.operator",
    "Decoder": "optoenc.decoders",
    "DecoderConfig": "optoenc.decoders",
    "Dataset": "optoenc.datasets.base",
    "DatasetConfig": "optoenc.datasets.base",
    "Splits": "optoenc.datasets.base",
    "Split": "optoenc.datasets.base",
    "Augmentation": "optoenc.augment",
    "SceneConfig": "optoenc.encoders.geometry",
    "SensorConfig": "optoenc.encoders.geometry",
    "FidelityConfig": "optoenc.encoders.fidelity",
    "Knobs": "optoenc.encoders.fidelity",
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
