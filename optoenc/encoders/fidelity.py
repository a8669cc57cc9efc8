"""Fidelity: how finely the optics are simulated, as one typed, frozen value.

:class:`FidelityConfig` is the ``fidelity`` settings section (a named preset
plus explicit knobs); :meth:`FidelityConfig.resolved` turns it into
:class:`Knobs`, the frozen typed setting every encoder reads as
``self.knobs.<knob>``. :data:`FIDELITY_PRESETS` is the one table of the
presets' values; an encoder's measured per-preset values are its
``fidelity_presets``. ``auto`` (the cheapest measured setting within a
tolerance) is resolved per run by :mod:`optoenc.bench.auto`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Iterator, Optional, Union

from .. import devices, hardware
from ..errors import ConfigError
from ..settings import Settings, setting

__all__ = ["FidelityConfig", "FIDELITY_PRESETS", "KNOB_NAMES", "Knobs", "parse_padding"]


#: Named fidelity presets: the one table of their values (docs list it).
FIDELITY_PRESETS: dict[str, dict] = {
    "reference": {"grid": (768, 1024), "dtype": "float64", "padding": 1.0, "psf_oversample": 1, "propagation": "blas"},
    "default": {"grid": devices.DEFAULT_GRID, "dtype": "float32", "padding": "auto", "psf_oversample": 1,
                "propagation": "separable"},
    "fast": {"grid": (192, 256), "dtype": "float32", "padding": "auto", "psf_oversample": 1, "propagation": "separable"},
}
#: The fidelity knobs, in the order :class:`Knobs` holds them.
KNOB_NAMES = ("grid", "dtype", "padding", "psf_oversample", "operator_dtype", "propagation")
_DTYPES = ("float32", "float64")
#: Precisions of the scene -> embedding operator's products: the optics' own, or bfloat16 (float32 accumulation).
_OPERATOR_DTYPES = ("same", "float32", "float64", "bfloat16")
_OVERSAMPLES = (1, 3, 5, 7)
#: How a mask's field reaches the sensor: the 2-D band-limited angular spectrum, or axis by axis where the mask is
#: cells on a lattice and the dropped cross terms are negligible (:mod:`optoenc.optics.separable`).
_PROPAGATIONS = ("blas", "separable")


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
        operator_dtype: precision of the scene -> embedding operator
            (building it from the PSF and applying it to scenes): ``"same"``
            (``dtype``), ``"float32"``, ``"float64"`` or ``"bfloat16"``
            (8 significant bits, float32 accumulation: faster matrix
            products on CPUs with AMX or AVX512-BF16, at a relative
            embedding error of about 0.2 %; the errors and speed-ups are
            measured by ``optoenc bench precision``). The PSF itself is
            always computed in ``dtype``.
        propagation: ``"blas"`` (the 2-D band-limited angular spectrum) or
            ``"separable"``: a mask of cells on a lattice (the LCD encoders)
            propagated axis by axis as two small matrix products, where the
            factorisation drops at most 0.01 rad
            (:data:`optoenc.encoders.mask.SEPARABLE_MAX_PHASE`); other masks,
            and a learned ``d2``, use ``"blas"``.
    """

    grid: tuple[int, int]
    dtype: str
    padding: Union[str, float]
    psf_oversample: int = 1
    operator_dtype: str = "same"
    propagation: str = "blas"

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
        if self.operator_dtype not in _OPERATOR_DTYPES:
            raise ConfigError("fidelity.operator_dtype", self.operator_dtype, f"one of {', '.join(_OPERATOR_DTYPES)}")
        if self.propagation not in _PROPAGATIONS:
            raise ConfigError("fidelity.propagation", self.propagation, f"one of {', '.join(_PROPAGATIONS)}")
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
            psf_oversample=self.psf_oversample, operator_dtype=self.operator_dtype, propagation=self.propagation,
            **extra,
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
    operator_dtype: Optional[str] = setting(
        None,
        "precision of the scene->embedding operator's matrix products ('same': the optics' dtype; 'bfloat16': "
        "relative embedding error about 0.2 %, below the 1 % of 40 dB sensor noise, and a faster step where the "
        "operator dominates on CPUs with AMX or AVX512-BF16 (elsewhere emulated and 4-10x slower: a warning); "
        "'auto': 'bfloat16' where native, else 'same'; its gradient error is measured per encoder by `optoenc "
        "bench precision`); the PSF keeps `dtype`",
        choices=(*_OPERATOR_DTYPES, "auto"),
    )
    propagation: Optional[str] = setting(
        None,
        "'blas': the 2-D band-limited angular spectrum; 'separable': a mask of cells on a lattice (the LCD "
        "encoders) propagated axis by axis as two small matrix products where the dropped cross terms stay under "
        "0.01 rad (the paper's LCD: 3.5e-3 rad, PSF within 1.0e-5 of 'blas'); other masks and a learned d2 use 'blas'",
        choices=_PROPAGATIONS,
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
                :func:`optoenc.bench.auto.resolve`).
        """
        if self.preset == "auto":
            raise ConfigError(
                "fidelity.preset", "auto", "is resolved for a run by `optoenc fit` (optoenc.bench.auto.resolve); "
                "an encoder needs a named preset or explicit knobs"
            )
        out = dict(FIDELITY_PRESETS[self.preset])
        out.update((self._presets if overrides is None else overrides).get(self.preset, {}))
        for name in KNOB_NAMES:
            v = getattr(self, name)
            if v is not None:
                out[name] = v
        # 'auto': bfloat16 where this machine multiplies it natively (an explicit bfloat16 warns where emulated)
        out["operator_dtype"] = hardware.operator_dtype(out.get("operator_dtype", "same"))
        return Knobs(**out)
