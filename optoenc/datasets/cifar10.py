"""CIFAR-10 from the python version's pickles in a local ``cifar-10-batches-py/`` folder.

The folder (``dataset.root`` itself, or ``dataset.root/cifar-10-batches-py``)
holds ``data_batch_1`` ... ``data_batch_5`` (the training images),
``test_batch`` and ``batches.meta`` (the class names), as the CIFAR-10
"python version" archive unpacks. The pickles are read with an unpickler
that builds only NumPy arrays, lists, dicts, bytes and numbers. The decoded
arrays are kept in memory once per process.
"""

from __future__ import annotations

import hashlib
import io
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

from ..errors import ConfigError, DataError
from ..settings import setting, to_dict
from . import _files
from .base import Dataset, DatasetConfig, Split, Splits

__all__ = ["CIFAR10", "CIFAR10Config", "FOLDER", "TRAIN_FILES", "TEST_FILE", "META_FILE"]

#: The folder the python version's archive unpacks to.
FOLDER = "cifar-10-batches-py"
TRAIN_FILES = tuple(f"data_batch_{i}" for i in range(1, 6))
TEST_FILE = "test_batch"
META_FILE = "batches.meta"
_SIDE = 32
_CACHE: dict[tuple, dict[str, Any]] = {}
_CACHE_MAX = 2
_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("_codecs", "encode"),  # how Python 3 writes bytes at pickle protocol 2
}


@dataclass
class CIFAR10Config(DatasetConfig):
    """CIFAR-10 settings: where the pickles are, the colour and how the splits are cut."""

    root: Optional[str] = setting(None, f"folder holding {FOLDER}/ (or that folder itself), as the python version unpacks")
    color: str = setting(
        "rgb", "rgb: the three channels (needs sensor.color=rgb); gray: their luminance in linear light", choices=("rgb", "gray")
    )
    gamma: str = setting(
        "srgb", "how the pickles encode intensity: srgb (undone to linear light) or none (value / 255 as it is)",
        choices=("srgb", "none"),
    )
    val_size: Optional[int] = setting(
        None, "validation images carved from the training batches (null: a tenth of them, 5,000 for CIFAR-10)", ge=1
    )
    train_size: Optional[int] = setting(None, "training images (null: all not in the validation split); smaller for quick runs", ge=2)
    test_size: Optional[int] = setting(None, "test images, a fixed random subset (null: all of test_batch, 10,000)", ge=1)
    split_seed: int = setting(0, "seed of the fixed split permutation (independent of the training seed)")


class _Unpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(f"refusing {module}.{name}: a CIFAR-10 pickle holds only arrays, lists and numbers")
        if module.startswith("numpy.core.") and hasattr(np, "_core"):
            module = "numpy._core." + module.split(".", 2)[2]
        return super().find_class(module, name)


def _folder(root: Optional[str]) -> Path:
    path = _files.require_root(root, f"{FOLDER}/ with the CIFAR-10 python version's pickles")
    return path if (path / TRAIN_FILES[0]).is_file() or path.name == FOLDER else path / FOLDER


def _read(path: Path, root: Path) -> bytes:
    if not path.is_file():
        raise DataError(f"dataset.root {root}: no {path.relative_to(root)} (expected the CIFAR-10 python version's pickles)")
    return path.read_bytes()


def _unpickle(data: bytes, path: Path) -> dict:
    try:
        obj = _Unpickler(io.BytesIO(data), encoding="bytes").load()
    except Exception as err:  # any malformed pickle: one line naming the file
        raise DataError(f"{path}: not a CIFAR-10 python pickle ({type(err).__name__}: {err})") from None
    if not isinstance(obj, dict):
        raise DataError(f"{path}: not a CIFAR-10 python pickle (a {type(obj).__name__}, expected a dict)")
    return {k.decode() if isinstance(k, bytes) else k: v for k, v in obj.items()}


def _batch(obj: dict, path: Path, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    x, y = obj.get("data"), obj.get("labels")
    if not isinstance(x, np.ndarray) or x.dtype != np.uint8 or x.ndim != 2 or x.shape[1] != 3 * _SIDE * _SIDE:
        what = f"{x.dtype} {x.shape}" if isinstance(x, np.ndarray) else type(x).__name__
        raise DataError(f"{path}: 'data' is {what}, expected uint8 (N, 3072) (32 x 32 RGB planes)")
    expected = f"{path}: 'labels' must be {len(x)} integers in [0, {n_classes})"
    try:
        labels = np.asarray(y, dtype=np.int64)
    except (TypeError, ValueError):
        raise DataError(f"{expected}, got {type(y).__name__}") from None
    if labels.shape != (len(x),) or (len(labels) and (labels.min() < 0 or labels.max() >= n_classes)):
        raise DataError(f"{expected}, got {labels.size} in [{labels.min()}, {labels.max()}]" if labels.size else f"{expected}, got none")
    return x.reshape(len(x), 3, _SIDE, _SIDE), labels


def load_arrays(root: Optional[str]) -> dict[str, Any]:
    """uint8 images ``(N, 3, 32, 32)`` and int64 labels of the training batches and the test batch, the class names
    and the SHA-256 of the seven files; cached per process.

    Raises:
        ConfigError: ``root`` not set or not a folder.
        DataError: a missing file or one that is not a CIFAR-10 pickle, naming it and what is expected.
    """
    folder = _folder(root)
    blobs = {name: _read(folder / name, Path(str(root)).expanduser()) for name in (META_FILE, *TRAIN_FILES, TEST_FILE)}
    h = hashlib.sha256(b"cifar10")
    for name, data in blobs.items():
        h.update(name.encode() + len(data).to_bytes(8, "little") + data)
    key = (str(folder), h.hexdigest())
    if key not in _CACHE:
        raw = {name: _unpickle(data, folder / name) for name, data in blobs.items()}
        names = raw[META_FILE].get("label_names")
        if not isinstance(names, list) or len(names) < 2:
            raise DataError(f"{folder / META_FILE}: 'label_names' must be a list of the class names (CIFAR-10: 10)")
        names = tuple(n.decode() if isinstance(n, bytes) else str(n) for n in names)
        train = [_batch(raw[f], folder / f, len(names)) for f in TRAIN_FILES]
        test = _batch(raw[TEST_FILE], folder / TEST_FILE, len(names))
        while len(_CACHE) >= _CACHE_MAX:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = {
            "train_images": np.concatenate([x for x, _ in train]), "train_labels": np.concatenate([y for _, y in train]),
            "test_images": test[0], "test_labels": test[1], "class_names": names, "digest": key[1],
        }
    return _CACHE[key]


def _tensor(x: np.ndarray, color: str, gamma: str) -> torch.Tensor:
    images = torch.from_numpy(np.take(_files.levels(gamma), x))
    if color == "gray":
        r, g, b = _files.LUMINANCE
        images = (r * images[:, 0:1] + g * images[:, 1:2] + b * images[:, 2:3]).clamp_(0.0, 1.0)
    return images.contiguous()


class CIFAR10(Dataset):
    """CIFAR-10: 32x32 colour photographs of 10 classes, read from the local python-version pickles.

    The validation split is a fixed random subset of the 50,000 training
    images (``torch.randperm`` seeded with ``split_seed``); the training
    split is the next ``train_size`` images of the same permutation;
    ``test_size`` takes a fixed random subset of ``test_batch``. Each split
    is returned in the files' order.
    """

    name = "cifar10"
    local_files = True
    Config = CIFAR10Config
    num_classes = 10

    def load(self) -> Splits:
        c = self.config
        a = load_arrays(c.root)
        n_train, n_test = len(a["train_labels"]), len(a["test_labels"])
        n_val = _files.carve(n_train, 0.1) if c.val_size is None else c.val_size
        if n_train - n_val < 2:
            raise ConfigError("dataset.val_size", c.val_size, f"must leave >= 2 of the {n_train} training images for training")
        n_fit = n_train - n_val if c.train_size is None else c.train_size
        if n_val + n_fit > n_train:
            raise ConfigError(
                "dataset.train_size", c.train_size,
                f"val_size + train_size must be <= {n_train}, the training images (val_size = {n_val})",
            )
        gen = torch.Generator().manual_seed(c.split_seed)
        perm = torch.randperm(n_train, generator=gen)
        val, train = perm[:n_val].sort().values, perm[n_val : n_val + n_fit].sort().values
        test = torch.arange(n_test)
        if c.test_size is not None and c.test_size < n_test:
            test = torch.randperm(n_test, generator=gen)[: c.test_size].sort().values

        def split(kind: str, idx: torch.Tensor) -> Split:
            i = idx.numpy()
            return Split(_tensor(a[f"{kind}_images"][i], c.color, c.gamma), torch.from_numpy(a[f"{kind}_labels"][i]))

        settings = repr(sorted((k, v) for k, v in to_dict(c).items() if k != "root"))
        return Splits(
            train=split("train", train), val=split("train", val), test=split("test", test), num_classes=len(a["class_names"]),
            digest=hashlib.sha256((a["digest"] + settings).encode()).hexdigest(), class_names=a["class_names"],
        )
