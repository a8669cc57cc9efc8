"""Helpers of the fault-injection suite: bad input and faults through the real `optoenc` command and the Python API.

Every CLI case runs the console script in a subprocess (exit code, streams and
messages exactly as a person sees them) with tiny settings (a few
hundred digits, one epoch, a 6 x 8 embedding of the fixed diffuser, whose
embeddings the cache holds after the first run), so each takes seconds.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

#: Tiny run: seconds per CLI call. verify_preset null: no re-simulation at the reference preset.
TINY = [
    "--encoder", "diffuser", "--decoder", "logistic",
    "--dataset.train_size=400", "--dataset.val_size=200", "--dataset.test_size=200",
    "--trainer.max_epochs=1", "--trainer.verify_preset=null", "--trainer.progress=false",
    "--sensor.embedding=[6,8]", "--output.examples=2",
]


def optoenc_cmd() -> list[str]:
    exe = shutil.which("optoenc", path=str(Path(sys.executable).parent)) or shutil.which("optoenc")
    return [exe] if exe else [sys.executable, "-m", "optoenc.cli"]


def run(*args, cwd=None, timeout=300, **kw) -> subprocess.CompletedProcess:
    """``optoenc ARGS`` in a subprocess (text output captured)."""
    return subprocess.run([*optoenc_cmd(), *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=timeout, **kw)


def one_line_error(proc: subprocess.CompletedProcess, code: int = 2, stdout: str = "") -> str:
    """Assert the command failed with ``code``, no traceback, nothing on stdout but ``stdout``, and stderr holding
    one ``optoenc: error:`` line (after the ``run directory:`` line of a run that started); return that line."""
    err = proc.stderr.strip()
    assert proc.returncode == code, (proc.returncode, proc.stdout[-2000:], err[-3000:])
    assert "Traceback" not in err, err
    lines = err.splitlines()
    assert lines and lines[-1].startswith("optoenc: error:"), err
    assert all(ln.startswith("run directory: ") for ln in lines[:-1]), err  # one line, nothing else on stderr
    assert proc.stdout == stdout, proc.stdout[-2000:]  # errors go to stderr only
    return lines[-1]
