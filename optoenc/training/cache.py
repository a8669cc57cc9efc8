"""On-disk cache of precomputed (noise-free) embeddings of fixed encoders.

The key is computed from what the embeddings are a function of, never from
source text: the bytes of the PSF the sensor sees (``encoder.psf()``), the
embeddings of a fixed probe batch of scenes (so an encoder that overrides
``measure`` is keyed by what it does), the scene, sensor and fidelity
settings, the encoder's settings and ``cache_token()``, the dataset's
settings and content digest, and the entry format. A change anywhere in the
code the encoder calls (a plugin's module-level helper included) changes the
PSF or the probe embeddings and so the key. Entries are written atomically
and carry a checksum; a corrupt entry is detected, reported and recomputed.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
import zlib
from pathlib import Path
from typing import Any, Callable, Mapping

import torch

from ..errors import DataError
from ..settings import to_dict
from .rundir import atomic_write_bytes

__all__ = ["cache_dir", "embedding_key", "tensor_digest", "load", "store", "cached", "FORMAT"]

ENV = "OPTOENC_CACHE_DIR"
#: Entry header: format tag, then the CRC-32 of the payload (corruption check; the key is the SHA-256).
_MAGIC = b"OPTOENC-EMB1"
#: Version of what an entry holds and how its key is made; bump it when either changes.
FORMAT = 2
#: Digests keep this many bits of each value relative to the tensor's peak: far finer than any
#: physical change, coarse enough that last-bit rounding (thread counts, BLAS) rarely matters
#: (a rounding flip only costs a recomputation, never a stale entry).
_DIGEST_BITS = 40
#: Scenes in the probe batch: a few dataset scenes plus seeded random ones (every pixel lit).
_PROBE = 4
#: Cache folders a write failed in (read-only, full): this process stores nothing more there, and warned once.
_UNWRITABLE: set[str] = set()


def cache_dir(override: str | None = None) -> Path:
    """Cache folder: the setting, else ``$OPTOENC_CACHE_DIR``, else ``~/.cache/optoenc``."""
    root = override or os.environ.get(ENV) or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "optoenc"
    return Path(root) / "embeddings"


def tensor_digest(t: torch.Tensor) -> str:
    """SHA-256 of a tensor's values, quantised to ``_DIGEST_BITS`` bits relative to its peak, and its shape."""
    x = t.detach().to("cpu", torch.float64).contiguous()
    peak = float(x.abs().max()) if x.numel() else 0.0
    h = hashlib.sha256(repr((tuple(x.shape), f"{peak:.12e}")).encode())
    if peak > 0 and x.isfinite().all():
        h.update(torch.round(x / peak * 2.0**_DIGEST_BITS).to(torch.int64).numpy().tobytes())
    else:
        h.update(x.numpy().tobytes())
    return h.hexdigest()


def _probe_scenes(scenes: torch.Tensor | None, channels: int, shape: tuple[int, int]) -> torch.Tensor:
    g = torch.Generator().manual_seed(20240229)
    rand = torch.rand(_PROBE, channels, *shape, generator=g, dtype=torch.float64)
    if scenes is None:
        return rand
    return torch.cat([scenes[:_PROBE].to(torch.float64), rand])


@torch.no_grad()
def embedding_key(encoder, dataset_config: Any, dataset_token: str = "", scenes: torch.Tensor | None = None) -> str:
    """A hex digest of everything that determines ``encoder``'s embeddings of a dataset.

    Args:
        encoder: a fixed (non-learnable) encoder.
        dataset_config: the dataset's settings.
        dataset_token: the dataset's content digest.
        scenes: ``(N, C, h, w)`` scenes of the dataset (the first few are
            encoded as the probe); default a seeded random 28 x 28 batch.
    """
    channels, shape = (1, (28, 28)) if scenes is None else (scenes.shape[1], tuple(scenes.shape[-2:]))
    was_training = encoder.training
    encoder.eval()
    try:
        probe = encoder.measure(_probe_scenes(scenes, channels, shape).to(torch.float32))
        psf = encoder.psf()
    finally:
        encoder.train(was_training)
    token = encoder.cache_token() if hasattr(encoder, "cache_token") else ""
    material = {
        "format": FORMAT,
        "encoder": encoder.name,
        "encoder_config": to_dict(encoder.config),
        "encoder_token": token,
        "scene": to_dict(encoder.scene_config),
        "sensor": to_dict(encoder.sensor),
        "fidelity": encoder.knobs.to_dict(),
        "embedding_shape": list(encoder.output_shape),
        "dataset": to_dict(dataset_config),
        "dataset_token": dataset_token,
        "psf": tensor_digest(psf),
        "probe": tensor_digest(probe),
    }
    blob = json.dumps(material, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()


def _path(key: str, root: str | None) -> Path:
    return cache_dir(root) / f"{key[:2]}" / f"{key}.pt"


def load(key: str, root: str | None = None) -> dict[str, torch.Tensor] | None:
    """The cached tensors for ``key``, or ``None`` (missing or corrupt; corrupt entries are removed)."""
    path = _path(key, root)
    if not path.exists():
        return None
    try:
        raw = path.read_bytes()
        head, payload = raw[: len(_MAGIC) + 8], raw[len(_MAGIC) + 8 :]
        if head != _MAGIC + b"%08x" % zlib.crc32(payload):
            raise ValueError("checksum mismatch")
        return torch.load(io.BytesIO(payload), map_location="cpu", weights_only=True)
    except Exception as err:
        warnings.warn(f"corrupt embedding cache entry {path} ({err}); recomputing", stacklevel=2)
        path.unlink(missing_ok=True)
        return None


def store(key: str, tensors: dict[str, torch.Tensor], root: str | None = None) -> Path:
    """Write ``tensors`` for ``key`` atomically (header with the payload's CRC-32, then the payload)."""
    buf = io.BytesIO()
    torch.save({k: v.contiguous() for k, v in tensors.items()}, buf)
    payload = buf.getvalue()
    return atomic_write_bytes(_path(key, root), _MAGIC + b"%08x" % zlib.crc32(payload) + payload)


def _mismatch(tensors: Any, expect: Mapping[str, int] | None) -> str:
    """Why a loaded entry cannot be what was asked for ("" if it can): not tensors, other keys, other lengths."""
    if not isinstance(tensors, dict) or not all(isinstance(v, torch.Tensor) for v in tensors.values()):
        return "not a mapping of tensors"
    if expect is None:
        return ""
    if set(tensors) != set(expect):
        return f"holds {sorted(tensors)}, expected {sorted(expect)}"
    bad = [k for k, n in expect.items() if tensors[k].dim() == 0 or len(tensors[k]) != n]
    return f"wrong number of examples in {bad}" if bad else ""


def cached(
    key: str,
    compute: Callable[[], dict[str, torch.Tensor]],
    root: str | None = None,
    enabled: bool = True,
    expect: Mapping[str, int] | None = None,
):
    """``load(key)`` if present, else ``compute()`` and store it. Returns ``(tensors, hit)``.

    Args:
        expect: ``{name: number of examples}`` the entry must hold; an entry
            with a valid checksum but other names or lengths (crafted, or
            written by other code) is treated as corrupt: removed and recomputed.
    """
    if enabled:
        hit = load(key, root)
        why = _mismatch(hit, expect) if hit is not None else ""
        if why:
            warnings.warn(f"corrupt embedding cache entry {_path(key, root)} ({why}); recomputing", stacklevel=2)
            _path(key, root).unlink(missing_ok=True)
        elif hit is not None:
            return hit, True
    tensors = compute()
    folder = str(cache_dir(root))
    if enabled and folder not in _UNWRITABLE:
        try:
            store(key, tensors, root)
        except (OSError, DataError) as err:  # a read-only or full disk must not stop a run: it runs without the cache
            _UNWRITABLE.add(folder)
            warnings.warn(
                f"the embedding cache cannot be written, running without it ({err}); set {ENV} or trainer.cache_dir "
                "to a writable folder, or trainer.cache=false",
                stacklevel=2,
            )
    return tensors, False
