"""``optoenc bench``: speed and accuracy benchmarks, one subcommand each, each with its own options.

``optoenc bench`` alone lists the benchmarks. The measuring is in
:mod:`optoenc.bench` (one module per benchmark); this module parses the
options, prints the tables and writes the files. Every report starts and ends
with the machine's load average (the machine may be shared).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

from ..errors import ConfigError
from ..settings import parse_hw
from ..training.quiet import quiet_lightning
from .args import command, names

__all__ = ["add_parsers"]

_DESCRIPTION = """\
Benchmarks of the simulation's speed and accuracy, side by side. `optoenc bench` alone prints this list;
`optoenc bench NAME --help` lists a benchmark's options."""


def add_parsers(sub) -> None:
    """Add ``bench`` and its benchmarks to the CLI's subparsers."""
    b = sub.add_parser("bench", help="speed and accuracy benchmarks (`optoenc bench` lists them)",
                       description=_DESCRIPTION)
    command(b, lambda args, extra: _list(b))
    benches = b.add_subparsers(dest="benchmark", title="benchmarks", metavar="NAME")

    f = benches.add_parser(
        "fidelity", help="presets and knobs against the converged truth (the main one)",
        description="The main benchmark: for every encoder, the embedding error against the converged truth and the "
        "cost of each fidelity preset and of each knob swept alone, beside the paper's pipeline as published and on "
        "its grid; the learned SLM's step against the published step, interleaved; the cheapest setting meeting "
        "--tolerance; the outcome checks. Long (tens of minutes).")
    _encoders(f)
    _measurement(f)
    f.add_argument("--paper", action=argparse.BooleanOptionalAction, default=True, help="run the paper pipeline")
    f.add_argument("--paper-grid", default="380x507", metavar="HxW", help="grid of the paper pipeline")
    f.add_argument("--encode-all", action=argparse.BooleanOptionalAction, default=True,
                   help="also time encoding all 70,000 MNIST digits with fixed_slm, cache cold")
    f.add_argument("--speed", action=argparse.BooleanOptionalAction, default=True,
                   help="also time learned_slm's default step against the published paper step, interleaved")
    _speed_options(f)
    _choice_options(f, "the tolerance of the cheapest-setting row of the outcome checks")
    f.add_argument("--out", metavar="DIR", help="also write bench.csv and pareto.png here (and keep the truth under DIR/truth)")
    f.add_argument("--docs", metavar="DIR", help="also rewrite the generated blocks of DIR/benchmarks.md and "
                   "DIR/fidelity.md from this run (CSV and plot under DIR/bench)")
    command(f, _quiet(_fidelity))

    c = benches.add_parser(
        "converge", help="the convergence study behind the truth",
        description="Each encoder's simulation on grids refined towards the sensor pitch, against the truth: the "
        "change per level, the observed order and the extrapolated limit.")
    _encoders(c)
    c.add_argument("--digits", type=int, default=256, help="test digits the embedding error is measured on")
    c.add_argument("--out", metavar="DIR", help="also write converge.csv here")
    command(c, _quiet(_converge))

    s = benches.add_parser(
        "speed", help="a training step against the published paper step",
        description="One encoder's training step at the default preset and the published paper step, timed "
        "alternately so that a change of the machine's load hits both alike.")
    s.add_argument("--encoder", default="learned_slm", help="the encoder timed (default learned_slm)")
    _speed_options(s)
    command(s, _quiet(_speed))

    t = benches.add_parser(
        "tasks", help="a reconstruction training step beside the classification step",
        description="One encoder's training step for reconstruction (a reconstruction decoder, MSE) and for "
        "classification (FCNN, cross-entropy) at the default preset and a 24 x 32 embedding, timed alternately; "
        "prints both and their ratio.")
    t.add_argument("--encoder", default="learned_slm", help="the encoder timed (default learned_slm)")
    t.add_argument("--decoder", default="unet", help="the reconstruction decoder (default unet)")
    t.add_argument("--batch", type=int, default=200, help="examples per step")
    _timing(t, 5)
    command(t, _quiet(_tasks))

    a = benches.add_parser(
        "auto", help="the cheapest measured setting meeting an error tolerance",
        description="The cheapest fidelity setting of one encoder whose embedding error against the truth meets "
        "--tolerance: measured now, or chosen among the rows of a CSV written by `optoenc bench fidelity --out`. "
        "Prints the settings to pass to `optoenc fit`.")
    a.add_argument("--encoder", help="the encoder to choose a setting for (required)")
    _choice_options(a, "largest relative embedding error")
    a.add_argument("--from-csv", metavar="CSV", help="choose among the rows of this CSV of `optoenc bench fidelity --out` "
                   "(measures nothing)")
    _measurement(a)
    a.add_argument("--out", metavar="DIR", help="keep the truth under DIR/truth (a later run reuses it)")
    command(a, _quiet(_auto))

    o = benches.add_parser(
        "optics", help="PSF timings: all wavelengths batched against one at a time",
        description="The simulated SLM PSF timed per grid, number of wavelengths and precision: all wavelengths in "
        "one batched call against one call each, and forward + backward.")
    command(o, _quiet(_optics))

    p = benches.add_parser(
        "precision", help="bfloat16 products against float32: errors and speed-up",
        description="Each encoder with a bfloat16 scene operator (and the decoder under bfloat16 autocast) against "
        "float32: embedding and gradient errors beside the sensor noise, and the step speed-up, interleaved.")
    _encoders(p)
    p.add_argument("--embedding", default="24x32", metavar="AxB", help="the sensor embedding")
    p.add_argument("--scene-shape", metavar="HxW", help="a canvas the digits are centred on "
                   "(109x146: Table 3's 24x32 learned SLM); default the 28x28 digits")
    _timing(p, 5)
    p.add_argument("--out", metavar="DIR", help="also write precision.csv here")
    command(p, _quiet(_precision))

    st = benches.add_parser(
        "steps", help="the training step of a sweep spec's cells",
        description="One training step (the cell's batch, augmentations, encoder and decoder) of each cell of a "
        "sweep spec, timed; the epoch's training steps at that rate.")
    st.add_argument("--spec", metavar="SPEC.yaml", help="the sweep spec whose cells are timed (required)")
    st.add_argument("--only", action="append", metavar="GLOB", help="only the cells whose name matches (repeatable)")
    _timing(st, 5)
    command(st, _quiet(_steps))

    lo = benches.add_parser(
        "loop", help="fixed-encoder epochs with trainer.loop=batch and =epoch",
        description="Fixed-encoder cells of Table 1 trained with Lightning's per-batch loop and with the per-epoch "
        "loop, alternately: the median epoch time of each and whether both end with the same test accuracy.")
    lo.add_argument("--epochs", type=int, default=3, help="epochs per run (the first of each is warm-up, not timed)")
    _timing(lo, 5)
    command(lo, _quiet(_loop))


def _encoders(p: argparse.ArgumentParser) -> None:
    p.add_argument("--encoders", metavar="A,B", help="comma-separated encoders (default: every built-in)")


def _measurement(p: argparse.ArgumentParser) -> None:
    """What the fidelity measurement covers (``fidelity``; ``auto`` without ``--from-csv``)."""
    p.add_argument("--presets", metavar="A,B", help="comma-separated presets (default: reference,default,fast)")
    p.add_argument("--digits", type=int, default=256, help="test digits the embedding error is measured on")
    p.add_argument("--sweep", action=argparse.BooleanOptionalAction, default=True, help="sweep each knob alone")
    p.add_argument("--truth-grid", default="3040x4056", metavar="HxW", help="finest grid of the truth (the sensor)")
    p.add_argument("--encode-count", type=int, default=10000, help="digits encoded for the fixed encoders' encode time")


def _speed_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeats", type=int, default=5, help="interleaved repeats per thread count")
    p.add_argument("--threads", default="1,2", metavar="N,M", help="torch thread counts timed (e.g. 1 on a shared machine)")


def _timing(p: argparse.ArgumentParser, repeats: int) -> None:
    p.add_argument("--repeats", type=int, default=repeats, help="interleaved repeats")
    p.add_argument("--threads", type=int, default=1, metavar="N", help="torch threads")


def _choice_options(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--tolerance", type=float, default=0.01, help=f"{what} (0.01 = 1%%)")
    p.add_argument("--safety", type=float, default=1.0, help="require error * safety <= tolerance")


def _quiet(handler):
    """``handler`` with Lightning's console chatter off (several benchmarks train runs)."""

    def run(args, extra) -> int:
        quiet_lightning()
        return handler(args, extra)

    return run


def _list(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 0


def _thread_counts(text: str) -> tuple[int, ...]:
    """``--threads N,M``: positive thread counts, or a ConfigError."""
    try:
        out = tuple(int(v) for v in names(text))
    except ValueError:
        out = ()
    if not out or min(out) < 1:
        raise ConfigError("--threads", text, "comma-separated thread counts >= 1, e.g. 1,2")
    return out


def _threads(n: int) -> int:
    if n < 1:
        raise ConfigError("--threads", n, "must be >= 1")
    return n


def _encoder_names(args):
    from .. import bench

    return names(args.encoders) if args.encoders else bench.ENCODERS


class _Bar:
    """The progress bar on stderr (none when stderr is not a terminal), as a ``progress(done, total, what)``."""

    def __init__(self):
        from tqdm.auto import tqdm

        self.bar = tqdm(total=1, desc="bench", unit="step", file=sys.stderr, disable=None, leave=False)

    def __call__(self, done: int, total: int, what: str) -> None:
        self.bar.total = total
        self.bar.n = done
        self.bar.set_description(what)
        self.bar.refresh()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.bar.close()


def _measured(compute, table, *, before: tuple[str, ...] = (), csv=None):
    """What every benchmark command prints: the machine's load, ``before``, a progress bar around
    ``compute(bar)``, the rows' table (``table(rows)``), the load again and, with ``csv``, the path
    ``csv(rows)`` wrote. Returns the rows."""
    from ..bench.machine import load_line

    print(load_line("start"))
    for line in before:
        print(line)
    with _Bar() as bar:
        rows = compute(bar)
    print(table(rows))
    print(load_line("end"))
    if csv is not None:
        print(csv(rows))
    return rows


def _optics(args, extra) -> int:
    from ..bench import optics

    _measured(lambda bar: optics.run(), optics.format_table)
    return 0


def _converge(args, extra) -> int:
    from ..bench import converge

    encoders = _encoder_names(args)
    _measured(lambda bar: converge.study(encoders, digits=args.digits, progress=bar), converge.format_table,
              csv=None if args.out is None else lambda rows: converge.write_csv(rows, Path(args.out) / "converge.csv"))
    return 0


def _precision(args, extra) -> int:
    from ..bench import precision
    from ..hardware import native_bfloat16

    threads = _threads(args.threads)
    encoders = _encoder_names(args)
    emb = parse_hw("--embedding", args.embedding, "24x32")
    shape = parse_hw("--scene-shape", args.scene_shape, "109x146") if args.scene_shape else None
    _measured(lambda bar: precision.compare(encoders, emb, shape, repeats=args.repeats, threads=threads, progress=bar),
              precision.format_table,
              before=(f"native bfloat16 products on this CPU (AMX or AVX512-BF16): {'yes' if native_bfloat16('cpu') else 'no'}",),
              csv=None if args.out is None else lambda rows: precision.write_csv(rows, Path(args.out) / "precision.csv"))
    return 0


def _steps(args, extra) -> int:
    from ..bench import steps

    threads = _threads(args.threads)
    if not args.spec:
        raise ConfigError("--spec", None, "required by `optoenc bench steps` (a sweep spec, e.g. examples/paper/table3.yaml)")
    def compute(bar):
        rows = steps.time_steps(args.spec, args.only, repeats=args.repeats, threads=threads, progress=bar)
        if args.only and not rows:
            raise ConfigError("--only", ",".join(args.only), "matches no cell of the spec")
        return rows

    _measured(compute, steps.format_table)
    return 0


def _loop(args, extra) -> int:
    from ..bench import loop

    threads = _threads(args.threads)
    if args.epochs < 2 or args.repeats < 1:
        raise ConfigError("--epochs" if args.epochs < 2 else "--repeats", args.epochs if args.epochs < 2 else args.repeats,
                          "--epochs >= 2 (the first is warm-up) and --repeats >= 1")
    _measured(lambda bar: loop.compare(epochs=args.epochs, repeats=args.repeats, threads=threads, progress=bar),
              lambda rows: loop.format_table(rows, threads))
    return 0


def _tasks(args, extra) -> int:
    from ..bench import speed

    if args.repeats < 1 or args.threads < 1 or args.batch < 2:
        raise ConfigError("--repeats/--threads/--batch", (args.repeats, args.threads, args.batch),
                          "must be >= 1, >= 1 and >= 2")
    _measured(lambda bar: speed.task_steps(args.encoder, args.decoder, threads=args.threads, repeats=args.repeats,
                                           batch=args.batch, progress=bar), speed.format_task_steps)
    return 0


def _speed(args, extra) -> int:
    from ..bench import speed

    threads = _thread_counts(args.threads)
    _measured(lambda bar: speed.interleaved(args.encoder, "default", threads=threads, repeats=args.repeats, progress=bar),
              speed.format_speed)
    return 0


def _measure_kw(args) -> dict:
    """The options of the fidelity measurement, as :func:`optoenc.bench.run` takes them."""
    from .. import bench

    return dict(
        presets=names(args.presets) if args.presets else bench.PRESETS,
        digits=args.digits,
        sweep=args.sweep,
        truth_grid=parse_hw("--truth-grid", args.truth_grid, "1520x2028"),
        encode_count=args.encode_count,
        truth_dir=None if args.out is None else Path(args.out) / "truth",
    )


def _auto(args, extra) -> int:
    from .. import bench

    kw = _measure_kw(args)
    if not args.encoder:
        raise ConfigError("--encoder", None, "required by `optoenc bench auto` (e.g. --encoder learned_slm)")
    with _Bar() as bar:
        choice = bench.auto_select(
            args.encoder, args.tolerance, args.from_csv, safety=args.safety, progress=bar,
            **({} if args.from_csv else kw),
        )
    f = choice.fidelity.resolved()
    print(f"auto {args.encoder} @ tolerance {100 * args.tolerance:g}%: {choice.describe()}")
    print(f"  --fidelity.preset={choice.fidelity.preset} --fidelity.grid={list(f['grid'])} "
          f"--fidelity.dtype={f['dtype']} --fidelity.padding={f['padding']} "
          f"--fidelity.psf_oversample={f['psf_oversample']}")
    print(f"  ({choice.considered} measured settings considered; rejected by the sampling diagnostics: "
          f"{', '.join(choice.rejected) or 'none'})")
    return 0


def _fidelity(args, extra) -> int:
    from .. import bench
    from ..bench.machine import load_line, peak_rss_gb

    threads = _thread_counts(args.threads)  # checked before anything is measured
    encoders = _encoder_names(args)
    kw = _measure_kw(args)
    kw["paper_grid"] = parse_hw("--paper-grid", args.paper_grid, "1520x2028")
    out = Path(args.out) if args.out else None
    report: list[str] = []

    def say(text: str = "") -> None:  # printed now, and kept for --docs
        print(text, flush=True)
        report.append(text)

    started, t0 = time.strftime("%Y-%m-%d %H:%M %Z"), time.perf_counter()
    docs = Path(args.docs) if args.docs else None
    if docs is not None:
        from ..bench import docs as docs_mod

        docs_mod.check_docs(docs)  # fail before an hour of measuring, not after
    say(load_line("start"))
    everything = bench.encode_all() if args.encode_all else None  # first: everything cold
    with _Bar() as bar:
        rows = bench.run(encoders, paper=args.paper, progress=bar, **kw)
    speed_res = None
    if args.speed and args.paper and "learned_slm" in encoders:
        from ..bench import speed

        speed_res = speed.interleaved("learned_slm", "default", threads=threads, repeats=args.repeats)
    autos = {}
    for enc in encoders:
        try:
            autos[enc] = bench.choose(rows, enc, args.tolerance, args.safety)
        except ConfigError as err:
            autos[enc] = err.allowed
    say(bench.format_table(rows))
    if args.sweep:
        say("\nEach knob alone from `default` (cost: learned encoders per training step, fixed per 10,000 digits):")
        say(bench.format_sweep(rows))
    if speed_res is not None:
        from ..bench.speed import format_speed

        say()
        say(format_speed(speed_res))
    say()
    say(bench.format_outcomes(bench.outcomes(rows, everything, autos, speed=speed_res)))
    say(load_line("end"))
    peak = peak_rss_gb()
    if peak is not None:
        say(f"peak resident memory: {peak:.1f} GB")
    if out is not None:
        print(bench.write_csv(rows, out / "bench.csv"))
        print(bench.save_pareto(rows, out / "pareto.png"))
    if docs is not None:
        print(bench.write_csv(rows, docs / "bench" / "bench.csv"))
        print(bench.save_pareto(rows, docs / "bench" / "pareto.png"))
        command_line = shlex.join(["optoenc", *getattr(args, "argv", ["bench", "fidelity"])])
        run = docs_mod.run_block("\n".join(report), command_line, started, time.perf_counter() - t0, peak, os.cpu_count())
        for path in docs_mod.update_docs(docs, {
            "benchmarks.md": {"run": run, "targets": docs_mod.targets_block(rows, speed_res)},
            "fidelity.md": {"overrides": docs_mod.overrides_block(rows)},
        }):  # fmt: skip
            print(path)
    return 0
