"""Write docs/results/ from the committed cells and the current specs alone; ``--check`` compares.

    python examples/paper/make_results.py                         # tables and figures from docs/results/cells/
    python examples/paper/make_results.py --import table1=DIR ...  # first copy a sweep's finished cells in
    python examples/paper/make_results.py --check                 # exit 0 iff every committed table is what it
                                                                  # would write; else 1, naming the first difference

The headline (Tables 1 and 3: examples/paper/table1.yaml, table3.yaml) is trained on the settings
``optoenc fit`` gives a user; the like-for-like checks with the paper's point-sampling sensor
(sampling.yaml, table3_sampling.yaml) differ from them in ``sensor.sampling`` only. Each spec's finished
cells live in ``docs/results/cells/<spec>/cells/<cell>/`` (config.yaml, summary.json, metrics.csv and, for
learned encoders, the trained PSF and mask pictures, and for Table 1's seed-0 FCNN cells at 24x32 and 6x8 the
example embeddings; never checkpoints): a cell counts where its stored
configuration is the spec's. Table 2 (relative drop 24x32 -> 3x4) comes from Table 1, Table 4 (relative drop
under each transform) from Tables 1 and 3, and the paper's drops the same way from its own tables.
Everything explored beyond the defaults (``docs/results/explored/<spec>/<cell>/``, read as stored) is one
separate table, ``explored.csv``. ``--check`` trains nothing and compares the text tables only (CSV and
markdown); figures are redrawn but not compared.
"""

from __future__ import annotations

import argparse
import csv
import functools
import io
import math
import shutil
import sys
import tempfile
from pathlib import Path

import yaml

from optoenc import sweep
from optoenc.training.rundir import atomic_write_text

HERE = Path(__file__).parent
ROOT = HERE.parent.parent
RESULTS = ROOT / "docs" / "results"

#: The specs whose cells make the tables, in the order they are read.
HEADLINE = ("table1", "table3")
CHECKS = ("sampling", "table3_sampling")
#: Settings that measure rather than train (or place the run): a cell differing only in these is on the defaults.
MEASUREMENT_ONLY = ("trainer.test_every_epoch", "trainer.verify_preset", "trainer.threads", "trainer.progress",
                    "trainer.cache", "trainer.cache_dir", "trainer.logger", "trainer.mlflow_uri", "trainer.eval_batch_size",
                    "output.", "seed")
#: What each table's protocol sets beyond the defaults (the same for every cell of the table).
PROTOCOL = {"table1": {}, "table3": {"trainer.augment_draw": "once"},
            "sampling": {"sensor.sampling": "point"},
            "table3_sampling": {"trainer.augment_draw": "once", "sensor.sampling": "point"}}

T1_COLUMNS = ("encoder", "embedding", "decoder", "settings", "seeds", "test_acc", "test_acc_std", "best_test_acc",
              "paper_acc", "diff_vs_paper", "diff_in_sd")
T3_COLUMNS = ("encoder", "embedding", "decoder", "transform", "settings", "seeds", "test_acc", "test_acc_std",
              "best_test_acc", "paper_acc", "diff_vs_paper", "diff_in_sd")
T2_COLUMNS = ("encoder", "decoder", "drop", "paper_drop", "drop_minus_paper")
T4_COLUMNS = ("encoder", "embedding", "transform", "drop", "paper_drop", "drop_minus_paper")
TS_COLUMNS = ("encoder", "embedding", "decoder", "transform", "seeds", "paper_acc", "box_test_acc", "point_test_acc",
              "point_test_acc_std", "point_minus_box", "point_minus_paper")
WELCH_COLUMNS = ("table", "embedding", "decoder", "transform", "learned_seeds", "learned_acc", "fixed_seeds",
                 "fixed_acc", "difference", "welch_t", "welch_df", "p_two_sided")
EXPLORED_COLUMNS = ("spec", "encoder", "embedding", "decoder", "transform", "settings", "seeds", "test_acc",
                    "test_acc_std", "headline_acc", "minus_headline")
COST_COLUMNS = ("table", "cells", "finished", "cell_hours", "machines")
ENCODERS = ("lens", "coded_aperture", "diffuser", "fixed_slm", "learned_slm")
EMBEDDINGS = ("24x32", "12x16", "6x8", "3x4")
#: Table 1's cells whose example embeddings (``pictures/measurements.png``) are kept for ``embeddings.png``.
EXAMPLE_EMBEDDINGS = ((24, 32), (6, 8))
TRANSFORMS = ("original", "shift", "rescale", "rotate", "perspective")


# ------------------------------------------------------------------ formatting
def _csv(rows, columns) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if r.get(k) is None else r[k] for k in columns})
    return buf.getvalue()


def _fmt(v, key: str = "") -> str:
    if v is None:
        return "-"
    if key == "p_two_sided":  # two significant digits: a p value spans orders of magnitude
        return f"{v:.2g}"
    if key == "welch_df":
        return f"{v:.1f}"
    return f"{v:.2f}" if isinstance(v, float) else str(v)


def _md(rows, columns, title: str = "", note: str = "") -> str:
    lines = [f"# {title}\n"] if title else []
    if note:
        lines += [note, ""]
    lines += ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(r.get(k), k) for k in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _order(r) -> tuple:
    enc = ENCODERS.index(r["encoder"]) if r.get("encoder") in ENCODERS else 99
    emb = EMBEDDINGS.index(r["embedding"]) if r.get("embedding") in EMBEDDINGS else 99
    tr = TRANSFORMS.index(r["transform"]) if r.get("transform") in TRANSFORMS else 99
    return (r.get("decoder") or "", tr, enc, emb)


def _round(x, digits: int = 2):
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else round(float(x), digits)


def _mean_sd(vals: list[float]) -> tuple[float | None, float | None]:
    if not vals:
        return None, None
    m = sum(vals) / len(vals)
    sd = math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1)) if len(vals) > 1 else None
    return m, sd


# ------------------------------------------------------------------ cells
def _measures(key: str) -> bool:
    return any(key == m or (m.endswith(".") and key.startswith(m)) for m in MEASUREMENT_ONLY) or key.startswith("augment.")


def _settings(run, protocol: dict) -> str:
    """``default`` where the cell's configuration is ``optoenc fit``'s for its encoder, decoder, dataset, embedding
    and transforms plus the table's ``protocol``, measurement-only settings aside; else what differs."""
    return _stored_settings(run.to_yaml(), protocol)


@functools.lru_cache(maxsize=None)
def _reference(names: tuple, overrides: tuple, augment: tuple) -> dict:
    """The flattened configuration ``optoenc fit`` composes for these plugins, overrides and transforms."""
    from optoenc.config import compose

    return _flatten(yaml.safe_load(compose(overrides=list(overrides), names=dict(names), augment=list(augment)).to_yaml()))


def _stored_settings(stored_yaml: str, protocol: dict | None = None) -> str:
    """What a stored configuration sets beyond ``optoenc fit``'s defaults for its plugins, embedding, transforms and
    seed (and ``protocol``): ``key=value`` pairs, settings this version no longer has included; ``default`` if none."""
    cfg = yaml.safe_load(stored_yaml)
    flat = _flatten(cfg)
    names = {k: flat[f"{k}.name"] for k in ("encoder", "decoder", "dataset", "task") if flat.get(f"{k}.name")}
    emb = flat.get("sensor.embedding") or [24, 32]
    overrides = [f"sensor.embedding=[{emb[0]},{emb[1]}]", *(f"{k}={v}" for k, v in (protocol or {}).items())]
    try:
        ref = _reference(tuple(sorted(names.items())), tuple(overrides), tuple(cfg.get("augment") or {}))
    except Exception as err:  # a plugin this environment does not have: say so rather than guess
        return f"(not comparable: {type(err).__name__})"
    diffs = []
    for k in sorted(flat):
        if _measures(k) or k.endswith(".name"):
            continue
        if k in ref:
            if flat[k] != ref[k]:
                diffs.append(f"{k}={flat[k]}")
        elif flat[k] not in (None, False, 0, 0.0, "", [], "none"):  # a setting of another version, set
            diffs.append(f"{k}={flat[k]}")
    return ",".join(diffs) or "default"


def _flatten(tree, prefix: str = "") -> dict:
    out = {}
    for k, v in (tree or {}).items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _table(name: str, cells_root: Path):
    """``(planned, rows, aggregated)`` of a spec's committed cells: aggregated over seeds, with ``settings``."""
    spec = sweep.load_spec(HERE / f"{name}.yaml")
    planned = sweep.plan(spec, cells_root / name)
    rows = sweep.cell_rows(spec, planned)
    settings = {p.cell.name: _settings(p.run, PROTOCOL[name]) for p in planned}
    for r in rows:
        r["settings"] = settings[r["cell"]]
    groups: dict[tuple, list] = {}
    for r in rows:
        if r["state"] == "finished":
            groups.setdefault((r["encoder"], r["embedding"], r["decoder"], r["transform"], r["settings"]), []).append(r)
    agg = []
    for (enc, emb, dec, tr, st), rs in groups.items():
        m, sd = _mean_sd([r["test_acc"] for r in rs if r["test_acc"] is not None])
        best, _ = _mean_sd([r["best_test_acc"] for r in rs if r["best_test_acc"] is not None])
        paper = rs[0]["paper_acc"]
        diff = None if m is None or paper is None else m - paper
        agg.append({"encoder": enc, "embedding": emb, "decoder": dec, "transform": tr, "settings": st,
                    "seeds": len(rs), "test_acc": _round(m), "test_acc_std": _round(sd), "best_test_acc": _round(best),
                    "paper_acc": paper, "diff_vs_paper": _round(diff),
                    "diff_in_sd": _round(diff / sd, 1) if diff is not None and sd else None,
                    "accs": [r["test_acc"] for r in rs], "wall": sum(r["wall_time_s"] or 0 for r in rs)})
    return spec, planned, rows, sorted(agg, key=_order)


def _drop(top, low):
    """Relative drop in percent, ``100 (top - low) / top``; None when either is missing."""
    return None if top is None or low is None or not top else round(100 * (top - low) / top, 2)


def _diff(a, b):
    return None if a is None or b is None else round(a - b, 2)


def _table2(agg1) -> list[dict]:
    by = {(r["encoder"], r["embedding"], r["decoder"]): r for r in agg1}
    out = []
    for (enc, emb, dec), top in by.items():
        low = by.get((enc, "3x4", dec))
        if emb != "24x32" or low is None:
            continue
        drop, paper = _drop(top["test_acc"], low["test_acc"]), _drop(top["paper_acc"], low["paper_acc"])
        out.append({"encoder": enc, "decoder": dec, "drop": drop, "paper_drop": paper, "drop_minus_paper": _diff(drop, paper)})
    return sorted(out, key=lambda r: (r["decoder"], _order({**r, "embedding": ""})))


def _table4(agg1, agg3) -> list[dict]:
    orig = {(r["encoder"], r["embedding"]): r for r in agg1 if r["decoder"] == "fcnn"}
    out = []
    for r in agg3:
        o = orig.get((r["encoder"], r["embedding"]))
        if o is None:
            continue
        drop, paper = _drop(o["test_acc"], r["test_acc"]), _drop(o["paper_acc"], r["paper_acc"])
        out.append({"encoder": r["encoder"], "embedding": r["embedding"], "transform": r["transform"], "drop": drop,
                    "paper_drop": paper, "drop_minus_paper": _diff(drop, paper)})
    return sorted(out, key=_order)


def _table3_wide(agg1, agg3) -> str:
    """Table 3 in the paper's layout: ``ours ± sd (paper)`` per transform; the original column is Table 1's FCNN."""
    orig = {(r["encoder"], r["embedding"]): r for r in agg1 if r["decoder"] == "fcnn"}
    cells = {(r["encoder"], r["embedding"], r["transform"]): r for r in agg3}
    keys = sorted({(e, m) for e, m, _t in cells}, key=lambda k: _order({"encoder": k[0], "embedding": k[1]}))

    def fmt(r):
        if r is None or r.get("test_acc") is None:
            return "-"
        sd = f" ± {r['test_acc_std']:.2f}" if r.get("test_acc_std") is not None else ""
        paper = f" ({r['paper_acc']:.1f})" if r.get("paper_acc") is not None else ""
        return f"{r['test_acc']:.2f}{sd}{paper}"
    lines = ["| encoder | embedding | original | " + " | ".join(TRANSFORMS[1:]) + " |", "|" + "---|" * 7]
    for enc, emb in keys:
        row = [fmt(orig.get((enc, emb)))] + [fmt(cells.get((enc, emb, t))) for t in TRANSFORMS[1:]]
        lines.append(f"| {enc} | {emb} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def _point(base, agg_point) -> list[dict]:
    """Each point-sampling cell beside the same cell with physical pixels (the headline) and the paper."""
    box = {(r["encoder"], r["embedding"], r["decoder"], r["transform"]): r for r in base}
    out = []
    for r in agg_point:
        b = box.get((r["encoder"], r["embedding"], r["decoder"], r["transform"]), {})
        out.append({**{k: r[k] for k in ("encoder", "embedding", "decoder", "transform", "seeds", "paper_acc")},
                    "box_test_acc": b.get("test_acc"), "point_test_acc": r["test_acc"],
                    "point_test_acc_std": r["test_acc_std"], "point_minus_box": _diff(r["test_acc"], b.get("test_acc")),
                    "point_minus_paper": _diff(r["test_acc"], r["paper_acc"])})
    return sorted(out, key=_order)


def welch(a: list[float], b: list[float]) -> tuple[float, float, float] | None:
    """Welch's t statistic of ``mean(a) - mean(b)``, its degrees of freedom (Welch-Satterthwaite) and the two-sided
    p value; None with fewer than two values on a side or no spread."""
    from scipy import stats

    if len(a) < 2 or len(b) < 2:
        return None
    va, vb = _mean_sd(a)[1] ** 2 / len(a), _mean_sd(b)[1] ** 2 / len(b)
    if va + vb == 0:
        return None
    t = (sum(a) / len(a) - sum(b) / len(b)) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return t, df, float(2 * stats.t.sf(abs(t), df))


def _learned_vs_fixed(name: str, agg) -> list[dict]:
    """The learned SLM against the fixed SLM per cell, Welch's t over their distinct seeds."""
    by = {(r["encoder"], r["embedding"], r["decoder"], r["transform"]): r for r in agg}
    out = []
    for (enc, emb, dec, tr), lr in by.items():
        fx = by.get(("fixed_slm", emb, dec, tr))
        if enc != "learned_slm" or fx is None:
            continue
        w = welch(lr["accs"], fx["accs"])
        out.append({"table": name, "embedding": emb, "decoder": dec, "transform": tr, "learned_seeds": lr["seeds"],
                    "learned_acc": lr["test_acc"], "fixed_seeds": fx["seeds"], "fixed_acc": fx["test_acc"],
                    "difference": _diff(lr["test_acc"], fx["test_acc"]),
                    "welch_t": _round(w[0]) if w else None, "welch_df": _round(w[1], 1) if w else None,
                    "p_two_sided": float(f"{w[2]:.2g}") if w else None})
    return sorted(out, key=_order)


def _explored(explored_root: Path, headline: dict) -> list[dict]:
    """Every explored cell as stored (its config.yaml and summary.json), seeds aggregated per spec and settings,
    beside the headline cell of the same encoder, embedding, decoder and transform."""
    import json

    groups: dict[tuple, list] = {}
    for summary in sorted(explored_root.glob("*/*/summary.json")):
        cell = summary.parent
        s = json.loads(summary.read_text())
        if s.get("test_acc") is None:
            continue
        cfg = _flatten(yaml.safe_load((cell / "config.yaml").read_text()))
        names = {k: cfg.get(f"{k}.name") for k in ("encoder", "decoder")}
        emb = "x".join(str(v) for v in cfg.get("sensor.embedding", []))
        transform = "+".join((yaml.safe_load((cell / "config.yaml").read_text()).get("augment") or {}).keys()) or "original"
        settings = _stored_settings((cell / "config.yaml").read_text())
        key = (cell.parent.name, names.get("encoder"), emb, names.get("decoder"), transform, settings)
        groups.setdefault(key, []).append(100 * float(s["test_acc"]))
    out = []
    for (spec, enc, emb, dec, tr, st), accs in groups.items():
        m, sd = _mean_sd(accs)
        h = headline.get((enc, emb, dec, tr))
        out.append({"spec": spec, "encoder": enc, "embedding": emb, "decoder": dec, "transform": tr, "settings": st,
                    "seeds": len(accs), "test_acc": _round(m), "test_acc_std": _round(sd),
                    "headline_acc": h["test_acc"] if h else None, "minus_headline": _diff(_round(m), h["test_acc"] if h else None)})
    return sorted(out, key=lambda r: (r["spec"], *_order(r)))


def _cost(name: str, planned, rows) -> dict:
    """Machine time of a table's finished cells (their summed wall time) and the machines they ran on."""
    import json

    hours = sum(r["wall_time_s"] or 0 for r in rows if r["state"] == "finished") / 3600
    machines = {}
    for p in planned:
        if p.state == "finished":
            hw = json.loads((p.path / "summary.json").read_text()).get("hardware") or {}
            n = hw.get("threads", "?")
            key = f"{hw.get('name', '?')} ({n} thread{'' if n == 1 else 's'})"
            machines[key] = machines.get(key, 0) + 1
    return {"table": name, "cells": len(rows), "finished": sum(r["state"] == "finished" for r in rows),
            "cell_hours": round(hours, 2), "machines": "; ".join(f"{k}: {v}" for k, v in sorted(machines.items()))}


# ------------------------------------------------------------------ figures (redrawn, not compared)
def _figures(out: Path, planned1, agg1, planned3) -> None:
    from optoenc.sweep import plots

    plots.accuracy_vs_embedding(agg1, out / "table1_accuracy.png")
    plots.learning_curves(planned1, out / "table1_curves.png")
    plots.learning_curves(planned3, out / "table3_curves.png")
    _pictures(planned1, "psf_final.png", out / "learned_psfs.png", "learned PSFs (Table 1, seed 0)")
    _pictures(planned1, "mask_final.png", out / "learned_masks.png", "learned masks (Table 1, seed 0)")
    _pictures(planned1, "measurements.png", out / "embeddings.png",
              "example embeddings (Table 1, FCNN, seed 0; top row the scene, bottom row the sensor)", learned=False,
              cols=2, panel=(7.2, 2.2))


def _shows_embeddings(run) -> bool:
    """The cells whose example embeddings are kept: seed 0, FCNN, at 24x32 and 6x8 (one per encoder and size)."""
    return (run.seed == 0 and run.names["decoder"] == "fcnn"
            and tuple(run.sensor.embedding) in EXAMPLE_EMBEDDINGS)


def _pictures(planned, name: str, out: Path, title: str, learned: bool = True, cols: int = 4,
              panel: tuple[float, float] = (4.2, 3.4)) -> Path | None:
    """A montage of one picture per cell (seed 0; of the learned encoders only with ``learned``)."""
    from optoenc.training.pictures import new_figure, save_figure

    pics = [(p.cell.name, p.path / "pictures" / name) for p in planned
            if (p.run.names["encoder"].startswith("learned") or not learned) and p.run.seed == 0
            and (p.path / "pictures" / name).is_file()]
    if not pics:
        return None
    import matplotlib.image as mpimg

    cols = min(cols, len(pics))
    rows = (len(pics) + cols - 1) // cols
    plt, fig = new_figure((panel[0] * cols, panel[1] * rows))
    for i, (cell, path) in enumerate(pics):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(mpimg.imread(path))
        ax.set_title(cell.replace("encoder=", "").replace(",", " ")[:64], fontsize=7)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return save_figure(plt, fig, out)


# ------------------------------------------------------------------ import, write, check
def import_cells(name: str, sweep_dir: Path, cells_root: Path) -> int:
    """Copy a sweep's finished cells of spec ``name`` (small files and the learned pictures; never checkpoints)."""
    spec = sweep.load_spec(HERE / f"{name}.yaml")
    n = 0
    for p in sweep.plan(spec, sweep_dir):
        if p.state != "finished":
            continue
        dest = cells_root / name / "cells" / p.cell.name
        dest.mkdir(parents=True, exist_ok=True)
        for f in ("config.yaml", "summary.json", "metrics.csv"):
            shutil.copyfile(p.path / f, dest / f)
        pictures = ["psf_final.png", "mask_final.png"] if p.run.names["encoder"].startswith("learned") else []
        if name == "table1" and _shows_embeddings(p.run):
            pictures.append("measurements.png")
        for f in pictures:
            if (p.path / "pictures" / f).is_file():
                (dest / "pictures").mkdir(exist_ok=True)
                shutil.copyfile(p.path / "pictures" / f, dest / "pictures" / f)
        n += 1
    return n


def write(out: Path, cells_root: Path, explored_root: Path, figures: bool = True) -> list[Path]:
    """Every table (and, with ``figures``, the figures) into ``out``; returns the text tables written."""
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, str] = {}
    _, planned1, rows1, agg1 = _table("table1", cells_root)
    _, planned3, rows3, agg3 = _table("table3", cells_root)
    files["table1.csv"] = _csv(agg1, T1_COLUMNS)
    files["table1.md"] = _md(agg1, T1_COLUMNS)
    files["table3.csv"] = _csv(agg3, T3_COLUMNS)
    files["table3.md"] = _md(agg3, T3_COLUMNS)
    files["table3_wide.md"] = _table3_wide(agg1, agg3)
    t2, t4 = _table2(agg1), _table4(agg1, agg3)
    files["table2.csv"], files["table2.md"] = _csv(t2, T2_COLUMNS), _md(t2, T2_COLUMNS)
    files["table4.csv"], files["table4.md"] = _csv(t4, T4_COLUMNS), _md(t4, T4_COLUMNS)
    welch_rows = _learned_vs_fixed("table1", agg1) + _learned_vs_fixed("table3", agg3)
    files["learned_vs_fixed.csv"] = _csv(welch_rows, WELCH_COLUMNS)
    files["learned_vs_fixed.md"] = _md(welch_rows, WELCH_COLUMNS)
    costs = [_cost("table1", planned1, rows1), _cost("table3", planned3, rows3)]
    for name, base in (("sampling", agg1), ("table3_sampling", agg3)):
        _, planned, rows, agg = _table(name, cells_root)
        ts = _point(base, agg)
        files[f"{name}.csv"], files[f"{name}.md"] = _csv(ts, TS_COLUMNS), _md(ts, TS_COLUMNS)
        costs.append(_cost(name, planned, rows))
        if name == "sampling":  # Table 2 like for like: the drops with the paper's point samples
            t2p = _table2(agg)
            files["table2_point.csv"], files["table2_point.md"] = _csv(t2p, T2_COLUMNS), _md(t2p, T2_COLUMNS)
    headline = {(r["encoder"], r["embedding"], r["decoder"], r["transform"]): r for r in agg1 + agg3}
    explored = _explored(explored_root, headline)
    files["explored.csv"], files["explored.md"] = _csv(explored, EXPLORED_COLUMNS), _md(explored, EXPLORED_COLUMNS)
    files["cost.csv"], files["cost.md"] = _csv(costs, COST_COLUMNS), _md(costs, COST_COLUMNS)
    written = [atomic_write_text(out / name, text) for name, text in files.items()]
    if figures:
        _figures(out, planned1, agg1, planned3)
    return written


def first_difference(mine: Path, regenerated: str, writer: str = "make_results.py") -> str | None:
    """Where the committed file ``mine`` first differs from the ``regenerated`` text: ``FILE:LINE: committed ...,
    regenerated ...``; None where they agree."""
    if not mine.is_file():
        return f"{mine}: missing ({writer} writes it)"
    a, b = mine.read_text().splitlines(), regenerated.splitlines()
    for i, (x, y) in enumerate(zip(a, b), start=1):
        if x != y:
            return f"{mine}:{i}: committed {x!r}, regenerated {y!r}"
    if len(a) != len(b):
        return f"{mine}: {len(a)} lines committed, {len(b)} regenerated"
    return None


def check(committed: Path, cells_root: Path, explored_root: Path) -> str | None:
    """The first difference between the committed tables and what :func:`write` writes; None where they agree."""
    with tempfile.TemporaryDirectory() as tmp:
        for path in write(Path(tmp), cells_root, explored_root, figures=False):
            diff = first_difference(committed / path.name, path.read_text())
            if diff:
                return diff
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=RESULTS, help="docs/results (default)")
    ap.add_argument("--import", dest="imports", action="append", default=[], metavar="SPEC=SWEEP_DIR",
                    help="first copy SWEEP_DIR's finished cells of examples/paper/SPEC.yaml into OUT/cells/SPEC "
                         f"(SPEC one of {', '.join(HEADLINE + CHECKS)}; repeatable)")
    ap.add_argument("--check", action="store_true", help="compare the committed tables with what would be written; "
                    "exit 1 naming the first difference")
    args = ap.parse_args(argv)
    cells_root, explored_root = args.out / "cells", args.out / "explored"
    if args.check:
        diff = check(args.out, cells_root, explored_root)
        if diff:
            print(f"make_results --check: {diff}", file=sys.stderr)
            return 1
        return 0
    for item in args.imports:
        name, _, folder = item.partition("=")
        if name not in HEADLINE + CHECKS or not folder:
            ap.error(f"--import {item!r}: expected SPEC=SWEEP_DIR with SPEC one of {', '.join(HEADLINE + CHECKS)}")
        print(f"{name}: {import_cells(name, Path(folder), cells_root)} finished cells imported")
    written = write(args.out, cells_root, explored_root)
    print(f"{len(written)} tables written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
