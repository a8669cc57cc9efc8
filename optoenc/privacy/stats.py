"""Confidence intervals of the measured rates (re-identification, readability).

A rate measured on ``n`` probes is reported with its Wilson score interval
(Wilson 1927): unlike the normal approximation ``p +- z sqrt(p (1 - p) / n)``
it is not degenerate at 0 % and 100 % (0 hits out of 1,000 probes gives
[0, 0.38 %], not "0 +- 0") and it keeps close to its nominal coverage for
small ``n`` and rates near the ends.
"""

from __future__ import annotations

import math
from statistics import NormalDist

from ..errors import ConfigError

__all__ = ["wilson"]


def wilson(rate: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """``(low, high)``: the Wilson score interval of a rate ``rate`` (hits / n) measured on ``n`` trials.

    ``center = (p + z^2 / 2n) / (1 + z^2 / n)``, ``half width = z / (1 + z^2 / n) * sqrt(p (1 - p) / n + z^2 / 4n^2)``
    with ``z`` the two-sided normal quantile of ``confidence`` (1.95996 for 95 %). ``rate`` may be a mean of
    per-probe fractions (e.g. hits averaged over attacker seeds): their variance is at most ``p (1 - p)``, so the
    interval is then conservative for the probes' sampling.

    Raises:
        ConfigError: ``n < 1``, a rate outside [0, 1] or a confidence outside (0, 1).
    """
    if n < 1:
        raise ConfigError("probes", n, "must be >= 1 for a confidence interval")
    if not 0.0 <= rate <= 1.0:
        raise ConfigError("rate", rate, "must be in [0, 1]")
    if not 0.0 < confidence < 1.0:
        raise ConfigError("confidence", confidence, "must be in (0, 1)")
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    z2n = z * z / n
    center = (rate + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * math.sqrt(rate * (1 - rate) / n + z2n / (4 * n))
    return max(0.0, center - half), min(1.0, center + half)
