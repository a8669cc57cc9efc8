"""Scene, sensor and fidelity settings shared by every encoder (SI units).

These three settings groups describe what every optical encoder images (the
scene), what it images onto (the sensor and its embedding) and how finely it
is simulated (fidelity). An encoder's own ``Config`` holds only what is
specific to it (its distance ``d2``, its mask, ...).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Iterator, Optional, Union

from . import devices
from .errors import ConfigError
from .settings import Settings, setting

__all__ = ["SceneConfig", "SensorConfig", "FidelityConfig", "FIDELITY_PRESETS", "Knobs", "Geometry"]


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
    photons: float = setting(1e4, "photons at the brightest pixel (poisson model)", gt=0)
    read_noise: float = setting(0.0, "read noise (poisson model)", unit="e-", ge=0)
    adc_bits: Optional[int] = setting(None, "ADC bit depth (null: no quantisation)", ge=1, le=32)

    @property
    def size(self) -> tuple[float, float]:
        """Physical sensor size (height, width), metres."""
        return (self.resolution[0] * self.pixel_pitch, self.resolution[1] * self.pixel_pitch)


#: Named fidelity presets: the one table of their values (docs list it).
FIDELITY_PRESETS: dict[str, dict] = {
    "reference": {"grid": (768, 1024), "dtype": "float64", "padding": 1.0, "psf_oversample": 1},
    "default": {"grid": devices.DEFAULT_GRID, "dtype": "float32", "padding": "auto", "psf_oversample": 1},
    "fast": {"grid": (192, 256), "dtype": "float32", "padding": "auto", "psf_oversample": 1},
}
#: The fidelity knobs, in the order :class:`Knobs` holds them.
KNOB_NAMES = ("grid", "dtype", "padding", "psf_oversample")
_DTYPES = ("float32", "float64")
_OVERSAMPLES = (1, 3, 5, 7)


def parse_padding(value: Any, name: str = "fidelity.padding") -> Union[str, float]:
    """``'auto'`` or a fraction ``>= 0`` of the grid (a float), from a string or a number.

    Raises:
        ConfigError: anything else, naming ``name``.
    """
    if isinstance(value, str) and value.strip() == "auto":
        return "auto"
    try:
        out = float(value)
    except (TypeError, ValueError):
        out = float("nan")
    if isinstance(value, bool) or not out >= 0 or out == float("inf"):
        raise ConfigError(name, value, "must be 'auto' or a fraction >= 0 of the grid (e.g. 0.5)")
    return out


@dataclass(frozen=True, eq=False)
class Knobs(Mapping):
    """The resolved fidelity knobs of one encoder: typed and read-only.

    What :meth:`FidelityConfig.resolved` returns and what an encoder reads as
    ``self.knobs`` (attributes: ``self.knobs.grid``; the mapping form
    ``self.knobs["grid"]`` is kept for older code). Equal to a dict with the
    same items; :meth:`to_dict` gives the JSON form.

    Attributes:
        grid: simulation grid (rows, columns) over the sensor area.
        dtype: ``"float32"`` or ``"float64"``, the optics' precision.
        padding: ``"auto"`` or a float, the zero padding per side as a
            fraction of the (field) grid. Never a string number.
        psf_oversample: odd int (1, 3, 5, 7): field samples per grid pixel
            and axis.
    """

    grid: tuple[int, int]
    dtype: str
    padding: Union[str, float]
    psf_oversample: int = 1

    def __post_init__(self) -> None:
        try:
            grid = tuple(int(n) for n in self.grid)
        except (TypeError, ValueError):
            grid = ()
        if len(grid) != 2 or min(grid) < 1 or any(float(n) != g for n, g in zip(self.grid, grid)):
            raise ConfigError("fidelity.grid", self.grid, "must be two integers >= 1 (rows, columns)")
        if self.dtype not in _DTYPES:
            raise ConfigError("fidelity.dtype", self.dtype, f"one of {', '.join(_DTYPES)}")
        s = self.psf_oversample
        if isinstance(s, bool) or not isinstance(s, int) or s not in _OVERSAMPLES:
            raise ConfigError("fidelity.psf_oversample", s, f"an odd integer, one of {', '.join(map(str, _OVERSAMPLES))}")
        object.__setattr__(self, "grid", grid)
        object.__setattr__(self, "padding", parse_padding(self.padding))

    # mapping view (read-only), for code written against the old dict
    def __getitem__(self, key: str) -> Any:
        if key not in KNOB_NAMES:
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(KNOB_NAMES)

    def __len__(self) -> int:
        return len(KNOB_NAMES)

    def __hash__(self) -> int:
        return hash(tuple(self.values()))

    def __repr__(self) -> str:
        return "Knobs(" + ", ".join(f"{k}={v!r}" for k, v in self.items()) + ")"

    def to_dict(self) -> dict[str, Any]:
        """Plain ``{knob: value}`` (JSON-ready: ``grid`` a list)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self.items()}

    def replace(self, **changes: Any) -> "Knobs":
        """A validated copy with some knobs changed."""
        return dataclasses.replace(self, **changes)

    def fidelity(self, preset: str = "default", tolerance: float | None = None) -> "FidelityConfig":
        """The :class:`FidelityConfig` that sets every knob explicitly to these values (``preset`` kept as a label)."""
        extra = {} if tolerance is None else {"tolerance": tolerance}
        return FidelityConfig(
            preset=preset, grid=self.grid, dtype=self.dtype, padding=str(self.padding),
            psf_oversample=self.psf_oversample, **extra,
        )


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
    tolerance: float = setting(0.01, "preset 'auto': largest relative embedding error against the converged truth (optoenc bench)", gt=0)
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
        if self.padding is not None:
            parse_padding(self.padding, "padding")
        #: An encoder's measured per-preset overrides (``OpticalEncoder.fidelity_presets``), set by
        #: :meth:`bind`; not a setting (not in ``to_dict``, equality or the docs).
        self._presets: Mapping[str, Mapping] = {}

    def bind(self, presets: Mapping[str, Mapping] | None) -> "FidelityConfig":
        """A copy whose :meth:`resolved` applies ``presets`` (an encoder's ``fidelity_presets``).

        Every encoder binds its own ``self.fidelity`` this way, so that
        ``encoder.fidelity.resolved() == encoder.knobs``.
        """
        out = dataclasses.replace(self)
        out._presets = dict(presets or {})
        return out

    def resolved(self, overrides: Mapping[str, Mapping] | None = None) -> Knobs:
        """The typed knobs after filling the nulls from the preset.

        Order, lowest first: the shared preset table
        (:data:`FIDELITY_PRESETS`), the encoder's measured per-preset values
        (``overrides``, default the presets this config was bound to by its
        encoder, see :meth:`bind`), then the knobs set explicitly.

        Raises:
            ConfigError: ``preset`` is ``auto`` (resolved per run by
                :func:`optoenc.autofidelity.resolve`).
        """
        if self.preset == "auto":
            raise ConfigError(
                "fidelity.preset", "auto", "is resolved for a run by `optoenc fit` (optoenc.autofidelity.resolve); "
                "an encoder needs a named preset or explicit knobs"
            )
        out = dict(FIDELITY_PRESETS[self.preset])
        out.update((self._presets if overrides is None else overrides).get(self.preset, {}))
        for name in KNOB_NAMES:
            v = getattr(self, name)
            if v is not None:
                out[name] = v
        return Knobs(**out)


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
