"""`pinhole`: a pinhole camera, the simplest optical encoder (an example plugin).

A circular hole of diameter ``D`` sits ``d2`` in front of the sensor and
``d1`` behind the scene. A scene point casts two blurs on the sensor:

* geometric: the hole's shadow, a uniform disk of diameter
  ``D (d1 + d2) / d1``;
* diffraction: the Airy pattern of the hole, ``x = pi D r / (lambda d2)``,
  here approximated by its best-fitting Gaussian, standard deviation
  ``sigma = 0.42 lambda d2 / D``.

The PSF is the disk convolved with the Gaussian (Rayleigh's classic model of
the pinhole; the two blurs balance at ``D = sqrt(2.44 lambda d2)``, about
73 um for 550 nm and 4 mm). It is computed per wavelength (R, G, B at
:data:`optoenc.devices.WAVELENGTHS_RGB`), supersampled on a small window
around the axis, integrated over each grid pixel and placed with the axis at
``(H // 2, W // 2)``. The image magnification ``d2 / d1`` and inversion are
applied by :class:`optoenc.OpticalEncoder`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from optoenc import EncoderConfig, OpticalEncoder, setting

__all__ = ["Pinhole", "PinholeConfig", "pinhole_psf", "GAUSS_AIRY"]

#: Gaussian fit to the Airy core: sigma = GAUSS_AIRY * lambda * N, N = d2 / D.
GAUSS_AIRY = 0.42
#: Largest supersampled window per axis (caps cost on very coarse grids).
_MAX_FINE = 1024


def _box_gauss(n: int, s: int, pitch: float, sigma: float, dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Fine sample positions of ``n`` grid pixels x ``s`` sub-samples, and the (n, n*s) blur-then-sum matrix."""
    k = n // 2
    pos = ((torch.arange(n * s, dtype=dtype) + 0.5) / s - k - 0.5) * pitch  # pixel k is centred on 0
    box = torch.zeros(n, n * s, dtype=dtype)
    box[torch.arange(n * s) // s, torch.arange(n * s)] = 1.0
    if sigma > 0:
        g = torch.exp(-0.5 * ((pos[:, None] - pos[None, :]) / sigma) ** 2)
        box = box @ g
    return pos, box


def pinhole_psf(
    diameter: float,
    d1: float,
    d2: float,
    wavelength: float,
    spacing: tuple[float, float],
    grid: tuple[int, int],
    diffraction: bool = True,
    dtype: torch.dtype = torch.float64,
) -> torch.Tensor:
    """Pixel-integrated intensity PSF of a pinhole, un-normalised.

    Args:
        diameter: pinhole diameter ``D``, metres.
        d1: scene-to-pinhole distance, metres.
        d2: pinhole-to-sensor distance, metres.
        wavelength: metres.
        spacing: ``(dy, dx)`` grid pixel pitch, metres.
        grid: ``(H, W)`` grid shape.
        diffraction: include the diffraction blur.

    Returns:
        ``(H, W)`` non-negative tensor, axis at ``(H // 2, W // 2)``.
    """
    radius = 0.5 * diameter * (d1 + d2) / d1
    sigma = GAUSS_AIRY * wavelength * d2 / diameter if diffraction else 0.0
    H, W = grid
    feature = min(radius, sigma) if sigma > 0 else radius
    out = torch.zeros(H, W, dtype=dtype)
    rows = []
    for n_grid, pitch, centre in ((H, spacing[0], H // 2), (W, spacing[1], W // 2)):
        half = min(math.ceil((radius + 4 * sigma) / pitch + 0.5), max(centre, n_grid - 1 - centre))
        n = 2 * half + 1
        s = max(1, min(math.ceil(4 * pitch / feature), _MAX_FINE // n))
        pos, blur = _box_gauss(n, s, pitch, sigma, dtype)
        rows.append((half, pos, blur, pitch / s))
    (hy, y, by, py), (hx, x, bx, px) = rows
    r = torch.sqrt(y[:, None] ** 2 + x[None, :] ** 2)
    disk = ((radius - r) / min(py, px) + 0.5).clamp(0, 1)  # one-sub-sample anti-aliased edge
    window = by @ disk @ bx.T
    cy, cx = H // 2, W // 2
    # the window may stick out of the grid on one side: crop to the grid
    y0, x0 = cy - hy, cx - hx
    wy0, wx0 = max(0, -y0), max(0, -x0)
    wy1, wx1 = min(window.shape[0], H - y0), min(window.shape[1], W - x0)
    out[y0 + wy0 : y0 + wy1, x0 + wx0 : x0 + wx1] = window[wy0:wy1, wx0:wx1]
    return out


@dataclass
class PinholeConfig(EncoderConfig):
    d2: float = setting(4e-3, "pinhole-to-sensor distance d2 (sets the magnification d2 / d1)", unit="m", gt=0)
    diameter: float = setting(
        75e-6, "pinhole diameter D (sharpest near sqrt(2.44 lambda d2), ~73 um at 550 nm and d2 = 4 mm)", unit="m", gt=0
    )
    diffraction: bool = setting(True, "add the diffraction blur (Gaussian fit to the Airy core, sigma = 0.42 lambda d2 / D)")


class Pinhole(OpticalEncoder):
    """Pinhole camera: a small circular hole at d2, geometric shadow blurred by diffraction."""

    name = "pinhole"
    Config = PinholeConfig
    learnable = False
    linear = True

    def compute_psf(self) -> torch.Tensor:
        from optoenc.devices import WAVELENGTHS_RGB

        c = self.config
        planes = [
            pinhole_psf(
                c.diameter, self.scene_config.distance, c.d2, wl, self.geometry.spacing, self.geometry.grid, c.diffraction
            )
            for wl in WAVELENGTHS_RGB
        ]
        return torch.stack(planes).to(self.optics_dtype)
