"""The example plugin (plugins/optoenc-example): registered, listed, conformant, and trainable from the CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from optoenc import plugins
from optoenc.cli import catalogue as listing

PLUGIN_DIR = Path(__file__).resolve().parents[1] / "plugins" / "optoenc-example"


@pytest.fixture
def example(monkeypatch):
    """The example plugin registered in the process-wide host, from its source tree (no install)."""
    monkeypatch.syspath_prepend(str(PLUGIN_DIR / "src"))
    plugins.reset()
    if "pinhole" not in plugins.get_registry("encoder"):  # unless it is installed (entry point loaded it)
        from optoenc_example import plugin

        info = plugins.register_plugin(plugin, name="example")
        assert info.ok, info.error
    yield plugins.get_registry("encoder").get("pinhole")
    plugins.reset()


def test_pyproject_advertises_the_entry_point():
    import tomllib

    meta = tomllib.loads((PLUGIN_DIR / "pyproject.toml").read_text())
    assert meta["project"]["entry-points"]["optoenc"] == {"example": "optoenc_example.plugin"}
    assert (PLUGIN_DIR / "README.md").is_file()


def test_listed(example):
    assert example.name == "pinhole"
    text = listing.show("encoder")
    assert "pinhole" in text and "Pinhole camera" in text and "(from example)" in text
    detail = json.loads(listing.show("encoder", "pinhole", as_json=True))
    assert detail["source"] == "example" and detail["linear"] is True and detail["learnable"] is False
    assert {s["name"] for s in detail["settings"]} == {"d2", "diameter", "diffraction"}
    assert "example  [ok]" in listing.plugins() and "encoders: pinhole" in listing.plugins()


def test_conformance(example):
    from optoenc.testing import check_encoder

    report = check_encoder(example)
    assert all(v == "ok" or v.startswith("skipped") for v in report.values()), report


def test_trains_through_the_cli(example, tmp_path, capsys):
    from optoenc.cli import main

    argv = ["fit", "--encoder", "pinhole", "--decoder", "logistic", "--trainer.max_epochs=1"]
    argv += ["--dataset.train_size=500", "--dataset.val_size=200", "--dataset.test_size=500"]
    argv += ["--output.root", str(tmp_path), "--trainer.progress=false", "--trainer.verify_preset=null"]
    assert main(argv) == 0
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["names"]["encoder"] == "pinhole"
    assert summary["encoder"]["diameter"] == pytest.approx(75e-6)
    assert 0.0 <= summary["test_acc"] <= 1.0  # three optimiser steps: a smoke test, not a benchmark
    for name in ("config.yaml", "metrics.csv", "checkpoints/best.ckpt", "checkpoints/last.ckpt", "pictures"):
        assert (run_dir / name).exists(), name
    assert "name: pinhole" in (run_dir / "config.yaml").read_text()
    assert "test_acc" in capsys.readouterr().out


def test_settings_override_reaches_the_encoder(example, capsys):
    from optoenc.cli import main

    assert main(["fit", "--encoder", "pinhole", "--encoder.diameter=1e-4", "--print-config"]) == 0
    assert "diameter: 0.0001" in capsys.readouterr().out
    assert main(["fit", "--encoder", "pinhole", "--encoder.diametre=1e-4", "--print-config"]) == 2
    assert "did you mean diameter" in capsys.readouterr().err


@pytest.mark.slow
def test_pip_install_and_entry_point(tmp_path):
    """A real ``pip install`` of the plugin, found through its entry point by a fresh ``optoenc encoders``.

    Installed into a temporary ``--target`` on PYTHONPATH (offline, no build isolation), so the
    shared environment is not modified.
    """
    import shutil

    source, target = tmp_path / "optoenc-example", tmp_path / "site"
    # build from a copy: setuptools leaves build/ and *.egg-info beside the sources
    shutil.copytree(PLUGIN_DIR, source, ignore=shutil.ignore_patterns("__pycache__", "build", "*.egg-info"))
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", "--no-build-isolation"]
    subprocess.run([*pip, "--target", str(target), str(source)], check=True, cwd=tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(target), os.environ.get("PYTHONPATH")]))}
    env["OPTOENC_STRICT_PLUGINS"] = "1"
    run = [sys.executable, "-m", "optoenc.cli"]
    out = subprocess.run([*run, "encoders"], env=env, capture_output=True, text=True, check=True, cwd=tmp_path).stdout
    assert "pinhole" in out and "(from example)" in out
    out = subprocess.run([*run, "plugins"], env=env, capture_output=True, text=True, check=True, cwd=tmp_path).stdout
    assert "example  [ok]  optoenc_example.plugin  (optoenc-example 0.1.0)" in out
