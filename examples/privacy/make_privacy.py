"""Write docs/results/privacy* from the privacy measurements; ``--check`` compares the committed tables.

    python examples/privacy/make_privacy.py --table W/privacy/all --cells T1/cells --budget W/budget \\
        --defence W/defence                # copy the measurements in, then derive the tables and figures
    python examples/privacy/make_privacy.py            # derive them again from the committed CSVs
    python examples/privacy/make_privacy.py --check    # exit 0 iff every derived table is what it would write;
                                                       # else 1, naming the first difference

The measurements (copied in, the data the rest is derived from):

* ``OUT/privacy/cameras/<run>.csv``: every attack on one camera, its run directory's ``privacy/privacy.csv``
  (``optoenc privacy --sweep CELLS --match '*decoder=fcnn,seed=0'`` writes them): the cameras named by
  ``--table``'s ``privacy.csv`` (the folder that sweep's ``--out`` wrote), found under ``--cells``, or with
  ``--cameras DIR`` every run directory of DIR that has one; with them the example reconstructions
  (``privacy/<encoder>-<embedding>_<attack>.png``);
* ``OUT/privacy/budget.csv``: every row of ``budget_study.py``'s CSVs in ``--budget`` (``budget_table.py``);
* ``OUT/privacy/defence/<run>.csv``: every attack on one defence run with its settings (K, lambda, seed,
  epochs), from each run directory of ``--defence`` (the sweep folder of ``examples/privacy/defence.yaml``) that
  has ``privacy/privacy.csv``.

Derived from those CSVs alone (``--check`` compares these text tables): ``OUT/privacy.csv`` (every camera's
attacks, encoders and embeddings in Table 1's order), ``privacy/privacy.md`` (the strongest attack
per threat model, then every attack), ``privacy_best.csv``, ``headline.md`` (one line per encoder and embedding:
accuracy and each threat model's strongest attack with its re-identification interval; then which cameras keep
the strongest black-box re-identification within 2x chance at most 1 point below the best accuracy),
``budget.md``, ``attacker_size.md``, ``defence.csv`` and ``defence.md`` (each defence run against its baseline);
the parts of ``OUT/../privacy.md`` (docs/privacy.md) between ``<!-- derived: NAME -->`` and ``<!-- /derived -->``
(``headline``: the headline table; ``question``: the cameras within a point and twice chance; the prose around
them is kept); and the figures (``privacy_utility*.png``, ``budget.png``;
redrawn, not compared). Nothing is trained.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import sys
from pathlib import Path

from optoenc.privacy import defence
from optoenc.privacy.report import (COLUMNS, PRIVACY_DIR, best_per_threat_model, document, read_table, save_frontiers,
                                    strength, sweep_cells, write_table)
from optoenc.privacy.settings import THREAT_MODELS, PrivacyConfig
from optoenc.privacy.tables import acc_text, count_text, csv_text, given, inputs_text, rate_text
from optoenc.training.rundir import atomic_write_text

HERE = Path(__file__).parent
RESULTS = HERE.parent.parent / "docs" / "results"
#: Example reconstructions shown in docs/privacy.md: (encoder, embedding, attack).
EXAMPLES = (("fixed_slm", "24x32", "admm"), ("learned_slm", "6x8", "admm"), ("learned_slm", "6x8", "learned_conv"),
            ("lens", "24x32", "pinv"), ("lens", "6x8", "learned_conv"), ("learned_slm", "24x32", "learned_conv"))
#: The question of docs/privacy.md: which cameras keep the strongest black-box re-identification within
#: FACTOR x chance while losing at most MARGIN (accuracy, fraction) against the most accurate camera.
FACTOR, MARGIN = 2, 0.01
#: The threat models open to the black-box attacker: his public scenes and their embeddings are pairs.
BLACK_BOX = ("black_box", "plaintext")
#: Re-identification chance: one in the gallery (the measurements' default gallery).
CHANCE = 1.0 / PrivacyConfig().gallery


def _load(name: str):
    """An example script as a module (they are scripts, not a package)."""
    path = {"budget_table": HERE / "budget_table.py", "make_results": HERE.parent / "paper" / "make_results.py"}[name]
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


#: Table 1's encoders and embeddings, in its order (examples/paper/make_results.py).
_RESULTS = _load("make_results")
ENCODERS, EMBEDDINGS = _RESULTS.ENCODERS, _RESULTS.EMBEDDINGS


def _attack(r: dict) -> str:
    return f"{r['attack']} (N={int(float(r['n_pairs']))})" if r["attack"] == "plaintext" else r["attack"]


def headline(best: list[dict], rows: list[dict] = ()) -> str:
    """One line per encoder and embedding: test accuracy, then per threat model its strongest attack, its
    re-identification top-1 with the Wilson 95 % interval, PSNR and SSIM; then the strongest of them all (what an
    attacker who knows the mask can reach: the mask lets him simulate any number of pairs, so every attack of
    the table is open to him); last which MLP attacked the camera in ``rows``: its hidden units and input scaling
    (``attacker_size``, ``attacker_inputs``; 256 standardise the former attacker, constant rate; 1024 whiten the
    current defaults, one-cycle; a table without ``attacker_inputs`` predates whitening: standardise)."""
    by = {(r["encoder"], r["embedding"], r["threat_model"]): r for r in best}
    units = {(r["encoder"], r["embedding"]): f"{count_text(r['attacker_size'])} {inputs_text(r)}" for r in rows
             if r["attack"] == "learned" and given(r.get("attacker_size"))}
    cells = [(e, s) for e in ENCODERS for s in EMBEDDINGS if any((e, s, t) in by for t in THREAT_MODELS)]
    head = ["encoder", "embedding", "test acc"]
    for t in THREAT_MODELS:
        head += [f"{t}: attack", "re-id [%] (95 % CI)", "PSNR [dB]", "SSIM"]
    head += ["strongest of all", "re-id [%] (95 % CI)", "MLP (units, inputs)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for enc, emb in cells:
        mine = [by[(enc, emb, t)] for t in THREAT_MODELS if (enc, emb, t) in by]
        line = [enc, emb, acc_text(mine[0])]
        for t in THREAT_MODELS:
            r = by.get((enc, emb, t))
            if r is None:
                line += ["-"] * 4
                continue
            line += [_attack(r), rate_text(r), f"{float(r['psnr']):.1f}", f"{float(r['ssim']):.2f}"]
        top = max(mine, key=strength)
        line += [_attack(top), rate_text(top), units.get((enc, emb), "-")]
        lines.append("| " + " | ".join(line) + " |")
    return "\n".join(lines) + "\n"


def question(best: list[dict], chance: float = CHANCE, factor: float = FACTOR, margin: float = MARGIN) -> str:
    """Which cameras keep the strongest black-box re-identification within ``factor`` x chance at most ``margin``
    below the best test accuracy; and the most accurate camera that keeps it there at all.

    The black-box attacker holds (public scene, embedding) pairs, as many as the plaintext attacker and more, so
    the plaintext attack is one of his: per camera the one of the two threat models' best rows with the higher
    re-identification counts (the black-box row on a tie)."""
    rank = lambda r: (float(r["reid_top1"]), r["threat_model"] == "black_box")  # noqa: E731 (a tie: his own)
    cams: dict[tuple, dict] = {}
    for r in best:
        if r["threat_model"] in BLACK_BOX and given(r.get("test_acc")):
            key = (r["encoder"], r["embedding"], r.get("run"))
            if key not in cams or rank(r) > rank(cams[key]):
                cams[key] = r
    bb = list(cams.values())
    if not bb:
        return ""
    top = max(bb, key=lambda r: float(r["test_acc"]))
    acc = float(top["test_acc"])
    limit = factor * chance
    name = lambda r: f"{r['encoder']} {r['embedding']}"  # noqa: E731
    near = sorted((r for r in bb if float(r["test_acc"]) >= acc - margin - 1e-12), key=lambda r: -float(r["test_acc"]))
    lines = [f"**Within {100 * margin:g} point of the best accuracy** ({name(top)}, {acc_text(top)}), the strongest "
             f"black-box attack (the plaintext attack included: the black-box attacker holds pairs too) against "
             f"{factor:g}x chance ({100 * limit:g} %):", "",
             "| encoder | embedding | test acc | below the best [pts] | black-box attack | re-id [%] (95 % CI) "
             "| within 2x chance |", "|---|---|---|---|---|---|---|"]
    for r in near:
        within = "yes" if float(r["reid_top1"]) <= limit else "no"
        lines.append(f"| {r['encoder']} | {r['embedding']} | {acc_text(r)} | {100 * (acc - float(r['test_acc'])):.2f} "
                     f"| {_attack(r)} | {rate_text(r)} | {within} |")
    kept = [r for r in near if float(r["reid_top1"]) <= limit]
    private = sorted((r for r in bb if float(r["reid_top1"]) <= limit), key=lambda r: -float(r["test_acc"]))
    lines += ["", f"Cameras that meet both: {', '.join(name(r) for r in kept) if kept else 'none'}. "]
    if private:
        p = private[0]
        lines[-1] += (f"The most accurate camera whose strongest black-box re-identification is within {factor:g}x "
                      f"chance: {name(p)}, {acc_text(p)} ({100 * (acc - float(p['test_acc'])):.1f} points below the "
                      f"best; re-id {rate_text(p)} %).")
    else:
        lines[-1] += f"No camera keeps the strongest black-box re-identification within {factor:g}x chance."
    return "\n".join(lines) + "\n"


#: A derived part of docs/privacy.md: its opening marker (group 1, naming the part in group 2), the text to
#: replace, its closing marker (group 3).
_PART = re.compile(r"(<!-- derived: ([\w-]+) -->\n).*?(<!-- /derived -->)", re.S)


def embed(doc: str, parts: dict[str, str], where: str = "docs/privacy.md") -> str:
    """``doc`` with the text between each ``<!-- derived: NAME -->`` and ``<!-- /derived -->`` replaced by
    ``parts[NAME]`` (a blank line either side); the rest as it is.

    Raises:
        SystemExit: a marker names a part not in ``parts``.
    """
    def put(m: re.Match) -> str:
        if m.group(2) not in parts:
            raise SystemExit(f"make_privacy: {where}: derived part {m.group(2)!r} unknown (one of {', '.join(parts)})")
        return f"{m.group(1)}\n{parts[m.group(2)].rstrip()}\n\n{m.group(3)}"
    return _PART.sub(put, doc)


def _camera_order(path: Path) -> tuple:
    rows = read_table(path)
    enc, emb = (rows[0]["encoder"], rows[0]["embedding"]) if rows else ("", "")
    rank = lambda seq, v: seq.index(v) if v in seq else len(seq)  # noqa: E731
    return rank(ENCODERS, enc), rank(EMBEDDINGS, emb), path.name


def cameras(out: Path) -> list[Path]:
    """The committed per-camera tables, in Table 1's order (encoders, then embeddings from large to small)."""
    return sorted((out / "privacy" / "cameras").glob("*.csv"), key=_camera_order)


def derive(out: Path, chance: float = CHANCE) -> dict[Path, str]:
    """Every derived text table (path -> text) from the measurement CSVs under ``out`` that exist."""
    priv = out / "privacy"
    texts: dict[Path, str] = {}
    rows = [r for path in cameras(out) for r in read_table(path)]
    if rows:
        best = best_per_threat_model(rows)
        texts[out / "privacy.csv"] = csv_text(rows, COLUMNS)
        texts[priv / "privacy.md"] = document(rows)
        texts[priv / "privacy_best.csv"] = csv_text(best, COLUMNS)
        parts = {"headline": headline(best, rows), "question": question(best, chance)}
        texts[priv / "headline.md"] = parts["headline"] + "\n" + parts["question"]
        doc = out.parent / "privacy.md"
        if doc.is_file():
            texts[doc] = embed(doc.read_text(), parts, str(doc))
    if (priv / "budget.csv").is_file():
        bt, budget = _load("budget_table"), read_table(priv / "budget.csv")
        texts[priv / "budget.md"] = bt.budget_markdown(budget)
        texts[priv / "attacker_size.md"] = bt.size_markdown(bt.size_rows(budget, rows))
    defended = [r for path in sorted((priv / "defence").glob("*.csv")) for r in read_table(path)]
    if defended:
        rows = defence.compare(defended)
        texts[priv / "defence.csv"] = csv_text(rows, defence.COLUMNS)
        texts[priv / "defence.md"] = defence.markdown(rows)
    return texts


def figures(out: Path, chance: float = CHANCE) -> list[Path]:
    """The privacy-utility figures and the budget figure from the committed CSVs."""
    priv = out / "privacy"
    rows = [r for path in cameras(out) for r in read_table(path)]
    paths = save_frontiers(rows, priv, chance) if rows else []
    if (priv / "budget.csv").is_file():
        paths.append(_load("budget_table").figure(read_table(priv / "budget.csv"), priv / "budget.png"))
    return [p for p in paths if p is not None]


def collect(out: Path, table: Path | None = None, cells: Path | None = None, budget: Path | None = None,
            defence_dir: Path | None = None, all_cameras: Path | None = None) -> list[Path]:
    """Copy the measurements in (the module docstring lists them); returns the files written."""
    priv = out / "privacy"
    (priv / "cameras").mkdir(parents=True, exist_ok=True)
    runs: dict[tuple, Path] = {}  # (encoder, embedding) -> run directory
    if table is not None:
        for r in read_table(table / "privacy.csv"):
            runs[(r["encoder"], r["embedding"])] = (cells or table.parent) / str(r["run"])
    if all_cameras is not None:
        for t in sorted(Path(all_cameras).glob("*/privacy/privacy.csv")):
            first = read_table(t)[0]
            runs[(first["encoder"], first["embedding"])] = t.parent.parent
    written = []
    for run in runs.values():
        src = run / "privacy" / "privacy.csv"
        if not src.is_file():
            raise SystemExit(f"make_privacy: {src}: missing (the camera's own table)")
        written.append(Path(shutil.copyfile(src, priv / "cameras" / f"{run.name}.csv")))
    for enc, emb, attack in EXAMPLES:
        src = runs[(enc, emb)] / "privacy" / f"recon_{attack}.png" if (enc, emb) in runs else None
        if src is not None and src.is_file():
            written.append(Path(shutil.copyfile(src, priv / f"{enc}-{emb}_{attack}.png")))
    if budget is not None:
        bt = _load("budget_table")
        rows = bt.load(budget)
        if not rows:
            raise SystemExit(f"make_privacy: --budget {budget}: no budget CSVs")
        written.append(write_table(rows, priv / "budget.csv", columns=bt.BUDGET_COLUMNS))
    if defence_dir is not None:
        measured = [run for run in sweep_cells(defence_dir) if (run / PRIVACY_DIR / "privacy.csv").is_file()]
        if not measured:
            raise SystemExit(f"make_privacy: --defence {defence_dir}: no run directory has privacy/privacy.csv")
        for run in measured:
            rows = defence.tag(run, read_table(run / PRIVACY_DIR / "privacy.csv"))
            written.append(write_table(rows, priv / "defence" / f"{run.name}.csv", columns=defence.RUN_COLUMNS))
    return written


def check(out: Path) -> str | None:
    """The first difference between the committed derived tables and what :func:`derive` gives; None where they
    agree."""
    for path, text in derive(out).items():
        diff = _RESULTS.first_difference(path, text, "make_privacy.py")
        if diff:
            return diff
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, help="folder of `optoenc privacy --sweep ... --out` (privacy.csv)")
    ap.add_argument("--cells", type=Path, help="folder of the run directories the table's rows name (their "
                    "example reconstructions; default: the --table folder's parent)")
    ap.add_argument("--cameras", type=Path, help="a folder of run directories: copy in every one that has "
                    "privacy/privacy.csv")
    ap.add_argument("--budget", type=Path, help="folder of budget_study.py CSVs")
    ap.add_argument("--defence", type=Path, help="the defence runs' sweep folder: copy in every run that has "
                    "privacy/privacy.csv")
    ap.add_argument("--out", type=Path, default=RESULTS, help="docs/results (default)")
    ap.add_argument("--check", action="store_true", help="compare the committed derived tables with what would be "
                    "written; exit 1 naming the first difference")
    args = ap.parse_args(argv)
    if args.check:
        diff = check(args.out)
        if diff:
            print(f"make_privacy --check: {diff}", file=sys.stderr)
            return 1
        return 0
    if args.table is not None and not (args.table / "privacy.csv").is_file():
        print(f"make_privacy: --table {args.table}: no privacy.csv (run optoenc privacy --sweep first)", file=sys.stderr)
        return 2
    files = collect(args.out, args.table, args.cells, args.budget, args.defence, args.cameras)
    files += [atomic_write_text(path, text) for path, text in derive(args.out).items()]
    files += figures(args.out)
    print(f"{len(files)} files -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
