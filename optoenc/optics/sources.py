"""Input fields: pixel coordinates, plane waves, point sources (spherical waves), Gaussian beams.

Coordinates are pixel centres with the optical axis at index ``(H // 2, W // 2)``
(the PSF convention of :mod:`optoenc.encoders.imaging`): ``y_i = (i - H // 2) dy``,
``x_j = (j - W // 2) dx``. Phases are computed in float64 and the field is cast
once to the requested complex dtype.
"""

from __future__ import annotations

import math

import torch

from ..errors import ConfigError
from ._common import as_real, as_spacing

__all__ = ["coordinates", "plane_wave", "point_source", "gaussian_beam", "source_phase_step"]

_AMPLITUDES = ("unit", "spherical")


def coordinates(shape, spacing, dtype: torch.dtype = torch.float64, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel-centre coordinates with the axis at ``(H // 2, W // 2)``.

    Args:
        shape: ``(H, W)``.
        spacing: float or ``(dy, dx)``, metres.

    Returns:
        ``(y, x)`` of shapes ``(H, 1)`` and ``(1, W)``, metres.
    """
    H, W = (int(n) for n in shape)
    dy, dx = as_spacing(spacing)
    y = (torch.arange(H, dtype=dtype, device=device) - H // 2) * dy
    x = (torch.arange(W, dtype=dtype, device=device) - W // 2) * dx
    return y[:, None], x[None, :]


def _pair(value, name: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(name, value, "must be a (y, x) pair of floats") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ConfigError(name, value, "must be finite")
    return a, b


def plane_wave(
    shape, spacing, wavelength, angle=(0.0, 0.0), dtype: torch.dtype = torch.complex64, device=None
) -> torch.Tensor:
    """A unit-amplitude plane wave ``exp(i k (y sin(theta_y) + x sin(theta_x)))``.

    Args:
        shape: ``(H, W)``.
        spacing: float or ``(dy, dx)``, metres.
        wavelength: float or tensor ``S_w``, metres.
        angle: ``(theta_y, theta_x)`` propagation angles to the axis, radians.

    Returns:
        complex ``S_w + (H, W)``.
    """
    ty, tx = _pair(angle, "angle")
    wl = as_real(wavelength, "wavelength", device, positive=True)
    y, x = coordinates(shape, spacing, device=wl.device)
    k = (2 * math.pi / wl)[..., None, None]
    phase = k * (y * math.sin(ty) + x * math.sin(tx))
    return torch.polar(torch.ones_like(phase), phase).to(dtype)


def point_source(
    shape,
    spacing,
    wavelength,
    distance,
    offset=(0.0, 0.0),
    amplitude: str = "unit",
    dtype: torch.dtype = torch.complex64,
    device=None,
) -> torch.Tensor:
    """The field of a point source at ``distance`` in front of the plane (a diverging spherical wave).

    ``U = A exp(i k (r - d))`` with ``r = sqrt(rho^2 + d^2)`` and ``rho`` the
    distance to the source's foot ``offset``. The phase is computed in the
    cancellation-free form ``k rho^2 / (r + d)``: the constant ``k d`` is
    dropped (it does not change any intensity), and the float32 loss of the
    naive ``k r`` (~0.5 rad at ``d = 0.4 m``) never happens.

    Args:
        shape: ``(H, W)``.
        spacing: float or ``(dy, dx)``, metres.
        wavelength: float or tensor ``S_w``, metres.
        distance: ``d > 0``, metres; float or tensor ``S_d`` (may require
            grad); ``inf`` gives a unit plane wave along the axis.
        offset: ``(y0, x0)`` lateral position of the source, metres (must be
            zero for ``d = inf``).
        amplitude: ``"unit"`` (``A = 1``: only the phase of the spherical wave)
            or ``"spherical"`` (``A = d / r``: the ``1/r`` fall-off, equal to 1
            on the source's foot).

    Returns:
        complex ``broadcast(S_w, S_d) + (H, W)``.
    """
    if amplitude not in _AMPLITUDES:
        raise ConfigError("amplitude", amplitude, f"must be one of {_AMPLITUDES}")
    y0, x0 = _pair(offset, "offset")
    wl = as_real(wavelength, "wavelength", device, positive=True)
    d = as_real(distance, "distance", wl.device, positive=True, allow_inf=True)
    inf = torch.isinf(d.detach())
    if bool(inf.any()) and (y0, x0) != (0.0, 0.0):
        raise ConfigError("offset", offset, "must be (0, 0) for a source at infinity (use plane_wave(angle=...))")
    y, x = coordinates(shape, spacing, device=wl.device)
    rho2 = (y - y0) ** 2 + (x - x0) ** 2
    dd = torch.where(inf, torch.ones_like(d), d)[..., None, None]
    r = torch.sqrt(rho2 + dd * dd)
    k = (2 * math.pi / wl)[..., None, None]
    finite = ~inf[..., None, None]
    phase = torch.where(finite, k * rho2 / (r + dd), torch.zeros_like(k * dd))
    amp = torch.where(finite, dd / r, torch.ones_like(r)) if amplitude == "spherical" else torch.ones_like(phase)
    return torch.polar(amp.expand_as(phase), phase).to(dtype)


def gaussian_beam(shape, spacing, waist: float, offset=(0.0, 0.0), dtype: torch.dtype = torch.complex64, device=None):
    """A Gaussian beam at its waist: ``exp(-rho^2 / w0^2)`` (flat phase, peak amplitude 1).

    Args:
        shape: ``(H, W)``.
        spacing: float or ``(dy, dx)``, metres.
        waist: ``1/e^2`` intensity radius ``w0``, metres.
        offset: ``(y0, x0)`` centre, metres.

    Returns:
        complex ``(H, W)``.
    """
    if not (isinstance(waist, (int, float)) and math.isfinite(waist) and waist > 0):
        raise ConfigError("waist", waist, "must be > 0 m")
    y0, x0 = _pair(offset, "offset")
    y, x = coordinates(shape, spacing, device=device)
    return torch.exp(-((y - y0) ** 2 + (x - x0) ** 2) / waist**2).to(dtype)


def source_phase_step(shape, spacing, wavelength, distance, offset=(0.0, 0.0)) -> float:
    """Largest phase change (rad) between neighbouring pixels of :func:`point_source`.

    ``max over axes of k * spacing * |coordinate - offset|_max / r`` (the phase
    gradient at the window's edge times the pitch). Above ``pi`` the spherical
    wave is aliased on the grid; 0 for a source at infinity.
    """
    H, W = (int(n) for n in shape)
    dy, dx = as_spacing(spacing)
    lam = float(as_real(wavelength, "wavelength", positive=True).detach().min())
    d = float(as_real(distance, "distance", positive=True, allow_inf=True).detach().min())
    if math.isinf(d):
        return 0.0
    y0, x0 = _pair(offset, "offset")
    ey = max(abs(-(H // 2) * dy - y0), abs((H - 1 - H // 2) * dy - y0))
    ex = max(abs(-(W // 2) * dx - x0), abs((W - 1 - W // 2) * dx - x0))
    k = 2 * math.pi / lam
    return max(k * dy * ey / math.hypot(ey, d), k * dx * ex / math.hypot(ex, d))
