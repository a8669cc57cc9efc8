"""``auto`` fidelity: the cheapest measured setting whose embedding error meets a tolerance.

The candidates are an encoder's measured presets and single-knob sweep points
(:func:`optoenc.bench.pipeline.run`): settings a :class:`FidelityConfig`
can express, on optoenc's default (operator) path. Rejected before choosing:
the paper pipelines and the truth (not candidates), the
one-wavelength point (not a fidelity knob), and every setting whose optics
sampling diagnostics found a problem (wrap-around, band limit, aliased
source or mask phase): its measured error may be right by luck and cannot be
trusted to stay right when the mask changes (a learned encoder) or the
scene does. Among the rest, those with ``error * safety <= tolerance`` are
kept and the one of lowest measured cost wins (ties: the lower error). Cost
is the time per training step for learned encoders, the cold time to encode
10,000 digits for fixed ones.

The measured error is for the benchmark's digits and, for learned encoders,
their initial (seeded) parameters; a ``safety`` factor above 1 leaves room
for training to move the mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from ..encoders.fidelity import FIDELITY_PRESETS, FidelityConfig
from ..errors import ConfigError

__all__ = ["AutoChoice", "candidates", "choose", "auto_select", "auto_fidelity"]


@dataclass(frozen=True)
class AutoChoice:
    """The setting chosen for ``encoder`` at ``tolerance``, with its measured row."""

    encoder: str
    tolerance: float
    fidelity: FidelityConfig
    row: dict
    considered: int
    rejected: tuple[str, ...] = field(default=())

    def describe(self) -> str:
        r = self.row
        grid = "x".join(str(int(n)) for n in r["grid"])
        cost = f"{1e3 * r['step_s']:.1f} ms per training step" if r["learnable"] else (
            f"{r['encode_s']:.2f} s to encode 10,000 digits (cold)")
        return (f"{r['setting']} (grid {grid}, {r['dtype']}, padding {r['padding']}, "
                f"psf_oversample {r.get('psf_oversample', 1)}): error {100 * r['error']:.3f}% vs the truth, {cost}")


def _fidelity(row: dict) -> FidelityConfig:
    """The measured setting of ``row``, every knob explicit (``psf_oversample`` included): what was measured."""
    return FidelityConfig(
        preset=row["setting"] if row["kind"] == "preset" and row["setting"] in FIDELITY_PRESETS else "default",
        grid=tuple(int(n) for n in row["grid"]),
        dtype=row["dtype"],
        padding=str(row["padding"]),
        psf_oversample=int(row.get("psf_oversample") or 1),
        propagation=row["value"] if row.get("knob") == "propagation" else None,
    )


def candidates(rows: Sequence[dict], encoder: str) -> tuple[list[dict], list[str]]:
    """``(usable, rejected)``: ``encoder``'s measured FidelityConfig-expressible rows, and the labels
    rejected by the sampling diagnostics."""
    usable, rejected = [], []
    for r in rows:
        if r["encoder"] != encoder or r["kind"] not in ("preset", "sweep") or int(r["wavelengths"]) != 3:
            continue
        if r.get("error") is None or r.get("cost_s") is None:
            continue
        if not r.get("sampling_ok", True):
            rejected.append(f"{r['setting']} ({r['sampling']})")
            continue
        usable.append(r)
    return usable, rejected


def choose(rows: Sequence[dict], encoder: str, tolerance: float = 0.01, safety: float = 1.0) -> AutoChoice:
    """The cheapest of ``encoder``'s measured settings meeting ``tolerance`` (see the module docstring).

    Raises:
        ConfigError: no measured setting of ``encoder``, or none meets the tolerance.
    """
    if not tolerance > 0:
        raise ConfigError("tolerance", tolerance, "must be > 0 (a relative error, 0.01 = 1%)")
    if not safety >= 1:
        raise ConfigError("safety", safety, "must be >= 1")
    usable, rejected = candidates(rows, encoder)
    if not usable:
        raise ConfigError("encoder", encoder, "no measured setting to choose from (run the benchmark for it)")
    ok = [r for r in usable if r["error"] * safety <= tolerance]
    if not ok:
        best = min(usable, key=lambda r: r["error"])
        raise ConfigError(
            "tolerance", tolerance,
            f"no measured setting of {encoder} meets it; the most accurate is {best['setting']} "
            f"at {100 * best['error']:.3f}%",
        )  # fmt: skip
    row = min(ok, key=lambda r: (r["cost_s"], r["error"]))
    return AutoChoice(encoder, float(tolerance), _fidelity(row), row, len(usable), tuple(rejected))


def auto_select(encoder_name: str, tolerance: float = 0.01, measurements=None, *, safety: float = 1.0,
                **run_kwargs) -> AutoChoice:
    """Like :func:`auto_fidelity`, returning the full :class:`AutoChoice` (measured error and cost)."""
    if measurements is None:
        from .pipeline import run

        rows = run([encoder_name], paper=False, **run_kwargs)
    elif isinstance(measurements, (str, Path)):
        from .report import read_csv

        rows = read_csv(measurements)
    else:
        rows = list(measurements)
    return choose(rows, encoder_name, tolerance, safety)


def auto_fidelity(encoder_name: str, tolerance: float = 0.01, measurements=None, *, safety: float = 1.0,
                  **run_kwargs) -> FidelityConfig:
    """The cheapest measured fidelity setting of ``encoder_name`` whose embedding error is within ``tolerance``.

    Args:
        encoder_name: registry name.
        tolerance: largest relative L2 error of the embeddings against the
            converged truth (0.01 = 1 %).
        measurements: rows of :func:`optoenc.bench.pipeline.run`, or the path
            of a CSV written by ``optoenc bench --out``; ``None`` measures
            now (presets and the sweep, no paper pipeline; ``run_kwargs`` go
            to :func:`~optoenc.bench.pipeline.run`).
        safety: require ``error * safety <= tolerance``.

    Returns:
        A :class:`FidelityConfig` (a preset's name, or explicit knobs).

    Raises:
        ConfigError: when no measured, reliably sampled setting meets the tolerance.
    """
    return auto_select(encoder_name, tolerance, measurements, safety=safety, **run_kwargs).fidelity
