"""A real sweep through the CLI: cells run in their own processes; failures are isolated and reported;
a re-run skips finished cells and re-runs failed ones."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

EXTRA = """cells:
  - {{encoder: lens, sensor.embedding: [3, 4], decoder: logistic, dataset.root: "{missing}"}}
paper:
  - {{where: {{encoder: lens, sensor.embedding: [6, 8], decoder: logistic}}, acc: 42.8}}
"""


def _sweep(*args):
    return subprocess.run([sys.executable, "-m", "optoenc.cli", "sweep", *args], capture_output=True, text=True,
                          timeout=600)


def test_sweep_isolates_failures_skips_finished_and_collects(tmp_path, tiny_spec):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(tiny_spec(trainer=", test_every_epoch: true", axes=EXTRA.format(missing=tmp_path / "no-mnist-here")))
    out = tmp_path / "sweep"
    first = _sweep(str(spec), "--out", str(out), "--workers", "2")
    assert first.returncode == 1, first.stderr  # one cell failed: non-zero, but the other finished
    assert "1 cell(s) failed" in first.stderr
    ok = out / "cells" / "embedding=6x8"
    bad = next(p for p in (out / "cells").iterdir() if p.name.startswith("embedding=3x4"))
    assert (ok / "summary.json").is_file()
    assert json.loads((bad / "status.json").read_text())["state"] == "failed"
    rows = list(csv.DictReader(open(out / "cells.csv")))
    by = {r["cell"]: r for r in rows}
    assert by[ok.name]["state"] == "finished" and by[bad.name]["state"] == "failed"
    assert by[bad.name]["error"]  # the one-line error, e.g. the missing dataset root
    # Per-epoch test accuracy gives the paper's best-test column, never below the selected one.
    assert float(by[ok.name]["best_test_acc"]) >= float(by[ok.name]["test_acc"])
    summary = list(csv.DictReader(open(out / "summary.csv")))
    assert summary[0]["paper_acc"] == "42.8" and summary[0]["seeds"] == "1"
    assert "Failed cells" in (out / "summary.md").read_text()
    # The machine clock of a cell is its process's, launch to exit: at least the run's own clock (training
    # and testing) and the span its status records (the process wrote both from inside). 0.01 s: clock.json
    # keeps two decimals, so its rounding may put it up to 0.005 s under the exact span.
    status = json.loads((ok / "status.json").read_text())
    clock = float(by[ok.name]["clock_s"])
    assert clock >= float(by[ok.name]["wall_time_s"]) and clock >= status["ended"] - status["started"] - 0.01
    assert by[bad.name]["clock_s"]  # a failed cell's process cost time too
    stamp = (ok / "summary.json").stat().st_mtime_ns
    again = _sweep(str(spec), "--out", str(out))
    assert again.returncode == 1
    assert (ok / "summary.json").stat().st_mtime_ns == stamp  # finished: skipped
    assert "FAILED" in again.stderr and bad.name in again.stderr  # failed: re-run
    rows = {r["cell"]: r for r in csv.DictReader(open(out / "cells.csv"))}
    assert float(rows[ok.name]["clock_s"]) == clock  # a skipped cell adds nothing
    assert float(rows[bad.name]["clock_s"]) > float(by[bad.name]["clock_s"])  # a re-run adds its segment
    assert json.loads((bad / "clock.json").read_text())["segments"] == 2
    dry = _sweep(str(spec), "--out", str(out), "--dry-run")
    assert dry.returncode == 0 and "finished" in dry.stdout and "failed" in dry.stdout
    # A sweep directory copied elsewhere (as docs/results/README.md resumes from committed cells) keeps its
    # finished cells: where a cell is stored is not a setting of its run.
    moved = tmp_path / "elsewhere"
    shutil.copytree(out / "cells", moved / "cells")
    dry = _sweep(str(spec), "--out", str(moved), "--dry-run")
    assert dry.returncode == 0
    assert next(line for line in dry.stdout.splitlines() if line.rstrip().endswith(ok.name)).startswith("finished")


@pytest.mark.parametrize("how", ["sigterm-to-the-sweep", "ctrl-c-to-its-group"])
def test_a_stopped_sweep_stops_its_running_cell_and_starts_no_more(tmp_path, how, tiny_spec):
    # A stopped sweep used to drain its queue: the pool's shutdown waited for every pending cell, so a
    # SIGTERM'd sweep went on starting cells, one after another, until all had run. Ctrl-C signals the
    # terminal's whole process group (the cells run in their own sessions and get it from the sweep).
    spec = tmp_path / "long.yaml"
    spec.write_text(tiny_spec("long", 400, axes="  seed: [0, 1, 2]\n"))
    out = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, "-m", "optoenc.cli", "sweep", str(spec), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    first = out / "cells" / "seed=0"
    deadline = time.time() + 300
    while time.time() < deadline and not (first / "checkpoints" / "last.ckpt").is_file():
        time.sleep(0.5)
    assert (first / "checkpoints" / "last.ckpt").is_file(), "the first cell never checkpointed"
    sig = signal.SIGTERM if how.startswith("sigterm") else signal.SIGINT
    if sig == signal.SIGTERM:
        os.kill(proc.pid, sig)  # the sweep only, as a scheduler would
    else:
        os.killpg(proc.pid, sig)  # the sweep leads its own group here, as in a terminal
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError(f"the sweep did not stop within 120 s of {sig.name}")
    assert proc.returncode == 128 + sig, err
    assert f"interrupted by {sig.name}" in err
    status = json.loads((first / "status.json").read_text())
    assert status["state"] == "interrupted", status  # the cell got the signal, saved, and said so
    # The stopped segment's machine time is on the cell's clock (resuming redoes part of it).
    assert json.loads((first / "clock.json").read_text())["segments"] == 1
    for seed in (1, 2):  # never started
        assert not (out / "cells" / f"seed={seed}" / "status.json").is_file()
