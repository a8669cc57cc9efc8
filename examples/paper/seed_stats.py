"""Learned vs fixed SLM at 24x32 under each transform (drawn once): mean ± sample std over seeds, Welch t.

    python examples/paper/seed_stats.py [CELLS]   # CELLS: default docs/results/rerun/sweep_cells/table3
    python examples/paper/seed_stats.py --epyc    # the AMD machines' runs with the axis-by-axis PSF

Reads each cell's summary.json (validation-selected test accuracy), or with ``--epyc`` the accuracies of
docs/results/epyc/ (learned SLM: ``propagation_table3_cells.csv``, the axis-by-axis PSF; fixed SLM:
``table3_fixed_cells.csv``, the epoch loop); cells with transforms redrawn every epoch are left out.
(``sorted_table3_cells.csv`` re-ran six of those learned cells for their clocks, with the build's rows
sorted by band; their accuracies are within the seed spread of these and are not pooled with them.)
|t| well above 2 puts the difference beyond seed noise.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import statistics
from pathlib import Path

TRANSFORMS = ("shift", "rescale", "rotate", "perspective")
RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
EPYC = RESULTS / "epyc"
# (file, accuracy column) per encoder for --epyc
EPYC_FILES = {"learned_slm": ("propagation_table3_cells.csv", "test_acc"),
              "fixed_slm": ("table3_fixed_cells.csv", "epyc_test_acc")}


def _wanted(name: str, encoder: str, transform: str) -> bool:
    return (re.match(rf"encoder={encoder},embedding=24x32,augment={transform}(,|$)", name) is not None
            and "augment_draw=epoch" not in name)


def accuracies(cells: Path, encoder: str, transform: str) -> list[float]:
    """Percent accuracies of the finished cells (summary.json) of ``encoder`` at 24x32 under ``transform``."""
    return [100 * json.loads(s.read_text())["test_acc"] for s in sorted(cells.glob("*/summary.json"))
            if _wanted(s.parent.name, encoder, transform)]


def epyc_accuracies(encoder: str, transform: str) -> list[float]:
    """The same from the AMD machines' CSVs (:data:`EPYC_FILES`)."""
    name, column = EPYC_FILES[encoder]
    with open(EPYC / name, newline="") as f:
        return [float(r[column]) for r in csv.DictReader(f) if _wanted(r["cell"], encoder, transform) and r[column]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cells", nargs="?", type=Path, default=RESULTS / "rerun" / "sweep_cells" / "table3",
                    help="a sweep's cells folder (default: the re-run's committed cells)")
    ap.add_argument("--epyc", action="store_true", help="read the AMD machines' CSVs in docs/results/epyc instead")
    args = ap.parse_args()
    for t in TRANSFORMS:
        if args.epyc:
            learned, fixed = epyc_accuracies("learned_slm", t), epyc_accuracies("fixed_slm", t)
        else:
            learned, fixed = accuracies(args.cells, "learned_slm", t), accuracies(args.cells, "fixed_slm", t)
        if min(len(learned), len(fixed)) < 2:
            print(f"{t}: fewer than two seeds (learned {len(learned)}, fixed {len(fixed)})")
            continue
        (ml, sl), (mf, sf) = ((statistics.mean(v), statistics.stdev(v)) for v in (learned, fixed))
        welch = (ml - mf) / math.sqrt(sl**2 / len(learned) + sf**2 / len(fixed))
        print(f"{t}: learned {ml:.2f} ± {sl:.2f} % (n={len(learned)}), fixed {mf:.2f} ± {sf:.2f} % (n={len(fixed)}), "
              f"difference {ml - mf:+.2f} points, Welch t = {welch:.1f}")


if __name__ == "__main__":
    main()
