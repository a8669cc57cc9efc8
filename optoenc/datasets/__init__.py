"""Datasets: labelled images loaded into train / val / test :class:`Splits`."""

from .base import Dataset, DatasetConfig, Split, Splits
from .celeba import CelebA, CelebAConfig
from .cifar10 import CIFAR10, CIFAR10Config
from .image_folder import ImageFolder, ImageFolderConfig
from .mnist import MNIST, MNISTConfig

__all__ = [
    "Dataset", "DatasetConfig", "Split", "Splits", "MNIST", "MNISTConfig", "ImageFolder", "ImageFolderConfig",
    "CIFAR10", "CIFAR10Config", "CelebA", "CelebAConfig",
]
