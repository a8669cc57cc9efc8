"""``optoenc bench --docs DIR``: the measured parts of ``benchmarks.md`` and ``fidelity.md`` from one run.

The pages are written by hand around generated blocks::

    <!-- optoenc bench: NAME -->
    ...generated...
    <!-- /optoenc bench: NAME -->

:func:`update_docs` replaces every block of one run (the prose stays), so
each figure on the pages comes from the same invocation; the CSV and the
Pareto plot go to ``DIR/bench/``. Blocks:

* ``benchmarks.md`` ``run``: how the run was made (command, date, wall time,
  peak memory, cores) and its whole console report (load at start and end,
  table, sweep, speed, outcome checks);
* ``benchmarks.md`` ``targets``: the benchmark's targets, met or not;
* ``fidelity.md`` ``overrides``: each encoder's measured preset overrides
  with the error of the preset against the truth in this run.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Optional, Sequence

from ..errors import ConfigError
from ..training.rundir import atomic_write_text

__all__ = ["BLOCKS", "replace_block", "check_docs", "run_block", "targets_block", "overrides_block", "update_docs"]

#: The generated blocks, per page.
BLOCKS = {"benchmarks.md": ("run", "targets"), "fidelity.md": ("overrides",)}
#: The benchmark's goals: the largest error of each preset against the truth.
GOALS = {"reference": 0.0025, "default": 0.01}


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- optoenc bench: {name} -->", f"<!-- /optoenc bench: {name} -->"


def replace_block(text: str, name: str, content: str, page: str = "page") -> str:
    """``text`` with the generated block ``name`` holding ``content`` (a ConfigError when its markers are missing)."""
    start, end = _markers(name)
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if len(pattern.findall(text)) != 1:
        raise ConfigError("--docs", page, f"must hold exactly one block '{start}' ... '{end}'")
    return pattern.sub(lambda _m: f"{start}\n{content.strip()}\n{end}", text)


def run_block(report: str, command: str, started: str, wall_s: float, peak_gb: Optional[float], cores: int) -> str:
    """The console report of the run, fenced, after one line saying how it was made."""
    peak = "" if peak_gb is None else f", peak {peak_gb:.1f} GB resident"
    return (f"`{command}`, started {started} on {cores} cores, {wall_s / 60:.0f} min wall{peak}:\n\n"
            f"```\n{report.strip()}\n```")


def _pct(v) -> str:
    return "n/a" if v is None else f"{100 * v:.3f} %"


def _row(rows, enc: str, setting: str) -> Optional[dict]:
    return next((r for r in rows if r["encoder"] == enc and r["setting"] == setting), None)


def targets_block(rows: Sequence[dict], speed: Optional[dict] = None) -> str:
    """Markdown table: each preset goal per encoder (met or missed, with the error and the truth's error)."""
    encs = list(dict.fromkeys(r["encoder"] for r in rows))
    lines = ["| target | " + " | ".join(f"`{e}`" for e in encs) + " |", "| --- |" + " --- |" * len(encs)]
    for preset, goal in GOALS.items():
        cells = []
        for e in encs:
            r = _row(rows, e, preset)
            if r is None or r["error"] is None:
                cells.append("not run")
            else:
                cells.append(f"{_pct(r['error'])} {'met' if r['error'] <= goal else '**missed**'}")
        lines.append(f"| `{preset}` <= {100 * goal:g} % | " + " | ".join(cells) + " |")
    truth = [_row(rows, e, "truth") for e in encs]
    lines.append("| truth's estimated error | " + " | ".join(_pct(t and t["truth_error"]) for t in truth) + " |")
    return "\n".join(lines)


def overrides_block(rows: Sequence[dict]) -> str:
    """Markdown table: every encoder's ``fidelity_presets`` override with the preset's measured error."""
    from ..plugins import get_registry

    reg = get_registry("encoder")
    lines = ["| encoder | preset | override | setting measured | error vs truth | truth err |",
             "| --- | --- | --- | --- | --- | --- |"]
    for enc in dict.fromkeys(r["encoder"] for r in rows):
        for preset, knobs in getattr(reg.get(enc), "fidelity_presets", {}).items():
            r = _row(rows, enc, preset)
            if r is None:
                continue
            over = ", ".join(f"{k} {'x'.join(map(str, v)) if isinstance(v, tuple) else v}" for k, v in knobs.items())
            grid = "x".join(map(str, r["grid"]))
            setting = f"{grid}, {r['dtype']}, padding {r['padding']}, psf_oversample {r['psf_oversample']}"
            lines.append(f"| `{enc}` | `{preset}` | {over} | {setting} | {_pct(r['error'])} | {_pct(r['truth_error'])} |")
    return "\n".join(lines)


def check_docs(docs: Path) -> None:
    """A ConfigError unless ``docs`` holds every page of :data:`BLOCKS` with each of its blocks once."""
    for page, names in BLOCKS.items():
        path = Path(docs) / page
        if not path.is_file():
            raise ConfigError("--docs", str(docs), f"must be a folder holding {page}")
        text = path.read_text(encoding="utf-8")
        for name in names:
            replace_block(text, name, "", str(path))


def update_docs(docs: Path, blocks: dict[str, dict[str, str]]) -> list[Path]:
    """Replace the generated ``blocks`` (``{page: {name: content}}``) in the pages under ``docs`` (atomic writes)."""
    written = []
    for page, contents in blocks.items():
        path = Path(docs) / page
        if not path.is_file():
            raise ConfigError("--docs", str(docs), f"must be a folder holding {page}")
        text = path.read_text(encoding="utf-8")
        for name, content in contents.items():
            text = replace_block(text, name, content, str(path))
        written.append(atomic_write_text(path, text))
    return written
