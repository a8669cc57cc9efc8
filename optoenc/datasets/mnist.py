"""MNIST from the IDX files bundled with optoenc, checksum-verified.

Where the files are read from, first match wins:

1. the config field ``root`` (a folder);
2. the environment variable ``OPTOENC_MNIST_ROOT``;
3. the copy bundled in ``optoenc/resources/mnist`` (a package resource).

The folder holds the four canonical ``*-ubyte.gz`` files and a ``SHA256SUMS``
of them. Every load checks each file's SHA-256 against it; a folder without
``SHA256SUMS`` (e.g. a torchvision download) is checked against the bundled
checksums of the *uncompressed* files instead (gzip headers differ between
mirrors). The decoded arrays are kept in memory once per process.
"""

from __future__ import annotations

import hashlib
import importlib.resources
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

from ..errors import ConfigError, DataError
from ..settings import setting
from .base import DatasetConfig, Dataset, Split, Splits
from .idx import decompress, parse_idx

__all__ = ["MNIST", "MNISTConfig", "ROOT_ENV", "FILES", "load_arrays"]

#: Environment variable overriding the folder of the MNIST files.
ROOT_ENV = "OPTOENC_MNIST_ROOT"
#: Role -> canonical file name.
FILES = {
    "train_images": "train-images-idx3-ubyte.gz",
    "train_labels": "train-labels-idx1-ubyte.gz",
    "test_images": "t10k-images-idx3-ubyte.gz",
    "test_labels": "t10k-labels-idx1-ubyte.gz",
}
TRAIN_TOTAL, TEST_TOTAL = 60_000, 10_000
_CACHE: dict[tuple, dict[str, np.ndarray]] = {}
_CACHE_MAX = 4


@dataclass
class MNISTConfig(DatasetConfig):
    """MNIST settings: where the files are and how the splits are cut."""

    root: Optional[str] = setting(
        None, f"folder of the IDX .gz files (null: ${ROOT_ENV} if set, else the bundled copy)"
    )
    val_size: int = setting(
        5000, "validation examples carved from the 60,000 training images (the best checkpoint is selected on them: "
        "a run needs >= 1)",
        ge=0, lt=TRAIN_TOTAL,
    )
    train_size: Optional[int] = setting(
        None, "training examples (null: all those not in the validation split); smaller for quick runs", ge=2
    )
    test_size: Optional[int] = setting(None, "test examples, a fixed random subset (null: all 10,000)", ge=1, le=TEST_TOTAL)
    split_seed: int = setting(0, "seed of the fixed split permutation (independent of the training seed)")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.train_size is not None and self.val_size + self.train_size > TRAIN_TOTAL:
            raise ConfigError(
                "train_size", self.train_size, f"val_size + train_size must be <= {TRAIN_TOTAL} (val_size = {self.val_size})"
            )


def _bundled_root():
    return importlib.resources.files("optoenc") / "resources" / "mnist"


def resolve_root(root: str | None = None) -> tuple[Any, str]:
    """The folder to read (a Path or package resource) and where it came from.

    Precedence: ``root`` argument > ``$OPTOENC_MNIST_ROOT`` > bundled copy.
    """
    if root:
        return Path(root).expanduser(), "dataset.root"
    env = os.environ.get(ROOT_ENV, "").strip()
    if env:
        return Path(env).expanduser(), f"${ROOT_ENV}"
    return _bundled_root(), "bundled"


def _read_sums(text: str) -> dict[str, str]:
    sums = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2:
            sums[parts[1].lstrip("*")] = parts[0].lower()
    return sums


def load_arrays(root: str | None = None) -> dict[str, np.ndarray]:
    """The four MNIST arrays (uint8 images ``(N, 28, 28)``, uint8 labels ``(N,)``), verified and cached.

    Raises:
        DataError: a missing or unreadable file, a checksum mismatch
            (naming the file, the expected and the actual SHA-256) or a
            malformed IDX file.
    """
    folder, origin = resolve_root(root)
    if not folder.is_dir():
        raise DataError(f"MNIST folder {folder} (from {origin}) does not exist or is not a folder")
    sums_file = folder / "SHA256SUMS"
    raw_check = not sums_file.is_file()
    sums = _read_sums((_bundled_root() / "SHA256SUMS.uncompressed" if raw_check else sums_file).read_text())
    blobs, digests = {}, []
    for role, fname in FILES.items():
        path = folder / fname
        key = fname[: -len(".gz")] if raw_check else fname
        expected = sums.get(key)
        if expected is None:
            raise DataError(f"{path}: no checksum for {key} in {'the bundled SHA256SUMS.uncompressed' if raw_check else sums_file}")
        if not path.is_file():
            raise DataError(f"{path}: MNIST file missing (expected sha256 {expected}, actual: no file)")
        data = path.read_bytes()
        if raw_check:
            data = decompress(data, str(path))
        actual = hashlib.sha256(data).hexdigest()
        if actual != expected:
            what = "uncompressed content " if raw_check else ""
            raise DataError(f"{path}: {what}SHA-256 mismatch: expected {expected}, actual {actual}")
        blobs[role], digests = data, digests + [actual]
    key = (str(folder), tuple(digests))
    if key not in _CACHE:
        arrays = {}
        for role, data in blobs.items():
            name = str(folder / FILES[role])
            arrays[role] = parse_idx(data if raw_check else decompress(data, name), name)
        _check_shapes(arrays, folder)
        arrays["digest"] = hashlib.sha256(" ".join(digests).encode()).hexdigest()
        while len(_CACHE) >= _CACHE_MAX:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = arrays
    return _CACHE[key]


def _check_shapes(a: dict[str, np.ndarray], folder: Any) -> None:
    for split in ("train", "test"):
        x, y = a[f"{split}_images"], a[f"{split}_labels"]
        if x.ndim != 3 or y.ndim != 1 or len(x) != len(y) or x.dtype != np.uint8:
            raise DataError(
                f"{folder / FILES[split + '_images']}: images {x.shape} {x.dtype} do not match labels {y.shape}"
            )


def _split(x: np.ndarray, y: np.ndarray, index: torch.Tensor) -> Split:
    idx = index.numpy()
    images = torch.from_numpy(x[idx]).to(torch.float32).div_(255.0).unsqueeze(1)
    return Split(images, torch.from_numpy(y[idx].astype(np.int64)))


class MNIST(Dataset):
    """MNIST handwritten digits, 28x28 gray in [0, 1] (bundled, checksum-verified).

    The validation split is a fixed random subset of the training images
    (``torch.randperm`` seeded with ``split_seed``); the training split is the
    next ``train_size`` images of the same permutation; ``test_size`` takes a
    fixed random subset of the test set. Each split is returned in the files'
    order.
    """

    name = "mnist"
    Config = MNISTConfig
    num_classes = 10

    def load(self) -> Splits:
        c = self.config
        a = load_arrays(c.root)
        n_train, n_test = len(a["train_labels"]), len(a["test_labels"])
        n_fit = n_train - c.val_size if c.train_size is None else c.train_size
        if c.val_size + n_fit > n_train or n_fit < 1:
            raise ConfigError(
                "dataset.train_size", c.train_size,
                f"val_size + train_size must be <= {n_train}, the training images in {c.root or 'the MNIST folder'} "
                f"(val_size = {c.val_size})",
            )
        gen = torch.Generator().manual_seed(c.split_seed)
        perm = torch.randperm(n_train, generator=gen)
        val = perm[: c.val_size].sort().values
        train = perm[c.val_size : c.val_size + n_fit].sort().values
        if c.test_size is None or c.test_size >= n_test:
            test = torch.arange(n_test)
        else:
            test = torch.randperm(n_test, generator=gen)[: c.test_size].sort().values
        return Splits(
            train=_split(a["train_images"], a["train_labels"], train),
            val=_split(a["train_images"], a["train_labels"], val),
            test=_split(a["test_images"], a["test_labels"], test),
            num_classes=self.num_classes,
            digest=a.get("digest", ""),
        )
