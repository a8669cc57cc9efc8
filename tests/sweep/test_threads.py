"""Torch threads per sweep worker: split from the machine's cores, or given (``--threads``) where other work
shares the machine; a bad value is a one-line error."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from optoenc.cli import main
from optoenc.errors import ConfigError
from optoenc.sweep import runner
from optoenc.sweep.spec import Cell


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


def _planned(name: str, path: Path, state: str = "new", threads: int | None = None) -> runner.PlannedCell:
    """A planned cell whose run configuration says only its ``trainer.threads`` (None: the sweep's share)."""
    return runner.PlannedCell(Cell(name, ()), path, state, "", SimpleNamespace(trainer=SimpleNamespace(threads=threads)))


def test_each_local_cell_process_gets_the_given_threads(monkeypatch, tmp_path):
    seen = []

    def fake_cell(p, threads, running, start, *budget):  # stands in for the cell's process
        seen.append((p.cell.name, threads))
        return True, ""

    monkeypatch.setattr(runner, "_prepare", lambda p, restart: None)
    monkeypatch.setattr(runner, "_run_local", fake_cell)
    cells = [_planned(f"c{i}", Path(tmp_path, f"c{i}")) for i in range(3)]
    cells.append(_planned("done", Path(tmp_path, "done"), "finished"))
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


class _FakeProcess:
    """A cell process that runs ``seconds`` and records, at its start, which cells were running with it.

    ``seconds`` (0.5) is how long the first cell of a pair runs, so the second, launched from another worker
    thread, starts while it still runs even on a loaded machine (thread start-up there takes milliseconds)."""

    log: list = []
    lock = threading.Lock()
    now: set = set()

    def __init__(self, name: str, threads: int, seconds: float = 0.5):
        self.name, self.threads, self.seconds, self.returncode = name, threads, seconds, None
        with self.lock:
            self.log.append((name, threads, frozenset(self.now)))
            self.now.add(name)

    def wait(self):
        time.sleep(self.seconds)
        with self.lock:
            self.now.discard(self.name)
        self.returncode = 0
        return 0

    def poll(self):
        return self.returncode


def test_a_cell_that_sets_its_threads_gets_them_and_holds_its_share_of_the_sweeps(monkeypatch, tmp_path):
    # Two workers of one thread each: the cell whose spec asks for two threads gets two and runs alone (no other
    # cell starts beside it, and it waits for the running one to end), the others run in pairs; cells start in
    # the queue's order, so the two-thread cell is not overtaken by the one-thread cells queued after it.
    _FakeProcess.log, _FakeProcess.now = [], set()
    monkeypatch.setattr(runner, "_prepare", lambda p, restart: None)
    monkeypatch.setattr(runner, "launch", lambda path, threads, start: _FakeProcess(path.name, threads))
    cells = [_planned(n, tmp_path / n, threads=t) for n, t in [("a", None), ("b", None), ("big", 2), ("c", None), ("d", None)]]
    for p in cells:
        p.path.mkdir()
    assert runner.run(cells, tmp_path, workers=2, threads=1, start="subprocess") == {}
    starts = {name: (threads, beside) for name, threads, beside in _FakeProcess.log}
    order = [name for name, *_ in _FakeProcess.log]
    # Two cells admitted together launch from two worker threads, in either order: the queue's order holds
    # between the pairs and the two-thread cell, not within a pair.
    assert set(order[:2]) == {"a", "b"} and order[2] == "big" and set(order[3:]) == {"c", "d"}
    assert starts["big"] == (2, frozenset()) and all(starts[n][0] == 1 for n in "abcd")
    assert "big" not in starts["c"][1] | starts["d"][1]  # nothing ran beside it
    assert starts[order[1]][1] == {order[0]}  # the one-thread cells still run two at once


def test_a_cell_holds_its_threads_at_most_the_whole_budget_and_keeps_the_threads_it_asked_for():
    assert runner.claim(2, 2) == 2 and runner.claim(8, 2) == 2 and runner.claim(1, 4) == 1
    assert runner.cell_threads(_planned("x", Path("x"), threads=8), 1) == 8
    assert runner.cell_threads(_planned("x", Path("x")), 3) == 3
    assert runner.cell_threads(_planned("x", Path("x")), None) is None  # neither: torch's default
    # Its share of the machine (the dry run's N-worker time): a per-worker cell 1/workers, an 8-thread one all.
    assert runner.machine_share(_planned("x", Path("x")), 2, 1) == 0.5
    assert runner.machine_share(_planned("x", Path("x"), threads=8), 2, 1) == 1.0


def test_a_stopping_sweep_releases_the_cells_waiting_for_threads():
    # Cancelled cells never take their turn; close() must free every cell still waiting (else the sweep's
    # threads would wait for ever at exit).
    budget = runner._Budget(2)
    assert budget.take(0, 2)
    results = []
    waiter = threading.Thread(target=lambda: results.append(budget.take(2, 1)))  # position 1 was cancelled
    waiter.start()
    time.sleep(0.05)
    assert waiter.is_alive()
    budget.close()
    waiter.join(2)
    assert not waiter.is_alive() and results == [False]
