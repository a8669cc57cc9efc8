"""Write docs/results/ from the paper sweeps: tables (CSV, markdown), curves, learned PSFs, example embeddings.

    python examples/paper/make_results.py --table1 sweeps/table1 --table3 sweeps/table3 \
        --sampling sweeps/sampling --table3-sampling sweeps/table3_sampling --table3-paper sweeps/table3_paper \
        --precision sweeps/precision --out docs/results

Table 2 (relative drop from 24x32 to 3x4) is derived from Table 1, Table 4 (relative drop under each
transform) from Tables 1 and 3; the paper's own drops are computed the same way from its Tables 1 and 3.
``--sampling`` adds the sensor-model check (examples/paper/sampling.yaml) beside Table 1's cells;
``--precision`` the bfloat16 check (examples/paper/precision.yaml) beside the cells' float32 or bfloat16
twins in Tables 1 and 3 (precision.csv / precision.md); ``--table3-paper`` the paper's own transforms
(examples/paper/table3_paper.yaml: perspective about the whole field, shift with point samples).

Each sweep is run first with ``optoenc sweep examples/paper/table1.yaml`` (and table3.yaml); missing
or unfinished cells are left out of the tables (their count is printed), so this can be re-run as
more cells finish.
"""

from __future__ import annotations

import argparse
import csv
import io
import shutil
from pathlib import Path

import torch

from optoenc import sweep
from optoenc.training.rundir import atomic_write_text

T1_COLUMNS = ("encoder", "embedding", "decoder", "precision", "seeds", "test_acc", "test_acc_std", "best_test_acc",
              "reference_test_acc", "paper_acc", "diff_vs_paper")
T3_COLUMNS = ("encoder", "embedding", "decoder", "transform", "augment_mode", "precision", "seeds", "test_acc", "test_acc_std",
              "best_test_acc", "paper_acc", "diff_vs_paper")
T2_COLUMNS = ("encoder", "decoder", "drop", "paper_drop")
T4_COLUMNS = ("encoder", "embedding", "transform", "augment_mode", "drop", "paper_drop")
TS_COLUMNS = ("encoder", "embedding", "decoder", "paper_acc", "box_test_acc", "point_test_acc", "point_best_test_acc",
              "point_minus_box")
ENCODERS = ("lens", "coded_aperture", "diffuser", "fixed_slm", "learned_slm", "learned_phase_mask")
EMBEDDINGS = ("24x32", "12x16", "6x8", "3x4")
DEFAULT_PRECISION = "float32/32-true"


def _csv(rows, columns) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if r.get(k) is None else r[k] for k in columns})
    return buf.getvalue()


def _order(r):
    enc = ENCODERS.index(r["encoder"]) if r["encoder"] in ENCODERS else 99
    emb = EMBEDDINGS.index(r["embedding"]) if r["embedding"] in EMBEDDINGS else 99
    return (r.get("decoder", ""), enc, emb, r.get("transform", ""), r.get("augment_mode", ""))


def _fmt(v, sd=None):
    if v is None:
        return "-"
    return f"{v:.2f}" + (f" ± {sd:.2f}" if sd is not None else "")


def _md(rows, keys) -> str:
    head = [*keys, "paper", "ours (val-selected)", "ours (best test, paper's way)", "difference", "seeds"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join([*(str(r[k]) for k in keys), _fmt(r["paper_acc"]),
                                         _fmt(r["test_acc"], r["test_acc_std"]), _fmt(r["best_test_acc"]),
                                         _fmt(r["diff_vs_paper"]), str(r["seeds"])]) + " |")
    return "\n".join(lines) + "\n"


def _drop(top, low):
    """Relative drop in percent, ``100 (top - low) / top``; None when either is missing."""
    return None if top is None or low is None or not top else round(100 * (top - low) / top, 2)


def _table2(agg) -> list[dict]:
    """Relative drop from 24x32 to 3x4 per encoder and decoder (the paper's Table 2), ours and the paper's."""
    by = {(r["encoder"], r["embedding"], r["decoder"]): r for r in agg}
    out = []
    for (enc, emb, dec), top in by.items():
        low = by.get((enc, "3x4", dec))
        if emb != "24x32" or low is None:
            continue
        out.append({"encoder": enc, "decoder": dec, "drop": _drop(top["test_acc"], low["test_acc"]),
                    "paper_drop": _drop(top["paper_acc"], low["paper_acc"])})
    return sorted(out, key=lambda r: (r["decoder"], _order({**r, "embedding": ""})))


def _table4(agg1, agg3) -> list[dict]:
    """Relative drop under each transform (the paper's Table 4): Table 3's cells against Table 1's FCNN cell."""
    orig = {(r["encoder"], r["embedding"]): r for r in agg1 if r["decoder"] == "fcnn"}
    out = []
    for r in agg3:
        o = orig.get((r["encoder"], r["embedding"]))
        if o is None:
            continue
        out.append({"encoder": r["encoder"], "embedding": r["embedding"], "transform": r.get("transform"),
                    "augment_mode": r.get("augment_mode"), "drop": _drop(o["test_acc"], r["test_acc"]),
                    "paper_drop": _drop(o["paper_acc"], r["paper_acc"])})
    return out


TRANSFORMS = ("shift", "rescale", "rotate", "perspective")


def _table3_wide(agg1, agg3) -> str:
    """Table 3 in the paper's layout: a row per encoder and size, "ours (paper)" per transform, the original
    column from Table 1's FCNN cell; the learned SLM's per-epoch redraws in rows of their own."""
    orig = {(r["encoder"], r["embedding"]): r for r in agg1 if r["decoder"] == "fcnn"}
    cells = {(r["encoder"], r["embedding"], r.get("augment_mode"), r.get("transform")): r for r in agg3}
    keys = sorted({(e, m, mode) for e, m, mode, _t in cells}, key=lambda k: (_order({"encoder": k[0], "embedding": k[1]}),
                                                                            k[2] != "once"))
    def fmt(r):
        if r is None or r.get("test_acc") is None:
            return "-"
        sd = f" ± {r['test_acc_std']:.2f}" if r.get("test_acc_std") is not None else ""
        paper = f" ({r['paper_acc']:.1f})" if r.get("paper_acc") is not None else ""
        fast = "" if r.get("precision", DEFAULT_PRECISION) == DEFAULT_PRECISION else " †"
        return f"{r['test_acc']:.2f}{sd}{fast}{paper}"
    lines = ["| encoder | embedding | draws | original | " + " | ".join(TRANSFORMS) + " |", "|" + "---|" * 8]
    for enc, emb, mode in keys:
        row = [fmt(orig.get((enc, emb)))] + [fmt(cells.get((enc, emb, mode, t))) for t in TRANSFORMS]
        lines.append(f"| {enc} | {emb} | {mode} | " + " | ".join(row) + " |")
    fast = sorted({r["precision"] for r in agg3 if r.get("precision", DEFAULT_PRECISION) != DEFAULT_PRECISION})
    if fast:
        lines.append(f"\n† trained with bfloat16 products ({', '.join(fast)}: operator dtype / trainer precision; "
                     f"the rest {DEFAULT_PRECISION}), see docs/results.md.")
    return "\n".join(lines) + "\n"


def _sampling(agg1, agg_point) -> list[dict]:
    """The sensor-model check: each cell with physical pixels (Table 1) beside the same cell with point samples."""
    box = {(r["encoder"], r["embedding"], r["decoder"]): r for r in agg1}
    out = []
    for r in agg_point:
        b = box.get((r["encoder"], r["embedding"], r["decoder"]), {})
        out.append({"encoder": r["encoder"], "embedding": r["embedding"], "decoder": r["decoder"],
                    "paper_acc": r["paper_acc"],
                    "box_test_acc": b.get("test_acc"), "point_test_acc": r["test_acc"],
                    "point_best_test_acc": r["best_test_acc"],
                    "point_minus_box": None if b.get("test_acc") is None or r["test_acc"] is None
                    else round(r["test_acc"] - b["test_acc"], 2)})
    return sorted(out, key=_order)


T3S_COLUMNS = ("encoder", "embedding", "transform", "paper_acc", "box_test_acc", "point_test_acc",
               "point_best_test_acc", "point_minus_box")


def _table3_sampling(agg3, agg_point) -> list[dict]:
    """Table 3's sensor-model check: each cell with physical pixels (table3) beside point samples."""
    box = {(r["encoder"], r["embedding"], r["transform"]): r for r in agg3 if r.get("augment_mode") == "once"}
    out = []
    for r in agg_point:
        b = box.get((r["encoder"], r["embedding"], r["transform"]), {})
        out.append({"encoder": r["encoder"], "embedding": r["embedding"], "transform": r["transform"],
                    "paper_acc": r["paper_acc"], "box_test_acc": b.get("test_acc"), "point_test_acc": r["test_acc"],
                    "point_best_test_acc": r["best_test_acc"],
                    "point_minus_box": None if b.get("test_acc") is None or r["test_acc"] is None
                    else round(r["test_acc"] - b["test_acc"], 2)})
    return sorted(out, key=_order)


TP_COLUMNS = ("encoder", "embedding", "decoder", "transform", "precision", "seeds", "test_acc", "test_acc_std",
              "twin_precision", "twin_seeds", "twin_test_acc", "twin_test_acc_std", "difference")


def _precision(base, agg_check) -> list[dict]:
    """The bfloat16 check: each cell of examples/paper/precision.yaml beside its twin of another precision in
    Table 1 or Table 3 (same encoder, embedding, decoder, transform and draw mode)."""
    keys = ("encoder", "embedding", "decoder", "transform", "augment_mode")
    out = []
    for r in agg_check:
        twin = next((b for b in base if all(b.get(k) == r.get(k) for k in keys)
                     and b.get("precision") != r.get("precision")), {})
        out.append({**{k: r[k] for k in ("encoder", "embedding", "decoder", "transform", "precision", "seeds",
                                         "test_acc", "test_acc_std")},
                    "twin_precision": twin.get("precision"), "twin_seeds": twin.get("seeds"),
                    "twin_test_acc": twin.get("test_acc"), "twin_test_acc_std": twin.get("test_acc_std"),
                    "difference": None if twin.get("test_acc") is None or r["test_acc"] is None
                    else round(r["test_acc"] - twin["test_acc"], 2)})
    return sorted(out, key=_order)


TPAPER_COLUMNS = ("encoder", "embedding", "transform", "variant", "paper_acc", "table3_test_acc", "check_test_acc",
                  "check_best_test_acc", "check_minus_table3")


def _table3_paper(agg3, agg_check) -> list[dict]:
    """The paper's own transforms (examples/paper/table3_paper.yaml) beside Table 3's cell and the paper."""
    ours = {(r["encoder"], r["embedding"], r["transform"]): r for r in agg3
            if r.get("augment_mode") == "once" and r.get("precision", DEFAULT_PRECISION) == DEFAULT_PRECISION}
    out = []
    for r in agg_check:
        t = ours.get((r["encoder"], r["embedding"], r["transform"]), {})
        out.append({"encoder": r["encoder"], "embedding": r["embedding"], "transform": r["transform"],
                    "variant": r.get("variant"), "paper_acc": r["paper_acc"], "table3_test_acc": t.get("test_acc"),
                    "check_test_acc": r["test_acc"], "check_best_test_acc": r["best_test_acc"],
                    "check_minus_table3": None if t.get("test_acc") is None or r["test_acc"] is None
                    else round(r["test_acc"] - t["test_acc"], 2)})
    return sorted(out, key=_order)


def _plain_md(rows, columns) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r[k]) if isinstance(r.get(k), float) or r.get(k) is None
                                       else str(r[k]) for k in columns) + " |")
    return "\n".join(lines) + "\n"


def _collect(spec_path: Path, sweep_dir: Path):
    spec = sweep.load_spec(spec_path)
    planned = sweep.plan(spec, sweep_dir)
    sweep.write_tables(spec, planned, sweep_dir)
    rows = sweep.cell_rows(spec, planned)
    return spec, planned, rows, sorted(sweep.aggregate(rows), key=_order)


def _copy_cells(planned, out: Path) -> None:
    """Each finished cell's small files (summary, metrics, config), never checkpoints."""
    for p in planned:
        if (p.path / "summary.json").is_file():
            dest = out / p.cell.name
            dest.mkdir(parents=True, exist_ok=True)
            for name in ("summary.json", "metrics.csv", "config.yaml"):
                if (p.path / name).is_file():
                    shutil.copyfile(p.path / name, dest / name)


def _learned_psfs(planned, out: Path) -> Path | None:
    from optoenc.training.pictures import new_figure, save_figure

    pics = [(p.cell.name, p.path / "pictures" / "psf_final.png") for p in planned
            if p.run.names["encoder"].startswith("learned") and (p.path / "pictures" / "psf_final.png").is_file()]
    if not pics:
        return None
    import matplotlib.image as mpimg

    cols = min(4, len(pics))
    rows = (len(pics) + cols - 1) // cols
    plt, fig = new_figure((4.2 * cols, 3.4 * rows))
    for i, (name, path) in enumerate(pics):
        ax = fig.add_subplot(rows, cols, i + 1)
        ax.imshow(mpimg.imread(path))
        ax.set_title(name.replace("encoder=", "").replace(",", " ")[:48], fontsize=7)
        ax.axis("off")
    fig.tight_layout()
    return save_figure(plt, fig, out)


def _embeddings(planned, out: Path, n: int = 4) -> Path | None:
    """The same test digits through every encoder at every size (learned ones: their trained checkpoint)."""
    from optoenc.config import encoder_from_run, compose
    from optoenc.training.pictures import new_figure, save_figure
    from optoenc.plugins import get_registry
    from optoenc.training import checkpoint_path, load_encoder

    digits = get_registry("dataset").get("mnist")(None).load().test[0][:n]
    trained = {(p.run.names["encoder"], "x".join(map(str, p.run.sensor.embedding))): p for p in planned
               if p.run.names["decoder"] == "fcnn" and p.run.seed == 0 and not p.run.augment
               and checkpoint_path(p.path, "best").is_file()}
    rows = []
    for enc in ENCODERS:
        for emb in EMBEDDINGS:
            a, b = (int(v) for v in emb.split("x"))
            if enc.startswith("learned"):
                p = trained.get((enc, emb))
                if p is None:
                    continue
                encoder = load_encoder(p.run, p.path)
            else:
                encoder = encoder_from_run(compose(overrides=[f"sensor.embedding=[{a},{b}]"], names={"encoder": enc}))
            with torch.no_grad():
                rows.append((f"{enc}\n{emb}", encoder.eval().measure(digits)))
    if not rows:
        return None
    plt, fig = new_figure((1.6 * (n + 1), 1.25 * len(rows)))
    for i in range(n):
        ax = fig.add_subplot(len(rows) + 1, n + 1, i + 2)
        ax.imshow(digits[i, 0], cmap="gray")
        ax.axis("off")
        ax.set_title("scene" if i == 0 else "", fontsize=7)
    for r, (label, emb) in enumerate(rows, start=1):
        ax = fig.add_subplot(len(rows) + 1, n + 1, r * (n + 1) + 1)
        ax.text(0.5, 0.5, label, ha="center", va="center", fontsize=6)
        ax.axis("off")
        for i in range(n):
            ax = fig.add_subplot(len(rows) + 1, n + 1, r * (n + 1) + i + 2)
            ax.imshow(emb[i, 0], cmap="gray")
            ax.axis("off")
    fig.suptitle("sensor embeddings of the same test digits (noise-free, each image scaled to its own range)",
                 fontsize=8)
    return save_figure(plt, fig, out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).parent
    ap.add_argument("--table1", type=Path, default=Path("sweeps/table1"))
    ap.add_argument("--table3", type=Path, default=Path("sweeps/table3"))
    ap.add_argument("--sampling", type=Path, default=Path("sweeps/sampling"))
    ap.add_argument("--table3-sampling", type=Path, default=Path("sweeps/table3_sampling"))
    ap.add_argument("--table3-paper", type=Path, default=Path("sweeps/table3_paper"))
    ap.add_argument("--precision", type=Path, default=Path("sweeps/precision"))
    ap.add_argument("--out", type=Path, default=Path("docs/results"))
    ap.add_argument("--no-embeddings", action="store_true", help="skip the example-embedding figure")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    agg1 = []
    if (args.table1 / "cells").is_dir():
        _, planned, rows, agg = _collect(here / "table1.yaml", args.table1)
        agg1 = agg
        t2 = _table2(agg)
        atomic_write_text(args.out / "table2.csv", _csv(t2, T2_COLUMNS))
        atomic_write_text(args.out / "table2.md", _plain_md(t2, T2_COLUMNS))
        atomic_write_text(args.out / "table1.csv", _csv(agg, T1_COLUMNS))
        atomic_write_text(args.out / "table1.md", _md(agg, ("encoder", "embedding", "decoder")))
        for name in ("accuracy.png", "curves.png"):
            if (args.table1 / name).is_file():
                shutil.copyfile(args.table1 / name, args.out / f"table1_{name}")
        _copy_cells(planned, args.out / "sweep_cells" / "table1")
        _learned_psfs(planned, args.out / "learned_psfs.png")
        if not args.no_embeddings:
            _embeddings(planned, args.out / "embeddings.png")
        done = sum(r["state"] == "finished" for r in rows)
        times = [r["wall_time_s"] for r in rows if r["wall_time_s"]]
        print(f"table1: {done} of {len(rows)} cells finished, {sum(times) / 3600:.2f} h of cell wall time")
    agg3 = []
    if (args.table3 / "cells").is_dir():
        _, planned, rows, agg = _collect(here / "table3.yaml", args.table3)
        agg3 = agg
        atomic_write_text(args.out / "table3.csv", _csv(agg, T3_COLUMNS))
        atomic_write_text(args.out / "table3.md", _md(agg, ("encoder", "embedding", "transform", "augment_mode", "precision")))
        atomic_write_text(args.out / "table3_wide.md", _table3_wide(agg1, agg))
        t4 = _table4(agg1, agg)
        atomic_write_text(args.out / "table4.csv", _csv(t4, T4_COLUMNS))
        atomic_write_text(args.out / "table4.md", _plain_md(t4, T4_COLUMNS))
        _copy_cells(planned, args.out / "sweep_cells" / "table3")
        _learned_psfs(planned, args.out / "table3_learned_psfs.png")
        if (args.table3 / "curves.png").is_file():
            shutil.copyfile(args.table3 / "curves.png", args.out / "table3_curves.png")
        done = sum(r["state"] == "finished" for r in rows)
        times = [r["wall_time_s"] for r in rows if r["wall_time_s"]]
        print(f"table3: {done} of {len(rows)} cells finished, {sum(times) / 3600:.2f} h of cell wall time")
    for name, sweep_dir, pair, base, columns in (
        ("sampling", args.sampling, _sampling, agg1, TS_COLUMNS),
        ("table3_sampling", args.table3_sampling, _table3_sampling, agg3, T3S_COLUMNS),
        ("table3_paper", args.table3_paper, _table3_paper, agg3, TPAPER_COLUMNS),
        ("precision", args.precision, _precision, agg1 + agg3, TP_COLUMNS),
    ):
        if (sweep_dir / "cells").is_dir():  # a check: its cells beside the base table's (point samples, precision)
            _, planned, rows, agg = _collect(here / f"{name}.yaml", sweep_dir)
            ts = pair(base, agg)
            atomic_write_text(args.out / f"{name}.csv", _csv(ts, columns))
            atomic_write_text(args.out / f"{name}.md", _plain_md(ts, columns))
            _copy_cells(planned, args.out / "sweep_cells" / name)
            print(f"{name}: {sum(r['state'] == 'finished' for r in rows)} of {len(rows)} cells finished")

if __name__ == "__main__":
    main()
