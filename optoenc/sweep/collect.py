"""Collecting a sweep: one row per cell, seeds aggregated, CSV + markdown + plots.

All accuracies in the sweep's tables are in percent (the paper's unit);
``summary.json`` of each run keeps fractions. A reconstruction sweep's tables carry
``test_psnr`` (dB) and ``test_ssim`` with their standard deviations over seeds, a sweep under
``sensor.exposure=fixed`` the encoders' ``throughput``; columns no cell fills are left out.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

from ..training.callbacks import read_metrics
from ..training.rundir import RUN_FILES, atomic_write_text
from . import plots
from .cells import STATUS, read_clock
from .runner import PlannedCell
from .spec import SweepSpec, _fmt

__all__ = ["cell_rows", "aggregate", "write_tables", "CELL_COLUMNS", "SUMMARY_COLUMNS"]

CELL_COLUMNS = (
    "cell", "state", "encoder", "embedding", "decoder", "transform", "augment_mode", "precision", "variant", "seed",
    "epochs",
    "best_epoch", "val_acc", "test_acc", "best_test_acc", "reference_test_acc", "paper_acc", "test_psnr", "test_ssim",
    "throughput", "wall_time_s", "epoch_time_s", "clock_s", "error",
)
SUMMARY_COLUMNS = (
    "encoder", "embedding", "decoder", "transform", "augment_mode", "precision", "variant", "seeds", "test_acc", "test_acc_std",
    "best_test_acc", "reference_test_acc", "paper_acc", "diff_vs_paper", "test_psnr", "test_psnr_std", "test_ssim",
    "test_ssim_std", "throughput", "throughput_std", "wall_time_s",
)
#: Columns shown only where some row fills them (a classification sweep has no PSNR; throughput: exposure=fixed).
OPTIONAL_COLUMNS = ("val_acc", "test_acc", "test_acc_std", "best_test_acc", "reference_test_acc", "paper_acc",
                    "diff_vs_paper", "test_psnr", "test_psnr_std", "test_ssim", "test_ssim_std", "throughput",
                    "throughput_std")


def _pct(x: Any) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(100 * float(x), 2)


def precision(run, summary: dict | None = None) -> str:
    """``"<operator dtype>/<trainer precision>"``: ``float32/32-true`` by default, ``bfloat16/bf16-mixed`` fast.

    What the run used: ``summary.json``'s resolved values where it has them (``auto`` depends on the
    machine), else the configuration's.
    """
    from ..encoders.fidelity import FIDELITY_PRESETS

    summary = summary or {}
    fid = summary.get("fidelity") or {}
    op = fid.get("operator_dtype") or run.fidelity.operator_dtype or "same"
    if op == "same":
        op = fid.get("dtype") or run.fidelity.dtype or FIDELITY_PRESETS.get(run.fidelity.preset, {}).get("dtype", run.fidelity.preset)
    return f"{op}/{summary.get('precision') or run.trainer.precision}"


#: Spec keys with columns of their own (or that do not change the experiment): not part of a cell's ``variant``.
_COLUMN_KEYS = {"encoder", "decoder", "dataset", "sensor.embedding", "augment", "trainer.augment_draw", "seed",
                "fidelity.operator_dtype", "trainer.precision", "trainer.verify_preset"}


def variant(cell) -> str:
    """The cell's other settings from the spec's axes (``about=field,sampling=point``); ``""`` for none."""
    return ",".join(f"{k.rsplit('.', 1)[-1]}={_fmt(v)}" for k, v in cell.values if k not in _COLUMN_KEYS)


def cell_rows(spec: SweepSpec, planned: list[PlannedCell]) -> list[dict[str, Any]]:
    """One row per cell with what it measured (empty fields for unfinished cells)."""
    rows = []
    for p in planned:
        run = p.run
        summary, status = {}, {}
        if (p.path / RUN_FILES["summary"]).is_file():
            summary = json.loads((p.path / RUN_FILES["summary"]).read_text())
        if (p.path / STATUS).is_file():
            try:
                status = json.loads((p.path / STATUS).read_text())
            except ValueError:
                status = {}
        metrics = read_metrics(p.path / RUN_FILES["metrics"])
        times = [float(m["time_s"]) for m in metrics if m.get("time_s")]
        mode = run.trainer.augment_draw if run.augment else ""  # "once" (the paper's protocol) or "epoch"
        clock = read_clock(p.path)
        rows.append({
            "cell": p.cell.name,
            "state": "finished" if summary else ("failed" if status.get("state") == "failed" else p.state),
            "encoder": run.names["encoder"],
            "embedding": _fmt(list(run.sensor.embedding)),
            "decoder": run.names["decoder"],
            "transform": "+".join(run.augment) or "original",
            "augment_mode": mode,
            "precision": precision(run, summary),
            "variant": variant(p.cell),
            "seed": run.seed,
            "epochs": len(metrics) or None,
            "best_epoch": summary.get("best_epoch"),
            "val_acc": _pct(summary.get("val_acc")),
            "test_acc": _pct(summary.get("test_acc")),
            "best_test_acc": _pct(summary.get("best_test_acc")),
            "reference_test_acc": _pct((summary.get("verify") or {}).get("test_acc")),
            "paper_acc": spec.paper_figure(p.cell),
            "test_psnr": _round(summary.get("test_psnr"), 2),
            "test_ssim": _round(summary.get("test_ssim"), 4),
            "throughput": _round(summary.get("throughput"), 4) if run.sensor.exposure == "fixed" else None,
            "wall_time_s": summary.get("wall_time_s"),
            "epoch_time_s": round(sum(times) / len(times), 2) if times else None,
            "clock_s": clock["seconds"] if clock else None,
            "error": status.get("error", "") if status.get("state") == "failed" else "",
        })
    return rows


def _round(x: Any, digits: int) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(float(x), digits)


def _mean_std(vals: list[float], digits: int = 2) -> tuple[float | None, float | None]:
    if not vals:
        return None, None
    m = sum(vals) / len(vals)
    sd = math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else None
    return round(m, digits), (round(sd, digits) if sd is not None else None)


def aggregate(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Finished cells grouped over seeds: mean and sample standard deviation of the test accuracy."""
    keys = ("encoder", "embedding", "decoder", "transform", "augment_mode", "precision", "variant")
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        if r["state"] == "finished":
            groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    out = []
    for key, rs in groups.items():
        test, sd = _mean_std([r["test_acc"] for r in rs if r["test_acc"] is not None])
        best, _ = _mean_std([r["best_test_acc"] for r in rs if r["best_test_acc"] is not None])
        ref, _ = _mean_std([r["reference_test_acc"] for r in rs if r["reference_test_acc"] is not None])
        paper = rs[0]["paper_acc"]
        extra = {}
        for name, digits in (("test_psnr", 2), ("test_ssim", 4), ("throughput", 4)):
            extra[name], extra[f"{name}_std"] = _mean_std([r[name] for r in rs if r.get(name) is not None], digits)
        out.append({
            **dict(zip(keys, key)),
            "seeds": len(rs),
            "test_acc": test,
            "test_acc_std": sd,
            "best_test_acc": best,
            "reference_test_acc": ref,
            "paper_acc": paper,
            "diff_vs_paper": round(test - paper, 2) if test is not None and paper is not None else None,
            **extra,
            "wall_time_s": round(sum(r["wall_time_s"] or 0 for r in rs), 1),
        })
    return out


def _csv(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in columns})
    return buf.getvalue()


def _markdown(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> str:
    def cell(v: Any, column: str) -> str:
        if v is None:
            return ""
        if isinstance(v, float):  # SSIM and throughput are fractions: three decimals; the rest two
            return f"{v:.3f}" if column.startswith(("test_ssim", "throughput")) else f"{v:.2f}"
        return str(v)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(k), k) for k in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def filled(rows: list[dict[str, Any]], columns: tuple[str, ...]) -> tuple[str, ...]:
    """``columns`` less the :data:`OPTIONAL_COLUMNS` that no row fills."""
    return tuple(c for c in columns if c not in OPTIONAL_COLUMNS or any(r.get(c) is not None for r in rows))


def write_tables(spec: SweepSpec, planned: list[PlannedCell], sweep_dir: str | Path) -> dict[str, Path]:
    """``cells.csv``, ``summary.csv``, ``summary.md`` and the plots under ``sweep_dir``."""
    sweep_dir = Path(sweep_dir)
    rows = cell_rows(spec, planned)
    agg = aggregate(rows)
    columns = filled(agg, SUMMARY_COLUMNS) if agg else SUMMARY_COLUMNS
    out = {
        "cells": atomic_write_text(sweep_dir / "cells.csv", _csv(rows, filled(rows, CELL_COLUMNS) if agg else CELL_COLUMNS)),
        "summary": atomic_write_text(sweep_dir / "summary.csv", _csv(agg, columns)),
    }
    done = sum(r["state"] == "finished" for r in rows)
    units = ("Accuracies in percent; test_acc is selected on validation, best_test_acc is the best test accuracy "
             "over epochs (the paper's selection, shown for comparison only)." if "test_acc" in columns else
             "test_psnr in dB and test_ssim (Wang et al. 2004) of the epoch with the lowest validation loss.")
    if "throughput" in columns:
        units += " throughput: the light collected relative to a fully open aperture of the same size."
    md = [f"# Sweep {spec.name}\n", f"{done} of {len(rows)} cells finished. {units}\n", _markdown(agg, columns)]
    failed = [r for r in rows if r["state"] == "failed"]
    if failed:
        md += ["\n## Failed cells\n", _markdown(failed, ("cell", "error"))]
    out["markdown"] = atomic_write_text(sweep_dir / "summary.md", "\n".join(md))
    out.update(plots.sweep_plots(agg, planned, sweep_dir))
    return out
