"""Datasets: labelled images loaded into train / val / test :class:`Splits`."""

from .base import Dataset, DatasetConfig, Split, Splits
from .mnist import MNIST, MNISTConfig

__all__ = ["Dataset", "DatasetConfig", "Split", "Splits", "MNIST", "MNISTConfig"]
