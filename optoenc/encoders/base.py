"""`OpticalEncoder`: the abstract base every encoder (built-in or plugin) derives from.

An encoder holds its physical settings (``Config``, SI units) and parameters,
and supplies one thing: its intensity PSF on the simulation grid
(:meth:`OpticalEncoder.compute_psf`). The base class does the rest: the PSF as
the sensor sees it, the scene -> embedding map (placing the scene in the
object plane with magnification ``d2 / d1``, convolving, integrating over the
sensor pixels: :class:`~optoenc.encoders.operator.SceneOperator`) and the
sensor's noise (:mod:`optoenc.encoders.noise`).

In your own training loop::

    enc = optoenc.build_encoder("learned_slm")
    y = enc(x)                      # (B, 1, h, w) intensities >= 0 -> noisy (B, C, a, b) embeddings
    y0 = enc(x, noise=False)        # the same without noise: enc.measure(x)
    loss(decoder(y), labels).backward(); optimiser.step()
    enc.constrain_()                # after every optimiser step (the projected parameterisation needs it)
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

from .. import limits
from ..errors import ConfigError, DataError
from .fidelity import FidelityConfig
from ..settings import Documented, Settings, coerce, setting
from . import imaging
from .geometry import Geometry, SceneConfig, SensorConfig
from .noise import add_noise, photon_noise, quantize, snr_sigma
from . import sensor as colour_sensor
from ._operator_cache import OperatorCache
from .operator import SceneOperator

__all__ = ["EncoderConfig", "OpticalEncoder"]

#: The precisions an encoder's optics compute in (``fidelity.dtype``; ``.to(dtype)`` changes it).
_OPTICS_DTYPES = (torch.float32, torch.float64)


@dataclass
class EncoderConfig(Settings):
    """Settings every encoder has: the encoder-to-sensor distance."""

    d2: float = setting(4e-3, "encoder-to-sensor distance d2", unit="m", gt=0)


def _as_intensity(scene: Any) -> torch.Tensor:
    """A floating-point ``(B, C, h, w)`` scene: integer images scaled by their dtype's maximum; non-finite or negative
    pixels refused."""
    if not isinstance(scene, torch.Tensor):
        raise ConfigError("scene", type(scene).__name__, "must be a torch.Tensor of shape (batch, channels, height, width)")
    if scene.dim() != 4:
        raise ConfigError("scene", tuple(scene.shape), "must be a (batch, channels, height, width) tensor")
    if scene.is_complex():
        raise ConfigError("scene", str(scene.dtype), "must be real intensities, not complex")
    if scene.dtype == torch.bool:
        return scene.to(torch.float32)
    if not scene.is_floating_point():
        scene = scene.to(torch.float32) / float(torch.iinfo(scene.dtype).max)
    if scene.numel() == 0:
        return scene
    # One pass for both checks: a NaN makes both extremes NaN, an infinity one of them infinite; only then is
    # every pixel looked at.
    lo, hi = (float(v) for v in torch.aminmax(scene.detach()))
    if not (math.isfinite(lo) and math.isfinite(hi)):
        bad = int((~torch.isfinite(scene.detach())).sum())
        raise DataError(f"scene: {bad} pixel(s) are NaN or infinite; intensities must be finite")
    if lo < 0:
        raise DataError(f"scene minimum = {lo:.6g}: must be >= 0 (intensities)")
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

    What a library user calls:

    * :meth:`forward` (``enc(x)``): noisy embeddings; ``enc(x, noise=False)`` is :meth:`measure`;
    * :meth:`measure`: noise-free embeddings of non-negative intensities (``C`` 1 or the sensor's channels);
    * :meth:`psf`: the normalised PSF the sensor sees, ``(channels, H, W)`` (times the throughput under
      ``sensor.exposure=fixed``);
    * :meth:`throughput`: the light collected relative to a fully open aperture of the same size;
    * :meth:`operator`: the scene -> embedding map as a :class:`~optoenc.encoders.operator.SceneOperator`
      (apply, the ``(C, a, b, h, w)`` tensor, the float64 matrix and its adjoint);
    * :meth:`constrain_`: after every optimiser step (a projected mask is clamped back into ``[0, 1]``);
    * :meth:`mask`: the element for pictures (a mask encoder's
      :meth:`~optoenc.encoders.mask.MaskEncoder.field_mask` is the field grid's; the LCDs'
      ``displayed_amplitudes()`` their sub-pixels' amplitudes whatever the parameterisation);
    * ``.to(device)``, ``.to(torch.float64)`` / ``.double()``: parameters, buffers and optics together.

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

    def lr_scales(self) -> dict[str, float]:
        """Learning rate of named parameters relative to ``trainer.encoder_lr`` (others: 1).

        Adam moves every parameter by about its learning rate each step, whatever the size of its
        gradient (while that stays above Adam's ``eps``, 1e-8): a scalar such as a log-distance needs a
        smaller one than a mask's logits.
        """
        return {}

    def constrain_(self) -> None:
        """Bring constrained parameters back into their domain after an optimiser step (projected gradient).

        The trainer calls it after every step; in your own loop call it after each ``optimiser.step()``.
        Default: nothing to do."""

    def __init__(
        self,
        config: Any = None,
        *,
        scene: SceneConfig | Mapping | None = None,
        sensor: SensorConfig | Mapping | None = None,
        fidelity: FidelityConfig | Mapping | None = None,
    ):
        super().__init__()
        self.config = coerce(self.Config, config, "encoder")
        self.scene_config = coerce(SceneConfig, scene, "scene")
        self.sensor = coerce(SensorConfig, sensor, "sensor")
        #: Bound to this class's ``fidelity_presets``: ``self.fidelity.resolved() == self.knobs``.
        self.fidelity = coerce(FidelityConfig, fidelity, "fidelity").bind(type(self).fidelity_presets)
        #: The resolved fidelity knobs (:class:`optoenc.encoders.fidelity.Knobs`: preset, this encoder's overrides, explicit knobs).
        self.knobs = self.fidelity.resolved()
        limits.check_simulation(self.knobs)  # before any array is made: a grid that cannot fit fails here
        self.geometry = Geometry.of(self.sensor, self.fidelity)
        self.optics_dtype = getattr(torch, self.knobs.dtype)
        #: Precision of the scene -> embedding operator's products (``fidelity.operator_dtype``).
        self.operator_dtype = self.optics_dtype if self.knobs.operator_dtype == "same" else getattr(torch, self.knobs.operator_dtype)
        self._check_object_size()
        #: ``(state key, PSF, token of its hook or None)``
        self._psf_cache: tuple[Any, torch.Tensor, object | None] | None = None
        #: The scene operator's caches and choice of algorithm (:mod:`optoenc.encoders.operator`).
        self._operators = OperatorCache()
        # Empty, not saved, in the optics' precision: follows ``.to(device)`` and ``.to(dtype)`` also where an
        # encoder has no parameters or buffers (a fixed PSF), so that :attr:`device`, the caches' keys and
        # :meth:`_apply` know where the module is and what precision it is asked for.
        self.register_buffer("_device_anchor", torch.zeros(0, dtype=self.optics_dtype), persistent=False)

    # ----------------------------------------------------------------- to implement
    @abc.abstractmethod
    def compute_psf(self) -> torch.Tensor:
        """The un-normalised intensity PSF on the simulation grid.

        The channels must be on one power scale: channel ``c`` is the
        intensity at the sensor per unit source power at wavelength ``c``, so
        a colour filter that passes less light gives a dimmer channel (under
        ``sensor.exposure=scene`` only the ratios matter: one shared factor is
        removed by :meth:`psf`; under ``fixed`` its power relative to
        :meth:`open_power` is the :meth:`throughput`). A
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

    def open_power(self) -> float | None:
        """The spectrally weighted total of :meth:`compute_psf` for the fully open aperture of the same size.

        With it the PSF's power is absolute: :meth:`throughput` is the PSF's total over it. ``None`` (the
        default): :meth:`compute_psf` has no absolute scale (a measured PSF, a plugin's), and the element is
        taken as fully transmissive (throughput 1). :class:`~optoenc.encoders.mask.MaskEncoder` computes it.
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
        """Colour planes the sensor's PSF and operator have: 1 for a gray sensor, 3 for RGB and Bayer."""
        return 1 if self.sensor.color == "gray" else 3

    @property
    def output_shape(self) -> tuple[int, int, int]:
        """``(C, a, b)`` of one embedding: 1 channel for a gray or Bayer (mosaic) sensor, 3 for RGB."""
        return (1 if self.sensor.color == "bayer" else self.channels, *self.geometry.embedding)

    # ----------------------------------------------------------------- device and precision
    @property
    def device(self) -> torch.device:
        """Where the module is (``.to(device)`` moves it): its PSF and operators are built and returned there."""
        return self._device_anchor.device

    def _apply(self, fn, recurse=True):
        """``.to(device)``, ``.to(dtype)``, ``.double()``, ``.float()``: parameters, buffers and the optics together.

        A floating-point precision moves the optics too: ``self.optics_dtype`` (``fidelity.dtype``, the PSF and the
        measurement) becomes it, and so does the operator's where ``fidelity.operator_dtype`` is ``"same"`` (an
        explicit operator precision, e.g. bfloat16, is kept); the cached PSF and operators are dropped.

        Raises:
            ConfigError: a precision the optics cannot compute in (float16, bfloat16): float32 or float64.
        """
        anchor = getattr(self, "_device_anchor", None)
        target = None if anchor is None else fn(anchor).dtype  # what this conversion makes of a float tensor
        if target is not None and target != self.optics_dtype and target not in _OPTICS_DTYPES:
            raise ConfigError("encoder dtype", str(target).replace("torch.", ""),
                              "the optics compute in float32 or float64 (fidelity.dtype); "
                              "the operator alone may run in bfloat16 (fidelity.operator_dtype)")
        out = super()._apply(fn, recurse)
        if target is not None and target != self.optics_dtype:
            self._set_optics_dtype(target)
        return out

    def _set_optics_dtype(self, dtype: torch.dtype) -> None:
        name = str(dtype).replace("torch.", "")
        self.fidelity = dataclasses.replace(self.fidelity, dtype=name).bind(type(self).fidelity_presets)
        self.knobs = self.knobs.replace(dtype=name)
        self.optics_dtype = dtype
        if self.knobs.operator_dtype == "same":
            self.operator_dtype = dtype
        self.invalidate_psf()
        self._operators.clear()

    # ----------------------------------------------------------------- PSF
    def _state_key(self) -> tuple:
        # The device: an empty buffer's data_ptr is 0 wherever it lives, and a fixed encoder may hold no other.
        return (torch.is_grad_enabled() and self.training, str(self.device)) + tuple(
            (p._version, p.data_ptr()) for p in self.parameters()
        ) + tuple((b._version, b.data_ptr()) for b in self.buffers())

    def invalidate_psf(self) -> None:
        """Forget the cached PSF and the operator built from it: the next :meth:`psf` recomputes them."""
        self._psf_cache = None
        self._operators.forget_operator()

    def psf(self) -> torch.Tensor:
        """Normalised intensity PSF as the sensor sees it: ``(channels, H, W)``.

        The spectral channels of :meth:`compute_psf` keep their relative
        power (one normalisation shared by all channels,
        :func:`optoenc.encoders.imaging.normalize_psf`): a gray sensor sees
        ``sum_c w_c PSF_c`` with :data:`optoenc.devices.GRAYSCALE_WEIGHTS`,
        summing to one; an RGB (or Bayer) sensor sees the channels, whose weighted sums
        add to one. Under ``sensor.exposure=fixed`` it is then multiplied by
        the :meth:`throughput` (its absolute power). The PSF is recomputed only when a parameter changes (once
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
        if self.sensor.exposure == "fixed":  # the absolute power: the normalised PSF times the throughput
            psf = psf * self._throughput_of(raw)
        token = None
        if psf.requires_grad:  # a backward pass frees the graph behind it: the next forward rebuilds it
            token = object()  # the hook holds neither the PSF nor the encoder: no reference cycle keeps a graph
            psf.register_hook(functools.partial(_drop_graph, weakref.ref(self), token))
        self._psf_cache = (key, psf, token)
        return psf

    def _throughput_of(self, raw: torch.Tensor) -> torch.Tensor:
        open_power = self.open_power()
        if open_power is None:
            return torch.ones((), dtype=raw.dtype, device=raw.device)
        return imaging.psf_power(raw) / open_power

    def throughput(self) -> float:
        """Light collected, relative to a fully open aperture of the same size (1: all of it).

        The spectrally weighted power of :meth:`compute_psf` (:func:`~optoenc.encoders.imaging.psf_power`,
        the sensor's :data:`~optoenc.devices.GRAYSCALE_WEIGHTS`) over :meth:`open_power`: what every colour
        filter, sub-pixel and opaque part lets through to the sensor. 1 where the PSF has no absolute scale.
        Under ``sensor.exposure=fixed`` :meth:`psf` carries this factor.
        """
        with torch.no_grad():
            return float(self._throughput_of(self.compute_psf().to(self.device)))

    # ----------------------------------------------------------------- imaging
    def operator(self, scene_shape: tuple[int, int], height: float | None = None, scene_channels: int = 1) -> SceneOperator:
        """The scene -> embedding map for ``(h, w)`` scenes of physical height ``height`` metres.

        A :class:`~optoenc.encoders.operator.SceneOperator` that follows this encoder's parameters:
        ``op(x)`` measures as :meth:`measure` does, ``op.tensor()`` is the ``(C, a, b, h, w)`` matrix
        (differentiable, in ``fidelity.operator_dtype``), ``op.dense()`` / ``op.adjoint(y)`` / ``op.gram()``
        the float64 linear algebra for reconstruction.

        Args:
            scene_shape: ``(h, w)`` scene pixels.
            height: physical height of the scene image, a finite number > 0 (default ``scene.object_height``).
            scene_channels: 1 (a gray scene seen by every sensor channel) or the sensor's channels.

        Raises:
            ConfigError: a bad ``height`` or ``scene_channels``.
        """
        return SceneOperator(self, scene_shape, height, scene_channels)

    def _checked_scene(self, scene: Any) -> torch.Tensor:
        """``scene`` as floating-point intensities (:func:`_as_intensity`) with channels the sensor takes: an
        R, G, B scene on a gray sensor becomes its luminance (:func:`optoenc.encoders.sensor.to_luminance`)."""
        x = _as_intensity(scene)
        if x.shape[1] == 3 and self.channels == 1:
            return colour_sensor.to_luminance(x)
        if x.shape[1] not in (1, 3):
            raise ConfigError("scene channels", x.shape[1],
                              "must be 1 (gray) or 3 (R, G, B), whatever the sensor (sensor.color)")
        return x

    def _read_out(self, planes: torch.Tensor) -> torch.Tensor:
        """What the sensor reads of its colour planes: the planes, or a Bayer sensor's mosaic of them."""
        return colour_sensor.mosaic(planes) if self.sensor.color == "bayer" else planes

    def measure(self, scene: torch.Tensor, height: float | None = None, method: str = "auto") -> torch.Tensor:
        """Noise-free embedding of ``(B, C, h, w)`` scenes of physical height ``height`` metres.

        Args:
            scene: non-negative, finite intensities; ``C`` is 1 or the
                sensor's channels. Integer images are fixed-point intensities
                in ``[0, max]`` of their dtype and are divided by that maximum
                (``uint8``: 255, so 255 is full scale 1.0); ``bool`` is 0 / 1.
            height: physical height of the scene image, a finite number > 0
                (default ``scene.object_height``).
            method: ``"operator"`` (the scene -> embedding matrix, :meth:`operator`),
                ``"direct"`` (place, FFT-convolve and integrate on the grid)
                or ``"auto"`` (operator unless it would be too large). The
                operator's products run in ``fidelity.operator_dtype``; the
                rest keeps ``fidelity.dtype``, also under a mixed-precision
                trainer (autocast is off in here).

        Returns:
            ``(B, channels, a, b)`` in the scene's dtype (``float32`` for integer or bool scenes).

        Raises:
            DataError: NaN, infinite or negative pixels. ConfigError: a bad shape, channel count or ``height``.
        """
        scene = self._checked_scene(scene)
        self._check_height(height)
        with torch.autocast(scene.device.type, enabled=False):  # the optics keep their own precisions
            out = self._read_out(self._operators.measure(self, scene, height, method))
        return out.to(scene.dtype)

    def _check_height(self, height) -> None:
        if height is not None:
            if isinstance(height, bool) or not isinstance(height, (int, float)) or not math.isfinite(height) or height <= 0:
                raise ConfigError("height", height, "must be a finite number > 0 m (the scene's physical height)")
            self._check_object_size(height)

    def add_sensor_noise(self, clean: torch.Tensor, generator: torch.Generator | None = None,
                         sigma: torch.Tensor | None = None, noise: torch.Tensor | None = None) -> torch.Tensor:
        """Sensor noise (zero-mean, after integration) and optional ADC quantisation.

        ``sigma``: the Gaussian noise's per-example standard deviation where the caller has it
        (:meth:`noise_sigma` of the same clean embeddings); ``noise``: its standard-normal draws where the
        caller drew them (given only with ``sigma``); see :func:`~optoenc.encoders.noise.add_noise`.
        """
        s = self.sensor
        if s.exposure == "fixed":  # photo-electrons at a fixed exposure (optoenc.encoders.noise.photon_noise)
            out, clipped = photon_noise(clean, s.photons, s.read_noise, s.full_well, s.adc_bits,
                                        shot=s.noise == "poisson", generator=generator) if s.noise == "poisson" else photon_noise(
                clean, s.photons, 0.0, s.full_well, s.adc_bits, shot=False)
            #: Fraction of the last noisy batch's pixels clipped at the full well (a detached 0-d tensor).
            self.clipped_fraction = clipped
            count = getattr(self, "_clip_count", None)
            n = clean.numel()
            self._clip_count = (clipped * n, n) if count is None else (count[0] + clipped * n, count[1] + n)
            return out
        out = add_noise(clean, s.snr_db, s.noise, s.photons, s.read_noise, generator, sigma, noise)
        if s.adc_bits is not None:
            out = quantize(out, s.adc_bits)
        return out

    def saturated_fraction(self) -> float | None:
        """Fraction of all pixels read with noise under ``sensor.exposure=fixed`` since the encoder was built that
        were clipped at the full well (``sensor.full_well``); None where none were read so."""
        count = getattr(self, "_clip_count", None)
        return None if count is None or count[1] == 0 else float(count[0]) / count[1]

    def noise_sigma(self, clean: torch.Tensor) -> torch.Tensor | None:
        """The per-example standard deviation :meth:`add_sensor_noise` gives ``clean`` (None: not Gaussian noise).

        Row for row the same numbers as computed batch by batch (each example's variance is its own
        reduction): a fixed encoder's embeddings can have theirs computed once, not every epoch. None too
        where a subclass brings its own :meth:`add_sensor_noise` (its noise is its own business).
        """
        s = self.sensor
        if s.noise != "gaussian" or s.snr_db is None or type(self).add_sensor_noise is not OpticalEncoder.add_sensor_noise:
            return None
        return snr_sigma(clean.detach(), s.snr_db)

    def forward(self, scene: torch.Tensor, height: float | None = None, noise: bool = True) -> torch.Tensor:
        """Sensor embeddings ``(B, channels, a, b)`` of ``(B, C, h, w)`` scenes: :meth:`measure`, then
        :meth:`add_sensor_noise` unless ``noise=False`` (drawn from the global generator)."""
        clean = self.measure(scene, height)
        return self.add_sensor_noise(clean) if noise else clean

    # ----------------------------------------------------------------- description

    def extra_repr(self) -> str:
        return f"name={self.name!r}, config={self.config}"
