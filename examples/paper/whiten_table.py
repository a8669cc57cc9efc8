"""The whitening check beside Tables 1 and 3: docs/results/whiten.csv against table1.csv and table3.csv.

For each learned-SLM cell of the whitening sweep (examples/paper/whiten.yaml, ``whiten_batchnorm_relu``)
it prints the paper's figure, the table's learned SLM (BatchNorm+ReLU; mean over the table's seeds), the
whitened learned SLM (and its re-simulation at the ``reference`` preset where the cell has one), the table's
fixed SLM (``standardize``), the whitened fixed SLM (from whiten.csv, else table1_whiten.csv), and the
learned-minus-fixed margin both ways.

With ``--table1`` it prints Table 1's fixed encoders instead (docs/results/table1_whiten.csv, from
examples/paper/table1_whiten.yaml): the table's figure (``standardize``), the whitened one, the paper's
point-sampling sensor's (sampling.csv, where measured) and the paper's.

With ``--select`` it chooses, for each learned-SLM cell of Tables 1 and 3 (seed 0, Table 3's transforms drawn
once), the variant with the highest *validation* accuracy among the table's (BatchNorm+ReLU, the decoder's
Adam at 1e-3), the whitened one (``whiten_batchnorm_relu``; examples/paper/whiten.yaml) and the decoder's rate
1e-2 (examples/paper/decoder_lr.yaml), where each has run; reads them from the cells' ``summary.json`` under
docs/results/sweep_cells/{table1,table3,whiten,decoder_lr}, and prints the selected variant's test accuracy
against the paper's: hyperparameters chosen on validation, as the epoch is.

    python examples/paper/whiten_table.py [--results docs/results] [--table1 | --select]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _num(s: str | None) -> float | None:
    return float(s) if s not in (None, "") else None


def _fmt(v: float | None, signed: bool = False) -> str:
    return "-" if v is None else (f"{v:+.2f}" if signed else f"{v:.2f}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, default=Path(__file__).resolve().parents[2] / "docs" / "results")
    ap.add_argument("--table1", action="store_true", help="Table 1's fixed encoders, whitened (table1_whiten.csv)")
    ap.add_argument("--select", action="store_true", help="the learned SLM's decoder variant chosen on validation")
    args = ap.parse_args(argv)
    if args.select:
        return _select(args.results)
    tables = {"1": _rows(args.results / "table1.csv"), "3": _rows(args.results / "table3.csv")}
    if args.table1:
        return _table1(args.results, tables["1"])
    wh = _rows(args.results / "whiten.csv")
    t1w = _rows(args.results / "table1_whiten.csv") if (args.results / "table1_whiten.csv").exists() else []

    def table_acc(encoder, emb, dec, transform):
        if transform == "original":
            rows = [r for r in tables["1"] if (r["encoder"], r["embedding"], r["decoder"]) == (encoder, emb, dec)]
        else:
            rows = [r for r in tables["3"] if (r["encoder"], r["embedding"], r["decoder"], r["transform"]) ==
                    (encoder, emb, dec, transform) and r["augment_mode"] in ("once", "")]
        return _num(rows[0]["test_acc"]) if rows else None

    def whitened(encoder, emb, dec, transform):
        rows = [r for r in wh if (r["encoder"], r["embedding"], r["decoder"], r["transform"]) == (encoder, emb, dec, transform)
                and r["augment_mode"] in ("once", "") and
                (r["variant"] == "" if encoder == "learned_slm" else r["variant"] == "embedding_norm=whiten")]
        if not rows and encoder != "learned_slm" and transform == "original":  # Table 1's whitened fixed encoders
            rows = [r for r in t1w if (r["encoder"], r["embedding"], r["decoder"]) == (encoder, emb, dec)]
        return rows[0] if rows else None

    print("| table | embedding | decoder | transform | paper | learned (table) | learned, whitened | "
          "whitened at reference | fixed (table) | fixed, whitened | learned - fixed (table) | learned - fixed (whitened) |")
    print("|" + "---|" * 12)
    for r in wh:
        if r["encoder"] != "learned_slm" or r["variant"]:
            continue
        key = (r["embedding"], r["decoder"], r["transform"])
        lt, lw = table_acc("learned_slm", *key), _num(r["test_acc"])
        ft = table_acc("fixed_slm", *key)
        fw_row = whitened("fixed_slm", *key)
        fw = _num(fw_row["test_acc"]) if fw_row else None
        print(f"| {'1' if r['transform'] == 'original' else '3'} | {r['embedding']} | {r['decoder']} | {r['transform']} | "
              f"{_fmt(_num(r['paper_acc']))} | {_fmt(lt)} | {_fmt(lw)} | {_fmt(_num(r['reference_test_acc']))} | "
              f"{_fmt(ft)} | {_fmt(fw)} | {_fmt(lt - ft if None not in (lt, ft) else None, True)} | "
              f"{_fmt(lw - fw if None not in (lw, fw) else None, True)} |")


def _table1(results: Path, table1: list[dict[str, str]]) -> None:
    sampling = _rows(results / "sampling.csv")

    def acc(rows, r, column="test_acc"):
        hit = [x for x in rows if (x["encoder"], x["embedding"], x["decoder"]) == (r["encoder"], r["embedding"], r["decoder"])]
        return _num(hit[0].get(column)) if hit else None

    print("| encoder | embedding | decoder | paper | table (standardize) | whitened | whitened - table | "
          "point samples (standardize) |")
    print("|" + "---|" * 8)
    for r in sorted(_rows(results / "table1_whiten.csv"), key=lambda r: (r["encoder"], r["decoder"],
                                                                          -int(r["embedding"].split("x")[0]))):
        t, w = acc(table1, r), _num(r["test_acc"])
        print(f"| {r['encoder']} | {r['embedding']} | {r['decoder']} | {_fmt(_num(r['paper_acc']))} | {_fmt(t)} | "
              f"{_fmt(w)} | {_fmt(w - t if None not in (w, t) else None, True)} | {_fmt(acc(sampling, r, 'point_test_acc'))} |")


def _summary(cell: Path) -> dict | None:
    import json

    try:
        return json.loads((cell / "summary.json").read_text())
    except (OSError, ValueError):
        return None


#: The learned SLM's variants --select chooses among: (label, sweep folder under sweep_cells ("table": table1
#: or table3), its cell names' prefix); the table's own cells first (a tie keeps the earlier variant).
VARIANTS = (("table", "table", "encoder=learned_slm,"), ("whitened", "whiten", ""), ("decoder 1e-2", "decoder_lr", ""))


def _select(results: Path) -> None:
    cells = results / "sweep_cells"
    paper = {(r["embedding"], r["decoder"], r.get("transform", "original")): _num(r["paper_acc"])
             for name in ("table1.csv", "table3.csv") for r in _rows(results / name) if r["encoder"] == "learned_slm"
             and r.get("augment_mode", "once") in ("once", "")}
    print("| embedding | decoder | transform | paper | " + " | ".join(f"{v}: val | {v}: test" for v, _, _ in VARIANTS)
          + " | selected | selected: test | minus paper |")
    print("|" + "---|" * (4 + 2 * len(VARIANTS) + 3))
    below = 0
    for (emb, dec, transform), p in paper.items():
        found = []
        for label, folder, prefix in VARIANTS:
            if transform == "original":
                name = f"{prefix}embedding={emb},decoder={dec}," + ("seed=0," if folder == "table" else "") + "verify_preset=reference"
            else:
                suffix = ",operator_dtype=auto,precision=auto" if emb == "24x32" else ""
                name = f"{prefix}embedding={emb}," + ("" if folder == "table" else "decoder=fcnn,") + \
                    f"augment={transform},augment_draw=once{suffix}"
            where = ("table1" if transform == "original" else "table3") if folder == "table" else folder
            summary = _summary(cells / where / name)
            found.append(None if summary is None else (100 * summary["val_acc"], 100 * summary["test_acc"]))
        if found[0] is None:
            print(f"| {emb} | {dec} | {transform} | {_fmt(p)} | not run: the table's cell |")
            continue
        best = max((k for k in range(len(VARIANTS)) if found[k] is not None), key=lambda k: (found[k][0], -k))
        acc = found[best][1]
        below += acc < p
        runs = " | ".join("- | -" if f is None else f"{_fmt(f[0])} | {_fmt(f[1])}" for f in found)
        print(f"| {emb} | {dec} | {transform} | {_fmt(p)} | {runs} | {VARIANTS[best][0]} | {_fmt(acc)} | "
              f"{_fmt(acc - p, True)} |")
    print(f"\n{below} cells below the paper with the variant chosen on validation (seed 0; '-': not run)")


if __name__ == "__main__":
    main()
