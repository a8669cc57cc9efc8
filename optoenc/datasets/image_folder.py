"""Images from a local folder (the ImageFolder convention): classes from folder names, or no labels.

Layouts of ``dataset.root`` (PNG or JPEG files, any case of ``.png``,
``.jpg``, ``.jpeg``; hidden files and other files are skipped):

* ``root/<class>/*.png``: one folder per class (files in deeper folders
  count for their class folder); classes are the sorted folder names.
* ``root/*.png``: images directly in ``root``: no labels (every label 0,
  one class), for reconstruction.
* ``root/train/...`` and ``root/test/...`` (and optionally ``root/val/...``),
  each in one of the layouts above: the official splits. ``test`` and
  ``val`` may hold only classes that ``train`` has.

Without a ``test`` folder, the test and validation splits are carved from
all images (``test_fraction``, ``val_fraction``) by a permutation seeded
with ``split_seed``; without a ``val`` folder, validation is carved from the
training images alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch

from ..errors import ConfigError, DataError
from ..settings import setting, to_dict
from . import _files
from .base import Dataset, DatasetConfig, Split, Splits

__all__ = ["ImageFolder", "ImageFolderConfig"]

_EXPECTED = "images as root/<class>/*.png|jpg (or root/*.png|jpg without labels; root/train, root/test for official splits)"


@dataclass
class ImageFolderConfig(DatasetConfig):
    """Image folder settings: where the images are, how they are read and how the splits are cut."""

    root: Optional[str] = setting(
        None, "folder of the PNG or JPEG images: root/<class>/*.png, root/*.png (no labels), or root/train + root/test"
    )
    labels: str = setting(
        "folders", "folders: the class is the image's folder (images directly in root: no labels); "
        "none: every label 0, one class (reconstruction)", choices=("folders", "none"),
    )
    color: str = setting(
        "auto", "gray: one channel (luminance of colour images); rgb: three (gray images repeated); "
        "auto: rgb if any image has colour", choices=("auto", "gray", "rgb"),
    )
    size: Optional[tuple[int, int]] = setting(
        None, "resize every image to (rows, columns), bilinear in linear light (null: all images must have one size)", ge=1
    )
    gamma: str = setting(
        "srgb", "how the files encode intensity: srgb (undone to linear light) or none (value / 255 as it is)",
        choices=("srgb", "none"),
    )
    val_fraction: float = setting(
        0.1, "validation images carved from the training images when there is no root/val folder (at least one)", gt=0, lt=1
    )
    test_fraction: float = setting(
        0.1, "test images carved from all images when there is no root/test folder (at least one)", gt=0, lt=1
    )
    train_size: Optional[int] = setting(None, "training images (null: all not carved off); smaller for quick runs", ge=2)
    split_seed: int = setting(0, "seed of the fixed split permutation (independent of the training seed)")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.val_fraction + self.test_fraction >= 1:
            raise ConfigError(
                "val_fraction", self.val_fraction, f"val_fraction + test_fraction must be < 1 (test_fraction = {self.test_fraction})"
            )


def _images_under(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file() and _files.is_image(p) and not _hidden(p, folder))


def _hidden(path: Path, top: Path) -> bool:
    return any(part.startswith(".") for part in path.relative_to(top).parts)


def _scan(folder: Path) -> tuple[list[Path], list[str]]:
    """The images of one split folder and the class of each ("" for images directly in it), in sorted order."""
    direct = sorted(p for p in folder.iterdir() if p.is_file() and _files.is_image(p))
    subdirs = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    classes = {d.name: _images_under(d) for d in subdirs}
    with_images = [name for name, files in classes.items() if files]
    if direct and with_images:
        raise DataError(
            f"{folder}: holds images ({direct[0].name}) and class folders ({with_images[0]}/): "
            f"put each image in a class folder ({folder}/<class>/x.png) or all directly in {folder}"
        )
    if direct:
        return direct, [""] * len(direct)
    if not with_images:
        raise DataError(f"{folder}: no .png, .jpg or .jpeg image (expected {_EXPECTED})")
    empty = [name for name, files in classes.items() if not files]
    if empty:
        raise DataError(f"{folder / empty[0]}: class folder holds no .png, .jpg or .jpeg image")
    paths, names = [], []
    for name in with_images:
        paths += classes[name]
        names += [name] * len(classes[name])
    return paths, names


def _layout(root: Path) -> dict[str, tuple[list[Path], list[str]]]:
    """Each official split folder's scan: ``{"all": ...}``, or ``train``, ``test`` and optionally ``val``."""
    if (root / "train").is_dir() and (root / "test").is_dir():
        return {k: _scan(root / k) for k in ("train", "val", "test") if (root / k).is_dir()}
    if (root / "train").is_dir() != (root / "test").is_dir() and not any(_files.is_image(p) for p in root.iterdir()):
        have, missing = ("train", "test") if (root / "train").is_dir() else ("test", "train")
        raise DataError(f"{root}: has a {have}/ folder but no {missing}/ folder (official splits need both; "
                        f"otherwise rename {have}/)")
    return {"all": _scan(root)}


def _cut(parts: dict, c: ImageFolderConfig, root: Path) -> tuple[dict, dict[str, torch.Tensor]]:
    """Each split's source folder scan and the indices into it that the split takes (unsorted)."""
    gen = torch.Generator().manual_seed(c.split_seed)
    if "all" in parts:
        n = len(parts["all"][0])
        perm = torch.randperm(n, generator=gen)
        n_test, n_val = _files.carve(n, c.test_fraction), _files.carve(n, c.val_fraction)
        cut = {"train": perm[n_test + n_val :], "val": perm[n_test : n_test + n_val], "test": perm[:n_test]}
        source = {k: parts["all"] for k in cut}
    else:
        n = len(parts["train"][0])
        source = {k: parts.get(k, parts["train"]) for k in ("train", "val", "test")}
        cut = {"test": torch.arange(len(parts["test"][0]))}
        if "val" in parts:
            cut["val"], cut["train"] = torch.arange(len(parts["val"][0])), torch.arange(n)
        else:
            perm = torch.randperm(n, generator=gen)
            n_val = _files.carve(n, c.val_fraction)
            cut["val"], cut["train"] = perm[:n_val], perm[n_val:]
    if c.train_size is not None and c.train_size < len(cut["train"]):
        cut["train"] = cut["train"][torch.randperm(len(cut["train"]), generator=gen)[: c.train_size]]
    if len(cut["train"]) < 2:
        raise ConfigError(
            "dataset.val_fraction", c.val_fraction,
            f"leaves {len(cut['train'])} training image(s) of {n} in {root}: a run needs >= 2 (lower the fractions or add images)",
        )
    return source, cut


def _classes(parts: dict, labels: str, root: Path) -> list[str] | None:
    """The sorted class names, or None without labels (``labels=none`` or images directly in the folders)."""
    foldered = {key: bool(names[0]) for key, (_, names) in parts.items()}
    if labels == "none" or not any(foldered.values()):
        return None
    if not all(foldered.values()):
        flat = min(k for k, v in foldered.items() if not v)
        uses = ", ".join(k + "/" for k, v in foldered.items() if v)
        raise DataError(
            f"{root / flat}: holds images directly while {uses} uses class folders: put class folders in all of "
            "train/, val/, test/ or in none (or set dataset.labels=none)"
        )
    classes = sorted(set(parts.get("train", parts.get("all"))[1]))
    for key, (_, names) in parts.items():
        extra = sorted(set(names) - set(classes))
        if extra:
            raise DataError(f"{root / key / extra[0]}: class folder not in {root / 'train'} (classes: {', '.join(classes)})")
    return classes


def _pictures(files: dict[str, list[Path]], decoded: dict[str, list], c: ImageFolderConfig) -> dict[str, torch.Tensor]:
    """Each split's decoded images in one colour and one size, stacked."""
    color = c.color
    if color == "auto":
        color = "rgb" if any(_files.has_colour(x) for xs in decoded.values() for x in xs) else "gray"
    shape0, file0 = None, None
    out = {}
    for k, xs in decoded.items():
        pictures = []
        for p, x in zip(files[k], xs):
            x = _files.to_channels(x, color)
            if c.size is not None:
                x = _files.resize(x, c.size)
            elif shape0 is None:
                shape0, file0 = x.shape[-2:], p
            elif x.shape[-2:] != shape0:
                raise DataError(
                    f"{p}: image is {x.shape[-2]} x {x.shape[-1]} but {file0} is {shape0[0]} x {shape0[1]}: "
                    f"set dataset.size (e.g. dataset.size={shape0[0]}x{shape0[1]}) to resize every image"
                )
            pictures.append(x)
        out[k] = _files.stack(pictures)
    return out


class ImageFolder(Dataset):
    """PNG or JPEG images from a local folder, labelled by class folder (or unlabelled, for reconstruction)."""

    name = "image_folder"
    local_files = True
    Config = ImageFolderConfig
    #: Set per folder by :meth:`load` (the number of class folders; 1 without labels).
    num_classes = 0

    def load(self) -> Splits:
        c = self.config
        root = _files.require_root(c.root, _EXPECTED)
        parts = _layout(root)
        classes = _classes(parts, c.labels, root)
        index = {n: i for i, n in enumerate(classes or [])}
        source, cut = _cut(parts, c, root)
        digest = _files.Digest("image_folder", to_dict(c))
        files: dict[str, list[Path]] = {}
        decoded: dict[str, list] = {}
        labels: dict[str, torch.Tensor] = {}
        for k in ("train", "val", "test"):
            paths, names = source[k]
            idx = cut[k].sort().values.tolist()
            files[k] = [paths[i] for i in idx]
            labels[k] = torch.tensor([index[names[i]] if classes else 0 for i in idx], dtype=torch.int64)
            decoded[k] = []
            for p in files[k]:
                data = p.read_bytes()
                digest.add(p.relative_to(root).as_posix(), data)
                decoded[k].append(_files.decode(data, p, c.gamma))
            digest.add_labels(labels[k].tolist())
        images = _pictures(files, decoded, c)
        return Splits(
            **{k: Split(images[k], labels[k]) for k in images}, num_classes=len(classes) if classes else 1,
            digest=digest.hexdigest(), class_names=tuple(classes or ()),
        )
