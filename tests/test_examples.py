"""The examples run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from optoenc.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_paper_config_resolves(capsys):
    assert main(["fit", "--config", str(EXAMPLES / "paper_learned_slm.yaml"), "--print-config"]) == 0
    out = capsys.readouterr().out
    assert "name: learned_slm" in out and "max_epochs: 50" in out


def test_library_usage_example_runs(tmp_path):
    proc = subprocess.run([sys.executable, str(EXAMPLES / "library_usage.py"), str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "embedding shape: (4, 1, 12, 16)" in proc.stdout and (tmp_path / "psf.png").exists()
    assert (tmp_path / "run" / "summary.json").exists()


def test_warm_start_example_reaches_the_first_step(tmp_path, monkeypatch):
    monkeypatch.setenv("OPTOENC_CACHE_DIR", str(tmp_path / "cache"))
    cmd = [sys.executable, str(EXAMPLES / "warm_start_timing.py"), "diffuser"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**__import__("os").environ})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "first training step after" in proc.stdout
