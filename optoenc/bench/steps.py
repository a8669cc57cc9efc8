"""Training steps of a sweep's cells, a reference and a candidate interleaved (``optoenc bench steps``).

For every cell of a spec (or those ``--only`` names), one optimiser step as
training takes it (:func:`optoenc.sweep.estimate.training_step`: batch of
real test digits, the cell's augmentations, encoder and decoder) is timed
under a reference setting and a candidate one, alternately, ``repeats``
times, so a change in the machine's load hits both alike. ``against``
names the pair (:data:`AGAINST`):

* ``support``: :attr:`OpticalEncoder.support_regions` off (the whole
  scene's operator) -> on (the operator of the batch's support);
* ``banded``: :attr:`OpticalEncoder.banded_operators` off (dense products)
  -> on (the correlation tensors' zeros skipped);
* ``propagation``: ``fidelity.propagation`` ``blas`` (the mask's PSF by 2-D
  FFTs) -> ``separable`` (axis by axis, the LCD encoders);
* ``sorted``: :attr:`OpticalEncoder.sorted_band_rows` off (the banded build's
  blocks of consecutive rows) -> on (blocks of rows sorted by their band);
* ``rows``: :attr:`OpticalEncoder.row_major_operators` off (the sorted build's
  operator copied into the ``(C, a, b, h, w)`` layout) -> on (held and applied
  canvas row by canvas row).
* ``matrix_units``: :attr:`OpticalEncoder.matrix_unit_operators` off (a bfloat16
  operator's banded build) -> on (dense products for the CPU's matrix units, AMX;
  the same step where the operator is not bfloat16 or the CPU has none).
* ``bands``: :attr:`optoenc.augment.Compose.placement_bands` off (transforms redrawn
  every step resample the whole window of the canvas) -> on (each object's band,
  pasted on the window; the same canvases). Other cells take the same step.

The allocator setting (:mod:`optoenc.training.allocator`) cannot be compared
in one process: glibc reuses the free chunks a process has kept whatever its
thresholds are set to later. Compare it with two runs, ``OPTOENC_MALLOC=system``
and ``keep`` (docs/benchmarks.md, "Freed memory kept").

Reported per cell: the least disturbed (minimum) step of each, their ratio,
and the epoch's training steps at that rate. Fixed encoders train on
precomputed embeddings: every setting gives the same step there.
"""

from __future__ import annotations

import math
import time
import warnings

import torch

from ..limits import torch_threads

__all__ = ["compare", "format_table", "AGAINST"]


def _set_support(enc, on: bool) -> None:
    enc.support_regions = on


def _set_banded(enc, on: bool) -> None:
    enc.banded_operators = on


def _set_sorted(enc, on: bool) -> None:
    enc.sorted_band_rows = on


def _set_rows(enc, on: bool) -> None:
    enc.row_major_operators = on


def _set_matrix_units(enc, on: bool) -> None:
    enc.matrix_unit_operators = on


def _set_bands(enc, on: bool) -> None:
    from ..augment import Compose

    Compose.placement_bands = on


def _set_propagation(enc, on: bool) -> None:
    enc.knobs = enc.knobs.replace(propagation="separable" if on else "blas")
    enc.invalidate_psf()


#: ``--against`` choices: (the reference's label, the candidate's label, setter(encoder, on)).
AGAINST = {
    "support": ("whole operator", "support region", _set_support),
    "banded": ("dense build", "banded build", _set_banded),
    "propagation": ("2-D BLAS PSF", "axis-by-axis PSF", _set_propagation),
    "sorted": ("consecutive band rows", "sorted band rows", _set_sorted),
    "rows": ("(C, a, b, h, w) operator", "canvas-row operator", _set_rows),
    "matrix_units": ("banded bfloat16 build", "matrix-unit build", _set_matrix_units),
    "bands": ("whole-window placement", "band placement", _set_bands),
}


def _timed(fn, n: int) -> float:
    best = math.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def compare(spec_path, only=None, repeats: int = 3, steps: int = 3, threads: int = 1, progress=None,
            against: str = "support") -> list[dict]:
    """Rows ``{"cell", "encoder", "against", "reference_s", "candidate_s", "speedup", "epoch_steps",
    "reference_epoch_s", "candidate_epoch_s"}`` for the cells of ``spec_path`` matching a glob of ``only``."""
    from ..errors import ConfigError

    if against not in AGAINST:
        raise ConfigError("--against", against, f"must be one of {', '.join(AGAINST)}")
    toggle = AGAINST[against][2]
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
            ref, cand = math.inf, math.inf
            try:
                for _ in range(repeats):
                    toggle(enc, False)
                    ref = min(ref, _timed(built.step, steps))
                    toggle(enc, True)
                    cand = min(cand, _timed(built.step, steps))
            finally:
                toggle(enc, True)  # every setting compared is on by default
            n = math.ceil(len(data[key].train[0]) / run.trainer.batch_size)
            rows.append({
                "cell": cell.name, "encoder": run.names["encoder"], "against": against, "reference_s": ref,
                "candidate_s": cand, "speedup": ref / cand, "epoch_steps": n, "reference_epoch_s": n * ref,
                "candidate_epoch_s": n * cand,
            })
    return rows


def format_table(rows: list[dict]) -> str:
    """A markdown table of :func:`compare`'s rows."""
    ref, cand, _ = AGAINST[rows[0]["against"] if rows else "support"]
    out = [f"| cell | step, {ref} (s) | step, {cand} (s) | speed-up | training steps of an epoch (s): {ref} -> {cand} |",
           "| --- | --- | --- | --- | --- |"]
    for r in rows:
        out.append(f"| {r['cell']} | {r['reference_s']:.4f} | {r['candidate_s']:.4f} | {r['speedup']:.2f}x | "
                   f"{r['reference_epoch_s']:.1f} -> {r['candidate_epoch_s']:.1f} |")
    return "\n".join(out)
