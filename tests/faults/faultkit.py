"""Helpers of the fault-injection suite: bad input and faults through the real `optoenc` command and the Python API.

CLI cases run the console script in a subprocess with tiny settings (a few
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


def one_line_error(proc: subprocess.CompletedProcess, code: int = 2) -> str:
    """Assert the CLI failed with ``code`` and one ``optoenc: error:`` line, no traceback; return that line."""
    err = proc.stderr.strip()
    assert proc.returncode == code, (proc.returncode, proc.stdout[-2000:], err[-3000:])
    assert "Traceback" not in err, err
    last = err.splitlines()[-1]
    assert last.startswith("optoenc: error:"), err
    return last




def main(*args) -> subprocess.CompletedProcess:
    """``optoenc ARGS`` in this process (``optoenc.cli.main``): the same code path, without the start-up cost.

    Used for the many variants of a case; each cause also runs the real
    command in a subprocess (:func:`run`).
    """
    import contextlib
    import io

    from optoenc.cli import main as cli_main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_main([str(a) for a in args])
    return subprocess.CompletedProcess(["optoenc", *map(str, args)], code, out.getvalue(), err.getvalue())
