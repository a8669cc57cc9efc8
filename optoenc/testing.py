"""Conformance kits: the checks every registered encoder, decoder, dataset, augmentation and task passes.

One kit per plugin kind (:data:`KITS`): ``encoder``, ``decoder``, ``dataset``,
``augmentation``, ``task``. optoenc runs every kit over every registered name
(``tests/test_conformance.py``), and plugin authors reuse them for their own
classes, either as plain functions::

    from optoenc.testing import check_encoder, check_decoder, check_dataset
    check_encoder(MyEncoder, fidelity={"grid": (48, 64)}, sensor={"embedding": (6, 8)})
    check_decoder(MyDecoder)
    check_dataset(MyDataset, config={"size": 100})

or as a pytest base class whose ``test_<check>`` methods are generated from
the kit's list of checks::

    from optoenc.testing import EncoderConformance

    class TestMyEncoder(EncoderConformance):
        encoder_cls = MyEncoder
        setup = {"fidelity": {"grid": (48, 64)}}

(``DecoderConformance`` / ``decoder_cls``, ``DatasetConformance`` /
``dataset_cls``, ``AugmentationConformance`` / ``augmentation_cls``, ``TaskConformance`` / ``task_cls`` alike.)

Every check takes the class plus an optional small ``setup`` (its keys per
kit: :attr:`Kit.setup_keys`) and raises ``AssertionError`` naming the class
and what is wrong. A check returns ``None`` when it ran, or a string saying
why it does not apply (e.g. linearity for an encoder whose ``linear`` flag is
false). Numerical comparisons use one table, :data:`TOLERANCES`. Checks use
tiny grids and scenes so that a whole kit runs in seconds.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import re
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Mapping

__all__ = [
    "TOLERANCES",
    "SMALL_SETUP",
    "TINY_SETUP",
    "SCENE_SHAPE",
    "DECODER_SHAPES",
    "Kit",
    "KITS",
    "CHECKS",
    "ENCODER_CHECKS",
    "DECODER_CHECKS",
    "DATASET_CHECKS",
    "AUGMENTATION_CHECKS",
    "make_encoder",
    "make_decoder",
    "scenes",
    "check_documented",
    "check_config_roundtrip",
    "check_output_shape",
    "check_dtype",
    "check_determinism",
    "check_nonnegative",
    "check_psf",
    "check_exposure",
    "check_presets",
    "check_cache_key",
    "check_linearity",
    "check_gradients",
    "check_gradcheck",
    "check_state_dict",
    "check_device",
    "check_encoder",
    "check_decoder",
    "check_dataset",
    "check_augmentation",
    "EncoderConformance",
    "DecoderConformance",
    "DatasetConformance",
    "AugmentationConformance",
    "TaskConformance",
    "check_task",
]

#: The one tolerance table of the kits: relative to the largest magnitude compared, unless noted.
TOLERANCES: dict[str, float] = {
    # float32 round-off of sums over the kits' small grids (eps 6e-8 x ~100 terms, with margin)
    "float32": 1e-5,
    # float64 round-off, same reasoning (eps 1e-16)
    "float64": 1e-10,
    # PSF normalisation: a float32 PSF of ~3,000 pixels summed in float64
    "psf_sum": 1e-4,
    # f(a x + b y) vs a f(x) + b f(y) in float32 through the scene operator (~1,000-term sums)
    "linearity": 1e-4,
    # float32 vs float64 optics on a 48 x 64 grid: the float32 FFT propagation's round-off
    "dtype": 1e-3,
    # CUDA vs CPU float32: different FFT and BLAS kernels
    "device": 1e-4,
    # decoder standardisation's affine invariance in float32 (a x + b through (x - m) / s)
    "standardize": 1e-4,
    # float64 gradcheck: finite-difference step and its absolute / relative tolerances
    "gradcheck_eps": 1e-6,
    "gradcheck_atol": 1e-7,
    "gradcheck_rtol": 1e-5,
}

#: Default small setup: a 48 x 64 simulation grid and a 6 x 8 embedding.
SMALL_SETUP: dict[str, Any] = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}
#: The float64 gradcheck setup: a 12 x 16 grid and a 3 x 4 embedding on a 0.37 x 0.50 mm sensor (240 x 320
#: pixels), so that every built-in's scene image spans more than one grid pixel (31 um).
TINY_SETUP: dict[str, Any] = {
    "fidelity": {"grid": (12, 16), "dtype": "float64"},
    "sensor": {"embedding": (3, 4), "resolution": (240, 320)},
}
#: Scene size (rows, columns) used by the checks; not square, to catch transposes.
SCENE_SHAPE = (8, 6)
_SETUP_KEYS = ("config", "scene", "sensor", "fidelity")


# --------------------------------------------------------------------------- helpers
def _as_dict(value: Any) -> dict:
    if value is None:
        return {}
    if dataclasses.is_dataclass(value):
        return {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return dict(value)
    raise TypeError(f"setup sections must be mappings or settings dataclasses, got {type(value).__name__}")


def _merge(base: Mapping[str, Any], setup: Mapping[str, Any]) -> dict[str, dict]:
    unknown = sorted(set(setup) - set(_SETUP_KEYS))
    if unknown:
        raise TypeError(f"unknown setup key(s) {unknown}; allowed: {', '.join(_SETUP_KEYS)}")
    return {k: {**_as_dict(base.get(k)), **_as_dict(setup.get(k))} for k in _SETUP_KEYS}


def _label(cls: type, kind: str = "encoder") -> str:
    return f"{kind} {getattr(cls, 'name', '') or cls.__name__!r} ({cls.__module__}.{cls.__qualname__})"


def make_encoder(cls: type, *, base: Mapping[str, Any] = SMALL_SETUP, **setup: Any):
    """Instantiate ``cls`` with ``setup`` (``config``, ``scene``, ``sensor``, ``fidelity``) merged over ``base``."""
    s = _merge(base, setup)
    return cls(s["config"] or None, scene=s["scene"], sensor=s["sensor"], fidelity=s["fidelity"])


def scenes(n: int = 2, channels: int = 1, shape: tuple[int, int] = SCENE_SHAPE, dtype=None, seed: int = 0):
    """``(n, channels, *shape)`` non-negative random scenes, drawn from a private generator."""
    import torch

    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, channels, *shape, generator=g, dtype=dtype or torch.float32)


def _close(a, b, rel: float, what: str, cls: type, kind: str = "encoder") -> None:
    import torch

    scale = max(float(b.detach().abs().max()), 1e-30)
    err = float((a.detach() - b.detach()).abs().max())
    label = _label(cls, kind)
    assert err <= rel * scale, f"{label}: {what}: max |difference| {err:.3g} > {rel:g} x max |value| {scale:.3g}"
    assert torch.isfinite(a.detach()).all(), f"{label}: {what}: non-finite values"


def _tol(dtype) -> float:
    import torch

    return TOLERANCES["float64"] if dtype == torch.float64 else TOLERANCES["float32"]


def _check(fn: Callable[..., str | None]) -> Callable[..., str | None]:
    """Run a check with sampling warnings silenced: the checks' grids are tiny on purpose."""

    @functools.wraps(fn)
    def wrapper(cls: type, **setup: Any) -> str | None:
        from .optics.diagnostics import SamplingWarning

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SamplingWarning)
            return fn(cls, **setup)

    return wrapper


# --------------------------------------------------------------------------- checks
def _documented(cls: type, kind: str, base: type, config_base: type, flags: tuple[str, ...] = ()) -> None:
    """``name``, ``Config`` (help text on every field), flags and ``summary()`` of a plugin class of any kind."""
    label = _label(cls, kind)
    assert isinstance(cls, type) and issubclass(cls, base), f"{label}: must subclass {base.__module__}.{base.__qualname__}"
    name = getattr(cls, "name", "")
    assert isinstance(name, str) and re.match(r"^[a-z][a-z0-9_]*$", name), (
        f"{label}: class attribute `name` must be a lowercase identifier, got {name!r}"
    )
    assert not getattr(cls, "__abstractmethods__", None), (
        f"{label}: abstract methods not implemented: {sorted(cls.__abstractmethods__)}"
    )
    cfg = cls.Config
    assert dataclasses.is_dataclass(cfg) and issubclass(cfg, config_base), (
        f"{label}: `Config` must be a dataclass deriving from {config_base.__module__}.{config_base.__qualname__}, got {cfg!r}"
    )
    undocumented = [f.name for f in dataclasses.fields(cfg) if not str(f.metadata.get("help", "")).strip()]
    assert not undocumented, (
        f"{label}: Config fields without help text: {undocumented}; declare them with optoenc.setting(default, help, unit=...)"
    )
    for flag in flags:
        assert isinstance(getattr(cls, flag, None), bool), f"{label}: capability flag `{flag}` must be a bool"
    summary = cls.summary()
    assert isinstance(summary, str) and summary.strip(), f"{label}: needs a class docstring (its first line is the summary)"


def _config_roundtrip(cls: type, kind: str, values: Mapping[str, Any], build: Callable[[dict], Any]) -> None:
    """``Config -> to_dict -> Config(**dict)``, omegaconf YAML, and ``build(mapping).config`` give back an equal config."""
    from omegaconf import OmegaConf

    from .settings import to_dict

    label = _label(cls, kind)
    cfg = cls.Config(**values)

    def rebuild(data: dict) -> Any:
        data = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return cls.Config(**data)

    plain = to_dict(cfg)
    assert rebuild(plain) == cfg, f"{label}: Config(**to_dict(c)) != c: {plain}"
    schema = OmegaConf.structured(cls.Config)
    yaml = OmegaConf.to_yaml(OmegaConf.merge(schema, plain))
    loaded = OmegaConf.merge(schema, OmegaConf.create(yaml))
    back = rebuild(OmegaConf.to_container(loaded, resolve=True))
    assert back == cfg, f"{label}: Config through omegaconf YAML changed:\n{yaml}-> {back}"
    built = build(plain)
    assert built.config == cfg, f"{label}: building from a mapping of the config gave {built.config}, expected {cfg}"


@_check
def check_documented(cls: type, **setup: Any) -> str | None:
    """``name``, ``Config`` (help text on every field), capability flags and ``summary()`` are there."""
    from .encoders.base import EncoderConfig, OpticalEncoder

    _documented(cls, "encoder", OpticalEncoder, EncoderConfig, ("learnable", "linear"))
    return None


@_check
def check_config_roundtrip(cls: type, **setup: Any) -> str | None:
    """``Config -> to_dict -> Config(**dict)`` and omegaconf YAML give back an equal config."""
    s = _merge({}, setup)
    _config_roundtrip(cls, "encoder", s["config"], lambda plain: make_encoder(cls, **{**setup, "config": plain}))
    return None


@_check
def check_output_shape(cls: type, **setup: Any) -> str | None:
    """Output shape is ``(batch, *encoder.output_shape)``, for gray and RGB sensors."""
    label = _label(cls)
    enc = make_encoder(cls, **setup)
    a, b = enc.geometry.embedding
    assert enc.output_shape == (enc.channels, a, b), f"{label}: output_shape {enc.output_shape} != (channels, a, b)"
    for n in (1, 3):
        out = enc(scenes(n), noise=False)
        assert tuple(out.shape) == (n, *enc.output_shape), (
            f"{label}: output shape {tuple(out.shape)} for {n} scenes; expected {(n, *enc.output_shape)}"
        )
    rgb = make_encoder(cls, **{**setup, "sensor": {**_as_dict(setup.get("sensor")), "color": "rgb"}})
    for c in (1, 3):
        out = rgb(scenes(2, channels=c), noise=False)
        assert tuple(out.shape) == (2, 3, a, b), f"{label}: RGB sensor, {c}-channel scene: shape {tuple(out.shape)}"
    out = enc(scenes(2, channels=3), noise=False)  # an RGB scene on the gray sensor: its luminance
    assert tuple(out.shape) == (2, 1, a, b), f"{label}: gray sensor, 3-channel scene: shape {tuple(out.shape)}"
    bayer = make_encoder(cls, **{**setup, "sensor": {**_as_dict(setup.get("sensor")), "color": "bayer"}})
    out = bayer(scenes(2, channels=3), noise=False)
    assert bayer.output_shape == (1, a, b) and tuple(out.shape) == (2, 1, a, b), (
        f"{label}: Bayer sensor: shape {tuple(out.shape)}, expected (2, 1, {a}, {b})")
    return None


@_check
def check_dtype(cls: type, **setup: Any) -> str | None:
    """float32 in -> float32 out; with ``fidelity.dtype=float64`` the PSF and output are float64 and agree."""
    import torch

    label = _label(cls)
    enc32 = make_encoder(cls, **setup)
    x = scenes(2)
    out32 = enc32(x, noise=False)
    assert out32.dtype == torch.float32, f"{label}: float32 scene gave {out32.dtype}"
    fid = {**_as_dict(setup.get("fidelity")), "dtype": "float64"}
    enc64 = make_encoder(cls, **{**setup, "fidelity": fid})
    psf = enc64.psf()
    assert psf.dtype == torch.float64, f"{label}: fidelity.dtype=float64 but psf() is {psf.dtype}"
    out64 = enc64(x.double(), noise=False)
    assert out64.dtype == torch.float64, f"{label}: float64 scene at float64 fidelity gave {out64.dtype}"
    _close(out32.double(), out64, TOLERANCES["dtype"], "float32 and float64 outputs differ", cls)
    return None


@_check
def check_determinism(cls: type, **setup: Any) -> str | None:
    """Noise off: the same input gives identical outputs; noise on: the same torch seed gives identical draws."""
    import torch

    label = _label(cls)
    enc = make_encoder(cls, **setup)
    x = scenes(2)
    a, b = enc(x, noise=False), enc(x, noise=False)
    assert torch.equal(a, b), f"{label}: two noise-free passes differ (max {float((a - b).abs().max()):.3g})"
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(1234)
        n1 = enc(x, noise=True)
        torch.manual_seed(1234)
        n2 = enc(x, noise=True)
    assert torch.equal(n1, n2), f"{label}: noisy passes under the same torch seed differ"
    return None


@_check
def check_nonnegative(cls: type, **setup: Any) -> str | None:
    """A non-negative scene gives a non-negative, finite measurement (noise off)."""
    import torch

    label = _label(cls)
    enc = make_encoder(cls, **setup)
    out = enc(scenes(2), noise=False).detach()
    assert torch.isfinite(out).all(), f"{label}: non-finite output"
    floor = -_tol(out.dtype) * float(out.abs().max())
    assert float(out.min()) >= floor, f"{label}: negative intensity {float(out.min()):.3g} with noise off"
    assert float(out.max()) > 0, f"{label}: all-zero output for a bright scene"
    return None


def _assert_psf(enc, label: str) -> None:
    """The PSF contract: ``(channels, H, W)`` in the optics dtype, finite, non-negative, spectrally weighted sum 1."""
    import torch

    from .devices import GRAYSCALE_WEIGHTS

    psf = enc.psf()
    expected = (enc.channels, *enc.geometry.grid)
    assert tuple(psf.shape) == expected, f"{label}: psf() shape {tuple(psf.shape)}, expected {expected}"
    assert psf.dtype == enc.optics_dtype, f"{label}: psf() dtype {psf.dtype}, expected {enc.optics_dtype}"
    assert torch.isfinite(psf).all(), f"{label}: psf() has non-finite values"
    psf = psf.detach()
    floor = -_tol(psf.dtype) * float(psf.abs().max())
    assert float(psf.min()) >= floor, f"{label}: psf() has negative values ({float(psf.min()):.3g})"
    sums = psf.double().sum(dim=(-2, -1))
    rgb = enc.channels == 3
    total = float((torch.tensor(GRAYSCALE_WEIGHTS, dtype=torch.float64) * sums).sum()) if rgb else float(sums[0])
    assert abs(total - 1) <= TOLERANCES["psf_sum"], f"{label}: psf() channel sums {sums.tolist()} (weighted total {total}) != 1"


@_check
def check_psf(cls: type, **setup: Any) -> str | None:
    """``psf()`` is ``(channels, H, W)``, finite, non-negative; gray sums to 1, RGB's spectrally weighted sums add to 1."""
    for color in ("gray", "rgb"):
        enc = make_encoder(cls, **{**setup, "sensor": {**_as_dict(setup.get("sensor")), "color": color}})
        _assert_psf(enc, f"{_label(cls)} ({color} sensor)")
    return None


@_check
def check_exposure(cls: type, **setup: Any) -> str | None:
    """``throughput()`` is in ``(0, 1]``; under ``sensor.exposure=fixed`` the PSF is the default PSF times it, and
    a noisy reading (shot and read noise, full well, ADC) is finite."""
    import math

    import torch

    label = _label(cls)
    enc = make_encoder(cls, **setup)
    t = enc.throughput()
    assert math.isfinite(t) and 0 < t <= 1 + TOLERANCES["psf_sum"], f"{label}: throughput() = {t}, must be in (0, 1]"
    sensor = {**_as_dict(setup.get("sensor")), "exposure": "fixed", "noise": "poisson", "photons": 1e3,
              "read_noise": 2.0, "full_well": 5e2, "adc_bits": 10}
    fixed = make_encoder(cls, **{**setup, "sensor": sensor})
    with torch.no_grad():
        psf, ref = fixed.psf().double(), enc.psf().double() * t
        gap = float((psf - ref).abs().max()) / max(float(ref.abs().max()), 1e-300)
        assert gap <= _tol(fixed.psf().dtype), f"{label}: fixed-exposure psf() != psf() x throughput (gap {gap:.3g})"
        out = fixed(scenes(2, dtype=fixed.optics_dtype))
    assert torch.isfinite(out).all(), f"{label}: non-finite fixed-exposure reading"
    return None


@_check
def check_presets(cls: type, **setup: Any) -> str | None:
    """Every fidelity preset, ``reference`` included, on the setup's small grid: typed knobs with the encoder's
    own ``fidelity_presets`` applied, the PSF contract, and a finite embedding of the right shape (the setup's
    own preset, which every other check runs, only for its knobs)."""
    import torch

    from .encoders.fidelity import FIDELITY_PRESETS, KNOB_NAMES, Knobs

    own = _merge(SMALL_SETUP, setup)["fidelity"].get("preset") or "default"
    for preset in FIDELITY_PRESETS:
        fid = {**_as_dict(_merge(SMALL_SETUP, setup)["fidelity"]), "preset": preset}
        label = f"{_label(cls)} at fidelity.preset={preset}"
        try:
            enc = make_encoder(cls, **{**setup, "fidelity": fid})
            expected = {**FIDELITY_PRESETS[preset], **cls.fidelity_presets.get(preset, {})}
            expected.update({k: fid[k] for k in KNOB_NAMES if fid.get(k) is not None})
            assert enc.knobs == Knobs(**expected), f"{label}: knobs {enc.knobs}, expected {Knobs(**expected)}"
            assert enc.fidelity.resolved() == enc.knobs, f"{label}: fidelity.resolved() != knobs"
            if preset == own:
                continue
            _assert_psf(enc, label)
            with torch.no_grad():
                out = enc(scenes(2, dtype=enc.optics_dtype), noise=False)
        except AssertionError:
            raise
        except Exception as err:  # e.g. a knob passed on in the wrong type
            raise AssertionError(f"{label}: {type(err).__name__}: {str(err).splitlines()[0]}") from err
        assert tuple(out.shape) == (2, *enc.output_shape), f"{label}: output shape {tuple(out.shape)}"
        assert torch.isfinite(out).all(), f"{label}: non-finite output"
    return None


@_check
def check_cache_key(cls: type, **setup: Any) -> str | None:
    """The embedding cache key (:func:`optoenc.training.cache.embedding_key`) is the same for two encoders of one
    configuration and changes when the PSF changes with every setting kept (e.g. an edited helper function)."""
    import torch

    from .training.cache import embedding_key
    from .datasets.base import DatasetConfig

    label = _label(cls)

    def key(c: type) -> str:
        with torch.no_grad():
            return embedding_key(make_encoder(c, **setup), DatasetConfig(), "kit", scenes=scenes(2))

    k1 = key(cls)
    assert key(cls) == k1, f"{label}: two encoders of one configuration give different cache keys"

    def changed_psf(self):
        raw = cls.compute_psf(self)  # the same PSF plus a faint ramp: what an edited helper would do
        ramp = torch.linspace(0, 1, raw.shape[-1], dtype=raw.dtype, device=raw.device)
        return raw + 0.1 * raw.mean(dim=(-2, -1), keepdim=True) * ramp

    edited = type(cls.__name__, (cls,), {"compute_psf": changed_psf, "__module__": cls.__module__, "__doc__": cls.__doc__})
    assert key(edited) != k1, f"{label}: the cache key did not change when the PSF changed: stale embeddings would be reused"
    return None


@_check
def check_linearity(cls: type, **setup: Any) -> str | None:
    """For ``linear`` encoders: ``f(a x + b y) = a f(x) + b f(y)`` with noise off."""
    if not cls.linear:
        return "the encoder is not linear in the scene (linear = False)"
    enc = make_encoder(cls, **setup)
    x, y = scenes(2, seed=1), scenes(2, seed=2)
    lhs = enc(0.7 * x + 1.3 * y, noise=False)
    rhs = 0.7 * enc(x, noise=False) + 1.3 * enc(y, noise=False)
    _close(lhs, rhs, TOLERANCES["linearity"], "f(a x + b y) != a f(x) + b f(y)", cls)
    return None


@_check
def check_gradients(cls: type, **setup: Any) -> str | None:
    """Flags are honest: a ``learnable`` encoder's parameters all receive finite gradients (one non-zero);
    a fixed encoder has no trainable parameters."""
    import torch

    label = _label(cls)
    enc = make_encoder(cls, **setup)
    trainable = {n: p for n, p in enc.named_parameters() if p.requires_grad}
    if not cls.learnable:
        assert not trainable, (
            f"{label}: learnable = False but has trainable parameters {sorted(trainable)}; "
            "set learnable = True or register them with requires_grad=False / as buffers"
        )
        return None
    assert trainable, f"{label}: learnable = True but has no trainable parameters"
    out = enc(scenes(2), noise=False)
    weights = scenes(1, shape=tuple(out.shape[-2:]), dtype=out.dtype, seed=7).expand_as(out)
    (out * weights).sum().backward()  # a weighted loss: the plain sum may be invariant (normalised PSF)
    missing = sorted(n for n, p in trainable.items() if p.grad is None)
    assert not missing, f"{label}: no gradient reaches parameters {missing}"
    bad = sorted(n for n, p in trainable.items() if not torch.isfinite(p.grad).all())
    assert not bad, f"{label}: non-finite gradients in {bad}"
    assert any(float(p.grad.abs().max()) > 0 for p in trainable.values()), f"{label}: all parameter gradients are zero"
    return None


@_check
def check_gradcheck(cls: type, **setup: Any) -> str | None:
    """float64 ``torch.autograd.gradcheck`` w.r.t. the scene on a tiny grid and sensor (:data:`TINY_SETUP`)."""
    import torch

    if not cls.linear:
        return "gradcheck w.r.t. the scene runs for linear encoders (linear = False)"
    s = _merge({}, setup)
    tiny = {
        "config": s["config"],
        "scene": s["scene"],
        "sensor": {**s["sensor"], **TINY_SETUP["sensor"]},
        "fidelity": {**s["fidelity"], **TINY_SETUP["fidelity"]},
    }
    enc = make_encoder(cls, base={}, **tiny)
    x = scenes(1, shape=(4, 4), dtype=torch.float64).requires_grad_(True)
    try:
        ok = torch.autograd.gradcheck(
            lambda t: enc(t, noise=False), (x,), eps=TOLERANCES["gradcheck_eps"],
            atol=TOLERANCES["gradcheck_atol"], rtol=TOLERANCES["gradcheck_rtol"],
        )
    except Exception as err:  # gradcheck raises GradcheckError with the Jacobians
        raise AssertionError(f"{_label(cls)}: float64 gradcheck w.r.t. the scene failed: {err}") from err
    assert ok, f"{_label(cls)}: float64 gradcheck w.r.t. the scene failed"
    return None


@_check
def check_state_dict(cls: type, **setup: Any) -> str | None:
    """A fresh encoder loading another's ``state_dict`` gives the same output."""
    import torch

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(1)
        a = make_encoder(cls, **setup)
        torch.manual_seed(2)
        b = make_encoder(cls, **setup)
    b.load_state_dict(copy.deepcopy(a.state_dict()), strict=True)
    x = scenes(2)
    with torch.no_grad():
        ya, yb = a(x, noise=False), b(x, noise=False)
    assert torch.equal(ya, yb), f"{_label(cls)}: outputs differ after load_state_dict"
    return None


@_check
def check_device(cls: type, **setup: Any) -> str | None:
    """On CUDA (when available), ``encoder.to(device)`` runs there and matches the CPU result."""
    import torch

    if not torch.cuda.is_available():
        return "no CUDA device"
    label = _label(cls)
    enc = make_encoder(cls, **setup)
    x = scenes(2)
    with torch.no_grad():
        ref = enc(x, noise=False)
        enc = enc.to("cuda")
        try:
            out = enc(x.to("cuda"), noise=False)
        except RuntimeError as err:  # typically a tensor left on the CPU (a PSF not built on the parameters' device)
            raise AssertionError(f"{label}: forward on CUDA failed: {str(err).splitlines()[0]}") from err
    assert out.device.type == "cuda", f"{label}: CUDA scene gave output on {out.device}"
    _close(out.cpu(), ref, TOLERANCES["device"], "CUDA and CPU outputs differ", cls)
    return None


# --------------------------------------------------------------------------- kits
@dataclass(frozen=True)
class Kit:
    """A conformance kit: the named checks of one plugin kind.

    Attributes:
        kind: the plugin kind (``"encoder"``, ...).
        attribute: the class attribute its pytest base class reads (``"encoder_cls"``).
        checks: check name -> ``check(cls, **setup)``, in the order they run.
        setup_keys: the keys a ``setup`` may hold.
    """

    kind: str
    attribute: str
    checks: dict[str, Callable[..., str | None]]
    setup_keys: tuple[str, ...]

    def run(self, cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
        """Run every check (or those named in ``checks``) on ``cls``.

        Returns:
            Check name -> ``"ok"`` or ``"skipped: <reason>"``.

        Raises:
            KeyError: an unknown check name (the message lists the kit's).
            TypeError: an unknown setup key.
            AssertionError: the first failing check, with its name and the reason.
        """
        names = list(self.checks) if checks is None else list(checks)
        unknown = [n for n in names if n not in self.checks]
        if unknown:
            raise KeyError(f"unknown {self.kind} check(s) {unknown}; available: {', '.join(self.checks)}")
        bad = sorted(set(setup) - set(self.setup_keys))
        if bad:
            raise TypeError(f"unknown setup key(s) {bad} for the {self.kind} kit; allowed: {', '.join(self.setup_keys)}")
        report = {}
        for n in names:
            try:
                reason = self.checks[n](cls, **setup)
            except AssertionError as err:
                raise AssertionError(f"[{n}] {err}") from err
            report[n] = "ok" if reason is None else f"skipped: {reason}"
        return report

    def conformance_class(self, name: str) -> type:
        """A pytest base class with one ``test_<check>`` method per check, reading ``<attribute>`` and ``setup``."""

        def run(self_, check: str) -> None:
            import pytest

            cls = getattr(self_, self.attribute)
            if cls is None:
                pytest.skip(f"{self.attribute} is not set")
            reason = self.checks[check](cls, **dict(self_.setup))
            if reason is not None:
                pytest.skip(reason)

        def test(check: str) -> Callable:
            def method(self_) -> None:
                run(self_, check)

            method.__name__ = f"test_{check}"
            method.__doc__ = self.checks[check].__doc__
            return method

        namespace: dict[str, Any] = {
            "__doc__": f"pytest base class: set ``{self.attribute}`` (and optionally ``setup``); each {self.kind} check "
            f"is a test ({', '.join(self.checks)}).",
            "__module__": __name__,
            self.attribute: None,
            "setup": {},
            "kit": self,
        }
        namespace.update({f"test_{c}": test(c) for c in self.checks})
        return type(name, (), namespace)


#: Encoder check name -> function, in the order :func:`check_encoder` runs them.
ENCODER_CHECKS: dict[str, Callable[..., str | None]] = {
    "documented": check_documented,
    "config_roundtrip": check_config_roundtrip,
    "psf": check_psf,
    "exposure": check_exposure,
    "presets": check_presets,
    "output_shape": check_output_shape,
    "dtype": check_dtype,
    "determinism": check_determinism,
    "nonnegative": check_nonnegative,
    "linearity": check_linearity,
    "gradients": check_gradients,
    "gradcheck": check_gradcheck,
    "state_dict": check_state_dict,
    "cache_key": check_cache_key,
    "device": check_device,
}
#: The encoder checks under their historical name.
CHECKS = ENCODER_CHECKS


# --------------------------------------------------------------------------- decoders
#: Embedding shapes ``(C, a, b)`` the decoder kit tries: from 1 x 1 up, gray and RGB, non-square.
DECODER_SHAPES: tuple[tuple[int, int, int], ...] = ((1, 1, 1), (1, 1, 4), (3, 2, 3), (1, 6, 8), (3, 12, 16))
_DECODER_KEYS = ("config", "in_shapes", "num_classes")


def _decoder_setup(setup: Mapping[str, Any]) -> tuple[dict, tuple, int]:
    bad = sorted(set(setup) - set(_DECODER_KEYS))
    if bad:
        raise TypeError(f"unknown setup key(s) {bad}; allowed: {', '.join(_DECODER_KEYS)}")
    shapes = tuple(tuple(int(n) for n in s) for s in setup.get("in_shapes") or DECODER_SHAPES)
    return _as_dict(setup.get("config")), shapes, int(setup.get("num_classes", 10))


#: Output ``(S, h, w)`` of an image decoder in the kit (the scene of a reconstruction).
IMAGE_OUT_SHAPE = (1, 12, 12)


def _is_image(cls: type) -> bool:
    return getattr(cls, "output", "logits") == "image"


def _kit_encoder(in_shape):
    """A small fixed encoder whose output is ``in_shape`` (what a physics-informed decoder reads)."""
    from .config import build_encoder

    C, a, b = (int(v) for v in in_shape)
    return build_encoder("diffuser", sensor={"embedding": [a, b], "color": "gray" if C == 1 else "rgb"},
                         fidelity={"preset": "fast"})


def make_decoder(cls: type, in_shape=(1, 6, 8), num_classes: int = 10, learnable_encoder: bool = False, config=None):
    """Instantiate decoder ``cls`` as the framework does (keyword arguments from the encoder and the dataset; an
    image decoder gets ``out_shape`` :data:`IMAGE_OUT_SHAPE` and, where it reads one, a small encoder)."""
    if _is_image(cls):
        enc = _kit_encoder(in_shape) if getattr(cls, "needs_encoder", False) else None
        return cls(config or None, in_shape=tuple(in_shape), out_shape=IMAGE_OUT_SHAPE, encoder=enc,
                   learnable_encoder=learnable_encoder)
    return cls(config or None, in_shape=tuple(in_shape), num_classes=num_classes, learnable_encoder=learnable_encoder)


def _out_shape(cls: type, k: int) -> tuple[int, ...]:
    return IMAGE_OUT_SHAPE if _is_image(cls) else (k,)


def _decoder_loss(cls: type, out, k: int):
    import torch

    if _is_image(cls):
        return (out - 0.5).pow(2).mean()
    return torch.nn.functional.cross_entropy(out, torch.arange(len(out)) % k)


def _embeddings(n: int, shape: tuple[int, ...], seed: int = 0):
    import torch

    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, *shape, generator=g) * 3.0 + 0.5  # not centred, not unit: the norms must do their job


def _decoder_check(fn: Callable[..., str | None]) -> Callable[..., str | None]:
    """Run a decoder check with the global RNG forked (parameter initialisation draws from it)."""

    @functools.wraps(fn)
    def wrapper(cls: type, **setup: Any) -> str | None:
        import torch

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(0)
            return fn(cls, **setup)

    return wrapper


@_decoder_check
def check_decoder_documented(cls: type, **setup: Any) -> str | None:
    """``name``, ``Config`` deriving from ``DecoderConfig`` with help on every field, ``flatten`` a bool, a summary."""
    from .decoders import Decoder, DecoderConfig

    _documented(cls, "decoder", Decoder, DecoderConfig, ("flatten",))
    return None


@_decoder_check
def check_decoder_config_roundtrip(cls: type, **setup: Any) -> str | None:
    """``Config -> to_dict -> Config(**dict)`` and omegaconf YAML give back an equal config."""
    config, shapes, k = _decoder_setup(setup)
    _config_roundtrip(cls, "decoder", config, lambda plain: make_decoder(cls, shapes[0], k, config=plain))
    return None


@_decoder_check
def check_decoder_shapes(cls: type, **setup: Any) -> str | None:
    """Every embedding shape from 1 x 1 up, both normalisations (fixed / learned encoder), train and eval mode:
    finite logits ``(B, num_classes)`` (an image decoder: ``(B, *IMAGE_OUT_SHAPE)``); a single example in eval mode."""
    import torch

    config, shapes, k = _decoder_setup(setup)
    label = _label(cls, "decoder")
    for shape in shapes:
        for learnable in (False, True):
            dec = make_decoder(cls, shape, k, learnable, config)
            for mode, n in (("train", 4), ("eval", 4), ("eval", 1)):
                dec.train(mode == "train")
                with torch.no_grad():
                    out = dec(_embeddings(n, shape))
                where = f"in_shape {shape}, learnable_encoder={learnable}, {mode} mode, batch {n}"
                want = (n, *_out_shape(cls, k))
                assert tuple(out.shape) == want, f"{label}: {where}: output shape {tuple(out.shape)}, expected {want}"
                assert torch.isfinite(out).all(), f"{label}: {where}: non-finite logits"
    return None


@_decoder_check
def check_decoder_gradients(cls: type, **setup: Any) -> str | None:
    """Cross-entropy gradients reach every trainable parameter (finite, one non-zero) and the embedding
    (so a learned encoder upstream is trained), for every kit shape."""
    import torch

    config, shapes, k = _decoder_setup(setup)
    label = _label(cls, "decoder")
    for shape in shapes:
        dec = make_decoder(cls, shape, k, True, config)
        dec.train()
        x = _embeddings(4, shape).requires_grad_(True)
        _decoder_loss(cls, dec(x), k).backward()
        params = {n: p for n, p in dec.named_parameters() if p.requires_grad}
        assert params, f"{label}: in_shape {shape}: no trainable parameters"
        missing = sorted(n for n, p in params.items() if p.grad is None)
        assert not missing, f"{label}: in_shape {shape}: no gradient reaches {missing}"
        bad = sorted(n for n, p in params.items() if not torch.isfinite(p.grad).all())
        assert not bad, f"{label}: in_shape {shape}: non-finite gradients in {bad}"
        assert any(float(p.grad.abs().max()) > 0 for p in params.values()), f"{label}: in_shape {shape}: all gradients zero"
        assert x.grad is not None and torch.isfinite(x.grad).all() and float(x.grad.abs().max()) > 0, (
            f"{label}: in_shape {shape}: no finite, non-zero gradient reaches the embedding"
        )
    return None


@_decoder_check
def check_decoder_standardize(cls: type, **setup: Any) -> str | None:
    """``embedding_norm=standardize`` makes the logits invariant to an affine change of the embedding
    (``a x + b`` with statistics ``a m + b``, ``a s``), as for a brighter scene or another gain."""
    import torch

    config, shapes, k = _decoder_setup(setup)
    if getattr(cls, "needs_encoder", False):
        return "a physics-informed decoder reads the raw measurement (no standardisation)"
    shape = shapes[-1]
    dec = make_decoder(cls, shape, k, False, {**config, "embedding_norm": "standardize"}).eval()
    x, (m, sd), (a, b) = _embeddings(4, shape), (2.0, 0.8), (7.0, 3.0)
    with torch.no_grad():
        dec.set_statistics(m, sd)
        y1 = dec(x)
        dec.set_statistics(a * m + b, a * sd)
        y2 = dec(a * x + b)
    _close(y2, y1, TOLERANCES["standardize"], "standardize: logits changed under an affine change of the embedding", cls, "decoder")
    return None


@_decoder_check
def check_decoder_state_dict(cls: type, **setup: Any) -> str | None:
    """A fresh decoder loading another's ``state_dict`` (statistics and running norms included) gives the same logits."""
    import torch

    config, shapes, k = _decoder_setup(setup)
    shape = shapes[-1]
    for learnable in (False, True):
        torch.manual_seed(1)
        a = make_decoder(cls, shape, k, learnable, config)
        torch.manual_seed(2)
        b = make_decoder(cls, shape, k, learnable, config)
        a.set_statistics(1.5, 0.7)
        with torch.no_grad():
            a.train()(_embeddings(8, shape, seed=3))  # moves batch-norm running statistics
        b.load_state_dict(copy.deepcopy(a.state_dict()), strict=True)
        x = _embeddings(4, shape, seed=4)
        with torch.no_grad():
            ya, yb = a.eval()(x), b.eval()(x)
        assert torch.equal(ya, yb), f"{_label(cls, 'decoder')}: logits differ after load_state_dict (learnable_encoder={learnable})"
    return None


@_decoder_check
def check_decoder_determinism(cls: type, **setup: Any) -> str | None:
    """Eval mode: the same embedding gives identical logits twice."""
    import torch

    config, shapes, k = _decoder_setup(setup)
    dec = make_decoder(cls, shapes[-1], k, True, config).eval()
    x = _embeddings(4, shapes[-1])
    with torch.no_grad():
        assert torch.equal(dec(x), dec(x)), f"{_label(cls, 'decoder')}: two eval-mode passes differ"
    return None


#: Decoder check name -> function.
DECODER_CHECKS: dict[str, Callable[..., str | None]] = {
    "documented": check_decoder_documented,
    "config_roundtrip": check_decoder_config_roundtrip,
    "shapes": check_decoder_shapes,
    "gradients": check_decoder_gradients,
    "standardize": check_decoder_standardize,
    "state_dict": check_decoder_state_dict,
    "determinism": check_decoder_determinism,
}


# --------------------------------------------------------------------------- datasets
_LOADED: dict[tuple, Any] = {}


def _load(cls: type, config: Mapping[str, Any], fresh: bool = False):
    """``cls(config).load()``, kept for the next check (the two most recent loads)."""
    key = (cls, repr(sorted(config.items())))
    if fresh or key not in _LOADED:
        splits = cls(dict(config) or None).load()
        if fresh:
            return splits
        while len(_LOADED) >= 2:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = splits
    return _LOADED[key]


def _dataset_setup(setup: Mapping[str, Any]) -> tuple[dict, dict | None]:
    bad = sorted(set(setup) - {"config", "variant"})
    if bad:
        raise TypeError(f"unknown setup key(s) {bad}; allowed: config, variant")
    variant = setup.get("variant")
    return _as_dict(setup.get("config")), (None if variant is None else _as_dict(variant))


def check_dataset_documented(cls: type, **setup: Any) -> str | None:
    """``name``, ``Config`` deriving from ``DatasetConfig`` with help on every field, a summary."""
    from .datasets.base import Dataset, DatasetConfig

    _documented(cls, "dataset", Dataset, DatasetConfig)
    return None


def check_dataset_config_roundtrip(cls: type, **setup: Any) -> str | None:
    """``Config -> to_dict -> Config(**dict)`` and omegaconf YAML give back an equal config."""
    config, _ = _dataset_setup(setup)
    _config_roundtrip(cls, "dataset", config, lambda plain: cls(plain))
    return None


def check_dataset_splits(cls: type, **setup: Any) -> str | None:
    """``load()`` gives :class:`Splits`: images float32 ``(N, C, h, w)`` (C 1 or 3, one shape for all splits),
    finite, in ``[0, 1]``; labels int64 ``(N,)`` in ``[0, num_classes)``; no split empty; class names, if given,
    one per class."""
    import torch

    from .datasets.base import Splits

    config, _ = _dataset_setup(setup)
    label = _label(cls, "dataset")
    s = _load(cls, config)
    assert isinstance(s, Splits), f"{label}: load() returned {type(s).__name__}, expected optoenc.datasets.base.Splits"
    assert isinstance(s.num_classes, int) and s.num_classes >= 2, f"{label}: num_classes {s.num_classes!r} must be an int >= 2"
    shapes = set()
    for name in ("train", "val", "test"):
        x, y = getattr(s, name)
        where = f"{label}: {name} split"
        assert x.dtype == torch.float32 and x.dim() == 4, f"{where}: images {x.dtype} {tuple(x.shape)}, expected float32 (N, C, h, w)"
        assert x.shape[1] in (1, 3) and min(x.shape[-2:]) >= 1, f"{where}: images {tuple(x.shape)}: C must be 1 or 3"
        assert y.dtype == torch.int64 and y.dim() == 1 and len(y) == len(x), (
            f"{where}: labels {y.dtype} {tuple(y.shape)}, expected int64 ({len(x)},)"
        )
        assert len(y) >= 1, f"{where} is empty"
        assert torch.isfinite(x).all() and float(x.min()) >= 0 and float(x.max()) <= 1, (
            f"{where}: images must be finite intensities in [0, 1], got [{float(x.min()):.3g}, {float(x.max()):.3g}]"
        )
        assert int(y.min()) >= 0 and int(y.max()) < s.num_classes, f"{where}: labels outside [0, {s.num_classes})"
        shapes.add(tuple(x.shape[1:]))
    assert len(shapes) == 1, f"{label}: the splits' images differ in shape: {sorted(shapes)}"
    names = getattr(s, "class_names", ())
    assert not names or (len(names) == s.num_classes and all(isinstance(n, str) for n in names)), (
        f"{label}: class_names {names!r} must be {s.num_classes} strings (or empty)"
    )
    return None


def check_dataset_disjoint(cls: type, **setup: Any) -> str | None:
    """No image appears in two splits (compared by content): the test split stays unseen."""
    import hashlib

    config, _ = _dataset_setup(setup)
    s = _load(cls, config)

    def digests(x) -> set:
        rows = x.contiguous().numpy().reshape(len(x), -1)
        return {hashlib.blake2b(r.tobytes(), digest_size=16).digest() for r in rows}

    d = {k: digests(getattr(s, k).images) for k in ("train", "val", "test")}
    for a, b in (("train", "val"), ("train", "test"), ("val", "test")):
        both = len(d[a] & d[b])
        assert not both, f"{_label(cls, 'dataset')}: {both} image(s) in both the {a} and the {b} split"
    return None


def check_dataset_digest(cls: type, **setup: Any) -> str | None:
    """``content_digest()`` is stable (a fresh load gives the same digest and tensors) and sensitive: without a
    source digest one changed pixel changes it; with ``setup['variant']`` (a config reading other source data)
    different content gives a different digest."""
    import dataclasses as dc

    import torch

    config, variant = _dataset_setup(setup)
    label = _label(cls, "dataset")
    a, b = _load(cls, config), _load(cls, config, fresh=True)
    assert isinstance(a.digest, str), f"{label}: Splits.digest must be a string, got {type(a.digest).__name__}"
    for k in ("train", "val", "test"):
        assert torch.equal(getattr(a, k).images, getattr(b, k).images) and torch.equal(getattr(a, k).labels, getattr(b, k).labels), (
            f"{label}: two loads of one config differ in the {k} split (the cache key would not identify the data)"
        )
    assert a.content_digest() == b.content_digest(), f"{label}: content_digest() differs between two loads of one config"
    if not a.digest:
        x = a.test.images.clone()
        x.view(-1)[0] = 0.5 if float(x.view(-1)[0]) != 0.5 else 0.25
        edited = dc.replace(a, test=type(a.test)(x, a.test.labels))
        assert edited.content_digest() != a.content_digest(), f"{label}: content_digest() ignores a changed pixel"
    if variant is not None:
        v = _load(cls, variant, fresh=True)
        same = all(
            getattr(v, k).images.shape == getattr(a, k).images.shape and torch.equal(getattr(v, k).images, getattr(a, k).images)
            for k in ("train", "val", "test")
        )
        if not same:
            assert v.content_digest() != a.content_digest(), (
                f"{label}: setup['variant'] loads other data with the same digest {a.content_digest()[:12]}...: "
                "Splits.digest must change with the source data"
            )
    return None


#: Dataset check name -> function.
DATASET_CHECKS: dict[str, Callable[..., str | None]] = {
    "documented": check_dataset_documented,
    "config_roundtrip": check_dataset_config_roundtrip,
    "splits": check_dataset_splits,
    "disjoint": check_dataset_disjoint,
    "digest": check_dataset_digest,
}


# --------------------------------------------------------------------------- augmentations
def _canvas(setup: Mapping[str, Any], dtype=None, seed: int = 0):
    """A small canvas ``(2, 1, rows, cols)`` with a centred 8 x 6 scene of 12 cm on a 20 x 27 cm field of view."""
    from .augment import canvas_geometry, to_canvas

    bad = sorted(set(setup) - {"config"})
    if bad:
        raise TypeError(f"unknown setup key(s) {bad}; allowed: config")
    geometry = canvas_geometry(0.12, SCENE_SHAPE, 0.20, 0.27)
    return to_canvas(scenes(2, shape=SCENE_SHAPE, dtype=dtype, seed=seed), geometry), geometry


def _augment(cls: type, setup: Mapping[str, Any], canvas, geometry, seed: int):
    import torch

    aug = cls(_as_dict(setup.get("config")) or None)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return aug(canvas, geometry)


def check_augmentation_documented(cls: type, **setup: Any) -> str | None:
    """``name``, a settings ``Config`` with help on every field, a summary."""
    from .augment import Augmentation
    from .settings import Settings

    _documented(cls, "augmentation", Augmentation, Settings)
    return None


def check_augmentation_config_roundtrip(cls: type, **setup: Any) -> str | None:
    """``Config -> to_dict -> Config(**dict)`` and omegaconf YAML give back an equal config."""
    _config_roundtrip(cls, "augmentation", _as_dict(setup.get("config")), lambda plain: cls(plain))
    return None


def check_augmentation_canvas(cls: type, **setup: Any) -> str | None:
    """The canvas keeps its shape and dtype (float32 and float64) and stays finite and non-negative."""
    import torch

    label = _label(cls, "augmentation")
    for dtype in (torch.float32, torch.float64):
        canvas, geometry = _canvas(setup, dtype)
        out = _augment(cls, setup, canvas, geometry, seed=0)
        assert tuple(out.shape) == tuple(canvas.shape) and out.dtype == dtype, (
            f"{label}: {dtype} canvas {tuple(canvas.shape)} gave {out.dtype} {tuple(out.shape)}"
        )
        assert torch.isfinite(out).all(), f"{label}: non-finite output"
        assert float(out.min()) >= -_tol(dtype) * float(canvas.max()), f"{label}: negative intensity {float(out.min()):.3g}"
    return None


def check_augmentation_determinism(cls: type, **setup: Any) -> str | None:
    """The same torch seed gives the same transform (runs are reproducible)."""
    import torch

    canvas, geometry = _canvas(setup)
    a, b = (_augment(cls, setup, canvas, geometry, seed=5) for _ in range(2))
    assert torch.equal(a, b), f"{_label(cls, 'augmentation')}: two draws under one torch seed differ"
    return None


def check_augmentation_linearity(cls: type, **setup: Any) -> str | None:
    """Under one seed, ``T(a x + b y) = a T(x) + b T(y)``: an object-plane transform moves light, it does not
    create it (set ``linear = False`` on the class for a non-linear one)."""
    if not getattr(cls, "linear", True):
        return "the augmentation is not linear in the intensity (linear = False)"
    x, geometry = _canvas(setup, seed=1)
    y, _ = _canvas(setup, seed=2)
    lhs = _augment(cls, setup, 0.7 * x + 1.3 * y, geometry, seed=3)
    rhs = 0.7 * _augment(cls, setup, x, geometry, seed=3) + 1.3 * _augment(cls, setup, y, geometry, seed=3)
    _close(lhs, rhs, TOLERANCES["linearity"], "T(a x + b y) != a T(x) + b T(y)", cls, "augmentation")
    return None


#: Augmentation check name -> function.
AUGMENTATION_CHECKS: dict[str, Callable[..., str | None]] = {
    "documented": check_augmentation_documented,
    "config_roundtrip": check_augmentation_config_roundtrip,
    "canvas": check_augmentation_canvas,
    "determinism": check_augmentation_determinism,
    "linearity": check_augmentation_linearity,
}


# --------------------------------------------------------------------------- tasks
def _task_data(cls: type, n: int = 6):
    """Small splits (``n`` gray 12 x 12 scenes of 2 classes each) and a perfect and a poor decoder output."""
    import torch

    from .datasets.base import Split, Splits

    g = torch.Generator().manual_seed(0)

    def split(seed: int) -> Split:
        return Split(torch.rand(n, 1, 12, 12, generator=g), torch.arange(n) % 2)

    splits = Splits(split(0), split(1), split(2), num_classes=2)
    task = cls()
    target = task.target(splits.val)
    if task.decoder_output == "logits":
        good = torch.nn.functional.one_hot(target, 2).float() * 10.0
        poor = torch.zeros(n, 2)
    else:
        good = target.float().clone()
        poor = torch.full_like(good, 0.5)
    return task, splits, target, good, poor


def _task_check(fn: Callable[..., str | None]) -> Callable[..., str | None]:
    @functools.wraps(fn)
    def wrapper(cls: type, **setup: Any) -> str | None:
        bad = sorted(set(setup) - {"config"})
        if bad:
            raise TypeError(f"unknown setup key(s) {bad}; allowed: config")
        return fn(cls, **setup)

    return wrapper


@_task_check
def check_task_documented(cls: type, **setup: Any) -> str | None:
    """``name``, ``Config`` deriving from ``TaskConfig`` with help on every field, a summary; ``features`` among
    ``TASK_FEATURES``; ``decoder_output`` one of ``DECODER_OUTPUTS``, ``monitor`` a ``(metric, 'min' | 'max')`` pair
    among the logged metrics."""
    from .tasks import DECODER_OUTPUTS, Task, TaskConfig

    from .tasks import TASK_FEATURES

    _documented(cls, "task", Task, TaskConfig)
    label = _label(cls, "task")
    unknown = sorted(set(cls.features) - set(TASK_FEATURES))
    assert not unknown, f"{label}: unknown features {unknown}; known: {', '.join(TASK_FEATURES)}"
    assert cls.decoder_output in DECODER_OUTPUTS, f"{label}: decoder_output {cls.decoder_output!r} not in {DECODER_OUTPUTS}"
    metric, mode = cls.monitor
    assert mode in ("min", "max"), f"{label}: monitor mode {mode!r} must be 'min' or 'max'"
    assert metric in cls.summary_metrics, f"{label}: the monitored metric {metric!r} must be among summary_metrics"
    return None


@_task_check
def check_task_config_roundtrip(cls: type, **setup: Any) -> str | None:
    """``Config -> to_dict -> Config(**dict)`` and omegaconf YAML give back an equal config."""
    _config_roundtrip(cls, "task", _as_dict(setup.get("config")), lambda plain: cls(plain))
    return None


@_task_check
def check_task_loss(cls: type, **setup: Any) -> str | None:
    """One target per example; the loss is a finite scalar, lower for the perfect output than for a poor one, and
    its gradient reaches the decoder's output."""
    import torch

    task, splits, target, good, poor = _task_data(cls)
    label = _label(cls, "task")
    assert len(target) == len(splits.val.labels), f"{label}: target() gives {len(target)} rows for {len(splits.val.labels)} examples"
    out = poor.clone().requires_grad_(True)
    loss = task.loss(out, target)
    assert loss.dim() == 0 and torch.isfinite(loss), f"{label}: the loss must be a finite scalar, got {loss}"
    loss.backward()
    assert out.grad is not None and float(out.grad.abs().max()) > 0, f"{label}: no gradient reaches the output"
    assert float(task.loss(good, target)) < float(loss.detach()), f"{label}: the perfect output's loss is not lower than a poor one's"
    return None


@_task_check
def check_task_metrics(cls: type, **setup: Any) -> str | None:
    """Validation metrics finite, and the monitored one better for the perfect output than for a poor one (where
    it is not the loss); reference scores give every ``test_<metric>`` of ``summary_metrics`` but the loss."""
    import math
    from types import SimpleNamespace

    task, splits, target, good, poor = _task_data(cls)
    label = _label(cls, "task")
    dec = SimpleNamespace(num_classes=splits.num_classes)
    values = {}
    for name, out in (("good", good), ("poor", poor)):
        metrics = task.make_metrics("val", dec)
        task.update_metrics(metrics, out, target)
        values[name] = {k: float(m.compute()) for k, m in metrics.items()}
        assert all(not math.isnan(v) for v in values[name].values()), f"{label}: NaN metrics {values[name]}"
    metric, mode = task.monitor
    if metric != "loss":
        g, p = values["good"][metric], values["poor"][metric]
        assert (g > p) if mode == "max" else (g < p), f"{label}: {metric} {g} (perfect) not better than {p} (poor)"
    scores = task.reference_scores([good[:3], good[3:]], [target[:3], target[3:]])
    want = {f"test_{m}" for m in task.summary_metrics if m != "loss"}
    assert want <= set(scores), f"{label}: reference_scores gave {sorted(scores)}, expected {sorted(want)}"
    return None


@_task_check
def check_task_pictures(cls: type, **setup: Any) -> str | None:
    """``pictures()`` gives file stems -> rows of ``(title, (N, C, h, w))`` images, one per example."""
    import torch

    task, splits, target, good, poor = _task_data(cls)
    label = _label(cls, "task")
    x = splits.val.images
    pics = task.pictures(x, torch.rand(len(x), 1, 4, 5), good)
    assert isinstance(pics, dict), f"{label}: pictures() must return a dict"
    for stem, rows in pics.items():
        assert re.match(r"^[a-z][a-z0-9_]*$", stem), f"{label}: picture name {stem!r} is not a plain file stem"
        for title, images in rows:
            assert isinstance(title, str) and images.dim() == 4 and len(images) == len(x), (
                f"{label}: picture {stem!r} row {title!r}: expected ({len(x)}, C, h, w) images")
    return None


#: Task check name -> function.
TASK_CHECKS: dict[str, Callable[..., str | None]] = {
    "documented": check_task_documented,
    "config_roundtrip": check_task_config_roundtrip,
    "loss": check_task_loss,
    "metrics": check_task_metrics,
    "pictures": check_task_pictures,
}


# --------------------------------------------------------------------------- the kits
#: Plugin kind -> its kit (the kinds of :data:`optoenc.plugins.registry.KINDS`).
KITS: dict[str, Kit] = {
    "encoder": Kit("encoder", "encoder_cls", ENCODER_CHECKS, _SETUP_KEYS),
    "decoder": Kit("decoder", "decoder_cls", DECODER_CHECKS, _DECODER_KEYS),
    "augmentation": Kit("augmentation", "augmentation_cls", AUGMENTATION_CHECKS, ("config",)),
    "dataset": Kit("dataset", "dataset_cls", DATASET_CHECKS, ("config", "variant")),
    "task": Kit("task", "task_cls", TASK_CHECKS, ("config",)),
}


def check_encoder(cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
    """Run the encoder kit on ``cls``: ``setup`` holds ``config``, ``scene``, ``sensor``, ``fidelity``
    (mappings, merged over :data:`SMALL_SETUP`). See :meth:`Kit.run`."""
    return KITS["encoder"].run(cls, checks=checks, **setup)


def check_decoder(cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
    """Run the decoder kit on ``cls``: ``setup`` holds ``config``, ``in_shapes`` (default
    :data:`DECODER_SHAPES`) and ``num_classes`` (default 10). See :meth:`Kit.run`."""
    return KITS["decoder"].run(cls, checks=checks, **setup)


def check_dataset(cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
    """Run the dataset kit on ``cls``: ``setup`` holds ``config`` and optionally ``variant`` (a config reading
    other source data). See :meth:`Kit.run`."""
    return KITS["dataset"].run(cls, checks=checks, **setup)


def check_augmentation(cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
    """Run the augmentation kit on ``cls``: ``setup`` holds ``config``. See :meth:`Kit.run`."""
    return KITS["augmentation"].run(cls, checks=checks, **setup)


EncoderConformance = KITS["encoder"].conformance_class("EncoderConformance")
DecoderConformance = KITS["decoder"].conformance_class("DecoderConformance")
DatasetConformance = KITS["dataset"].conformance_class("DatasetConformance")
AugmentationConformance = KITS["augmentation"].conformance_class("AugmentationConformance")
TaskConformance = KITS["task"].conformance_class("TaskConformance")


def check_task(cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
    """Run the task kit on ``cls``: ``setup`` holds ``config``. See :meth:`Kit.run`."""
    return KITS["task"].run(cls, checks=checks, **setup)
