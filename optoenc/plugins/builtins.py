"""optoenc's built-in plugins, registered through the same hooks as third-party ones."""

from __future__ import annotations

from .hookspecs import hookimpl


@hookimpl
def optoenc_register_encoders(registry):
    from ..encoders.coded_aperture import CodedAperture
    from ..encoders.diffuser import Diffuser
    from ..encoders.lens import Lens
    from ..encoders.phase_mask import LearnedPhaseMask, PhaseMask
    from ..encoders.slm import FixedSLM, LearnedSLM

    for cls in (Lens, CodedAperture, Diffuser, FixedSLM, LearnedSLM, PhaseMask, LearnedPhaseMask):
        registry.add(cls)


@hookimpl
def optoenc_register_decoders(registry):
    from ..decoders import FCNN, Logistic
    from ..decoders.image import Tikhonov, UNet, UnrolledADMM

    for cls in (Logistic, FCNN, UNet, Tikhonov, UnrolledADMM):
        registry.add(cls)


@hookimpl
def optoenc_register_augmentations(registry):
    from .. import augment

    for cls in augment.BUILTIN:
        registry.add(cls)


@hookimpl
def optoenc_register_datasets(registry):
    from ..datasets.celeba import CelebA
    from ..datasets.cifar10 import CIFAR10
    from ..datasets.image_folder import ImageFolder
    from ..datasets.mnist import MNIST

    for cls in (MNIST, ImageFolder, CIFAR10, CelebA):
        registry.add(cls)


@hookimpl
def optoenc_register_tasks(registry):
    from ..tasks import Classification, Reconstruction

    for cls in (Classification, Reconstruction):
        registry.add(cls)
