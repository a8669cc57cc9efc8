"""A mask made of cells on a lattice, propagated axis by axis: the field as two small matrix products.

A mask whose cells sit on a rectangular lattice (an LCD's sub-pixels, a
coded aperture's squares), rasterised with exact areas, factors by axis:
``mask = A_y @ V @ A_x^T`` (:func:`~optoenc.optics.elements.cell_factors`).
The point source and the band-limited angular spectrum do not factor, but
on a grid like an LCD encoder's they nearly do:

* source: ``exp(i k rho^2 / (r + d1))`` ~ ``s(y) s(x)`` with
  ``s(t) = exp(i k t^2 / (sqrt(t^2 + d1^2) + d1))``: exact on both axes;
  the dropped cross term is ``-k x^2 y^2 / (4 d1^3)`` to leading order;
* transfer function: ``exp(i k d sqrt(1 - lam^2 (u^2 + v^2)))`` ~
  ``exp(i k d) h(v) h(u)`` with ``h(f) = exp(i k d (sqrt(1 - lam^2 f^2) - 1))``
  (the BLAS band limit is a box, so it factors exactly); the dropped cross
  term is ``-k d lam^4 u^2 v^2 / 4`` to leading order.

Then the sensor field is ``U = L_y V L_x^T`` with ``L_y = P_y diag(s_y) A_y``,
``P_y`` being the 1-D zero-padded angular spectrum along y as an ``(H, H)``
matrix: exactly what the 2-D FFT of :func:`~optoenc.optics.propagation.propagate`
does along that axis on the same padded grid. The constant ``exp(i k d)``
is dropped (no intensity depends on it). :func:`cross_phase` bounds the two
dropped terms (radians) on a given grid: about 3e-3 rad for the ST7735R LCD
at d1 = 0.4 m, d2 = 4 mm. An ``(H, W)`` field then costs ``H m n + H n W``
complex multiply-adds per wavelength instead of two 2-D FFTs of the padded
grid each way.
"""

from __future__ import annotations

import math

import torch

from ..errors import ConfigError

__all__ = [
    "axis_propagator", "source_factor", "axis_operator", "separable_field", "real_operators", "separable_intensity",
    "cross_phase",
]


def _frequencies(padded: int, spacing: float) -> torch.Tensor:
    return torch.fft.fftfreq(padded, d=spacing, dtype=torch.float64)


def axis_propagator(n: int, padded: int, spacing: float, wavelengths: torch.Tensor, distance: float,
                    bandlimit: bool = True) -> torch.Tensor:
    """``(C, n, n)`` complex128: the 1-D band-limited angular spectrum over ``distance`` as a matrix.

    Column ``j`` is sample ``j`` zero-padded after the last sample to
    ``padded``, transformed, multiplied by ``h(f) = exp(i k d (sqrt(1 - lam^2 f^2) - 1))``
    (zero where the BLAS band limit ``|f| <= 1 / (lam sqrt((2 d / (padded spacing))^2 + 1))``
    cuts it, when ``bandlimit``), transformed back and cropped to ``n``.

    Raises:
        ConfigError: ``padded < n``, or a frequency of the grid is evanescent at some wavelength
            (``lam / (2 spacing) >= 1``: the 1-D factors would not be the 2-D transfer function's).
    """
    if padded < n:
        raise ConfigError("padded", padded, f"must be at least the axis' {n} samples")
    wl = wavelengths.to(torch.float64).reshape(-1, 1)
    f = _frequencies(padded, spacing)[None, :]
    s = (wl * f) ** 2
    if bool((s >= 1).any()):
        raise ConfigError("spacing", spacing, f"must exceed half the longest wavelength ({float(wl.max()) / 2:.3g} m) "
                          "for separable propagation (evanescent frequencies)")
    k = 2 * math.pi / wl
    # sqrt(1 - s) - 1 = -s / (1 + sqrt(1 - s)): no cancellation for the small s of a coarse grid
    h = torch.polar(torch.ones_like(s), -k * distance * s / (1 + torch.sqrt(1 - s)))
    if bandlimit:
        limit = 1 / (wl * math.sqrt((2 * distance / (padded * spacing)) ** 2 + 1))
        h = h * (f.abs() <= limit)
    eye = torch.zeros(padded, n, dtype=torch.complex128)
    eye[:n] = torch.eye(n, dtype=torch.complex128)
    spectrum = torch.fft.fft(eye, dim=0)  # (padded, n)
    return torch.fft.ifft(h[:, :, None] * spectrum[None], dim=1)[:, :n, :]


def source_factor(n: int, spacing: float, wavelengths: torch.Tensor, d1: float) -> torch.Tensor:
    """``(C, n)`` complex128: ``exp(i k t^2 / (sqrt(t^2 + d1^2) + d1))``, ``t = (i - n // 2) spacing``; ones for ``d1 = inf``."""
    wl = wavelengths.to(torch.float64).reshape(-1, 1)
    t = (torch.arange(n, dtype=torch.float64) - n // 2)[None, :] * spacing
    if math.isinf(d1):
        return torch.ones(wl.shape[0], n, dtype=torch.complex128)
    phase = (2 * math.pi / wl) * t * t / (torch.sqrt(t * t + d1 * d1) + d1)
    return torch.polar(torch.ones_like(phase), phase)


def axis_operator(a: torch.Tensor, padded: int, spacing: float, wavelengths: torch.Tensor, d1: float, d2: float,
                  bandlimit: bool = True) -> torch.Tensor:
    """``(C, n, m)`` complex128 ``L = P diag(s) A`` of one axis, for the ``(n, m)`` rasterisation factor ``a``."""
    n = a.shape[0]
    p = axis_propagator(n, padded, spacing, wavelengths, d2, bandlimit)
    s = source_factor(n, spacing, wavelengths, d1)
    return p @ (s[:, :, None] * a.to(torch.complex128)[None])


def separable_field(ly: torch.Tensor, values: torch.Tensor, lx: torch.Tensor) -> torch.Tensor:
    """``(C, H, W)`` complex field ``L_y V L_x^T`` per wavelength.

    Args:
        ly: ``(C, H, m)`` complex (:func:`axis_operator` of the rows).
        values: ``(C, m, n)`` or ``(m, n)`` cell transmittances (real or complex; may require grad).
        lx: ``(C, W, n)`` complex (:func:`axis_operator` of the columns).
    """
    v = values.to(ly.dtype)
    return (ly @ v) @ lx.transpose(-1, -2)


def real_operators(ly: torch.Tensor, lx: torch.Tensor, scale: float = 1.0, dtype=torch.float32):
    """The real forms of the axis operators that :func:`separable_intensity` multiplies.

    Returns:
        ``lr``: ``(C, 2H, m)``, ``[Re L_y; Im L_y]``; ``bt``: ``(C, 2n, 2W)``,
        ``[[Re, Im], [-Im, Re]]`` of ``sqrt(scale) L_x^T``, so that
        ``[Re A, Im A] @ bt = sqrt(scale) [Re, Im] (A L_x^T)``. In ``dtype``.
    """
    r = math.sqrt(scale)
    lr = torch.cat([ly.real, ly.imag], -2)
    xr, xi = (r * lx.real).transpose(-1, -2), (r * lx.imag).transpose(-1, -2)
    bt = torch.cat([torch.cat([xr, xi], -1), torch.cat([-xi, xr], -1)], -2)
    return lr.to(dtype).contiguous(), bt.to(dtype).contiguous()


def separable_intensity(lr: torch.Tensor, values: torch.Tensor, bt: torch.Tensor) -> torch.Tensor:
    """``(C, H, W)``: ``scale |L_y V L_x^T|^2`` for real cell ``values`` ``(C, m, n)``, in real arithmetic.

    The same as ``scale * separable_field(ly, values, lx).abs() ** 2`` (to float
    rounding) with the operators of :func:`real_operators`: two real batched
    products, and a backward without complex temporaries.
    """
    c, h2, _ = lr.shape
    h, n, w = h2 // 2, bt.shape[-2] // 2, bt.shape[-1] // 2
    a = (lr @ values.to(lr.dtype)).view(c, 2, h, n).transpose(1, 2).reshape(c, h, 2 * n)  # [Re A, Im A]
    return (a @ bt).square().view(c, h, 2, w).sum(2)


def cross_phase(shape, padded, spacing, wavelengths, d1: float, d2: float) -> float:
    """The largest phase (radians) the axis-by-axis factorisation drops, on this grid; ``inf`` where it fails.

    The sum of the two dropped cross terms, exactly, at their worst corners
    (both grow with each coordinate): the transfer function's
    ``k |d2| (sqrt(1 - lam^2 (u^2 + v^2)) - sqrt(1 - lam^2 u^2) - sqrt(1 - lam^2 v^2) + 1)``
    at the highest frequency of each padded axis (about ``k d lam^4 u^2 v^2 / 4``),
    and the source's ``phi(x^2 + y^2) - phi(x^2) - phi(y^2)``,
    ``phi(t) = k t / (sqrt(t + d1^2) + d1)``, at the window's corner (about
    ``k x^2 y^2 / (4 d1^3)``). ``inf`` when the band's corner is evanescent at
    some wavelength (the 2-D transfer function decays there, the product of
    the 1-D ones does not).
    """
    (h, w), (hp, wp), (dy, dx) = shape, padded, spacing
    u = float(_frequencies(wp, dx).abs().max())
    v = float(_frequencies(hp, dy).abs().max())
    y, x = (h // 2) * dy, (w // 2) * dx
    worst = 0.0
    for lam in (float(val) for val in torch.as_tensor(wavelengths, dtype=torch.float64).reshape(-1)):
        k = 2 * math.pi / lam
        a, b = (lam * u) ** 2, (lam * v) ** 2
        if a + b >= 1:
            return math.inf
        transfer = k * abs(d2) * abs(math.sqrt(1 - a - b) - math.sqrt(1 - a) - math.sqrt(1 - b) + 1)
        source = 0.0
        if not math.isinf(d1):
            phi = lambda t: k * t / (math.sqrt(t + d1 * d1) + d1)  # noqa: E731
            source = abs(phi(x * x + y * y) - phi(x * x) - phi(y * y))
        worst = max(worst, transfer + source)
    return worst
