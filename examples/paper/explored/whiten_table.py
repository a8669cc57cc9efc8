"""The whitening check beside Tables 1 and 3: docs/results/explored/tables/whiten.csv against table1.csv and table3.csv.

For each learned-SLM cell of the whitening sweep (examples/paper/explored/whiten.yaml, ``whiten_batchnorm_relu``)
it prints the paper's figure, the table's learned SLM (BatchNorm+ReLU; mean over the table's seeds), the
whitened learned SLM (and its re-simulation at the ``reference`` preset where the cell has one), the table's
fixed SLM (``standardize``), the whitened fixed SLM (from whiten.csv, else table1_whiten.csv), and the
learned-minus-fixed margin both ways.

With ``--table1`` it prints Table 1's fixed encoders instead (docs/results/explored/tables/table1_whiten.csv, from
examples/paper/explored/table1_whiten.yaml): the table's figure (``standardize``), the whitened one, the paper's
point-sampling sensor's (sampling.csv, where measured) and the paper's.

The learned SLM's variant chosen on validation among all its committed runs: examples/paper/select_variant.py.

    python examples/paper/explored/whiten_table.py [--results docs/results/explored/tables] [--table1]
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
    ap.add_argument("--results", type=Path, default=Path(__file__).resolve().parents[3] / "docs" / "results" / "explored" / "tables")
    ap.add_argument("--table1", action="store_true", help="Table 1's fixed encoders, whitened (table1_whiten.csv)")
    args = ap.parse_args(argv)
    tables = {"1": _rows(args.results / "table1_mixed.csv"), "3": _rows(args.results / "table3_mixed.csv")}
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
    sampling = _rows(results / "sampling_mixed.csv")

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


if __name__ == "__main__":
    main()
