"""optoenc's built-in plugins, registered through the same hooks as third-party ones."""

from __future__ import annotations

from .hookspecs import hookimpl


@hookimpl
def optoenc_register_encoders(registry):
    from .encoders.diffuser import Diffuser

    for cls in (Diffuser,):
        registry.add(cls)


@hookimpl
def optoenc_register_decoders(registry):
    from .decoders import FCNN, Logistic

    for cls in (Logistic, FCNN):
        registry.add(cls)


@hookimpl
def optoenc_register_augmentations(registry):
    from . import augment

    for cls in augment.BUILTIN:
        registry.add(cls)


@hookimpl
def optoenc_register_datasets(registry):
    from .datasets.mnist import MNIST

    registry.add(MNIST)
