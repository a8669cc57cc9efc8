"""The intensity PSF of a mask: point source -> mask -> free-space propagation -> ``|U|^2``.

For each wavelength (all in one batched FFT):
``U1 = point_source(d1) * mask``, ``U2 = propagate(U1, d2)``, ``PSF = |U2|^2``,
then a stated normalisation (paper A.5; REFERENCE section 1).
"""

from __future__ import annotations

import torch

from ..errors import ConfigError, PhysicsError
from .diagnostics import check_sampling
from ._common import CACHE, as_real, as_spacing, tensor_key
from .propagation import propagate
from .sources import point_source
from .spectrum import Spectrum

__all__ = ["NORMALIZATIONS", "sensor_field", "intensity_psf", "check_energy"]

#: Normalisations understood by :func:`intensity_psf`.
NORMALIZATIONS = ("sum", "power", "none")


def _wavelengths(wavelengths, device) -> torch.Tensor:
    if isinstance(wavelengths, Spectrum):
        return wavelengths.wavelength_tensor(device=device)
    wl = as_real(wavelengths, "wavelengths", device, positive=True)
    if wl.ndim > 1:
        raise ConfigError("wavelengths", tuple(wl.shape), "must be a float, a (C,) sequence or tensor, or a Spectrum")
    return wl.reshape(-1)


def _checked(mask: torch.Tensor) -> tuple[torch.Tensor, torch.dtype]:
    """The mask as a float/complex tensor, and the complex dtype of the computation."""
    if not isinstance(mask, torch.Tensor) or mask.ndim < 2:
        raise ConfigError("mask", getattr(mask, "shape", mask), "must be a tensor of shape (H, W), (C, H, W) or (..., C, H, W)")
    if mask.is_complex():
        return mask, mask.dtype
    if mask.dtype == torch.float64:
        return mask, torch.complex128
    return mask.to(torch.float32), torch.complex64  # a real mask multiplies the complex source directly


def _source(shape, spacing, wl, d1, offset, amplitude, dtype):
    d = as_real(d1, "d1", wl.device, positive=True, allow_inf=True)
    if d.requires_grad or wl.requires_grad:
        return point_source(shape, spacing, wl, d, offset, amplitude, dtype, wl.device)
    key = ("source", tuple(shape), as_spacing(spacing), tensor_key(wl), tensor_key(d), tuple(offset), amplitude, dtype, str(wl.device))
    hit = CACHE.get(key)
    if hit is None:
        hit = point_source(shape, spacing, wl, d, offset, amplitude, dtype, wl.device)
        CACHE.put(key, hit)
    return hit


def sensor_field(
    mask: torch.Tensor,
    wavelengths,
    spacing,
    d1,
    d2,
    *,
    method: str = "blas",
    padding="auto",
    bandlimit: bool = True,
    source_offset=(0.0, 0.0),
    source_amplitude: str = "unit",
) -> torch.Tensor:
    """Complex field at the sensor for a point source at ``d1`` and a mask ``d2`` before the sensor.

    Arguments as :func:`intensity_psf`. Returns complex ``(..., C, H, W)``.
    """
    field_mask, cdtype = _checked(mask)
    wl = _wavelengths(wavelengths, field_mask.device)
    lead = tuple(field_mask.shape[:-2])
    try:
        out_lead = torch.broadcast_shapes(lead, (wl.numel(),))
    except RuntimeError:
        raise ConfigError(
            "mask", tuple(mask.shape), f"leading dimensions must broadcast against the {wl.numel()} wavelengths (C, H, W)"
        ) from None
    shape = tuple(field_mask.shape[-2:])
    source = _source(shape, spacing, wl, d1, source_offset, source_amplitude, cdtype)
    u1 = (source * field_mask).expand(*out_lead, *shape)
    return propagate(u1, d2, wl, spacing, method=method, padding=padding, bandlimit=bandlimit)


def intensity_psf(
    mask: torch.Tensor,
    wavelengths,
    spacing,
    d1,
    d2,
    *,
    method: str = "blas",
    padding="auto",
    bandlimit: bool = True,
    normalize: str = "sum",
    source_offset=(0.0, 0.0),
    source_amplitude: str = "unit",
    check: bool = True,
) -> torch.Tensor:
    """Intensity PSF of a mask at ``d2`` before the sensor, for a point source at ``d1``.

    The source is :func:`~optoenc.optics.sources.point_source` (unit amplitude by
    default, axis at ``(H // 2, W // 2)``); the mask's window is also the
    sensor's (light leaving it is lost). Differentiable with respect to
    ``mask``, ``d1`` and ``d2``.

    Args:
        mask: complex amplitude transmittance (a real tensor is an amplitude
            transmittance, not an intensity one): ``(H, W)`` shared by all
            wavelengths, ``(C, H, W)`` one per wavelength (e.g. LCD colour
            filters), or ``(..., C, H, W)`` / ``(..., 1, H, W)`` batches.
            float32/complex64 computes in complex64, float64/complex128 in
            complex128.
        wavelengths: metres: a float, a ``(C,)`` sequence or tensor, or a
            :class:`~optoenc.optics.spectrum.Spectrum` (its weights are not
            applied here: use :meth:`Spectrum.combine`).
        spacing: pixel pitch, float or ``(dy, dx)``, metres.
        d1: source-to-mask distance, metres, ``> 0`` or ``inf`` (plane wave).
        d2: mask-to-sensor distance, metres (float or tensor, may require grad).
        method: ``"blas"`` (default), ``"asm"`` or ``"fresnel"``.
        padding: ``"auto"``, int pixels per side, or ``(py, px)``.
        bandlimit: apply the BLAS band limit.
        normalize: ``"sum"`` (default): each wavelength's PSF sums to 1 over
            the window (the relative power of the wavelengths is lost).
            ``"power"``: ``|U2|^2 / sum |U1-|^2``, so each PSF sums to the
            fraction of the power incident on the window that reaches the
            sensor window (~ the mask's mean ``|M|^2`` at that wavelength):
            the wavelengths keep their relative transmitted power (what an
            encoder with colour filters needs). ``"none"``: raw ``|U2|^2`` for
            the unit-amplitude source.
        source_offset: ``(y0, x0)`` lateral position of the point source, metres.
        source_amplitude: ``"unit"`` or ``"spherical"`` (``1/r`` fall-off).
        check: run :func:`~optoenc.optics.diagnostics.check_sampling` (warns
            once per configuration when the sampling is unreliable).

    Returns:
        real ``(..., C, H, W)`` of the mask's real dtype (``C = 1`` for a
        single float wavelength).

    Raises:
        PhysicsError: the PSF is not finite, or has no energy: with
            ``normalize="sum"`` at any wavelength (it cannot be scaled to 1),
            otherwise at every wavelength (an opaque colour filter is physical,
            an opaque mask is not usable).
    """
    if normalize not in NORMALIZATIONS:
        raise ConfigError("normalize", normalize, f"must be one of {NORMALIZATIONS}")
    field = sensor_field(
        mask, wavelengths, spacing, d1, d2, method=method, padding=padding, bandlimit=bandlimit,
        source_offset=source_offset, source_amplitude=source_amplitude,
    )  # fmt: skip
    wl = _wavelengths(wavelengths, field.device)
    if check:
        check_sampling(tuple(field.shape[-2:]), spacing, wl, d2, d1, method=method, padding=padding, bandlimit=bandlimit)
    psf = field.real.square() + field.imag.square()
    total = check_energy(psf, wl, normalize != "sum")
    if normalize == "sum":
        return psf / total
    if normalize == "power":
        source = _source(tuple(field.shape[-2:]), spacing, wl, d1, source_offset, source_amplitude, field.dtype)
        incident = (source.real.square() + source.imag.square()).sum(dim=(-2, -1), keepdim=True)
        return psf / incident
    return psf


def check_energy(psf: torch.Tensor, wl: torch.Tensor, powers_kept: bool = True) -> torch.Tensor:
    """``psf``'s total per wavelength ``(..., C, 1, 1)``, refusing NaN or inf, or no energy.

    With ``powers_kept`` (any normalisation but ``"sum"``) a dark wavelength is
    allowed (an opaque colour filter is physical); only an all-dark PSF is not.

    Raises:
        PhysicsError: naming the wavelengths, as :func:`intensity_psf`.
    """
    total = psf.sum(dim=(-2, -1), keepdim=True)
    bad = ~(total.detach() > 0) | ~torch.isfinite(total.detach())
    if powers_kept and bool(torch.isfinite(total.detach()).all()):
        bad = bad.all(dim=-3, keepdim=True).expand_as(bad)
    if bool(bad.any()):
        idx = bad.reshape(-1, wl.numel()).any(dim=0).nonzero().reshape(-1).tolist()
        nm = ", ".join(f"{1e9 * float(wl[i]):.0f} nm" for i in idx)
        what = "no energy (all-zero or opaque mask?)" if bool(torch.isfinite(total.detach()).all()) else "NaN or inf values"
        raise PhysicsError(f"intensity_psf: the PSF at {nm} has {what}; nothing usable reaches the sensor")
    return total
