"""Freed memory kept for reuse, for the command line's processes (the library leaves the allocator alone).

glibc's malloc hands every block above its mmap threshold (at most 32 MB) to the kernel with ``mmap``
and returns it with ``munmap`` when freed, and it trims freed memory at the top of its heap back to the
kernel. A learned encoder on an augmentation canvas allocates and frees tens of MB every step (Table 3's
24x32 whole-canvas operator is 49 MB, its gradient as much again): each fresh block costs a page fault
per 4 KB page on first touch. Raising both thresholds keeps freed memory in the process for the next
step's tensors; the process's resident size stays at its peak, which a training process reaches every
step anyway.

Measured on a 2-core AMD EPYC machine, one torch thread, 8 interleaved pairs of fresh processes: Table
3's learned SLM 24x32 step under shift (transforms drawn once, the paper's protocol) takes 87 ms kept
against 129 ms with glibc's defaults (median over the processes of each one's median step); pair by
pair, the default's fastest step over the kept one's is 1.48x at the median (7 pairs 1.42-1.58x, one
0.85x). The plain learned 24x32 step, whose blocks stay under the cap: 27.0 ms against 27.7 ms (1.01x),
no gain there and no loss.

``OPTOENC_MALLOC=system`` leaves glibc alone (its defaults, dynamic mmap threshold included: for
comparisons, or a process that must give memory back). Set it before the process starts: glibc reuses
the chunks a process has kept whatever its thresholds say later, so there is no switching back.
Elsewhere than glibc (macOS, Windows, musl) this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

__all__ = ["keep_freed_memory", "ENV", "CHOICES"]

ENV = "OPTOENC_MALLOC"
CHOICES = ("keep", "system")
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
_KEEP = {_M_TRIM_THRESHOLD: 2**31 - 1, _M_MMAP_THRESHOLD: 2**31 - 1}  # mallopt takes an int: 2 GiB - 1


def _libc():
    try:
        name = ctypes.util.find_library("c")
        lib = ctypes.CDLL(name) if name else None
        return lib if lib is not None and hasattr(lib, "mallopt") and hasattr(lib, "gnu_get_libc_version") else None
    except OSError:
        return None


def keep_freed_memory(mode: str | None = None) -> bool:
    """Set malloc to keep freed memory (``"keep"``) or leave it alone (``"system"``); None: ``$OPTOENC_MALLOC`` or keep.

    Returns whether glibc's thresholds were set (False for ``"system"``, and where the C library is
    not glibc).

    Raises:
        ConfigError: an unknown mode (one line naming the value and the choices).
    """
    from ..errors import ConfigError

    mode = mode if mode is not None else (os.environ.get(ENV) or "keep")
    if mode not in CHOICES:
        raise ConfigError(ENV, mode, f"must be one of {', '.join(CHOICES)}")
    lib = _libc() if mode == "keep" else None
    if lib is None:
        return False
    return all(lib.mallopt(ctypes.c_int(p), ctypes.c_int(v)) == 1 for p, v in _KEEP.items())
