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


# ----------------------------------------------------------------------------- help and usage errors


def test_top_level_help_gives_each_command_one_line(capsys):
    from optoenc.cli.main import command_names

    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    for name in command_names():
        (line,) = [ln for ln in lines if ln.split()[:1] == [name]]  # listed once, its help on the same line
        assert len(line.split()) > 2, line


def test_bench_lists_its_benchmarks_and_each_has_its_own_options(capsys):
    code, out, _ = run_cli(capsys, "bench")  # plain `optoenc bench` runs nothing: it lists the benchmarks
    assert code == 0
    for name in ("fidelity", "converge", "speed", "auto", "optics", "precision", "steps", "loop"):
        assert f"    {name}" in out
    helps = {}
    for name in ("fidelity", "speed", "steps", "optics"):
        with pytest.raises(SystemExit):
            main(["bench", name, "--help"])
        helps[name] = capsys.readouterr().out
    assert "--truth-grid" in helps["fidelity"] and "--docs" in helps["fidelity"]
    assert "--threads" in helps["speed"] and "--truth-grid" not in helps["speed"] and "--spec" not in helps["speed"]
    assert "--spec" in helps["steps"] and "--docs" not in helps["steps"] and "--against" not in helps["steps"]
    assert "--encoders" not in helps["optics"] and "--out" not in helps["optics"]


@pytest.mark.parametrize("argv,needles", [
    (["bench", "speed", "--repeats", "x"], ["bench speed", "--repeats", "'x'"]),
    (["bench", "speed", "--truth-grid", "96x128"], ["unrecognized arguments: --truth-grid"]),
    (["bench", "nosuch"], ["nosuch", "fidelity"]),
    (["nosuch"], ["nosuch", "fit"]),
    (["fit", "--resume"], ["--resume", "expected one argument"]),
    (["validate"], ["--run"]),
    (["encoders", "--bogus"], ["--bogus"]),
    (["privacy", "--encoder", "lens", "--plaintext-n", "100,x", "--out", "x"], ["--plaintext-n", "100,x"]),
])
def test_usage_errors_are_one_line_exit_2(capsys, argv, needles):
    code, _, err = run_cli(capsys, *argv)
    assert code == 2
    line = err.strip()
    assert "\n" not in line and "Traceback" not in line and line.startswith("optoenc: error:"), err
    for n in needles:
        assert n in line


def test_privacy_and_reconstruct_help_describe_their_own_output_and_seed(capsys):
    helps = {}
    for name in ("privacy", "reconstruct"):
        with pytest.raises(SystemExit):
            main([name, "--help"])
        helps[name] = " ".join(capsys.readouterr().out.split())  # argparse's line wrapping undone
    assert "re-identification" in helps["privacy"] and "noted and skipped" in helps["privacy"]
    assert "Reconstruct scenes" in helps["reconstruct"]
    assert "RUN_DIR/privacy with --run, DIR/privacy with --sweep" in helps["privacy"]
    assert "RUN_DIR/reconstruct with --run" in helps["reconstruct"] and "privacy" not in helps["reconstruct"].split("--out")[-1]
    assert "galleries" in helps["privacy"] and "attackers" in helps["privacy"]
    assert "seed of the sensor noise added to the embeddings" in helps["reconstruct"]


def test_bench_option_defaults_are_the_bench_settings(capsys):
    # The parser holds them as text (building it must not import torch); the bench's settings are the source.
    from optoenc.bench import settings as S
    from optoenc.cli.main import build_parser

    grid = lambda hw: "x".join(str(n) for n in hw)  # noqa: E731
    parser = build_parser()
    for name in ("fidelity", "auto"):
        ns = parser.parse_args(["bench", name])
        assert (ns.digits, ns.encode_count, ns.truth_grid) == (S.DIGITS, S.ENCODE_COUNT, grid(S.TRUTH_GRID))
    assert parser.parse_args(["bench", "fidelity"]).paper_grid == grid(S.PAPER_GRID)
    assert parser.parse_args(["bench", "converge"]).digits == S.DIGITS
    assert parser.parse_args(["bench", "precision"]).embedding == grid(S.EMBEDDING)
    with pytest.raises(SystemExit):
        main(["bench", "fidelity", "--help"])
    assert f"(default: {','.join(S.PRESETS)})" in " ".join(capsys.readouterr().out.split())


def test_building_the_parser_imports_neither_torch_nor_lightning():
    # `optoenc --help` and every refused command line answer without the seconds torch takes to import.
    code = ("import sys; from optoenc.cli.main import build_parser; build_parser(); "
            "print(sorted(m for m in ('torch', 'lightning', 'omegaconf') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"
