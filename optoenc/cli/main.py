"""``optoenc`` command line: train, evaluate, list plugins, draw PSFs, benchmark.

Bad input (unknown key or name, value out of range, corrupt file) prints one
line ``optoenc: error: ...`` and exits with code 2, without a traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Sequence

from . import __version__
from .training.quiet import quiet_lightning  # logging and warnings only: cheap at start-up
from .errors import ConfigError, Interrupted, OptoencError
from .plugins.registry import KINDS

__all__ = ["main"]

#: Listing command -> plugin kind (`optoenc encoders`, ...), one per kind of :data:`optoenc.plugins.registry.KINDS`.
#: Set by rank 0 of ``optoenc fit`` for the DDP workers Lightning launches with the same command line.
_RUN_DIR_ENV = "OPTOENC_RUN_DIR"

KIND_COMMANDS = {f"{kind}s": kind for kind in KINDS}


def _split_overrides(extra: Sequence[str]) -> list[str]:
    """``--a.b=v`` / ``--a.b v`` / ``a.b=v`` tokens -> ``["a.b=v", ...]``."""
    out, i, extra = [], 0, list(extra)
    while i < len(extra):
        tok = extra[i]
        key = tok[2:] if tok.startswith("--") else tok
        if "=" in key:
            out.append(key)
        elif tok.startswith("--") and "." in key and i + 1 < len(extra):
            out.append(f"{key}={extra[i + 1]}")
            i += 1
        else:
            raise ConfigError(key or tok, "", "not an option; settings are given as --section.key=value")
        i += 1
    return out


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", action="append", default=[], metavar="YAML", help="run config file (repeatable; later wins)")
    p.add_argument("--encoder", help="optical encoder (see `optoenc encoders`)")
    p.add_argument("--decoder", help="digital decoder (see `optoenc decoders`)")
    p.add_argument("--dataset", help="dataset (see `optoenc datasets`)")
    p.add_argument("--augment", help="comma-separated augmentations (see `optoenc augmentations`); '' for none")
    p.add_argument("--seed", type=int, help="run seed")
    p.add_argument("--print-config", action="store_true", help="print the resolved config and exit")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="optoenc",
        description="Design optical encoders end to end. Settings: --section.key=value (e.g. --encoder.d2=4e-3).",
    )
    p.add_argument("--version", action="store_true", help="print versions of optoenc and its plugins")
    sub = p.add_subparsers(dest="command")
    f = sub.add_parser("fit", help="train an encoder and decoder; writes a run directory")
    _run_options(f)
    f.add_argument("--resume", metavar="RUN_DIR", help="continue a run from its last checkpoint")
    for stage in ("validate", "test"):
        s = sub.add_parser(stage, help=f"{stage} a trained run (best checkpoint)")
        s.add_argument("--run", required=True, metavar="RUN_DIR", help="run directory written by `optoenc fit`")
        s.add_argument("--which", default="best", choices=("best", "last"), help="checkpoint")
    pl = sub.add_parser("plugins", help="list installed plugins and what they register")
    pl.add_argument("--json", action="store_true")
    for cmd, kind in KIND_COMMANDS.items():
        s = sub.add_parser(cmd, help=f"list {cmd}, or show one {kind}'s settings")
        s.add_argument("pattern", nargs="?", help=f"a {kind} name (its settings) or a glob pattern")
        s.add_argument("--json", action="store_true")
    ps = sub.add_parser("psf", help="render an encoder's PSF (and mask) to PNG")
    _run_options(ps)
    ps.add_argument("--out", required=True, metavar="FILE.png")
    si = sub.add_parser("simulate", help="write example measurements at each paper embedding size")
    _run_options(si)
    si.add_argument("--out", required=True, metavar="DIR")
    si.add_argument("--count", type=int, default=8, help="digits per picture")
    ex = sub.add_parser("export", help="export a trained SLM pattern as the 128 x 160 RGB image the panel displays")
    ex.add_argument("--run", required=True, metavar="RUN_DIR", help="run directory written by `optoenc fit`")
    ex.add_argument("--which", default="best", choices=("best", "last"), help="checkpoint")
    ex.add_argument("--out", required=True, metavar="FILE.png")
    b = sub.add_parser(
        "bench",
        help="benchmarks (speed and accuracy, side by side)",
        description="fidelity (default): the paper pipeline (as published and on its grid), the presets and a "
        "sweep of each knob against the converged truth; converge: the convergence study behind the truth; "
        "speed: the learned SLM's step vs the published paper step, interleaved; auto: the cheapest measured "
        "setting meeting --tolerance; optics: PSF timings; precision: bfloat16 operator and decoder products against "
        "float32 (embedding and gradient errors, step speed-up, interleaved); steps: the training step of a sweep "
        "spec's cells (--spec, --only) with the whole scene operator and with the support region, interleaved; loop: "
        "fixed-encoder cells' epochs with trainer.loop=batch and =epoch, alternated (--epochs, --repeats, --threads).",
    )
    b.add_argument("what", nargs="?", default="fidelity", choices=("fidelity", "converge", "speed", "auto", "optics", "precision", "steps", "loop"),
                   help="which benchmark")
    b.add_argument("--out", metavar="DIR", help="also write CSV/PNG here")
    b.add_argument("--docs", metavar="DIR", help="fidelity: also rewrite the generated blocks of DIR/benchmarks.md and "
                   "DIR/fidelity.md from this run (CSV and plot under DIR/bench)")
    b.add_argument("--encoders", metavar="A,B", help="comma-separated encoders (default: every built-in)")
    b.add_argument("--presets", metavar="A,B", help="comma-separated presets (default: reference,default,fast)")
    b.add_argument("--digits", type=int, default=256, help="test digits the embedding error is measured on")
    b.add_argument("--sweep", action=argparse.BooleanOptionalAction, default=True, help="sweep each knob alone")
    b.add_argument("--paper", action=argparse.BooleanOptionalAction, default=True, help="run the paper pipeline")
    b.add_argument("--truth-grid", default="3040x4056", metavar="HxW", help="finest grid of the truth (the sensor)")
    b.add_argument("--speed", action=argparse.BooleanOptionalAction, default=True,
                   help="fidelity: also time learned_slm's default step vs the published paper step, interleaved")
    b.add_argument("--repeats", type=int, default=5, help="speed: interleaved repeats per thread count")
    b.add_argument("--threads", default="1,2", metavar="N,M", help="speed: torch thread counts timed (e.g. 1 on a shared machine); precision: the first")
    b.add_argument("--paper-grid", default="380x507", metavar="HxW", help="grid of the paper pipeline")
    b.add_argument("--encode-count", type=int, default=10000, help="digits encoded for the fixed encoders' encode time")
    b.add_argument("--encode-all", action=argparse.BooleanOptionalAction, default=True,
                   help="also time encoding all 70,000 MNIST digits with fixed_slm, cache cold")
    b.add_argument("--embedding", default="24x32", metavar="AxB", help="precision: the sensor embedding")
    b.add_argument("--scene-shape", metavar="HxW", help="precision: a canvas the digits are centred on "
                   "(109x146: Table 3's 24x32 learned SLM); default the 28x28 digits")
    b.add_argument("--encoder", help="auto: the encoder to choose a setting for")
    b.add_argument("--tolerance", type=float, default=0.01, help="auto: largest relative embedding error (0.01 = 1%%)")
    b.add_argument("--safety", type=float, default=1.0, help="auto: require error * safety <= tolerance")
    b.add_argument("--from-csv", metavar="CSV", help="auto: choose among the rows of a CSV of `optoenc bench --out`")
    b.add_argument("--epochs", type=int, default=3, help="loop: epochs per run (the first of each is warm-up, not timed)")
    b.add_argument("--spec", metavar="SPEC.yaml", help="steps: the sweep spec whose cells are timed")
    b.add_argument("--only", action="append", metavar="GLOB", help="steps: only the cells whose name matches (repeatable)")
    b.add_argument("--against", default="support", metavar="PAIR",
                   help="steps: the pair timed side by side (optoenc.bench.steps.AGAINST): support regions off/on (default), dense/banded operator "
                        "build, the LCD's PSF by 2-D FFTs/axis by axis (propagation), the banded build's consecutive/sorted rows (sorted), "
                        "its operator copied/held by canvas rows (rows), a bfloat16 operator's banded/matrix-unit build (matrix_units), "
                        "redrawn transforms placed over the whole window/each object's band (bands)")
    sw = sub.add_parser("sweep", help="run a sweep of runs from a spec (resumable), collect CSV, tables and plots")
    sw.add_argument("spec", help="sweep spec YAML (base config, axes, cells, paper figures)")
    sw.add_argument("--out", metavar="DIR", help="sweep directory (default: sweeps/<spec name>)")
    sw.add_argument("--dry-run", action="store_true", help="list the cells, their state and estimated time; run nothing")
    sw.add_argument("--workers", type=int, default=1, help="cells run at once (torch threads split between them)")
    sw.add_argument("--threads", type=int, metavar="N",
                    help="torch threads per worker (default: the machine's cores split between the workers; "
                         "set it when other work, such as a second sweep, shares the cores); a cell whose spec sets "
                         "trainer.threads runs with those and holds as many of the workers x N while it runs")
    sw.add_argument("--executor", default="local", help="local (processes), submitit-local or slurm (needs submitit)")
    sw.add_argument("--start", default="auto",
                    help="how a local cell's process starts: forkserver (forked from one process that has imported "
                         "torch, Lightning and optoenc: no per-cell imports, seconds a cell), subprocess (a fresh "
                         "interpreter per cell), auto (forkserver where the platform has it and the cell is one process)")
    sw.add_argument("--restart-changed", action="store_true", help="move aside cells whose stored config differs, re-run them")
    sw.add_argument("--collect", action="store_true", help="only collect finished cells into the tables and plots")
    sw.add_argument("--order", default="spec",
                    help="the order cells start in: spec (the spec's) or longest (the longest first by the --dry-run "
                         "estimate: with several workers, fewer idle at the end)")
    sw.add_argument("--only", action="append", metavar="GLOB",
                    help="run only the cells whose name matches (repeatable), e.g. 'encoder=learned_slm,*'")
    from .privacy.commands import add_parsers as _privacy_parsers

    _privacy_parsers(sub)
    return p


def _compose(args, extra):
    from .config import compose

    names = {k: getattr(args, k, None) for k in ("encoder", "decoder", "dataset")}
    files = [_load_yaml(c) for c in getattr(args, "config", [])]
    augment = None if getattr(args, "augment", None) is None else [a.strip() for a in args.augment.split(",")]
    return compose(files, _split_overrides(extra), names, augment, getattr(args, "seed", None))


def _load_yaml(path: str):
    from omegaconf import DictConfig, OmegaConf

    if not Path(path).is_file():
        raise ConfigError("--config", path, "file not found")
    try:
        tree = OmegaConf.load(path)
    except Exception as err:
        raise ConfigError("--config", path, f"not valid YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(tree, DictConfig):
        raise ConfigError("--config", path, "must hold a mapping of sections (seed:, encoder:, ...) at its top level, not a list")
    return tree


def cmd_fit(args, extra) -> int:
    from .training.rundir import RUN_FILES, new_run_dir, remove_if_empty

    if args.resume:
        run_dir = Path(args.resume)
        cfg = run_dir / RUN_FILES["config"]
        if not cfg.is_file():
            raise ConfigError("--resume", args.resume, f"not a run directory (no {RUN_FILES['config']})")
        args.config = [str(cfg)] + list(args.config)
    run = _compose(args, extra)
    if args.print_config:
        print(run.to_yaml(), end="")
        return 0
    if args.resume:
        from .config import compose
        from .training.resume import check_resume

        check_resume(run_dir, compose([_load_yaml(str(cfg))]).tree, run.tree)
    elif os.environ.get(_RUN_DIR_ENV) and os.environ.get("LOCAL_RANK", "0") != "0":
        run_dir = Path(os.environ[_RUN_DIR_ENV])  # a DDP worker Lightning re-launched: rank 0's run directory
    else:
        stem = f"{run.names['encoder']}-{run.names['decoder']}"
        run_dir = new_run_dir(run.output.root, run.output.name, stem)
        os.environ[_RUN_DIR_ENV] = str(run_dir)  # inherited by DDP workers (strategy=ddp re-runs this command)
    from .training.run import fit  # Lightning: imported once the settings check out (a refusal takes ~1 s, not ~5)

    quiet_lightning()
    print(f"run directory: {run_dir}", file=sys.stderr)
    try:
        summary = fit(run, run_dir, resume=bool(args.resume))
    except Interrupted as err:
        if not err.where and (run_dir / RUN_FILES["config"]).is_file():  # after training: testing, pictures
            from .training.resume import interrupted_note

            err.where = interrupted_note(run_dir, err.name, run.trainer.max_epochs)
        err.where = err.where or f"while preparing {run_dir} (before training; nothing to resume, start the run again)"
        raise
    finally:
        remove_if_empty(run_dir)  # a start that failed leaves no stub directory behind
    line = f"val_acc {summary['val_acc']:.4f}  test_acc {summary['test_acc']:.4f}"
    if "verify" in summary:
        line += f"  test_acc@{summary['verify']['preset']} {summary['verify']['test_acc']:.4f}"
    print(f"{line}  ({summary['wall_time_s']:.0f} s)  -> {run_dir}")
    return 0


def cmd_evaluate(args, extra) -> int:
    from .training.run import evaluate

    run_dir = Path(args.run)
    run = _run_config(args.run, extra)
    quiet_lightning()
    metrics = evaluate(run, run_dir, args.command, args.which)
    print("  ".join(f"{k} {v:.4f}" for k, v in sorted(metrics.items())))
    return 0


def _run_config(run_dir: str, extra):
    from .config import compose
    from .training.rundir import RUN_FILES

    from .training.resume import check_evaluate

    cfg = Path(run_dir) / RUN_FILES["config"]
    if not cfg.is_file():
        raise ConfigError("--run", run_dir, f"not a run directory (no {RUN_FILES['config']})")
    stored = _load_yaml(str(cfg))
    run = compose([stored], _split_overrides(extra))
    check_evaluate(Path(run_dir), compose([stored]).tree, run.tree)
    return run


def cmd_export(args, extra) -> int:
    from PIL import Image

    from .training.rundir import atomic_write_bytes
    from .training.run import load_encoder

    out = _out_file(args.out)
    run = _run_config(args.run, extra)
    enc = load_encoder(run, Path(args.run), args.which)
    mask = enc.mask()
    if mask is None or tuple(mask.shape) != (384, 160):
        raise ConfigError("--run", args.run, f"encoder {enc.name!r} has no ST7735R panel pattern to export")
    from .encoders.slm import panel_image
    import io

    buf = io.BytesIO()
    Image.fromarray(panel_image(enc), mode="RGB").save(buf, format="PNG")
    print(atomic_write_bytes(out, buf.getvalue()))
    return 0


def cmd_list(args, extra) -> int:
    from .plugins import listing

    kind = KIND_COMMANDS[args.command]
    print(listing.show(kind, args.pattern, as_json=args.json))
    return 0


def cmd_plugins(args, extra) -> int:
    from .plugins import listing

    print(listing.plugins(as_json=args.json))
    return 0


def cmd_psf(args, extra) -> int:
    from .training import pictures
    from .config import build_encoder

    out = _out_file(args.out)
    run = _compose(args, extra)
    enc = build_encoder(run)
    pictures.save_psf(out, pictures.spectral_psf(enc), enc.geometry.spacing, f"{enc.name} PSF")
    print(out)
    mask = enc.mask()
    if mask is not None:
        print(pictures.save_mask(out.with_name(out.stem + "_mask.png"), mask, f"{enc.name} mask", pictures.mask_spacing(enc, mask)))
    return 0


def _out_file(path: str) -> Path:
    """``--out FILE``: refused up front if it names a folder or lies under a file."""
    out = Path(path)
    if out.is_dir():
        raise ConfigError("--out", path, "is a folder; give a file name (e.g. psf.png)")
    if any(p.exists() and not p.is_dir() for p in out.parents):
        raise ConfigError("--out", path, "lies under a file, not a folder")
    return out


def _out_dir(path: str) -> Path:
    """``--out DIR``: refused up front if it names a file or lies under one."""
    out = Path(path)
    if any(p.exists() and not p.is_dir() for p in (out, *out.parents)):
        raise ConfigError("--out", path, "is (or lies under) a file; give a folder")
    return out


def cmd_simulate(args, extra) -> int:
    import dataclasses

    from . import devices
    from .training import pictures
    from .config import build_encoder
    from .plugins import get_registry

    if not 1 <= args.count <= 64:
        raise ConfigError("--count", args.count, "must be >= 1 and <= 64 (digits drawn per picture)")
    out = _out_dir(args.out)
    run = _compose(args, extra)
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    x, y = splits.test[0][: args.count], splits.test[1][: args.count]
    for i, emb_shape in enumerate(devices.EMBEDDINGS):
        run.sensor = dataclasses.replace(run.sensor, embedding=emb_shape)
        enc = build_encoder(run)
        if i == 0:  # computed, not quoted: |M| = d2 / d1 on this run's grid
            H, W = enc.geometry.grid
            print(f"{enc.name}: the {1e3 * enc.scene_config.object_height:g} mm object at d1 = "
                  f"{enc.scene_config.distance:g} m is {enc.object_height_px():.1f} px tall on the {H} x {W} grid "
                  f"(|M| = {enc.magnification:.4g})")
        emb = enc(x)
        path = pictures.save_measurements(
            out / f"{enc.name}_{emb_shape[0]}x{emb_shape[1]}.png", x, emb, y.tolist(),
            scene_height=enc.scene_config.object_height, sensor_size=enc.sensor.size,
        )
        print(path)
    return 0


def cmd_bench(args, extra) -> int:
    from .bench.command import main as bench_main

    quiet_lightning()  # bench loop trains runs
    return bench_main(args)


def cmd_reconstruct(args, extra) -> int:
    from .privacy.commands import reconstruct

    return reconstruct(args, extra)


def cmd_privacy(args, extra) -> int:
    from .privacy.commands import privacy

    return privacy(args, extra)


def cmd_version() -> int:
    from .plugins import get_host

    print(f"optoenc {__version__}")
    for info in get_host().plugins:
        state = "ok" if info.ok else f"FAILED: {info.error}"
        print(f"  plugin {info.name} {info.distribution} {info.version} ({state})")
    return 0


def cmd_sweep(args, extra) -> int:
    from . import sweep

    spec = sweep.load_spec(args.spec)
    out = Path(args.out or Path("sweeps") / spec.name)
    planned = sweep.plan(spec, out, args.only)
    if args.only and not planned:
        raise ConfigError("--only", ",".join(args.only), "matches no cell (see the names with --dry-run)")
    if args.order not in sweep.ORDERS:
        raise ConfigError("--order", args.order, f"one of {', '.join(sweep.ORDERS)}")
    from .sweep.launch import resolve_start

    resolve_start(args.start)  # a bad --start is refused before anything runs (each cell's start: sweep.run)
    if args.dry_run or (args.order == "longest" and not args.collect):
        from .sweep.estimate import estimate

        per_worker = sweep.resolve_threads(args.workers, args.threads)
        est = estimate(planned, threads=per_worker)
        if args.order == "longest":
            planned = sweep.longest_first(planned, {k: e["seconds"] for k, e in est.items()},
                                          {p.cell.name: sweep.machine_share(p, args.workers, per_worker) for p in planned})
    if args.dry_run:
        # A cell holds its share of the sweep's threads while it runs (one that asks for them all runs alone).
        secs = [(est[p.cell.name]["seconds"], sweep.machine_share(p, args.workers, per_worker))
                for p in planned if p.state != "finished"]
        total = sum(s for s, _ in secs if s == s)  # NaN: a cell that could not be estimated
        for p in planned:
            e = est[p.cell.name]
            print(f"{p.state:11s} {e['seconds']:8.1f} s ({e['source']})  {p.cell.name}")
        todo = sum(p.state != "finished" for p in planned)
        wall = sum(s * share for s, share in secs if s == s)
        wall = f", about {wall / 60:.1f} min with {args.workers} workers" if args.workers > 1 else ""
        print(f"{len(planned)} cells, {todo} to run, estimated {total / 60:.1f} min on one worker{wall} -> {out}")
        return 0
    if not args.collect:
        quiet_lightning()
        from tqdm.auto import tqdm

        todo = [p for p in planned if p.todo]
        print(f"sweep {spec.name}: {len(planned)} cells, {len(todo)} to run -> {out}", file=sys.stderr)
        with tqdm(total=len(todo), desc="cells", unit="cell", disable=not sys.stderr.isatty()) as bar:
            def done(p, ok, err):
                bar.update(1)
                msg = f"{'done' if ok else 'FAILED'} {p.cell.name}" + (f": {err}" if err else "")
                (bar.write if sys.stderr.isatty() else lambda m: print(m, file=sys.stderr))(msg)

            failures = sweep.run(planned, out, workers=args.workers, executor=args.executor,
                                 restart_changed=args.restart_changed, on_done=done, threads=args.threads,
                                 start=args.start)
    else:
        failures = {}
    files = sweep.write_tables(spec, sweep.plan(spec, out), out)  # the tables always cover every cell
    for path in files.values():
        print(path)
    if failures:
        print(f"optoenc: {len(failures)} cell(s) failed: {', '.join(sorted(failures))} (see their status.json)",
              file=sys.stderr)
        return 1
    return 0


COMMANDS = {
    "sweep": cmd_sweep,
    "fit": cmd_fit,
    "validate": cmd_evaluate,
    "test": cmd_evaluate,
    "plugins": cmd_plugins,
    "psf": cmd_psf,
    "simulate": cmd_simulate,
    "bench": cmd_bench,
    "export": cmd_export,
    "reconstruct": cmd_reconstruct,
    "privacy": cmd_privacy,
    **{k: cmd_list for k in KIND_COMMANDS},
}


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args, extra = parser.parse_known_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command as typed (e.g. in generated docs)
    try:
        if args.version:
            return cmd_version()
        if not args.command:
            parser.print_help()
            return 0
        if extra and args.command not in ("fit", "validate", "test", "psf", "simulate", "export", "reconstruct", "privacy"):
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        from .training.allocator import keep_freed_memory
        from .training.resume import raise_on_signals

        keep_freed_memory()  # $OPTOENC_MALLOC (default keep): no page faults on every step's large tensors
        with raise_on_signals():
            return COMMANDS[args.command](args, extra)
    except OptoencError as err:
        print(f"optoenc: error: {err}", file=sys.stderr)
        return err.exit_code
    except OSError as err:  # a file system refusal not caught earlier: one line, naming the file
        print(f"optoenc: error: {err.filename or ''}: {err.strerror or err}", file=sys.stderr)
        return 2
    except Interrupted as err:
        print(f"optoenc: interrupted by {err.name}{' ' + err.where if err.where else ''}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print("optoenc: interrupted by SIGINT", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
