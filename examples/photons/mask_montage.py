"""The learned masks of a photon-budget sweep side by side: one row per embedding size, one column per light level.

    python examples/photons/mask_montage.py SWEEP_DIR OUT.png [--seed 0] [--redraw]

Reads each finished learned cell's ``pictures/mask_final.png`` (its title states the mask's throughput) from
``SWEEP_DIR/cells/`` (a sweep of examples/photons/photon_budget.yaml, or its committed cells under
docs/results/photons/), and the fixed LCD's mask of the same sweep as the starting point the learned ones begin from.
``--redraw`` first redraws each cell's ``mask_final.png`` from its last checkpoint where the cell still has one
(pictures drawn by another version of optoenc then look like today's).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from optoenc.training.pictures import new_figure, save_figure


def _cells(sweep_dir: Path, encoder: str, seed: int) -> dict[tuple[str, float], Path]:
    out = {}
    for pic in sorted((sweep_dir / "cells").glob(f"encoder={encoder},*seed={seed}/pictures/mask_final.png")):
        m = re.search(r"embedding=(\d+x\d+),photons=([0-9e.+]+)", pic.parent.parent.name)
        if m:
            out[(m.group(1), float(m.group(2)))] = pic
    return out


def redraw(sweep_dir: Path) -> int:
    """Redraw ``pictures/mask_final.png`` of every finished LCD cell: a fixed one from its configuration, a learned
    one where it kept its last checkpoint; how many."""
    import torch

    from optoenc.privacy.report import load_run
    from optoenc.training import checkpoint_path, pictures

    n = 0
    for cell in sorted((sweep_dir / "cells").glob("encoder=*_slm,*")):
        learned = cell.name.startswith("encoder=learned")
        if not (cell / "summary.json").is_file() or (learned and not checkpoint_path(cell, "last").is_file()):
            continue
        _, enc, _ = load_run(cell, which="last")
        with torch.no_grad():
            mask = enc.mask()
            pictures.save_mask(cell / "pictures" / "mask_final.png", mask, f"{enc.name} mask (final)",
                               pictures.mask_spacing(enc, mask), throughput=enc.throughput())
        n += 1
    return n


def montage(sweep_dir: Path, out: Path, seed: int = 0) -> Path | None:
    import matplotlib.image as mpimg

    learned = _cells(sweep_dir, "learned_slm", seed)
    fixed = _cells(sweep_dir, "fixed_slm", seed)
    if not learned:
        return None
    sizes = sorted({k[0] for k in learned}, key=lambda s: -int(s.split("x")[0]))
    levels = sorted({k[1] for k in learned}, reverse=True)
    cols = 1 + len(levels)
    plt, fig = new_figure((3.6 * cols, 3.0 * len(sizes)))
    for r, size in enumerate(sizes):
        start = next((fixed[k] for k in fixed if k[0] == size), None)
        panels = [("fixed LCD (the learned mask's start)", start)] + [
            (f"learned, {level:g} photons", learned.get((size, level))) for level in levels]
        for c, (title, path) in enumerate(panels):
            ax = fig.add_subplot(len(sizes), cols, r * cols + c + 1)
            ax.axis("off")
            if path is not None:
                ax.imshow(mpimg.imread(path))
            ax.set_title(f"{size}: {title}", fontsize=8)
    fig.suptitle(f"LCD masks under a fixed exposure (seed {seed}); each picture's title gives its throughput", fontsize=9)
    fig.tight_layout()
    return save_figure(plt, fig, out)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("sweep_dir", type=Path, help="sweep folder (holding cells/)")
    p.add_argument("out", type=Path, help="PNG to write")
    p.add_argument("--seed", type=int, default=0, help="the seed whose masks are shown (default 0)")
    p.add_argument("--redraw", action="store_true", help="first redraw the cells' mask pictures from their checkpoints")
    a = p.parse_args(argv)
    if a.redraw:
        print(f"{redraw(a.sweep_dir)} mask pictures redrawn")
    path = montage(a.sweep_dir, a.out, a.seed)
    if path is None:
        p.error(f"{a.sweep_dir}/cells: no finished learned_slm cell with pictures/mask_final.png for seed {a.seed}")
    print(path)


if __name__ == "__main__":
    main()
