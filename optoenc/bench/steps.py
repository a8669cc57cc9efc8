"""Training steps of a sweep's cells with and without support regions, interleaved (``optoenc bench steps``).

For every cell of a spec (or those ``--only`` names), one optimiser step as
training takes it (:func:`optoenc.sweep.estimate.training_step`: batch of
real test digits, the cell's augmentations, encoder and decoder) is timed
with :attr:`OpticalEncoder.support_regions` off (the whole scene's operator:
the reference) and on, alternately, ``repeats`` times, so a change in the
machine's load hits both alike. Reported per cell: the least disturbed
(minimum) step of each, their ratio, and the epoch's training steps at
that rate. Fixed encoders train on precomputed embeddings: both settings
give the same step there.
"""

from __future__ import annotations

import math
import time
import warnings

import torch

from ..limits import torch_threads

__all__ = ["compare", "format_table"]


def _timed(fn, n: int) -> float:
    best = math.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def compare(spec_path, only=None, repeats: int = 3, steps: int = 3, threads: int = 1, progress=None) -> list[dict]:
    """Rows ``{"cell", "encoder", "whole_s", "support_s", "speedup", "epoch_steps", "whole_epoch_s",
    "support_epoch_s"}`` for the cells of ``spec_path`` matching a glob of ``only``."""
    from fnmatch import fnmatchcase

    from ..plugins import get_registry
    from ..sweep.cells import compose_cell
    from ..sweep.spec import load_spec

    spec = load_spec(spec_path)
    cells = [c for c in spec.expand() if not only or any(fnmatchcase(c.name, p) for p in only)]
    rows: list[dict] = []
    data: dict = {}
    with torch_threads(threads):
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
                from ..sweep.estimate import training_step

                built = training_step(run, tuple(scenes.shape[1:]), scenes)
            enc = built.module.encoder
            built.step()  # warm-up: correlation tensors, allocator
            whole, part = math.inf, math.inf
            for _ in range(repeats):
                enc.support_regions = False
                whole = min(whole, _timed(built.step, steps))
                enc.support_regions = True
                part = min(part, _timed(built.step, steps))
            n = math.ceil(len(data[key].train[0]) / run.trainer.batch_size)
            rows.append({
                "cell": cell.name, "encoder": run.names["encoder"], "whole_s": whole, "support_s": part,
                "speedup": whole / part, "epoch_steps": n, "whole_epoch_s": n * whole, "support_epoch_s": n * part,
            })
    return rows


def format_table(rows: list[dict]) -> str:
    """A markdown table of :func:`compare`'s rows."""
    out = ["| cell | step, whole operator (s) | step, support region (s) | speed-up | training steps of an epoch (s): whole -> support |",
           "| --- | --- | --- | --- | --- |"]
    for r in rows:
        out.append(f"| {r['cell']} | {r['whole_s']:.4f} | {r['support_s']:.4f} | {r['speedup']:.2f}x | "
                   f"{r['whole_epoch_s']:.1f} -> {r['support_epoch_s']:.1f} |")
    return "\n".join(out)
