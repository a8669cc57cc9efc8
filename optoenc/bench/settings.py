"""The bench's shared settings: what is measured, how an encoder is built at a setting, how it is compared.

* the defaults of a measurement (:data:`ENCODERS`, :data:`PRESETS`, the
  paper's grid, the truth's grid, the sweep points, the embedding, batch and
  digit counts);
* :class:`Setting`, one simulation setting of one encoder, and the settings
  measured (:func:`preset_setting`, :func:`paper_setting`,
  :func:`paper_grid_setting`, :func:`truth_setting`, :func:`sweep_settings`);
* :func:`build_encoder` (an encoder at a setting), :func:`embed` (its
  noise-free float64 embeddings) and :func:`relative_error`.

The measurement (:mod:`optoenc.bench.pipeline`) and the truth
(:mod:`optoenc.bench.truth`) both read them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional

import torch

from .. import devices
from ..encoders.fidelity import FIDELITY_PRESETS, FidelityConfig
from ..errors import ConfigError
from ..settings import to_dict
from ..training.loaders import encode

__all__ = [
    "ENCODERS",
    "PRESETS",
    "PAPER_GRID",
    "PAPER_PADDING",
    "TRUTH_GRID",
    "EMBEDDING",
    "BATCH",
    "DIGITS",
    "ENCODE_COUNT",
    "MONO_WAVELENGTH",
    "Setting",
    "preset_setting",
    "paper_setting",
    "paper_grid_setting",
    "truth_setting",
    "sweep_settings",
    "encoder_class",
    "is_mask_encoder",
    "build_encoder",
    "embed",
    "relative_error",
]

#: Encoders measured by default (the built-ins).
ENCODERS = ("lens", "coded_aperture", "diffuser", "fixed_slm", "learned_slm", "phase_mask", "learned_phase_mask")
#: Presets measured by default.
PRESETS = tuple(FIDELITY_PRESETS)
#: The paper's simulation grid (sensor / 8) and its 2x propagation window (0.5 per side).
PAPER_GRID = (380, 507)
PAPER_PADDING = "0.5"
#: The truth's finest grid: the full sensor.
TRUTH_GRID = tuple(devices.IMX477_RESOLUTION)
#: Sweep points, each knob alone from the ``default`` preset.
SWEEP_GRIDS = ((96, 128), (192, 256), (288, 384), (380, 507), (576, 768), (768, 1024))
SWEEP_PADDINGS = ("0", "0.25", "0.5", "1.0")
SWEEP_DTYPES = ("float32", "float64")
#: The single wavelength of the one-wavelength sweep point (the G channel).
MONO_WAVELENGTH = 550e-9
#: Embedding, training batch and test digits of the benchmark.
EMBEDDING = (24, 32)
BATCH = 200
DIGITS = 256
ENCODE_COUNT = 10_000


def _grid_str(grid) -> str:
    return "x".join(str(int(n)) for n in grid)


@dataclass(frozen=True)
class Setting:
    """One simulation setting of one encoder.

    Attributes:
        label: name in the tables (``"default"``, ``"paper"``, ``"grid=192x256"``).
        kind: ``"truth"``, ``"paper"`` (as published), ``"paper-grid"``, ``"preset"`` or ``"sweep"``.
        grid, dtype, padding: the fidelity knobs.
        preset: the preset name (presets only).
        knob, value: the swept knob and its value (sweep points only).
        wavelengths: 3 (the spectral model) or 1 (550 nm only, mask encoders).
        oversample: ``psf_oversample``.
        propagation: ``fidelity.propagation`` (None: the preset's own; a preset's setting names it).
    """

    label: str
    kind: str
    grid: tuple[int, int]
    dtype: str
    padding: str
    preset: Optional[str] = None
    knob: Optional[str] = None
    value: Optional[str] = None
    wavelengths: int = 3
    oversample: int = 1
    propagation: Optional[str] = None

    @property
    def method(self) -> str:
        """Imaging path: ``published`` (the paper's), ``direct`` (paper-grid) or the exact scene ``operator``."""
        return {"paper": "published", "paper-grid": "direct"}.get(self.kind, "operator")

    def fidelity(self) -> FidelityConfig:
        """The :class:`FidelityConfig` of this setting (explicit knobs; a preset's name kept)."""
        return FidelityConfig(
            preset=self.preset or "default",
            grid=tuple(self.grid),
            dtype=self.dtype,
            padding=str(self.padding),
            psf_oversample=int(self.oversample),
            propagation=self.propagation,
        )


def preset_setting(name: str, encoder_name: str | None = None) -> Setting:
    """The setting of a named fidelity preset (with the encoder's own measured overrides)."""
    if name not in FIDELITY_PRESETS:
        raise ConfigError("preset", name, f"one of {', '.join(FIDELITY_PRESETS)}")
    overrides = getattr(encoder_class(encoder_name), "fidelity_presets", {}) if encoder_name else {}
    p = FidelityConfig(preset=name).resolved(overrides)
    return Setting(
        name, "preset", tuple(p["grid"]), p["dtype"], p["padding"], preset=name, oversample=int(p.get("psf_oversample") or 1),
        propagation=p.propagation,
    )


def paper_setting(grid=PAPER_GRID, padding: str = PAPER_PADDING) -> Setting:
    """The published paper pipeline's setting: its grid, float32, 2x padding (:mod:`optoenc.bench.published`)."""
    return Setting("paper", "paper", tuple(grid), "float32", str(padding))


def paper_grid_setting(grid=PAPER_GRID, padding: str = PAPER_PADDING) -> Setting:
    """The paper's grid, padding and per-step PSF with optoenc's exact placement and box integration."""
    return Setting("paper-grid", "paper-grid", tuple(grid), "float32", str(padding))


def truth_setting(grid: tuple[int, int] = TRUTH_GRID) -> Setting:
    """The refined simulation setting of the truth's other routes: ``grid``, float64, padding ``auto``."""
    return Setting("truth", "truth", tuple(int(n) for n in grid), "float64", "auto")


def is_mask_encoder(cls) -> bool:
    """Whether ``cls`` is a :class:`~optoenc.encoders.mask.MaskEncoder` class (a mask and propagation)."""
    from ..encoders.mask import MaskEncoder

    return isinstance(cls, type) and issubclass(cls, MaskEncoder)


def encoder_class(name: str):
    """The encoder class registered as ``name`` (PluginError for an unknown name)."""
    from ..plugins import get_registry

    return get_registry("encoder").get(name)


def sweep_settings(encoder_name: str, base: str = "default") -> list[Setting]:
    """Each knob alone from ``base``: grid, dtype; for mask encoders also padding, wavelengths, PSF oversampling,
    and propagation (2-D or axis by axis) for those whose mask factors by axis (``MaskEncoder.separable``).

    Every other knob keeps ``base``'s value (``psf_oversample`` included);
    points equal to ``base`` itself are left out (the preset row stands for them).
    """
    b = preset_setting(base, encoder_name)
    cls = encoder_class(encoder_name)
    mask = is_mask_encoder(cls)

    def point(knob: str, value, **changed) -> Setting:
        return dataclasses.replace(b, label=f"{knob}={value}", kind="sweep", preset=None, knob=knob, value=str(value),
                                   **changed)

    out = [point("grid", _grid_str(g), grid=tuple(g)) for g in SWEEP_GRIDS if tuple(g) != b.grid]
    if mask:
        out += [point("padding", p, padding=p) for p in SWEEP_PADDINGS if p != str(b.padding)]
    out += [point("dtype", d, dtype=d) for d in SWEEP_DTYPES if d != b.dtype]
    if mask:
        out.append(point("wavelengths", 1, wavelengths=1))
        other = 3 if b.oversample == 1 else 1
        out.append(point("psf_oversample", other, oversample=other))
        if getattr(cls, "separable", False):
            other = "blas" if b.propagation == "separable" else "separable"
            out.append(point("propagation", other, propagation=other))
    return out


# ----------------------------------------------------------------------------- encoders


def build_encoder(name: str, setting: Setting, embedding=EMBEDDING, setup: Optional[dict] = None):
    """The encoder ``name`` at ``setting``.

    ``setup`` may hold ``config`` (the encoder's settings), ``scene`` and
    ``sensor`` (mappings or settings objects) to measure a specific encoder;
    by default its registry defaults are used.
    """
    cls = encoder_class(name)
    setup = dict(setup or {})
    sensor = setup.get("sensor")
    sensor = dict(to_dict(sensor)) if sensor is not None and not isinstance(sensor, dict) else dict(sensor or {})
    sensor["embedding"] = tuple(int(e) for e in embedding)
    enc = cls(setup.get("config"), scene=setup.get("scene"), sensor=sensor, fidelity=setting.fidelity())
    if setting.wavelengths == 1:
        if not is_mask_encoder(cls):
            raise ConfigError("wavelengths", 1, f"only mask encoders can be reduced to one wavelength, not {name}")
        enc.set_monochromatic(MONO_WAVELENGTH)
    return enc


@torch.no_grad()
def embed(enc, images: torch.Tensor, method: str = "operator", chunk: int = 64) -> torch.Tensor:
    """Noise-free float64 embeddings of ``images`` (eval mode); ``method="published"``: the paper's pipeline."""
    if method == "published":
        from .published import published_forward

        was = enc.training
        enc.eval()
        try:
            return torch.cat([published_forward(enc, images[i : i + chunk], noise=False, recompute_psf=False).double()
                              for i in range(0, len(images), chunk)])
        finally:
            enc.train(was)
    step = max(len(images), 1) if method == "operator" else chunk
    return encode(enc, images.to(torch.float64), step, method=method).double()


def relative_error(e: torch.Tensor, ref: torch.Tensor) -> float:
    """``||e - ref|| / ||ref||`` over all examples and pixels."""
    return float((e.double() - ref.double()).norm() / ref.double().norm().clamp_min(1e-300))
