"""Scene, sensor and fidelity settings shared by every encoder (SI units).

These three settings groups describe what every optical encoder images (the
scene), what it images onto (the sensor and its embedding) and how finely it
is simulated (fidelity). An encoder's own ``Config`` holds only what is
specific to it (its distance ``d2``, its mask, ...).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping, Optional

from . import devices
from .errors import ConfigError
from .settings import Settings, setting

__all__ = ["SceneConfig", "SensorConfig", "FidelityConfig", "FIDELITY_PRESETS", "Geometry"]


@dataclass
class SceneConfig(Settings):
    """The object in front of the camera."""

    object_height: float = setting(devices.SCENE_HEIGHT, "physical height of the scene image (a digit)", unit="m", gt=0)
    distance: float = setting(devices.SCENE_DISTANCE, "scene-to-encoder distance d1", unit="m", gt=0)


@dataclass
class SensorConfig(Settings):
    """The sensor (Raspberry Pi HQ / IMX477 by default), its embedding and noise."""

    pixel_pitch: float = setting(devices.IMX477_PITCH, "physical sensor pixel pitch", unit="m", gt=0)
    resolution: tuple[int, int] = setting(devices.IMX477_RESOLUTION, "physical sensor pixels (rows, columns)", ge=1)
    embedding: tuple[int, int] = setting(devices.EMBEDDINGS[0], "embedding size (rows, columns) after pixel integration", ge=1)
    color: str = setting("gray", "sensor colour: 'gray' (one channel) or 'rgb'", choices=("gray", "rgb"))
    noise: str = setting("gaussian", "noise model", choices=("gaussian", "poisson", "none"))
    snr_db: Optional[float] = setting(devices.SNR_DB, "SNR of the gaussian noise (null: no noise)", unit="dB")
    photons: float = setting(1e4, "photons at the brightest pixel (poisson model)", gt=0)
    read_noise: float = setting(0.0, "read noise (poisson model)", unit="e-", ge=0)
    adc_bits: Optional[int] = setting(None, "ADC bit depth (null: no quantisation)", ge=1, le=32)

    @property
    def size(self) -> tuple[float, float]:
        """Physical sensor size (height, width), metres."""
        return (self.resolution[0] * self.pixel_pitch, self.resolution[1] * self.pixel_pitch)


#: Named fidelity presets: the one table of their values (docs list it).
FIDELITY_PRESETS: dict[str, dict] = {
    "reference": {"grid": (768, 1024), "dtype": "float64", "padding": "1.0", "psf_oversample": 1},
    "default": {"grid": devices.DEFAULT_GRID, "dtype": "float32", "padding": "auto", "psf_oversample": 1},
    "fast": {"grid": (192, 256), "dtype": "float32", "padding": "auto", "psf_oversample": 1},
}


@dataclass
class FidelityConfig(Settings):
    """How finely the optics are simulated: the speed/accuracy knobs.

    ``preset`` fills every knob left at ``null``; a knob set explicitly wins.
    """

    preset: str = setting(
        "default",
        "named preset filling the knobs left null; 'auto': the cheapest setting whose measured embedding error "
        "is within `tolerance` (measured once per encoder configuration by `optoenc fit`, then cached)",
        choices=(*FIDELITY_PRESETS, "auto"),
    )
    tolerance: float = setting(0.01, "preset 'auto': largest relative embedding error against the high-fidelity reference", gt=0)
    grid: Optional[tuple[int, int]] = setting(None, "simulation grid (rows, columns) over the sensor area", ge=1)
    dtype: Optional[str] = setting(None, "floating point precision of the optics", choices=("float32", "float64"))
    padding: Optional[str] = setting(
        None,
        "propagation zero padding per side: 'auto' (the diffraction spread the grid can carry, "
        "so nothing wraps around) or a fraction of the grid such as 0.5",
    )

    psf_oversample: Optional[int] = setting(
        None,
        "simulated PSFs: the wave field is computed on a grid this many (odd) times finer per axis and its "
        "intensity integrated over each grid pixel (anti-aliased PSF; cost grows as its square)",
        choices=(1, 3, 5, 7),
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.padding is not None and self.padding != "auto":
            try:
                ok = float(self.padding) >= 0
            except ValueError:
                ok = False
            if not ok:
                raise ConfigError("padding", self.padding, "must be 'auto' or a fraction >= 0 of the grid")

    def resolved(self, overrides: Mapping[str, Mapping] | None = None) -> dict:
        """The knob values after filling the nulls from the preset.

        Args:
            overrides: an encoder's measured per-preset values
                (``OpticalEncoder.fidelity_presets``), applied over the
                shared preset table and under explicitly set knobs.
        """
        if self.preset == "auto":
            raise ConfigError(
                "fidelity.preset", "auto", "is resolved for a run by `optoenc fit` (optoenc.autofidelity.resolve); "
                "an encoder needs a named preset or explicit knobs"
            )
        out = dict(FIDELITY_PRESETS[self.preset])
        out.update((overrides or {}).get(self.preset, {}))
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name not in ("preset", "tolerance") and v is not None:
                out[f.name] = tuple(v) if isinstance(v, (list, tuple)) else v
        return out


@dataclass(frozen=True)
class Geometry:
    """Derived simulation geometry (read-only), from sensor + fidelity settings."""

    grid: tuple[int, int]
    spacing: tuple[float, float]
    embedding: tuple[int, int]

    @classmethod
    def of(cls, sensor: SensorConfig, fidelity: FidelityConfig, overrides: Mapping | None = None) -> "Geometry":
        grid = tuple(int(g) for g in fidelity.resolved(overrides)["grid"])
        h, w = sensor.size
        emb = tuple(int(e) for e in sensor.embedding)
        for axis, (e, g) in enumerate(zip(emb, grid)):
            if e > g:
                raise ConfigError(
                    f"sensor.embedding[{axis}]", e, f"must be <= the simulation grid {grid[axis]} (fidelity.grid)"
                )
        return cls(grid=grid, spacing=(h / grid[0], w / grid[1]), embedding=emb)
