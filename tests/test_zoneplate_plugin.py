"""The mask plugin (plugins/optoenc-zoneplate): ~20 lines of physics, registered, drawn, installable."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from optoenc import plugins

PLUGIN_DIR = Path(__file__).resolve().parents[1] / "plugins" / "optoenc-zoneplate"


@pytest.fixture
def zoneplate(monkeypatch):
    """The plugin registered in the process-wide host from its source tree (no install)."""
    monkeypatch.syspath_prepend(str(PLUGIN_DIR / "src"))
    plugins.reset()
    if "zone_plate" not in plugins.get_registry("encoder"):
        from optoenc_zoneplate import plugin

        info = plugins.register_plugin(plugin, name="zoneplate")
        assert info.ok, info.error
    yield plugins.get_registry("encoder").get("zone_plate")
    plugins.reset()


def test_the_physics_is_a_mask_and_a_config():
    """The encoder module holds a Config and one mask() method: no grid, padding, propagation or integration code."""
    import ast

    tree = ast.parse((PLUGIN_DIR / "src" / "optoenc_zoneplate" / "zoneplate.py").read_text())
    (cls,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "ZonePlate"]
    assert [n.name for n in cls.body if isinstance(n, ast.FunctionDef)] == ["mask"]
    physics = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    assert sum(n.end_lineno - n.lineno + 1 for n in physics) <= 25


@pytest.mark.filterwarnings("ignore::optoenc.optics.SamplingWarning")
def test_psf_command_draws_the_psf_and_the_mask(zoneplate, tmp_path, capsys):
    from optoenc.cli import main

    out = tmp_path / "zp.png"
    assert main(["psf", "--encoder", "zone_plate", "--out", str(out), "--fidelity.preset=fast"]) == 0
    assert out.stat().st_size > 0 and (tmp_path / "zp_mask.png").stat().st_size > 0  # mask() is the picture hook


@pytest.mark.slow
def test_pip_install_and_entry_point(tmp_path):
    """A real ``pip install`` into a temporary ``--target`` (offline, no build isolation), found by ``optoenc encoders``."""
    import shutil

    source, target = tmp_path / "optoenc-zoneplate", tmp_path / "site"
    shutil.copytree(PLUGIN_DIR, source, ignore=shutil.ignore_patterns("__pycache__", "build", "*.egg-info"))
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", "--no-build-isolation"]
    subprocess.run([*pip, "--target", str(target), str(source)], check=True, cwd=tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(target), os.environ.get("PYTHONPATH")]))}
    env["OPTOENC_STRICT_PLUGINS"] = "1"
    out = subprocess.run([sys.executable, "-m", "optoenc.cli", "encoders"], env=env, capture_output=True, text=True,
                         check=True, cwd=tmp_path).stdout
    assert "zone_plate" in out and "(from zoneplate)" in out
