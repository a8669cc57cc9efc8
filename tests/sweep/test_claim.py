"""Two sweeps over one folder: a cell is run by exactly one process (an exclusive claim file), never twice."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import socket
import subprocess
import sys

from optoenc.sweep.cells import CLAIM, claim_cell, release_cell


def _dead_pid() -> int:
    """A process id that runs nothing now: a child that has exited and been reaped."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_claim_is_exclusive_and_released(tmp_path):
    assert claim_cell(tmp_path) is None
    assert json.loads((tmp_path / CLAIM).read_text()) == {"pid": os.getpid(), "host": socket.gethostname()}
    assert "another sweep" in claim_cell(tmp_path)  # held by a live process (this one): not claimed twice
    release_cell(tmp_path)
    assert not (tmp_path / CLAIM).exists() and claim_cell(tmp_path) is None


def test_a_dead_process_claim_is_taken_over_and_a_finished_cell_is_left(tmp_path):
    (tmp_path / CLAIM).write_text(json.dumps({"pid": _dead_pid(), "host": socket.gethostname()}))
    assert claim_cell(tmp_path) is None  # the sweep that claimed it is gone (killed): the cell runs again
    release_cell(tmp_path)
    (tmp_path / "summary.json").write_text("{}")
    assert claim_cell(tmp_path) == "finished by another sweep"


def _race(path: str, barrier, results) -> None:
    barrier.wait()
    results.put(claim_cell(__import__("pathlib").Path(path)))


def test_of_racing_processes_exactly_one_claims_the_cell(tmp_path):
    """Six processes released together by a barrier: O_CREAT | O_EXCL lets one through, whatever the timing."""
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(6), ctx.Queue()
    procs = [ctx.Process(target=_race, args=(str(tmp_path), barrier, results)) for _ in range(6)]
    for p in procs:
        p.start()
    outcomes = [results.get(timeout=60) for _ in procs]
    for p in procs:
        p.join(timeout=60)
    assert sum(o is None for o in outcomes) == 1, outcomes


def test_a_sweep_leaves_a_cell_another_sweep_runs(tmp_path, tiny_spec):
    """The second sweep over a folder, planned while the first runs a cell: it reports the cell as left to the
    other process and trains only the rest (before the claim both trained every cell, into one folder)."""
    spec = tmp_path / "tiny.yaml"
    spec.write_text(tiny_spec(axes="  seed: [0, 1]\n", epochs=1))
    out = tmp_path / "sweep"
    held = out / "cells" / "seed=0"
    held.mkdir(parents=True)
    (held / CLAIM).write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}))  # a live sweep's
    proc = subprocess.run([sys.executable, "-m", "optoenc.cli", "sweep", str(spec), "--out", str(out), "--workers", "1"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert f"left seed=0: skipped: run by another sweep (pid {os.getpid()})" in proc.stderr
    assert not (held / "summary.json").exists() and (out / "cells" / "seed=1" / "summary.json").is_file()
    assert not (out / "cells" / "seed=1" / CLAIM).exists()  # released when its run ended
