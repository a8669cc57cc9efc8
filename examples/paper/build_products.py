"""The matrix-unit build's products on a sweep cell's own factors: a product per embedding column against one
product per channel and a copy, forward and backward, side by side in one process.

    python examples/paper/build_products.py CELL_DIR [--threads 2] [--repeats 5] [--steps 10]

CELL_DIR holds the cell's ``config.yaml`` (a sweep writes one per cell; a bfloat16 cell, e.g. Table 3's 24x32
learned SLM). Its correlation tensors and PSF are built as training builds them; then each way of a pass is
timed ``steps`` times in a row, the two alternating ``repeats`` times (a change in the machine's load hits
both), and the least disturbed mean is kept. Printed per pass: both times, their ratio, and whether both give
the same bfloat16 numbers bit for bit.

* forward: ``ry (a h, Hp) x u[b] (Hp, w)`` for each column ``b``, written into the ``(b, a h, w)`` layout,
  against ``ry x u (Hp, b w)`` and its ``(a h, b, w) -> (b, a h, w)`` copy (optoenc's: the same numbers);
* backward: ``ry^T (Hp, a h) x grad[b] (a h, w)`` for each column (optoenc's) against the gradient's
  ``(a h, b w)`` copy and one product (another summation order, so other bfloat16 numbers: not used).
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from pathlib import Path

import torch
from omegaconf import OmegaConf

from optoenc.config import compose
from optoenc.limits import torch_threads


def _mean_seconds(fn, steps: int) -> float:
    t0 = time.perf_counter()
    for _ in range(steps):
        fn()
    return (time.perf_counter() - t0) / steps


def _side_by_side(ref, cand, repeats: int, steps: int) -> tuple[float, float]:
    ref(), cand()  # warm-up
    best_ref, best_cand = math.inf, math.inf
    for _ in range(repeats):
        best_ref = min(best_ref, _mean_seconds(ref, steps))
        best_cand = min(best_cand, _mean_seconds(cand, steps))
    return best_ref, best_cand


def factors(cell: Path):
    """``(psf (C, Hp, Wp), (ry2, ry2^T, rx2, rx2^T), w)`` of ``cell``'s encoder on its augmentation canvas."""
    from optoenc.sweep.estimate import training_step

    run = compose([OmegaConf.load(Path(cell) / "config.yaml")], [])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        built = training_step(run, (1, 28, 28), torch.zeros(2, 1, 28, 28))
    enc = built.module.encoder
    H, W = built.canvas.shape if built.canvas is not None else (28, 28)
    height = built.canvas.height if built.canvas is not None else None
    psf = enc.psf().detach().to(enc.operator_dtype)
    dense = enc._operators.geometry_factors(enc, (H, W), enc.object_height_px(height), psf.device, dense=True)
    return psf, dense, W


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("cell", type=Path)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--steps", type=int, default=10)
    args = p.parse_args(argv)
    if not (args.cell / "config.yaml").is_file():
        raise SystemExit(f"CELL_DIR = {args.cell}: no config.yaml there (a sweep cell's folder holds one)")
    psf, (ry2, ry2_t, rx2, rx2_t), w = factors(args.cell)
    (C, Hp, Wp), ah, b = psf.shape, ry2.shape[0], rx2.shape[0] // w
    u = (psf.reshape(C * Hp, Wp) @ rx2_t).view(C, Hp, b, w)
    u_cols = u.transpose(1, 2).contiguous()  # (C, b, Hp, w): each column's factor whole
    out_cols, out_one = psf.new_empty(C, b, ah, w), psf.new_empty(C, b, ah, w)

    def per_column(left, right, out):  # a product per channel and embedding column, into its block of out
        for c in range(C):
            for j in range(b):
                torch.mm(left, right[c, j], out=out[c, j])

    def fwd_columns():
        per_column(ry2, u_cols, out_cols)

    def fwd_one():
        for c in range(C):
            out_one[c] = (ry2 @ u[c].reshape(Hp, b * w)).view(ah, b, w).transpose(0, 1)

    grad = torch.randn(C, b, ah, w, generator=torch.Generator().manual_seed(0)).to(psf.dtype)
    gu_cols, gu_one = psf.new_empty(C, b, Hp, w), psf.new_empty(C, Hp, b * w)

    def bwd_columns():
        per_column(ry2_t, grad, gu_cols)

    def bwd_one():
        for c in range(C):
            torch.mm(ry2_t, grad[c].transpose(0, 1).reshape(ah, b * w), out=gu_one[c])

    print(f"{args.cell.name}: a h = {ah}, b = {b}, w = {w}, Hp = {Hp}, Wp = {Wp}, {psf.dtype}, {args.threads} threads")
    with torch_threads(args.threads):
        for name, ref, cand, same in (
            ("forward", fwd_columns, fwd_one, lambda: torch.equal(out_cols, out_one)),
            ("backward", bwd_columns, bwd_one, lambda: torch.equal(gu_cols, gu_one.view(C, Hp, b, w).transpose(1, 2))),
        ):
            r, c = _side_by_side(ref, cand, args.repeats, args.steps)
            print(f"{name}: a product per column {1e3 * r:.2f} ms, one product and a copy {1e3 * c:.2f} ms, "
                  f"{r / c:.2f}x; the same numbers: {same()}")


if __name__ == "__main__":
    main()
