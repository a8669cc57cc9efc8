"""Sampling diagnostics: can this grid support this propagation? Numbers, and warnings in words.

Formulas (``N`` pixels, ``Np`` padded pixels, pitch ``dx``, wavelength ``lambda``,
distance ``d``; each axis separately, the worst axis and wavelength reported):

* Fresnel number ``N_F = a^2 / (lambda |d|)`` with ``a = N dx / 2`` the
  window's half width (``N_F >> 1``: near field; ``<~ 1``: far field).
* ``z_max = Np dx^2 / lambda * sqrt(1 - (lambda / 2 dx)^2)``: beyond it the
  angular-spectrum transfer function is undersampled on the padded grid
  (plain ASM aliases, BLAS starts to remove frequencies). ``0`` when
  ``dx < lambda / 2``.
* ``band_removed``: the fraction of the grid's propagating band
  ``|u| <= min(1 / 2dx, 1 / lambda)`` (area, both axes) that the band limit
  removes.
* ``source_phase_step``: the largest phase change between neighbouring pixels
  of the spherical wave from ``d1`` (aliased above ``pi``).
* ``spread``: how far the highest frequency the propagator keeps travels
  sideways; wrap-around happens when it exceeds the padding.
* ``paraxial_error``: ``k |d| |sqrt(1 - s) - 1 + s / 2|`` at the band edge,
  ``s = (lambda u)^2 + (lambda v)^2``: the Fresnel approximation's phase error.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

from ..errors import ConfigError, PhysicsError
from ._common import as_real, as_spacing
from .propagation import METHODS, padded_shape
from .sources import source_phase_step

__all__ = ["SamplingReport", "SamplingWarning", "sampling_report", "check_sampling"]

#: Above this fraction of the band removed by the band limit, a warning is given.
MAX_BAND_REMOVED = 0.5
#: Above this Fresnel-approximation phase error (rad), the "fresnel" method warns.
MAX_PARAXIAL_ERROR = math.pi / 2

_WARNED: set = set()


class SamplingWarning(UserWarning):
    """The sampling cannot support the requested propagation reliably."""


@dataclass(frozen=True)
class SamplingReport:
    """Numbers describing how well a grid samples a propagation (see the module docstring)."""

    shape: tuple[int, int]
    padded_shape: tuple[int, int]
    spacing: tuple[float, float]
    wavelengths: tuple[float, ...]
    distance: float
    d1: float | None
    method: str
    fresnel_number: float
    z_max: float
    band_removed: float
    source_phase_step: float
    subwavelength: bool
    spread: float
    padding: tuple[float, float]
    paraxial_error: float
    warnings: tuple[str, ...] = field(default=())
    kinds: tuple[str, ...] = field(default=(), repr=False)

    @property
    def ok(self) -> bool:
        """True when no warning applies."""
        return not self.warnings


def sampling_report(
    shape, spacing, wavelength, distance, d1=None, *, method: str = "blas", padding="auto", bandlimit: bool = True
) -> SamplingReport:
    """Sampling numbers and warnings for propagating an ``(H, W)`` field over ``distance``.

    Args:
        shape: ``(H, W)`` of the field (before padding).
        spacing: float or ``(dy, dx)``, metres.
        wavelength: float or sequence/tensor of wavelengths, metres (all checked).
        distance: propagation distance, metres (``|d|`` is used).
        d1: optional point-source distance, metres (``inf``: plane wave).
        method, padding, bandlimit: as for :func:`~optoenc.optics.propagation.propagate`.

    Returns:
        A :class:`SamplingReport`; ``report.warnings`` lists the problems in words.
    """
    if method not in METHODS:
        raise ConfigError("method", method, f"must be one of {METHODS}")
    H, W = (int(n) for n in shape)
    dy, dx = as_spacing(spacing)
    wls = tuple(float(w) for w in as_real(wavelength, "wavelength", positive=True).detach().reshape(-1).cpu())
    d = float(as_real(distance, "distance").detach().abs().max())
    Hp, Wp = padded_shape((H, W), (dy, dx), wls, d, padding, method)
    limit = bandlimit and method != "asm"
    axes = ((H, Hp, dy), (W, Wp, dx))
    fresnel, zmax, removed, spread, parax = math.inf, math.inf, 0.0, 0.0, 0.0
    for lam in wls:
        k = 2 * math.pi / lam
        kept, s_edge = 1.0, 0.0
        for n, n_p, delta in axes:
            fresnel = min(fresnel, (n * delta / 2) ** 2 / (lam * d) if d > 0 else math.inf)
            q = lam / (2 * delta)
            zmax = min(zmax, n_p * delta**2 / lam * math.sqrt(1 - q * q) if q < 1 else 0.0)
            band = min(1 / (2 * delta), 1 / lam)
            if limit and d > 0:
                L = n_p * delta
                ulim = L / (2 * lam * d) if method == "fresnel" else 1 / (lam * math.sqrt((2 * d / L) ** 2 + 1))
            else:
                ulim = math.inf
            u = min(band, ulim)
            kept *= min(1.0, u / band)
            s_edge += (lam * u) ** 2
            sin = lam * u
            if method == "fresnel":
                spread = max(spread, d * sin)
            else:
                spread = max(spread, math.inf if sin >= 1 and d > 0 else (d * sin / math.sqrt(1 - sin * sin) if sin < 1 else 0.0))
        removed = max(removed, 1.0 - kept)
        s_edge = min(s_edge, 1.0)
        parax = max(parax, k * d * abs(math.sqrt(1 - s_edge) - 1 + s_edge / 2))
    pad = ((Hp - H) * dy, (Wp - W) * dx)
    if d1 is not None:  # the closest source is the worst case
        d1 = float(as_real(d1, "d1", positive=True, allow_inf=True).detach().min())
    step = source_phase_step((H, W), (dy, dx), wls, d1) if d1 is not None else 0.0
    sub = min(dy, dx) < max(wls) / 2

    msgs, kinds = [], []

    def warn(kind: str, text: str) -> None:
        kinds.append(kind)
        msgs.append(text)

    if not limit and method != "fresnel" and d > zmax:
        warn("aliasing", f"plain ASM aliases: |d| = {d:.4g} m > z_max = {zmax:.4g} m (use method='blas' or more padding)")
    if limit and removed > MAX_BAND_REMOVED:
        warn(
            "bandlimit",
            f"the band limit removes {100 * removed:.1f}% of the band at |d| = {d:.4g} m (z_max = {zmax:.4g} m): "
            "detail finer than the kept band is lost (use a larger window / padding, or a coarser grid)",
        )
    if step > math.pi:
        warn("source", f"the spherical wave from d1 = {d1:.4g} m is aliased: {step:.3g} rad per pixel > pi at the window's edge")
    if sub:
        warn(
            "subwavelength",
            f"spacing {min(dy, dx):.4g} m < lambda/2 = {max(wls) / 2:.4g} m: sub-wavelength sampling, "
            "scalar diffraction is unreliable at this scale",
        )
    if 0 < d < max(wls):
        warn("near", f"|d| = {d:.4g} m is below one wavelength: scalar diffraction is unreliable")
    axis_pad = min(pad)
    if spread > axis_pad:
        warn("wraparound", f"light spreads {spread:.4g} m sideways, more than the padding ({axis_pad:.4g} m): it wraps around")
    if method == "fresnel" and parax > MAX_PARAXIAL_ERROR:
        warn("paraxial", f"the Fresnel approximation's phase error reaches {parax:.3g} rad at the band edge")
    return SamplingReport(
        shape=(H, W), padded_shape=(Hp, Wp), spacing=(dy, dx), wavelengths=wls, distance=d,
        d1=d1, method=method, fresnel_number=fresnel, z_max=zmax,
        band_removed=removed, source_phase_step=step, subwavelength=sub, spread=spread, padding=pad,
        paraxial_error=parax, warnings=tuple(msgs), kinds=tuple(kinds),
    )  # fmt: skip


def check_sampling(
    shape,
    spacing,
    wavelength,
    distance,
    d1=None,
    *,
    method: str = "blas",
    padding="auto",
    bandlimit: bool = True,
    strict: bool = False,
) -> SamplingReport:
    """:func:`sampling_report`, then warn (or raise) when the sampling is unreliable.

    A :class:`SamplingWarning` is issued once per distinct configuration (shape,
    spacing, wavelengths, method, padding, band limit, ``d1``) and kind of
    problem, so a trainable distance that drifts does not repeat it every step.

    Raises:
        PhysicsError: with ``strict=True``, when any warning applies.
    """
    report = sampling_report(shape, spacing, wavelength, distance, d1, method=method, padding=padding, bandlimit=bandlimit)
    if report.ok:
        return report
    text = "optics sampling: " + "; ".join(report.warnings)
    if strict:
        raise PhysicsError(text)
    key = (report.shape, report.spacing, report.wavelengths, method, str(padding), bandlimit, report.d1, report.kinds)
    if key not in _WARNED:
        if len(_WARNED) > 4096:
            _WARNED.clear()
        _WARNED.add(key)
        warnings.warn(text, SamplingWarning, stacklevel=2)
    return report
