"""Defence tables: each attack's quality against a variable-pattern or adversarially trained camera, beside its baseline.

A sweep folder holds runs of one encoder that differ in ``encoder.patterns``
(K, the variable-pattern defence) and ``privacy.adversary_weight`` (lambda,
privacy-aware training). For every embedding size the baseline is the run
with K = 1 and lambda = 0 and the same seed; every row gives the attack's metrics and their
change against the same attack on the baseline:

* ``psnr_drop``, ``ssim_drop``: relative drops ``1 - value / baseline`` (the
  follow-up work's "drop in image quality"; positive = the defence helps);
* ``reid_change``, ``readability_change``, ``acc_change``: differences in
  rate (points / 100).

``admm_search`` and ``learned_one`` (only against ``K > 1``) are compared with
the baseline's ``admm`` and ``learned``.

Written by ``optoenc privacy --sweep DIR --defence`` to ``DIR/privacy/defence.{csv,md}``. Each run's own rows
with its settings (:func:`tag`, :data:`RUN_COLUMNS`) are what examples/privacy/make_privacy.py commits, one file a
run (docs/results/privacy/defence/); :func:`compare` derives the table from them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from ..training.rundir import RUN_FILES, atomic_write_text
from .tables import rate_text, write_csv

__all__ = ["COLUMNS", "RUN_COLUMNS", "cell_settings", "tag", "compare", "defence_rows", "write_defence", "markdown"]

COLUMNS = (
    "encoder", "embedding", "patterns", "adversary_weight", "seed", "epochs", "test_acc", "threat_model", "attack",
    "n_pairs", "max_epochs", "epochs_run", "val_loss", "attack_seeds", "attacker_size", "attacker_inputs", "psnr",
    "ssim", "readability", "readability_ci_low", "readability_ci_high", "reid_top1", "reid_top1_se", "reid_ci_low",
    "reid_ci_high", "psnr_drop", "ssim_drop", "reid_change", "readability_change", "acc_change", "count", "run",
)
#: The columns :func:`compare` derives from a run's rows and its baseline's.
CHANGES = ("psnr_drop", "ssim_drop", "reid_change", "readability_change", "acc_change")
#: One run's rows with its settings (:func:`tag`): the committed measurement of one defence run.
RUN_COLUMNS = tuple(c for c in COLUMNS if c not in CHANGES)


def cell_settings(run_dir: str | Path) -> dict[str, Any]:
    """``patterns`` (K), ``adversary_weight`` (lambda), ``seed`` and ``epochs`` of a run directory (defaults when absent)."""
    from omegaconf import OmegaConf

    tree = OmegaConf.to_container(OmegaConf.load(Path(run_dir) / RUN_FILES["config"]))
    return {
        "patterns": int((tree.get("encoder") or {}).get("patterns", 1)),
        "adversary_weight": float((tree.get("privacy") or {}).get("adversary_weight", 0.0)),
        "epochs": int((tree.get("trainer") or {}).get("max_epochs", 0)),
        "seed": int(tree.get("seed", 0)),
    }


#: Attacks that exist only against a K-pattern camera, compared with the baseline's attack of the same kind.
BASELINE_ATTACK = {"admm_search": "admm", "learned_one": "learned"}


def _key(r: dict, baseline: bool = False) -> tuple:
    attack = r["attack"] if baseline else BASELINE_ATTACK.get(r["attack"], r["attack"])
    pairs = r.get("n_pairs", "")
    # n_pairs: an int when measured, a float when read back from a table, empty for other attacks
    return (r["encoder"], r["embedding"], r.get("seed", 0), attack, "" if pairs in ("", None) else int(float(pairs)))


def tag(run_dir: str | Path, rows: Sequence[dict]) -> list[dict[str, Any]]:
    """``rows`` (one run's privacy rows) with the run's settings (:func:`cell_settings`) attached."""
    s = cell_settings(run_dir)
    return [{**r, **s} for r in rows]


def compare(tagged: Sequence[dict]) -> list[dict[str, Any]]:
    """Rows of several runs (each with its settings, :func:`tag`), sorted, with the change of each against the
    same attack on the baseline of its embedding and seed (K = 1, lambda = 0); a row without a baseline keeps its
    change columns empty."""
    base = {_key(r, baseline=True): r for r in tagged
            if float(r["patterns"]) == 1 and float(r["adversary_weight"]) == 0}
    out = []
    key = lambda r: (r["embedding"], float(r["patterns"]), float(r["adversary_weight"]), float(r["seed"]))  # noqa: E731
    for r in sorted(tagged, key=key):
        row = dict(r)
        b = base.get(_key(r))
        if b is not None:
            row["psnr_drop"] = 1 - float(r["psnr"]) / float(b["psnr"])
            row["ssim_drop"] = 1 - float(r["ssim"]) / float(b["ssim"])
            row["reid_change"] = float(r["reid_top1"]) - float(b["reid_top1"])
            row["readability_change"] = float(r["readability"]) - float(b["readability"])
            row["acc_change"] = float(r["test_acc"]) - float(b["test_acc"])
        out.append(row)
    return out


def defence_rows(cells: Sequence[tuple[str | Path, Sequence[dict]]]) -> list[dict[str, Any]]:
    """Rows of every cell with its settings and its change against the baseline cell of its embedding.

    Args:
        cells: ``(run directory, its privacy rows)`` pairs (as ``report.measure_run`` returns them).
    """
    return compare([r for run_dir, rows in cells for r in tag(run_dir, rows)])


def write_defence(rows: Sequence[dict], out_dir: str | Path) -> list[Path]:
    """``defence.csv`` (all :data:`COLUMNS`) and ``defence.md`` under ``out_dir``."""
    out_dir = Path(out_dir)
    return [write_csv(rows, out_dir / "defence.csv", COLUMNS),
            atomic_write_text(out_dir / "defence.md", markdown(rows))]


def _pct(v: Any, signed: bool = False) -> str:
    if v in ("", None):
        return "-"
    return f"{100 * float(v):+.1f}" if signed else f"{100 * float(v):.1f}"


def markdown(rows: Sequence[dict]) -> str:
    """Markdown table: settings, accuracy, each attack's quality and its change against the baseline."""
    lines = ["| embedding | K | lambda | seed | test acc [%] | attack | PSNR [dB] | SSIM | re-id top-1 [%] | readability [%] "
             "| PSNR drop [%] | SSIM drop [%] | re-id change [pts] | acc change [pts] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["attack"] == "mean_scene":
            continue
        att = r["attack"] + (f" (N={int(float(r['n_pairs']))})" if r.get("n_pairs") not in ("", None) else "")
        reid = rate_text(r)
        lines.append(
            f"| {r['embedding']} | {int(float(r['patterns']))} | {float(r['adversary_weight']):g} | {int(float(r.get('seed', 0)))} | {_pct(r['test_acc'])} | {att} "
            f"| {float(r['psnr']):.1f} | {float(r['ssim']):.2f} | {reid} "
            f"| {_pct(r['readability'])} | {_pct(r.get('psnr_drop'), True)} | {_pct(r.get('ssim_drop'), True)} "
            f"| {_pct(r.get('reid_change'), True)} | {_pct(r.get('acc_change'), True)} |"
        )
    return "\n".join(lines) + "\n"
