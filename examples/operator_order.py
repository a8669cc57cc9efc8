"""The scene operator's two products in either order, timed side by side (forward and backward).

``operator.scene_operator`` contracts ``ry (a, h, Hp)``, the PSF ``(C, Hp, Wp)`` and ``rx (b, w, Wp)``
in whichever order costs fewer multiply-adds. This script times the rows-first order (the reference,
what every scene used before) against the library's (columns first on both cases here), alternated
in one process, on the learned SLM's real correlation tensors: Table 1's 28 x 28 digit and Table 3's 24x32 canvas
(109 x 146 pixels), one thread. Run: ``python examples/operator_order.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import time
import warnings

import torch


def rows_first(psf, ry, rx):
    C, (a, h, _), (b, w, Wp) = psf.shape[0], ry.shape, rx.shape
    m = torch.einsum("phk,ckl->cphl", ry, psf).reshape(C * a * h, Wp) @ rx.reshape(b * w, Wp).T
    return m.reshape(C, a, h, b, w).transpose(2, 3).contiguous()


def columns_first(psf, ry, rx):
    """``operator.scene_operator``, which takes the columns first on both cases below (asserted there)."""
    from optoenc.encoders import operator

    return operator.scene_operator(psf, ry, rx)


def cases():
    """``(name, psf, ry, rx)``: the learned SLM at 24x32 on Table 1's digit and on Table 3's canvas."""
    from optoenc.config import encoder_from_run, compose
    from optoenc.training.run import canvas_for

    run = compose(names={"encoder": "learned_slm", "decoder": "fcnn"}, overrides=["sensor.embedding=[24,32]"])
    enc = encoder_from_run(run)
    psf = enc.psf().detach()
    canvas = canvas_for(run, enc, (28, 28))
    yield "Table 1, 28 x 28 digit", psf, *enc._operators.geometry_factors(enc, (28, 28), enc.object_height_px(None), "cpu")[:2]
    yield f"Table 3, {canvas.shape[0]} x {canvas.shape[1]} canvas", psf, *enc._operators.geometry_factors(enc,
        canvas.shape, enc.object_height_px(canvas.fov[0]), "cpu")[:2]


def compare(repeats: int = 5, only_first: bool = False) -> list[dict]:
    rows = []
    with torch.random.fork_rng(), warnings.catch_warnings():
        # Table 3's canvas is the field of view: its rounded height overfills the grid by a fraction of a pixel.
        warnings.filterwarnings("ignore", message=".*larger than the field of view.*")
        torch.manual_seed(0)
        for name, psf0, ry, rx in cases():
            (a, h, Hp), (b, w, Wp) = ry.shape, rx.shape
            assert Hp * b * w * (Wp + a * h) < a * h * Wp * (Hp + b * w), name  # the library takes the columns first
            G = torch.randn(psf0.shape[0], ry.shape[0], rx.shape[0], ry.shape[1], rx.shape[1])
            times: dict = {rows_first: [], columns_first: []}
            out = {}
            for _ in range(repeats + 1):  # the first round is warm-up
                for f in times:
                    psf = psf0.clone().requires_grad_()
                    t = time.perf_counter()
                    op = f(psf, ry, rx)
                    (op * G).sum().backward()
                    times[f].append(time.perf_counter() - t)
                    out[f] = op.detach()
            ref, new = min(times[rows_first][1:]), min(times[columns_first][1:])
            err = float((out[columns_first] - out[rows_first]).norm() / out[rows_first].norm())
            rows.append({"case": name, "rows_first_s": ref, "columns_first_s": new, "speedup": ref / new, "rel_diff": err})
            if only_first:
                break
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    print("| case | rows first (ms) | columns first (ms) | speed-up | relative difference |")
    print("| --- | --- | --- | --- | --- |")
    for r in compare(args.repeats):
        print(f"| {r['case']} | {1e3 * r['rows_first_s']:.1f} | {1e3 * r['columns_first_s']:.1f} | "
              f"{r['speedup']:.2f}x | {r['rel_diff']:.1e} |")


if __name__ == "__main__":
    main()
