"""Collect the privacy measurements into docs/results/: the headline table, the budget study, the defences.

    python examples/privacy/make_privacy.py --table RUNS/privacy --budget BUDGET_DIR --defence DEFENCE_DIR \
        --out docs/results

* ``--table``: the folder ``optoenc privacy --sweep CELLS --match '*decoder=fcnn,seed=0' --out FOLDER`` wrote
  (privacy.csv, privacy_best.csv, the privacy-utility figures); its rows name their run directories, whose
  ``privacy/recon_<attack>.png`` pictures are found under ``--cells`` (default: the runs' own folder as
  recorded beside the table, i.e. the ``--sweep`` folder).
* ``--budget``: the folder of ``budget_study.py`` CSVs (``budget_table.py`` reads it).
* ``--defence``: the folder ``optoenc privacy --sweep DEFENCE_RUNS --defence`` wrote (defence.csv, defence.md).

Writes ``OUT/privacy.csv`` (every attack on every cell) and, under ``OUT/privacy/``: ``privacy.md`` (every attack),
``privacy_best.csv``, ``headline.md`` (one line per encoder and embedding: accuracy and the strongest attack of
each threat model with its re-identification interval), the privacy-utility figures, example reconstructions,
``budget.*`` and ``attacker_size.md``, ``defence.csv`` and ``defence.md``. Nothing is trained.
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import sys
from pathlib import Path

from optoenc.privacy.report import budget_text, read_table
from optoenc.privacy.tables import acc_text, rate_text
from optoenc.privacy.settings import THREAT_MODELS
from optoenc.training.rundir import atomic_write_text

HERE = Path(__file__).parent
#: Example reconstructions shown in docs/privacy.md: (encoder, embedding, attack).
EXAMPLES = (("fixed_slm", "24x32", "admm"), ("learned_slm", "6x8", "admm"), ("learned_slm", "6x8", "learned_conv"),
            ("lens", "24x32", "pinv"), ("lens", "6x8", "learned_conv"), ("learned_slm", "24x32", "learned_conv"))
ENCODERS = ("lens", "coded_aperture", "diffuser", "fixed_slm", "learned_slm")
EMBEDDINGS = ("24x32", "12x16", "6x8", "3x4")


def _attack(r: dict) -> str:
    return f"{r['attack']} ({budget_text(r)})" if r["attack"] == "plaintext" else r["attack"]


def headline(best: list[dict]) -> str:
    """One line per encoder and embedding: test accuracy, then per threat model its strongest attack, its
    re-identification top-1 with the Wilson 95 % interval, PSNR and SSIM."""
    by = {(r["encoder"], r["embedding"], r["threat_model"]): r for r in best}
    cells = [(e, s) for e in ENCODERS for s in EMBEDDINGS if any((e, s, t) in by for t in THREAT_MODELS)]
    head = ["encoder", "embedding", "test acc"]
    for t in THREAT_MODELS:
        head += [f"{t}: attack", "re-id [%] (95 % CI)", "PSNR [dB]", "SSIM"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for enc, emb in cells:
        first = next(by[(enc, emb, t)] for t in THREAT_MODELS if (enc, emb, t) in by)
        line = [enc, emb, acc_text(first)]
        for t in THREAT_MODELS:
            r = by.get((enc, emb, t))
            if r is None:
                line += ["-"] * 4
                continue
            line += [_attack(r), rate_text(r),
                     f"{float(r['psnr']):.1f}", f"{float(r['ssim']):.2f}"]
        lines.append("| " + " | ".join(line) + " |")
    return "\n".join(lines) + "\n"


def _budget_table():
    spec = importlib.util.spec_from_file_location("budget_table", HERE / "budget_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def collect(table: Path, cells: Path, out: Path, budget: Path | None = None, defence: Path | None = None) -> list[Path]:
    """Copy and derive everything listed in the module docstring; returns the files written."""
    priv = out / "privacy"
    priv.mkdir(parents=True, exist_ok=True)
    written = [Path(shutil.copyfile(table / "privacy.csv", out / "privacy.csv"))]
    for name in ("privacy.md", "privacy_best.csv", "privacy_utility.png", "privacy_utility_admm.png",
                 "privacy_utility_learned.png"):
        if (table / name).is_file():
            written.append(Path(shutil.copyfile(table / name, priv / name)))
    best = read_table(table / "privacy_best.csv")
    written.append(atomic_write_text(priv / "headline.md", headline(best)))
    runs = {(r["encoder"], r["embedding"]): r["run"] for r in read_table(table / "privacy.csv")}
    for enc, emb, attack in EXAMPLES:
        run = runs.get((enc, emb))
        src = cells / str(run) / "privacy" / f"recon_{attack}.png" if run else None
        if src is not None and src.is_file():
            written.append(Path(shutil.copyfile(src, priv / f"{enc}-{emb}_{attack}.png")))
    if budget is not None:
        if _budget_table().main([str(budget), "--out", str(priv)]) != 0:
            raise SystemExit(f"make_privacy: no budget CSVs in {budget}")
        written += [priv / n for n in ("budget.csv", "budget.md", "attacker_size.md", "budget.png")]
    if defence is not None:
        for name in ("defence.csv", "defence.md"):
            written.append(Path(shutil.copyfile(defence / name, priv / name)))
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, required=True, help="folder of `optoenc privacy --sweep ... --out`")
    ap.add_argument("--cells", type=Path, help="folder of the run directories the table's rows name "
                    "(default: the --table folder's parent)")
    ap.add_argument("--budget", type=Path, help="folder of budget_study.py CSVs")
    ap.add_argument("--defence", type=Path, help="folder of `optoenc privacy --sweep ... --defence`")
    ap.add_argument("--out", type=Path, default=HERE.parent.parent / "docs" / "results", help="docs/results (default)")
    args = ap.parse_args(argv)
    if not (args.table / "privacy_best.csv").is_file():
        print(f"make_privacy: --table {args.table}: no privacy_best.csv (run optoenc privacy --sweep first)",
              file=sys.stderr)
        return 2
    files = collect(args.table, args.cells or args.table.parent, args.out, args.budget, args.defence)
    print(f"{len(files)} files -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
