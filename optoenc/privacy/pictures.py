"""Pictures of reconstructions (rows: scene, embedding, reconstructions; one column per example) and the frontier."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import torch

from ..training.pictures import new_figure, save_figure

__all__ = ["save_rows", "save_frontier"]


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


def save_frontier(path: str | Path, rows: Sequence[dict], attack: str = "learned", chance: float | None = None) -> Path:
    """Test accuracy against re-identification (``attack``), one curve per encoder over embedding sizes."""
    plt, fig = new_figure((6.4, 4.6))
    ax = fig.add_subplot(111)
    by_enc: dict[str, list[dict]] = {}
    for r in rows:
        if r["attack"] == attack and r.get("test_acc") == r.get("test_acc"):  # not NaN
            by_enc.setdefault(r["encoder"], []).append(r)
    for enc, rs in sorted(by_enc.items()):
        rs = sorted(rs, key=lambda r: _pixels(r["embedding"]))
        xs = [100 * float(r["reid_top1"]) for r in rs]
        ys = [100 * float(r["test_acc"]) for r in rs]
        ax.plot(xs, ys, marker="o", label=enc)
        for r, xv, yv in zip(rs, xs, ys):
            ax.annotate(r["embedding"], (xv, yv), fontsize=6, xytext=(3, 2), textcoords="offset points")
    if chance is not None:
        ax.axvline(100 * chance, color="gray", ls=":", lw=1, label=f"chance {100 * chance:g} %")
    ax.set_xlabel(f"re-identification top-1 by the {attack} attacker [%]")
    ax.set_ylabel("test accuracy [%]")
    ax.set_title("privacy-utility: up and to the left is better")
    ax.legend(fontsize=7)
    return save_figure(plt, fig, path)


def _pixels(embedding: str) -> int:
    a, b = (int(v) for v in str(embedding).split("x"))
    return a * b
