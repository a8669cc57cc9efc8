"""Training steps of a sweep's cells (``optoenc bench steps``).

For every cell of a spec (or those ``--only`` names), one optimiser step as
training takes it (:func:`optoenc.sweep.estimate.training_step`: batch of
real test digits, the cell's augmentations, encoder and decoder) is timed
``repeats`` times ``steps`` steps. Reported per cell: the least disturbed
(minimum) step and the epoch's training steps at that rate. Fixed encoders
train on precomputed embeddings: their step is the decoder's.

:func:`cell_steps` builds the steps; ``benchmarks/operator_paths.py`` times
the scene operator's algorithms on them side by side.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Iterator

import torch

from ..limits import torch_threads

__all__ = ["time_steps", "cell_steps", "timed", "format_table"]


def timed(fn, n: int) -> float:
    """The least of ``n`` wall-clock times of ``fn()``, seconds."""
    best = math.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def cell_steps(spec_path, only=None, progress=None) -> Iterator[tuple]:
    """``(cell, run, built, epoch_steps)`` for the cells of ``spec_path`` matching a glob of ``only``, each step
    built and taken once (warm-up: correlation tensors, allocator); ``built.step()`` takes one more."""
    from fnmatch import fnmatchcase

    from ..plugins import get_registry
    from ..sweep.cells import compose_cell
    from ..sweep.estimate import training_step
    from ..sweep.spec import load_spec

    spec = load_spec(spec_path)
    cells = [c for c in spec.expand() if not only or any(fnmatchcase(c.name, p) for p in only)]
    data: dict = {}
    for i, cell in enumerate(cells):
        if progress is not None:
            progress(i, len(cells), cell.name)
        run = compose_cell(spec, cell, "/nonexistent-bench-sweep")  # nothing is written
        key = (run.names["dataset"], repr(run.dataset))
        if key not in data:
            data[key] = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
        scenes = data[key].test[0]
        torch.manual_seed(0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            built = training_step(run, tuple(scenes.shape[1:]), scenes)
        built.step()
        yield cell, run, built, math.ceil(len(data[key].train[0]) / run.trainer.batch_size)


def time_steps(spec_path, only=None, repeats: int = 3, steps: int = 3, threads: int = 1, progress=None) -> list[dict]:
    """Rows ``{"cell", "encoder", "step_s", "epoch_steps", "epoch_s"}`` for the cells of ``spec_path`` matching a
    glob of ``only``: the least of ``repeats`` times ``steps`` steps."""
    rows: list[dict] = []
    with torch_threads(threads):
        for cell, run, built, n in cell_steps(spec_path, only, progress):
            step = timed(built.step, repeats * steps)
            rows.append({"cell": cell.name, "encoder": run.names["encoder"], "step_s": step, "epoch_steps": n,
                         "epoch_s": n * step})
    return rows


def format_table(rows: list[dict]) -> str:
    """A markdown table of :func:`time_steps`'s rows."""
    out = ["| cell | encoder | step (s) | training steps of an epoch | their time (s) |", "| --- | --- | --- | --- | --- |"]
    for r in rows:
        out.append(f"| {r['cell']} | {r['encoder']} | {r['step_s']:.4f} | {r['epoch_steps']} | {r['epoch_s']:.1f} |")
    return "\n".join(out)
