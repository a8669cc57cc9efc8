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

from ..training.rundir import atomic_write_bytes

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
    "encoder", "setting", "kind", "knob", "value", "grid", "dtype", "padding", "psf_oversample", "wavelengths",
    "method", "learnable", "error", "truth_error", "step_s", "encode_s", "encode_estimated", "psf_s", "cost_s",
    "step_speedup", "encode_speedup", "sampling_ok", "sampling",
)  # fmt: skip
_FLOATS = ("error", "truth_error", "step_s", "encode_s", "psf_s", "cost_s", "step_speedup", "encode_speedup")
#: Rows of the main table (the sweep has its own).
_MAIN_KINDS = ("truth", "paper", "paper-grid", "preset")
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
    """The main table: per encoder, the truth, both paper pipelines and each preset: error, its truth's error, costs."""
    header = ("encoder", "setting", "grid", "dtype", "padding", "os", "error vs truth", "truth err", "step ms",
              "step vs paper", "encode 10k s", "encode vs paper", "psf s", "sampling")
    lines = []
    for r in rows:
        if r["kind"] not in _MAIN_KINDS:
            continue
        truth = r["kind"] == "truth"
        lines.append((
            r["encoder"], r["setting"], _grid(r["grid"]), "" if truth else r["dtype"], "" if truth else str(r["padding"]),
            "" if truth else str(r.get("psf_oversample", 1)),
            r["method"].split(":", 1)[-1] if truth else _pct(r["error"]), _pct(r.get("truth_error")),
            _ms(r["step_s"]), _x(r["step_speedup"]) if r["kind"] in ("preset", "paper-grid") else "",
            _s(r["encode_s"], r["encode_estimated"]),
            _x(r["encode_speedup"]) if r["kind"] in ("preset", "paper-grid") else "",
            _s(r["psf_s"]), "ok" if r["sampling_ok"] else r["sampling"],
        ))  # fmt: skip
    return _render(header, lines)


def format_sweep(rows: Iterable[dict]) -> str:
    """Each knob alone from ``default``: error (and its ratio to ``default``'s) and cost per point."""
    rows = list(rows)
    base = {r["encoder"]: r for r in rows if r["kind"] == "preset" and r["setting"] == "default"}
    header = ("encoder", "knob", "value", "error vs truth", "x default", "cost", "sampling")
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


#: The benchmark's targets: reference and default within these of the converged truth; the learned
#: SLM's default step this much faster than the published paper step (goal: SPEED_GOAL), with this much
#: lower error.
REFERENCE_TOLERANCE = 0.0025
DEFAULT_TOLERANCE = 0.01
SPEED_TARGET = 100.0
SPEED_GOAL = 200.0
ERROR_RATIO_TARGET = 10.0


def outcomes(rows: Iterable[dict], encode_all: Optional[dict] = None, auto: Optional[dict] = None,
             speed_encoder: str = "learned_slm", speed: Optional[dict] = None) -> list[tuple[Optional[bool], str]]:
    """The issue's claims checked on measured rows: ``(passed or None for information, text)``.

    Args:
        encode_all: :func:`optoenc.bench.pipeline.encode_all`'s result.
        auto: ``{encoder: AutoChoice or error text}`` from :mod:`optoenc.bench.choose`.
        speed: :func:`optoenc.bench.speed.interleaved`'s result (the step ratio measured interleaved);
            without it the ratio of the rows' best step times is checked.
    """
    rows = list(rows)
    out: list[tuple[Optional[bool], str]] = []

    def get(enc, setting):
        return next((r for r in rows if r["encoder"] == enc and r["setting"] == setting), None)

    d, p = get(speed_encoder, "default"), get(speed_encoder, "paper")
    if d and p and d["step_speedup"] is not None and not speed:
        out.append((d["step_speedup"] >= SPEED_TARGET,
                    f"{speed_encoder}: default training step {_ms(d['step_s'])} ms vs published paper "
                    f"{_ms(p['step_s'])} ms = {d['step_speedup']:.0f}x faster (>= {SPEED_TARGET:.0f}x, goal "
                    f"{SPEED_GOAL:.0f}x; best of each, not interleaved)"))
    for t, res in sorted((speed or {}).get("threads", {}).items()):
        out.append((res["ratio_min"] >= SPEED_TARGET,
                    f"{speed_encoder}: default step vs published paper step, {t} thread(s), interleaved: "
                    f"min {res['ratio_min']:.0f}x, median {res['ratio_median']:.0f}x (>= {SPEED_TARGET:.0f}x, "
                    f"goal {SPEED_GOAL:.0f}x; load {res['load_before']:.2f} -> {res['load_after']:.2f})"))
    if d and p and d["error"] and p["error"] is not None:
        ratio = p["error"] / d["error"]
        out.append((ratio >= ERROR_RATIO_TARGET,
                    f"{speed_encoder}: default error {_pct(d['error'])} vs published paper {_pct(p['error'])} = "
                    f"{ratio:.1f}x lower (>= {ERROR_RATIO_TARGET:.0f}x)"))
    for enc in dict.fromkeys(r["encoder"] for r in rows):
        truth = next((r for r in rows if r["encoder"] == enc and r["kind"] == "truth"), None)
        if truth is not None:
            out.append((None, f"{enc}: truth {truth['method'].split(':', 1)[-1]}, estimated error "
                              f"{_pct(truth['truth_error'])}"))
        for name, tol in (("reference", REFERENCE_TOLERANCE), ("default", DEFAULT_TOLERANCE)):
            r = get(enc, name)
            if r and r["error"] is not None:
                out.append((r["error"] <= tol, f"{enc}: {name} within {100 * tol:g}% of the truth "
                                                f"({_pct(r['error'])}; truth error {_pct(r.get('truth_error'))})"))
        for name in ("paper", "paper-grid", "fast"):
            r = get(enc, name)
            if r and r["error"] is not None:
                note = "" if r["sampling_ok"] else f" (sampling: {r['sampling']})"
                out.append((None, f"{enc}: {name} error {_pct(r['error'])}{note}"))
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
    """Rows written by :func:`write_csv` (types restored).

    Raises:
        DataError: a missing, unreadable or binary file, missing columns or a malformed cell (naming the file).
    """
    from ..errors import DataError

    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            missing = [k for k in ("encoder", "kind", "grid", "wavelengths", "error") if k not in (reader.fieldnames or [])]
            if missing:
                raise DataError(f"{path}: not a CSV written by `optoenc bench --out` (missing columns: {', '.join(missing)})")
            return _rows(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise DataError(f"{path}: cannot read as a bench CSV ({getattr(err, 'strerror', None) or err})") from None
    except (ValueError, KeyError, AttributeError) as err:
        raise DataError(f"{path}: malformed bench CSV row ({err})") from None


def _rows(reader) -> list[dict]:
    out = []
    for rec in reader:
        r: dict = dict(rec)
        for k in _FLOATS:
            r[k] = float(r[k]) if r.get(k) not in (None, "") else None
        for k in _BOOLS:
            r[k] = r.get(k) == "True"
        r["grid"] = tuple(int(n) for n in r["grid"].split("x"))
        r["wavelengths"] = int(r["wavelengths"])
        r["psf_oversample"] = int(r.get("psf_oversample") or 1)
        out.append(r)
    return out


def save_pareto(rows: Iterable[dict], path) -> Path:
    """Log-log Pareto plot: cost vs error per encoder (learned: time per step; fixed: encode 10k digits)."""
    from ..training.pictures import new_figure, save_figure

    rows = [r for r in rows if r["kind"] != "truth" and r["error"] is not None and r["error"] > 0]
    plt, fig = new_figure((12, 5))
    panels = (
        (True, "step_s", "time per training step [s] (batch 200, FCNN)"),
        (False, "encode_s", "time to encode 10,000 digits, cache cold [s]"),
    )
    marks = {"paper": "X", "paper-grid": "P", "preset": "o", "sweep": "."}
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
                if r["kind"] in ("paper", "paper-grid", "preset"):
                    ax.annotate(r["setting"], (r[key], r["error"]), fontsize=7, xytext=(3, 3),
                                textcoords="offset points")
            # Pareto front of auto's candidates: cheapest first, each more accurate than all cheaper ones.
            front, best = [], math.inf
            for r in sorted(pts, key=lambda r: (r[key], r["error"])):
                if r["error"] < best and r["kind"] in ("preset", "sweep") and r["sampling_ok"] and int(r["wavelengths"]) == 3:
                    front.append(r)
                    best = r["error"]
            if len(front) > 1:
                ax.step([r[key] for r in front], [r["error"] for r in front], where="post", color=color, alpha=0.5)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative L2 error of the embeddings vs the truth")
        ax.set_title(("learned" if learned else "fixed") + " encoders (X: paper, P: paper-grid, o: presets, .: sweep)")
        ax.grid(True, which="both", alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    return save_figure(plt, fig, path)
