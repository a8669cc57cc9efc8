"""Privacy tables for a run directory and for a sweep of run directories, and the privacy-utility plot.

A run directory is what `optoenc fit` writes (``config.yaml``, ``summary.json``,
``checkpoints/``); a sweep directory holds run directories as sub-folders.
Each run's table goes to ``RUN_DIR/privacy/`` (``privacy.csv``, ``privacy.md``,
example pictures); a sweep's combined table and ``privacy_utility.png`` go
to ``SWEEP_DIR/privacy/``. A run whose ``privacy/privacy.csv`` exists is not
measured again (delete it to re-measure), so an interrupted sweep resumes.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any, Callable, Sequence


from ..errors import ConfigError
from ..training.rundir import RUN_FILES, atomic_write_text

__all__ = ["COLUMNS", "load_run", "run_rows", "sweep_cells", "write_table", "read_table", "markdown"]

#: Table columns, in order (docs/results/privacy.csv).
COLUMNS = (
    "encoder", "embedding", "attack", "n_pairs", "psnr", "psnr_std", "ssim", "ssim_std", "readability",
    "readability_se", "reid_top1", "reid_top1_se", "test_acc", "count", "run",
)
PRIVACY_DIR = "privacy"


def load_run(run_dir: str | Path, overrides: Sequence[str] = (), which: str = "best"):
    """``(run config, encoder with the trained parameters, summary dict)`` of a run directory."""
    from omegaconf import OmegaConf

    from ..config import build_encoder, compose
    from ..training.run import checkpoint_path, load_encoder

    run_dir = Path(run_dir)
    cfg = run_dir / RUN_FILES["config"]
    if not cfg.is_file():
        raise ConfigError("--run", str(run_dir), f"not a run directory (no {RUN_FILES['config']})")
    run = compose([OmegaConf.load(cfg)], list(overrides))
    if checkpoint_path(run_dir, which).is_file():
        encoder = load_encoder(run, run_dir, which)
    else:
        encoder = build_encoder(run)
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


def sweep_cells(sweep_dir: str | Path) -> list[Path]:
    """Run directories (with config.yaml and summary.json) directly under ``sweep_dir``, sorted."""
    root = Path(sweep_dir)
    if not root.is_dir():
        raise ConfigError("--sweep", str(sweep_dir), "not a folder")
    cells = sorted(p for p in root.iterdir() if (p / RUN_FILES["config"]).is_file() and (p / RUN_FILES["summary"]).is_file())
    if not cells:
        raise ConfigError("--sweep", str(sweep_dir), "holds no run directories (sub-folders with config.yaml and summary.json)")
    return cells


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def write_table(rows: Sequence[dict], csv_path: str | Path, md_path: str | Path | None = None) -> Path:
    """Write ``rows`` as CSV (all :data:`COLUMNS`) and optionally as a markdown table."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(COLUMNS), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _fmt(r.get(k, "")) for k in COLUMNS})
    path = atomic_write_text(csv_path, buf.getvalue())
    if md_path is not None:
        atomic_write_text(md_path, markdown(rows))
    return path


def read_table(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a table written by :func:`write_table` (numbers as floats)."""
    out = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            row: dict[str, Any] = {}
            for k, v in r.items():
                try:
                    row[k] = float(v) if k not in ("encoder", "embedding", "attack", "run") and v != "" else v
                except ValueError:
                    row[k] = v
            out.append(row)
    return out


def markdown(rows: Sequence[dict]) -> str:
    """A readable markdown table: mean +- spread, rates in percent."""
    head = "| encoder | embedding | test acc | attack | PSNR [dB] | SSIM | readability | re-id top-1 |"
    lines = [head, "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        att = r["attack"] + (f" (N={int(float(r['n_pairs']))})" if r.get("n_pairs") not in ("", None) else "")
        acc = r.get("test_acc", float("nan"))
        acc_s = "-" if acc != acc else f"{100 * float(acc):.1f} %"
        lines.append(
            f"| {r['encoder']} | {r['embedding']} | {acc_s} | {att} | {float(r['psnr']):.1f} +- {float(r['psnr_std']):.1f} "
            f"| {float(r['ssim']):.2f} +- {float(r['ssim_std']):.2f} "
            f"| {100 * float(r['readability']):.1f} +- {100 * float(r['readability_se']):.1f} % "
            f"| {100 * float(r['reid_top1']):.1f} +- {100 * float(r['reid_top1_se']):.1f} % |"
        )
    return "\n".join(lines) + "\n"


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
                say: Callable[[str], None] = lambda _m: None, out: Path | None = None) -> list[dict]:
    """Measure one run directory (or reuse its existing table unless ``force``); returns its rows.

    The table and pictures go to ``out`` (default ``RUN_DIR/privacy``).
    """
    from ..plugins import get_registry
    from .evaluate import evaluate

    out = Path(out) if out else Path(run_dir) / PRIVACY_DIR
    table = out / "privacy.csv"
    if table.is_file() and not force:
        return read_table(table)
    run, encoder, summary = load_run(run_dir, overrides)
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    result = evaluate(encoder, splits, cache_root=run.trainer.cache_dir, progress=say, **evaluate_kw)
    rows = run_rows(result, encoder, summary, Path(run_dir).name)
    save_examples(out, result, f"{encoder.name} {rows[0]['embedding']}")
    write_table(rows, table, out / "privacy.md")
    return rows


def write_sweep(rows: Sequence[dict], out_dir: Path, chance: float) -> list[Path]:
    """The combined table and the privacy-utility plots (learned and ADMM attackers) of a sweep."""
    from .pictures import save_frontier

    out_dir = Path(out_dir)
    paths = [write_table(rows, out_dir / "privacy.csv", out_dir / "privacy.md"), out_dir / "privacy.md"]
    for attack in ("learned", "admm"):
        if any(r["attack"] == attack for r in rows):
            paths.append(save_frontier(out_dir / f"privacy_utility_{attack}.png", rows, attack, chance))
    return paths
