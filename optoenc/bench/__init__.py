"""Benchmarks: speed and accuracy of the simulation settings, side by side (``optoenc bench``).

* :mod:`optoenc.bench.pipeline`: the paper pipeline (speed reference), the
  high-fidelity reference (error reference) and the measurement of every
  preset and single-knob sweep point (:func:`run`), and the cold encoding of
  all of MNIST (:func:`encode_all`);
* :mod:`optoenc.bench.report`: tables, CSV, the Pareto plot, outcome checks;
* :mod:`optoenc.bench.auto`: :func:`auto_fidelity`, the cheapest measured
  setting meeting an error tolerance.

The optics micro-benchmark (batched vs looped wavelengths) is
:mod:`optoenc.bench_optics` (``optoenc bench optics``).
"""

from .auto import AutoChoice, auto_fidelity, auto_select, choose
from .pipeline import ENCODERS, HIFI_GRID, PAPER_GRID, PRESETS, encode_all, paper_forward, plan, run
from .report import format_outcomes, format_sweep, format_table, outcomes, read_csv, save_pareto, write_csv

__all__ = [
    "ENCODERS",
    "PRESETS",
    "PAPER_GRID",
    "HIFI_GRID",
    "run",
    "plan",
    "paper_forward",
    "encode_all",
    "format_table",
    "format_sweep",
    "outcomes",
    "format_outcomes",
    "write_csv",
    "read_csv",
    "save_pareto",
    "AutoChoice",
    "auto_fidelity",
    "auto_select",
    "choose",
]
