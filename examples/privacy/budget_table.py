"""Tables and a figure from budget_study.py's CSVs: where each learned attacker levels off, and whether a
stronger attacker (four times wider, trained four times longer, or with a learning-rate schedule) re-identifies
more.

    python examples/privacy/budget_table.py DIR --out docs/results/privacy

DIR holds the budget studies, one CSV per run (``<encoder>-<embedding>.csv``, any name), and the stronger
attackers': ``...-larger.csv`` (budget_study.py with ``--hidden 1024 --channels 128``: both four times wider,
6.8x and 5.4x the weights at 6x8), ``...-longer.csv`` (the default attackers with four times the maximum
epochs, ``--epochs 200``) and ``...-scheduled.csv`` (``--schedule one_cycle --lr 3e-3``). Writes into OUT:

* ``budget.csv``: every row of every study, with ``attacker`` = ``default``, ``larger``, ``longer`` or
  ``scheduled``;
* ``budget.md``: per cell and attack, re-identification top-1 [%] with its Wilson 95 % interval over the grid of
  pairs (rows) x maximum epochs (columns), and whether it has levelled off: the largest budget re-identifies
  less than :data:`RISE` (3 points) more than the next smaller pair count at the same epochs and the next
  smaller epoch budget at the same pairs;
* ``attacker_size.md``: each stronger (larger, longer-trained or scheduled) attacker against the camera's
  privacy-table row for the same attack (with ``--table``; else the default attacker at the same pairs and
  epochs) and the table's strongest black-box attack, the differences in points;
* ``budget.png``: re-identification against pairs, one line per maximum epochs, one panel per cell and attack.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from optoenc.privacy.report import COLUMNS, read_table, strength, write_table
from optoenc.privacy.tables import acc_text, rate_text
from optoenc.training.rundir import atomic_write_text

#: The stronger attackers' files end with these (before ``.csv``): four times wider, four times the epochs, a
#: learning-rate schedule.
STRONGER = {"-larger": "larger", "-longer": "longer", "-scheduled": "scheduled"}
#: budget.csv's columns: the privacy table's and which attacker (``default`` or one of :data:`STRONGER`).
BUDGET_COLUMNS = (*COLUMNS, "attacker")


def _n(v) -> str:
    """A count as read back from CSV (a float) written as a whole number."""
    return str(int(v)) if isinstance(v, float) and v == int(v) else str(v)


def load(folder: Path) -> list[dict]:
    """Every row of the folder's budget CSVs, tagged ``attacker`` by the file's ending (:data:`STRONGER`: e.g.
    ``larger`` for -larger.csv) or ``default``."""
    rows = []
    for path in sorted(folder.glob("*.csv")):
        kind = next((k for suffix, k in STRONGER.items() if path.stem.endswith(suffix)), "default")
        rows += [{**r, "attacker": kind} for r in read_table(path)]
    return rows


def _cells(rows):
    seen = []
    for r in rows:
        key = (r["encoder"], r["embedding"], r["attack"])
        if key not in seen:
            seen.append(key)
    return seen


#: A rise in re-identification below this (a rate, 3 points) counts as levelled off: the "within a few points"
#: the attackers are held to. (Whether the rate lies inside the neighbour's Wilson interval is no test at the
#: ceiling: 99.7 % [99.1, 99.9] -> 100.0 % would count as rising.)
RISE = 0.03


def _flat(r: dict, ref: dict | None) -> bool:
    return ref is None or r["reid_top1"] - ref["reid_top1"] < RISE


def levelled(grid: dict) -> bool:
    """The largest budget re-identifies less than :data:`RISE` more than its neighbours one step smaller in pairs
    and in epochs (``grid``: ``(pairs, epochs) -> row``)."""
    pairs, epochs = sorted({p for p, _ in grid}), sorted({e for _, e in grid})
    top = grid[(pairs[-1], epochs[-1])]
    less_pairs = grid.get((pairs[-2], epochs[-1])) if len(pairs) > 1 else None
    less_epochs = grid.get((pairs[-1], epochs[-2])) if len(epochs) > 1 else None
    return _flat(top, less_pairs) and _flat(top, less_epochs)


def budget_markdown(rows: list[dict]) -> str:
    out = []
    default = [r for r in rows if r["attacker"] == "default"]
    for enc, emb, attack in _cells(default):
        grid = {(r["n_pairs"], r["max_epochs"]): r for r in default
                if (r["encoder"], r["embedding"], r["attack"]) == (enc, emb, attack)}
        pairs, epochs = sorted({p for p, _ in grid}), sorted({e for _, e in grid})
        verdict = "levelled off" if levelled(grid) else "still rising"
        out.append(f"**{enc} {emb}, {attack}** (test accuracy {acc_text(grid[(pairs[-1], epochs[-1])])};"
                   f" {verdict} at {_n(pairs[-1])} pairs, <= {_n(epochs[-1])} epochs)\n")
        out.append("| pairs | " + " | ".join(f"<= {_n(e)} epochs" for e in epochs) + " |")
        out.append("|---|" + "---|" * len(epochs))
        for p in pairs:
            cells = []
            for e in epochs:
                r = grid.get((p, e))
                cells.append("-" if r is None else f"{rate_text(r)} ({_n(r['epochs_run'])} run)")
            out.append(f"| {_n(p)} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def size_rows(rows: list[dict], table: list[dict] | None = None) -> list[dict]:
    """Each stronger attacker (``larger``, ``longer``, ``scheduled``) beside its reference: the camera's
    privacy-table row for the same attack (``table``: the cameras' rows, 3 seeds averaged) where given, else the
    budget study's default attacker at the same pairs and the most epochs up to its own (a longer-trained
    attacker's 200 against the grid's 50); and beside the table's strongest black-box attack on that camera."""
    def grid_point(b: dict) -> dict | None:
        same = [r for r in rows if r["attacker"] == "default" and r["max_epochs"] <= b["max_epochs"]
                and all(r[k] == b[k] for k in ("encoder", "embedding", "attack", "n_pairs"))]
        return max(same, key=lambda r: r["max_epochs"], default=None)

    table = table or []
    out = []
    for b in (r for r in rows if r["attacker"] != "default"):
        cam = (b["encoder"], b["embedding"])
        own = [t for t in table if (t["encoder"], t["embedding"]) == cam]
        ref = next((t for t in own if t["attack"] == b["attack"]), None)
        source = "table"
        if ref is None:
            ref, source = grid_point(b), "budget"
        if ref is None:
            continue
        bb = [t for t in own if t["threat_model"] == "black_box"]
        best = max(bb, key=strength) if bb else None  # ranked as the privacy tables rank attacks
        out.append({"encoder": cam[0], "embedding": cam[1], "attack": b["attack"], "attacker": b["attacker"],
                    "reference": source,
                    "n_pairs": b["n_pairs"], "max_epochs": b["max_epochs"],
                    "size": ref["attacker_size"], "reid": rate_text(ref), "size_stronger": b["attacker_size"],
                    "reid_stronger": rate_text(b), "change_pts": f"{100 * (b['reid_top1'] - ref['reid_top1']):+.1f}",
                    "best": "-" if best is None else f"{best['attack']} {rate_text(best)}",
                    "over_best_pts": "-" if best is None else f"{100 * (b['reid_top1'] - best['reid_top1']):+.1f}",
                    "val_loss": f"{ref['val_loss']:.4f}", "val_loss_stronger": f"{b['val_loss']:.4f}"})
    return out


def size_markdown(rows: list[dict]) -> str:
    cols = ("encoder", "embedding", "attack", "attacker", "reference", "n_pairs", "max_epochs", "size", "reid",
            "size_stronger", "reid_stronger", "change_pts", "best", "over_best_pts", "val_loss", "val_loss_stronger")
    heads = ("encoder", "embedding", "attack", "stronger attacker", "reference", "pairs", "max epochs", "size",
             "re-id [%]", "its size", "its re-id [%]", "change [pts]", "table's best black-box [%]",
             "it - best [pts]", "val loss", "its val loss")
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(_n(r[c]) for c in cols) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def figure(rows: list[dict], out: Path) -> Path | None:
    from optoenc.training.pictures import new_figure, save_figure

    default = [r for r in rows if r["attacker"] == "default"]
    cells = _cells(default)
    if not cells:
        return None
    cols = min(4, len(cells))
    nrows = (len(cells) + cols - 1) // cols
    plt, fig = new_figure((3.6 * cols, 2.8 * nrows))
    for i, (enc, emb, attack) in enumerate(cells):
        ax = fig.add_subplot(nrows, cols, i + 1)
        mine = [r for r in default if (r["encoder"], r["embedding"], r["attack"]) == (enc, emb, attack)]
        for e in sorted({r["max_epochs"] for r in mine}):
            pts = sorted((r["n_pairs"], r) for r in mine if r["max_epochs"] == e)
            x = [p for p, _ in pts]
            y = [100 * r["reid_top1"] for _, r in pts]
            lo = [100 * (r["reid_top1"] - r["reid_ci_low"]) for _, r in pts]
            hi = [100 * (r["reid_ci_high"] - r["reid_top1"]) for _, r in pts]
            ax.errorbar(x, y, yerr=[lo, hi], marker="o", ms=3, capsize=2, label=f"<= {_n(e)} epochs")
        ax.set_xscale("log")
        ax.set_title(f"{enc} {emb}, {attack}", fontsize=8)
        ax.set_xlabel("training pairs", fontsize=7)
        ax.set_ylabel("re-identification top-1 [%]", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6)
    fig.tight_layout()
    return save_figure(plt, fig, out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="folder of budget_study.py CSVs")
    ap.add_argument("--out", type=Path, required=True, help="folder to write budget.csv, budget.md, "
                    "attacker_size.md and budget.png into")
    ap.add_argument("--table", type=Path, help="the cameras' privacy.csv (optoenc privacy's table): compare the stronger "
                    "attackers with its rows rather than with the budget study's default attacker")
    args = ap.parse_args(argv)
    rows = load(args.folder)
    if not rows:
        print(f"budget_table: {args.folder} holds no budget CSVs", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    write_table(rows, args.out / "budget.csv", columns=BUDGET_COLUMNS)
    atomic_write_text(args.out / "budget.md", budget_markdown(rows))
    atomic_write_text(args.out / "attacker_size.md", size_markdown(size_rows(rows, read_table(args.table) if args.table else None)))
    figure(rows, args.out / "budget.png")
    print(f"{len(rows)} rows -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
