"""How a local sweep starts its cells: forked from a preloaded server or as fresh interpreters.

Both must give the same run, bit for bit (the fork changes where the imports happen, nothing the cell
computes), and a forked cell must see the sweep's environment as it is when the cell starts, not as
it was when the server started (a second sweep in the same process with another setting).
"""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import pytest

from optoenc import sweep
from optoenc.cli import main
from optoenc.errors import ConfigError
from optoenc.sweep import launch

def _run(tmp_path, name, start, text):
    spec_path = tmp_path / "tiny.yaml"
    spec_path.write_text(text)
    spec = sweep.load_spec(spec_path)
    out = tmp_path / name
    planned = sweep.plan(spec, out)
    failures = sweep.run(planned, out, workers=1, threads=1, start=start)
    return planned[0].path, failures


def _metrics(path):
    rows = list(csv.DictReader(open(path / "metrics.csv")))
    return [{k: v for k, v in r.items() if "time" not in k} for r in rows]


@pytest.mark.slow
@pytest.mark.skipif("forkserver" not in __import__("multiprocessing").get_all_start_methods(), reason="no forkserver")
def test_a_forked_cell_trains_as_a_fresh_interpreter_does_and_sees_the_sweeps_environment_now(tmp_path, monkeypatch,
                                                                                             tiny_spec):
    text = tiny_spec(trainer=", test_every_epoch: true")
    forked, failures = _run(tmp_path, "forked", "forkserver", text)
    assert failures == {}
    fresh, failures = _run(tmp_path, "fresh", "subprocess", text)
    assert failures == {}
    # Same seed, same run: every logged number of every epoch (times aside) and the summary's accuracies.
    assert _metrics(forked) == _metrics(fresh) and len(_metrics(forked)) == 2
    a, b = (json.loads((p / "summary.json").read_text()) for p in (forked, fresh))
    assert (a["test_acc"], a["val_acc"]) == (b["test_acc"], b["val_acc"])
    assert json.loads((forked / "status.json").read_text())["state"] == "finished"
    # The server runs on (it started with the first sweep); a setting changed since reaches the next cell:
    # a bad allocator mode makes the cell refuse it, in one line, in the cell's own log.
    monkeypatch.setenv("OPTOENC_MALLOC", "bogus-mode")
    again, failures = _run(tmp_path, "again", "forkserver", text)
    assert len(failures) == 1
    log = (again / "log.txt").read_text()
    assert "OPTOENC_MALLOC" in log and "bogus-mode" in log


def test_start_methods_are_resolved_per_cell_and_bad_ones_refused():
    one = SimpleNamespace(trainer=SimpleNamespace(devices="1", num_nodes=1))
    two = SimpleNamespace(trainer=SimpleNamespace(devices="2", num_nodes=1))
    assert launch.resolve_start("subprocess", one) == "subprocess"
    # A multi-process cell re-runs its command line for its other ranks: never forked from the server.
    assert launch.resolve_start("auto", two) == "subprocess"
    with pytest.raises(ConfigError, match="--start"):
        launch.resolve_start("forkserver", two)
    with pytest.raises(ConfigError, match="--start.*auto, forkserver, subprocess"):
        launch.resolve_start("fork", one)


def test_the_cli_refuses_an_unknown_start_in_one_line(tmp_path, capsys, tiny_spec):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(tiny_spec())
    code = main(["sweep", str(spec), "--out", str(tmp_path / "s"), "--start", "spawn"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "--start" in err and "spawn" in err
    assert not (tmp_path / "s").exists()  # refused before anything ran or was written


@pytest.mark.slow
@pytest.mark.skipif("forkserver" not in __import__("multiprocessing").get_all_start_methods(), reason="no forkserver")
def test_a_sweep_script_without_a_main_guard_runs_once(tmp_path, tiny_spec):
    # multiprocessing re-runs the parent's main script in each child it starts: a user's script calling
    # sweep.run at its top level would run again in every forked cell (and fail it: a sweep inside a cell).
    import subprocess
    import sys

    spec = tmp_path / "tiny.yaml"
    spec.write_text(tiny_spec(epochs=1, axes="  seed: [0, 1]\n"))
    runs, out = tmp_path / "runs.txt", tmp_path / "out"
    script = tmp_path / "user_script.py"
    script.write_text(
        "from optoenc import sweep\n"
        f"open({str(runs)!r}, 'a').write('ran\\n')\n"
        f"planned = sweep.plan(sweep.load_spec({str(spec)!r}), {str(out)!r})\n"
        f"assert sweep.run(planned, {str(out)!r}, workers=2, threads=1, start='forkserver') == {{}}\n"
    )
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert runs.read_text() == "ran\n"
    assert all((p / "summary.json").is_file() for p in (out / "cells").iterdir())
