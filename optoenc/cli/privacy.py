"""``optoenc reconstruct`` and ``optoenc privacy``: reconstruction from sensor embeddings and privacy measurement.

The library parts are :mod:`optoenc.privacy` (operators, solvers, attacks,
metrics, tables); this module parses the options, prints and writes files.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

from ..errors import ConfigError, DataError
from ..privacy.settings import ATTACKS, INPUTS, METHODS, SCHEDULES, ADMMConfig, LearnedConfig, PrivacyConfig, TikhonovConfig
from ..settings import parse_hw
from ..training.rundir import atomic_torch_save, atomic_write_bytes, write_json
from .args import command, compose, names, split_overrides

__all__ = ["add_parsers"]


def _source_options(p: argparse.ArgumentParser) -> None:
    """Where the encoder comes from, and the solvers' settings (shared by both commands)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--run", action="append", metavar="RUN_DIR", help="run directory of `optoenc fit` (trained or fixed encoder)")
    g.add_argument("--encoder", help="an encoder by name, with --section.key=value settings (e.g. --sensor.embedding=[6,8])")
    p.add_argument("--config", action="append", default=[], metavar="YAML", help="with --encoder: run config file")
    p.add_argument("--which", default="best", choices=("best", "last"), help="checkpoint of --run")
    p.add_argument("--iterations", type=int, help=f"ADMM iterations (default {ADMMConfig().iterations})")
    p.add_argument("--tau", type=float, help=f"ADMM TV weight, unit-norm operator (default {ADMMConfig().tau:g})")
    p.add_argument("--mu-tv", type=float, help=f"ADMM penalty of u = Psi x (default {ADMMConfig().mu_tv:g})")
    p.add_argument("--mu-nonneg", type=float, help=f"ADMM penalty of w = x (default {ADMMConfig().mu_nonneg:g})")
    p.add_argument("--rcond", type=float, help=f"pseudo-inverse cut-off (default {TikhonovConfig().rcond:g})")


def add_parsers(sub) -> None:
    """Add ``privacy`` and ``reconstruct`` to the CLI's subparsers."""
    p = sub.add_parser(
        "privacy", help="attack an encoder's embeddings and measure what leaks",
        description="Attack an encoder's noisy sensor embeddings of test digits and measure what leaks: each "
        "attacker's reconstructions (PSNR, SSIM), whether a digit classifier can read them (readability) and "
        "whether they pick the true scene out of a gallery of its class (re-identification top-1). The encoder "
        "comes from one run directory (--run), every run directory of a folder (--sweep: one table and the "
        "privacy-utility plots) or a name (--encoder). Attacks that need a camera showing several patterns "
        "(admm_search, learned_one) are noted and skipped on a single-pattern camera.")
    _source_options(p)
    p.add_argument("--sweep", metavar="DIR", help="a folder of run directories: one table and the privacy-utility plot")
    p.add_argument("--match", metavar="PATTERN", default="*",
                   help="with --sweep: only the run directories whose name matches this shell pattern, e.g. "
                   "'*decoder=fcnn,seed=0' (default: all)")
    p.add_argument("--attacks", default=",".join(ATTACKS), help=f"comma-separated attacks: {', '.join(ATTACKS)}")
    p.add_argument("--count", type=int, help=f"test digits attacked (default {PrivacyConfig().count})")
    p.add_argument("--gallery", type=int, help=f"re-identification gallery size (default {PrivacyConfig().gallery})")
    p.add_argument("--plaintext-n", metavar="N,N", help="plaintext attack: numbers of known pairs (default "
                   f"{','.join(str(v) for v in PrivacyConfig().plaintext_n)})")
    p.add_argument("--learned-epochs", type=int, help=f"learned attacker's epochs (default {LearnedConfig().epochs})")
    p.add_argument("--learned-pairs", type=int, help=f"learned attacker's training pairs (default {LearnedConfig().pairs})")
    p.add_argument("--learned-hidden", type=int, help="learned (MLP) attacker's hidden units per layer (default "
                   f"{LearnedConfig().hidden})")
    p.add_argument("--learned-schedule", help=f"learned attackers' learning-rate schedule: {', '.join(SCHEDULES)} "
                   f"(default {LearnedConfig().schedule})")
    p.add_argument("--learned-lr", type=float, help="learned attackers' Adam learning rate, the peak of one_cycle "
                   f"(default {LearnedConfig().lr:g})")
    p.add_argument("--learned-inputs", help=f"learned attackers' input scaling: {', '.join(INPUTS)} "
                   f"(default {LearnedConfig().inputs})")
    p.add_argument("--attack-seeds", type=int, help="learned attackers: each trained with this many seeds (--seed, "
                   f"--seed + 1, ...), a row the mean over them (default {PrivacyConfig().attack_seeds})")
    p.add_argument("--seed", type=int, help="seed of the sensor noise, the patterns a multi-pattern camera shows, the "
                   "re-identification galleries, the readability classifier and the attackers' training "
                   f"(default {PrivacyConfig().seed})")
    p.add_argument("--out", metavar="DIR", help="folder of the table (privacy.csv, privacy.md) and pictures; default "
                   "RUN_DIR/privacy with --run, DIR/privacy with --sweep; required with --encoder")
    p.add_argument("--force", action="store_true", help="re-measure runs that already have privacy/privacy.csv")
    p.add_argument("--defence", action="store_true", help="with --sweep: defence.{csv,md}, each run's attacks against "
                   "its baseline (encoder.patterns = 1, privacy.adversary_weight = 0; docs/privacy.md)")
    command(p, privacy, overrides=True)
    r = sub.add_parser(
        "reconstruct", help="reconstruct scenes from sensor embeddings (ADMM and others)",
        description="Reconstruct scenes (test digits, or your own images with --image) from an encoder's sensor "
        "embeddings, with sensor noise unless --no-noise, and write the reconstructions as a picture, NumPy "
        "arrays and reconstruct.json (PSNR and SSIM of each method).")
    _source_options(r)
    r.add_argument("--image", action="append", default=[], metavar="FILE", help="reconstruct this image (repeatable) instead of test digits")
    r.add_argument("--count", type=int, default=8, help="test digits (when no --image)")
    r.add_argument("--scene-shape", metavar="HxW", help="reconstruction grid (default: the dataset's, 28x28)")
    r.add_argument("--method", default="admm", help=f"comma-separated methods: {', '.join(METHODS)}")
    r.add_argument("--lam", type=float, help=f"Tikhonov weight, unit-norm operator (default {TikhonovConfig().lam:g})")
    r.add_argument("--no-noise", action="store_true", help="reconstruct noise-free embeddings")
    r.add_argument("--seed", type=int, default=0, help="seed of the sensor noise added to the embeddings (default 0)")
    r.add_argument("--out", metavar="DIR", help="folder of the picture, arrays and reconstruct.json; default "
                   "RUN_DIR/reconstruct with --run; required with --encoder")
    command(r, reconstruct, overrides=True)


def _given(**kw):
    return {k: v for k, v in kw.items() if v is not None}


def _admm_config(args) -> ADMMConfig:
    return ADMMConfig(**_given(iterations=args.iterations, tau=args.tau, mu_tv=args.mu_tv, mu_nonneg=args.mu_nonneg))


def _choices(text: str, allowed, key: str) -> list[str]:
    """Comma-separated names, each one of ``allowed`` (at least one), or a ConfigError naming ``key``."""
    out = names(text)
    for v in out:
        if v not in allowed:
            raise ConfigError(key, v, f"one of {', '.join(allowed)}")
    if not out:
        raise ConfigError(key, text, f"name at least one of {', '.join(allowed)}")
    return out


def _encoder(args, extra):
    """``(run config, encoder, summary, default output folder)`` from --run or --encoder."""
    from ..config import encoder_from_run
    from ..privacy.report import load_run

    if args.run:
        if len(args.run) > 1:
            raise ConfigError("--run", args.run, "give one run directory here (several: a --sweep folder)")
        run, enc, summary = load_run(args.run[0], split_overrides(extra), args.which)
        return run, enc, summary, Path(args.run[0])
    if not args.encoder:
        raise ConfigError("--encoder", None, "give --run RUN_DIR or --encoder NAME")
    run = compose(args, extra)
    return run, encoder_from_run(run).eval(), {}, None


def _load_images(files, shape):
    import numpy as np
    import torch
    from PIL import Image, UnidentifiedImageError

    out = []
    for f in files:
        try:
            img = Image.open(f).convert("L").resize((shape[1], shape[0]), Image.BILINEAR)
        except (OSError, UnidentifiedImageError) as err:
            raise DataError(f"--image {f}: cannot read the image ({str(err).splitlines()[0]})") from None
        out.append(torch.from_numpy(np.asarray(img, dtype="float64").copy()).reshape(1, *shape) / 255.0)
    return torch.stack(out)


def _npy(path: Path, t) -> Path:
    import numpy as np

    buf = io.BytesIO()
    np.save(buf, t.detach().cpu().numpy())
    return atomic_write_bytes(path, buf.getvalue())


def reconstruct(args: argparse.Namespace, extra) -> int:
    import torch

    from ..plugins import get_registry
    from ..privacy import metrics
    from ..privacy.admm import admm
    from ..privacy.operators import from_encoder
    from ..privacy.pictures import save_rows
    from ..privacy.tikhonov import pseudo_inverse, tikhonov

    methods = _choices(args.method, METHODS, "--method")
    run, enc, _summary, run_dir = _encoder(args, extra)
    if args.out is None and run_dir is None:
        raise ConfigError("--out", None, "required with --encoder (the folder the pictures and arrays go to)")
    out = Path(args.out) if args.out else run_dir / "reconstruct"
    if args.count < 1:
        raise ConfigError("--count", args.count, "must be >= 1")
    if args.image:
        shape = parse_hw("--scene-shape", args.scene_shape) if args.scene_shape else (28, 28)
        scenes, titles = _load_images(args.image, shape), [Path(f).name for f in args.image]
    else:
        splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
        scenes, labels = splits.test[0][: args.count].double(), splits.test[1][: args.count]
        if args.scene_shape:
            shape = parse_hw("--scene-shape", args.scene_shape)
            scenes = torch.nn.functional.interpolate(scenes, size=shape, mode="area")
        titles = [f"label {int(v)}" for v in labels]
    print(f"operator of {enc.name} for {tuple(scenes.shape[-2:])} scenes", file=sys.stderr)
    op = from_encoder(enc, tuple(scenes.shape[-2:]), scene_channels=scenes.shape[1])
    emb = op.forward(scenes)
    if not args.no_noise:
        emb = enc.add_sensor_noise(emb.float(), generator=torch.Generator().manual_seed(args.seed)).double()
    rows, arrays, report = [("scene", scenes), ("sensor embedding", emb)], {"scenes": scenes, "embeddings": emb}, {}
    for m in methods:
        print(f"{m} ...", file=sys.stderr)
        if m == "admm":
            rec = admm(op, emb, _admm_config(args))
        elif m == "tikhonov":
            rec = tikhonov(op, emb, args.lam)
        else:
            rec = pseudo_inverse(op, emb, args.rcond)
        rows.append((f"{m}", rec.clamp(0, 1)))
        arrays[m] = rec
        report[m] = {"psnr_db": metrics.summarize(metrics.psnr(rec, scenes)),
                     "ssim": metrics.summarize(metrics.ssim(rec, scenes))}
        _npy(out / f"reconstructions_{m}.npy", rec)
    a, b = enc.geometry.embedding
    pic = save_rows(out / "reconstruction.png", rows, titles, f"{enc.name}, embedding {a}x{b}")
    _npy(out / "scenes.npy", scenes)
    _npy(out / "embeddings.npy", emb)
    atomic_torch_save(out / "reconstructions.pt", {k: v.float() for k, v in arrays.items()})
    write_json(out / "reconstruct.json", {"encoder": enc.name, "embedding": [a, b], "noise": not args.no_noise,
                                          "admm": vars(_admm_config(args)), "metrics_mean_std": report})
    for m, r in report.items():
        print(f"{m:9s} PSNR {r['psnr_db'][0]:.2f} +- {r['psnr_db'][1]:.2f} dB  SSIM {r['ssim'][0]:.3f} +- {r['ssim'][1]:.3f}")
    print(pic)
    return 0


def _counts(text: str, key: str) -> tuple[int, ...]:
    """``"100,300"`` -> ``(100, 300)``, or a ConfigError naming ``key``."""
    try:
        out = tuple(int(v) for v in names(text))
    except ValueError:
        out = ()
    if not out:
        raise ConfigError(key, text, "comma-separated whole numbers, e.g. 100,1000")
    return out


def _evaluate_kw(args) -> dict:
    pc = PrivacyConfig(**_given(count=args.count, gallery=args.gallery, seed=args.seed, attack_seeds=args.attack_seeds,
                                plaintext_n=_counts(args.plaintext_n, "--plaintext-n") if args.plaintext_n else None))
    lc = LearnedConfig(**_given(epochs=args.learned_epochs, pairs=args.learned_pairs, hidden=args.learned_hidden,
                                schedule=args.learned_schedule, lr=args.learned_lr, inputs=args.learned_inputs))
    tc = TikhonovConfig(**_given(rcond=args.rcond))
    return {"attacks": tuple(_choices(args.attacks, ATTACKS, "--attacks")), "config": pc, "admm_config": _admm_config(args),
            "learned_config": lc, "linear_config": tc}


def privacy(args: argparse.Namespace, extra) -> int:
    from ..privacy import report

    if args.match != "*" and not args.sweep:
        raise ConfigError("--match", args.match, "only with --sweep DIR (it picks run directories of the folder)")
    if args.defence and not args.sweep:
        raise ConfigError("--defence", True, "needs --sweep DIR (the baseline and the defended runs side by side)")
    kw = _evaluate_kw(args)
    say = lambda msg: print(f"  {msg} ...", file=sys.stderr)  # noqa: E731
    note = lambda msg: print(f"  note: {msg}", file=sys.stderr)  # noqa: E731
    chance = 1.0 / kw["config"].gallery
    if args.sweep:
        rows, cells = [], []
        for cell in report.sweep_cells(args.sweep, args.match):
            print(f"{cell.name}", file=sys.stderr)
            cells.append((cell, report.measure_run(cell, kw, split_overrides(extra), args.force, say, note=note)))
            rows += cells[-1][1]
        out = Path(args.out) if args.out else Path(args.sweep) / report.PRIVACY_DIR
        paths = report.write_sweep(rows, out, chance)
        if args.defence:
            from ..privacy import defence

            paths += defence.write_defence(defence.defence_rows(cells), out)
    elif args.run:
        if len(args.run) > 1:
            raise ConfigError("--run", args.run, "give one run directory (several: put them in a --sweep folder)")
        out = Path(args.out) if args.out else Path(args.run[0]) / report.PRIVACY_DIR
        rows = report.measure_run(Path(args.run[0]), kw, split_overrides(extra), True, say, out, note)
        paths = [out / "privacy.csv"]
    else:
        from ..plugins import get_registry
        from ..privacy.evaluate import evaluate

        run, enc, _s, _d = _encoder(args, extra)
        if not args.out:
            raise ConfigError("--out", None, "required with --encoder (the folder the table and pictures go to)")
        splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
        result = evaluate(enc, splits, cache_root=run.trainer.cache_dir, progress=say, **kw)
        for line in result.notes:
            note(line)
        rows = report.run_rows(result, enc, {}, enc.name)
        out = Path(args.out)
        report.save_examples(out, result, enc.name)
        paths = [report.write_table(rows, out / "privacy.csv", out / "privacy.md")]
    print(report.markdown(rows), end="")
    for p in paths:
        print(p)
    return 0
