"""Cause 7: CLI details: exit codes and streams, refused counts, bad CSVs, conflicting names, no stub run directory."""

from __future__ import annotations

import pytest

from optoenc.config import compose
from optoenc.errors import ConfigError

from faultkit import one_line_error, run


def test_unknown_listing_name_exits_2_on_stderr():
    proc = run("encoders", "nosuch")  # used to exit 0 with the message on stdout
    line = one_line_error(proc)
    assert "nosuch" in line and "diffuser" in line


@pytest.mark.slow
def test_listing_pattern_matching_nothing_exits_2_on_stderr():
    assert "nosuch*" in one_line_error(run("decoders", "nosuch*", "--json"))


@pytest.mark.parametrize("count", [pytest.param(0, marks=pytest.mark.slow), -1])
def test_simulate_count_must_be_positive(tmp_path, count):
    # -1 used to hang, 0 printed paths it never wrote
    args = ("simulate", "--encoder", "diffuser", "--count", count, "--out", tmp_path / "sim")
    proc = run(*args, timeout=120)  # -1 used to hang: a time limit
    assert "--count" in one_line_error(proc)
    assert not (tmp_path / "sim").exists()


BAD_CSVS = {
    "missing": None,
    "binary": b"\x89PNG\r\n\x1a\n\x00\xff\xfe binary",
    "columns": b"a,b\n1,2\n",
    "cell": b"encoder,kind,grid,wavelengths,error\nx,preset,ax3,1,0.1\n",
}


def _bad_csv(tmp_path, what):
    path = tmp_path / "bench.csv"
    if BAD_CSVS[what] is not None:
        path.write_bytes(BAD_CSVS[what])
    return path


@pytest.mark.parametrize("what", list(BAD_CSVS))
def test_bench_csv_reader_refuses_bad_files(tmp_path, what):
    from optoenc.bench.report import read_csv
    from optoenc.errors import DataError

    path = _bad_csv(tmp_path, what)
    with pytest.raises(DataError) as err:  # these used to escape as raw exceptions (tracebacks in the CLI)
        read_csv(path)
    assert str(path) in str(err.value)


@pytest.mark.parametrize("what", [w if w == "missing" else pytest.param(w, marks=pytest.mark.slow) for w in BAD_CSVS])
def test_bench_auto_from_bad_csv(tmp_path, what):
    path = _bad_csv(tmp_path, what)
    line = one_line_error(run("bench", "auto", "--encoder", "diffuser", "--from-csv", path))
    assert str(path) in line


def test_encoder_name_conflict():
    # `--encoder diffuser --encoder.name=lens` used to use the diffuser silently
    with pytest.raises(ConfigError, match="conflicts") as err:
        compose(names={"encoder": "diffuser"}, overrides=["encoder.name=lens"])
    assert err.value.key == "encoder.name"
    assert compose(overrides=["encoder.name=lens"]).names["encoder"] == "lens"  # alone it chooses the encoder
    assert compose(names={"encoder": "lens"}, overrides=["encoder.name=lens"]).names["encoder"] == "lens"


def test_cli_encoder_name_conflict(tmp_path):
    line = one_line_error(run("fit", "--encoder", "diffuser", "--encoder.name=lens", "--print-config"))
    assert "encoder.name" in line and "diffuser" in line


@pytest.mark.slow  # the same path (a refusal while the run is built) is checked by test_labels_outside_the_class_count_...
def test_failed_start_leaves_no_stub_run_directory(tmp_path, tiny):
    # the dataset is read when the run is built: after the run directory used to be created with config.yaml
    line = one_line_error(run("fit", *tiny, f"--dataset.root={tmp_path / 'no-mnist'}"))
    assert "no-mnist" in line
    runs = tmp_path / "runs"
    assert not runs.exists() or list(runs.iterdir()) == []
