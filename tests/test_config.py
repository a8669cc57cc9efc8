"""The run configuration and the library's encoder builder: what a user types is read as meant, or refused in one line."""

from __future__ import annotations

import pytest
import torch

import optoenc
from optoenc.config import SECTIONS, AdversaryConfig, build_encoder, compose, encoder_from_run, load_yaml
from optoenc.errors import ConfigError, PluginError


# --- sizes written as text ------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["24x32", "24X32", "24,32", "[24,32]", "[24, 32]"])
def test_embedding_given_as_text_is_read_as_two_integers(text):
    run = compose(names={"encoder": "fixed_slm"}, overrides=[f"sensor.embedding={text}"])
    assert run.sensor.embedding == (24, 32)
    assert list(run.tree.sensor.embedding) == [24, 32]  # the stored config holds the list, as a file would


def test_embedding_text_in_a_file_and_in_other_tuple_settings():
    from omegaconf import OmegaConf

    run = compose([OmegaConf.create({"sensor": {"embedding": "6x8"}, "fidelity": {"grid": "96x128"}})],
                  names={"encoder": "fixed_slm"})
    assert run.sensor.embedding == (6, 8) and run.fidelity.grid == (96, 128)


@pytest.mark.parametrize("text,words", [("24xz", "must be 2 values, written 24x32 or [24,32]"),
                                        ("24x32x3", "must have 2 values, not 3"), ("0x32", ">= 1")])
def test_bad_embedding_text_names_the_setting(text, words):
    with pytest.raises(ConfigError) as err:
        compose(names={"encoder": "fixed_slm"}, overrides=[f"sensor.embedding={text}"])
    assert err.value.key == "sensor.embedding" and words in str(err.value), str(err.value)


def test_text_is_left_alone_where_a_setting_is_not_a_list():
    run = compose(names={"encoder": "fixed_slm"}, overrides=["trainer.devices=0,1"])  # a string setting
    assert run.trainer.devices == "0,1"


# --- YAML files -----------------------------------------------------------------------------------
def test_yaml_syntax_error_gives_file_line_and_the_parser_message(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("seed: 1\nencoder:\n  d2: [1, 2\n  x: 3\n")
    with pytest.raises(ConfigError) as err:
        load_yaml(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert f"{path}:4:" in msg  # the line the parser stopped at (1-based)
    assert "did not find expected ',' or ']'" in msg and "line 3" in msg  # its message and where the list began


def test_yaml_file_missing_or_not_a_mapping(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_yaml(tmp_path / "none.yaml")
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="mapping of sections"):
        load_yaml(tmp_path / "list.yaml")


# --- a plugin named by its name alone ------------------------------------------------------------
@pytest.mark.parametrize("section,name", [("encoder", "diffuser"), ("decoder", "logistic"), ("dataset", "mnist")])
def test_plugin_section_given_as_a_name(tmp_path, section, name):
    path = tmp_path / "c.yaml"
    path.write_text(f"{section}: {name}\n")
    short = compose([load_yaml(path)])
    (tmp_path / "d.yaml").write_text(f"{section}:\n  name: {name}\n")
    long = compose([load_yaml(tmp_path / "d.yaml")])
    assert short.names[section] == name
    assert short.to_yaml() == long.to_yaml()


def test_plugin_name_on_the_command_line_wins_over_the_file_as_with_a_mapping(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("encoder: diffuser\n")
    assert compose([load_yaml(path)], names={"encoder": "lens"}).names["encoder"] == "lens"
    with pytest.raises(PluginError, match="difuser"):
        compose([load_yaml(path)], overrides=["encoder=difuser"])


# --- the fixed sections -------------------------------------------------------------------------
def test_privacy_section_is_the_adversary_settings_of_config():
    assert SECTIONS["privacy"] is AdversaryConfig
    run = compose(names={"encoder": "fixed_slm"}, overrides=["privacy.adversary_weight=0.5"])
    assert run.privacy == AdversaryConfig(adversary_weight=0.5)


def test_settings_reference_lists_the_fixed_sections():
    from optoenc.cli.catalogue import shared_sections

    assert shared_sections() == SECTIONS and shared_sections() is not SECTIONS  # a copy: the table stays intact


# --- build_encoder --------------------------------------------------------------------------------
def test_build_encoder_by_name_equals_the_run_encoder():
    """The same seeded parameters and the same PSF as the encoder of the equivalent run configuration."""
    enc = optoenc.build_encoder("learned_slm", sensor={"embedding": [6, 8]}, fidelity={"preset": "fast"})
    run = compose(names={"encoder": "learned_slm"}, overrides=["sensor.embedding=[6,8]", "fidelity.preset=fast"])
    ref = encoder_from_run(run)
    assert enc.output_shape == ref.output_shape and enc.output_shape[1:] == (6, 8)
    for (k, a), (_, b) in zip(enc.state_dict().items(), ref.state_dict().items()):
        assert torch.equal(a, b), k
    with torch.no_grad():
        assert torch.equal(enc.psf(), ref.psf())


def test_build_encoder_defaults_and_settings_objects():
    lens = build_encoder("lens")
    assert lens.config == type(lens.config)() and tuple(lens.sensor.embedding) == (24, 32)
    from optoenc.encoders.geometry import SensorConfig

    other = build_encoder("lens", encoder={"d2": 5e-3}, sensor=SensorConfig(embedding=(6, 8)))
    assert other.config.d2 == 5e-3 and other.output_shape[1:] == (6, 8)


def test_build_encoder_bad_input_is_one_clear_error():
    with pytest.raises(ConfigError, match="did you mean sensor"):
        build_encoder("lens", sensr={"embedding": [6, 8]})
    with pytest.raises(ConfigError) as err:
        build_encoder("lens", sensor={"embeding": [6, 8]})
    assert err.value.key == "sensor.embeding" and "known: " in str(err.value)
    with pytest.raises(ConfigError) as err:
        build_encoder("lens", sensor={"embedding": [0, 8]})
    assert err.value.key == "sensor.embedding"
    with pytest.raises(PluginError):
        build_encoder("lense")
    with pytest.raises(ConfigError, match="encoder_from_run"):
        build_encoder(compose(names={"encoder": "lens"}))
