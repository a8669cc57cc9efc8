"""Command line: listings, overrides, and one-line errors with exit code 2 (no traceback)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

from optoenc.cli import main


def run_cli(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_encoders_listing_and_details(capsys):
    code, out, _ = run_cli(capsys, "encoders")
    assert code == 0 and "diffuser" in out
    code, out, _ = run_cli(capsys, "encoders", "diffuser")
    assert code == 0
    assert "d2" in out and "0.004" in out and " m " in out  # setting, default, unit
    code, out, _ = run_cli(capsys, "encoders", "--json")
    assert any(r["name"] == "diffuser" for r in json.loads(out))
    code, out, _ = run_cli(capsys, "encoders", "diffuser", "--json")
    d = json.loads(out)
    assert {s["name"] for s in d["settings"]} >= {"d2", "psf_path"} and d["linear"] is True


@pytest.mark.parametrize("cmd", ["decoders", "datasets", "augmentations"])
def test_other_listings(capsys, cmd):
    code, out, _ = run_cli(capsys, cmd)
    assert code == 0 and out.strip()


def test_print_config_resolves_defaults_and_overrides(capsys):
    code, out, _ = run_cli(capsys, "fit", "--encoder", "diffuser", "--decoder", "logistic", "--encoder.d2=5e-3", "--trainer.max_epochs", "3", "--print-config")
    assert code == 0
    assert "d2: 0.005" in out and "max_epochs: 3" in out and "name: diffuser" in out and "name: logistic" in out


def test_config_file_and_command_line_precedence(capsys, tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text("encoder:\n  name: diffuser\n  d2: 0.003\ntrainer:\n  max_epochs: 7\n")
    code, out, _ = run_cli(capsys, "fit", "--config", str(cfg), "--trainer.max_epochs=2", "--print-config")
    assert code == 0 and "d2: 0.003" in out and "max_epochs: 2" in out


@pytest.mark.parametrize(
    "argv,needles",
    [
        (["--encoder", "diffuser", "--encoder.d3=1"], ["encoder.d3", "d2"]),
        (["--encoder", "nosuch"], ["unknown encoder", "diffuser"]),
        (["--encoder", "diffuser", "--encoder.d2=-1"], ["encoder.d2", "-1", "> 0"]),
        (["--encoder", "diffuser", "--trainer.max_epochs=abc"], ["trainer.max_epochs"]),
        (["--encoder", "diffuser", "--sensor.snr_db=nan"], ["sensor.snr_db", "NaN"]),
        (["--encoder", "diffuser", "--encoder.psf_path=/no/such.png", "--trainer.max_epochs=1"], ["encoder.psf_path", "not found"]),
        (["--config", "/no/such.yaml"], ["--config", "not found"]),
    ],
)
def test_bad_input_is_one_line_exit_2(capsys, argv, needles, tmp_path):
    code, out, err = run_cli(capsys, "fit", *argv, f"--output.root={tmp_path}", "--print-config")
    assert code == 2, (out, err)
    line = err.strip()
    assert "\n" not in line and "Traceback" not in line and line.startswith("optoenc: error:")
    for n in needles:
        assert n in line


def test_missing_psf_file_fails_before_training(capsys, tmp_path):
    code, _, err = run_cli(capsys, "psf", "--encoder", "diffuser", "--encoder.psf_path=/no/such.tif", "--out", str(tmp_path / "p.png"))
    assert code == 2 and "encoder.psf_path" in err and "not found" in err


def test_console_script_exit_code_and_no_traceback(tmp_path):
    exe = shutil.which("optoenc") or f"{sys.executable} -m optoenc.cli"
    proc = subprocess.run(
        [*exe.split(), "fit", "--encoder", "diffuser", "--encoder.d3=1"], capture_output=True, text=True, cwd=tmp_path
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert "encoder.d3" in proc.stderr and "d2" in proc.stderr  # the key and its valid neighbour


def test_psf_picture(capsys, tmp_path):
    out = tmp_path / "psf.png"
    code, _, _ = run_cli(capsys, "psf", "--encoder", "diffuser", "--out", str(out))
    assert code == 0 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_version_lists_plugins(capsys):
    code, out, _ = run_cli(capsys, "--version")
    assert code == 0 and "optoenc" in out and "builtins" in out


def test_output_name_is_used_for_the_run_directory(tmp_path, quick_args):
    assert main(["fit", "--encoder", "diffuser", "--decoder", "logistic", "--trainer.max_epochs=1", "--output.name=myrun", *quick_args]) == 0
    assert (tmp_path / "myrun" / "summary.json").exists()
