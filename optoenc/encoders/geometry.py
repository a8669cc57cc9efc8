"""Scene and sensor settings shared by every encoder (SI units), and the derived simulation geometry.

These settings groups describe what every optical encoder images (the
scene) and what it images onto (the sensor and its embedding); how finely it
is simulated (fidelity) is :mod:`optoenc.encoders.fidelity`, whose names this
module also exports as before. An encoder's own ``Config`` holds only what
is specific to it (its distance ``d2``, its mask, ...).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Optional

from .. import devices
from ..errors import ConfigError
from .fidelity import FIDELITY_PRESETS, KNOB_NAMES, FidelityConfig, Knobs, parse_padding
from ..settings import Settings, setting

#: The fidelity names are :mod:`optoenc.encoders.fidelity`'s, exported here too (their old home).
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
    color: str = setting(
        "gray",
        "sensor colour: 'gray' (one channel), 'rgb' (three ideal colour planes) or 'bayer' (an RGGB mosaic at the "
        "embedding's pixel pitch: one plane, each pixel behind one colour filter; docs/optics.md)",
        choices=("gray", "rgb", "bayer"),
    )
    exposure: str = setting(
        "scene",
        "'scene': the signal level is set per scene (the noise is relative to each example's own signal); "
        "'fixed': a fixed exposure, a scene of unit radiance through a fully open aperture gives `photons` "
        "photo-electrons at its brightest pixel and an element that blocks light gives proportionally fewer",
        choices=("scene", "fixed"),
    )
    noise: str = setting("gaussian", "noise model (exposure=fixed: poisson or none)", choices=("gaussian", "poisson", "none"))
    snr_db: Optional[float] = setting(devices.SNR_DB, "SNR of the gaussian noise (null: no noise)", unit="dB", ge=-100, le=300)
    photons: float = setting(
        1e4, "photo-electrons at the brightest pixel: of each scene (poisson model, exposure=scene), or of a "
        "unit-radiance scene through a fully open aperture (exposure=fixed)", gt=0,
    )
    read_noise: float = setting(0.0, "read noise (poisson model)", unit="e-", ge=0)
    full_well: Optional[float] = setting(
        None, "full-well capacity, exposure=fixed: readings are clipped there and the clipped fraction counted "
        "(null: no saturation)", unit="e-", gt=0,
    )
    adc_bits: Optional[int] = setting(
        None, "ADC bit depth (null: no quantisation); full scale: each example's maximum (exposure=scene), "
        "full_well or else photons (exposure=fixed)", ge=1, le=32,
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.exposure == "fixed" and self.noise == "gaussian":
            raise ConfigError(
                "sensor.noise", self.noise,
                "under sensor.exposure=fixed the noise is photon counting: 'poisson' (shot and read noise) or 'none'",
            )
        if self.full_well is not None and self.exposure != "fixed":
            raise ConfigError("sensor.full_well", self.full_well, "applies under sensor.exposure=fixed only (null otherwise)")

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
