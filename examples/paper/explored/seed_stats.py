"""Learned vs fixed SLM at 24x32 under each transform (drawn once): mean ± sample std over seeds, Welch t.

    python examples/paper/explored/seed_stats.py [CELLS]   # CELLS: default docs/results/explored/table3_seeds

Reads each cell's summary.json (validation-selected test accuracy) in CELLS, a sweep's cells folder of
examples/paper/table3.yaml; cells with transforms redrawn every epoch are left out. The default folder holds
Table 3's 24x32 fixed and learned SLM cells, three seeds each (five under perspective). |t| well above 2 puts the
difference beyond seed noise.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import statistics
from pathlib import Path

TRANSFORMS = ("shift", "rescale", "rotate", "perspective")
RESULTS = Path(__file__).resolve().parents[3] / "docs" / "results"


def _wanted(name: str, encoder: str, transform: str) -> bool:
    return (re.match(rf"encoder={encoder},embedding=24x32,augment={transform}(,|$)", name) is not None
            and "augment_draw=epoch" not in name)


def accuracies(cells: Path, encoder: str, transform: str) -> list[float]:
    """Percent accuracies of the finished cells (summary.json) of ``encoder`` at 24x32 under ``transform``."""
    return [100 * json.loads(s.read_text())["test_acc"] for s in sorted(cells.glob("*/summary.json"))
            if _wanted(s.parent.name, encoder, transform)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cells", nargs="?", type=Path, default=RESULTS / "explored" / "table3_seeds",
                    help="a sweep's cells folder (default: docs/results/explored/table3_seeds)")
    args = ap.parse_args()
    for t in TRANSFORMS:
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
