"""Privacy tables for a run directory and for a sweep of run directories, and the privacy-utility plot.

A run directory is what `optoenc fit` writes (``config.yaml``, ``summary.json``,
``checkpoints/``); a sweep directory holds run directories as sub-folders.
Each run's table goes to ``RUN_DIR/privacy/`` (``privacy.csv``, ``privacy.md``,
example pictures); a sweep's combined table, the strongest attack per cell
and threat model (``privacy_best.csv``) and the privacy-utility plots go to
``SWEEP_DIR/privacy/``. ``privacy.md`` opens with the strongest attack per
threat model (:func:`best_per_threat_model`), then lists every attack. A run whose ``privacy/privacy.csv`` exists is not
measured again (delete it to re-measure), so an interrupted sweep resumes; a run interrupted mid-way keeps its
finished attacks in ``privacy/partial/`` and resumes at the attack it was in.
"""

from __future__ import annotations

import csv
import fnmatch
import json
import math
import shutil
from pathlib import Path
from typing import Any, Callable, Sequence


from ..errors import ConfigError
from .settings import THREAT_MODEL, THREAT_MODELS
from .tables import acc_text, given, rate_text, write_csv
from ..training.rundir import RUN_FILES, atomic_write_text

__all__ = [
    "COLUMNS", "load_run", "run_rows", "sweep_cells", "write_table", "read_table", "markdown", "best_per_threat_model",
    "best_markdown", "document", "strength", "save_frontiers",
]  # fmt: skip

#: Table columns, in order (docs/results/privacy.csv). ``threat_model``: the attack's
#: (:data:`~optoenc.privacy.settings.THREAT_MODEL`); ``n_pairs``: the attacker's (scene, embedding) pairs
#: (plaintext, learned: validation part included); the learned attackers' budget ``val_pairs``,
#: ``max_epochs``, ``epochs_run`` (per seed), their mean final ``val_loss``, ``attack_seeds``, ``attacker_size``
#: (the MLP's hidden units, the convolutional decoder's first channels), ``attacker_inputs`` (their input scaling,
#: :data:`~optoenc.privacy.settings.INPUTS`; empty in tables from before it was a setting: standardise) and each
#: seed's re-identification
#: ``reid_seeds``; rates with their binomial standard error (``_se``) and Wilson 95 %
#: interval (``_ci_low``, ``_ci_high``); ``count``: probes.
COLUMNS = (
    "encoder", "embedding", "threat_model", "attack", "n_pairs", "val_pairs", "max_epochs", "epochs_run", "val_loss",
    "attack_seeds", "attacker_size", "attacker_inputs", "psnr", "psnr_std", "ssim", "ssim_std", "readability", "readability_se", "readability_ci_low",
    "readability_ci_high", "reid_top1", "reid_top1_se", "reid_ci_low", "reid_ci_high", "reid_seeds", "test_acc",
    "count", "run",
)
#: Columns read back as text.
_TEXT = ("encoder", "embedding", "threat_model", "attack", "run", "epochs_run", "reid_seeds", "attacker_inputs")
PRIVACY_DIR = "privacy"
#: Sub-folder of a run's privacy folder holding its finished attacks until the table is written.
PARTIAL_DIR = "partial"


def load_run(run_dir: str | Path, overrides: Sequence[str] = (), which: str = "best"):
    """``(run config, encoder with the trained parameters, summary dict)`` of a run directory."""
    from omegaconf import OmegaConf

    from ..config import encoder_from_run, compose
    from ..training.run import checkpoint_path, load_encoder

    run_dir = Path(run_dir)
    cfg = run_dir / RUN_FILES["config"]
    if not cfg.is_file():
        raise ConfigError("--run", str(run_dir), f"not a run directory (no {RUN_FILES['config']})")
    run = compose([OmegaConf.load(cfg)], list(overrides))
    if checkpoint_path(run_dir, which).is_file():
        encoder = load_encoder(run, run_dir, which)
    else:
        encoder = encoder_from_run(run)
        if encoder.learnable:
            raise ConfigError("--run", str(run_dir), f"has no {which} checkpoint for its learned encoder")
    summary_path = run_dir / RUN_FILES["summary"]
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    return run, encoder.eval(), summary


def run_rows(result, encoder, summary: dict, run_label: str) -> list[dict[str, Any]]:
    """The evaluation rows of one encoder with its identity and test accuracy attached."""
    a, b = encoder.geometry.embedding
    acc = summary.get("test_acc", float("nan"))
    return [
        {"encoder": encoder.name, "embedding": f"{a}x{b}", "test_acc": acc, "run": run_label, "n_pairs": "", **r}
        for r in result.rows
    ]


def sweep_cells(sweep_dir: str | Path, match: str = "*") -> list[Path]:
    """Run directories (with config.yaml and summary.json) directly under ``sweep_dir`` whose name matches the
    shell pattern ``match``, sorted. A sweep's folder (with ``cells/``) stands for its ``cells/`` folder."""
    root = Path(sweep_dir)
    if not root.is_dir():
        raise ConfigError("--sweep", str(sweep_dir), "not a folder")
    if (root / "cells").is_dir() and not (root / RUN_FILES["config"]).is_file():
        root = root / "cells"
    runs = [p for p in root.iterdir() if (p / RUN_FILES["config"]).is_file() and (p / RUN_FILES["summary"]).is_file()]
    if not runs:
        raise ConfigError("--sweep", str(sweep_dir), "holds no run directories (sub-folders with config.yaml and summary.json)")
    cells = sorted(p for p in runs if fnmatch.fnmatchcase(p.name, match))
    if not cells:
        raise ConfigError("--match", match, f"matches none of the {len(runs)} run directories of {sweep_dir}")
    return cells


def write_table(rows: Sequence[dict], csv_path: str | Path, md_path: str | Path | None = None,
                columns: Sequence[str] = COLUMNS) -> Path:
    """Write ``rows`` as CSV (``columns``: all :data:`COLUMNS` unless a study adds its own) and optionally as a
    markdown table."""
    path = write_csv(rows, csv_path, columns)
    if md_path is not None:
        atomic_write_text(md_path, document(rows))
    return path


def read_table(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a table written by :func:`write_table` (numbers as floats)."""
    out = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            row: dict[str, Any] = {}
            for k, v in r.items():
                try:
                    row[k] = float(v) if k not in _TEXT and v != "" else v
                except ValueError:
                    row[k] = v
            out.append(row)
    return out


def budget_text(r: dict) -> str:
    """The attacker's budget in words: ``N=1000`` (plaintext), ``54000+6000 pairs, 12;14;11/50 ep, 3 seeds``
    (learned: training + validation pairs, epochs run per seed / maximum, seeds), ``-`` for the others."""
    if not given(r.get("n_pairs")):
        return "-"
    n = int(float(r["n_pairs"]))
    if not given(r.get("max_epochs")):
        return f"N={n}"
    val = int(float(r.get("val_pairs") or 0))
    runs = str(r.get("epochs_run", "")).removesuffix(".0")
    seeds = int(float(r.get("attack_seeds") or 1))
    return f"{n - val}+{val} pairs, {runs}/{int(float(r['max_epochs']))} ep, {seeds} seed{'s' if seeds > 1 else ''}"


def _threat(r: dict) -> str:
    return r.get("threat_model") or THREAT_MODEL.get(r["attack"], "") or "-"


def markdown(rows: Sequence[dict]) -> str:
    """A readable markdown table: PSNR, SSIM mean +- spread over probes; rates in percent with their Wilson 95 %
    interval; the attacker's threat model and budget."""
    head = ("| encoder | embedding | test acc | threat model | attack | budget | PSNR [dB] | SSIM | readability [%] "
            "| re-id top-1 [%] |")
    lines = [head, "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['encoder']} | {r['embedding']} | {acc_text(r)} | {_threat(r)} | {r['attack']} | {budget_text(r)} "
            f"| {float(r['psnr']):.1f} +- {float(r['psnr_std']):.1f} | {float(r['ssim']):.2f} +- {float(r['ssim_std']):.2f} "
            f"| {rate_text(r, 'readability', 'readability')} | {rate_text(r, 'reid_top1', 'reid')} |"
        )
    return "\n".join(lines) + "\n"


def strength(r: dict) -> tuple[float, float, float]:
    """How strong an attack's row is, for ranking attacks: re-identification top-1, then readability, then PSNR."""
    return tuple(float(r[k]) if given(r.get(k)) else -math.inf for k in ("reid_top1", "readability", "psnr"))


def best_per_threat_model(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """Per cell (encoder, embedding, run), the strongest attack under each threat model.

    Strongest: the highest re-identification top-1 (what leaks about the image beyond its class); ties go to
    the higher readability, then the higher PSNR. Plaintext rows compete across their pair counts (the row
    names its ``n_pairs``). The ``mean_scene`` floor belongs to no threat model and is left out. Cells keep the
    order of their first row, threat models :data:`~optoenc.privacy.settings.THREAT_MODELS`' order.
    """
    best: dict[tuple, dict] = {}
    cells: list[tuple] = []
    for r in rows:
        threat = r.get("threat_model") or THREAT_MODEL.get(r["attack"], "")
        if not threat:
            continue
        cell = (r["encoder"], r["embedding"], r.get("run", ""))
        if cell not in cells:
            cells.append(cell)
        score = strength(r)
        key = (*cell, threat)
        if key not in best or score > best[key][0]:
            best[key] = (score, {**r, "threat_model": threat})
    return [best[(*c, t)][1] for c in cells for t in THREAT_MODELS if (*c, t) in best]


def best_markdown(rows: Sequence[dict]) -> str:
    """Markdown table of :func:`best_per_threat_model`: one line per cell and threat model."""
    lines = ["| encoder | embedding | test acc | threat model | strongest attack | budget | re-id top-1 [%] "
             "| readability [%] | PSNR [dB] | SSIM |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in best_per_threat_model(rows):
        lines.append(
            f"| {r['encoder']} | {r['embedding']} | {acc_text(r)} | {r['threat_model']} | {r['attack']} | {budget_text(r)} "
            f"| {rate_text(r, 'reid_top1', 'reid')} | {rate_text(r, 'readability', 'readability')} | {float(r['psnr']):.1f} "
            f"| {float(r['ssim']):.2f} |"
        )
    return "\n".join(lines) + "\n"


def document(rows: Sequence[dict]) -> str:
    """privacy.md: the strongest attack per threat model, then every attack."""
    return ("## Strongest attack per threat model (highest re-identification)\n\n" + best_markdown(rows)
            + "\n## Every attack\n\n" + markdown(rows))


def save_examples(out_dir: Path, result, title: str) -> list[Path]:
    """One picture per attack: scene, embedding, reconstruction."""
    from .pictures import save_rows

    paths = []
    cols = [f"label {int(v)}" for v in result.labels]
    for name, recon in result.examples.items():
        rows = [("scene", result.scenes), ("embedding", result.embeddings), (name, recon)]
        paths.append(save_rows(out_dir / f"recon_{name}.png", rows, cols, f"{title}: {name}"))
    return paths


def measure_run(run_dir: Path, evaluate_kw: dict, overrides: Sequence[str] = (), force: bool = False,
                say: Callable[[str], None] = lambda _m: None, out: Path | None = None,
                note: Callable[[str], None] = lambda _m: None) -> list[dict]:
    """Measure one run directory (or reuse its existing table unless ``force``); returns its rows.

    The table and pictures go to ``out`` (default ``RUN_DIR/privacy``); ``note`` is given each line of
    :attr:`Result.notes <optoenc.privacy.evaluate.Result.notes>` (attacks that do not apply to the camera).
    """
    from ..plugins import get_registry
    from .evaluate import evaluate

    out = Path(out) if out else Path(run_dir) / PRIVACY_DIR
    table, partial = out / "privacy.csv", out / PARTIAL_DIR
    if table.is_file() and not force:
        return read_table(table)
    if force:
        shutil.rmtree(partial, ignore_errors=True)
    run, encoder, summary = load_run(run_dir, overrides)
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    result = evaluate(encoder, splits, cache_root=run.trainer.cache_dir, progress=say, resume_dir=partial,
                      **evaluate_kw)
    for line in result.notes:
        note(line)
    rows = run_rows(result, encoder, summary, Path(run_dir).name)
    save_examples(out, result, f"{encoder.name} {rows[0]['embedding']}")
    write_table(rows, table, out / "privacy.md")
    shutil.rmtree(partial, ignore_errors=True)
    return rows


def write_sweep(rows: Sequence[dict], out_dir: Path, chance: float) -> list[Path]:
    """The combined table (``privacy.csv``, ``privacy.md``), the strongest attack per cell and threat model
    (``privacy_best.csv``) and the privacy-utility plots of a sweep: one panel per threat model with its
    strongest attack (``privacy_utility.png``), and the learned and ADMM attackers' own."""
    out_dir = Path(out_dir)
    best = best_per_threat_model(rows)
    return [write_table(rows, out_dir / "privacy.csv", out_dir / "privacy.md"), out_dir / "privacy.md",
            write_table(best, out_dir / "privacy_best.csv"), *save_frontiers(rows, out_dir, chance)]


def save_frontiers(rows: Sequence[dict], out_dir: str | Path, chance: float) -> list[Path]:
    """The privacy-utility plots of a table's rows: one panel per threat model with its strongest attack
    (``privacy_utility.png``), and the learned and ADMM attackers' own (``privacy_utility_<attack>.png``)."""
    from .pictures import save_frontier, save_threat_frontiers

    out_dir, paths = Path(out_dir), []
    best = best_per_threat_model(rows)
    if best:
        paths.append(save_threat_frontiers(out_dir / "privacy_utility.png", best, THREAT_MODELS, chance))
    for attack in ("learned", "admm"):
        if any(r["attack"] == attack for r in rows):
            paths.append(save_frontier(out_dir / f"privacy_utility_{attack}.png", rows, attack, chance))
    return paths
