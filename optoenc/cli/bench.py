"""``optoenc bench``: what the command does, after the CLI has parsed its arguments.

``fidelity`` (default): :func:`optoenc.bench.pipeline.run`, tables, outcome
checks, CSV and Pareto plot; ``converge``: the convergence study
(:mod:`optoenc.bench.converge`); ``speed``: the interleaved step timing
(:mod:`optoenc.bench.speed`); ``steps``: sweep cells' training steps with and without
support regions (:mod:`optoenc.bench.steps`); ``loop``: fixed-encoder epochs with the
per-batch and the per-epoch training loop (:mod:`optoenc.bench.loop`); ``auto``: the cheapest measured setting;
``optics``: the PSF micro-benchmark. Every report starts and ends with the
machine's load average (the machine may be shared).
"""

from __future__ import annotations

import os
import shlex
import sys
import time
from pathlib import Path

from ..errors import ConfigError
from ..settings import parse_hw

__all__ = ["main", "parse_grid", "load_line", "peak_rss_gb"]


def parse_grid(key: str, text: str) -> tuple[int, int]:
    """``"HxW"`` -> ``(H, W)``, or a ConfigError naming ``key``."""
    return parse_hw(key, text, "1520x2028")


def load_line(when: str) -> str:
    """``load average (when): 1.23 0.98 0.76 on N cores``."""
    try:
        a, b, c = os.getloadavg()
    except OSError:  # pragma: no cover - not on POSIX
        return f"load average ({when}): unknown"
    return f"load average ({when}): {a:.2f} {b:.2f} {c:.2f} (1, 5, 15 min) on {os.cpu_count()} cores"


def peak_rss_gb() -> float | None:
    """This process's peak resident memory so far, GB (None where unknown)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on POSIX
        return None
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kilobytes on Linux
    return kb * (1 if sys.platform != "darwin" else 1 / 1024) / 1e6


def _threads(args) -> tuple[int, ...]:
    """``--threads``: positive thread counts, or a ConfigError."""
    text = getattr(args, "threads", "1,2")
    try:
        out = tuple(int(v) for v in _names(text))
    except ValueError:
        out = ()
    if not out or min(out) < 1:
        raise ConfigError("--threads", text, "comma-separated thread counts >= 1, e.g. 1,2")
    return out


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def main(args) -> int:
    from tqdm.auto import tqdm

    from .. import bench

    if args.what == "optics":
        from . import optics as bench_optics

        print(load_line("start"))
        print(bench_optics.format_table(bench_optics.run()))
        print(load_line("end"))
        return 0
    bar = tqdm(total=1, desc="bench", unit="step", file=sys.stderr, disable=None, leave=False)

    def progress(done: int, total: int, what: str) -> None:
        bar.total = total
        bar.n = done
        bar.set_description(what)
        bar.refresh()

    out = Path(args.out) if args.out else None
    threads = _threads(args)  # checked before anything is measured
    encoders = _names(args.encoders) if args.encoders else bench.ENCODERS
    if args.what == "converge":
        from . import converge

        print(load_line("start"))
        with bar:
            rows = converge.study(encoders, digits=args.digits, progress=progress)
        print(converge.format_table(rows))
        print(load_line("end"))
        if out is not None:
            print(converge.write_csv(rows, out / "converge.csv"))
        return 0
    if args.what == "precision":
        from . import precision

        emb = parse_hw("--embedding", args.embedding, "24x32")
        shape = parse_hw("--scene-shape", args.scene_shape, "109x146") if args.scene_shape else None
        print(load_line("start"))
        from ..hardware import native_bfloat16

        print(f"native bfloat16 products on this CPU (AMX or AVX512-BF16): {'yes' if native_bfloat16('cpu') else 'no'}")
        with bar:
            rows = precision.compare(encoders, emb, shape, repeats=args.repeats, threads=threads[0], progress=progress)
        print(precision.format_table(rows))
        print(load_line("end"))
        if out is not None:
            print(precision.write_csv(rows, out / "precision.csv"))
        return 0
    if args.what == "steps":
        from . import steps

        if not args.spec:
            raise ConfigError("--spec", None, "required by `optoenc bench steps` (a sweep spec, e.g. examples/paper/table3.yaml)")
        print(load_line("start"))
        with bar:
            rows = steps.compare(args.spec, args.only, repeats=args.repeats, threads=threads[0], progress=progress,
                                against=args.against)
        if args.only and not rows:
            raise ConfigError("--only", ",".join(args.only), "matches no cell of the spec")
        print(steps.format_table(rows))
        print(load_line("end"))
        return 0
    if args.what == "loop":
        from . import loop

        if args.epochs < 2 or args.repeats < 1:
            raise ConfigError("--epochs" if args.epochs < 2 else "--repeats", args.epochs if args.epochs < 2 else args.repeats,
                              "--epochs >= 2 (the first is warm-up) and --repeats >= 1")
        print(load_line("start"))
        with bar:
            rows = loop.compare(epochs=args.epochs, repeats=args.repeats, threads=threads[0], progress=progress)
        print(loop.format_table(rows, threads[0]))
        print(load_line("end"))
        return 0
    if args.what == "speed":
        from . import speed

        print(load_line("start"))
        with bar:
            res = speed.interleaved(args.encoder or "learned_slm", "default", threads=threads, repeats=args.repeats,
                                    progress=progress)
        print(speed.format_speed(res))
        print(load_line("end"))
        return 0
    kw = dict(
        presets=_names(args.presets) if args.presets else bench.PRESETS,
        digits=args.digits,
        sweep=args.sweep,
        truth_grid=parse_grid("--truth-grid", args.truth_grid),
        paper_grid=parse_grid("--paper-grid", args.paper_grid),
        encode_count=args.encode_count,
        truth_dir=None if out is None else out / "truth",
    )
    if args.what == "auto":
        if not args.encoder:
            raise ConfigError("--encoder", None, "required by `optoenc bench auto` (e.g. --encoder learned_slm)")
        kw.pop("paper_grid")
        with bar:
            choice = bench.auto_select(
                args.encoder, args.tolerance, args.from_csv, safety=args.safety, progress=progress,
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
    report: list[str] = []

    def say(text: str = "") -> None:  # printed now, and kept for --docs
        print(text, flush=True)
        report.append(text)

    started, t0 = time.strftime("%Y-%m-%d %H:%M %Z"), time.perf_counter()
    docs = Path(args.docs) if getattr(args, "docs", None) else None
    if docs is not None:
        from . import docs as docs_mod

        docs_mod.check_docs(docs)  # fail before an hour of measuring, not after
    say(load_line("start"))
    everything = bench.encode_all() if args.encode_all else None  # first: everything cold
    with bar:
        rows = bench.run(encoders, paper=args.paper, progress=progress, **kw)
    speed_res = None
    if args.speed and args.paper and "learned_slm" in encoders:
        from . import speed

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
        from .speed import format_speed

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
        command = shlex.join(["optoenc", *getattr(args, "argv", ["bench"])])
        run = docs_mod.run_block("\n".join(report), command, started, time.perf_counter() - t0, peak, os.cpu_count())
        for path in docs_mod.update_docs(docs, {
            "benchmarks.md": {"run": run, "targets": docs_mod.targets_block(rows, speed_res)},
            "fidelity.md": {"overrides": docs_mod.overrides_block(rows)},
        }):  # fmt: skip
            print(path)
    return 0
