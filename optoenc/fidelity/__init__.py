"""Fidelity: how finely the optics are simulated, and choosing it. One domain.

* :mod:`optoenc.fidelity.knobs`: :class:`FidelityConfig` (the settings
  section), :class:`Knobs` (the frozen typed setting encoders read),
  :data:`FIDELITY_PRESETS` (the one table of presets);
* :mod:`optoenc.fidelity.choose`: the cheapest measured setting whose
  embedding error meets a tolerance (``optoenc bench auto``,
  :func:`~optoenc.fidelity.choose.auto_fidelity`), from the rows the
  benchmark (:mod:`optoenc.bench.pipeline`) measures;
* :mod:`optoenc.fidelity.auto`: ``fidelity.preset=auto`` for a run: measure
  once per encoder configuration, cache the decision, return explicit knobs.

Only the light names of :mod:`~optoenc.fidelity.knobs` are imported here:
encoders import this domain, and choosing a setting needs the benchmark,
which needs the encoders.
"""

from .knobs import FIDELITY_PRESETS, KNOB_NAMES, FidelityConfig, Knobs, parse_padding

__all__ = ["FidelityConfig", "Knobs", "FIDELITY_PRESETS", "KNOB_NAMES", "parse_padding"]
