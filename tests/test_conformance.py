"""Every registered encoder, decoder, augmentation and dataset passes its conformance kit (optoenc.testing).

The registries are the single source of parametrisation: a class registered
by a built-in or an installed plugin is checked here without editing this file.
"""

from __future__ import annotations

import pytest
import torch

from optoenc.plugins import get_registry
from optoenc.plugins.registry import KINDS
from optoenc.testing import (
    CHECKS, KITS, DecoderConformance, EncoderConformance, SMALL_SETUP, check_dataset, check_decoder, check_encoder,
)

ENCODERS = get_registry("encoder").names()
#: (kind, name, check) for every registered class of every kind
CASES = [(kind, name, check) for kind in KINDS for name in get_registry(kind).names() for check in KITS[kind].checks]


@pytest.mark.parametrize("kind, name, check", CASES, ids=["-".join(c) for c in CASES])
def test_conformance(kind, name, check):
    cls = get_registry(kind).get(name)
    assert cls.name == name, f"registered as {name!r} but cls.name is {cls.name!r}"
    if kind == "dataset" and cls.local_files:
        pytest.skip("reads the user's own files: its tests run the kit on fixtures in its layout (tests/datasets)")
    reason = KITS[kind].checks[check](cls, **(SMALL_SETUP if kind == "encoder" else {}))
    if reason is not None:
        pytest.skip(reason)


def test_every_kind_has_a_kit_and_generated_test_methods():
    assert set(KITS) == set(KINDS)
    for kit in KITS.values():
        base = kit.conformance_class("Probe")
        assert {n for n in dir(base) if n.startswith("test_")} == {f"test_{c}" for c in kit.checks}
    assert {n for n in dir(EncoderConformance) if n.startswith("test_")} == {f"test_{c}" for c in CHECKS}


def test_registry_is_not_empty():
    assert "diffuser" in ENCODERS


def test_check_encoder_reports_every_check():
    report = check_encoder(get_registry("encoder").get("diffuser"), checks=["documented", "linearity", "gradients"])
    assert report == {"documented": "ok", "linearity": "ok", "gradients": "ok"}
    with pytest.raises(KeyError, match="available"):
        check_encoder(get_registry("encoder").get("diffuser"), checks=["nope"])
    with pytest.raises(TypeError, match="allowed"):
        check_encoder(get_registry("encoder").get("diffuser"), checks=["documented"], sensors={})


# --- the kit catches broken encoders -----------------------------------------------------
def _broken(**attrs):
    from optoenc.encoders.diffuser import Diffuser

    return type("Broken", (Diffuser,), {"__doc__": "A deliberately broken encoder.", **attrs})


def test_kit_catches_unnormalisable_psf():
    import torch

    cls = _broken(compute_psf=lambda self: torch.full((1, *self.geometry.grid), float("nan"), dtype=self.optics_dtype))
    with pytest.raises(Exception, match="NaN|non-finite"):
        check_encoder(cls, checks=["psf"])


def test_kit_catches_nonlinear_encoder_flagged_linear():
    cls = _broken(forward=lambda self, scene, height=None, noise=True: self.measure(scene, height) ** 2)
    with pytest.raises(AssertionError, match=r"\[linearity\].*f\(a x \+ b y\)"):
        check_encoder(cls, checks=["linearity"])


def test_kit_catches_dishonest_flags():
    import torch

    def init(self, *a, **k):
        type(self).__mro__[1].__init__(self, *a, **k)
        self.gain = torch.nn.Parameter(torch.ones(()))

    with pytest.raises(AssertionError, match="learnable = False but has trainable parameters"):
        check_encoder(_broken(__init__=init), checks=["gradients"])


def test_kit_catches_undocumented_config():
    from dataclasses import dataclass

    from optoenc.encoders.diffuser import DiffuserConfig

    @dataclass
    class Config(DiffuserConfig):
        gain: float = 1.0  # no help text

    with pytest.raises(AssertionError, match=r"without help text: \['gain'\]"):
        check_encoder(_broken(Config=Config), checks=["documented"])


class TestDiffuserThroughBaseClass(EncoderConformance):
    """The pytest base class plugin authors use, on a built-in."""

    encoder_cls = get_registry("encoder").get("diffuser")
    setup = {"fidelity": {"grid": (24, 32)}, "sensor": {"embedding": (6, 8)}}


# --- the new checks catch what the old kit passed -----------------------------------------
@pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")
def test_kit_catches_a_knob_passed_on_in_the_wrong_type_at_reference():
    """A plugin handing fidelity.padding straight to the optics works at `default` ('auto') and fails at
    `reference` (a fraction): the old kit, which ran one preset, passed it."""
    from optoenc import EncoderConfig, MaskEncoder
    from optoenc.devices import WAVELENGTHS_RGB
    from optoenc.optics import intensity_psf

    class Naive(MaskEncoder):
        """Open window, padding knob passed through."""

        name, Config, learnable, linear = "naive", EncoderConfig, False, True

        def compute_psf(self):
            y, x = self.field_coordinates()
            return intensity_psf(torch.ones(len(y), len(x), dtype=y.dtype), WAVELENGTHS_RGB, self.field_spacing,
                                 self.scene_config.distance, self.d2, padding=self.knobs.padding, normalize="power")

    assert check_encoder(Naive, checks=["psf", "linearity"]) == {"psf": "ok", "linearity": "ok"}
    with pytest.raises(AssertionError, match=r"\[presets\].*preset=reference.*padding"):
        check_encoder(Naive, checks=["presets"])


def test_kit_catches_a_cache_key_blind_to_the_psf(monkeypatch):
    from optoenc.training import cache

    diffuser = get_registry("encoder").get("diffuser")
    assert check_encoder(diffuser, checks=["cache_key"]) == {"cache_key": "ok"}
    monkeypatch.setattr(cache, "tensor_digest", lambda t: "same")  # a key of settings only, as a source-text key was
    with pytest.raises(AssertionError, match=r"\[cache_key\].*did not change when the PSF changed"):
        check_encoder(diffuser, checks=["cache_key"])


class _Detached(get_registry("decoder").get("logistic")):
    """A decoder that cuts the gradient to the embedding (a learned encoder would never train)."""

    name = "detached"

    def forward(self, embedding):
        return super().forward(embedding.detach())


class _FlatOnly(get_registry("decoder").get("logistic")):
    """A decoder assuming embeddings of at least 2 x 2."""

    name = "flat_only"

    def build(self):
        from torch import nn

        return nn.Sequential(nn.Unflatten(1, self.in_shape), nn.MaxPool2d(2), nn.Flatten(), nn.LazyLinear(self.num_classes))


def test_decoder_kit_catches_cut_gradients_and_small_embeddings():
    with pytest.raises(AssertionError, match=r"\[gradients\].*reaches the embedding"):
        check_decoder(_Detached, checks=["gradients"])
    with pytest.raises(Exception, match="1, 1, 1|size|Kernel|output"):
        check_decoder(_FlatOnly, checks=["shapes"])


def _splits(train_x, val_x, test_x, digest=""):
    from optoenc.datasets.base import Split, Splits

    y = lambda x: torch.arange(len(x)) % 2  # noqa: E731
    return Splits(Split(train_x, y(train_x)), Split(val_x, y(val_x)), Split(test_x, y(test_x)), 2, digest)


def _dataset(load, config_cls=None):
    from optoenc.datasets.base import Dataset

    return type("Toy", (Dataset,), {"name": "toy", "num_classes": 2, "load": load, "__doc__": "A toy dataset.",
                                    **({"Config": config_cls} if config_cls else {})})


def test_dataset_kit_catches_leaks_ranges_and_a_blind_digest():
    from dataclasses import dataclass

    from optoenc.datasets.base import DatasetConfig
    from optoenc.settings import setting

    g = torch.Generator().manual_seed(0)
    x = torch.rand(6, 1, 4, 4, generator=g)
    leaky = _dataset(lambda self: _splits(x[:4], x[:2], x[4:]))  # val is train[:2]: every val image is in train
    with pytest.raises(AssertionError, match=r"\[disjoint\].*both the train and the val split"):
        check_dataset(leaky, checks=["disjoint"])
    bright = _dataset(lambda self: _splits(255 * x[:3], 255 * x[3:4], 255 * x[4:]))
    with pytest.raises(AssertionError, match=r"\[splits\].*\[0, 1\]"):
        check_dataset(bright, checks=["splits"])

    @dataclass
    class SeedConfig(DatasetConfig):
        seed: int = setting(0, "which procedural images", ge=0)

    def load(self):
        xs = torch.rand(8, 1, 4, 4, generator=torch.Generator().manual_seed(self.config.seed))
        return _splits(xs[:4], xs[4:6], xs[6:], digest="v1")  # a digest that ignores the source (the seed)

    blind = _dataset(load, SeedConfig)
    with pytest.raises(AssertionError, match=r"\[digest\].*same digest"):
        check_dataset(blind, checks=["digest"], variant={"seed": 1})
    honest = _dataset(lambda self: _splits(x[:3], x[3:4], x[4:]))  # no digest: content hashed
    assert check_dataset(honest, checks=["splits", "disjoint", "digest"]) == {"splits": "ok", "disjoint": "ok", "digest": "ok"}


class TestLogisticThroughBaseClass(DecoderConformance):
    """The generated pytest base class of the decoder kit, on a built-in."""

    decoder_cls = get_registry("decoder").get("logistic")
    setup = {"in_shapes": [(1, 1, 1), (1, 3, 4)], "num_classes": 3}


def test_tuple_settings_given_as_lists_are_held_as_tuples_and_lists_stay_lists():
    """A mapping, YAML or the command line gives a list: a tuple-annotated setting holds it as the tuple its default
    is (so Config(**to_dict(c)) == c, the round trip above), Optional included; a list-annotated one stays a list."""
    import dataclasses

    from optoenc.settings import Settings, setting, to_dict

    @dataclasses.dataclass
    class Demo(Settings):
        pair: tuple[int, int] = setting((1, 2), "a pair", ge=0)
        many: tuple[float, ...] | None = setting(None, "any number")  # builtins only: the hints resolve here
        items: list[int] = setting(default_factory=lambda: [1], help="a list")

    d = Demo(pair=[3, 4], many=[0.5, 1.5], items=[5, 6])
    assert d.pair == (3, 4) and d.many == (0.5, 1.5) and d.items == [5, 6]
    assert Demo(**to_dict(Demo())) == Demo()
