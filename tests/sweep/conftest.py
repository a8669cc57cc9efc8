"""A tiny sweep spec for the tests that run real cells: 300 training digits, a 48 x 64 grid, the lens at 6x8."""

from __future__ import annotations

import pytest

_TINY = """
name: {name}
base:
  dataset: {{train_size: 300, val_size: 100, test_size: 100}}
  trainer: {{max_epochs: {epochs}, verify_preset: null, eval_batch_size: 200{trainer}}}
  fidelity: {{grid: [48, 64]}}
  output: {{examples: 0}}
axes:
  encoder: [lens]
  sensor.embedding: [[6, 8]]
  decoder: [logistic]
{axes}"""


@pytest.fixture
def tiny_spec():
    """``tiny_spec(name, epochs, trainer=", key: value", axes="  seed: [0, 1]\\n")``: the spec's YAML text."""

    def make(name: str = "tiny", epochs: int = 2, trainer: str = "", axes: str = "") -> str:
        return _TINY.format(name=name, epochs=epochs, trainer=trainer, axes=axes)

    return make
