"""Tables 1 and 3 on one kind of machine: the cells' measured run clocks where they have run, the sweep's
quiet estimate elsewhere, and the machine time both add up to with two workers; then how many fixed-encoder
and learned cells are within the issue's per-cell goals (60 s and 10 min).

    python examples/paper/cost_tally.py [--machine xeon|epyc|zen4] [--csv OUT.csv]

``xeon`` (the default) reads docs/results/xeon/: the Intel machines with AMX of 2026-11-25, where both tables run
in one sweep each with the current code (resumed over sittings) (``table{1,3}_cells.csv``, the sweeps' own cell
tables) and the estimates are ``table{1,3}_estimate_2workers.txt``. ``epyc`` reads docs/results/epyc/: the AMD
machines of 2026-11-24/25, whose cells were measured over several sittings (the newest file naming a cell
wins; each file's command is in docs/results/README.md). ``zen4`` reads docs/results/zen4/: the AMD EPYC
machines of sessions 30-33, 2026-11-28 (family 25 model 17, AVX-512 with bfloat16 products), where the tables run in one sweep
each as on the Intel machines. Estimates come from ``optoenc sweep SPEC --dry-run
--workers 2``. A measured cell ran two at once, one thread each, as the tables are run, or alone on both threads
where its spec sets ``trainer.threads: 2`` (the fixed encoders' 24x32 FCNN cells, since session 27): the machine
time adds each cell's clock times its share of the machine (:func:`share`). The estimate times steps on a quiet
machine, so where both exist their ratio says how far the estimate is from a real sweep.
"""

from __future__ import annotations

import argparse
import csv
import functools
import re
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
# Per kind of machine (its folder: docs/results/<name>/): the estimate file of each table, and the measured clocks as
# (file, table, clock column), oldest first: a later file's clock replaces an earlier one's for the same cell.
#: A machine where each table ran as one sweep (resumed over sittings): the sweeps' own cell tables.
ONE_SWEEP_PER_TABLE = {
    "estimates": {"table1": "table1_estimate_2workers.txt", "table3": "table3_estimate_2workers.txt"},
    "measured": [
        ("table1_cells.csv", "table1", "wall_time_s"),  # optoenc sweep examples/paper/table1.yaml
        ("table3_cells.csv", "table3", "wall_time_s"),  # optoenc sweep examples/paper/table3.yaml
    ],
}
MACHINES = {
    "xeon": ONE_SWEEP_PER_TABLE,
    "epyc": {
        "estimates": {"table1": "table1_estimate_2workers_separable.txt",
                      "table3": "table3_estimate_2workers_separable.txt"},
        "measured": [
            ("epoch_loop_cells.csv", "table1", "epoch_loop_clock_s"),  # 40 fixed-encoder cells, the epoch loop
            ("table3_fixed_cells.csv", "table3", "epyc_epoch_loop_clock_s"),  # 38 fixed-encoder cells
            ("propagation_cells.csv", "table1", "clock_s"),  # 16 learned-SLM cells, the axis-by-axis PSF
            ("propagation_table3_cells.csv", "table3", "clock_s"),  # learned-SLM cells, the axis-by-axis PSF
            ("phase_mask_cells.csv", "table1", "clock_s"),  # the learned phase mask's 8 cells
            ("sorted_table3_cells.csv", "table3", "clock_s"),  # learned-SLM cells, the build's rows sorted by band
            ("table3_fixed_rerun_cells.csv", "table3", "clock_s"),  # the coded aperture's shift and rescale cells
            ("canvas_rows_table3_cells.csv", "table3", "clock_s"),  # learned-SLM cells, the operator by canvas row
        ],
    },
    "zen4": ONE_SWEEP_PER_TABLE,
}
_LINE = re.compile(r"^\s*\w+\s+([\d.]+) s \((\w+)\)\s+(\S+)\s*$")


def estimates(machine: str, table: str) -> dict[str, float]:
    out = {}
    for line in (RESULTS / machine / MACHINES[machine]["estimates"][table]).read_text().splitlines():
        m = _LINE.match(line)
        if m:
            out[m.group(3)] = float(m.group(1))
    return out


def measured(machine: str, table: str) -> dict[str, tuple[float, str]]:
    """The measured cells of ``table``: ``{cell: (seconds, file)}``. A sweep's own cell table gives the cell's
    machine clock (``clock_s``: its processes from launch to exit) where the sweep recorded one, else its run
    clock (``wall_time_s``: training and testing, without the process's start-up and re-simulation)."""
    out = {}
    for name, tab, col in MACHINES[machine]["measured"]:
        path = RESULTS / machine / name
        if tab != table or not path.exists():
            continue
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row.get(col) and row.get("state", "finished") == "finished":
                    out[row["cell"]] = (float(row.get("clock_s") or row[col]), name)
    return out


def _twin(cell: str) -> str:
    """The cell's name without its seed: cells differing only in seed cost the same."""
    return re.sub(r",seed=\d+$", "", cell)


def tally(machine: str = "xeon") -> tuple[list[dict], dict]:
    """Every cell of both specs: its measured clock, else a measured twin's (the same cell with another
    seed, which trains the same shapes for the same epochs), else the sweep's estimate. Cells are matched by
    the specs' current names (:func:`_spec_name`); their share of the machine by the name they ran under."""
    rows, totals = [], {}
    for table, estimate_file in MACHINES[machine]["estimates"].items():
        est = {_spec_name(c, table): (e, c) for c, e in estimates(machine, table).items()}
        meas = {_spec_name(c, table): (clock, src, c) for c, (clock, src) in measured(machine, table).items()}
        unknown = sorted(set(meas) - _spec_names(table))
        if unknown:
            raise SystemExit(f"{table}: measured cells the spec does not have: {unknown[:3]}")
        twins = {}
        for name, (clock, src, raw) in meas.items():
            twins.setdefault(_twin(name), (clock, src, raw))
        cells = _spec_order(table)
        t = totals[table] = {"cells": len(cells), "measured": 0, "measured_s": 0.0, "compared_s": 0.0,
                             "their_estimate_s": 0.0, "twin": 0, "twin_s": 0.0, "estimated": 0, "estimated_s": 0.0}
        for name in cells:
            e, raw_e = est.get(name, (float("nan"), None))
            if name in meas:
                clock, src, raw = meas[name]
                t["measured"] += 1
                t["measured_s"] += clock
                if raw_e is not None:  # the estimate's ratio, over the cells that have both
                    t["compared_s"] += clock
                    t["their_estimate_s"] += e
            elif _twin(name) in twins:
                clock, src, raw = twins[_twin(name)]
                src = f"twin {raw} ({src})"
                t["twin"] += 1
                t["twin_s"] += clock
            elif raw_e is not None:
                clock, src, raw = e, estimate_file, raw_e
                t["estimated"] += 1
                t["estimated_s"] += e
            else:
                raise SystemExit(f"{table}: {name}: not measured, no measured twin, not in {estimate_file}")
            rows.append({"table": table, "cell": name, "seconds": round(clock, 1),
                         "estimate_s": e if raw_e is not None else "", "source": src, "share": share(raw)})
    return rows, totals


@functools.lru_cache(maxsize=None)
def _spec_order(table: str) -> tuple[str, ...]:
    from optoenc import sweep

    return tuple(c.name for c in sweep.load_spec(Path(__file__).parent / f"{table}.yaml").expand())


#: The sweeps' workers and threads per worker on the 2-core machines (``--workers 2``: one thread each).
WORKERS, THREADS = 2, 1


def share(cell: str) -> float:
    """The part of the machine the cell held while it ran (or, estimated, would hold): one worker's, or, where it
    ran with its own ``trainer.threads`` (its name says ``threads=N``), that many of the sweep's threads
    (``optoenc.sweep.claim``; two: the whole machine). Named as measured: a cell measured before its spec gave it
    threads ran as one worker."""
    from optoenc.sweep import claim

    m = re.search(r"(?:^|,)threads=(\d+)(?:,|$)", cell)
    budget = WORKERS * THREADS
    return claim(int(m.group(1)) if m else THREADS, budget) / budget


#: What the specs' ``trainer.precision=auto`` adds to a cell's name. The fixed encoders' 24x32 FCNN cells gained it
#: on 2026-11-25 (session 22); on a CPU without native bfloat16 (the AMD machines) ``auto`` is ``32-true``, so the
#: float32 cells measured there before, named without it, are the very runs the specs now ask for on them.
_AUTO = ",precision=auto"
#: What the specs' ``trainer.threads: 2`` adds to the same cells' names (session 27); their earlier one-thread runs
#: are named without it (and counted as one worker's share: :func:`share`).
_THREADS = ",threads=2"


def _spec_name(cell: str, table: str) -> str:
    """``cell`` as the spec now names it: a name from before the fixed cells gained ``precision=auto`` or
    ``threads=2`` mapped to the spec's cell that differs from it only by those (the AMD machines' files); any
    other name unchanged."""
    return cell if cell in _spec_names(table) else _by_plain(table).get(cell, cell)


@functools.lru_cache(maxsize=None)
def _spec_names(table: str) -> frozenset[str]:
    return frozenset(_spec_order(table))


@functools.lru_cache(maxsize=None)
def _by_plain(table: str) -> dict[str, str]:
    """The spec's cells by their names without ``threads=2``, and without both it and ``precision=auto``."""
    out = {}
    for name in _spec_names(table):
        plain = name.replace(_THREADS, "")
        out[plain] = out[plain.replace(_AUTO, "")] = name
    return out


# The per-cell goals, seconds: a fixed-encoder cell (cached embeddings) and a learned one.
CELL_GOALS = {"fixed": 60.0, "learned": 600.0}


def learned(cell: str) -> bool:
    """Whether a cell's encoder is trained (the encoder registry's ``learnable`` flag, from the cell's name)."""
    from optoenc.plugins import get_registry

    return get_registry("encoder").get(re.match(r"encoder=([^,]+)", cell).group(1)).learnable


def per_cell_goals(rows: list[dict]) -> list[str]:
    """One line per kind of cell: how many are within the issue's per-cell goal, and the slowest."""
    out = []
    for kind, goal in CELL_GOALS.items():
        mine = [r for r in rows if learned(r["cell"]) == (kind == "learned")]
        within = sum(r["seconds"] <= goal for r in mine)
        slow = max(mine, key=lambda r: r["seconds"])
        out.append(f"{kind} cells within {goal:.0f} s: {within} of {len(mine)} (slowest {slow['seconds']:.0f} s: "
                   f"{slow['table']} {slow['cell']})")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--machine", choices=sorted(MACHINES), default="xeon",
                   help="which machines' measurements (docs/results/MACHINE/); default: xeon")
    p.add_argument("--csv", type=Path, help="also write every cell's row here")
    args = p.parse_args()
    rows, totals = tally(args.machine)
    all_s = 0.0
    machine_s = sum(r["seconds"] * r["share"] for r in rows)
    for table, t in totals.items():
        s = t["measured_s"] + t["twin_s"] + t["estimated_s"]
        all_s += s
        ratio = t["compared_s"] / t["their_estimate_s"] if t["their_estimate_s"] else float("nan")
        print(f"{table}: {t['cells']} cells; measured {t['measured']} ({t['measured_s'] / 60:.1f} min, "
              f"{ratio:.2f}x their estimate), a measured twin's clock {t['twin']} ({t['twin_s'] / 60:.1f} min), "
              f"estimated {t['estimated']} ({t['estimated_s'] / 60:.1f} min): "
              f"{s / 60:.1f} min of cell time")
    alone = [r for r in rows if r["share"] == 1.0]
    print(f"Tables 1 and 3: {all_s / 60:.1f} min of cell time, about {machine_s / 3600:.2f} h of machine time with two "
          f"workers (each cell's time x its share of the machine: half, or all of it for the {len(alone)} cells "
          f"that ran alone on both threads; goal: 4 h)")
    for line in per_cell_goals(rows):
        print(line)
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


if __name__ == "__main__":
    main()
