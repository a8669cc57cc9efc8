"""`coded_aperture`: a FlatCam-style binary amplitude mask (separable MLS pattern) near the sensor.

Mask (paper A.6): ``scipy.signal.max_len_seq(order)`` (0/1, length
``2**order - 1``; 63 for order 6) tiled ``repeats`` times (126), and the outer
product of the sequence with itself: a 126 x 126 binary pattern, 25.8 % open,
of ``feature_size`` (30 um) square cells, i.e. 3.78 mm, ~80 % of the sensor
height, centred on the optical axis; everything outside is opaque.

PSF: point source at ``d1`` -> mask -> band-limited angular spectrum over
``d2`` (0.5 mm, as FlatCam) -> ``|U|^2`` at 640 / 550 / 460 nm in one batched
FFT. The cells are rasterised with exact fractional areas.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .. import devices as K
from ..optics import cell_mask
from ..settings import setting
from .base import EncoderConfig
from .mask import MaskEncoder

__all__ = ["CodedApertureConfig", "CodedAperture", "mls_sequence", "mls_pattern"]


def mls_sequence(order: int = K.MLS_ORDER) -> np.ndarray:
    """The 0/1 maximum length sequence of ``scipy.signal.max_len_seq(order)`` (length ``2**order - 1``)."""
    from scipy.signal import max_len_seq  # lazy: scipy.signal takes ~1 s to import

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

    #: Measured against the converged truth (``optoenc bench``, grid-free
    #: Fresnel integrals of the MLS squares): the digit spans few grid pixels
    #: (|M| = d2 / d1 = 1/800) and the 30 um squares diffract light to angles a
    #: coarse field grid cannot carry, so both presets oversample the field
    #: (sub-pixel scene geometry comes with it). ``default``: 4.1 % at
    #: 384 x 512 without, 0.74 % with 5x. ``reference`` (768 x 1024): 0.58 %
    #: with 3x, 0.317 % with 5x, 0.2405 % with 7x (a 0.88 um field; the
    #: error follows the field pitch: 1536 x 2048 with 3x, 1.02 um, is
    #: 0.293 %; 1152 x 1536 with 5x, 0.82 um, 0.227 % at ~1.5x the cost).
    #: 7x costs a PSF of ~70 s instead of ~30 s and 5.4 GB peak instead of
    #: 3.1 GB (2-core machine at load ~8).
    fidelity_presets = {"reference": {"psf_oversample": 7, "padding": "auto"}, "default": {"psf_oversample": 5}}

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
