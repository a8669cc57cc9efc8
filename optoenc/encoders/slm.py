"""`fixed_slm` and `learned_slm`: an ST7735R LCD used as a programmable amplitude mask.

Model (paper A.5, A.5.2): a point source at ``d1`` gives a spherical wave at
the LCD; the LCD multiplies it by a real amplitude mask ``M_c(x, y)`` per
wavelength (ideal one-hot colour filters: at 640 / 550 / 460 nm only the R /
G / B sub-pixel rows transmit, each with its amplitude ``w_k`` in ``[0, 1]``,
deadspace opaque, see :mod:`optoenc.encoders.slm_panel`); the field
propagates ``d2`` to the sensor with the band-limited angular spectrum and the
intensity PSF is ``|U_c|^2``, all three wavelengths in one batched FFT; or, with
``fidelity.propagation = "separable"`` (the default preset), axis by axis as two small
matrix products per wavelength (:mod:`optoenc.optics.separable`: the sub-pixels are
cells on a lattice; PSF within 1.0e-5 of the 2-D one at the paper's geometry).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from torch import nn

from .. import devices as K
from ..errors import ConfigError
from ..settings import setting
from . import slm_panel
from .base import EncoderConfig
from .mask import MaskEncoder
from .patterns import PatternSet

__all__ = ["SLMConfig", "FixedSLM", "LearnedSLMConfig", "LearnedSLM", "panel_image", "start_logits", "EDGE_LOGIT"]

#: The logit a pattern value of exactly 1 starts at (-EDGE_LOGIT for 0): that of 1 - eps (float64's machine epsilon),
#: the nearest amplitude to the edge whose logit is finite in both directions. sigmoid(-36.04) = 2.2e-16.
EDGE_LOGIT = float(torch.logit(torch.tensor(1 - torch.finfo(torch.float64).eps, dtype=torch.float64)))


def start_logits(pattern: torch.Tensor) -> torch.Tensor:
    """float64 logits whose sigmoid is ``pattern`` (values in ``[0, 1]``) to float64 rounding (1.1e-16).

    Exact 0 and 1, which no finite logit reaches, and values within float64's epsilon of them become
    -:data:`EDGE_LOGIT` and :data:`EDGE_LOGIT` (an amplitude within 2.2e-16 of the value)."""
    p = pattern.to(torch.float64)
    return torch.logit(p).clamp(-EDGE_LOGIT, EDGE_LOGIT)


@dataclass
class SLMConfig(EncoderConfig):
    d2: float = setting(K.SLM_D2, "LCD-to-sensor distance d2", unit="m", gt=0)
    aperture: float = setting(
        K.SLM_APERTURE, "fraction of the sub-pixels over the sensor left open, per axis", gt=0, le=1
    )
    active_subpixels: Optional[tuple[int, int]] = setting(
        None, "explicit (rows, columns) of the centred active sub-pixel block; null: from the aperture", ge=1
    )
    pattern_path: Optional[str] = setting(
        None, "sub-pixel amplitudes in [0, 1]: .npy of the active block (e.g. 51 x 22) or the panel (384 x 160); "
        "null: seeded uniform random"
    )
    seed: int = setting(0, "seed of the random pattern", ge=0)
    pattern_range: tuple[float, float] = setting(
        (0.0, 1.0), "(low, high) of the seeded uniform random pattern (pattern_path null): e.g. (0.45, 0.55) starts a "
        "learned mask half open everywhere, where the sigmoid's gradient is largest", ge=0, le=1,
    )
    quantize: str = setting("none", "display levels: 'none', '8bit' or 'rgb565' (R 5, G 6, B 5 bits)",
                            choices=("none", "8bit", "rgb565"))

    def __post_init__(self) -> None:
        super().__post_init__()
        low, high = self.pattern_range
        if low > high:
            raise ConfigError("pattern_range", list(self.pattern_range), "must be (low, high) with low <= high")


@dataclass
class LearnedSLMConfig(SLMConfig):
    learn_d2: bool = setting(False, "also learn d2 (d2 = d2_init * exp(s), s learned)")
    d2_lr_scale: float = setting(
        0.01, "learn_d2: learning rate of s = log(d2 / d2_init) relative to trainer.encoder_lr (Adam moves s by "
        "about its rate each step: at the mask's 1e-2, d2 drifted from 4 to 0.3 mm within one epoch)", gt=0, le=1,
    )
    parameterization: str = setting(
        "sigmoid", "how the optimiser holds each sub-pixel's amplitude w in [0, 1]: 'sigmoid' (w = sigmoid(logit), "
        "logit unconstrained; a sub-pixel driven to |logit| ~ 10 gets gradients below Adam's eps and stays there) or "
        "'projected' (w itself, clamped into [0, 1] after every optimiser step; its gradient never shrinks at the "
        "bounds)", choices=("sigmoid", "projected"),
    )
    patterns: int = setting(
        1, "K patterns learned jointly with one decoder; each capture displays one, drawn at random "
        "(variable-pattern defence, docs/privacy.md); 1: a single pattern", ge=1, le=64
    )


class _SLMBase(MaskEncoder):
    """Shared layout and PSF of the LCD encoders."""

    #: Measured against the converged truth (``optoenc bench``, grid-free
    #: Fresnel integrals of the LCD cells): on 384 x 512 an LCD row (73 um)
    #: spans 5.95 grid pixels and the point-sampled intensity beats into a
    #: moire; 288 x 384 (4.46 px per row, still dividing every paper
    #: embedding) is 0.91 % and cheaper. ``reference``: the sharp cell edges
    #: diffract light to angles a 5.9 um field grid cannot carry (0.56 % at
    #: 768 x 1024, error ~ field pitch); a 5x finer field (1.19 um) is 0.14 %.
    fidelity_presets = {"default": {"grid": (288, 384)}, "reference": {"psf_oversample": 5, "padding": "auto"}}

    Config = SLMConfig

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        self.block = slm_panel.active_block(self.sensor.size, self.config.aperture, self.config.active_subpixels)
        levels = slm_panel.level_counts(self.config.quantize, self.block)
        self._levels = None if levels is None else torch.from_numpy(levels)[:, None]

    def initial_pattern(self, count: int = 1) -> torch.Tensor:
        """``(rows, cols)`` float64 block amplitudes from ``pattern_path`` or the seeded random draw.

        ``count > 1``: ``(count, rows, cols)`` seeded random patterns, the first one the ``count = 1`` pattern.
        """
        shape = self.block.shape
        path = self.config.pattern_path
        if path is None:
            low, high = (float(v) for v in self.config.pattern_range)
            draw = np.random.default_rng(self.config.seed).uniform(low, high, (count, *shape) if count > 1 else shape)
            return torch.from_numpy(draw)
        if count > 1:
            raise ConfigError("encoder.pattern_path", path, f"is one pattern; leave it null with encoder.patterns = {count}")
        if Path(path).suffix.lower() != ".npy" or not Path(path).is_file():
            raise ConfigError("encoder.pattern_path", path, "file not found (must be an existing .npy file)")
        try:
            arr = np.asarray(np.load(path, allow_pickle=False), dtype=np.float64)
        except Exception as err:  # unreadable file: report the setting, one line
            raise ConfigError("encoder.pattern_path", path, f"unreadable ({type(err).__name__}: {err})") from None
        b = self.block
        if arr.shape == K.ST7735R_SUBPIXELS:
            arr = arr[b.row0 : b.row0 + b.rows, b.col0 : b.col0 + b.cols]
        elif arr.shape != shape:
            raise ConfigError("encoder.pattern_path", path,
                              f"shape {arr.shape} must be the active block {shape} or the panel {K.ST7735R_SUBPIXELS}")
        if not np.isfinite(arr).all() or arr.min() < 0 or arr.max() > 1:
            raise ConfigError("encoder.pattern_path", path, "values must be finite and within [0, 1]")
        return torch.from_numpy(arr.copy())

    def _quantize(self, w: torch.Tensor) -> torch.Tensor:
        """Round to the display levels; straight-through (identity) gradient."""
        if self._levels is None:
            return w
        lv = self._levels.to(w.device, w.dtype)
        return w + (torch.round(w * lv) / lv - w).detach()

    def displayed_amplitudes(self) -> torch.Tensor:
        """``(rows, cols)`` amplitudes of the active block's sub-pixels, in ``[0, 1]``, as the panel displays them.

        The one accessor whatever the encoder holds: a fixed pattern, a learned mask's ``logits``
        (``parameterization='sigmoid'``) or ``amplitudes`` (``'projected'``), the pattern shown now
        (:attr:`active_pattern`) of several, rounded to the display levels (``quantize``, straight-through
        gradient). Differentiable with respect to a learned mask's parameter; float64.
        """
        raise NotImplementedError

    def d2_tensor(self) -> torch.Tensor | float:
        return float(self.config.d2)

    #: Physical spacing of :meth:`mask`'s samples (one LCD sub-pixel), metres: mask pictures in mm.
    mask_spacing = K.ST7735R_PITCH
    #: The sub-pixels are cells on a lattice: propagated axis by axis (``fidelity.propagation``).
    separable = True

    def mask(self) -> torch.Tensor:
        """The panel as displayed: ``(384, 160)`` sub-pixel amplitude transmittances (0 outside the active block),
        detached, one sample per sub-pixel (:attr:`mask_spacing`). On the field grid: :meth:`field_mask`."""
        return slm_panel.full_panel(self.displayed_amplitudes().detach(), self.block)

    def field_mask(self) -> torch.Tensor:
        """``(3, H, W)`` amplitude transmittance on the field grid per R, G, B wavelength: the open cells of the
        displayed sub-pixels with exact fractional areas (:func:`~optoenc.encoders.slm_panel.rasterise`), in
        ``self.optics_dtype``; what the 2-D propagation propagates. Differentiable."""
        w = self.displayed_amplitudes().to(self.optics_dtype)
        return slm_panel.rasterise(w, self.block, self.field_grid, self.field_spacing)

    def cell_factors(self) -> tuple[torch.Tensor, torch.Tensor]:
        return slm_panel.panel_factors(self.block, self.field_grid, self.field_spacing)

    def compute_psf(self) -> torch.Tensor:
        d2 = self.d2_tensor()
        if self.separable_applies(d2):  # the sub-pixels are cells on a lattice: axis by axis
            w = self.displayed_amplitudes().to(self.optics_dtype)
            return self.separable_psf(slm_panel.colour_values(w, self.block), d2)
        return self.propagated_psf(self.field_mask(), d2)


class FixedSLM(_SLMBase):
    """ST7735R LCD with a fixed (seeded random or loaded) pattern, 4 mm from the sensor."""

    name = "fixed_slm"
    Config = SLMConfig
    learnable = False
    linear = True

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        self.register_buffer("pattern", self.initial_pattern(), persistent=False)

    def displayed_amplitudes(self) -> torch.Tensor:
        return self._quantize(self.pattern)


class LearnedSLM(PatternSet, _SLMBase):
    """ST7735R LCD whose 1122 sub-pixel amplitudes (and optionally d2) are learned end to end.

    Parameterisation (``parameterization``): by default amplitude ``w = sigmoid(logit)``
    of an unconstrained ``logit`` per active sub-pixel, so ``w`` stays in ``(0, 1)``
    with a non-zero gradient ``w (1 - w)`` for every finite logit (no clamping in
    forward). Non-zero is not enough for Adam: at ``|logit| ~ 10`` the gradient
    (``w (1 - w) ~ 5e-5`` times the amplitude's) falls below Adam's ``eps`` (1e-8),
    whose steps then shrink in proportion, and the sub-pixel stays where it is
    (1010 of the 6x8 logistic cell's 1122 sub-pixels after 200 epochs).
    ``'projected'``: the amplitudes ``w`` are the parameters themselves, clamped
    into ``[0, 1]`` after every optimiser step (:meth:`constrain_`, projected
    gradient; never inside forward), so a closed sub-pixel reopens as soon as its
    gradient says so. With ``quantize`` the displayed value is rounded to the panel's
    levels with a straight-through gradient. With ``learn_d2``,
    ``d2 = config.d2 * exp(s)`` with a learned scalar ``s`` (always positive).
    The PSF is recomputed once per optimiser step (the base class caches it
    on the parameter versions). With ``patterns = K > 1`` the logits are
    ``(K, rows, cols)``, pattern 0 being the ``K = 1`` pattern, and each
    capture displays one of them (:class:`~optoenc.encoders.patterns.PatternSet`).

    The start is :class:`FixedSLM`'s pattern at the same ``seed`` (or ``pattern_path``):
    ``displayed_amplitudes()`` equals it to float64 rounding (1.1e-16; bit for bit once
    rounded to the float32 optics), so both encoders' first embeddings are the same.
    A value of exactly 0 or 1, which no finite logit reaches, starts at
    :data:`EDGE_LOGIT` (amplitude within float64's epsilon, 2.2e-16, of it);
    ``'projected'`` starts at, and can stay at, exact 0 and 1.
    Read the amplitudes with :meth:`displayed_amplitudes` whatever the parameterisation.
    """

    name = "learned_slm"
    Config = LearnedSLMConfig
    learnable = True
    linear = True

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        self.patterns = int(self.config.patterns)
        self.projected = self.config.parameterization == "projected"
        if self.projected:  # the amplitudes themselves, float64, kept in [0, 1] by constrain_()
            self.amplitudes = nn.Parameter(self.initial_pattern(self.patterns))
        else:
            # float64 logits: the gradient w (1 - w) stays non-zero up to |logit| ~ 36 (float32: ~16).
            self.logits = nn.Parameter(start_logits(self.initial_pattern(self.patterns)))
        if self.config.learn_d2:
            self.log_d2_scale = nn.Parameter(torch.zeros((), dtype=torch.float64))
        else:
            self.log_d2_scale = None

    def displayed_amplitudes(self) -> torch.Tensor:
        if self.projected:
            return self._quantize(self.amplitudes if self.patterns == 1 else self.amplitudes[self.active_pattern])
        logits = self.logits if self.patterns == 1 else self.logits[self.active_pattern]
        return self._quantize(torch.sigmoid(logits))

    def constrain_(self) -> None:
        """``projected``: clamp the amplitudes into ``[0, 1]`` (after each optimiser step)."""
        if self.projected:
            with torch.no_grad():
                self.amplitudes.clamp_(0.0, 1.0)

    def lr_scales(self) -> dict[str, float]:
        return {"log_d2_scale": float(self.config.d2_lr_scale)} if self.config.learn_d2 else {}

    def d2_tensor(self) -> torch.Tensor | float:
        if getattr(self, "log_d2_scale", None) is None:  # also while the base class initialises
            return float(self.config.d2)
        return self.config.d2 * torch.exp(self.log_d2_scale.to(torch.float64))

    @property
    def d2(self) -> float:
        """Current (possibly learned) LCD-to-sensor distance, metres."""
        d2 = self.d2_tensor()
        return float(d2.detach()) if isinstance(d2, torch.Tensor) else d2


def panel_image(encoder: _SLMBase) -> np.ndarray:
    """The ``(128, 160, 3)`` uint8 RGB image an SLM encoder's panel displays (opaque sub-pixels = 0)."""
    return slm_panel.to_panel_image(encoder.mask())

