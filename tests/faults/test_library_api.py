"""Cause 8: the Python API validates at the boundary (measure inputs, settings types, non-finite numbers)."""

from __future__ import annotations

import pytest
import torch

from optoenc.config import encoder_from_run, compose
from optoenc.encoders.lens import LensConfig
from optoenc.errors import ConfigError, DataError
from optoenc.encoders.geometry import SceneConfig, SensorConfig


@pytest.fixture(scope="module")
def encoder():
    return encoder_from_run(compose(names={"encoder": "diffuser"}, overrides=["sensor.embedding=[6,8]"]))


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_measure_refuses_non_finite_pixels(encoder, bad):
    x = torch.rand(2, 1, 28, 28)
    x[1, 0, 3, 4] = bad  # used to return NaN embeddings
    with pytest.raises(DataError, match="NaN or infinite"):
        encoder.measure(x)


@pytest.mark.parametrize("height", [0.0, -0.01, float("nan"), float("inf"), "0.1"])
def test_measure_refuses_bad_height(encoder, height):
    with pytest.raises(ConfigError) as err:
        encoder.measure(torch.rand(1, 1, 28, 28), height=height)
    assert err.value.key == "height"


def test_measure_reads_integer_images_with_the_dtype_scale(encoder):
    # uint8 used to fail with NotImplementedError; 255 is full scale: the same embedding as the float image
    x8 = torch.randint(0, 256, (3, 1, 28, 28), dtype=torch.uint8)
    ref = encoder.measure(x8.to(torch.float32) / 255)
    out = encoder.measure(x8)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, ref)  # same arithmetic after the scaling: float32 round-off only
    x16 = x8.to(torch.int16) * 128  # int16 maximum is 32767: 255 * 128 = 32640 is ~0.996 of full scale
    torch.testing.assert_close(encoder.measure(x16), encoder.measure(x16.to(torch.float32) / 32767))


@pytest.mark.parametrize(
    "cls,kw,key",
    [
        (LensConfig, {"d2": "0.004"}, "d2"),  # a string used to be accepted
        (LensConfig, {"f_number": float("inf")}, "f_number"),  # used to give ZeroDivisionError
        (LensConfig, {"d2": None}, "d2"),
        (SceneConfig, {"distance": [0.4]}, "distance"),
        (SensorConfig, {"embedding": (24, 32, 1)}, "embedding"),
        (SensorConfig, {"adc_bits": 8.5}, "adc_bits"),
    ],
)
def test_settings_refuse_wrong_types_with_config_error(cls, kw, key):
    with pytest.raises(ConfigError) as err:
        cls(**kw)
    assert err.value.key == key


def test_encoder_from_mapping_with_a_string_number():
    from optoenc.plugins import get_registry

    with pytest.raises(ConfigError) as err:
        get_registry("encoder").get("lens")({"d2": "0.004"})
    assert err.value.key == "encoder.d2"
