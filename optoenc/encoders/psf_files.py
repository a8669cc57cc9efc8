"""Reading measured PSFs (PNG, TIFF, NPY) and resampling them to the simulation grid."""

from __future__ import annotations

import hashlib
from importlib import resources
from pathlib import Path

import numpy as np
import torch

from ..errors import ConfigError
from .imaging import area_matrix, normalize_channels

__all__ = ["bundled_psf_path", "read_psf", "subtract_background", "resample_area", "file_digest", "measured_psf"]

SUFFIXES = (".png", ".tif", ".tiff", ".npy")


def bundled_psf_path() -> Path:
    """Path of the bundled DiffuserCam PSF (BSD-3, Waller Lab; licence beside it)."""
    return Path(str(resources.files("optoenc") / "resources" / "psf" / "diffusercam_psf.tif"))


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's contents (cache keys depend on what a file holds, not its name)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_psf(path: str | Path, key: str = "encoder.psf_path") -> np.ndarray:
    """Read a measured PSF as a float64 ``(C, H, W)`` array (C = 1, or 3 for R, G, B).

    Raises:
        ConfigError: the file is missing, unreadable, of an unknown type,
            wrongly shaped, non-finite or all zero.
    """
    p = Path(path)
    if p.suffix.lower() not in SUFFIXES:
        raise ConfigError(key, str(path), f"must be a {', '.join(SUFFIXES)} file")
    if not p.is_file():
        raise ConfigError(key, str(path), "file not found")
    try:
        if p.suffix.lower() == ".npy":
            arr = np.load(p, allow_pickle=False)
        else:
            from PIL import Image

            with Image.open(p) as img:
                arr = np.array(img)
    except Exception as err:
        raise ConfigError(key, str(path), f"unreadable PSF file ({type(err).__name__}: {err})") from None
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim == 3 and arr.shape[-1] in (3, 4) and arr.shape[0] not in (1, 3):
        arr = np.moveaxis(arr[..., :3], -1, 0)  # (H, W, RGB[A]) image -> (3, H, W)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[0] not in (1, 3) or min(arr.shape[1:]) < 2:
        raise ConfigError(key, str(path), f"PSF shape {arr.shape} must be (H, W), (H, W, 3) or (C, H, W) with C in 1, 3")
    if not np.isfinite(arr).all():
        raise ConfigError(key, str(path), "PSF has NaN or infinite values")
    if not (arr != 0).any():
        raise ConfigError(key, str(path), "PSF is all zero")
    return arr


def subtract_background(psf: np.ndarray, background: float | None) -> np.ndarray:
    """Subtract a background level and clip at zero.

    Args:
        psf: ``(C, H, W)`` raw counts.
        background: a level in counts, or ``None`` for the mean of the four
            dark corner patches (each 1/16 of the height and width).
    """
    if background is None:
        C, H, W = psf.shape
        ph, pw = max(1, H // 16), max(1, W // 16)
        corners = [psf[:, :ph, :pw], psf[:, :ph, -pw:], psf[:, -ph:, :pw], psf[:, -ph:, -pw:]]
        level = np.stack([c.mean(axis=(1, 2)) for c in corners]).mean(axis=0)[:, None, None]
    else:
        level = float(background)
    return np.clip(psf - level, 0.0, None)


def resample_area(psf: np.ndarray, grid: tuple[int, int], key: str = "encoder.psf_path") -> torch.Tensor:
    """Area-average a ``(C, h, w)`` PSF spanning the sensor onto the ``(H, W)`` grid.

    The PSF is taken to cover the whole sensor; its aspect ratio must match
    the grid's within 2 %.
    """
    C, h, w = psf.shape
    H, W = grid
    if abs((h / w) / (H / W) - 1) > 0.02:
        raise ConfigError(key, f"{h}x{w} PSF", f"aspect ratio must match the sensor grid {H}x{W} within 2%")
    my = area_matrix(h, H, 0.0, float(H))
    mx = area_matrix(w, W, 0.0, float(W))
    t = torch.from_numpy(psf)
    return my @ t @ mx.T


def measured_psf(path: str | Path, background, grid: tuple[int, int], key: str = "encoder.psf_path") -> torch.Tensor:
    """A measured PSF file on the ``(H, W)`` grid: read, background removed, area-resampled, float64.

    Each colour channel is scaled to sum one on its own: a measurement's
    colour balance is that of the lab's light source and sensor, not of the
    optic (a clear diffuser or lens passes every colour alike).

    Raises:
        ConfigError: the file is unusable, or all zero after background subtraction.
    """
    clean = subtract_background(read_psf(path, key=key), background)
    if not (clean > 0).any():
        raise ConfigError(key, str(path), "PSF is all zero after background subtraction")
    return normalize_channels(resample_area(clean, grid, key=key), name=f"{key} {path}")
