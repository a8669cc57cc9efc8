"""Run one sweep cell in this process: ``python -m optoenc.sweep.cell CELL_DIR [THREADS]``.

The cell's ``config.yaml`` is written by the sweep before it starts. A cell
with a last checkpoint resumes from it; ``status.json`` records running,
finished or failed (with the one-line error), so a sweep re-run knows what
to do. Exit code 0 on success, 1 on failure.
"""

from __future__ import annotations

import os
import sys
import time
import traceback
from pathlib import Path

from ..training.rundir import RUN_FILES, write_json
from .cells import STATUS, add_clock

__all__ = ["run_cell", "run_cell_clocked", "main"]


def run_cell(path: str | Path, threads: int | None = None) -> dict:
    """Train (or resume) the run in ``path``; returns its summary. Raises on failure (status ``failed``)."""
    from omegaconf import OmegaConf

    from ..config import compose
    from ..training.run import checkpoint_path, fit

    path = Path(path)
    started = time.time()
    import socket

    write_json(path / STATUS, {"state": "running", "pid": os.getpid(), "host": socket.gethostname(), "started": started})
    try:
        overrides = [f"trainer.threads={int(threads)}"] if threads else []
        run = compose([OmegaConf.load(path / RUN_FILES["config"])], overrides)
        summary = fit(run, path, resume=checkpoint_path(path, "last").is_file())
    except BaseException as err:
        from ..errors import Interrupted

        line = f"{type(err).__name__}: {err}".splitlines()[0] if str(err) else type(err).__name__
        state = "interrupted" if isinstance(err, (KeyboardInterrupt, Interrupted)) else "failed"
        write_json(path / STATUS, {"state": state, "error": line, "started": started, "ended": time.time(),
                                   "traceback": traceback.format_exc(limit=8)})
        raise
    write_json(path / STATUS, {"state": "finished", "started": started, "ended": time.time()})
    return summary


def run_cell_clocked(path: str | Path, threads: int | None = None) -> dict:
    """:func:`run_cell`, adding its time to the cell's machine clock (``clock.json``): a cluster job's entry.

    A local sweep times the whole process from outside instead (its start-up included); here the clock
    starts once the job's interpreter runs this function.
    """
    t0 = time.monotonic()
    try:
        return run_cell(path, threads)
    finally:
        add_clock(Path(path), time.monotonic() - t0)


def main(argv=None) -> int:
    from ..training.allocator import keep_freed_memory
    from ..training.quiet import quiet_lightning

    from ..errors import Interrupted
    from ..training.resume import raise_on_signals

    args = list(sys.argv[1:] if argv is None else argv)
    quiet_lightning()
    try:
        keep_freed_memory()  # as the CLI's processes ($OPTOENC_MALLOC)
        with raise_on_signals():  # a signal anywhere in the cell (training, testing, the reference check): one line
            run_cell(args[0], int(args[1]) if len(args) > 1 else None)
    except Interrupted as err:  # the run directory is marked (interrupted.json) and says how to resume
        print(f"optoenc sweep cell interrupted by {err.name}{' ' + err.where if err.where else ''}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print("optoenc sweep cell interrupted by SIGINT", file=sys.stderr)
        return 130
    except Exception as err:  # the status file holds the details; one line for the sweep's log
        print(f"optoenc sweep cell failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
