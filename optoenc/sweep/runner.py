"""Running a sweep: plan the cells, run what is not finished, in parallel processes or on a cluster.

Every cell runs in its own process (a crash, a leak or a thread setting of
one cell never touches another): locally forked from a server that has
imported what cells need (or ``python -m optoenc.sweep.cell``:
:mod:`optoenc.sweep.launch`), on a cluster through submitit (SLURM, or its local executor). Fixed-encoder
cells share the on-disk embedding cache, whose writes are atomic.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from ..errors import ConfigError
from ..training.rundir import RUN_FILES, atomic_write_text
from .launch import STARTS, launch, resolve_start
from .cells import add_clock, cell_dir, cell_state, claim_cell, compose_cell, config_differences, release_cell
from .spec import Cell, SweepSpec

__all__ = ["PlannedCell", "plan", "run", "thread_budget", "resolve_threads", "cell_threads", "claim",
           "machine_share", "EXECUTORS", "STARTS"]

#: Where cells run: in local processes, or through submitit.
EXECUTORS = ("local", "submitit-local", "slurm")


@dataclass
class PlannedCell:
    cell: Cell
    path: Path
    state: str  #: new, finished, running, interrupted, failed, changed
    config_yaml: str
    run: object  #: the RunConfig

    @property
    def todo(self) -> bool:
        """Whether a sweep run picks it up (a changed cell is refused there unless restarted)."""
        return self.state in ("new", "interrupted", "failed", "changed")


def plan(spec: SweepSpec, sweep_dir: str | Path, only: list[str] | None = None) -> list[PlannedCell]:
    """Every cell (or those whose name matches a glob of ``only``) with its state.

    Composing each cell checks all its settings before anything runs.
    """
    from fnmatch import fnmatchcase

    out = []
    for cell in spec.expand():
        if only and not any(fnmatchcase(cell.name, pat) for pat in only):
            continue
        try:
            run = compose_cell(spec, cell, sweep_dir)
        except ConfigError as err:
            raise ConfigError(f"sweep cell {cell.name}: {err.key}", err.value, err.allowed) from None
        yaml = run.to_yaml()
        path = cell_dir(sweep_dir, cell)
        out.append(PlannedCell(cell, path, cell_state(path, yaml), yaml, run))
    return out


#: ``optoenc sweep --order`` values: the spec's order, or the longest cells (by the sweep's estimate) first.
ORDERS = ("spec", "longest")


def longest_first(planned: list[PlannedCell], seconds: dict[str, float],
                  shares: dict[str, float] | None = None) -> list[PlannedCell]:
    """``planned`` with the cells that take longest first (``seconds``: cell name -> estimated seconds).

    With several workers the sweep ends when its last cell does: started last, a long cell runs on alone
    while the other workers idle; started first, the short cells fill the workers' ends (the longest-
    processing-time rule). Ties and cells without an estimate (missing or NaN: counted as 0) keep the
    spec's order.

    ``shares`` (cell name -> :func:`machine_share`): the cells that hold the whole machine go first, longest
    first among them. Cells start in queue order (:class:`_Budget`), so such a cell queued behind a shared
    one waits for it to end while the other workers' threads idle (measured: a one-thread cell started as a
    two-thread one ended, and the next two-thread cell held one core idle for its 7.5 min).
    """
    def key(p: PlannedCell) -> tuple[bool, float]:
        s = seconds.get(p.cell.name, 0.0)
        alone = shares is not None and shares.get(p.cell.name, 0.0) >= 1.0
        return (not alone, -s if s == s else 0.0)

    return sorted(planned, key=key)


def thread_budget(workers: int, cores: int | None = None) -> int:
    """Torch threads per worker: the machine's cores shared evenly (at least one)."""
    if cores is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores // max(1, workers))


def resolve_threads(workers: int, threads: int | None) -> int:
    """Torch threads per worker: ``threads`` where given (>= 1), else :func:`thread_budget`."""
    if threads is None:
        return thread_budget(workers)
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ConfigError("--threads", threads, "must be an integer >= 1 (torch threads per worker)")
    return threads


def cell_threads(p: PlannedCell, per_worker: int | None) -> int | None:
    """The torch threads ``p`` runs with: its own ``trainer.threads`` where its spec sets one, else the
    sweep's per-worker share (``per_worker``, :func:`resolve_threads`; None: neither, torch's default)."""
    n = p.run.trainer.threads or per_worker
    return None if n is None else int(n)


def claim(threads: int, budget: int) -> int:
    """How much of the sweep's ``budget`` of threads (workers x threads per worker) a cell of ``threads``
    threads holds while it runs: its threads, at most the whole budget (a cell asking for more runs alone)."""
    return max(1, min(int(threads), int(budget)))


def machine_share(p: PlannedCell, workers: int, per_worker: int) -> float:
    """The part of the sweep's threads ``p`` holds while it runs locally (:func:`claim` of its threads, over
    ``workers x per_worker``): ``1 / workers`` for a cell of the per-worker threads, 1 for one that runs alone."""
    budget = workers * per_worker
    return claim(cell_threads(p, per_worker), budget) / budget


class _Budget:
    """The sweep's torch threads, handed to cells in the order they were queued.

    A cell waits until every cell queued before it has started and enough threads are free, so a cell
    asking for the whole budget is not overtaken for ever by smaller ones; :meth:`close` (the sweep
    stops) releases every waiting cell unstarted.
    """

    def __init__(self, total: int) -> None:
        self.free = total
        self.turn = 0  # the queue position whose turn it is
        self.closed = False
        self.cond = threading.Condition()

    def take(self, position: int, n: int) -> bool:
        """Wait for ``position``'s turn and ``n`` free threads, and hold them; False: the sweep stopped."""
        with self.cond:
            self.cond.wait_for(lambda: self.closed or (self.turn == position and self.free >= n))
            if self.closed:
                return False
            self.free -= n
            self.turn += 1
            self.cond.notify_all()
            return True

    def give(self, n: int) -> None:
        with self.cond:
            self.free += n
            self.cond.notify_all()

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()


def _prepare(p: PlannedCell, restart_changed: bool) -> None:
    if p.state == "changed":
        if not restart_changed:
            keys = config_differences((p.path / RUN_FILES["config"]).read_text(), p.config_yaml)
            raise ConfigError(
                "sweep cell", p.cell.name,
                f"{p.path} holds a run of another configuration (differs in {', '.join(keys[:6])}); "
                "use --restart-changed to move it aside and re-run",
            )
        p.path.rename(p.path.with_name(f"{p.path.name}.old-{time.strftime('%Y%m%d-%H%M%S')}"))
        p.state = "new"
    p.path.mkdir(parents=True, exist_ok=True)
    atomic_write_text(p.path / RUN_FILES["config"], p.config_yaml)


class _Running:
    """The local cell processes running now, and whether the sweep is stopping (no new cells then)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.procs: dict[str, object] = {}  # cell name -> its process (Popen-like: :func:`.launch.launch`)
        self.stopping = False

    def stop(self, signum: int) -> None:
        """Start no more cells; pass ``signum`` on to the running ones (each saves a checkpoint and says
        where it stopped) and wait for them to exit."""
        with self.lock:
            self.stopping = True
            procs = list(self.procs.values())
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signum)
        for proc in procs:
            proc.wait()


#: How :func:`run` reports a cell it left to another sweep over the same folder (``ok`` True, this message).
SKIPPED = "skipped"


def _run_local(p: PlannedCell, threads: int, running: _Running, start: str, budget: _Budget, position: int,
               held: int) -> tuple[bool, str]:
    """Run the cell in its own process (``start``: forkserver or subprocess) with ``threads`` torch threads and
    wait for it; its time goes on the cell's clock, launch to exit. It first waits for its turn (``position``)
    and ``held`` of the sweep's threads (``budget``), and gives them back when it ends."""
    if not budget.take(position, held):
        return False, "not started: the sweep was interrupted"
    try:
        other = claim_cell(p.path)  # a second sweep over the same folder may have started or finished it
        if other is not None:
            return True, f"{SKIPPED}: {other}"
        try:
            with running.lock:
                if running.stopping:
                    return False, "not started: the sweep was interrupted"
                launched = time.monotonic()
                proc = launch(p.path, threads, start)
                running.procs[p.cell.name] = proc
            try:
                proc.wait()
            finally:
                add_clock(p.path, time.monotonic() - launched)
                with running.lock:
                    running.procs.pop(p.cell.name, None)
        finally:
            release_cell(p.path)
    finally:
        budget.give(held)
    return proc.returncode == 0, _error(p)


def _error(p: PlannedCell) -> str:
    import json

    try:
        status = json.loads((p.path / "status.json").read_text())
    except (OSError, ValueError):
        return "no status written (killed?)"
    return status.get("error", "") if status.get("state") != "finished" else ""


def _submitit_executor(kind: str, sweep_dir: Path, threads: int, slurm: dict | None):
    try:
        import submitit
    except ImportError:
        raise ConfigError("--executor", kind, "needs submitit: pip install 'optoenc[cluster]'") from None
    folder = sweep_dir / "submitit"
    if kind == "submitit-local":
        ex = submitit.LocalExecutor(folder=str(folder))
        ex.update_parameters(timeout_min=int((slurm or {}).get("timeout_min", 24 * 60)))
    else:
        ex = submitit.AutoExecutor(folder=str(folder), cluster="slurm")
        ex.update_parameters(cpus_per_task=threads, **(slurm or {}))
    return ex


def run(
    planned: Iterable[PlannedCell],
    sweep_dir: str | Path,
    workers: int = 1,
    executor: str = "local",
    restart_changed: bool = False,
    slurm: dict | None = None,
    on_done: Callable[[PlannedCell, bool, str], None] | None = None,
    threads: int | None = None,
    start: str = "auto",
) -> dict[str, str]:
    """Run every unfinished cell; returns ``{cell name: error}`` for the cells that failed.

    A failing cell never stops the others. ``workers`` cells run at once, each with ``threads`` torch
    threads (None: :func:`thread_budget`, the machine's cores split between the workers; give it where
    other work shares the machine, such as a second sweep, so that the threads do not outnumber the cores).
    A cell whose spec sets ``trainer.threads`` runs with that many instead (:func:`cell_threads`) and, run
    locally, holds as many of the sweep's ``workers x threads`` while it runs (:func:`claim`): cells start
    in order, each once the threads it needs are free (a cell asking for them all runs alone).
    ``start``: how a local cell's process starts (:data:`~optoenc.sweep.launch.STARTS`; ``auto``: forked
    from a server that has imported what cells need, where it can be: :mod:`optoenc.sweep.launch`).
    """
    if executor not in EXECUTORS:
        raise ConfigError("--executor", executor, f"one of {', '.join(EXECUTORS)}")
    if workers < 1:
        raise ConfigError("--workers", workers, "must be >= 1")
    threads = resolve_threads(workers, threads)
    todo = [p for p in planned if p.todo]
    starts = [resolve_start(start, p.run) for p in todo]  # refused before any cell runs
    for p in todo:
        _prepare(p, restart_changed)
    failures: dict[str, str] = {}

    def done(p: PlannedCell, ok: bool, err: str) -> None:
        if not ok:
            failures[p.cell.name] = err
        if on_done is not None:
            on_done(p, ok, err)

    if executor == "local":
        running = _Running()
        total = workers * threads
        budget = _Budget(total)
        pool = ThreadPoolExecutor(max_workers=workers)
        try:
            futures = {}
            for i, (p, s) in enumerate(zip(todo, starts)):
                n = cell_threads(p, threads)
                futures[pool.submit(_run_local, p, n, running, s, budget, i, claim(n, total))] = p
            for fut in as_completed(futures):
                ok, err = fut.result()
                done(futures[fut], ok, err)
        except BaseException as err:  # SIGINT / SIGTERM (Interrupted, KeyboardInterrupt): stop, not drain the queue
            pool.shutdown(wait=False, cancel_futures=True)
            budget.close()  # cells waiting for threads start no more (the cancelled ones never take their turn)
            running.stop(getattr(err, "signum", signal.SIGINT if isinstance(err, KeyboardInterrupt) else signal.SIGTERM))
            raise
        pool.shutdown()
        return failures
    from .cell import run_cell_clocked

    ex = _submitit_executor(executor, Path(sweep_dir), threads, slurm)
    jobs = []
    for p in todo:
        n = cell_threads(p, threads)
        if executor == "slurm":
            ex.update_parameters(cpus_per_task=n)  # each job asks for its cell's threads
        jobs.append((p, ex.submit(run_cell_clocked, str(p.path), n)))
    for p, job in jobs:
        try:
            job.result()
            done(p, True, "")
        except Exception:  # submitit wraps the cell's exception; the status file has its line
            done(p, False, _error(p) or "failed (see the submitit logs)")
    return failures
