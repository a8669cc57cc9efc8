"""Sweep specs: expansion, cell names, paper figures, errors; cell states on disk."""

from __future__ import annotations

import json

import pytest

from optoenc.errors import ConfigError
from optoenc.sweep import load_spec
from optoenc.sweep.cells import cell_state, compose_cell

SPEC = """
name: demo
base:
  trainer: {max_epochs: 3}
  dataset.train_size: 500
axes:
  - encoder: [lens, diffuser]
    sensor.embedding: [[24, 32], [3, 4]]
    decoder: [fcnn]
  - encoder: [fixed_slm]
    sensor.embedding: [[3, 4]]
    decoder: [fcnn]
    seed: [1, 2]
cells:
  - {encoder: lens, sensor.embedding: [24, 32], decoder: fcnn}
  - {encoder: lens, sensor.embedding: [6, 8], decoder: logistic, augment: "rotate,shift"}
paper:
  - {where: {encoder: lens, sensor.embedding: [24, 32], decoder: fcnn}, acc: 97.7}
"""


@pytest.fixture
def spec(tmp_path):
    p = tmp_path / "demo.yaml"
    p.write_text(SPEC)
    return load_spec(p)


def test_expansion_order_names_and_duplicates(spec):
    cells = spec.expand()
    names = [c.name for c in cells]
    # 4 + 2 from the blocks, the first explicit cell repeats a block cell (dropped), one new explicit cell.
    assert len(cells) == 7 and len(set(names)) == 7
    assert names[0] == "encoder=lens,embedding=24x32,decoder=fcnn"
    assert names[4] == "encoder=fixed_slm,embedding=3x4,decoder=fcnn,seed=1"
    assert names[-1] == "encoder=lens,embedding=6x8,decoder=logistic,augment=rotate_shift"


def test_paper_figure_matches_only_its_cell(spec):
    cells = spec.expand()
    assert spec.paper_figure(cells[0]) == 97.7
    assert all(spec.paper_figure(c) is None for c in cells[1:])


def test_cell_config_layers_base_then_cell(spec, tmp_path):
    cell = spec.expand()[-1]
    run = compose_cell(spec, cell, tmp_path / "sweep")
    assert run.names["encoder"] == "lens" and run.names["decoder"] == "logistic"
    assert run.trainer.max_epochs == 3 and run.dataset.train_size == 500  # nested and dotted base keys
    assert tuple(run.sensor.embedding) == (6, 8) and sorted(run.augment) == ["rotate", "shift"]
    assert run.output.name == cell.name and run.trainer.progress is False


@pytest.mark.parametrize("given", ["rescale", "rescale, rotate", ["rescale", "rotate"]])
def test_augmentations_named_in_the_base_apply_to_every_cell_unless_a_cell_names_its_own(tmp_path, given):
    # A base `augment: rescale` used to be dropped without a word: the cells trained untransformed.
    spec_file = tmp_path / "s.yaml"
    spec_file.write_text(json.dumps({"name": "s", "base": {"augment": given},
                                     "axes": {"encoder": ["lens"]}, "cells": [{"encoder": "lens", "augment": "shift"}]}))
    spec = load_spec(spec_file)
    plain, own = spec.expand()
    expected = ["rescale"] if given == "rescale" else ["rescale", "rotate"]
    assert sorted(compose_cell(spec, plain, tmp_path / "sweep").augment) == expected
    assert sorted(compose_cell(spec, own, tmp_path / "sweep").augment) == ["shift"]


@pytest.mark.parametrize(
    "text,key",
    [
        ("- a\n- b\n", "sweep spec"),
        ("nonsense: 1\n", "sweep.nonsense"),
        ("axes: {encoder: []}\n", "sweep.axes.encoder"),
        ("paper: [{where: {encoder: lens}}]\n", "sweep.paper[0]"),
    ],
)
def test_bad_specs_name_the_key(tmp_path, text, key):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_spec(p)
    assert info.value.key == key


def test_bad_setting_in_a_cell_is_caught_before_anything_runs(tmp_path):
    from optoenc.sweep import plan

    p = tmp_path / "bad.yaml"
    p.write_text("axes: {encoder: [lens], trainer.max_epochs: [0]}\n")
    with pytest.raises(ConfigError, match="max_epochs"):
        plan(load_spec(p), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_cell_states(tmp_path):
    d = tmp_path / "cell"
    d.mkdir()
    assert cell_state(d) == "new"
    (d / "checkpoints").mkdir()
    (d / "checkpoints" / "last.ckpt").write_bytes(b"x")
    assert cell_state(d) == "interrupted"
    (d / "status.json").write_text(json.dumps({"state": "failed", "error": "boom"}))
    assert cell_state(d) == "failed"
    (d / "summary.json").write_text("{}")
    assert cell_state(d) == "finished"
    (d / "config.yaml").write_text("seed: 0\ntrainer: {threads: 1, max_epochs: 2}\n")
    # Thread and progress settings differ per machine: never stale. Anything else is.
    assert cell_state(d, "seed: 0\ntrainer: {threads: 2, max_epochs: 2}\n") == "finished"
    assert cell_state(d, "seed: 0\ntrainer: {threads: 1, max_epochs: 3}\n") == "changed"
    # A setting a newer optoenc added (absent from the stored config) does not make a finished cell stale.
    assert cell_state(d, "seed: 0\ntrainer: {threads: 1, max_epochs: 2, logger: csv}\n") == "finished"
    # Where the cell is stored (its sweep directory moved, the cell renamed) is not a setting of the run.
    (d / "config.yaml").write_text("seed: 0\noutput: {root: /a/cells, name: x}\n")
    assert cell_state(d, "seed: 0\noutput: {root: /b/cells, name: y}\n") == "finished"


def test_an_augmentation_setting_added_later_does_not_make_a_cell_stale(tmp_path):
    d = tmp_path / "cell"
    d.mkdir()
    (d / "summary.json").write_text("{}")
    (d / "config.yaml").write_text("augment: {perspective: {distortion: 0.5, p: 1.0}}\n")
    grown = "augment: {perspective: {distortion: 0.5, p: 1.0, about: object}}\n"
    assert cell_state(d, grown) == "finished"
    # Another value of a shared setting, or another set of augmentations, is a different run.
    assert cell_state(d, "augment: {perspective: {distortion: 0.6, p: 1.0}}\n") == "changed"
    assert cell_state(d, "augment: {rotate: {max_angle: 90.0}}\n") == "changed"
    assert cell_state(d, "augment: {perspective: {distortion: 0.5, p: 1.0}, rotate: {max_angle: 90.0}}\n") == "changed"
    assert cell_state(d, "augment: {}\n") == "changed"


def test_a_cell_trained_by_a_live_process_is_left_alone(tmp_path):
    import os
    import socket

    d = tmp_path / "cell"
    d.mkdir()
    (d / "status.json").write_text(json.dumps({"state": "running", "pid": os.getpid(), "host": socket.gethostname()}))
    assert cell_state(d) == "running"  # this test's own process: alive
    dead = subprocess_pid_that_exited()
    (d / "status.json").write_text(json.dumps({"state": "running", "pid": dead, "host": socket.gethostname()}))
    assert cell_state(d) == "new"  # killed without a checkpoint: run it again


def subprocess_pid_that_exited() -> int:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(proc.stdout)


def test_only_selects_cells_by_glob(spec, tmp_path):
    from optoenc.sweep import plan

    planned = plan(spec, tmp_path / "out", only=["encoder=fixed_slm,*", "*augment=*"])
    assert [p.cell.name for p in planned] == [
        "encoder=fixed_slm,embedding=3x4,decoder=fcnn,seed=1",
        "encoder=fixed_slm,embedding=3x4,decoder=fcnn,seed=2",
        "encoder=lens,embedding=6x8,decoder=logistic,augment=rotate_shift",
    ]
