"""Pictures of a sweep: accuracy against embedding size per encoder, and learning curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..training.callbacks import read_metrics
from ..training.pictures import new_figure, save_figure
from ..training.rundir import RUN_FILES

__all__ = ["sweep_plots"]


def _pixels(embedding: str) -> int:
    a, b = (int(v) for v in embedding.split("x"))
    return a * b


def accuracy_vs_embedding(summary: list[dict[str, Any]], path: Path) -> Path | None:
    """Test accuracy (mean over seeds, bars = one standard deviation) against embedding pixels, one line per encoder
    (and, where the rows carry a ``paper_acc``, the paper's figures dashed in the same colour).

    ``summary``: the sweep's rows aggregated over seeds (:func:`optoenc.sweep.collect.aggregate`).
    """
    agg = [r for r in summary if r["transform"] == "original" and r["test_acc"] is not None]
    decoders = sorted({r["decoder"] for r in agg})
    if not agg or not all("x" in r["embedding"] for r in agg):
        return None
    plt, fig = new_figure((5.2 * len(decoders), 4.2))
    encoders = sorted({r["encoder"] for r in agg})
    colour = {e: f"C{k % 10}" for k, e in enumerate(encoders)}  # one colour per encoder in every panel
    for i, dec in enumerate(decoders):
        ax = fig.add_subplot(1, len(decoders), i + 1)
        for enc in sorted({r["encoder"] for r in agg if r["decoder"] == dec}):
            pts = sorted((_pixels(r["embedding"]), r["test_acc"], r["test_acc_std"] or 0.0, r["embedding"])
                         for r in agg if r["decoder"] == dec and r["encoder"] == enc)
            ax.errorbar([p[0] for p in pts], [p[1] for p in pts], yerr=[p[2] for p in pts], marker="o",
                        capsize=3, label=enc, color=colour[enc])
            paper = sorted((_pixels(r["embedding"]), r["paper_acc"]) for r in agg
                           if r["decoder"] == dec and r["encoder"] == enc and r.get("paper_acc") is not None)
            if paper:  # the paper's figures where the rows carry them: dashed, same colour
                ax.plot([p[0] for p in paper], [p[1] for p in paper], ls="--", marker="x", lw=1, color=colour[enc],
                        alpha=0.7, label=f"{enc} (paper)")
        ticks = sorted({(_pixels(r["embedding"]), r["embedding"]) for r in agg})
        ax.set_xscale("log")
        ax.set_xticks([t[0] for t in ticks], [t[1] for t in ticks])
        ax.set_xlabel("sensor embedding (rows x columns)")
        ax.set_ylabel("test accuracy (%), validation-selected epoch")
        ax.set_title(f"decoder: {dec}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(plt, fig, path)


def learning_curves(planned, path: Path) -> Path | None:
    """Per-epoch test accuracy (validation where no test column) of every finished cell, one panel per encoder."""
    curves: dict[str, list[tuple[str, list[int], list[float], str]]] = {}
    for p in planned:
        rows = read_metrics(p.path / RUN_FILES["metrics"])
        col = "test_acc" if rows and rows[0].get("test_acc") else "val_acc"
        pts = [(int(r["epoch"]) + 1, 100 * float(r[col])) for r in rows if r.get(col)]
        if pts:
            curves.setdefault(p.run.names["encoder"], []).append(
                (p.cell.name, [e for e, _ in pts], [a for _, a in pts], col))
    if not curves:
        return None
    n = len(curves)
    cols = min(3, n)
    rows_n = (n + cols - 1) // cols
    plt, fig = new_figure((5 * cols, 3.8 * rows_n))
    for i, (enc, cs) in enumerate(sorted(curves.items())):
        ax = fig.add_subplot(rows_n, cols, i + 1)
        for name, ep, acc, col in cs:
            ax.plot(ep, acc, lw=1, label=name.replace(f"encoder={enc},", "")[:40])
        ax.set_title(enc)
        ax.set_xlabel("epoch (completed)")
        ax.set_ylabel(f"{cs[0][3].replace('_', ' ')} (%)")
        ax.grid(alpha=0.3)
        if len(cs) <= 8:
            ax.legend(fontsize=6)
    fig.tight_layout()
    return save_figure(plt, fig, path)


def sweep_plots(summary, planned, sweep_dir: Path) -> dict[str, Path]:
    """``accuracy.png`` from the aggregated rows (``summary``) and ``curves.png`` from the cells' metrics."""
    out = {}
    for key, fn, arg in (("accuracy_plot", accuracy_vs_embedding, summary), ("curves_plot", learning_curves, planned)):
        p = fn(arg, sweep_dir / f"{key.replace('_plot', '')}.png")
        if p is not None:
            out[key] = p
    return out
