"""`phase_mask` and `learned_phase_mask`: a PhlatCam-style thin phase plate near the sensor.

No reference implementation exists; this is the model and its defaults.

* **Height map.** A surface height ``h >= 0`` (metres) given at the nodes of
  a lattice of ``feature_size`` (15 um) cells covering a centred rectangle of
  ``aperture`` (80 %) of the sensor's height and width (as the SLM's crop);
  between nodes the surface is bilinear, and outside the rectangle the plate
  is opaque (an exact fractional-area aperture, keeping the PSF within the
  LSI field). ``phase_mask`` draws the nodes once from a seed: white
  Gaussian noise smoothed by a Gaussian of standard deviation
  ``correlation_length`` (30 um), then scaled to ``[0, max_height]`` (2 um);
  or loads them from an ``.npy`` file (any ``(m, n)`` array of heights in
  metres spanning the aperture). ``learned_phase_mask`` learns them as
  ``h = max_height * sigmoid(logit)``: bounded, with a non-zero gradient for
  every finite logit (never clamped), optionally rounded to ``levels``
  equally spaced heights (lithography steps) with a straight-through
  gradient. A learned map may set neighbouring nodes anywhere in
  ``[0, max_height]``, so its defaults differ: 75 um cells of up to
  1.28 um (one wave at 640 nm), whose steepest ramp changes the phase by
  at most 2.9 rad per sample on the ``fast`` grid (1.4 on ``default``);
  :meth:`LearnedPhaseMask.phase_step_bound` gives the bound and a
  :class:`~optoenc.optics.SamplingWarning` names the settings when it
  exceeds ``pi`` (an aliased plate that training can exploit: 15 um cells
  of up to 2 um lost 10-43 points when re-simulated at ``reference``).
* **Material.** Phase ``phi = 2 pi (n(lambda) - 1) h / lambda`` with a Cauchy
  model ``n(lambda) = n_550 + B (1 / lambda^2 - 1 / (550 nm)^2)``;
  defaults ``n_550 = 1.5`` and ``B = 0`` (a constant index; PMMA is about
  ``n_550 = 1.49``, ``B = 3.5e-15 m^2``).
* **PSF.** Point source at ``d1`` -> plate ``exp(i phi)`` sampled at the grid
  pixel centres -> band-limited angular spectrum over ``d2`` (2 mm) ->
  ``|U|^2`` at 640 / 550 / 460 nm, one batched FFT. Smooth bumps act as
  lenslets of focal length ~ ``L^2 / (2 (n - 1) h)``, a few mm for the
  defaults, so caustic contours form near ``d2``.
* **Sampling.** The grid carries angles up to ``lambda / (2 pixel)`` (~0.02 rad
  on the default 12.3 um grid), so the PSF can spread at most ~``d2 lambda /
  pixel`` around each mask point and the phase must change by less than pi
  per grid pixel: the defaults give at most ~1.9 rad at 460 nm on the
  default grid; coarser grids (the ``fast`` preset) alias.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from scipy.ndimage import gaussian_filter
from torch import nn

from .. import devices
from ..errors import ConfigError
from ..optics import SamplingWarning, phase_mask, rect_aperture
from ..settings import setting
from .base import EncoderConfig
from .mask import MaskEncoder

__all__ = [
    "PhaseMaskConfig",
    "PhaseMask",
    "LearnedPhaseMaskConfig",
    "LearnedPhaseMask",
    "smooth_height_map",
    "bilinear_matrix",
]

#: Reference wavelength of ``refractive_index``, metres.
_LAMBDA_REF = 550e-9


def smooth_height_map(shape: tuple[int, int], correlation_cells: float, max_height: float, seed: int) -> np.ndarray:
    """Seeded smooth random heights in ``[0, max_height]``: Gaussian-filtered white noise, min-max scaled."""
    noise = np.random.default_rng(seed).standard_normal(shape)
    smooth = gaussian_filter(noise, sigma=max(correlation_cells, 1e-6), mode="wrap")
    lo, hi = smooth.min(), smooth.max()
    return (smooth - lo) / (hi - lo if hi > lo else 1.0) * max_height


def bilinear_matrix(n_nodes: int, cell: float, n_grid: int, spacing: float) -> torch.Tensor:
    """``(n_grid, n_nodes)`` linear interpolation from lattice nodes to grid-pixel centres along one axis.

    Node ``j`` sits at the centre of cell ``j`` of a centred lattice of
    ``n_nodes`` cells of size ``cell``; grid pixel ``i`` is centred
    ``(i - n_grid // 2) * spacing`` from the axis. Beyond the outer nodes
    the height is held constant.
    """
    pos = (torch.arange(n_grid, dtype=torch.float64) - n_grid // 2) * spacing
    t = (pos / cell + (n_nodes - 1) / 2).clamp(0, n_nodes - 1)
    lo = t.floor().long().clamp(max=max(n_nodes - 2, 0))
    frac = t - lo
    out = torch.zeros(n_grid, n_nodes, dtype=torch.float64)
    rows = torch.arange(n_grid)
    out[rows, lo] += 1 - frac
    if n_nodes > 1:
        out[rows, lo + 1] += frac
    else:
        out[rows, lo] += frac
    return out


@dataclass
class PhaseMaskConfig(EncoderConfig):
    d2: float = setting(devices.PHASE_MASK_D2, "phase-plate-to-sensor distance d2", unit="m", gt=0)
    aperture: float = setting(0.8, "fraction of the sensor height and width covered by the plate", gt=0, le=1)
    feature_size: float = setting(15e-6, "side of one height-map cell (random or learned maps)", unit="m", gt=0)
    max_height: float = setting(2e-6, "largest surface height", unit="m", gt=0)
    correlation_length: float = setting(30e-6, "smoothing length (Gaussian sigma) of the random height map",
                                        unit="m", gt=0)
    refractive_index: float = setting(1.5, "refractive index of the plate at 550 nm", gt=1)
    cauchy_b: float = setting(0.0, "Cauchy dispersion coefficient B of n(lambda) = n_550 + B (1/lambda^2 - 1/550nm^2)",
                              unit="m^2", ge=0)
    height_map_path: Optional[str] = setting(
        None, ".npy height map (metres) spanning the aperture; null: seeded random"
    )
    seed: int = setting(0, "seed of the random height map", ge=0)
    levels: Optional[int] = setting(None, "number of equally spaced height levels in [0, max_height]; null: continuous",
                                    ge=2)


@dataclass
class LearnedPhaseMaskConfig(PhaseMaskConfig):
    # A learned map can put any two neighbouring nodes at 0 and max_height; these defaults keep even that
    # sampled on the `fast` grid (LearnedPhaseMask.phase_step_bound), so training cannot exploit aliasing.
    feature_size: float = setting(75e-6, "side of one height-map cell (random or learned maps)", unit="m", gt=0)
    max_height: float = setting(1.28e-6, "largest surface height (1.28 um: one wave at 640 nm for n = 1.5)",
                                unit="m", gt=0)


class PhaseMask(MaskEncoder):
    """PhlatCam-style phase plate: a smooth random (or loaded) height map 2 mm from the sensor."""

    name = "phase_mask"
    Config = PhaseMaskConfig
    learnable = False
    linear = True

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        init = self.initial_heights()
        self._lattice = tuple(init.shape)
        self.register_buffer("heights", init, persistent=False)
        self._interp: tuple[torch.Tensor, torch.Tensor] | None = None

    # ----------------------------------------------------------------- height map
    def initial_heights(self) -> torch.Tensor:
        """``(m, n)`` float64 heights (metres) from ``height_map_path`` or the seeded random draw."""
        cfg, (sh, sw) = self.config, self.sensor.size
        path = cfg.height_map_path
        if path is None:
            shape = tuple(max(1, round(cfg.aperture * s / cfg.feature_size)) for s in (sh, sw))
            return torch.from_numpy(
                smooth_height_map(shape, cfg.correlation_length / cfg.feature_size, cfg.max_height, cfg.seed)
            )
        if Path(path).suffix.lower() != ".npy" or not Path(path).is_file():
            raise ConfigError("encoder.height_map_path", path, "file not found (must be an existing .npy file)")
        try:
            arr = np.asarray(np.load(path, allow_pickle=False), dtype=np.float64)
        except Exception as err:  # unreadable file: report the setting, one line
            raise ConfigError("encoder.height_map_path", path, f"unreadable ({type(err).__name__}: {err})") from None
        if arr.ndim != 2 or min(arr.shape) < 1 or not np.isfinite(arr).all() or arr.min() < 0:
            raise ConfigError("encoder.height_map_path", path, "must hold a 2-D array of finite heights >= 0, metres")
        return torch.from_numpy(arr.copy())

    def height_map(self) -> torch.Tensor:
        """``(m, n)`` heights as manufactured (quantised to ``levels`` if set), metres."""
        return self._quantize(self.heights)

    def _quantize(self, h: torch.Tensor) -> torch.Tensor:
        if self.config.levels is None:
            return h
        step = self.config.max_height / (self.config.levels - 1)
        return h + (torch.round(h / step).clamp(0, self.config.levels - 1) * step - h).detach()

    @property
    def cell_size(self) -> tuple[float, float]:
        """``(height, width)`` of one height-map cell, metres."""
        return tuple(self.config.aperture * s / n for s, n in zip(self.sensor.size, self._lattice))

    def index(self, wavelength: torch.Tensor) -> torch.Tensor:
        """Refractive index at ``wavelength`` (metres, float64 tensor): the Cauchy model."""
        return self.config.refractive_index + self.config.cauchy_b * (1 / wavelength**2 - 1 / _LAMBDA_REF**2)

    def _interpolation(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self._interp is None:
            self._interp = tuple(
                bilinear_matrix(n, cell, g, d)
                for n, cell, g, d in zip(self._lattice, self.cell_size, self.field_grid, self.field_spacing)
            )
        return self._interp

    def surface(self) -> torch.Tensor:
        """``(H, W)`` surface height on the grid (bilinear between the lattice nodes), metres."""
        by, bx = self._interpolation()
        h = self.height_map()
        return by.to(h.device, h.dtype) @ h @ bx.to(h.device, h.dtype).T

    def mask(self) -> torch.Tensor:
        """``(3, H, W)`` complex transmittance on the grid at the R, G, B wavelengths (opaque outside the aperture)."""
        cdt = torch.complex128 if self.optics_dtype == torch.float64 else torch.complex64
        t = phase_mask(self.surface(), devices.WAVELENGTHS_RGB, self.index, dtype=cdt)  # (3, H, W)
        size = tuple(self.config.aperture * s for s in self.sensor.size)
        grid, spacing = self.field_grid, self.field_spacing
        opening = rect_aperture(grid, spacing, size, dtype=self.optics_dtype, device=t.device)
        return t * opening


class LearnedPhaseMask(PhaseMask):
    """Learned phase plate: heights ``max_height * sigmoid(logit)`` per cell, optionally quantised."""

    name = "learned_phase_mask"
    Config = LearnedPhaseMaskConfig
    learnable = True
    linear = True

    def __init__(self, config=None, **kw):
        super().__init__(config, **kw)
        p = (self.heights / self.config.max_height).clamp(0.01, 0.99)
        if bool((self.heights > self.config.max_height * (1 + 1e-9)).any()):
            raise ConfigError("encoder.height_map_path", self.config.height_map_path,
                              f"initial heights must lie within [0, max_height = {self.config.max_height}] m")
        del self.heights
        self.logits = nn.Parameter(torch.log(p / (1 - p)))
        bound = self.phase_step_bound()
        if bound > math.pi:
            warnings.warn(SamplingWarning(
                f"learned_phase_mask: a learned height map can change the phase by up to {bound:.3g} rad between "
                f"neighbouring grid samples (> pi: aliased, and training can exploit the aliasing); raise "
                f"encoder.feature_size (now {self.config.feature_size:.3g} m), lower encoder.max_height "
                f"(now {self.config.max_height:.3g} m) or refine fidelity.grid"
            ), stacklevel=2)

    def phase_step_bound(self) -> float:
        """Largest phase change (rad) between neighbouring field samples that any height map can make.

        Two neighbouring lattice nodes at 0 and ``max_height`` give the steepest
        bilinear ramp: ``2 pi (n - 1) max_height / lambda`` over one cell, at
        the shortest wavelength, i.e. that times ``spacing / cell`` per field
        sample (the whole step when a cell is narrower than a sample). Above
        ``pi`` the field grid aliases the plate.
        """
        lam = torch.tensor(min(devices.WAVELENGTHS_RGB), dtype=torch.float64)
        full = 2 * math.pi * (float(self.index(lam)) - 1) * self.config.max_height / float(lam)
        return full * max(min(1.0, d / c) for d, c in zip(self.field_spacing, self.cell_size))

    def height_map(self) -> torch.Tensor:
        return self._quantize(self.config.max_height * torch.sigmoid(self.logits))
