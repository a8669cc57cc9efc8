"""Shared fixtures: small, fast runs of the real pipeline."""

from __future__ import annotations

import pytest

#: Overrides for a quick run: a few hundred digits, no bars, no re-evaluation.
QUICK = [
    "dataset.train_size=600",
    "dataset.val_size=200",
    "dataset.test_size=300",
    "trainer.progress=false",
    "trainer.verify_preset=null",
    "output.examples=4",
]


@pytest.fixture
def quick():
    """Dotted overrides (``key=value``) for a quick run."""
    return list(QUICK)


@pytest.fixture
def quick_args(tmp_path):
    """CLI arguments for a quick run writing under tmp_path."""
    return [f"--{o}" for o in QUICK] + [f"--output.root={tmp_path}"]


@pytest.fixture(autouse=True)
def _no_strict_plugins(monkeypatch):
    monkeypatch.delenv("OPTOENC_STRICT_PLUGINS", raising=False)
