"""Upper bounds on sizes, derived from this machine: a setting that cannot fit fails up front, in one line.

A simulation grid of 30000 x 40000 or 100,000 torch threads do not fail
gracefully later (MemoryError, or a crash inside a library): they are
refused when the run is built, saying how much they need and how much there is.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

from .errors import ConfigError

__all__ = ["memory_bytes", "max_threads", "check_threads", "torch_threads", "simulation_bytes", "check_simulation"]

#: Threads per CPU core allowed for ``trainer.threads`` (oversubscription beyond this only slows a run down,
#: and every thread reserves stack memory).
THREADS_PER_CORE = 4
_GIB = 2.0**30


def memory_bytes() -> int:
    """Physical memory of this machine, bytes (a large value if it cannot be read)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 1 << 50


def max_threads() -> int:
    """The largest ``trainer.threads`` accepted here: :data:`THREADS_PER_CORE` x the CPU cores."""
    return THREADS_PER_CORE * (os.cpu_count() or 1)


def check_threads(key: str, value: int | None) -> None:
    """Refuse a thread count above :func:`max_threads`."""
    if value is not None and value > max_threads():
        raise ConfigError(
            key, value, f"must be <= {max_threads()} ({THREADS_PER_CORE} x the {os.cpu_count()} CPU cores of this machine)"
        )


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Within the block torch uses ``n`` (at least 1) intra-op threads; the previous count is restored after."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(max(1, int(n)))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def simulation_bytes(grid: tuple[int, int], dtype: str, padding, oversample: int, channels: int = 3) -> int:
    """A lower bound on the memory one PSF simulation needs, bytes.

    One complex wave field per wavelength on the padded, oversampled grid:
    ``channels x (H s (1 + 2p)) x (W s (1 + 2p)) x 2 x itemsize`` (``p`` the
    padding fraction per side, 0 for ``auto``'s smallest case). The real
    simulation needs several such arrays, so a grid refused here can never run.
    """
    item = 8 if dtype == "float64" else 4
    pad = 0.0 if padding in (None, "auto") else float(padding)
    rows, cols = (n * oversample * (1 + 2 * pad) for n in grid)
    return int(channels * rows * cols * 2 * item)


def check_simulation(knobs, key: str = "fidelity.grid") -> None:
    """Refuse fidelity knobs whose simulation cannot fit in this machine's memory (naming ``key`` and the need)."""
    need, have = simulation_bytes(knobs.grid, knobs.dtype, knobs.padding, knobs.psf_oversample), memory_bytes()
    if need > have:
        raise ConfigError(
            key,
            list(knobs.grid),
            f"needs at least {need / _GIB:.1f} GiB for one {knobs.dtype} PSF simulation (3 wavelengths, "
            f"psf_oversample {knobs.psf_oversample}, padding {knobs.padding}); this machine has {have / _GIB:.1f} GiB",
        )
