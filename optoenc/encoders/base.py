"""`OpticalEncoder`: the abstract base every encoder (built-in or plugin) derives from.

An encoder holds its physical settings (``Config``, SI units) and parameters,
and supplies one thing: its intensity PSF on the simulation grid
(:meth:`OpticalEncoder.compute_psf`). The base class does the rest with the
shared imaging steps of :mod:`optoenc.encoders.imaging`: placing the scene in the
object plane (magnification ``d2 / d1``), convolving, integrating over the
sensor pixels and adding noise.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math
import weakref
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

import torch
from torch import nn

from .. import hardware, limits
from ..errors import ConfigError, DataError
from ..fidelity.knobs import FidelityConfig
from ..settings import Documented, Settings, setting
from . import banded, imaging
from .geometry import Geometry, SceneConfig, SensorConfig

__all__ = ["EncoderConfig", "OpticalEncoder"]

#: Up to this many operator entries the operator is always used; above it only while it is smaller than what
#: the fine-grid (FFT) path would allocate for the batch, and never above _HARD_MAX_OPERATOR_ENTRIES (1 GiB).
_MAX_OPERATOR_ENTRIES = 40_000_000
_HARD_MAX_OPERATOR_ENTRIES = 2**28
#: The fine-grid path convolves at most this many padded complex samples at once (~1 GiB); larger batches go
#: in chunks.
_DIRECT_CHUNK_SAMPLES = 2**26
#: Scene geometries whose correlation tensors are kept (oldest dropped first).
_MAX_GEOMETRIES = 4
#: :meth:`OpticalEncoder.support_region` builds the operator of the scenes' support when that costs less than
#: this fraction of the whole operator's multiply-adds (a margin for the slicing copies).
_REGION_GAIN = 0.8


@dataclass
class EncoderConfig(Settings):
    """Settings every encoder has: the encoder-to-sensor distance."""

    d2: float = setting(4e-3, "encoder-to-sensor distance d2", unit="m", gt=0)


def _coerce(cls: type, value: Any, section: str) -> Any:
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(value) - names)
        if unknown:
            raise ConfigError(f"{section}.{unknown[0]}", value[unknown[0]], f"unknown setting; known: {', '.join(sorted(names))}")
        try:
            return cls(**value)
        except ConfigError as err:
            raise err.with_prefix(section) from None
    raise ConfigError(section, value, f"must be a {cls.__name__} or a mapping")


def _as_intensity(scene: Any) -> torch.Tensor:
    """A floating-point ``(B, C, h, w)`` scene: integer images scaled by their dtype's maximum, non-finite refused."""
    if not isinstance(scene, torch.Tensor):
        raise ConfigError("scene", type(scene).__name__, "must be a torch.Tensor of shape (batch, channels, height, width)")
    if scene.dim() != 4:
        raise ConfigError("scene", tuple(scene.shape), "must be a (batch, channels, height, width) tensor")
    if scene.is_complex():
        raise ConfigError("scene", str(scene.dtype), "must be real intensities, not complex")
    if scene.dtype == torch.bool:
        return scene.to(torch.float32)
    if not scene.is_floating_point():
        return scene.to(torch.float32) / float(torch.iinfo(scene.dtype).max)
    # A NaN or infinity makes the sum non-finite (one cheap pass over a large canvas); only then is every
    # pixel looked at (finite values whose sum overflows are fine).
    if not bool(torch.isfinite(scene.detach().sum())) and not bool(torch.isfinite(scene.detach()).all()):
        bad = int((~torch.isfinite(scene.detach())).sum())
        raise DataError(f"scene: {bad} pixel(s) are NaN or infinite; intensities must be finite")
    return scene


def _drop_graph(encoder_ref, token, grad):
    """PSF hook: once a backward pass has gone through the cached PSF (identified by ``token``), forget it and
    its operator, whose graph that pass freed. Holds only a weak reference to the encoder and the token."""
    enc = encoder_ref()
    cache = None if enc is None else enc._psf_cache
    if cache is not None and cache[2] is token:
        enc.invalidate_psf()
    return grad


class OpticalEncoder(Documented, nn.Module, abc.ABC):
    """An optical encoder: scene ``(B, C, h, w)`` -> sensor embedding ``(B, C_out, a, b)``.

    Subclasses set ``name`` (the registry name), ``Config`` (a dataclass
    deriving from :class:`EncoderConfig`), the capability flags ``learnable``
    and ``linear``, and implement :meth:`compute_psf`.

    Args:
        config: the encoder's ``Config`` (or a mapping of its fields).
        scene: object size and distance (:class:`SceneConfig`).
        sensor: sensor, embedding size and noise (:class:`SensorConfig`).
        fidelity: simulation grid and precision (:class:`FidelityConfig`).
    """

    name: ClassVar[str] = ""
    Config: ClassVar[type] = EncoderConfig
    learnable: ClassVar[bool] = False
    linear: ClassVar[bool] = True
    #: Measured per-preset knob values for this encoder (e.g. a grid that
    #: avoids moire with its mask's pitch), over the shared preset table.
    fidelity_presets: ClassVar[dict[str, dict]] = {}
    #: :meth:`measure` builds the operator of the batch's nonzero pixels only, where cheaper
    #: (:meth:`support_region`; exact); False: always the whole scene's.
    support_regions: bool = True
    #: :meth:`operator` builds with the correlation tensors' zeros skipped where they are banded, and
    #: :meth:`measure` applies it to the rows of the scenes that are nonzero (:mod:`optoenc.encoders.banded`;
    #: exact); False: the dense products (the reference of ``optoenc bench steps --against banded``).
    banded_operators: bool = True
    #: The banded build may take the correlation tensors' rows in the order of their bands, in taller
    #: blocks (:class:`optoenc.encoders.banded.BandPlan`, ``sort_rows``; exact); False: consecutive rows
    #: only (the reference of ``optoenc bench steps --against sorted``).
    sorted_band_rows: bool = True
    #: The sorted build's operator is held canvas row by canvas row and applied so, without copies
    #: (:func:`optoenc.encoders.imaging.scene_operator`, ``row_major``; exact); False: copied into the
    #: contiguous ``(C, a, b, h, w)`` layout (the reference of ``optoenc bench steps --against rows``).
    row_major_operators: bool = True
    #: A bfloat16 operator on a CPU whose matrix units multiply bfloat16 (AMX) is built by dense products
    #: in the layout one product applies (:func:`optoenc.encoders.imaging.scene_operator`, ``matrix_units``;
    #: the same sums up to their order); False: the banded build (the reference of ``optoenc bench steps
    #: --against matrix_units``).
    matrix_unit_operators: bool = True

    def lr_scales(self) -> dict[str, float]:
        """Learning rate of named parameters relative to ``trainer.encoder_lr`` (others: 1).

        Adam moves every parameter by about its learning rate each step, whatever the size of its
        gradient (while that stays above Adam's ``eps``, 1e-8): a scalar such as a log-distance needs a
        smaller one than a mask's logits.
        """
        return {}

    def constrain_(self) -> None:
        """Bring constrained parameters back into their domain after an optimiser step (projected gradient);
        the trainer calls it after every step. Default: nothing to do."""

    def __init__(
        self,
        config: Any = None,
        *,
        scene: SceneConfig | Mapping | None = None,
        sensor: SensorConfig | Mapping | None = None,
        fidelity: FidelityConfig | Mapping | None = None,
    ):
        super().__init__()
        self.config = _coerce(self.Config, config, "encoder")
        self.scene_config = _coerce(SceneConfig, scene, "scene")
        self.sensor = _coerce(SensorConfig, sensor, "sensor")
        #: Bound to this class's ``fidelity_presets``: ``self.fidelity.resolved() == self.knobs``.
        self.fidelity = _coerce(FidelityConfig, fidelity, "fidelity").bind(type(self).fidelity_presets)
        #: The resolved fidelity knobs (:class:`optoenc.fidelity.knobs.Knobs`: preset, this encoder's overrides, explicit knobs).
        self.knobs = self.fidelity.resolved()
        limits.check_simulation(self.knobs)  # before any array is made: a grid that cannot fit fails here
        self.geometry = Geometry.of(self.sensor, self.fidelity)
        self.optics_dtype = getattr(torch, self.knobs.dtype)
        #: Precision of the scene -> embedding operator's products (``fidelity.operator_dtype``).
        self.operator_dtype = self.optics_dtype if self.knobs.operator_dtype == "same" else getattr(torch, self.knobs.operator_dtype)
        self._check_object_size()
        #: ``(state key, PSF, token of its hook or None)``
        self._psf_cache: tuple[Any, torch.Tensor, object | None] | None = None
        self._op_cache: dict[Any, Any] = {}
        # Empty, not saved: follows ``.to(device)`` also where an encoder has no parameters or buffers (a fixed PSF),
        # so that :attr:`device` and the caches' keys know where the module is.
        self.register_buffer("_device_anchor", torch.zeros(0), persistent=False)

    # ----------------------------------------------------------------- to implement
    @abc.abstractmethod
    def compute_psf(self) -> torch.Tensor:
        """The un-normalised intensity PSF on the simulation grid.

        The channels must be on one power scale: channel ``c`` is the
        intensity at the sensor per unit source power at wavelength ``c``, so
        a colour filter that passes less light gives a dimmer channel (only
        the ratios matter; one shared factor is removed by :meth:`psf`). A
        PSF whose channels carry no such meaning (a measured file) is
        normalised per channel here with
        :func:`optoenc.encoders.imaging.normalize_channels`.

        Returns:
            ``(C, H, W)`` non-negative tensor in ``self.optics_dtype``, with
            ``(H, W) = self.geometry.grid``, the optical axis at
            ``(H // 2, W // 2)`` and ``C`` either 1 (achromatic) or 3 (R, G, B
            at :data:`optoenc.devices.WAVELENGTHS_RGB`).
        """

    # ----------------------------------------------------------------- optional hook
    def mask(self) -> torch.Tensor | None:
        """The optical element's transmittance, for pictures; ``None`` (the default): no mask picture.

        Override it to have ``optoenc psf`` and every run save a mask picture
        next to the PSF: a real ``(H, W)`` or ``(3, H, W)`` amplitude in
        ``[0, 1]`` (drawn as gray or RGB), or a complex transmittance (drawn
        as a phase map). :class:`~optoenc.encoders.mask.MaskEncoder`
        propagates what it returns.
        """
        return None

    # ----------------------------------------------------------------- geometry
    @property
    def d2(self) -> float:
        """Encoder-to-sensor distance, metres."""
        return float(self.config.d2)

    @property
    def magnification(self) -> float:
        """|M| = d2 / d1 (the image is also inverted)."""
        return self.d2 / self.scene_config.distance

    def object_height_px(self, height: float | None = None) -> float:
        """Height on the grid, in grid pixels, of an object of ``height`` metres (default: the scene's)."""
        h = self.scene_config.object_height if height is None else height
        return h * self.magnification / self.geometry.spacing[0]

    #: Largest ratio of the scene's image height to the simulated field of view: beyond it less than
    #: 1/10 of the scene reaches the sensor and a classifier can only guess.
    MAX_OVERFILL = 10.0

    def _check_object_size(self, height: float | None = None) -> None:
        """Refuse a geometry whose scene image is mostly off the sensor (a tiny object is a point source: allowed)."""
        px = self.object_height_px(height)
        H = self.geometry.grid[0]
        if px <= self.MAX_OVERFILL * H:
            return
        h = self.scene_config.object_height if height is None else height
        size = f"the {h * 1e3:.3g} mm scene to {h * self.magnification * 1e3:.3g} mm on the {self.sensor.size[0] * 1e3:.3g} mm sensor"
        why = "less than 1/10 of it reaches the sensor"
        raise ConfigError(
            "encoder.d2", self.d2,
            f"images {size} (|M| = d2 / scene.distance = {self.magnification:.3g}): {why}; "
            "check encoder.d2, scene.distance and scene.object_height",
        )

    @property
    def subcells(self) -> int:
        """Scene sub-sampling per grid pixel and axis in the operator (``fidelity.psf_oversample``, odd)."""
        return self.knobs.psf_oversample

    @property
    def pixel_aspect(self) -> float:
        """Grid pixel height / width (the scene keeps its physical aspect ratio)."""
        return self.geometry.spacing[0] / self.geometry.spacing[1]

    @property
    def channels(self) -> int:
        """Output channels: 1 for a gray sensor, 3 for RGB."""
        return 1 if self.sensor.color == "gray" else 3

    @property
    def output_shape(self) -> tuple[int, int, int]:
        """``(C, a, b)`` of one embedding."""
        return (self.channels, *self.geometry.embedding)

    # ----------------------------------------------------------------- PSF
    @property
    def device(self) -> torch.device:
        """Where the module is (``.to(device)`` moves it): its PSF and operators are built and returned there."""
        return self._device_anchor.device

    def _state_key(self) -> tuple:
        # The device: an empty buffer's data_ptr is 0 wherever it lives, and a fixed encoder may hold no other.
        return (torch.is_grad_enabled() and self.training, str(self.device)) + tuple(
            (p._version, p.data_ptr()) for p in self.parameters()
        ) + tuple((b._version, b.data_ptr()) for b in self.buffers())

    def invalidate_psf(self) -> None:
        """Forget the cached PSF and the operator built from it: the next :meth:`psf` recomputes them."""
        self._psf_cache = None
        self._op_cache.pop("op", None)

    def psf(self) -> torch.Tensor:
        """Normalised intensity PSF as the sensor sees it: ``(channels, H, W)``.

        The spectral channels of :meth:`compute_psf` keep their relative
        power (one normalisation shared by all channels,
        :func:`optoenc.encoders.imaging.normalize_psf`): a gray sensor sees
        ``sum_c w_c PSF_c`` with :data:`optoenc.devices.GRAYSCALE_WEIGHTS`,
        summing to one; an RGB sensor sees the channels, whose weighted sums
        add to one. The PSF is recomputed only when a parameter changes (once
        per optimiser step when learning).
        """
        key = self._state_key()
        if self._psf_cache is not None and self._psf_cache[0] == key:
            return self._psf_cache[1]
        raw = self.compute_psf().to(self.device)  # a no-op where compute_psf built it on the parameters' device
        if raw.dim() != 3 or raw.shape[0] not in (1, 3) or tuple(raw.shape[1:]) != self.geometry.grid:
            raise RuntimeError(
                f"{type(self).__name__}.compute_psf returned shape {tuple(raw.shape)}; "
                f"expected (1 or 3, {self.geometry.grid[0]}, {self.geometry.grid[1]})"
            )
        psf = imaging.sensor_psf(raw, self.channels, name=f"encoder {self.name}")
        token = None
        if psf.requires_grad:  # a backward pass frees the graph behind it: the next forward rebuilds it
            token = object()  # the hook holds neither the PSF nor the encoder: no reference cycle keeps a graph
            psf.register_hook(functools.partial(_drop_graph, weakref.ref(self), token))
        self._psf_cache = (key, psf, token)
        return psf

    # ----------------------------------------------------------------- imaging
    def _geometry_factors(self, scene_shape: tuple[int, int], height_px: float, device, dense: bool = False):
        """``(ry, rx, spans)``: the correlation tensors and their row spans (:func:`banded.row_spans`), cached.

        ``dense``: instead, their :func:`imaging.dense_factors` (the matrix-unit build's), made on first use and
        cached in the same entry.
        """
        key = ("corr", scene_shape, round(height_px, 9), self.operator_dtype, str(device), self.sensor.sampling)
        if key not in self._op_cache:
            H, W = self.geometry.grid
            a, b = self.geometry.embedding
            s = self.subcells
            # s > 1: the scene is placed and integrated on an s-times finer grid while the
            # PSF's grid values are cell averages: the scene keeps its sub-pixel structure.
            py, px = imaging.placement_matrices(scene_shape, (H * s, W * s), height_px * s, pixel_aspect=self.pixel_aspect)
            sampling = self.sensor.sampling
            ry = imaging.correlation_tensor(imaging.sampling_matrix(H * s, a, sampling), py, H, sub=s)
            rx = imaging.correlation_tensor(imaging.sampling_matrix(W * s, b, sampling), px, W, sub=s)
            # Bounded: a learned d2 changes the height every step.
            stale = [k for k in self._op_cache if k[0] == "corr"]
            for k in stale[: max(0, len(stale) - _MAX_GEOMETRIES + 1)]:
                del self._op_cache[k]
            ry, rx = ry.to(device, self.operator_dtype), rx.to(device, self.operator_dtype)
            # Where each flattened row's nonzero entries lie: the banded build's plan (imaging.scene_operator).
            spans = tuple(banded.row_spans(r.reshape(-1, r.shape[-1])) for r in (ry, rx))
            # ry held as (h, a, Hp), its (a, h, Hp) view: the sorted build reads it in canvas-row order
            # without a copy, also cut to a region's rows (imaging.scene_operator).
            ry = ry.transpose(0, 1).contiguous().transpose(0, 1)
            self._op_cache[key] = [ry, rx, spans, None]  # None: the dense factors, made on first use
        entry = self._op_cache[key]
        if not dense:
            return tuple(entry[:3])
        if entry[3] is None:
            entry[3] = imaging.dense_factors(entry[0], entry[1])
        return entry[3]

    def _uses_matrix_units(self, device) -> bool:
        """Whether :meth:`operator` builds by dense products for the CPU's matrix units (:attr:`matrix_unit_operators`):
        a bfloat16 operator on a CPU with them (the one place this is decided; ``scene_operator`` does as told)."""
        return (self.matrix_unit_operators and self.operator_dtype == torch.bfloat16 and torch.device(device).type == "cpu"
                and hardware.matrix_units())

    @staticmethod
    def _region_spans(spans, scene_shape, region):
        """The row spans of the correlation tensors cut to the scene ``region`` (None: all of them)."""
        if region is None:
            return spans
        r0, r1, c0, c1 = region
        h, w = scene_shape

        def cut(pair, n, i0, i1):  # the rows (embedding row, scene row i0..i1) of a flattened (out, n) tensor
            return tuple(t.reshape(-1, n)[:, i0:i1].reshape(-1) for t in pair)

        return cut(spans[0], h, r0, r1), cut(spans[1], w, c0, c1)

    def operator(self, scene_shape: tuple[int, int], height: float | None = None,
                 region: tuple[int, int, int, int] | None = None) -> torch.Tensor:
        """The ``(C, a, b, h, w)`` matrix from scene pixels to embedding pixels (noise-free).

        Exact for a piecewise-constant scene: it equals place -> convolve ->
        integrate on the simulation grid (see :mod:`optoenc.encoders.imaging`).
        Built and held in ``self.operator_dtype`` (``fidelity.operator_dtype``).
        The banded build may return it as a view held canvas row by canvas row
        (:func:`optoenc.encoders.imaging.scene_operator`, :attr:`row_major_operators`):
        ``.reshape`` or ``.contiguous()`` copies it where a flat matrix is needed.

        Args:
            region: ``(r0, r1, c0, c1)``: only the columns of scene pixels
                ``[r0, r1) x [c0, c1)`` of the ``scene_shape`` scene, a
                ``(C, a, b, r1 - r0, c1 - c0)`` operator (not cached), equal
                to ``operator(scene_shape)[..., r0:r1, c0:c1]`` for a fraction
                of its cost. None: the whole scene (cached until a parameter
                changes).
        """
        psf = self.psf()
        height_px = self.object_height_px(height)
        ry, rx, spans = self._geometry_factors(tuple(scene_shape), height_px, psf.device)
        spans = self._region_spans(spans, tuple(scene_shape), region) if self.banded_operators else False
        units = self._uses_matrix_units(psf.device)
        if region is not None:
            r0, r1, c0, c1 = region
            return imaging.scene_operator(psf.to(self.operator_dtype), ry[:, r0:r1], rx[:, c0:c1], spans, self.sorted_band_rows,
                                          self.row_major_operators, units)
        key = ("op", tuple(scene_shape), height, self._state_key())
        cached = self._op_cache.get("op")
        if cached is not None and cached[0] == key:
            return cached[1]
        factors = self._geometry_factors(tuple(scene_shape), height_px, psf.device, dense=True) if units else None
        op = imaging.scene_operator(psf.to(self.operator_dtype), ry, rx, spans, self.sorted_band_rows, self.row_major_operators,
                                    units, factors)
        self._op_cache["op"] = (key, op)
        return op

    def support_region(self, scene: torch.Tensor, height: float | None = None) -> tuple[int, int, int, int] | None:
        """The region :meth:`measure` builds its operator for: the batch's nonzero pixels, or None (all).

        Zero pixels contribute nothing, so the operator restricted to the
        bounding box of the pixels that are nonzero in any scene of the batch
        gives the same embeddings (and gradients) as the whole operator. It is
        used where it costs fewer multiply-adds than the whole one: building
        ``(a, h, Hp)`` correlations into a PSF costs ``C a h Hp Wp + C a b h w Wp``
        and applying it ``B C a b h w``; the whole operator is free to build
        while it is cached (a fixed PSF), never while a learned PSF changes every
        step. On an augmentation canvas (the field of view, ~20 times a digit)
        a rotated or rescaled digit covers a few percent of the pixels.
        :attr:`support_regions` False: always None (the reference of ``optoenc bench steps``).
        """
        if not self.support_regions:
            return None
        h, w = scene.shape[-2:]
        flat = scene.detach().flatten(0, -3)
        on = (flat.amax(0) > 0) | (flat.amin(0) < 0)  # (h, w); two reductions: 7x cheaper than ne().any()
        rows, cols = on.any(1).nonzero(), on.any(0).nonzero()
        if len(rows) == 0:
            return (0, 1, 0, 1)  # all dark: any single pixel gives the zero embedding
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        return self._cheaper_region(len(scene), (h, w), height, (r0, r1, c0, c1))

    def _cheaper_region(self, batch: int, shape: tuple[int, int], height, region) -> tuple[int, int, int, int] | None:
        """``region`` where its operator costs fewer multiply-adds than the whole scene's, else None."""
        (h, w), (r0, r1, c0, c1) = shape, region
        if (r1 - r0, c1 - c0) == (h, w):
            return None
        C, (a, b), (Hp, Wp) = self.channels, self.geometry.embedding, self.geometry.grid
        build = lambda n, m: C * a * n * Hp * Wp + C * a * b * n * m * Wp  # noqa: E731
        apply = lambda n, m: batch * C * a * b * n * m  # noqa: E731
        cached = self._op_cache.get("op")
        whole_cached = cached is not None and cached[0] == ("op", (h, w), height, self._state_key())
        whole = (0 if whole_cached else build(h, w)) + apply(h, w)
        part = build(r1 - r0, c1 - c0) + apply(r1 - r0, c1 - c0)
        return (r0, r1, c0, c1) if part < _REGION_GAIN * whole else None

    def _padded_samples(self) -> int:
        """Complex samples per image and channel of the fine-grid path's zero-padded convolution (about)."""
        return 4 * self.geometry.grid[0] * self.geometry.grid[1] * self.subcells**2

    def auto_method(self, batch: int, scene_shape: tuple[int, int]) -> str:
        """``measure``'s ``"auto"`` choice for ``batch`` scenes of ``scene_shape`` pixels.

        The operator (one matrix product per batch) up to :data:`_MAX_OPERATOR_ENTRIES` entries, and
        beyond while it takes less memory than the fine-grid path would for the batch (a wide
        augmentation canvas on a fine grid: the FFT path needed ~20 GB per 1000 scenes); the
        fine-grid path above 1 GiB of operator.
        """
        a, b = self.geometry.embedding
        entries = self.channels * a * b * scene_shape[0] * scene_shape[1]
        # A batch's tail (fewer scenes) makes the same choice as its siblings: counted as at least 64 scenes.
        direct = max(batch, 64) * self.channels * self._padded_samples()
        if entries <= _MAX_OPERATOR_ENTRIES or entries <= min(direct, _HARD_MAX_OPERATOR_ENTRIES):
            return "operator"
        return "direct"

    def measure(self, scene: torch.Tensor, height: float | None = None, method: str = "auto") -> torch.Tensor:
        """Noise-free embedding of ``(B, C, h, w)`` scenes of physical height ``height`` metres.

        Args:
            scene: non-negative, finite intensities; ``C`` is 1 or the
                sensor's channels. Integer images are fixed-point intensities
                in ``[0, max]`` of their dtype and are divided by that maximum
                (``uint8``: 255, so 255 is full scale 1.0); ``bool`` is 0 / 1.
            height: physical height of the scene image, a finite number > 0
                (default ``scene.object_height``).
            method: ``"operator"`` (precomputed scene->embedding matrix),
                ``"direct"`` (place, FFT-convolve and integrate on the grid)
                or ``"auto"`` (operator unless it would be too large). The
                operator's products run in ``fidelity.operator_dtype``; the
                rest keeps ``fidelity.dtype``, also under a mixed-precision
                trainer (autocast is off in here).

        Returns:
            ``(B, channels, a, b)`` in the scene's dtype (``float32`` for integer or bool scenes).

        Raises:
            DataError: NaN or infinite pixels. ConfigError: a bad shape or ``height``.
        """
        scene = _as_intensity(scene)
        self._check_height(height)
        if method == "auto":
            method = self.auto_method(len(scene), tuple(scene.shape[-2:]))
        with torch.autocast(scene.device.type, enabled=False):  # the optics keep their own precisions
            out = self._measure(scene, height, method)
        return out.to(scene.dtype)

    def _check_height(self, height) -> None:
        if height is not None:
            if isinstance(height, bool) or not isinstance(height, (int, float)) or not math.isfinite(height) or height <= 0:
                raise ConfigError("height", height, "must be a finite number > 0 m (the scene's physical height)")
            self._check_object_size(height)

    def measure_window(self, windows: torch.Tensor, corner: tuple[int, int], scene_shape: tuple[int, int],
                       height: float | None = None) -> torch.Tensor:
        """Noise-free embeddings of ``scene_shape`` scenes that are zero outside one window, given its pixels.

        ``windows`` ``(B, C, h, w)`` are the scenes' pixels ``[r0, r0 + h) x [c0, c0 + w)``, ``corner =
        (r0, c0)``; every other pixel is zero. The same as :meth:`measure` of the whole scenes, without
        building them: the operator of the window alone where that is cheaper (:meth:`support_region`).
        """
        r0, c0 = (int(v) for v in corner)
        h, w = windows.shape[-2:]
        H, W = (int(v) for v in scene_shape)
        if r0 < 0 or c0 < 0 or r0 + h > H or c0 + w > W:
            raise ConfigError("window", (r0, c0, h, w), f"must lie within the {H} x {W} scene")
        x = _as_intensity(windows)

        def laid(dtype, whole: bool) -> torch.Tensor:
            v = self._in_optics(x, dtype)
            if not whole:
                return v.to(dtype)
            scenes = x.new_zeros(*x.shape[:2], H, W, dtype=dtype)
            scenes[..., r0 : r0 + h, c0 : c0 + w] = v
            return scenes

        return self._measure_laid(x, (r0, r0 + h, c0, c0 + w), (H, W), height, laid)

    def measure_pasted(self, windows: torch.Tensor, offsets: torch.Tensor, part: tuple[int, int, int, int],
                       scene_shape: tuple[int, int], height: float | None = None) -> torch.Tensor:
        """Noise-free embeddings of ``scene_shape`` scenes that are zero but for one window each.

        ``windows`` ``(B, C, h, w)``: example ``b``'s pixels from ``offsets[b]`` (row, column; ``(B, 2)``
        integers) on; every window lies in ``part = (r0, r1, c0, c1)``. The same numbers as
        :meth:`measure_window` of the windows pasted on ``part`` (the operator of ``part`` alone where that is
        cheaper), without that intermediate: the windows are pasted where the operator reads them, in its
        precision (a shifted digit's window is ~5 % of Table 3's canvas).
        """
        r0, r1, c0, c1 = (int(v) for v in part)
        h, w = windows.shape[-2:]
        H, W = (int(v) for v in scene_shape)
        offsets = offsets.to(windows.device, torch.long)
        lo, hi = offsets.amin(0).tolist(), (offsets.amax(0) + torch.tensor([h, w], device=offsets.device)).tolist()
        if r0 < 0 or c0 < 0 or r1 > H or c1 > W or lo[0] < r0 or lo[1] < c0 or hi[0] > r1 or hi[1] > c1:
            raise ConfigError("windows", (tuple(lo), tuple(hi)),
                              f"must lie within the part {(r0, r1, c0, c1)} of the {H} x {W} scene")
        x = _as_intensity(windows)

        def laid(dtype, whole: bool) -> torch.Tensor:
            v = self._in_optics(x, dtype).to(dtype)
            if whole:
                return imaging.paste(v, offsets, (H, W))
            return imaging.paste(v, offsets - torch.tensor([r0, c0], device=offsets.device), (r1 - r0, c1 - c0))

        return self._measure_laid(x, (r0, r1, c0, c1), (H, W), height, laid)

    def _in_optics(self, x: torch.Tensor, dtype) -> torch.Tensor:
        """``x`` rounded through the optics' precision on its way to ``dtype``, as :meth:`measure` rounds it; as it
        is where it is already in either (a bfloat16 window from autocast: the same values)."""
        return x if x.dtype in (self.optics_dtype, dtype) else x.to(self.optics_dtype)

    def _measure_laid(self, x: torch.Tensor, region: tuple[int, int, int, int], scene_shape: tuple[int, int],
                      height, laid) -> torch.Tensor:
        """:meth:`measure_window`'s and :meth:`measure_pasted`'s embeddings of scenes zero outside ``region``:
        ``laid(dtype, whole)`` lays out their pixels in ``dtype``, over ``region`` or (``whole``) the whole scene."""
        self._check_height(height)
        H, W = scene_shape
        if self.support_regions and self.auto_method(len(x), (H, W)) == "operator":
            with torch.autocast(x.device.type, enabled=False):  # the optics keep their own precisions
                if self._cheaper_region(len(x), (H, W), height, region) == region:
                    op = self.operator((H, W), height, region)
                    scenes = laid(op.dtype, False)
                else:
                    # The whole scene's operator: the region holds every nonzero pixel and is no cheaper, so no
                    # part of it is looked for (measure's support_region: a scan of the whole canvas), and the
                    # scenes are laid out in the operator's precision at once (a float padding and its conversion:
                    # ~4 ms of Table 3's 24x32 shift step on one core).
                    op = self.operator((H, W), height)
                    scenes = laid(op.dtype, True)
                out = imaging.apply_operator(op, scenes, self.banded_operators).to(self.optics_dtype)
            return out.to(x.dtype)
        return self.measure(laid(x.dtype, True), height)

    def _measure(self, scene: torch.Tensor, height: float | None, method: str) -> torch.Tensor:
        a, b = self.geometry.embedding
        x = scene.to(self.optics_dtype)
        if method == "operator":
            region = self.support_region(x, height)
            op = self.operator(scene.shape[-2:], height, region)
            if region is not None:
                r0, r1, c0, c1 = region
                x = x[..., r0:r1, c0:c1]
            out = imaging.apply_operator(op, x.to(op.dtype), self.banded_operators).to(self.optics_dtype)
        elif method == "direct":
            s = self.subcells  # the same sub-pixel scene geometry as the operator
            grid = tuple(n * s for n in self.geometry.grid)
            psf = imaging.subcell_psf(self.psf(), s)
            step = max(1, _DIRECT_CHUNK_SAMPLES // (self.channels * self._padded_samples()))
            out = torch.cat([
                imaging.integrate(imaging.fft_convolve(
                    imaging.place(x[i : i + step], grid, self.object_height_px(height) * s, pixel_aspect=self.pixel_aspect),
                    psf[None]), (a, b), self.sensor.sampling)
                for i in range(0, len(x), step)])
        else:
            raise ConfigError("method", method, "one of 'auto', 'operator', 'direct'")
        return out

    def add_sensor_noise(self, clean: torch.Tensor, generator: torch.Generator | None = None,
                         sigma: torch.Tensor | None = None, noise: torch.Tensor | None = None) -> torch.Tensor:
        """Sensor noise (zero-mean, after integration) and optional ADC quantisation.

        ``sigma``: the Gaussian noise's per-example standard deviation where the caller has it
        (:meth:`noise_sigma` of the same clean embeddings); ``noise``: its standard-normal draws where the
        caller drew them (given only with ``sigma``); see :func:`~optoenc.encoders.imaging.add_noise`.
        """
        s = self.sensor
        out = imaging.add_noise(clean, s.snr_db, s.noise, s.photons, s.read_noise, generator, sigma, noise,
                                level_gradient=s.noise_level_gradient)
        if s.adc_bits is not None:
            out = imaging.quantize(out, s.adc_bits)
        return out

    def noise_sigma(self, clean: torch.Tensor) -> torch.Tensor | None:
        """The per-example standard deviation :meth:`add_sensor_noise` gives ``clean`` (None: not Gaussian noise).

        Row for row the same numbers as computed batch by batch (each example's variance is its own
        reduction): a fixed encoder's embeddings can have theirs computed once, not every epoch. None too
        where a subclass brings its own :meth:`add_sensor_noise` (its noise is its own business).
        """
        s = self.sensor
        if s.noise != "gaussian" or s.snr_db is None or type(self).add_sensor_noise is not OpticalEncoder.add_sensor_noise:
            return None
        return imaging.snr_sigma(clean.detach(), s.snr_db)

    def forward(self, scene: torch.Tensor, height: float | None = None, noise: bool = True) -> torch.Tensor:
        """Sensor embedding of ``(B, C, h, w)`` scenes, noise included unless ``noise=False``."""
        clean = self.measure(scene, height)
        return self.add_sensor_noise(clean) if noise else clean

    # ----------------------------------------------------------------- description

    def extra_repr(self) -> str:
        return f"name={self.name!r}, config={self.config}"
