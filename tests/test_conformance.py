"""Every registered encoder passes optoenc's conformance kit (optoenc.testing).

The registry is the single source of parametrisation: an encoder registered
by a built-in or an installed plugin is checked here without editing this file.
"""

from __future__ import annotations

import pytest

from optoenc.plugins import get_registry
from optoenc.testing import CHECKS, EncoderConformance, SMALL_SETUP, check_encoder

ENCODERS = get_registry("encoder").names()


@pytest.mark.parametrize("check", list(CHECKS))
@pytest.mark.parametrize("name", ENCODERS)
def test_conformance(name, check):
    cls = get_registry("encoder").get(name)
    assert cls.name == name, f"registered as {name!r} but cls.name is {cls.name!r}"
    reason = CHECKS[check](cls, **SMALL_SETUP)
    if reason is not None:
        pytest.skip(reason)


def test_registry_is_not_empty():
    assert "diffuser" in ENCODERS


def test_check_encoder_reports_every_check():
    report = check_encoder(get_registry("encoder").get("diffuser"), checks=["documented", "linearity", "gradients"])
    assert report == {"documented": "ok", "linearity": "ok", "gradients": "ok"}
    with pytest.raises(KeyError, match="available"):
        check_encoder(get_registry("encoder").get("diffuser"), checks=["nope"])


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
