"""The privacy tables' text: a CSV of chosen columns, rates with their Wilson interval, accuracies.

Shared by the privacy table (:mod:`optoenc.privacy.report`), the defence table (:mod:`optoenc.privacy.defence`)
and the studies in ``examples/privacy/``; free of torch.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

from ..training.rundir import atomic_write_text

__all__ = ["csv_text", "write_csv", "rate_text", "acc_text", "count_text", "given", "inputs_text"]


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def csv_text(rows: Sequence[dict], columns: Sequence[str]) -> str:
    """``rows`` as CSV text with ``columns`` (missing values empty, floats to 6 significant digits)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _fmt(r.get(k, "")) for k in columns})
    return buf.getvalue()


def write_csv(rows: Sequence[dict], path: str | Path, columns: Sequence[str]) -> Path:
    """:func:`csv_text` written atomically to ``path``."""
    return atomic_write_text(path, csv_text(rows, columns))


def given(v: Any) -> bool:
    """A value is there: not empty, not None, not NaN."""
    return v not in ("", None) and v == v


def rate_text(r: dict, key: str = "reid_top1", short: str = "reid") -> str:
    """``51.0 [47.9, 54.1]`` (percent, Wilson 95 % interval), or ``51.0 +- 1.6`` for a table without intervals;
    ``key``/``short``: ``reid_top1``/``reid`` or ``readability``/``readability``."""
    m = 100 * float(r[key])
    if given(r.get(f"{short}_ci_low")):
        return f"{m:.1f} [{100 * float(r[f'{short}_ci_low']):.1f}, {100 * float(r[f'{short}_ci_high']):.1f}]"
    return f"{m:.1f} +- {100 * float(r[f'{key}_se']):.1f}"


def acc_text(r: dict) -> str:
    """The row's test accuracy as ``97.9 %``, ``-`` where it has none."""
    acc = r.get("test_acc", float("nan"))
    return "-" if not given(acc) else f"{100 * float(acc):.1f} %"


def count_text(v: Any) -> str:
    """A count as read back from CSV (a float, ``1024.0``) written as a whole number (``1024``); other values as
    they are."""
    return str(int(v)) if isinstance(v, float) and v == int(v) else str(v)


def inputs_text(r: dict) -> str:
    """A learned row's input scaling (``attacker_inputs``); a row without one predates the setting: standardise."""
    return r.get("attacker_inputs") or "standardise"
