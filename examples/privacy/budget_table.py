"""Tables and a figure from budget_study.py's CSVs: where each learned attacker levels off over pairs x epochs,
and whether another attacker (wider, or the former attacker's variants) re-identifies more than the table's.

    python examples/privacy/budget_table.py DIR --out docs/results/privacy

DIR holds the budget studies, one CSV per camera and attacker, ``<encoder>-<embedding>[-<attacker>].csv``
(see :data:`ATTACKERS`): the table's attacker (no ending: a grid of pairs x maximum epochs), the same with
twice the width (``-larger``: ``--hidden 2048``, 3.1x the weights at 6x8), the same with scalar standardisation
instead of whitening (``-standardised``: ``--inputs standardise``, a grid), and the former table attacker
(``-former``: ``--hidden 256 --schedule constant --lr 1e-3 --inputs standardise``, a grid) with its stronger
variants (``-former-larger``: ``--hidden 1024``; ``-former-longer``: ``--epochs 200``; ``-former-scheduled``:
``--schedule one_cycle --lr 3e-3``). Writes into OUT:

* ``budget.csv``: every row of every study, with ``attacker`` the file's ending (``default`` for none);
* ``budget.md``: per grid (the table's, the standardised and the former attacker's), cell and attack,
  re-identification top-1 [%] with its Wilson 95 % interval over pairs (rows) x maximum epochs (columns), and whether it has levelled off:
  the largest budget re-identifies less than :data:`RISE` (3 points) more than the next smaller pair count at
  the same epochs and the next smaller epoch budget at the same pairs;
* ``attacker_size.md``: every attacker that is not a grid (the larger and the former ones), and the table
  attacker's grid points trained longer than its table row, against the camera's privacy-table row for the same
  attack (with ``--table``; else its own grid's point at the same pairs and the most epochs up to its own) and
  the table's strongest black-box attack, the differences in points;
* ``budget.png``: re-identification against pairs, one line per maximum epochs, one panel per cell and attack.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from optoenc.privacy.report import COLUMNS, read_table, strength, write_table
from optoenc.privacy.settings import LearnedConfig
from optoenc.privacy.tables import acc_text, count_text as _n, inputs_text, rate_text
from optoenc.training.rundir import atomic_write_text

_TABLE = LearnedConfig()
#: The attackers, by the ending of their files' names (after ``<encoder>-<embedding>-``; ``default``: none):
#: the table's attacker, the same on standardised inputs (the table's attacker before whitening) and the former
#: table attacker (before the budget study showed it still rising at 6x8), each with the settings its rows were
#: trained with (budget_study.py's options).
_FORMER = "--schedule constant --lr 1e-3 --inputs standardise"
ATTACKERS = {
    "default": f"the table's attacker (the defaults: MLP {_TABLE.hidden} units, {_TABLE.schedule} to {_TABLE.lr:g}, "
               f"inputs {_TABLE.inputs})",
    "larger": "the table's MLP with 2048 units (--hidden 2048, 3.1x the weights at 6x8)",
    "standardised": "the table's attacker with scalar standardisation instead of whitening (--inputs standardise)",
    "former": f"the former attacker (--hidden 256 {_FORMER})",
    "former-larger": f"the former MLP with 1024 units (--hidden 1024 {_FORMER})",
    "former-longer": f"the former attacker, at most 200 epochs (--hidden 256 {_FORMER} --epochs 200)",
    "former-scheduled": "the former attacker with the one-cycle schedule (--hidden 256 --schedule one_cycle --lr 3e-3 "
                        "--inputs standardise)",
}
#: The attackers studied over a grid of pairs x epochs (the others are single points set against the table).
GRIDS = ("default", "standardised", "former")
#: budget.csv's columns: the privacy table's and which attacker (a key of :data:`ATTACKERS`).
BUDGET_COLUMNS = (*COLUMNS, "attacker")


def attacker(path: Path) -> str:
    """The attacker of a budget CSV from its name, ``<encoder>-<embedding>[-<attacker>].csv`` (encoder names hold
    no ``-``).

    Raises:
        ValueError: an ending that is not one of :data:`ATTACKERS`.
    """
    parts = path.stem.split("-", 2)
    kind = parts[2] if len(parts) == 3 else "default"
    if kind not in ATTACKERS:
        raise ValueError(f"budget file {path.name}: attacker {kind!r} is not one of {', '.join(ATTACKERS)}")
    return kind


def grid_of(kind: str) -> str:
    """The grid an attacker belongs to: a grid's own name for it and its variants (``former-larger``: ``former``),
    else ``default``."""
    head = kind.split("-")[0]
    return head if head in GRIDS else "default"


def load(folder: Path) -> list[dict]:
    """Every row of the folder's budget CSVs, tagged ``attacker`` by the file's name (:func:`attacker`)."""
    return [{**r, "attacker": attacker(path)} for path in sorted(folder.glob("*.csv")) for r in read_table(path)]


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


def _grids(rows: list[dict]):
    """(grid kind, encoder, embedding, attack, its grid ``(pairs, epochs) -> row``) for every grid study."""
    for kind in GRIDS:
        mine = [r for r in rows if r["attacker"] == kind]
        for enc, emb, attack in _cells(mine):
            yield kind, enc, emb, attack, {(r["n_pairs"], r["max_epochs"]): r for r in mine
                                           if (r["encoder"], r["embedding"], r["attack"]) == (enc, emb, attack)}


def budget_markdown(rows: list[dict]) -> str:
    out = []
    for kind, enc, emb, attack, grid in _grids(rows):
        pairs, epochs = sorted({p for p, _ in grid}), sorted({e for _, e in grid})
        verdict = "levelled off" if levelled(grid) else "still rising"
        out.append(f"**{enc} {emb}, {attack}, {ATTACKERS[kind]}** (test accuracy "
                   f"{acc_text(grid[(pairs[-1], epochs[-1])])}; {verdict} at {_n(pairs[-1])} pairs, "
                   f"<= {_n(epochs[-1])} epochs)\n")
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


def same_attacker(a: dict, b: dict) -> bool:
    """Whether two rows were measured by the same network: its size and input scaling (a row without
    ``attacker_inputs`` predates the setting: standardise)."""
    return a.get("attacker_size") == b.get("attacker_size") and inputs_text(a) == inputs_text(b)


def size_rows(rows: list[dict], table: list[dict] | None = None) -> list[dict]:
    """Each attacker that is not a grid (:data:`GRIDS`) beside its reference: the camera's privacy-table row for
    the same attack (``table``: the cameras' rows, 3 seeds averaged) where given, else its own grid's point at the
    same pairs and the most epochs up to its own (a longer-trained attacker's 200 against the grid's 50); and
    beside the table's strongest black-box attack on that camera. With ``table``, the grids' points at the table's
    pairs and more epochs than its row, measured by the same network (:func:`same_attacker`), are set against it
    too (``<grid>, longer``, e.g. ``default, longer``: the table's attacker trained longer)."""
    def grid_point(b: dict) -> dict | None:
        same = [r for r in rows if r["attacker"] == grid_of(b["attacker"]) and r["max_epochs"] <= b["max_epochs"]
                and all(r[k] == b[k] for k in ("encoder", "embedding", "attack", "n_pairs"))]
        return max(same, key=lambda r: r["max_epochs"], default=None)

    table = table or []

    def longer(r: dict) -> bool:  # a grid's point trained longer than the table's row by the same attacker
        ref = next((t for t in table if all(t[k] == r[k] for k in ("encoder", "embedding", "attack"))), None)
        return (r["attacker"] in GRIDS and ref is not None and same_attacker(r, ref) and r["n_pairs"] == ref["n_pairs"]
                and r["max_epochs"] > ref["max_epochs"])

    out = []
    for b in (r for r in rows if r["attacker"] not in GRIDS or longer(r)):
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
        out.append({"encoder": cam[0], "embedding": cam[1], "attack": b["attack"],
                    "attacker": f"{b['attacker']}, longer" if b["attacker"] in GRIDS else b["attacker"],
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
    heads = ("encoder", "embedding", "attack", "attacker", "reference", "pairs", "max epochs", "size",
             "re-id [%]", "its size", "its re-id [%]", "change [pts]", "table's best black-box [%]",
             "it - best [pts]", "val loss", "its val loss")
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(_n(r[c]) for c in cols) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def figure(rows: list[dict], out: Path) -> Path | None:
    from optoenc.training.pictures import new_figure, save_figure

    grids = list(_grids(rows))
    if not grids:
        return None
    cols = min(4, len(grids))
    nrows = (len(grids) + cols - 1) // cols
    plt, fig = new_figure((3.6 * cols, 2.8 * nrows))
    for i, (kind, enc, emb, attack, grid) in enumerate(grids):
        ax = fig.add_subplot(nrows, cols, i + 1)
        mine = list(grid.values())
        for e in sorted({r["max_epochs"] for r in mine}):
            pts = sorted(((r["n_pairs"], r) for r in mine if r["max_epochs"] == e), key=lambda t: t[0])
            x = [p for p, _ in pts]
            y = [100 * r["reid_top1"] for _, r in pts]
            lo = [100 * (r["reid_top1"] - r["reid_ci_low"]) for _, r in pts]
            hi = [100 * (r["reid_ci_high"] - r["reid_top1"]) for _, r in pts]
            ax.errorbar(x, y, yerr=[lo, hi], marker="o", ms=3, capsize=2, label=f"<= {_n(e)} epochs")
        ax.set_xscale("log")
        ax.set_title(f"{enc} {emb}, {attack}" + (", former attacker" if kind == "former" else ""), fontsize=8)
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
