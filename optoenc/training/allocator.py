"""Freed memory kept for reuse, for the command line's processes (the library leaves the allocator alone).

glibc's malloc hands every block above its mmap threshold (at most 32 MB) to
the kernel with ``mmap`` and returns it with ``munmap`` when freed, and it
trims freed memory at the top of its heap back to the kernel. A learned
encoder on an augmentation canvas allocates and frees tens of MB every step
(Table 3's 24x32 operator is 49 MB, its gradient as much again): each fresh
block costs a page fault per 4 KB page on first touch, and zeroing a freshly
mapped 49 MB tensor took 24 ms instead of 1.5 ms on the AMD EPYC machine,
and Table 3's 24x32 learned training step under shift (its whole-canvas
operator over glibc's 32-MB cap) ran 1.75x faster kept; steps whose blocks
stay under the cap gain nothing (docs/benchmarks.md, "Freed memory kept"). Raising both thresholds keeps freed
memory in the process for the next step's tensors; the process's resident
size stays at its peak, which a training process reaches every step anyway.

``OPTOENC_MALLOC=system`` leaves glibc alone (its defaults, dynamic mmap
threshold included: for comparisons, or a process that must give memory
back). Set it before the process starts: glibc reuses the chunks a process
has kept whatever its thresholds say later, so there is no switching back. Elsewhere than glibc (macOS, Windows,
musl) this does nothing.
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
