"""Shared parts of the datasets read from image files: decoding, colour, resizing, split carving, digests."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Any, Iterable, Optional

import numpy as np
import torch

from ..devices import LUMINANCE_WEIGHTS
from ..errors import ConfigError, DataError

#: File name endings read as images (compared case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
#: Linear-light luminance weights of R, G, B (Rec. 709 primaries, those of sRGB): the one copy, in devices.
LUMINANCE = LUMINANCE_WEIGHTS
_GRAY_MODES = {"1", "L", "LA", "I", "I;16", "I;16B", "I;16L", "F"}


def is_image(path: Path) -> bool:
    """A visible file whose name ends in one of :data:`IMAGE_EXTENSIONS`."""
    return not path.name.startswith(".") and path.suffix.lower() in IMAGE_EXTENSIONS


def require_root(root: Optional[str], expected: str) -> Path:
    """``dataset.root`` as an existing folder.

    Raises:
        ConfigError: ``root`` not set, or not an existing folder; ``expected``
            says what the folder must hold.
    """
    if not root:
        raise ConfigError("dataset.root", root, f"must be set: the folder holding {expected}")
    path = Path(root).expanduser()
    if not path.is_dir():
        raise ConfigError("dataset.root", root, f"is not an existing folder (expected {expected})")
    return path


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve undone (IEC 61966-2-1): encoded values in [0, 1] -> linear intensity in [0, 1]."""
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


_LEVELS: dict[str, np.ndarray] = {}


def levels(gamma: str) -> np.ndarray:
    """Intensity of each 8-bit value 0..255: float32 ``(256,)``, value / 255 through the sRGB curve unless ``"none"``
    (looked up per pixel: the curve's numbers at a fraction of its cost)."""
    if gamma not in _LEVELS:
        x = np.arange(256, dtype=np.float32) / np.float32(255.0)
        _LEVELS[gamma] = srgb_to_linear(x) if gamma == "srgb" else x
    return _LEVELS[gamma]


def decode(data: bytes, path: Path, gamma: str) -> np.ndarray:
    """An image file's bytes as float32 ``(C, h, w)`` intensities in [0, 1], C 1 (gray modes) or 3.

    8-bit values are divided by 255, 16-bit ones by 65535; alpha is dropped;
    ``gamma="srgb"`` undoes the sRGB curve (linear light), ``"none"`` keeps
    the values.

    Raises:
        DataError: a file Pillow cannot read, naming it.
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as img:
            img.load()
            mode = img.mode
            if mode in ("1", "LA"):
                img = img.convert("L")
            elif mode not in _GRAY_MODES:
                img = img.convert("RGB")
            arr = np.asarray(img)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
        raise DataError(f"{path}: not a readable PNG or JPEG image ({type(err).__name__}: {err})") from None
    arr = arr[None] if arr.ndim == 2 else np.ascontiguousarray(arr.transpose(2, 0, 1))
    if arr.dtype == np.uint8:
        return np.take(levels(gamma), arr)
    x = np.clip(arr.astype(np.float32) / np.float32(1.0 if arr.dtype.kind == "f" else 65535.0), 0.0, 1.0)
    return srgb_to_linear(x) if gamma == "srgb" else x


def has_colour(x: np.ndarray) -> bool:
    """Whether a ``(C, h, w)`` image has channels that differ (an RGB file of gray pixels has none)."""
    return x.shape[0] == 3 and not (np.array_equal(x[0], x[1]) and np.array_equal(x[0], x[2]))


def to_channels(x: np.ndarray, color: str) -> np.ndarray:
    """``(C, h, w)`` as ``color``: ``gray`` (luminance of an RGB image; an RGB file of gray pixels keeps its
    values) or ``rgb`` (a gray image repeated on the three channels)."""
    if color == "gray":
        if x.shape[0] == 1:
            return x
        if not has_colour(x):
            return x[:1]
        r, g, b = LUMINANCE
        return np.clip(r * x[0] + g * x[1] + b * x[2], 0.0, 1.0).astype(np.float32)[None]
    return x if x.shape[0] == 3 else np.repeat(x, 3, axis=0)


def center_crop(x: np.ndarray, crop: tuple[int, int], path: Path) -> np.ndarray:
    """The central ``crop = (rows, columns)`` of a ``(C, h, w)`` image (top-left of centre on odd margins)."""
    h, w = x.shape[-2:]
    ch, cw = crop
    if ch > h or cw > w:
        raise DataError(f"{path}: image {h} x {w} is smaller than dataset.crop = {ch} x {cw}")
    top, left = (h - ch) // 2, (w - cw) // 2
    return x[:, top : top + ch, left : left + cw]


def resize(x: np.ndarray, size: tuple[int, int]) -> torch.Tensor:
    """``(C, h, w)`` resampled to ``size = (rows, columns)`` in linear light: bilinear, antialiased when reducing
    (the area each new pixel covers is averaged), values kept in [0, 1]."""
    t = torch.from_numpy(np.ascontiguousarray(x))
    if tuple(t.shape[-2:]) == tuple(size):
        return t
    out = torch.nn.functional.interpolate(t[None], size=tuple(size), mode="bilinear", align_corners=False, antialias=True)
    return out[0].clamp_(0.0, 1.0)


def carve(n: int, fraction: float) -> int:
    """How many of ``n`` images a split of ``fraction`` takes: ``round(fraction * n)``, at least 1 when ``fraction > 0``."""
    if fraction <= 0 or n == 0:
        return 0
    return max(1, int(round(fraction * n)))


class Digest:
    """SHA-256 of what a dataset's tensors are made from: a tag, its settings, then each file's name and bytes."""

    def __init__(self, tag: str, settings: dict[str, Any]):
        import PIL

        self._h = hashlib.sha256(f"{tag}\0pillow {PIL.__version__}\0".encode())
        self._h.update(repr(sorted((k, settings[k]) for k in settings if k != "root")).encode())

    def add(self, name: str, data: bytes) -> None:
        """One file: its name (relative to the dataset root) and its bytes."""
        self._h.update(len(name).to_bytes(4, "little") + name.encode() + len(data).to_bytes(8, "little"))
        self._h.update(data)

    def add_labels(self, labels: Iterable[int]) -> None:
        """Labels not read from a file (e.g. from folder names)."""
        self._h.update(np.asarray(list(labels), dtype=np.int64).tobytes())

    def hexdigest(self) -> str:
        return self._h.hexdigest()


def stack(images: list) -> torch.Tensor:
    """``(C, h, w)`` arrays or tensors as one float32 ``(N, C, h, w)`` tensor."""
    return torch.stack([torch.as_tensor(x, dtype=torch.float32) for x in images]).contiguous()
