"""Fixtures of the fault-injection suite (helpers: faultkit.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from faultkit import TINY, run


@pytest.fixture
def tiny(tmp_path):
    """CLI arguments for a tiny run writing under ``tmp_path/runs``."""
    return [*TINY, f"--output.root={tmp_path / 'runs'}"]


@pytest.fixture
def trained(tmp_path_factory):
    """A finished tiny run directory (1 epoch), shared by the tests of one module."""
    return _trained(tmp_path_factory)


_TRAINED: dict = {}


def _trained(factory) -> Path:
    if "dir" not in _TRAINED or not _TRAINED["dir"].exists():
        root = factory.mktemp("trained")
        proc = run("fit", *TINY, f"--output.root={root}", "--output.name=run")
        assert proc.returncode == 0, proc.stderr[-3000:]
        _TRAINED["dir"] = root / "run"
    return _TRAINED["dir"]


@pytest.fixture
def copy_of_trained(tmp_path, tmp_path_factory):
    """A private copy of the finished tiny run (tests may damage it)."""
    dst = tmp_path / "copy"
    shutil.copytree(_trained(tmp_path_factory), dst)
    return dst


@pytest.fixture(autouse=True)
def _env(monkeypatch):
    monkeypatch.setenv("PYTHONWARNINGS", "ignore")
    monkeypatch.delenv("OPTOENC_STRICT_PLUGINS", raising=False)
