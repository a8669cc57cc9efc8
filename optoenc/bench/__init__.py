"""Benchmarks: speed and accuracy of the simulation settings, side by side (``optoenc bench``).

* :mod:`optoenc.bench.settings`: the shared settings (what is measured, an
  encoder at a setting, its embeddings and their error);
* :mod:`optoenc.bench.pipeline`: the measurement of every preset and
  single-knob sweep point against the truth, beside the paper's pipeline
  (:func:`run`), and the cold encoding of all of MNIST (:func:`encode_all`);
* :mod:`optoenc.bench.truth`: the error reference, computed without the
  encoders' wave-field grid where possible (Fresnel integrals of rectangles,
  the lens's analytic PSF), with its own estimated error;
* :mod:`optoenc.bench.converge`: the convergence study behind it
  (``optoenc bench converge``);
* :mod:`optoenc.bench.published`: the paper's pipeline as published (the
  ``paper`` rows, the speed reference);
* :mod:`optoenc.bench.speed`: the learned SLM's step against the published
  paper step, interleaved, 1 and 2 threads (``optoenc bench speed``);
* :mod:`optoenc.bench.report`: tables, CSV, the Pareto plot, outcome checks;
* :mod:`optoenc.bench.choose`: the cheapest measured setting meeting an
  error tolerance (:func:`auto_fidelity`);
* :mod:`optoenc.bench.auto`: ``fidelity.preset=auto`` for a run: measured
  once per encoder configuration, the decision cached.

The optics micro-benchmark (batched vs looped wavelengths) is
:mod:`optoenc.bench.optics` (``optoenc bench optics``).
"""

from .choose import AutoChoice, auto_fidelity, auto_select, choose
from .pipeline import encode_all, paper_forward, plan, run
from .report import format_outcomes, format_sweep, format_table, outcomes, read_csv, save_pareto, write_csv
from .settings import ENCODERS, PAPER_GRID, PRESETS, TRUTH_GRID

__all__ = [
    "ENCODERS",
    "PRESETS",
    "PAPER_GRID",
    "TRUTH_GRID",
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
