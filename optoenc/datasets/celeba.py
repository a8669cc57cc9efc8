"""CelebA faces from a local copy: the aligned JPEGs, the official partition and the attribute list.

``dataset.root`` (or ``dataset.root/celeba``, torchvision's layout) holds

* ``img_align_celeba/*.jpg``: the aligned and cropped faces (178 x 218);
* ``list_eval_partition.txt``: ``000001.jpg 0`` per line, 0 train, 1
  validation, 2 test (the official splits);
* ``list_attr_celeba.txt`` (read only with ``dataset.attribute``): the image
  count, the attribute names, then ``000001.jpg -1 1 ...`` per image.

With ``dataset.attribute`` (e.g. ``Smiling``) the label is 1 where the
attribute is +1 and 0 where it is -1; without it every label is 0 (one
class): identity-free reconstruction.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch

from ..errors import ConfigError, DataError
from ..settings import setting, to_dict
from . import _files
from .base import Dataset, DatasetConfig, Split, Splits

__all__ = ["CelebA", "CelebAConfig", "IMAGES", "PARTITION", "ATTRIBUTES"]

IMAGES = "img_align_celeba"
PARTITION = "list_eval_partition.txt"
ATTRIBUTES = "list_attr_celeba.txt"
_EXPECTED = f"{IMAGES}/*.jpg and {PARTITION} (and {ATTRIBUTES} for dataset.attribute)"
_SPLITS = ("train", "val", "test")


@dataclass
class CelebAConfig(DatasetConfig):
    """CelebA settings: where the files are, the label, the picture's crop and size, and split caps."""

    root: Optional[str] = setting(None, f"folder holding {IMAGES}/ and {PARTITION} (or its celeba/ subfolder)")
    attribute: Optional[str] = setting(
        None, f"binary label from this {ATTRIBUTES} column (e.g. Smiling: 1 where +1, 0 where -1); null: no labels "
        "(reconstruction)"
    )
    crop: Optional[tuple[int, int]] = setting(
        (178, 178), "central crop (rows, columns) of the 218 x 178 aligned face before resizing (null: the whole image)", ge=1
    )
    size: tuple[int, int] = setting((64, 64), "image size (rows, columns) after cropping, bilinear in linear light", ge=1)
    color: str = setting(
        "rgb", "rgb: the three channels (needs sensor.color=rgb); gray: their luminance in linear light", choices=("rgb", "gray")
    )
    gamma: str = setting(
        "srgb", "how the JPEGs encode intensity: srgb (undone to linear light) or none (value / 255 as it is)",
        choices=("srgb", "none"),
    )
    train_size: Optional[int] = setting(None, "training images, a fixed random subset of the official split (null: all)", ge=2)
    val_size: Optional[int] = setting(None, "validation images, a fixed random subset of the official split (null: all)", ge=1)
    test_size: Optional[int] = setting(None, "test images, a fixed random subset of the official split (null: all)", ge=1)
    split_seed: int = setting(0, "seed of the subsets drawn by train_size, val_size, test_size")


def _folder(root: Optional[str]) -> Path:
    path = _files.require_root(root, _EXPECTED)
    return path / "celeba" if not (path / PARTITION).is_file() and (path / "celeba" / PARTITION).is_file() else path


def _read_text(path: Path, what: str) -> bytes:
    if not path.is_file():
        raise DataError(f"dataset.root {path.parent}: no {path.name} (expected {what})")
    return path.read_bytes()


def _partition(path: Path, data: bytes) -> dict[str, list[str]]:
    """Official split -> image names, in the file's order."""
    out: dict[str, list[str]] = {k: [] for k in _SPLITS}
    for number, line in enumerate(data.decode("utf-8", "replace").splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 2 or parts[1] not in ("0", "1", "2"):
            raise DataError(f"{path} line {number}: {line.strip()!r}, expected '<image>.jpg 0|1|2' (0 train, 1 val, 2 test)")
        out[_SPLITS[int(parts[1])]].append(parts[0])
    for k, names in out.items():
        if not names:
            raise DataError(f"{path}: no image in the {k} split (partition {_SPLITS.index(k)}); expected '<image>.jpg 0|1|2' lines")
    return out


def _attribute(path: Path, data: bytes, attribute: str) -> dict[str, int]:
    """Image name -> 1 where ``attribute`` is +1, 0 where -1."""
    lines = data.decode("utf-8", "replace").splitlines()
    expected = "the image count, then the attribute names, then '<image>.jpg 1 -1 ...' per image"
    if len(lines) < 2 or not lines[0].strip().isdigit():
        raise DataError(f"{path} line 1: {lines[0].strip() if lines else ''!r} is not the image count (expected {expected})")
    names = lines[1].split()
    if attribute not in names:
        near = difflib.get_close_matches(attribute, names, n=1)
        hint = f"did you mean {near[0]}? " if near else ""
        raise ConfigError(
            "dataset.attribute", attribute,
            f"not a column of {path}: {hint}e.g. {', '.join(names[:6])} ({len(names)} attributes)",
        )
    col = names.index(attribute) + 1
    rows = [line.split() for line in lines[2:] if line.strip()]
    if len(rows) != int(lines[0]):
        raise DataError(f"{path}: line 1 gives {int(lines[0])} images but {len(rows)} follow (a truncated file?)")
    out = {}
    for number, parts in enumerate(rows, 3):
        if len(parts) != len(names) + 1 or parts[col] not in ("1", "-1"):
            raise DataError(f"{path} line {number}: expected '<image>.jpg' and {len(names)} values of 1 or -1")
        out[parts[0]] = int(parts[col] == "1")
    return out


class CelebA(Dataset):
    """CelebA aligned faces from local files: a binary attribute label (e.g. Smiling) or none, official splits.

    Each face is centre-cropped to ``crop`` and resized to ``size`` (64 x 64
    by default: a 3 x 64 x 64 scene keeps the scene operator of a 24 x 32
    embedding at 9.4 million entries, the fast precomputed path).
    ``train_size``, ``val_size`` and ``test_size`` draw fixed random subsets
    of the official splits (``split_seed``); each split is returned in the
    partition file's order.
    """

    name = "celeba"
    local_files = True
    Config = CelebAConfig
    #: 2 with ``dataset.attribute``, 1 without (set by :meth:`load`).
    num_classes = 2

    def load(self) -> Splits:
        c = self.config
        root = _folder(c.root)
        digest = _files.Digest("celeba", to_dict(c))
        part_file = root / PARTITION
        part_data = _read_text(part_file, "the official splits, '<image>.jpg 0|1|2' per line")
        digest.add(PARTITION, part_data)
        splits = _partition(part_file, part_data)
        labels_of: dict[str, int] = {}
        if c.attribute is not None:
            attr_file = root / ATTRIBUTES
            attr_data = _read_text(attr_file, "CelebA's attribute list, for dataset.attribute")
            digest.add(ATTRIBUTES, attr_data)
            labels_of = _attribute(attr_file, attr_data, c.attribute)
        images = root / IMAGES
        if not images.is_dir():
            raise DataError(f"dataset.root {root}: no {IMAGES}/ folder (expected {_EXPECTED})")
        gen = torch.Generator().manual_seed(c.split_seed)
        out = {}
        for k, cap in zip(_SPLITS, (c.train_size, c.val_size, c.test_size)):
            names = splits[k]
            if cap is not None and cap < len(names):
                keep = torch.randperm(len(names), generator=gen)[:cap].sort().values.tolist()
                names = [names[i] for i in keep]
            xs = torch.empty(len(names), 3 if c.color == "rgb" else 1, *c.size)  # filled in place: no second copy
            ys = []
            for i, name in enumerate(names):
                path = images / name
                if not path.is_file():
                    raise DataError(f"{path}: listed in {part_file.name} but missing (expected the aligned JPEGs in {IMAGES}/)")
                if c.attribute is not None and name not in labels_of:
                    raise DataError(f"{root / ATTRIBUTES}: no line for {name} (listed in {PARTITION})")
                data = path.read_bytes()
                digest.add(f"{IMAGES}/{name}", data)
                x = _files.decode(data, path, c.gamma)
                if c.crop is not None:
                    x = _files.center_crop(x, c.crop, path)
                xs[i] = _files.resize(_files.to_channels(x, c.color), c.size)
                ys.append(labels_of.get(name, 0))
            out[k] = Split(xs, torch.tensor(ys, dtype=torch.int64))
        labelled = c.attribute is not None
        return Splits(
            **out, num_classes=2 if labelled else 1, digest=digest.hexdigest(),
            class_names=(f"not {c.attribute}", c.attribute) if labelled else (),
        )
