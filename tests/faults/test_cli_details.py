"""Cause 7: CLI details: exit codes and streams, refused counts, bad CSVs, conflicting names, no stub run directory."""

from __future__ import annotations

import pytest

from optoenc.config import compose
from optoenc.errors import ConfigError

from faultkit import main, one_line_error, run


def test_unknown_listing_name_exits_2_on_stderr():
    proc = run("encoders", "nosuch")  # used to exit 0 with the message on stdout
    line = one_line_error(proc)
    assert proc.stdout == "" and "nosuch" in line and "diffuser" in line
    assert one_line_error(main("decoders", "nosuch*", "--json"))


@pytest.mark.parametrize("count", [0, -1])
def test_simulate_count_must_be_positive(tmp_path, count):
    # -1 used to hang, 0 printed paths it never wrote
    args = ("simulate", "--encoder", "diffuser", "--count", count, "--out", tmp_path / "sim")
    proc = run(*args, timeout=120) if count < 0 else main(*args)  # -1 used to hang: a subprocess with a time limit
    assert "--count" in one_line_error(proc) and proc.stdout == ""
    assert not (tmp_path / "sim").exists()


@pytest.mark.parametrize("content", [None, b"\x89PNG\r\n\x1a\n\x00\xff\xfe binary", b"a,b\n1,2\n", b"encoder,kind,grid,wavelengths,error\nx,preset,ax3,1,0.1\n"])
def test_bench_auto_from_bad_csv(tmp_path, content):
    path = tmp_path / "bench.csv"
    if content is not None:
        path.write_bytes(content)
    line = one_line_error(main("bench", "auto", "--encoder", "diffuser", "--from-csv", path))
    assert str(path) in line


def test_bench_auto_from_missing_csv_through_the_command(tmp_path):
    line = one_line_error(run("bench", "auto", "--encoder", "diffuser", "--from-csv", tmp_path / "none.csv"))
    assert "none.csv" in line


def test_encoder_name_conflict():
    # `--encoder diffuser --encoder.name=lens` used to use the diffuser silently
    with pytest.raises(ConfigError, match="conflicts") as err:
        compose(names={"encoder": "diffuser"}, overrides=["encoder.name=lens"])
    assert err.value.key == "encoder.name"
    assert compose(overrides=["encoder.name=lens"]).names["encoder"] == "lens"  # alone it chooses the encoder
    assert compose(names={"encoder": "lens"}, overrides=["encoder.name=lens"]).names["encoder"] == "lens"


def test_cli_encoder_name_conflict(tmp_path):
    line = one_line_error(main("fit", "--encoder", "diffuser", "--encoder.name=lens", "--print-config"))
    assert "encoder.name" in line and "diffuser" in line


def test_failed_start_leaves_no_stub_run_directory(tmp_path, tiny):
    # the dataset is read when the run is built: after the run directory used to be created with config.yaml
    line = one_line_error(main("fit", *tiny, f"--dataset.root={tmp_path / 'no-mnist'}"))
    assert "no-mnist" in line
    runs = tmp_path / "runs"
    assert not runs.exists() or list(runs.iterdir()) == []
