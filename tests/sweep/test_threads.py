"""Torch threads per sweep worker: split from the machine's cores, or given (``--threads``) where other work
shares the machine; a bad value is a one-line error."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from optoenc.cli import main
from optoenc.errors import ConfigError
from optoenc.sweep import runner


def test_the_default_splits_the_cores_and_a_given_count_is_kept():
    cores = len(os.sched_getaffinity(0))  # the cores this process may use (Linux, as CI)
    assert runner.resolve_threads(2, None) == max(1, cores // 2)
    assert runner.thread_budget(2, cores=2) == 1 and runner.thread_budget(3, cores=2) == 1  # never below one
    assert runner.thread_budget(1, cores=16) == 16
    assert runner.resolve_threads(2, 3) == 3  # more than cores // workers: the caller's choice


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_a_bad_thread_count_names_the_option(bad):
    with pytest.raises(ConfigError, match="--threads"):
        runner.resolve_threads(2, bad)


def test_each_local_cell_process_gets_the_given_threads(monkeypatch, tmp_path):
    seen = []

    def fake_cell(p, threads, running, start):  # stands in for the cell's process
        seen.append((p.cell, threads))
        return True, ""

    monkeypatch.setattr(runner, "_prepare", lambda p, restart: None)
    monkeypatch.setattr(runner, "_run_local", fake_cell)
    cells = [runner.PlannedCell(f"c{i}", Path(tmp_path, f"c{i}"), "new", "", None) for i in range(3)]
    cells.append(runner.PlannedCell("done", Path(tmp_path, "done"), "finished", "", None))
    assert runner.run(cells, tmp_path, workers=2, threads=1) == {}
    assert sorted(seen) == [("c0", 1), ("c1", 1), ("c2", 1)]  # the finished cell is skipped
    seen.clear()
    runner.run(cells, tmp_path, workers=2)
    assert {t for _, t in seen} == {max(1, len(os.sched_getaffinity(0)) // 2)}


def test_the_cli_refuses_a_bad_thread_count_in_one_line(capsys, tmp_path):
    spec = Path(__file__).resolve().parents[2] / "examples" / "paper" / "table1.yaml"
    code = main(["sweep", str(spec), "--out", str(tmp_path / "s"), "--dry-run", "--threads", "0"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "--threads" in err and "0" in err
