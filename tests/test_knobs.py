"""One typed fidelity setting: `FidelityConfig.resolved()` is the encoder's `Knobs`, typed and validated."""

from __future__ import annotations

import json

import pytest

from optoenc.encoders.coded_aperture import CodedAperture
from optoenc.encoders.slm import FixedSLM
from optoenc.errors import ConfigError
from optoenc.encoders.fidelity import FIDELITY_PRESETS, FidelityConfig, Knobs

SMALL_SENSOR = {"embedding": (6, 8)}


def test_resolved_includes_the_encoders_measured_presets():
    # coded_aperture's `reference` is measured oversampled, auto padding (resolved() once gave the table's '1.0', 1).
    measured = CodedAperture.fidelity_presets["reference"]
    assert measured["psf_oversample"] > 1 and measured["padding"] == "auto"
    enc = CodedAperture(fidelity={"preset": "reference"}, sensor=SMALL_SENSOR)
    assert enc.fidelity.resolved() == enc.knobs
    assert enc.knobs.psf_oversample == measured["psf_oversample"] and enc.knobs.padding == "auto"
    assert enc.knobs.grid == (768, 1024) and enc.knobs.dtype == "float64"
    # the unbound config still gives the shared table; explicit knobs beat the encoder's values
    assert FidelityConfig(preset="reference").resolved().psf_oversample == 1
    assert CodedAperture(fidelity={"preset": "reference", "psf_oversample": 1}, sensor=SMALL_SENSOR).knobs.psf_oversample == 1


@pytest.mark.parametrize("preset", list(FIDELITY_PRESETS))
def test_padding_is_auto_or_a_float_never_a_string_number(preset):
    knobs = FixedSLM(fidelity={"preset": preset}, sensor=SMALL_SENSOR).knobs
    assert knobs.padding == "auto" or type(knobs.padding) is float
    assert type(knobs.psf_oversample) is int and knobs.psf_oversample % 2 == 1
    assert FidelityConfig(padding="0.5").resolved().padding == 0.5
    # a mask plugin passes it through at every preset: fraction -> whole pixels per side
    pad = FixedSLM(fidelity={"preset": preset}, sensor=SMALL_SENSOR).fidelity_padding()
    assert pad == "auto" or all(isinstance(p, int) and p >= 0 for p in pad)


def test_knobs_are_frozen_validated_and_round_trip():
    k = FidelityConfig(preset="fast", dtype="float64").resolved()
    assert isinstance(k, Knobs) and k["dtype"] == k.dtype == "float64"  # attribute and the older mapping form
    with pytest.raises(AttributeError):
        k.grid = (1, 1)
    for bad in ({"psf_oversample": 2}, {"padding": "wide"}, {"padding": -0.5}, {"dtype": "float16"}, {"grid": (0, 4)},
                {"operator_dtype": "float16"}, {"propagation": "fft"}):
        with pytest.raises(ConfigError):
            k.replace(**bad)
    # Knobs -> explicit FidelityConfig -> resolved() is the same Knobs, for any encoder's presets
    f = k.replace(psf_oversample=3, padding=0.25).fidelity(preset="reference")
    assert f.resolved() == f.resolved(CodedAperture.fidelity_presets) == k.replace(psf_oversample=3, padding=0.25)
    assert json.loads(json.dumps(k.to_dict())) == {"grid": [192, 256], "dtype": "float64", "padding": "auto", "psf_oversample": 1,
                                                  "operator_dtype": "same", "propagation": "separable"}
    assert hash(k) == hash(FidelityConfig(preset="fast", dtype="float64").resolved())


def test_bad_padding_setting_is_one_clear_error():
    with pytest.raises(ConfigError, match=r"padding = '1,0'.*'auto' or a fraction"):
        FidelityConfig(padding="1,0")
