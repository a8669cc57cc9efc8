"""Cause 2: errors from the config layer name the full key path and the value given (never '?')."""

from __future__ import annotations

import pytest

from optoenc.config import compose
from optoenc.errors import ConfigError
from omegaconf import OmegaConf

from faultkit import one_line_error, run


@pytest.mark.parametrize(
    "override,key,value_text,words",
    [
        ("sensor.embedding=[4,4,4]", "sensor.embedding", "[4, 4, 4]", "2 values"),
        ("sensor.embedding=[nan,32]", "sensor.embedding", "nan", "Integer"),
        ("encoder.binary=maybe", "encoder.binary", "'maybe'", "unknown setting"),
        ("encoder.d2=abc", "encoder.d2", "'abc'", "Float"),
        ("seed=hello", "seed", "'hello'", "integer"),
        ("encoder.d2=[1,", "encoder.d2", "[1,", "not a valid value"),
    ],
)
def test_errors_name_key_and_value(override, key, value_text, words):
    with pytest.raises(ConfigError) as err:
        compose(names={"encoder": "fixed_slm"}, overrides=[override])
    msg = str(err.value)
    assert err.value.key == key and value_text in msg and words in msg, msg
    assert "'?'" not in msg and "$VALUE" not in msg


def test_yaml_list_top_level_and_unresolved_interpolation():
    with pytest.raises(ConfigError, match="mapping"):
        compose([OmegaConf.create(["a", "b"])])
    with pytest.raises(ConfigError) as err:
        compose([OmegaConf.create({"encoder": {"d2": "${nope}"}})])
    assert err.value.key == "encoder.d2" and "${nope}" in str(err.value)


@pytest.mark.parametrize(
    "text,needles",
    [
        ("- a\n- b\n", ["--config", "mapping"]),
        pytest.param("seed: hello\n", ["seed", "hello"], marks=pytest.mark.slow),  # in-process: test_errors_name_key_and_value
        pytest.param("encoder:\n  d2: ${nope}\n", ["encoder.d2", "${nope}"], marks=pytest.mark.slow),
    ],
)
def test_cli_config_files(tmp_path, text, needles):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    line = one_line_error(run("fit", "--config", cfg, "--print-config"))
    for n in needles:
        assert n in line


def test_accelerator_without_gpu_is_a_config_error():
    import torch

    from optoenc.training.run import _lightning_trainer

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    run_cfg = compose(names={"encoder": "diffuser"}, overrides=["trainer.accelerator=gpu"])
    with pytest.raises(ConfigError) as err:  # Lightning's refusal used to reach the user as a traceback
        _lightning_trainer(run_cfg, accelerator="gpu", devices="auto", logger=False)
    assert err.value.key == "trainer.accelerator" and err.value.value == "gpu"


@pytest.mark.slow  # Lightning's start-up: the refusal itself is checked in-process above
def test_cli_accelerator_without_gpu_is_a_config_error(tmp_path, tiny):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    line = one_line_error(run("fit", *tiny, "--trainer.accelerator=gpu"))
    assert "trainer.accelerator" in line and "gpu" in line
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # no stub run directory
