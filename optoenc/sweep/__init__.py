"""Sweeps: a base configuration times axes of settings, each cell an ordinary run directory.

``optoenc sweep SPEC.yaml`` (see :mod:`optoenc.sweep.spec` for the format)
runs every unfinished cell (skipping finished ones, resuming interrupted
ones from their last checkpoint, re-running failed ones), in parallel
processes or on a cluster, and collects the results into CSV, markdown and
plots. Usable from Python::

    from optoenc import sweep
    spec = sweep.load_spec("examples/paper/table1.yaml")
    planned = sweep.plan(spec, "sweeps/table1")
    failures = sweep.run(planned, "sweeps/table1", workers=2)
    sweep.write_tables(spec, planned, "sweeps/table1")
"""

from .collect import aggregate, cell_rows, write_tables
from .runner import (EXECUTORS, ORDERS, SKIPPED, STARTS, PlannedCell, cell_threads, claim, longest_first, machine_share,
                     plan, resolve_threads, run, thread_budget)
from .spec import Cell, SweepSpec, load_spec

__all__ = [
    "Cell", "SweepSpec", "load_spec", "PlannedCell", "plan", "run", "thread_budget", "resolve_threads", "EXECUTORS",
    "ORDERS", "STARTS", "SKIPPED", "longest_first", "cell_threads", "claim", "machine_share",
    "cell_rows", "aggregate", "write_tables",
]
