"""The machine a benchmark ran on: its load average (it may be shared) and this process's peak memory."""

from __future__ import annotations

import os
import sys

__all__ = ["load_line", "peak_rss_gb"]


def load_line(when: str) -> str:
    """``load average (when): 1.23 0.98 0.76 (1, 5, 15 min) on N cores``."""
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
