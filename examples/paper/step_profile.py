"""Time a sweep cell's real training steps: the cell's own run for a few batches, its own data.

    python examples/paper/step_profile.py CELL_DIR [OVERRIDE ...] [--steps 50] [--warm 10] [--profile]

CELL_DIR holds the cell's ``config.yaml`` (a sweep writes one per cell); overrides are dotted settings
(``fidelity.operator_dtype=float32 trainer.precision=32-true``). The run goes to a temporary directory: one
epoch of ``warm + steps`` training batches (plus one of validation and test), and the mean wall time of the
last ``steps`` training batches is printed (``--profile``: with cProfile's top functions by own time).

Unlike ``optoenc sweep --dry-run`` and ``optoenc bench steps``, which time steps on one batch of scenes
repeated, this feeds the cell's own batches, so costs that depend on what each batch holds (kernels compiled
per shape, lit rows, stored windows of varying size) show.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time
from pathlib import Path

import lightning as L
import torch
from omegaconf import OmegaConf

from optoenc.config import compose
from optoenc.training.allocator import keep_freed_memory
from optoenc.training.run import fit


class _StepClock(L.Callback):
    def __init__(self, warm: int, profiler: cProfile.Profile | None):
        self.warm, self.profiler, self.n, self.seconds, self.timed = warm, profiler, 0, 0.0, 0

    def on_train_batch_start(self, *args):
        if self.n >= self.warm and self.profiler:
            self.profiler.enable()
        self.t0 = time.perf_counter()

    def on_train_batch_end(self, *args):
        if self.n >= self.warm:
            self.seconds += time.perf_counter() - self.t0
            self.timed += 1
            if self.profiler:
                self.profiler.disable()
        self.n += 1


def step_seconds(cell: Path, overrides=(), steps: int = 50, warm: int = 10, threads: int = 1,
                 profiler: cProfile.Profile | None = None) -> float:
    """Mean seconds of training batches ``warm .. warm + steps`` of ``cell``'s run (its own data).

    The process keeps freed memory as a sweep cell's does (:func:`~optoenc.training.allocator.keep_freed_memory`).
    """
    keep_freed_memory()
    torch.set_num_threads(threads)
    run = compose([OmegaConf.load(Path(cell) / "config.yaml")],
                  ["trainer.max_epochs=1", f"trainer.limit_train_batches={warm + steps}",
                   "trainer.limit_val_batches=1", "trainer.limit_test_batches=1", *overrides])
    clock = _StepClock(warm, profiler)
    with tempfile.TemporaryDirectory() as tmp:
        fit(run, Path(tmp) / "run", callbacks=(clock,))
    if not clock.timed:
        raise SystemExit(f"{cell}: no training batch timed past the first {warm} (fewer batches, or the epoch "
                         "loop, which has no per-batch hooks: add trainer.loop=batch)")
    return clock.seconds / clock.timed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cell", type=Path)
    p.add_argument("overrides", nargs="*")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--warm", type=int, default=10)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--profile", action="store_true")
    args = p.parse_args()
    prof = cProfile.Profile() if args.profile else None
    s = step_seconds(args.cell, args.overrides, args.steps, args.warm, args.threads, prof)
    print(f"{args.cell.name} {' '.join(args.overrides)}: {1e3 * s:.1f} ms a step (batches {args.warm}-{args.warm + args.steps - 1})")
    if prof:
        pstats.Stats(prof).sort_stats("tottime").print_stats(20)


if __name__ == "__main__":
    main()
