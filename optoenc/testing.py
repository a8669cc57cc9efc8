"""Conformance kit for optical encoders: the checks every registered encoder passes.

optoenc runs these checks over every name in ``get_registry("encoder")``
(``tests/test_conformance.py``), and plugin authors reuse them for their own
encoders, either as plain functions::

    from optoenc.testing import check_encoder
    check_encoder(MyEncoder, fidelity={"grid": (48, 64)}, sensor={"embedding": (6, 8)})

or as a pytest base class whose ``test_*`` methods call the checks::

    from optoenc.testing import EncoderConformance

    class TestMyEncoder(EncoderConformance):
        encoder_cls = MyEncoder
        setup = {"fidelity": {"grid": (48, 64)}}

Every check takes the encoder class plus an optional small setup (``config``,
``scene``, ``sensor``, ``fidelity``: settings objects or mappings, merged over
:data:`SMALL_SETUP`) and raises ``AssertionError`` naming the encoder and what
is wrong. A check returns ``None`` when it ran, or a string saying why it does
not apply (e.g. linearity for an encoder whose ``linear`` flag is false).
Checks use tiny grids and scenes so that the whole kit runs in seconds.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import re
import warnings
from typing import Any, Callable, Mapping

__all__ = [
    "SMALL_SETUP",
    "TINY_SETUP",
    "SCENE_SHAPE",
    "CHECKS",
    "make_encoder",
    "scenes",
    "check_documented",
    "check_config_roundtrip",
    "check_output_shape",
    "check_dtype",
    "check_determinism",
    "check_nonnegative",
    "check_psf",
    "check_linearity",
    "check_gradients",
    "check_gradcheck",
    "check_state_dict",
    "check_device",
    "check_encoder",
    "EncoderConformance",
]

#: Default small setup: a 48 x 64 simulation grid and a 6 x 8 embedding.
SMALL_SETUP: dict[str, Any] = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}
#: The float64 gradcheck setup: a 12 x 16 grid and a 3 x 4 embedding.
TINY_SETUP: dict[str, Any] = {"fidelity": {"grid": (12, 16), "dtype": "float64"}, "sensor": {"embedding": (3, 4)}}
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


def _label(cls: type) -> str:
    return f"encoder {getattr(cls, 'name', '') or cls.__name__!r} ({cls.__module__}.{cls.__qualname__})"


def make_encoder(cls: type, *, base: Mapping[str, Any] = SMALL_SETUP, **setup: Any):
    """Instantiate ``cls`` with ``setup`` (``config``, ``scene``, ``sensor``, ``fidelity``) merged over ``base``."""
    s = _merge(base, setup)
    return cls(s["config"] or None, scene=s["scene"], sensor=s["sensor"], fidelity=s["fidelity"])


def scenes(n: int = 2, channels: int = 1, shape: tuple[int, int] = SCENE_SHAPE, dtype=None, seed: int = 0):
    """``(n, channels, *shape)`` non-negative random scenes, drawn from a private generator."""
    import torch

    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, channels, *shape, generator=g, dtype=dtype or torch.float32)


def _close(a, b, rel: float, what: str, cls: type) -> None:
    import torch

    scale = max(float(b.detach().abs().max()), 1e-30)
    err = float((a.detach() - b.detach()).abs().max())
    assert err <= rel * scale, f"{_label(cls)}: {what}: max |difference| {err:.3g} > {rel:g} x max |value| {scale:.3g}"
    assert torch.isfinite(a.detach()).all(), f"{_label(cls)}: {what}: non-finite values"


def _tol(dtype) -> float:
    import torch

    return 1e-10 if dtype == torch.float64 else 1e-5


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
@_check
def check_documented(cls: type, **setup: Any) -> str | None:
    """``name``, ``Config`` (help text on every field), capability flags and ``summary()`` are there."""
    from .encoders.base import EncoderConfig, OpticalEncoder

    label = _label(cls)
    assert isinstance(cls, type) and issubclass(cls, OpticalEncoder), f"{label}: must subclass optoenc.OpticalEncoder"
    name = getattr(cls, "name", "")
    assert isinstance(name, str) and re.match(r"^[a-z][a-z0-9_]*$", name), (
        f"{label}: class attribute `name` must be a lowercase identifier, got {name!r}"
    )
    assert not getattr(cls, "__abstractmethods__", None), (
        f"{label}: abstract methods not implemented: {sorted(cls.__abstractmethods__)}"
    )
    cfg = cls.Config
    assert dataclasses.is_dataclass(cfg) and issubclass(cfg, EncoderConfig), (
        f"{label}: `Config` must be a dataclass deriving from optoenc.EncoderConfig, got {cfg!r}"
    )
    undocumented = [f.name for f in dataclasses.fields(cfg) if not str(f.metadata.get("help", "")).strip()]
    assert not undocumented, (
        f"{label}: Config fields without help text: {undocumented}; declare them with optoenc.setting(default, help, unit=...)"
    )
    for flag in ("learnable", "linear"):
        assert isinstance(getattr(cls, flag, None), bool), f"{label}: capability flag `{flag}` must be a bool"
    summary = cls.summary()
    assert isinstance(summary, str) and summary.strip(), f"{label}: needs a class docstring (its first line is the summary)"
    return None


@_check
def check_config_roundtrip(cls: type, **setup: Any) -> str | None:
    """``Config -> to_dict -> Config(**dict)`` and omegaconf YAML give back an equal config."""
    from omegaconf import OmegaConf

    from .settings import to_dict

    label = _label(cls)
    s = _merge({}, setup)
    cfg = cls.Config(**s["config"])

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
    enc = make_encoder(cls, **{**setup, "config": plain})
    assert enc.config == cfg, f"{label}: building from a mapping of the config gave {enc.config}, expected {cfg}"
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
    _close(out32.double(), out64, 1e-3, "float32 and float64 outputs differ", cls)
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


@_check
def check_psf(cls: type, **setup: Any) -> str | None:
    """``psf()`` is ``(channels, H, W)``, finite, non-negative; gray sums to 1, RGB's spectrally weighted sums add to 1."""
    import torch

    from .devices import GRAYSCALE_WEIGHTS

    label = _label(cls)
    for color in ("gray", "rgb"):
        enc = make_encoder(cls, **{**setup, "sensor": {**_as_dict(setup.get("sensor")), "color": color}})
        psf = enc.psf()
        expected = (enc.channels, *enc.geometry.grid)
        assert tuple(psf.shape) == expected, f"{label}: psf() shape {tuple(psf.shape)}, expected {expected}"
        assert psf.dtype == enc.optics_dtype, f"{label}: psf() dtype {psf.dtype}, expected {enc.optics_dtype}"
        assert torch.isfinite(psf).all(), f"{label}: psf() has non-finite values"
        psf = psf.detach()
        floor = -_tol(psf.dtype) * float(psf.abs().max())
        assert float(psf.min()) >= floor, f"{label}: psf() has negative values ({float(psf.min()):.3g})"
        sums = psf.detach().double().sum(dim=(-2, -1))
        total = float((torch.tensor(GRAYSCALE_WEIGHTS, dtype=torch.float64) * sums).sum()) if color == "rgb" else float(sums[0])
        assert abs(total - 1) <= 1e-4, f"{label}: psf() channel sums {sums.tolist()} (weighted total {total}) != 1"
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
    _close(lhs, rhs, 1e-4, "f(a x + b y) != a f(x) + b f(y)", cls)
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
    """float64 ``torch.autograd.gradcheck`` w.r.t. the scene on a tiny grid (12 x 16, embedding 3 x 4)."""
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
        ok = torch.autograd.gradcheck(lambda t: enc(t, noise=False), (x,), eps=1e-6, atol=1e-7, rtol=1e-5)
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
    _close(out.cpu(), ref, 1e-4, "CUDA and CPU outputs differ", cls)
    return None


#: Check name -> function, in the order :func:`check_encoder` runs them.
CHECKS: dict[str, Callable[..., str | None]] = {
    "documented": check_documented,
    "config_roundtrip": check_config_roundtrip,
    "psf": check_psf,
    "output_shape": check_output_shape,
    "dtype": check_dtype,
    "determinism": check_determinism,
    "nonnegative": check_nonnegative,
    "linearity": check_linearity,
    "gradients": check_gradients,
    "gradcheck": check_gradcheck,
    "state_dict": check_state_dict,
    "device": check_device,
}


def check_encoder(cls: type, *, checks: list[str] | None = None, **setup: Any) -> dict[str, str]:
    """Run every conformance check (or those named in ``checks``) on ``cls``.

    Args:
        cls: an :class:`~optoenc.OpticalEncoder` subclass.
        checks: names from :data:`CHECKS` (default: all).
        **setup: ``config``, ``scene``, ``sensor``, ``fidelity`` (mappings),
            merged over :data:`SMALL_SETUP`.

    Returns:
        Check name -> ``"ok"`` or ``"skipped: <reason>"``.

    Raises:
        AssertionError: the first failing check, with its name and the reason.
    """
    names = list(CHECKS) if checks is None else list(checks)
    unknown = [n for n in names if n not in CHECKS]
    if unknown:
        raise KeyError(f"unknown check(s) {unknown}; available: {', '.join(CHECKS)}")
    report = {}
    for n in names:
        try:
            reason = CHECKS[n](cls, **setup)
        except AssertionError as err:
            raise AssertionError(f"[{n}] {err}") from err
        report[n] = "ok" if reason is None else f"skipped: {reason}"
    return report


class EncoderConformance:
    """pytest base class: set ``encoder_cls`` (and optionally ``setup``); each check is a test.

    Example:
        class TestPinhole(EncoderConformance):
            encoder_cls = Pinhole
            setup = {"fidelity": {"grid": (48, 64)}, "sensor": {"embedding": (6, 8)}}
    """

    encoder_cls: type | None = None
    setup: dict[str, Any] = {}

    def _run(self, name: str) -> None:
        if self.encoder_cls is None:
            import pytest

            pytest.skip("encoder_cls is not set")
        reason = CHECKS[name](self.encoder_cls, **dict(self.setup))
        if reason is not None:
            import pytest

            pytest.skip(reason)

    def test_documented(self):
        self._run("documented")

    def test_config_roundtrip(self):
        self._run("config_roundtrip")

    def test_psf(self):
        self._run("psf")

    def test_output_shape(self):
        self._run("output_shape")

    def test_dtype(self):
        self._run("dtype")

    def test_determinism(self):
        self._run("determinism")

    def test_nonnegative(self):
        self._run("nonnegative")

    def test_linearity(self):
        self._run("linearity")

    def test_gradients(self):
        self._run("gradients")

    def test_gradcheck(self):
        self._run("gradcheck")

    def test_state_dict(self):
        self._run("state_dict")

    def test_device(self):
        self._run("device")
