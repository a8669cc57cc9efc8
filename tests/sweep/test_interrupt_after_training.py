"""A cell stopped after its training, during the reference check: one line, a marked run, a resumable cell."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap

import pytest

from optoenc.config import compose

# The cell's own process, with the reference check replaced by one that receives SIGINT part way (as a cell does
# when its sweep is stopped: the sweep passes the signal on) and would otherwise go on for seconds.
_CELL = textwrap.dedent("""
    import os, signal, sys, time
    import optoenc.training.run as run_module

    def verify(parts, run, preset):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(10)
        raise AssertionError("the signal did not stop the reference check")

    run_module.verify = verify
    from optoenc.sweep import cell

    sys.exit(cell.main(sys.argv[1:]))
""")


@pytest.mark.filterwarnings("ignore")
def test_a_signal_during_the_reference_check_marks_the_cell_interrupted_in_one_line(tmp_path):
    # Before: a KeyboardInterrupt traceback in the cell's log, and no interrupted.json (only training was guarded).
    run = compose(names={"encoder": "lens", "decoder": "logistic"}, overrides=[
        "dataset.train_size=300", "dataset.val_size=100", "dataset.test_size=100", "trainer.max_epochs=1",
        "trainer.verify_preset=reference", "trainer.progress=false", "output.examples=0", "sensor.embedding=[6,8]",
        "fidelity.grid=[48,64]", "trainer.threads=1"])
    assert run.trainer.verify_preset != run.fidelity.preset  # so the cell runs the reference check
    cell = tmp_path / "cell"
    cell.mkdir()
    (cell / "config.yaml").write_text(run.to_yaml())
    (tmp_path / "cell.py").write_text(_CELL)
    proc = subprocess.run([sys.executable, str(tmp_path / "cell.py"), str(cell)], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 128 + signal.SIGINT, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("optoenc sweep cell interrupted by SIGINT after training (1 of 1 epochs)"), last
    assert last.endswith(f"resume with: optoenc fit --resume {cell}"), last
    marker = json.loads((cell / "interrupted.json").read_text())
    assert marker["signal"] == "SIGINT" and marker["epoch"] == 1
    assert json.loads((cell / "status.json").read_text())["state"] == "interrupted"
    assert not (cell / "summary.json").exists() and (cell / "checkpoints" / "last.ckpt").is_file()
