"""Run commands: ``fit``, ``validate``, ``test``, ``psf``, ``simulate``, ``export``.

Each takes settings as ``--section.key=value`` after its own options.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
from pathlib import Path

from ..errors import ConfigError, Interrupted
from ..training.quiet import quiet_lightning  # logging and warnings only: cheap at start-up
from .args import command, compose, out_dir, out_file, run_options, split_overrides

__all__ = ["add_parsers"]

#: Set by rank 0 of ``optoenc fit`` for the DDP workers Lightning launches with the same command line.
RUN_DIR_ENV = "OPTOENC_RUN_DIR"


def add_parsers(sub) -> None:
    """Add the run commands to the CLI's subparsers."""
    f = sub.add_parser("fit", help="train an encoder and decoder; writes a run directory",
                       description="Train an optical encoder and a digital decoder end to end, then test the best "
                       "checkpoint. Writes a run directory (config, metrics, checkpoints, pictures). Settings: "
                       "--section.key=value (e.g. --encoder.d2=4e-3, --trainer.max_epochs=10).")
    run_options(f)
    f.add_argument("--resume", metavar="RUN_DIR", help="continue a run from its last checkpoint")
    command(f, cmd_fit, overrides=True)
    for stage in ("validate", "test"):
        s = sub.add_parser(stage, help=f"{stage} a trained run (best checkpoint)",
                           description=f"Evaluate a trained run on its {'validation' if stage == 'validate' else 'test'} "
                           "split and print the metrics. Settings that do not change the trained model (e.g. "
                           "--trainer.batch_size) may be overridden.")
        s.add_argument("--run", required=True, metavar="RUN_DIR", help="run directory written by `optoenc fit`")
        s.add_argument("--which", default="best", choices=("best", "last"), help="checkpoint")
        command(s, cmd_evaluate, overrides=True)
    ps = sub.add_parser("psf", help="render an encoder's PSF (and mask) to PNG",
                        description="Render an encoder's point spread function (and its mask, where it has one) to PNG.")
    run_options(ps)
    ps.add_argument("--out", required=True, metavar="FILE.png", help="the PSF picture (the mask goes beside it, *_mask.png)")
    command(ps, cmd_psf, overrides=True)
    si = sub.add_parser("simulate", help="write example measurements at each paper embedding size",
                        description="Encode a few test digits at each of the paper's embedding sizes and write one "
                        "picture per size (scene and sensor measurement side by side).")
    run_options(si)
    si.add_argument("--out", required=True, metavar="DIR", help="folder the pictures go to")
    si.add_argument("--count", type=int, default=8, help="digits per picture (1-64)")
    command(si, cmd_simulate, overrides=True)
    ex = sub.add_parser("export", help="export a trained SLM pattern as the panel's RGB image",
                        description="Export a trained SLM pattern as the 128 x 160 RGB image the ST7735R panel displays.")
    ex.add_argument("--run", required=True, metavar="RUN_DIR", help="run directory written by `optoenc fit`")
    ex.add_argument("--which", default="best", choices=("best", "last"), help="checkpoint")
    ex.add_argument("--out", required=True, metavar="FILE.png", help="the panel image")
    command(ex, cmd_export, overrides=True)


def cmd_fit(args: argparse.Namespace, extra) -> int:
    from ..training.rundir import RUN_FILES, new_run_dir, remove_if_empty

    if args.resume:
        run_dir = Path(args.resume)
        cfg = run_dir / RUN_FILES["config"]
        if not cfg.is_file():
            raise ConfigError("--resume", args.resume, f"not a run directory (no {RUN_FILES['config']})")
        args.config = [str(cfg)] + list(args.config)
    run = compose(args, extra)
    if args.print_config:
        print(run.to_yaml(), end="")
        return 0
    if args.resume:
        from ..config import compose as compose_run, load_yaml
        from ..training.resume import check_resume

        check_resume(run_dir, compose_run([load_yaml(str(cfg))]).tree, run.tree)
    elif os.environ.get(RUN_DIR_ENV) and not _rank_zero():
        run_dir = Path(os.environ[RUN_DIR_ENV])  # a DDP worker Lightning re-launched: rank 0's run directory
    else:
        stem = f"{run.names['encoder']}-{run.names['decoder']}"
        run_dir = new_run_dir(run.output.root, run.output.name, stem)
        os.environ[RUN_DIR_ENV] = str(run_dir)  # inherited by DDP workers (strategy=ddp re-runs this command)
    from ..training.run import fit  # Lightning: imported once the settings check out (a refusal takes ~1 s, not ~5)

    quiet_lightning()
    if _rank_zero():  # DDP: the workers Lightning launches run this command too; one report
        print(f"run directory: {run_dir}", file=sys.stderr)
    try:
        summary = fit(run, run_dir, resume=bool(args.resume))
    except Interrupted as err:
        if not err.where and (run_dir / RUN_FILES["config"]).is_file():  # after training: testing, pictures
            from ..training.resume import interrupted_note

            err.where = interrupted_note(run_dir, err.name, run.trainer.max_epochs)
        err.where = err.where or f"while preparing {run_dir} (before training; nothing to resume, start the run again)"
        raise
    finally:
        remove_if_empty(run_dir)  # a start that failed leaves no stub directory behind
    if not _rank_zero():
        return 0
    if "val_acc" in summary:
        line = f"val_acc {summary['val_acc']:.4f}  test_acc {summary['test_acc']:.4f}"
    else:  # another task: its selection metric, then its test metrics
        line = "  ".join(f"{k} {v:.4f}" for k, v in summary.items()
                         if k.startswith(("val_", "test_")) and isinstance(v, float))
    if "verify" in summary:
        line += "".join(f"  {k}@{summary['verify']['preset']} {v:.4f}" for k, v in summary["verify"].items() if k != "preset")
    print(f"{line}  ({summary['wall_time_s']:.0f} s)  -> {run_dir}")
    return 0


def _rank_zero() -> bool:
    """Whether this process is the command as typed, not a DDP worker Lightning re-launched with it."""
    return os.environ.get("LOCAL_RANK", "0") == "0"


def cmd_evaluate(args: argparse.Namespace, extra) -> int:
    from ..training.run import evaluate

    run_dir = Path(args.run)
    run = _run_config(args.run, extra)
    quiet_lightning()
    metrics = evaluate(run, run_dir, args.command, args.which)
    print("  ".join(f"{k} {v:.4f}" for k, v in sorted(metrics.items())))
    return 0


def _run_config(run_dir: str, extra):
    """A run directory's stored configuration with the command line's overrides (checked against the stored one)."""
    from ..config import compose as compose_run, load_yaml
    from ..training.resume import check_evaluate
    from ..training.rundir import RUN_FILES

    cfg = Path(run_dir) / RUN_FILES["config"]
    if not cfg.is_file():
        raise ConfigError("--run", run_dir, f"not a run directory (no {RUN_FILES['config']})")
    stored = load_yaml(str(cfg))
    run = compose_run([stored], split_overrides(extra))
    check_evaluate(Path(run_dir), compose_run([stored]).tree, run.tree)
    return run


def cmd_export(args: argparse.Namespace, extra) -> int:
    from PIL import Image

    from ..encoders.slm import panel_image
    from ..training.run import load_encoder
    from ..training.rundir import atomic_write_bytes

    out = out_file(args.out)
    run = _run_config(args.run, extra)
    enc = load_encoder(run, Path(args.run), args.which)
    mask = enc.mask()
    if mask is None or tuple(mask.shape) != (384, 160):
        raise ConfigError("--run", args.run, f"encoder {enc.name!r} has no ST7735R panel pattern to export")
    buf = io.BytesIO()
    Image.fromarray(panel_image(enc), mode="RGB").save(buf, format="PNG")
    print(atomic_write_bytes(out, buf.getvalue()))
    return 0


def cmd_psf(args: argparse.Namespace, extra) -> int:
    from ..config import encoder_from_run
    from ..training import pictures

    out = out_file(args.out)
    run = compose(args, extra)
    enc = encoder_from_run(run)
    pictures.save_psf(out, pictures.spectral_psf(enc), enc.geometry.spacing, f"{enc.name} PSF")
    print(out)
    # stdout keeps the picture paths only; the figure goes beside them
    print(f"{enc.name}: throughput {enc.throughput():.4g} (light collected relative to a fully open aperture "
          "of the same size)", file=sys.stderr)
    mask = enc.mask()
    if mask is not None:
        print(pictures.save_mask(out.with_name(out.stem + "_mask.png"), mask, f"{enc.name} mask", pictures.mask_spacing(enc, mask),
                                 throughput=enc.throughput()))
    return 0


def cmd_simulate(args: argparse.Namespace, extra) -> int:
    import dataclasses

    from .. import devices
    from ..config import encoder_from_run
    from ..plugins import get_registry
    from ..training import pictures

    if not 1 <= args.count <= 64:
        raise ConfigError("--count", args.count, "must be >= 1 and <= 64 (digits drawn per picture)")
    out = out_dir(args.out)
    run = compose(args, extra)
    splits = get_registry("dataset").get(run.names["dataset"])(run.dataset).load()
    x, y = splits.test[0][: args.count], splits.test[1][: args.count]
    for i, emb_shape in enumerate(devices.EMBEDDINGS):
        run.sensor = dataclasses.replace(run.sensor, embedding=emb_shape)
        enc = encoder_from_run(run)
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
