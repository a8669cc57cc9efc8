"""Thin optical elements: lenses, apertures, amplitude masks rasterised from cells, phase masks.

Every function returns a transmittance on the pixel grid of :func:`coordinates`
(axis at ``(H // 2, W // 2)``); multiply a field by it. Real outputs are
amplitude transmittances (the field is multiplied, so intensity goes as the
square). Apertures and cell masks are rasterised with exact fractional areas
(or supersampling for circles), so their fill factor does not depend on the
grid.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from ..errors import ConfigError
from ._common import as_real, as_spacing
from .sources import _pair, coordinates

__all__ = ["thin_lens", "circular_aperture", "rect_aperture", "cell_mask", "cell_factors", "phase_mask"]


def thin_lens(
    shape,
    spacing,
    wavelength,
    focal_length,
    paraxial: bool = True,
    dtype: torch.dtype = torch.complex64,
    device=None,
) -> torch.Tensor:
    """Phase of a thin lens of focal length ``f`` (converging for ``f > 0``).

    Paraxial: ``exp(-i k rho^2 / (2 f))``. Exact (``paraxial=False``): the
    phase that turns a plane wave into a spherical wave converging on the
    focus, ``exp(-i k (sqrt(rho^2 + f^2) - |f|) sign(f))``, computed as
    ``k rho^2 / (sqrt(rho^2 + f^2) + |f|)``.

    Args:
        shape: ``(H, W)``.
        spacing: float or ``(dy, dx)``, metres.
        wavelength: float or tensor ``S_w``, metres.
        focal_length: metres, non-zero; float or tensor ``S_f`` (may require grad).
        paraxial: quadratic phase (default) or the exact hyperbolic one.

    Returns:
        complex ``broadcast(S_w, S_f) + (H, W)``.
    """
    wl = as_real(wavelength, "wavelength", device, positive=True)
    f = as_real(focal_length, "focal_length", wl.device)
    if bool((f.detach() == 0).any()):
        raise ConfigError("focal_length", focal_length, "must be non-zero (m)")
    y, x = coordinates(shape, spacing, device=wl.device)
    rho2 = y * y + x * x
    k = (2 * math.pi / wl)[..., None, None]
    ff = f[..., None, None]
    if paraxial:
        phase = -k * rho2 / (2 * ff)
    else:
        phase = -torch.sign(ff) * k * rho2 / (torch.sqrt(rho2 + ff * ff) + ff.abs())
    return torch.polar(torch.ones_like(phase), phase).to(dtype)


def _overlap(n: int, delta: float, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """``(n, m)``: fraction of pixel ``i`` (centre ``(i - n//2) delta``) covered by ``[lo_j, hi_j]``."""
    c = (torch.arange(n, dtype=torch.float64, device=lo.device) - n // 2) * delta
    a = torch.maximum(c[:, None] - delta / 2, lo[None, :])
    b = torch.minimum(c[:, None] + delta / 2, hi[None, :])
    return (b - a).clamp_min(0) / delta


def rect_aperture(
    shape, spacing, size, offset=(0.0, 0.0), dtype: torch.dtype = torch.float32, device=None
) -> torch.Tensor:
    """A rectangular opening of ``size = (height, width)`` metres centred at ``offset``.

    Returns:
        real ``(H, W)``: the exact fraction of each pixel that is open.
    """
    dy, dx = as_spacing(spacing)
    h, w = _pair(size, "size")
    y0, x0 = _pair(offset, "offset")
    if h < 0 or w < 0:
        raise ConfigError("size", size, "must be >= 0 m")
    t = lambda v: torch.tensor([v], dtype=torch.float64, device=device)  # noqa: E731
    ay = _overlap(int(shape[0]), dy, t(y0 - h / 2), t(y0 + h / 2))
    ax = _overlap(int(shape[1]), dx, t(x0 - w / 2), t(x0 + w / 2))
    return (ay @ ax.T).to(dtype)


def circular_aperture(
    shape, spacing, radius: float, offset=(0.0, 0.0), oversample: int = 8, dtype: torch.dtype = torch.float32, device=None
) -> torch.Tensor:
    """A circular opening of ``radius`` metres centred at ``offset``.

    Args:
        oversample: each pixel is sampled on an ``oversample x oversample``
            sub-grid and the open fraction is stored (1: binary at pixel centres).

    Returns:
        real ``(H, W)`` in ``[0, 1]``.
    """
    if not (math.isfinite(radius) and radius >= 0):
        raise ConfigError("radius", radius, "must be >= 0 m")
    if not (isinstance(oversample, int) and oversample >= 1):
        raise ConfigError("oversample", oversample, "must be an int >= 1")
    dy, dx = as_spacing(spacing)
    y0, x0 = _pair(offset, "offset")
    y, x = coordinates(shape, spacing, device=device)
    sub = (torch.arange(oversample, dtype=torch.float64, device=device) + 0.5) / oversample - 0.5
    H, W = y.shape[0], x.shape[1]
    ys = (y - y0).reshape(H, 1, 1, 1) + sub.reshape(1, -1, 1, 1) * dy  # (H, s, 1, 1)
    xs = (x - x0).reshape(1, 1, W, 1) + sub.reshape(1, 1, 1, -1) * dx  # (1, 1, W, s)
    inside = (ys * ys + xs * xs) <= radius * radius  # (H, s, W, s)
    return inside.to(torch.float64).mean(dim=(1, 3)).to(dtype)


def cell_mask(
    values: torch.Tensor,
    cell_size,
    shape,
    spacing,
    fill_factor=(1.0, 1.0),
    offset=(0.0, 0.0),
) -> torch.Tensor:
    """Rasterise a grid of mask cells (e.g. LCD sub-pixels) onto the simulation grid.

    Cell ``(a, b)`` of an ``(m, n)`` array is centred at
    ``((a - (m-1)/2) h_c + y0, (b - (n-1)/2) w_c + x0)``; its open part is
    ``fill_factor * cell_size`` wide (the rest is opaque dead space). Pixel
    values are the exact area-weighted sums ``A_y @ values @ A_x^T``, so the
    result is linear and differentiable in ``values``.

    Args:
        values: ``(..., m, n)`` transmittances of the cells (real or complex).
        cell_size: ``(h_c, w_c)`` cell pitch, metres.
        shape: ``(H, W)`` of the simulation grid.
        spacing: float or ``(dy, dx)``, metres.
        fill_factor: ``(f_y, f_x)`` linear fill factors in ``(0, 1]``.
        offset: ``(y0, x0)`` of the cell grid's centre, metres.

    Returns:
        ``(..., H, W)`` with ``values``' dtype.
    """
    if not isinstance(values, torch.Tensor) or values.ndim < 2:
        raise ConfigError("values", getattr(values, "shape", values), "must be a tensor of shape (..., m, n)")
    ay, ax = cell_factors(values.shape[-2:], cell_size, shape, spacing, fill_factor, offset, values.device)
    real = values.real.dtype if values.is_complex() else values.dtype
    ay, ax = ay.to(real), ax.to(real)
    if values.is_complex():
        ay, ax = ay.to(values.dtype), ax.to(values.dtype)
    return ay @ values @ ax.T


def cell_factors(cells, cell_size, shape, spacing, fill_factor=(1.0, 1.0), offset=(0.0, 0.0), device=None):
    """The per-axis factors of :func:`cell_mask`: ``(A_y, A_x)``, float64 ``(H, m)`` and ``(W, n)``.

    ``A_y[i, a]`` is the fraction of grid row ``i`` covered by the open part
    of cell row ``a`` (the same along x), so a mask of ``(m, n)`` cells is
    ``A_y @ values @ A_x^T``. Arguments as :func:`cell_mask`, ``cells = (m, n)``.
    """
    dy, dx = as_spacing(spacing)
    hc, wc = as_spacing(cell_size)
    fy, fx = _pair(fill_factor, "fill_factor")
    if not (0 < fy <= 1 and 0 < fx <= 1):
        raise ConfigError("fill_factor", fill_factor, "must be in (0, 1] on both axes")
    y0, x0 = _pair(offset, "offset")
    m, n = (int(c) for c in cells)
    cy = (torch.arange(m, dtype=torch.float64, device=device) - (m - 1) / 2) * hc + y0
    cx = (torch.arange(n, dtype=torch.float64, device=device) - (n - 1) / 2) * wc + x0
    ay = _overlap(int(shape[0]), dy, cy - fy * hc / 2, cy + fy * hc / 2)
    ax = _overlap(int(shape[1]), dx, cx - fx * wc / 2, cx + fx * wc / 2)
    return ay, ax


def phase_mask(
    height: torch.Tensor,
    wavelength,
    refractive_index: float | Callable[[torch.Tensor], torch.Tensor],
    medium_index: float = 1.0,
    dtype: torch.dtype | None = None,
) -> torch.Tensor:
    """Transmittance ``exp(i k (n(lambda) - n_0) h)`` of a thin phase plate of height map ``h``.

    Args:
        height: ``(..., H, W)`` surface height, metres (may require grad).
        wavelength: float or tensor ``S_w``, metres; ``S_w`` must broadcast
            against ``height.shape[:-2]`` (e.g. ``(C,)`` for ``(C, H, W)`` or
            an ``(H, W)`` height shared by all wavelengths).
        refractive_index: a constant, or a callable mapping a float64 tensor of
            wavelengths (metres) to indices (dispersion).
        medium_index: index ``n_0`` of the surrounding medium.
        dtype: complex output dtype (default: complex64 for float32 heights,
            complex128 for float64).

    Returns:
        complex ``broadcast(S_w, ...) + (H, W)``.
    """
    if not isinstance(height, torch.Tensor) or height.ndim < 2:
        raise ConfigError("height", getattr(height, "shape", height), "must be a tensor of shape (..., H, W)")
    wl = as_real(wavelength, "wavelength", height.device, positive=True)
    n = refractive_index(wl) if callable(refractive_index) else refractive_index
    n = torch.as_tensor(n, dtype=torch.float64, device=height.device)
    k = 2 * math.pi / wl
    phase = ((k * (n - medium_index))[..., None, None]) * height.to(torch.float64)
    if dtype is None:
        dtype = torch.complex128 if height.dtype == torch.float64 else torch.complex64
    return torch.polar(torch.ones_like(phase), phase).to(dtype)
