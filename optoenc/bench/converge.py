"""Convergence study: does the encoders' simulation approach the truth, and is the truth converged?

``optoenc bench converge`` measures, per encoder, the embeddings of the
benchmark's digits (noise-free, 24 x 32) at successive refinements: the
encoder's own simulation (float64, padding ``auto``) on grids of pitch
``8 p``, ``4 p``, ``2 p`` and ``p`` (``p`` the 1.55 um sensor pixel: 380 x 507
up to the full 3040 x 4056 sensor). Per level: the relative L2 difference to
the previous level and to the truth (:mod:`optoenc.bench.truth`), and from
the three finest levels the observed order and the Richardson-extrapolated
limit, with its difference to the truth. For the Fresnel truth this limit is
the exact (band-limited angular spectrum) kernel's: its agreement with the
truth and the 1-D Fresnel-vs-exact figure (:func:`~optoenc.bench.truth.kernel_error`)
show that the paraxial truth is good to well under the presets' tolerances.

Rows are dicts; :func:`format_table` renders them and
:func:`optoenc.bench.report.write_csv`-style CSV is written by :func:`write_csv`.
"""

from __future__ import annotations

import csv
import io
import time
import warnings
from typing import Callable, Optional, Sequence

import torch

from ..training.rundir import atomic_write_bytes
from .pipeline import release_memory, scenes
from .settings import DIGITS, EMBEDDING, ENCODERS, embed, relative_error
from .truth import SENSOR_GRID, _refined, richardson, truth

__all__ = ["LEVELS", "study", "format_table", "write_csv", "FIELDS"]

#: Grids of the study, coarse to fine: sensor / 8, / 4, / 2, / 1.
LEVELS = tuple((SENSOR_GRID[0] // k, SENSOR_GRID[1] // k) for k in (8, 4, 2, 1))
FIELDS = ("encoder", "level", "grid", "pitch_um", "error_vs_previous", "error_vs_truth", "truth_method",
          "truth_error", "order", "kernel_error", "seconds")


def study(encoders: Sequence[str] = ENCODERS, levels=LEVELS, digits: int = DIGITS, embedding=EMBEDDING,
          setups: Optional[dict] = None, progress: Optional[Callable[[int, int, str], None]] = None) -> list[dict]:
    """One row per encoder and level, then a ``limit`` row (Richardson) and a ``truth`` row per encoder."""
    data = scenes(digits, 1, 1)
    rows: list[dict] = []
    total, done = len(encoders) * (len(levels) + 1), 0
    for name in encoders:
        setup = (setups or {}).get(name)
        if progress is not None:
            progress(done, total, f"{name} truth")
        release_memory()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            t = truth(name, data.digits, tuple(embedding), setup, tuple(levels[-1]))
        done += 1
        base = {"encoder": name, "truth_method": t.method, "truth_error": t.error, "kernel_error": t.fresnel_vs_exact}
        embs: list[torch.Tensor] = []
        for g in levels:
            if progress is not None:
                progress(done, total, f"{name} {g[0]}x{g[1]}")
            release_memory()
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                enc = _refined(name, g, tuple(embedding), setup)
                e = embed(enc, data.digits)
            del enc
            pitch = SENSOR_GRID[0] / g[0] * 1.55  # um: the sensor pixel times the refinement
            rows.append({**base, "level": f"{g[0]}x{g[1]}", "grid": g, "pitch_um": pitch,
                         "error_vs_previous": relative_error(e, embs[-1]) if embs else None,
                         "error_vs_truth": relative_error(e, t.embeddings), "order": None,
                         "seconds": time.perf_counter() - t0})
            embs.append(e)
            done += 1
        if len(embs) >= 3:
            limit, p, corr = richardson(embs)
            rows.append({**base, "level": "limit", "grid": None, "pitch_um": 0.0, "error_vs_previous": corr,
                         "error_vs_truth": relative_error(limit, t.embeddings), "order": p, "seconds": None})
        rows.append({**base, "level": "truth", "grid": t.grid, "pitch_um": None, "error_vs_previous": None,
                     "error_vs_truth": 0.0, "order": t.order, "seconds": t.seconds})
    if progress is not None:
        progress(total, total, "done")
    return rows


def _pct(v) -> str:
    return "" if v is None else f"{100 * v:.4f}%"


def format_table(rows: Sequence[dict]) -> str:
    """Per encoder and level: pitch, change from the previous level, error against the truth."""
    header = ("encoder", "level", "pitch um", "vs previous", "vs truth", "order", "truth", "truth err", "kernel")
    lines = []
    for r in rows:
        pitch = "" if r["pitch_um"] is None else f"{r['pitch_um']:.2f}"
        lines.append((r["encoder"], r["level"], pitch, _pct(r["error_vs_previous"]), _pct(r["error_vs_truth"]),
                      "" if r["order"] is None else f"{r['order']:.2f}", r["truth_method"], _pct(r["truth_error"]),
                      _pct(r["kernel_error"])))
    widths = [max(len(h), *(len(line[i]) for line in lines)) if lines else len(h) for i, h in enumerate(header)]
    fmt = lambda cells: "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))  # noqa: E731
    return "\n".join([fmt(header), fmt(["-" * w for w in widths]), *map(fmt, lines)])


def write_csv(rows: Sequence[dict], path):
    """The study's rows as CSV (atomic), columns :data:`FIELDS`."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(FIELDS)
    for r in rows:
        w.writerow(["" if r.get(k) is None else "x".join(map(str, r[k])) if k == "grid" else
                    repr(r[k]) if isinstance(r[k], float) else r[k] for k in FIELDS])
    return atomic_write_bytes(path, buf.getvalue().encode())
