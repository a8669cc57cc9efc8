"""Cause 5: SIGINT / SIGTERM mid-run: exit 130 / 143, say where the run is and the real resume command, mark the run."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import pytest

from optoenc.training.callbacks import read_metrics

from faultkit import TINY, optoenc_cmd, run


@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_mid_run(tmp_path, sig, code):
    run_dir = tmp_path / "runs" / "r"
    log = open(tmp_path / "err.txt", "w")
    proc = subprocess.Popen(
        [*optoenc_cmd(), "fit", *TINY, "--trainer.max_epochs=100000", f"--output.root={tmp_path / 'runs'}", "--output.name=r"],
        stdout=subprocess.DEVNULL, stderr=log,
    )
    try:
        deadline = time.time() + 240
        while len(read_metrics(run_dir / "metrics.csv")) < 2:  # two epochs done: mid-training for sure
            assert proc.poll() is None and time.time() < deadline, (tmp_path / "err.txt").read_text()[-2000:]
            time.sleep(0.2)
        proc.send_signal(sig)
        rc = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
        log.close()
    err = (tmp_path / "err.txt").read_text()
    # Ctrl-C used to exit 1 silently, SIGTERM 0 silently; the message said the literal RUN_DIR
    assert rc == code, err[-3000:]
    assert "Traceback" not in err and "RUN_DIR" not in err
    lines = err.strip().splitlines()
    assert lines[:-1] == [f"run directory: {run_dir}"], err  # the message is one line, after the run directory
    assert lines[-1].startswith(f"optoenc: interrupted by {sig.name} during epoch ") and f"in {run_dir};" in lines[-1]
    assert lines[-1].endswith(f"resume with: optoenc fit --resume {run_dir}")
    marker = json.loads((run_dir / "interrupted.json").read_text())
    assert marker["signal"] == sig.name and marker["resume"] == f"optoenc fit --resume {run_dir}"
    # two epochs were in metrics.csv: the signal came in epoch 2 (its end hooks) or later; no summary of a finished run
    assert marker["epoch"] >= 1 and not (run_dir / "summary.json").exists()
    if sig == signal.SIGINT:  # the printed command works and completes the run (marker gone)
        done = len(read_metrics(run_dir / "metrics.csv"))
        proc = run("fit", "--resume", run_dir, f"--trainer.max_epochs={done + 1}")
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert not (run_dir / "interrupted.json").exists() and (run_dir / "summary.json").exists()
        assert [int(r["epoch"]) for r in read_metrics(run_dir / "metrics.csv")] == list(range(done + 1))


def test_run_markers_say_the_latest_state(tmp_path):
    """A run directory is marked failed or interrupted by its latest stop, and by neither once it completes."""
    from optoenc.errors import TrainingDiverged
    from optoenc.training.resume import clear_interrupted, mark_failed, mark_interrupted

    mark_failed(tmp_path, TrainingDiverged("training loss became nan\nsecond line"), epoch=3)
    failed = json.loads((tmp_path / "failed.json").read_text())
    assert (failed["state"], failed["message"], failed["epoch"], failed["exit_code"]) == ("failed", "training loss became nan", 3, 1)
    mark_interrupted(tmp_path, "SIGTERM", 4, "optoenc fit --resume x")  # resumed, then stopped: interrupted, no longer failed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["interrupted.json"]
    mark_failed(tmp_path, RuntimeError("boom"), epoch=5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["failed.json"]
    clear_interrupted(tmp_path)  # the run completed
    assert list(tmp_path.iterdir()) == []
