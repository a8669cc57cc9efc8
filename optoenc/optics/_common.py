"""Shared helpers of :mod:`optoenc.optics`: argument conversion and validation, FFT sizes, the cache."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from threading import Lock

import torch

from ..errors import ConfigError

__all__ = [
    "as_spacing",
    "as_real",
    "tensor_key",
    "check_broadcast",
    "safe_sqrt",
    "next_fast_size",
    "LRUCache",
    "CACHE",
    "cache_info",
    "clear_cache",
]


def as_spacing(spacing) -> tuple[float, float]:
    """``(dy, dx)`` in metres from a float or a pair; validated (> 0, finite)."""
    if isinstance(spacing, torch.Tensor):
        spacing = spacing.detach().cpu().tolist()
    try:
        pair = (float(spacing), float(spacing)) if isinstance(spacing, (int, float)) else tuple(float(s) for s in spacing)
    except (TypeError, ValueError):
        pair = ()
    if len(pair) != 2 or not all(math.isfinite(s) and s > 0 for s in pair):
        raise ConfigError("spacing", spacing, "must be a positive float or a (dy, dx) pair, in metres")
    return pair


def as_real(value, name: str, device=None, positive: bool = False, allow_inf: bool = False) -> torch.Tensor:
    """A float64 tensor view of a float, sequence or tensor (gradients flow through)."""
    if isinstance(value, torch.Tensor):
        if value.is_complex():
            raise ConfigError(name, value, "must be real")
        t = value.to(device=device if device is not None else value.device, dtype=torch.float64)
    else:
        try:
            t = torch.as_tensor(value, dtype=torch.float64, device=device)
        except (TypeError, ValueError, RuntimeError):
            raise ConfigError(name, value, "must be a number, a sequence of numbers or a real tensor") from None
    v = t.detach()
    bad = torch.isnan(v) | (torch.isinf(v) if not allow_inf else torch.isneginf(v))
    if positive:
        bad |= v <= 0
    if v.numel() == 0 or bool(bad.any()):
        allowed = "must be " + ("> 0" if positive else "finite") + (" (or inf)" if allow_inf else "") + ", in metres"
        raise ConfigError(name, value if not isinstance(value, torch.Tensor) else v.cpu().tolist(), allowed)
    return t


def tensor_key(t: torch.Tensor) -> tuple:
    """Hashable key of a tensor's values and shape (for caches)."""
    return (tuple(t.shape), tuple(t.detach().reshape(-1).cpu().tolist()))


def check_broadcast(name: str, shape: Sequence[int], lead: Sequence[int]) -> None:
    """Raise unless ``shape`` broadcasts against the field's leading ``lead`` without adding dims."""
    lead = tuple(lead)
    try:
        ok = torch.broadcast_shapes(tuple(shape), lead) == lead
    except RuntimeError:
        ok = False
    if not ok:
        raise ConfigError(
            name, tuple(shape), f"shape must broadcast against the field's leading dimensions {lead} (e.g. (C,) for (C, H, W))"
        )


def safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """``sqrt(max(x, 0))`` with a finite (zero) gradient at and below zero."""
    pos = x > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, x, torch.ones_like(x))), torch.zeros_like(x))


def next_fast_size(n: int) -> int:
    """Smallest ``2^a 3^b 5^c >= n`` (an FFT-friendly size)."""
    m = max(int(n), 1)
    while True:
        r = m
        for p in (2, 3, 5):
            while r % p == 0:
                r //= p
        if r == 1:
            return m
        m += 1


class LRUCache:
    """A small thread-safe LRU cache of tensors, bounded in entries and bytes."""

    def __init__(self, maxsize: int = 16, maxbytes: int = 512 * 2**20):
        self.maxsize, self.maxbytes = maxsize, maxbytes
        self._data: OrderedDict = OrderedDict()
        self._lock = Lock()
        self.hits = self.misses = 0

    @staticmethod
    def _nbytes(value) -> int:
        items = value if isinstance(value, tuple) else (value,)
        return sum(v.numel() * v.element_size() for v in items if isinstance(v, torch.Tensor))

    def get(self, key):
        with self._lock:
            if key in self._data:
                self._data.move_to_end(key)
                self.hits += 1
                return self._data[key]
            self.misses += 1
            return None

    def put(self, key, value) -> None:
        with self._lock:
            self._data[key] = value
            self._data.move_to_end(key)
            while len(self._data) > self.maxsize or (
                len(self._data) > 1 and sum(self._nbytes(v) for v in self._data.values()) > self.maxbytes
            ):
                self._data.popitem(last=False)

    def clear(self) -> None:
        with self._lock:
            self._data.clear()
            self.hits = self.misses = 0

    def info(self) -> dict:
        with self._lock:
            return {
                "entries": len(self._data),
                "bytes": sum(self._nbytes(v) for v in self._data.values()),
                "hits": self.hits,
                "misses": self.misses,
                "maxsize": self.maxsize,
                "maxbytes": self.maxbytes,
            }


#: Shared cache of transfer functions, their distance-independent parts and source fields.
CACHE = LRUCache()


def cache_info() -> dict:
    """Entries, bytes, hits and misses of the transfer-function / source cache."""
    return CACHE.info()


def clear_cache() -> None:
    """Empty the transfer-function / source cache."""
    CACHE.clear()
