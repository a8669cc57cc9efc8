"""Scene and sensor settings shared by every encoder (SI units), and the derived simulation geometry.

These settings groups describe what every optical encoder images (the
scene) and what it images onto (the sensor and its embedding); how finely it
is simulated (fidelity) is :mod:`optoenc.fidelity.knobs`, whose names this
module also exports as before. An encoder's own ``Config`` holds only what
is specific to it (its distance ``d2``, its mask, ...).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Optional

from .. import devices
from ..errors import ConfigError
from ..fidelity.knobs import FIDELITY_PRESETS, KNOB_NAMES, FidelityConfig, Knobs, parse_padding
from ..settings import Settings, setting

#: The fidelity names are :mod:`optoenc.fidelity.knobs`'s, exported here too (their old home).
__all__ = ["SceneConfig", "SensorConfig", "Geometry", "FidelityConfig", "FIDELITY_PRESETS", "KNOB_NAMES", "Knobs", "parse_padding"]


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
    sampling: str = setting(
        "box",
        "how a sensor pixel reads the image: 'box' integrates its area (a physical pixel); 'point' samples its "
        "centre bilinearly without antialiasing (the paper's published pipeline; fine structure aliases)",
        choices=("box", "point"),
    )
    color: str = setting("gray", "sensor colour: 'gray' (one channel) or 'rgb'", choices=("gray", "rgb"))
    noise: str = setting("gaussian", "noise model", choices=("gaussian", "poisson", "none"))
    snr_db: Optional[float] = setting(devices.SNR_DB, "SNR of the gaussian noise (null: no noise)", unit="dB", ge=-100, le=300)
    noise_level_gradient: bool = setting(
        False, "gaussian model: the noise level (set by the example's own variance through snr_db) passes gradient "
        "to the encoder, the exact derivative of the noisy reading; false: the level is a constant in the backward "
        "pass. Only learned encoders' training differs; the values, and fixed encoders, are the same either way",
    )
    photons: float = setting(1e4, "photons at the brightest pixel (poisson model)", gt=0)
    read_noise: float = setting(0.0, "read noise (poisson model)", unit="e-", ge=0)
    adc_bits: Optional[int] = setting(None, "ADC bit depth (null: no quantisation)", ge=1, le=32)

    @property
    def size(self) -> tuple[float, float]:
        """Physical sensor size (height, width), metres."""
        return (self.resolution[0] * self.pixel_pitch, self.resolution[1] * self.pixel_pitch)


@dataclass(frozen=True)
class Geometry:
    """Derived simulation geometry (read-only), from sensor + fidelity settings."""

    grid: tuple[int, int]
    spacing: tuple[float, float]
    embedding: tuple[int, int]

    @classmethod
    def of(cls, sensor: SensorConfig, fidelity: FidelityConfig, overrides: Mapping | None = None) -> "Geometry":
        grid = fidelity.resolved(overrides).grid
        h, w = sensor.size
        emb = tuple(int(e) for e in sensor.embedding)
        for axis, (e, g) in enumerate(zip(emb, grid)):
            if e > g:
                raise ConfigError(
                    f"sensor.embedding[{axis}]", e, f"must be <= the simulation grid {grid[axis]} (fidelity.grid)"
                )
        return cls(grid=grid, spacing=(h / grid[0], w / grid[1]), embedding=emb)
