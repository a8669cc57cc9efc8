"""pluggy hook specifications: the whole plugin interface of optoenc.

A plugin is a module (or object) with functions decorated by
:data:`hookimpl`, advertised under the ``optoenc`` entry-point group::

    [project.entry-points.optoenc]
    my_plugin = "my_package.plugin"

Each hook receives a registrar; call ``registry.add(cls)`` for each class.
optoenc registers its own built-ins through these same hooks
(:mod:`optoenc.plugins.builtins`). The classes' interfaces: docs/plugin-authoring.md;
their conformance kits: :mod:`optoenc.testing`.
"""

from __future__ import annotations

import pluggy

from .registry import KINDS

__all__ = ["PROJECT", "hookspec", "hookimpl", "HOOKS"]

PROJECT = "optoenc"
hookspec = pluggy.HookspecMarker(PROJECT)
#: Decorator for plugin hook implementations.
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def optoenc_register_encoders(registry):
    """Register `optoenc.OpticalEncoder` subclasses (or `optoenc.MaskEncoder` ones): ``registry.add(MyEncoder)``."""


@hookspec
def optoenc_register_decoders(registry):
    """Register `optoenc.Decoder` subclasses (digital decoders on the embedding: classifiers, reconstructions)."""


@hookspec
def optoenc_register_augmentations(registry):
    """Register `optoenc.Augmentation` subclasses (object-plane transforms)."""


@hookspec
def optoenc_register_datasets(registry):
    """Register `optoenc.Dataset` subclasses (labelled images loaded into `optoenc.Splits`)."""


@hookspec
def optoenc_register_tasks(registry):
    """Register `optoenc.tasks.Task` subclasses (what the decoder's output is trained for: target, loss, metrics)."""


#: hook name -> registry kind, in registration order: one hook per kind of
#: :data:`optoenc.plugins.registry.KINDS` (the one list of plugin kinds).
HOOKS = {f"optoenc_register_{kind}s": kind for kind in KINDS}
