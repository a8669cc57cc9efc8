"""How a local sweep starts each cell's process: forked from a preloaded server, or a fresh interpreter.

A cell's process spends seconds importing before it trains (Lightning alone imports torch's compiler
stack; colour-science imports pandas), paid by every cell. With ``forkserver`` the sweep starts one
server process that imports all of that once (:mod:`optoenc.sweep.preload`), and each cell is a fresh
process forked from it: its own memory, threads, signals and exit code, as before, without the imports.
Measured on a 2-core AMD EPYC machine: the imports take 5.3 s of wall time per process (median of 6),
and a sweep of three of Table 1's fixed-encoder cells (lens, 6x8, logistic, 50 epochs, one thread) took
41.8 s forked against 53.9 s with fresh interpreters (median of 3 interleaved pairs, 0.78x). ``subprocess`` runs
``python -m optoenc.sweep.cell`` per cell (where the platform has no forkserver, and for cells that
launch processes of their own: a multi-device run's Lightning launcher re-runs its command line).

Each forked cell gets the sweep's environment and working directory as they are when it starts (the
server's own are those of its start): what the cell reads at run time (``$OPTOENC_CACHE_DIR``, the
allocator setting) is per cell; what a library reads when imported comes from the server's start.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import threading
import types
from pathlib import Path

from ..errors import ConfigError

__all__ = ["STARTS", "resolve_start", "launch"]

#: ``optoenc sweep --start`` values.
STARTS = ("auto", "forkserver", "subprocess")
#: Imported once by the forkserver before it forks any cell.
PRELOAD = ["optoenc.sweep.preload"]
_MAIN_LOCK = threading.Lock()


def _single_process(run) -> bool:
    """Whether the cell trains in its own process alone (Lightning launches no processes of its own)."""
    t = getattr(run, "trainer", None)
    if t is None:
        return True
    return str(getattr(t, "devices", "1")).strip() == "1" and int(getattr(t, "num_nodes", 1)) == 1


def resolve_start(start: str, run=None) -> str:
    """``forkserver`` or ``subprocess`` for a cell of ``run`` (a RunConfig; None: a single-process cell).

    ``auto``: the forkserver where the platform has it and the cell is one process; ``forkserver`` asked
    for a multi-process cell is refused (its launcher would re-run the server's command line).
    """
    if start not in STARTS:
        raise ConfigError("--start", start, f"one of {', '.join(STARTS)}")
    available = "forkserver" in multiprocessing.get_all_start_methods()
    single = _single_process(run)
    if start == "auto":
        return "forkserver" if available and single else "subprocess"
    if start == "forkserver" and not available:
        raise ConfigError("--start", start, f"not on this platform ({sys.platform}); use subprocess or auto")
    if start == "forkserver" and not single:
        raise ConfigError("--start", start, "not for a cell of several processes (trainer.devices or num_nodes > 1); "
                                            "use subprocess or auto")
    return start


def _forked_cell(path: str, threads: int, env: dict, cwd: str) -> None:
    """The forked cell's body: its own process group, the sweep's environment and folder, output to its log."""
    os.setpgid(0, 0)  # as Popen's process_group=0: a terminal's Ctrl-C reaches the sweep, which passes it on
    os.environ.clear()
    os.environ.update(env)
    os.chdir(cwd)
    fd = os.open(Path(path) / "log.txt", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout = open(1, "w", buffering=1, closefd=False)
    sys.stderr = open(2, "w", buffering=1, closefd=False)
    from . import cell

    sys.argv = [cell.__file__, path, str(threads)]
    sys.exit(cell.main(sys.argv[1:]))


class _Forked:
    """A forked cell process with the parts of :class:`subprocess.Popen` the sweep uses."""

    def __init__(self, process) -> None:
        self.process = process
        self._lock = threading.Lock()  # one joiner at a time: the forkserver's exit status is read once

    @property
    def returncode(self) -> int | None:
        return self.process.exitcode

    def poll(self) -> int | None:
        return self.process.exitcode

    def send_signal(self, signum: int) -> None:
        try:
            os.kill(self.process.pid, signum)
        except ProcessLookupError:  # it has just exited
            pass

    def wait(self) -> int:
        with self._lock:
            self.process.join()
        return self.process.exitcode


def launch(path: Path, threads: int, start: str):
    """Start the cell in ``path`` with ``threads`` torch threads; returns a Popen-like handle
    (``poll``, ``send_signal``, ``wait``, ``returncode``). ``start``: forkserver or subprocess
    (:func:`resolve_start`). The cell's output goes to its ``log.txt``."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    if start == "forkserver":
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)  # no effect once the server runs: it keeps what it loaded
        proc = ctx.Process(target=_forked_cell, args=(str(path), int(threads), env, os.getcwd()),
                           name=f"optoenc cell {Path(path).name}", daemon=False)
        with _MAIN_LOCK:
            main = sys.modules["__main__"]
            # multiprocessing re-runs the parent's main script (or module) in every child it starts, so a
            # user's sweep script without an ``if __name__ == "__main__"`` guard would run again in each cell;
            # a cell needs nothing from it (its target and arguments come from optoenc), so it is not told of one.
            sys.modules["__main__"] = types.ModuleType("__main__")
            try:
                proc.start()
            finally:
                sys.modules["__main__"] = main
        return _Forked(proc)
    with open(Path(path) / "log.txt", "ab") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "optoenc.sweep.cell", str(path), str(threads)],
            stdout=log, stderr=subprocess.STDOUT, env=env, stdin=subprocess.DEVNULL,
            process_group=0,  # a group of its own: a terminal's Ctrl-C reaches the sweep only, which passes it on once
        )
