"""Pictures of reconstructions (rows: scene, embedding, reconstructions; one column per example) and the frontier."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import torch

from ..training.pictures import new_figure, save_figure

__all__ = ["save_rows", "save_frontier", "save_threat_frontiers"]


def _show(ax, img: torch.Tensor) -> None:
    e = img.detach().cpu().float()
    if e.shape[0] == 1:
        ax.imshow(e[0].numpy(), cmap="gray", interpolation="nearest")
    else:
        ax.imshow((e / e.max().clamp_min(1e-12)).permute(1, 2, 0).numpy(), interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])


def save_rows(path: str | Path, rows: Sequence[tuple[str, torch.Tensor]], column_titles: Sequence[str] = (),
              title: str = "") -> Path:
    """One row per ``(label, (N, C, h, w) images)``, one column per example, rows labelled on the left."""
    n = max(len(r[1]) for r in rows)
    plt, fig = new_figure((1.4 * n + 1.2, 1.5 * len(rows) + 0.4))
    for i, (label, imgs) in enumerate(rows):
        for j in range(len(imgs)):
            ax = fig.add_subplot(len(rows), n, i * n + j + 1)
            _show(ax, imgs[j])
            if j == 0:
                ax.set_ylabel(label, fontsize=8)
            if i == 0 and j < len(column_titles):
                ax.set_title(column_titles[j], fontsize=8)
            if i == 1 or (i == len(rows) - 1 and j == 0):
                ax.set_xlabel(f"{imgs.shape[-2]}x{imgs.shape[-1]} px", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    return save_figure(plt, fig, path)


def _frontier_panel(ax, rows: Sequence[dict], colour: dict, chance: float | None, xlabel: str) -> None:
    """Test accuracy against re-identification, one curve per encoder over embedding sizes (rows without a test
    accuracy left out); Wilson 95 % intervals as horizontal bars where the rows carry them."""
    for enc in colour:
        rs = sorted((r for r in rows if r["encoder"] == enc and r.get("test_acc") == r.get("test_acc")),
                    key=lambda r: _pixels(r["embedding"]))
        if not rs:
            continue
        xs = [100 * float(r["reid_top1"]) for r in rs]
        ys = [100 * float(r["test_acc"]) for r in rs]
        ci = all(r.get("reid_ci_low") not in ("", None) for r in rs)
        err = [[x - 100 * float(r["reid_ci_low"]) for x, r in zip(xs, rs)],
               [100 * float(r["reid_ci_high"]) - x for x, r in zip(xs, rs)]] if ci else None
        ax.errorbar(xs, ys, xerr=err, marker="o", ms=4, capsize=2, label=enc, color=colour[enc])
        for r, xv, yv in zip(rs, xs, ys):
            ax.annotate(r["embedding"], (xv, yv), fontsize=6, xytext=(3, 2), textcoords="offset points")
    if chance is not None:
        ax.axvline(100 * chance, color="gray", ls=":", lw=1, label=f"chance {100 * chance:g} %")
    ax.set_xlim(-2, 102)  # one scale in every figure and panel: they compare at a glance
    ax.set_xlabel(xlabel)
    ax.set_ylabel("test accuracy [%]")
    ax.legend(fontsize=7)


def _colours(rows: Sequence[dict]) -> dict:
    """One colour per encoder, the same in every panel."""
    return {e: f"C{k % 10}" for k, e in enumerate(sorted({r["encoder"] for r in rows}))}


def save_frontier(path: str | Path, rows: Sequence[dict], attack: str = "learned", chance: float | None = None) -> Path:
    """Test accuracy against re-identification (``attack``), one curve per encoder over embedding sizes."""
    plt, fig = new_figure((6.4, 4.6))
    mine = [r for r in rows if r["attack"] == attack]
    _frontier_panel(fig.add_subplot(111), mine, _colours(mine), chance,
                    f"re-identification top-1 by the {attack} attacker [%]")
    fig.suptitle("privacy-utility: up and to the left is better", fontsize=9)
    return save_figure(plt, fig, path)


def save_threat_frontiers(path: str | Path, best: Sequence[dict], threat_models: Sequence[str],
                          chance: float | None = None) -> Path:
    """One panel per threat model: test accuracy against the re-identification of that threat model's strongest
    attack (``best``: :func:`optoenc.privacy.report.best_per_threat_model`'s rows)."""
    plt, fig = new_figure((4.6 * len(threat_models), 4.4))
    colour = _colours(best)
    for i, threat in enumerate(threat_models):
        ax = fig.add_subplot(1, len(threat_models), i + 1)
        _frontier_panel(ax, [r for r in best if r["threat_model"] == threat], colour, chance,
                        "re-identification top-1, strongest attack [%]")
        ax.set_title(f"threat model: {threat}", fontsize=9)
    fig.suptitle("privacy-utility: up and to the left is better", fontsize=9)
    return save_figure(plt, fig, path)


def _pixels(embedding: str) -> int:
    a, b = (int(v) for v in str(embedding).split("x"))
    return a * b
