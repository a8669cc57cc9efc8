"""`lens`: a thin lens imaging the scene onto the sensor (the paper's lensed baseline).

Model: a thin lens of focal length ``f = 1 / (1 / focus + 1 / d2)`` (7.39 mm
for a lens focused at 40 cm with the sensor 7.53 mm behind it, REFERENCE §2)
and a circular aperture of diameter ``D = f / N``. The lens is focused once,
at ``focus_distance`` (default 0.40 m, the paper's setting); a scene at
another distance is out of focus (see :attr:`Lens.blur_diameter`). A point at the scene
distance ``d1`` images to ``v = 1 / (1 / f - 1 / d1)``; the sensor sits at
``d2``. The intensity PSF at wavelength ``lambda`` is

* in focus (``v = d2``): the Airy pattern ``(2 J1(x) / x)^2`` with
  ``x = pi D r / (lambda d2)`` (first zero at ``1.22 lambda d2 / D``);
* defocused: the geometric blur disk of diameter ``b = D |d2 - v| / v``
  convolved with that Airy pattern (a geometric-optics approximation).

The Airy disk (~1 um at F1.2) is far smaller than a grid pixel (~12 um), so
the PSF is never simulated at full sensor resolution: the analytic pattern is
supersampled on a small window around the axis (sub-samples of a quarter of
``lambda N``; the window spans the blur disk plus 60 ``lambda N``) and
integrated over each grid pixel, then placed at ``(H // 2, W // 2)``. The
Airy rings beyond the window (~0.3 % of the energy, spread over the whole
sensor) are kept with their ring-averaged asymptote
``<(2 J1(x) / x)^2> = 4 / (pi x^3)``, i.e. a fraction
``lambda N / (pi^3 r^3)`` of the power per unit area at radius ``r``
(:func:`airy_tail`); the window keeps the rest of the power.

Alternatively ``psf_path`` loads a measured lens PSF spanning the sensor
(PNG, TIFF or NPY, axis at its centre), area-resampled onto the grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from scipy.special import j1

from .. import devices
from ..errors import ConfigError, PhysicsError
from ..settings import setting
from . import psf_files
from .base import EncoderConfig, OpticalEncoder

__all__ = ["LensConfig", "Lens", "airy_pixel_psf", "airy_tail"]

#: Largest supersampled window (per axis) used for the analytic PSF.
_MAX_FINE = 1024
#: Window radius in units of lambda * N: the Airy energy beyond it is ~2 / (pi^2 * 60 / 1.22 ...) < 0.5 %.
_TAIL = 60.0


def airy_pixel_psf(
    wavelength: float, working_f_number: float, spacing: tuple[float, float], blur_diameter: float = 0.0
) -> np.ndarray:
    """Pixel-integrated PSF of an aberration-free circular pupil, on a small centred window.

    Args:
        wavelength: metres.
        working_f_number: ``d2 / D`` (image distance over pupil diameter).
        spacing: ``(dy, dx)`` grid pixel pitch, metres.
        blur_diameter: diameter of the geometric defocus disk at the sensor, metres.

    Returns:
        ``(2R + 1, 2R + 1)`` float64 array summing to one, centred on pixel ``(R, R)``.
    """
    lam_n = wavelength * working_f_number
    pix = min(spacing)
    radius = blur_diameter / 2 + _TAIL * lam_n
    R = int(math.ceil(radius / pix)) + 1
    s = max(1, int(math.ceil(pix / (lam_n / 4))))
    s = max(1, min(s, _MAX_FINE // (2 * R + 1)))
    n = 2 * R + 1
    sub = (np.arange(s) + 0.5) / s - 0.5
    ys = ((np.arange(n) - R)[:, None] + sub[None, :]).reshape(-1) * spacing[0]
    xs = ((np.arange(n) - R)[:, None] + sub[None, :]).reshape(-1) * spacing[1]
    rho = np.hypot(ys[:, None], xs[None, :])
    x = np.pi * rho / lam_n
    with np.errstate(invalid="ignore", divide="ignore"):
        airy = np.where(x > 1e-8, (2 * j1(x) / np.where(x > 1e-8, x, 1.0)) ** 2, 1.0)
    fine_step = min(spacing) / s
    if blur_diameter > fine_step:
        disk = np.clip((blur_diameter / 2 - rho) / fine_step + 0.5, 0.0, 1.0)
        from scipy.signal import fftconvolve  # lazy: scipy.signal takes ~1 s to import

        airy = np.clip(fftconvolve(airy, disk / disk.sum(), mode="same"), 0.0, None)
    out = airy.reshape(n, s, n, s).sum(axis=(1, 3))
    return out / out.sum()


def airy_tail(rho: np.ndarray, lam_n: float) -> np.ndarray:
    """Ring-averaged Airy intensity far from the axis: power per unit area over total power, at radius ``rho``.

    From ``(2 J1(x) / x)^2 -> 4 / (pi x^3)`` on average over a ring
    (``x = pi rho / (lambda N)``) and a total power of
    ``4 (lambda N)^2 / pi`` times the peak: ``lambda N / (pi^3 rho^3)``.
    Accurate to ``O(1 / x)`` (0.5 % at the window's edge, ``x ~ 190``).
    """
    return lam_n / (math.pi**3 * np.maximum(rho, 1e-12) ** 3)


def _with_tail(win: np.ndarray, grid: tuple[int, int], spacing: tuple[float, float], lam_n: float) -> np.ndarray:
    """``(H, W)``: the window ``win`` (sums to one) at the grid's centre, scaled to the power inside it, plus the
    Airy tail (:func:`airy_tail`, at the pixel centres) everywhere else on the grid."""
    H, W = grid
    R = win.shape[0] // 2
    y = (np.arange(H) - H // 2)[:, None] * spacing[0]
    x = (np.arange(W) - W // 2)[None, :] * spacing[1]
    tail = airy_tail(np.hypot(y, x), lam_n) * spacing[0] * spacing[1]
    inside = (np.abs(np.arange(H) - H // 2)[:, None] <= R) & (np.abs(np.arange(W) - W // 2)[None, :] <= R)
    tail[inside] = 0.0
    # power outside the window: on the grid, plus beyond it (a disk of the grid's mean half-size, analytic)
    beyond = 2 * lam_n / (math.pi**2 * (0.25 * (H * spacing[0] + W * spacing[1])))
    ry, rx = min(R, H // 2, H - 1 - H // 2), min(R, W // 2, W - 1 - W // 2)
    rows, cols = slice(H // 2 - ry, H // 2 + ry + 1), slice(W // 2 - rx, W // 2 + rx + 1)
    tail[rows, cols] += win[R - ry : R + ry + 1, R - rx : R + rx + 1] * max(0.0, 1.0 - tail.sum() - beyond)
    return tail


@dataclass
class LensConfig(EncoderConfig):
    d2: float = setting(devices.LENS_D2, "lens-to-sensor distance d2", unit="m", gt=0)
    focus_distance: float = setting(
        devices.LENS_FOCUS, "object distance the lens is focused at, once (sets f = 1 / (1 / focus + 1 / d2)); "
        "a scene at another distance d1 is defocused", unit="m", gt=0
    )
    f_number: float = setting(devices.LENS_F_NUMBER, "f-number N = f / D of the circular aperture", gt=0)
    psf_path: Optional[str] = setting(
        None, "measured lens PSF (PNG, TIFF or NPY) spanning the sensor; null: the diffraction-limited thin lens"
    )
    background: Optional[float] = setting(
        None, "background subtracted from a measured PSF, in file counts; null: mean of the dark corners", ge=0
    )


class Lens(OpticalEncoder):
    """Thin lens (6 mm wide-angle class) focused at 40 cm, 7.53 mm from the sensor; diffraction-limited PSF."""

    name = "lens"
    Config = LensConfig
    learnable = False
    linear = True

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        path = self.config.psf_path
        if path is not None and not Path(path).is_file():
            raise ConfigError("encoder.psf_path", path, "file not found")

    @property
    def focus_distance(self) -> float:
        """Object distance in focus, metres (fixed: the lens does not refocus on the scene)."""
        return float(self.config.focus_distance)

    @property
    def focal_length(self) -> float:
        """Thin-lens focal length focusing ``focus_distance`` onto ``d2``, metres."""
        return 1.0 / (1.0 / self.focus_distance + 1.0 / self.d2)

    @property
    def aperture_diameter(self) -> float:
        """Pupil diameter ``D = f / N``, metres."""
        return self.focal_length / self.config.f_number

    @property
    def image_distance(self) -> float:
        """Thin-lens image distance ``v = 1 / (1 / f - 1 / d1)`` of a point at the scene distance, metres."""
        f, d1 = self.focal_length, self.scene_config.distance
        if d1 <= f:
            raise PhysicsError(f"lens: the scene distance {d1} m is inside the focal length {f:.4g} m; no real image")
        return 1.0 / (1.0 / f - 1.0 / d1)

    @property
    def blur_diameter(self) -> float:
        """Diameter ``D |d2 - v| / v`` of the geometric defocus disk at the sensor for a point at ``d1``, metres."""
        v = self.image_distance
        return self.aperture_diameter * abs(self.d2 - v) / v

    def compute_psf(self) -> torch.Tensor:
        H, W = self.geometry.grid
        if self.config.psf_path is not None:
            psf = psf_files.measured_psf(self.config.psf_path, self.config.background, (H, W))
            return psf.to(self.optics_dtype)
        n_w = self.d2 / self.aperture_diameter
        blur = self.blur_diameter
        out = torch.zeros(3, H, W, dtype=torch.float64)
        for c, lam in enumerate(devices.WAVELENGTHS_RGB):
            win = airy_pixel_psf(lam, n_w, self.geometry.spacing, blur)
            out[c] = torch.from_numpy(_with_tail(win, (H, W), self.geometry.spacing, lam * n_w))
        return out.to(self.optics_dtype)

    def cache_token(self) -> str:
        """What, beyond the config, determines this encoder's PSF: a measured file's contents, if any."""
        return psf_files.file_digest(self.config.psf_path) if self.config.psf_path else ""
