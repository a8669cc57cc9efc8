"""The scene operator's speed-ups, each timed against its plain path on a sweep spec's training steps.

Developer-only. The operator (:mod:`optoenc.encoders.operator`) chooses its
algorithms itself; this script switches one choice off at a time (the
private ``_Paths`` of the encoder's operator) and times one training step of
each cell both ways, interleaved in one process so that a change in the
machine's load hits both alike, and prints the ratios side by side::

    python benchmarks/operator_paths.py examples/paper/table3.yaml --only 'embedding=24x32*' --paths support banded

Paths (reference -> candidate):

* ``support``: the whole scene's operator -> the operator of the batch's nonzero pixels;
* ``banded``: dense products -> the correlation tensors' zeros skipped (build and product);
* ``sorted``: the banded build's blocks of consecutive rows -> rows sorted by their band;
* ``rows``: the sorted build's operator copied into ``(C, a, b, h, w)`` -> held and applied canvas row by row;
* ``matrix_units``: a bfloat16 operator's banded build -> dense products on the CPU's matrix units (AMX);
* ``propagation``: the LCD's PSF by 2-D FFTs (``fidelity.propagation=blas``) -> axis by axis (``separable``);
* ``bands``: transforms redrawn every step resample the whole window -> each object's band.

Every pair gives the same numbers up to the order of float sums (tests/encoders/test_operator_paths.py);
fixed encoders train on precomputed embeddings, so their cells take the same step either way.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import warnings

from optoenc.augment import Compose
from optoenc.bench.steps import cell_steps, timed
from optoenc.limits import torch_threads


def _operator_path(field: str):
    def toggle(enc, on: bool) -> None:
        ops = enc._operators
        ops.paths = dataclasses.replace(ops.paths, **{field: on})
        ops.forget_operator()

    return toggle


def _propagation(enc, on: bool) -> None:
    enc.knobs = enc.knobs.replace(propagation="separable" if on else "blas")
    enc.invalidate_psf()


def _bands(enc, on: bool) -> None:
    Compose.placement_bands = on


#: name -> (the reference's label, the candidate's label, toggle(encoder, on)); on is the default everywhere.
PATHS = {
    "support": ("whole operator", "support region", _operator_path("support_regions")),
    "banded": ("dense build", "banded build", _operator_path("banded")),
    "sorted": ("consecutive band rows", "sorted band rows", _operator_path("sorted_rows")),
    "rows": ("(C, a, b, h, w) operator", "canvas-row operator", _operator_path("row_major")),
    "matrix_units": ("banded bfloat16 build", "matrix-unit build", _operator_path("matrix_units")),
    "propagation": ("2-D BLAS PSF", "axis-by-axis PSF", _propagation),
    "bands": ("whole-window placement", "band placement", _bands),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("spec", help="a sweep spec (e.g. examples/paper/table3.yaml)")
    ap.add_argument("--only", action="append", metavar="GLOB", help="only the cells whose name matches (repeatable)")
    ap.add_argument("--paths", nargs="+", choices=list(PATHS), default=list(PATHS), help="the speed-ups to time")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved rounds (default 3)")
    ap.add_argument("--steps", type=int, default=3, help="steps per round and setting (default 3)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")  # a small grid's sampling warnings, once per cell: not what is timed
    header = "| cell | " + " | ".join(f"{p}: {PATHS[p][0]} -> {PATHS[p][1]} (ms)" for p in args.paths) + " |"
    print(header)
    print("| --- " * (len(args.paths) + 1) + "|")
    with torch_threads(args.threads):
        for cell, _run, built, _n in cell_steps(args.spec, args.only):
            enc = built.module.encoder
            cols = []
            for name in args.paths:
                toggle = PATHS[name][2]
                ref, cand = math.inf, math.inf
                try:
                    for _ in range(args.repeats):
                        toggle(enc, False)
                        ref = min(ref, timed(built.step, args.steps))
                        toggle(enc, True)
                        cand = min(cand, timed(built.step, args.steps))
                finally:
                    toggle(enc, True)  # every path compared is on by default
                cols.append(f"{ref * 1e3:.1f} -> {cand * 1e3:.1f} ({ref / cand:.2f}x)")
            print(f"| {cell.name} | " + " | ".join(cols) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
