"""An explicit illumination spectrum: wavelengths (metres) with relative intensity weights.

Light from natural scenes is spatially incoherent and polychromatic: each
wavelength forms its own intensity PSF and intensities (never fields) add.
A :class:`Spectrum` carries the sampled wavelengths and the weight of each in
that sum; :meth:`Spectrum.combine` forms ``sum_c w_c PSF_c``.

The RGB table and the grayscale weights come from :mod:`optoenc.devices`
(the one channel <-> wavelength table): R 640 nm, G 550 nm, B 460 nm, and a
grayscale scene on a grayscale sensor sees ``0.299 PSF_R + 0.587 PSF_G +
0.114 PSF_B`` (ITU-R BT.601 luma weights).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from ..devices import GRAYSCALE_WEIGHTS, WAVELENGTHS_RGB
from ..errors import ConfigError

__all__ = ["Spectrum", "VISIBLE_BAND"]

#: The visible band used by :meth:`Spectrum.sampled` by default, metres.
VISIBLE_BAND = (380e-9, 780e-9)


@dataclass(frozen=True)
class Spectrum:
    """Sampled wavelengths and their relative intensity weights (immutable, validated).

    Attributes:
        wavelengths: ``C`` wavelengths in metres, each in ``(0, inf)``.
        weights: ``C`` non-negative relative intensities, not all zero (they
            need not sum to one; see :meth:`normalized`).
        names: optional ``C`` channel names (e.g. ``("R", "G", "B")``).
    """

    wavelengths: tuple[float, ...]
    weights: tuple[float, ...]
    names: tuple[str, ...] | None = None

    def __post_init__(self):
        try:
            wl = tuple(float(w) for w in self.wavelengths)
            wt = tuple(float(w) for w in self.weights)
        except (TypeError, ValueError):
            raise ConfigError("spectrum", (self.wavelengths, self.weights), "wavelengths and weights must be numbers") from None
        if not wl or len(wl) != len(wt):
            raise ConfigError("spectrum.weights", wt, f"must have one weight per wavelength ({len(wl)}), at least one")
        if not all(math.isfinite(w) and w > 0 for w in wl):
            raise ConfigError("spectrum.wavelengths", wl, "must be finite and > 0, in metres")
        if not all(math.isfinite(w) and w >= 0 for w in wt) or sum(wt) <= 0:
            raise ConfigError("spectrum.weights", wt, "must be finite, >= 0 and not all zero")
        if any(w > 1e-3 for w in wl):
            raise ConfigError("spectrum.wavelengths", wl, "must be in metres (e.g. 550e-9), not nanometres")
        names = None if self.names is None else tuple(str(n) for n in self.names)
        if names is not None and len(names) != len(wl):
            raise ConfigError("spectrum.names", names, f"must have one name per wavelength ({len(wl)})")
        object.__setattr__(self, "wavelengths", wl)
        object.__setattr__(self, "weights", wt)
        object.__setattr__(self, "names", names)

    # ------------------------------------------------------------------ constructors

    @classmethod
    def rgb(cls) -> "Spectrum":
        """R, G, B at 640, 550, 460 nm (``optoenc.devices.WAVELENGTHS_RGB``), equal weights."""
        return cls(WAVELENGTHS_RGB, (1.0, 1.0, 1.0), ("R", "G", "B"))

    @classmethod
    def gray(cls) -> "Spectrum":
        """The RGB wavelengths weighted by ``optoenc.devices.GRAYSCALE_WEIGHTS`` (0.299, 0.587, 0.114)."""
        return cls(WAVELENGTHS_RGB, GRAYSCALE_WEIGHTS, ("R", "G", "B"))

    @classmethod
    def monochromatic(cls, wavelength: float) -> "Spectrum":
        """A single wavelength (metres) of weight 1."""
        return cls((wavelength,), (1.0,))

    @classmethod
    def sampled(
        cls, n: int, band: tuple[float, float] = VISIBLE_BAND, density: Callable[[float], float] | None = None
    ) -> "Spectrum":
        """``n`` samples at the centres of ``n`` equal sub-bands of ``band`` (metres).

        Args:
            n: number of samples, >= 1.
            band: ``(lambda_min, lambda_max)``, metres.
            density: optional spectral power density ``S(lambda)`` (any unit);
                weights are ``S(lambda_c)`` (default: flat, all 1).
        """
        if not (isinstance(n, int) and n >= 1):
            raise ConfigError("n", n, "must be an int >= 1")
        lo, hi = (float(b) for b in band)
        if not (0 < lo < hi):
            raise ConfigError("band", band, "must be (lambda_min, lambda_max) with 0 < lambda_min < lambda_max, metres")
        wl = tuple(lo + (i + 0.5) * (hi - lo) / n for i in range(n))
        wt = tuple(float(density(w)) for w in wl) if density is not None else (1.0,) * n
        return cls(wl, wt)

    # ------------------------------------------------------------------ use

    def __len__(self) -> int:
        return len(self.wavelengths)

    def normalized(self) -> "Spectrum":
        """The same spectrum with weights summing to one."""
        total = sum(self.weights)
        return Spectrum(self.wavelengths, tuple(w / total for w in self.weights), self.names)

    def wavelength_tensor(self, dtype: torch.dtype = torch.float64, device=None) -> torch.Tensor:
        """``(C,)`` wavelengths in metres."""
        return torch.tensor(self.wavelengths, dtype=dtype, device=device)

    def weight_tensor(self, dtype: torch.dtype = torch.float64, device=None) -> torch.Tensor:
        """``(C,)`` weights."""
        return torch.tensor(self.weights, dtype=dtype, device=device)

    def combine(self, psf: torch.Tensor, normalize: bool = True) -> torch.Tensor:
        """Incoherent sum over wavelengths: ``(..., C, H, W) -> (..., H, W)``.

        Args:
            psf: per-wavelength intensity PSFs, channel dimension ``-3``.
            normalize: use the weights scaled to sum to one (so channels that
                each sum to one give a PSF that sums to one).
        """
        if psf.ndim < 3 or psf.shape[-3] != len(self):
            raise ConfigError("psf", tuple(psf.shape), f"must be (..., {len(self)}, H, W) for this spectrum")
        w = (self.normalized() if normalize else self).weight_tensor(psf.dtype, psf.device)
        return torch.einsum("...chw,c->...hw", psf, w)
