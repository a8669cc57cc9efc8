"""`coded_aperture`: a FlatCam-style binary amplitude mask (separable MLS pattern) near the sensor.

Mask (paper A.6): ``scipy.signal.max_len_seq(order)`` (0/1, length
``2**order - 1``; 63 for order 6) tiled ``repeats`` times (126), and the outer
product of the sequence with itself: a 126 x 126 binary pattern, 25.8 % open,
of ``feature_size`` (30 um) square cells, i.e. 3.78 mm, ~80 % of the sensor
height, centred on the optical axis; everything outside is opaque.

PSF: point source at ``d1`` -> mask -> band-limited angular spectrum over
``d2`` (0.5 mm, as FlatCam) -> ``|U|^2`` at 640 / 550 / 460 nm in one batched
FFT. The cells are rasterised with exact fractional areas.

:class:`MaskEncoder` is the shared base of every encoder whose PSF is
propagated from a mask (coded aperture, SLMs, phase masks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.signal import max_len_seq

from .. import devices
from ..optics import cell_mask, intensity_psf
from ..settings import setting
from . import constants as K
from .base import EncoderConfig, OpticalEncoder

__all__ = ["MaskEncoder", "CodedApertureConfig", "CodedAperture", "mls_sequence", "mls_pattern"]


class MaskEncoder(OpticalEncoder):
    """Base of the encoders whose PSF is point source -> mask -> BLAS over ``d2`` -> ``|U|^2``."""

    @property
    def oversample(self) -> int:
        """Field samples per grid pixel and axis (``fidelity.psf_oversample``)."""
        return int(self.knobs.get("psf_oversample") or 1)

    @property
    def field_grid(self) -> tuple[int, int]:
        """Grid of the wave field: the simulation grid refined ``oversample`` times per axis."""
        return tuple(n * self.oversample for n in self.geometry.grid)

    @property
    def field_spacing(self) -> tuple[float, float]:
        """Sample spacing of the wave field, metres."""
        return tuple(d / self.oversample for d in self.geometry.spacing)

    def fidelity_padding(self) -> tuple[int, int] | str:
        """Zero padding per side: ``"auto"``, or grid pixels from a fraction of the grid (``fidelity.padding``)."""
        pad = self.knobs["padding"]
        if pad == "auto":
            return "auto"
        return tuple(math.ceil(float(pad) * n) for n in self.field_grid)

    def propagated_psf(self, mask: torch.Tensor, d2: float | torch.Tensor) -> torch.Tensor:
        """``(3, H, W)`` intensity PSF (each channel summing to one) of an amplitude ``mask``.

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
        )
        if self.oversample > 1:  # intensity integrated over each grid pixel
            s = self.oversample
            psf = torch.nn.functional.avg_pool2d(psf[None] if psf.dim() == 3 else psf[None, None], s)[0]
        return psf.to(self.optics_dtype).expand(3, -1, -1) if psf.shape[0] == 1 else psf.to(self.optics_dtype)


def mls_sequence(order: int = K.MLS_ORDER) -> np.ndarray:
    """The 0/1 maximum length sequence of ``scipy.signal.max_len_seq(order)`` (length ``2**order - 1``)."""
    return max_len_seq(order)[0].astype(np.float64)


def mls_pattern(order: int = K.MLS_ORDER, repeats: int = K.MLS_REPEATS) -> np.ndarray:
    """``(n, n)`` 0/1 mask cells: the outer product of the sequence tiled ``repeats`` times with itself."""
    seq = np.tile(mls_sequence(order), repeats)
    return np.outer(seq, seq)


@dataclass
class CodedApertureConfig(EncoderConfig):
    d2: float = setting(K.MLS_D2, "mask-to-sensor distance d2", unit="m", gt=0)
    order: int = setting(K.MLS_ORDER, "order of the maximum length sequence (length 2**order - 1)", ge=2, le=16)
    repeats: int = setting(K.MLS_REPEATS, "times the sequence is tiled along each axis", ge=1)
    feature_size: float = setting(K.MLS_FEATURE, "side of one square mask cell", unit="m", gt=0)


class CodedAperture(MaskEncoder):
    """Coded aperture: separable MLS binary mask (30 um features) 0.5 mm from the sensor."""

    name = "coded_aperture"
    Config = CodedApertureConfig
    learnable = False
    linear = True

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        self.register_buffer("cells", torch.from_numpy(mls_pattern(self.config.order, self.config.repeats)),
                             persistent=False)

    @property
    def extent(self) -> float:
        """Side of the (square) mask, metres."""
        return self.cells.shape[0] * self.config.feature_size

    def mask(self) -> torch.Tensor:
        """``(H, W)`` amplitude transmittance of the mask on the simulation grid (exact fractional areas)."""
        size = (self.config.feature_size, self.config.feature_size)
        return cell_mask(self.cells.to(self.optics_dtype), size, self.field_grid, self.field_spacing)

    def compute_psf(self) -> torch.Tensor:
        return self.propagated_psf(self.mask(), self.d2)
