"""Free-space propagation of scalar fields: band-limited angular spectrum, plain ASM, Fresnel.

Conventions (see ``docs/optics.md``):
    * Fields are complex ``(..., H, W)`` tensors, rows (``y``) first; SI units.
    * Time dependence ``exp(-i omega t)``: a wave travelling towards ``+z`` is
      ``exp(+i k z)``, and propagating by ``d`` multiplies the angular spectrum
      by ``exp(+i 2 pi d / lambda * sqrt(1 - (lambda u)^2 - (lambda v)^2))``.
    * Transfer functions live on the *unshifted* FFT frequency grid
      (``torch.fft.fftfreq``), are built in float64 and cast once to the
      field's dtype. They are radially symmetric, so a centred impulse stays
      centred for odd and even sizes alike.
    * Zero padding is added after the field (``fft2(field, s=padded)``) and
      cropped off again; only the total amount matters for wrap-around.
    * Evanescent components (``(lambda u)^2 + (lambda v)^2 > 1``) decay as
      ``exp(-2 pi |d| sqrt((lambda u)^2 + (lambda v)^2 - 1) / lambda)`` for
      either sign of ``d``: they are never amplified.
"""

from __future__ import annotations

import math

import torch

from ..errors import ConfigError
from ._common import (  # noqa: F401  (cache_info, clear_cache, next_fast_size re-exported)
    CACHE,
    as_real,
    as_spacing,
    cache_info,
    check_broadcast,
    clear_cache,
    next_fast_size,
    safe_sqrt,
    tensor_key,
)

__all__ = [
    "METHODS",
    "next_fast_size",
    "padded_shape",
    "compute_transfer_function",
    "apply_transfer_function",
    "propagate",
    "cache_info",
    "clear_cache",
]

#: Propagation methods understood by :func:`propagate`.
METHODS = ("blas", "asm", "fresnel")
#: Extra pixels added by ``padding="auto"`` on top of the geometric spread.
AUTO_MARGIN = 8


# ----------------------------------------------------------------------------- geometry


def lateral_spread(spacing: float, wavelength: float, distance: float, method: str = "blas") -> float:
    """How far (m) the highest frequency the grid carries (``1 / 2 spacing``) travels sideways over ``distance``.

    ``|d| tan(theta)`` with ``sin(theta) = lambda / (2 spacing)`` for the angular
    spectrum (``inf`` when the grid's band reaches evanescent waves), and the
    paraxial ``|d| lambda / (2 spacing)`` for Fresnel.
    """
    s = wavelength / (2 * spacing)
    if method == "fresnel":
        return abs(distance) * s
    if s >= 1:
        return math.inf if distance != 0 else 0.0
    return abs(distance) * s / math.sqrt(1 - s * s)


def padded_shape(shape, spacing, wavelength, distance, padding="auto", method: str = "blas") -> tuple[int, int]:
    """The ``(Hp, Wp)`` grid a ``(H, W)`` field is zero-padded to before the FFT.

    Args:
        shape: ``(H, W)`` of the field.
        spacing: pixel pitch, float or ``(dy, dx)``, metres.
        wavelength: float or tensor, metres (the longest one decides).
        distance: float or tensor, metres (the largest ``|d|`` decides).
        padding: ``int`` pixels per side (``0``: none, periodic), a ``(py, px)``
            pair, or ``"auto"``: per axis, add ``ceil(spread / spacing) + 8``
            pixels in total, where ``spread`` is :func:`lateral_spread` (so
            no light that the grid can carry wraps around), capped at ``N``
            (a 2x window, whose BLAS band limit caps the spread at ``N``
            pixels), rounded up to a ``2^a 3^b 5^c`` size.

    Returns:
        ``(Hp, Wp)``.
    """
    H, W = (int(n) for n in shape)
    if isinstance(padding, str):
        if padding != "auto":
            raise ConfigError("padding", padding, "must be 'auto', an int >= 0 or a (py, px) pair of ints")
        dy, dx = as_spacing(spacing)
        lam = float(as_real(wavelength, "wavelength", positive=True).detach().max())
        dist = float(as_real(distance, "distance").detach().abs().max())
        out = []
        for n, delta in ((H, dy), (W, dx)):
            spread = lateral_spread(delta, lam, dist, method)
            extra = n if not math.isfinite(spread) else min(n, math.ceil(spread / delta) + AUTO_MARGIN)
            out.append(next_fast_size(n + extra))
        return out[0], out[1]
    try:
        pads = (padding, padding) if isinstance(padding, int) else tuple(padding)
    except TypeError:
        pads = ()
    if len(pads) != 2 or not all(isinstance(p, int) and not isinstance(p, bool) and p >= 0 for p in pads):
        raise ConfigError("padding", padding, "must be 'auto', an int >= 0 or a (py, px) pair of ints")
    return H + 2 * pads[0], W + 2 * pads[1]


# ----------------------------------------------------------------------------- transfer functions


def _rates(shape, spacing, wl: torch.Tensor, method: str):
    """Distance-independent parts: phase and decay per metre, ``wl.shape + shape`` float64."""
    (Hp, Wp), (dy, dx) = shape, spacing
    fy = torch.fft.fftfreq(Hp, d=dy, dtype=torch.float64, device=wl.device)[:, None]
    fx = torch.fft.fftfreq(Wp, d=dx, dtype=torch.float64, device=wl.device)[None, :]
    lam = wl[..., None, None]
    k = 2 * math.pi / lam
    if method == "fresnel":
        return k - math.pi * lam * (fy * fy + fx * fx), None
    s = (lam * fy) ** 2 + (lam * fx) ** 2
    phase = k * safe_sqrt(1 - s)
    decay = k * safe_sqrt(s - 1) if bool((s.detach() > 1).any()) else None
    return phase, decay


def _band(shape, spacing, wl: torch.Tensor, d: torch.Tensor, method: str) -> torch.Tensor:
    """Boolean band-limit mask (Matsushima & Shimobaba 2009; paraxial version for Fresnel)."""
    (Hp, Wp), (dy, dx) = shape, spacing
    fy = torch.fft.fftfreq(Hp, d=dy, dtype=torch.float64, device=wl.device)[:, None].abs()
    fx = torch.fft.fftfreq(Wp, d=dx, dtype=torch.float64, device=wl.device)[None, :].abs()
    lam, a = wl.detach()[..., None, None], d.detach().abs()[..., None, None]
    if method == "fresnel":  # chirp position lambda d u must stay within half the window
        ulim, vlim = Wp * dx / (2 * lam * a), Hp * dy / (2 * lam * a)  # a = 0 gives inf: no limit
    else:
        ulim = 1 / (lam * torch.sqrt((2 * a / (Wp * dx)) ** 2 + 1))
        vlim = 1 / (lam * torch.sqrt((2 * a / (Hp * dy)) ** 2 + 1))
    return (fx <= ulim) & (fy <= vlim)


def compute_transfer_function(
    shape,
    spacing,
    wavelength,
    distance,
    method: str = "blas",
    bandlimit: bool = True,
    dtype: torch.dtype = torch.complex64,
    device=None,
    cache: bool = True,
) -> torch.Tensor:
    """Free-space transfer function ``H(v, u)`` on the unshifted FFT grid of a (padded) window.

    Built in float64, then cast to ``dtype``. When neither ``wavelength`` nor
    ``distance`` requires grad and ``cache`` is true, the result comes from an
    LRU cache keyed by (shape, spacing, wavelength, distance, method,
    bandlimit, dtype, device): treat it as read-only. With a trainable
    distance only its distance-independent part is cached.

    Args:
        shape: ``(Hp, Wp)`` of the padded window (see :func:`padded_shape`).
        spacing: float or ``(dy, dx)``, metres.
        wavelength: float or tensor of shape ``S_w``, metres.
        distance: float or tensor of shape ``S_d`` (may require grad), metres,
            either sign.
        method: ``"blas"`` (band-limited angular spectrum), ``"asm"`` (angular
            spectrum, never band-limited) or ``"fresnel"`` (transfer-function
            Fresnel, ``exp(ikd) exp(-i pi lambda d (u^2 + v^2))``).
        bandlimit: apply the band limit ``|u| <= 1 / (lambda sqrt((2d/L_x)^2 + 1))``
            (``L_x = Wp dx``) to ``"blas"``, or its paraxial form
            ``|u| <= L_x / (2 lambda |d|)`` to ``"fresnel"``.
        dtype: complex output dtype.
        device: output device.
        cache: use the LRU cache when possible.

    Returns:
        ``broadcast(S_w, S_d) + (Hp, Wp)`` complex tensor.
    """
    if method not in METHODS:
        raise ConfigError("method", method, f"must be one of {METHODS}")
    if dtype not in (torch.complex64, torch.complex128):
        raise ConfigError("dtype", dtype, "must be torch.complex64 or torch.complex128")
    shape = tuple(int(n) for n in shape)
    spacing = as_spacing(spacing)
    wl = as_real(wavelength, "wavelength", device, positive=True)
    d = as_real(distance, "distance", device)
    dev = wl.device
    d = d.to(dev)
    limit = bandlimit and method != "asm"
    wl_fixed, d_fixed = not wl.requires_grad, not d.requires_grad
    key = None
    if cache and wl_fixed and d_fixed:
        key = ("H", shape, spacing, tensor_key(wl), tensor_key(d), method, limit, dtype, str(dev))
        hit = CACHE.get(key)
        if hit is not None:
            return hit
    if cache and wl_fixed:
        rkey = ("rates", shape, spacing, tensor_key(wl), method, str(dev))
        rates = CACHE.get(rkey)
        if rates is None:
            rates = _rates(shape, spacing, wl, method)
            CACHE.put(rkey, rates)
    else:
        rates = _rates(shape, spacing, wl, method)
    phase, decay = rates
    dd = d[..., None, None]
    amp = torch.exp(-decay * dd.abs()) if decay is not None else torch.ones_like(phase * dd)
    H = torch.polar(amp, phase * dd)
    if limit:
        H = H * _band(shape, spacing, wl, d, method)
    H = H.to(dtype)
    if key is not None:
        CACHE.put(key, H)
    return H


def apply_transfer_function(field: torch.Tensor, transfer: torch.Tensor) -> torch.Tensor:
    """Filter ``(..., H, W)`` fields with a transfer function on a padded ``(Hp, Wp)`` grid.

    The field is zero-padded after its last row and column to ``(Hp, Wp)``,
    transformed with ``fft2``, multiplied by ``transfer`` (broadcasting over
    the leading dimensions), transformed back and cropped to ``(H, W)``.

    Args:
        field: complex ``(..., H, W)``.
        transfer: complex ``(..., Hp, Wp)`` with ``Hp >= H``, ``Wp >= W``.

    Returns:
        complex ``broadcast(...) + (H, W)``.
    """
    H, W = field.shape[-2:]
    Hp, Wp = transfer.shape[-2:]
    if Hp < H or Wp < W:
        raise ConfigError("transfer", tuple(transfer.shape), f"grid must be at least the field's ({H}, {W})")
    out = torch.fft.ifft2(torch.fft.fft2(field, s=(Hp, Wp)) * transfer)
    return out if (Hp, Wp) == (H, W) else out[..., :H, :W]


def propagate(
    field: torch.Tensor,
    distance,
    wavelength,
    spacing,
    method: str = "blas",
    padding="auto",
    bandlimit: bool = True,
) -> torch.Tensor:
    """Propagate a scalar field over ``distance`` in free space.

    Args:
        field: complex ``(..., H, W)`` (complex64 or complex128; a real field
            is promoted to the matching complex dtype).
        distance: metres, either sign; float or tensor (may require grad)
            broadcasting against ``field.shape[:-2]``.
        wavelength: metres; float or tensor whose shape broadcasts against
            ``field.shape[:-2]`` without adding dimensions: ``(C,)`` for a
            ``(C, H, W)`` or ``(B, C, H, W)`` field. All wavelengths go through
            one batched FFT.
        spacing: pixel pitch, float or ``(dy, dx)``, metres.
        method: ``"blas"``, ``"asm"`` or ``"fresnel"`` (see
            :func:`compute_transfer_function`).
        padding: ``"auto"``, int pixels per side (``0``: periodic) or ``(py, px)``
            (see :func:`padded_shape`).
        bandlimit: apply the band limit (``"blas"``, ``"fresnel"``).

    Returns:
        The propagated field, same shape and complex dtype as ``field``.
    """
    if not isinstance(field, torch.Tensor) or field.ndim < 2:
        raise ConfigError("field", getattr(field, "shape", field), "must be a tensor of shape (..., H, W)")
    if not field.is_complex():
        field = field.to(torch.complex128 if field.dtype == torch.float64 else torch.complex64)
    lead = tuple(field.shape[:-2])
    for name, value in (("wavelength", wavelength), ("distance", distance)):
        check_broadcast(name, tuple(torch.as_tensor(value).shape) if not isinstance(value, torch.Tensor) else value.shape, lead)
    grid = padded_shape(field.shape[-2:], spacing, wavelength, distance, padding, method)
    transfer = compute_transfer_function(
        grid, spacing, wavelength, distance, method, bandlimit, dtype=field.dtype, device=field.device
    )
    return apply_transfer_function(field, transfer)
