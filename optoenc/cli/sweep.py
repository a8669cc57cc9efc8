"""``optoenc sweep``: run a spec's cells (resumable), then collect the tables and plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import ConfigError
from ..training.quiet import quiet_lightning
from .args import command

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``sweep`` to the CLI's subparsers."""
    sw = sub.add_parser("sweep", help="run a sweep spec's cells (resumable), then tables and plots",
                        description="Run every cell of a sweep spec (a base config and axes), each as a run directory "
                        "under the sweep folder; finished cells are kept, so an interrupted sweep resumes. Then "
                        "collect the cells into CSV, markdown tables and plots.")
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
    command(sw, cmd_sweep)


def cmd_sweep(args: argparse.Namespace, extra) -> int:
    from .. import sweep

    spec = sweep.load_spec(args.spec)
    out = Path(args.out or Path("sweeps") / spec.name)
    planned = sweep.plan(spec, out, args.only)
    if args.only and not planned:
        raise ConfigError("--only", ",".join(args.only), "matches no cell (see the names with --dry-run)")
    if args.order not in sweep.ORDERS:
        raise ConfigError("--order", args.order, f"one of {', '.join(sweep.ORDERS)}")
    from ..sweep.launch import resolve_start

    resolve_start(args.start)  # a bad --start is refused before anything runs (each cell's start: sweep.run)
    if args.dry_run or (args.order == "longest" and not args.collect):
        from ..sweep.estimate import estimate

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
                word = "left" if ok and err.startswith(sweep.SKIPPED) else "done" if ok else "FAILED"
                msg = f"{word} {p.cell.name}" + (f": {err}" if err else "")
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
