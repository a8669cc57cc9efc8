"""Learned vs fixed SLM at 24x32 under each transform (drawn once): mean ± sample std over seeds, Welch t.

    python examples/paper/seed_stats.py [CELLS]   # CELLS: default docs/results/rerun/sweep_cells/table3

Reads each cell's summary.json (validation-selected test accuracy); cells with transforms redrawn every
epoch are left out. |t| well above 2 puts the difference beyond seed noise.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
from pathlib import Path

TRANSFORMS = ("shift", "rescale", "rotate", "perspective")


def accuracies(cells: Path, encoder: str, transform: str) -> list[float]:
    out = []
    for summary in sorted(cells.glob(f"encoder={encoder},embedding=24x32,augment={transform}*/summary.json")):
        if "augment_draw=epoch" not in summary.parent.name:
            out.append(100 * json.loads(summary.read_text())["test_acc"])
    return out


def main() -> None:
    cells = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/results/rerun/sweep_cells/table3")
    for t in TRANSFORMS:
        learned, fixed = accuracies(cells, "learned_slm", t), accuracies(cells, "fixed_slm", t)
        if min(len(learned), len(fixed)) < 2:
            print(f"{t}: fewer than two seeds (learned {len(learned)}, fixed {len(fixed)})")
            continue
        (ml, sl), (mf, sf) = ((statistics.mean(v), statistics.stdev(v)) for v in (learned, fixed))
        welch = (ml - mf) / math.sqrt(sl**2 / len(learned) + sf**2 / len(fixed))
        print(f"{t}: learned {ml:.2f} ± {sl:.2f} % (n={len(learned)}), fixed {mf:.2f} ± {sf:.2f} % (n={len(fixed)}), "
              f"difference {ml - mf:+.2f} points, Welch t = {welch:.1f}")


if __name__ == "__main__":
    main()
