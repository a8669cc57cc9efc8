"""`MaskEncoder`: the shared base of every encoder whose PSF is propagated from a mask.

Coded aperture, LCD/SLM and phase-mask encoders supply a transmittance on the
wave-field grid (the simulation grid refined ``fidelity.psf_oversample``
times); the PSF is point source at ``d1`` -> mask -> band-limited angular
spectrum over ``d2`` -> ``|U|^2`` at the R, G, B wavelengths in one batched
FFT, integrated over each grid pixel.
"""

from __future__ import annotations

import math

import torch

from .. import devices
from ..optics import intensity_psf
from .base import OpticalEncoder

__all__ = ["MaskEncoder"]


class MaskEncoder(OpticalEncoder):
    """Base of the encoders whose PSF is point source -> mask -> BLAS over ``d2`` -> ``|U|^2``."""

    @property
    def oversample(self) -> int:
        """Field samples per grid pixel and axis (``fidelity.psf_oversample``)."""
        return self.knobs.psf_oversample

    @property
    def field_grid(self) -> tuple[int, int]:
        """Grid of the wave field: the simulation grid refined ``oversample`` (odd) times per axis.

        Its centre sample (the optical axis, at index ``N // 2``) is the centre
        sub-sample of grid pixel ``n // 2``, so the pixel-integrated PSF keeps
        the grid's axis convention; the few extra samples past ``n * s`` are
        dropped after propagation.
        """
        s = self.oversample
        out = []
        for n in self.geometry.grid:
            c = (n // 2) * s + (s - 1) // 2
            out.append(2 * c if 2 * c >= n * s else 2 * c + 1)
        return tuple(out)

    @property
    def field_spacing(self) -> tuple[float, float]:
        """Sample spacing of the wave field, metres."""
        return tuple(d / self.oversample for d in self.geometry.spacing)

    def fidelity_padding(self) -> tuple[int, int] | str:
        """Zero padding per side: ``"auto"``, or grid pixels from a fraction of the grid (``fidelity.padding``)."""
        pad = self.knobs.padding
        if pad == "auto":
            return "auto"
        return tuple(math.ceil(pad * n) for n in self.field_grid)

    def propagated_psf(self, mask: torch.Tensor, d2: float | torch.Tensor) -> torch.Tensor:
        """``(3, H, W)`` intensity PSF of an amplitude ``mask``, channels keeping their transmitted power.

        Channel ``c`` is the fraction of the power incident on the window at
        wavelength ``c`` that reaches each sensor pixel
        (``normalize="power"`` of :func:`optoenc.optics.intensity_psf`), so a
        colour whose filter is dimmed gives a dimmer channel.

        Args:
            mask: ``(H, W)`` or ``(3, H, W)`` (one per R, G, B wavelength)
                amplitude transmittance on the field grid (:attr:`field_grid`),
                real or complex.
            d2: mask-to-sensor distance, metres (a tensor may require grad).
        """
        psf = intensity_psf(
            mask,
            devices.WAVELENGTHS_RGB,
            self.field_spacing,
            self.scene_config.distance,
            d2,
            padding=self.fidelity_padding(),
            normalize="power",
        )
        if self.oversample > 1:  # intensity integrated over each grid pixel
            s = self.oversample
            H, W = self.geometry.grid
            psf = psf[..., : H * s, : W * s]
            psf = torch.nn.functional.avg_pool2d(psf[None] if psf.dim() == 3 else psf[None, None], s)[0]
        return psf.to(self.optics_dtype).expand(3, -1, -1) if psf.shape[0] == 1 else psf.to(self.optics_dtype)
