"""Tables, CSV, the Pareto plot and the outcome checks of the fidelity benchmark's rows.

Rows are the dicts of :func:`optoenc.bench.pipeline.run`. Nothing is printed
here: the functions return strings, or write files atomically.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Iterable, Optional, Sequence

from ..rundir import atomic_write_bytes

__all__ = [
    "CSV_FIELDS",
    "format_table",
    "format_sweep",
    "outcomes",
    "format_outcomes",
    "write_csv",
    "read_csv",
    "save_pareto",
]

#: Columns of the CSV, in order.
CSV_FIELDS = (
    "encoder", "setting", "kind", "knob", "value", "grid", "dtype", "padding", "wavelengths", "method",
    "learnable", "error", "step_s", "encode_s", "encode_estimated", "psf_s", "cost_s", "step_speedup",
    "encode_speedup", "sampling_ok", "sampling",
)  # fmt: skip
_FLOATS = ("error", "step_s", "encode_s", "psf_s", "cost_s", "step_speedup", "encode_speedup")
_BOOLS = ("learnable", "encode_estimated", "sampling_ok")


def _render(header: Sequence[str], lines: list[Sequence[str]], left: int = 2) -> str:
    widths = [max([len(h)] + [len(line[i]) for line in lines]) for i, h in enumerate(header)]

    def fmt(cells):
        return "  ".join(c.ljust(w) if i < left else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    return "\n".join([fmt(header), fmt(["-" * w for w in widths]), *map(fmt, lines)])


def _pct(v: Optional[float]) -> str:
    return "" if v is None else f"{100 * v:.3f}%"


def _ms(v: Optional[float]) -> str:
    if v is None:
        return ""
    return f"{1e3 * v:.1f}" if v < 10 else f"{1e3 * v:.0f}"


def _s(v: Optional[float], est: bool = False) -> str:
    if v is None:
        return ""
    return ("~" if est else "") + (f"{v:.2f}" if v < 100 else f"{v:.0f}")


def _x(v: Optional[float]) -> str:
    return "" if v is None else f"{v:.0f}x" if v >= 10 else f"{v:.1f}x"


def _grid(g) -> str:
    return g if isinstance(g, str) else "x".join(str(int(n)) for n in g)


def format_table(rows: Iterable[dict]) -> str:
    """The main table: per encoder, hi-fi, paper and each preset, with error, step and encode costs."""
    header = ("encoder", "setting", "grid", "dtype", "padding", "error vs hi-fi", "step ms", "step vs paper",
              "encode 10k s", "encode vs paper", "psf s", "sampling")
    lines = []
    for r in rows:
        if r["kind"] not in ("hifi", "paper", "preset"):
            continue
        lines.append((
            r["encoder"], r["setting"], _grid(r["grid"]), r["dtype"], str(r["padding"]),
            "(reference)" if r["kind"] == "hifi" else _pct(r["error"]),
            _ms(r["step_s"]), _x(r["step_speedup"]) if r["kind"] == "preset" else "",
            _s(r["encode_s"], r["encode_estimated"]), _x(r["encode_speedup"]) if r["kind"] == "preset" else "",
            _s(r["psf_s"]), "ok" if r["sampling_ok"] else r["sampling"],
        ))  # fmt: skip
    return _render(header, lines)


def format_sweep(rows: Iterable[dict]) -> str:
    """Each knob alone from ``default``: error (and its ratio to ``default``'s) and cost per point."""
    rows = list(rows)
    base = {r["encoder"]: r for r in rows if r["kind"] == "preset" and r["setting"] == "default"}
    header = ("encoder", "knob", "value", "error vs hi-fi", "x default", "cost", "sampling")
    lines = []
    for r in rows:
        if r["kind"] != "sweep":
            continue
        b = base.get(r["encoder"])
        ratio = r["error"] / b["error"] if b and b["error"] and r["error"] is not None else None
        cost = f"{_ms(r['step_s'])} ms/step" if r["learnable"] else f"{_s(r['encode_s'])} s/10k"
        lines.append((r["encoder"], r["knob"], r["value"], _pct(r["error"]), "" if ratio is None else f"{ratio:.2f}",
                      cost, "ok" if r["sampling_ok"] else r["sampling"]))
    return _render(header, lines, left=3)


def outcomes(rows: Iterable[dict], encode_all: Optional[dict] = None, auto: Optional[dict] = None,
             speed_encoder: str = "learned_slm") -> list[tuple[Optional[bool], str]]:
    """The issue's claims checked on measured rows: ``(passed or None for information, text)``.

    Args:
        encode_all: :func:`optoenc.bench.pipeline.encode_all`'s result.
        auto: ``{encoder: AutoChoice or error text}`` from :mod:`optoenc.bench.auto`.
    """
    rows = list(rows)
    out: list[tuple[Optional[bool], str]] = []

    def get(enc, setting):
        return next((r for r in rows if r["encoder"] == enc and r["setting"] == setting), None)

    d, p = get(speed_encoder, "default"), get(speed_encoder, "paper")
    if d and p and d["step_speedup"] is not None:
        out.append((d["step_speedup"] >= 100, f"{speed_encoder}: default training step {_ms(d['step_s'])} ms vs paper "
                                               f"{_ms(p['step_s'])} ms = {d['step_speedup']:.0f}x faster (>= 100x)"))
        out.append((d["error"] <= p["error"], f"{speed_encoder}: default error {_pct(d['error'])} no larger than "
                                              f"paper's {_pct(p['error'])}"))
    for enc in dict.fromkeys(r["encoder"] for r in rows):
        ref, dflt, pap, fast = get(enc, "reference"), get(enc, "default"), get(enc, "paper"), get(enc, "fast")
        if ref and ref["error"] is not None:
            out.append((ref["error"] <= 0.005, f"{enc}: reference within 0.5% of hi-fi ({_pct(ref['error'])})"))
        if dflt and pap and dflt["error"] is not None and pap["error"] is not None:
            out.append((dflt["error"] <= pap["error"],
                        f"{enc}: default no worse than paper ({_pct(dflt['error'])} vs {_pct(pap['error'])})"))
        if fast and fast["error"] is not None:
            note = "" if fast["sampling_ok"] else f" (sampling: {fast['sampling']})"
            out.append((None, f"{enc}: fast error {_pct(fast['error'])}{note}"))
    for enc, choice in (auto or {}).items():
        if isinstance(choice, str):
            out.append((False, f"auto {enc}: {choice}"))
        else:
            out.append((choice.row["error"] <= choice.tolerance,
                        f"auto {enc} @ {100 * choice.tolerance:g}%: {choice.describe()}"))
    if encode_all:
        out.append((encode_all["seconds"] < 30,
                     f"{encode_all['encoder']} ({encode_all['preset']}) encodes all {encode_all['count']:,} MNIST digits "
                     f"to {_grid(encode_all['shape'][-2:])} in {encode_all['seconds']:.1f} s cache cold (< 30 s; "
                     f"dataset load {encode_all['load_s']:.1f} s)"))
    return out


def format_outcomes(items: Sequence[tuple[Optional[bool], str]]) -> str:
    """``[ok]`` / ``[FAIL]`` / ``[info]`` lines."""
    tag = {True: "[ok]  ", False: "[FAIL]", None: "[info]"}
    return "\n".join(f"{tag[ok]} {text}" for ok, text in items)


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, tuple):
        return _grid(v)
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_csv(rows: Iterable[dict], path) -> Path:
    """Write the rows to ``path`` (atomically), one line each, columns :data:`CSV_FIELDS`."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_FIELDS)
    for r in rows:
        w.writerow([_cell(r.get(k)) for k in CSV_FIELDS])
    return atomic_write_bytes(path, buf.getvalue().encode())


def read_csv(path) -> list[dict]:
    """Rows written by :func:`write_csv` (types restored)."""
    out = []
    with open(path, newline="") as f:
        for rec in csv.DictReader(f):
            r: dict = dict(rec)
            for k in _FLOATS:
                r[k] = float(r[k]) if r.get(k) not in (None, "") else None
            for k in _BOOLS:
                r[k] = r.get(k) == "True"
            r["grid"] = tuple(int(n) for n in r["grid"].split("x"))
            r["wavelengths"] = int(r["wavelengths"])
            out.append(r)
    return out


def save_pareto(rows: Iterable[dict], path) -> Path:
    """Log-log Pareto plot: cost vs error per encoder (learned: time per step; fixed: encode 10k digits)."""
    from ..pictures import _figure, _save

    rows = [r for r in rows if r["kind"] != "hifi" and r["error"] is not None and r["error"] > 0]
    plt, fig = _figure((12, 5))
    panels = (
        (True, "step_s", "time per training step [s] (batch 200, FCNN)"),
        (False, "encode_s", "time to encode 10,000 digits, cache cold [s]"),
    )
    marks = {"paper": "X", "preset": "o", "sweep": "."}
    cmap = plt.get_cmap("tab10")
    encs = list(dict.fromkeys(r["encoder"] for r in rows))
    for i, (learned, key, xlabel) in enumerate(panels):
        ax = fig.add_subplot(1, 2, i + 1)
        for j, enc in enumerate(encs):
            pts = [r for r in rows if r["encoder"] == enc and r["learnable"] == learned and r[key]]
            if not pts:
                continue
            color = cmap(j % 10)
            for kind, m in marks.items():
                sel = [r for r in pts if r["kind"] == kind]
                if sel:
                    ax.scatter([r[key] for r in sel], [r["error"] for r in sel], marker=m, color=color,
                               s=60 if kind != "sweep" else 30, label=enc if kind == "preset" else None,
                               edgecolors="k" if kind == "paper" else None, linewidths=0.5)
            for r in pts:
                if r["kind"] in ("paper", "preset"):
                    ax.annotate(r["setting"], (r[key], r["error"]), fontsize=7, xytext=(3, 3),
                                textcoords="offset points")
            # Pareto front of auto's candidates: cheapest first, each more accurate than all cheaper ones.
            front, best = [], math.inf
            for r in sorted(pts, key=lambda r: (r[key], r["error"])):
                if r["error"] < best and r["kind"] != "paper" and r["sampling_ok"] and int(r["wavelengths"]) == 3:
                    front.append(r)
                    best = r["error"]
            if len(front) > 1:
                ax.step([r[key] for r in front], [r["error"] for r in front], where="post", color=color, alpha=0.5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative L2 error of the embeddings vs hi-fi")
        ax.set_title(("learned" if learned else "fixed") + " encoders (X: paper, o: presets, .: sweep)")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    return _save(plt, fig, path)
