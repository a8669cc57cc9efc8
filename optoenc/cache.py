"""On-disk cache of precomputed (noise-free) embeddings of fixed encoders.

The key hashes everything that affects the embeddings: the encoder's name and
resolved settings, the scene, sensor and fidelity settings, the dataset
settings and file contents, what the encoder declares beyond its settings
(``cache_token()``, e.g. the PSF file's contents) and the source code of the
modules that compute them. Entries are written atomically and carry a
checksum; a corrupt entry is detected, reported and recomputed.
"""

from __future__ import annotations

import hashlib
import inspect
import io
import json
import os
import warnings
import zlib
from pathlib import Path
from typing import Any, Callable

import torch

from .rundir import atomic_write_bytes
from .settings import to_dict

__all__ = ["cache_dir", "embedding_key", "load", "store", "cached"]

ENV = "OPTOENC_CACHE_DIR"
#: Entry header: format tag, then the CRC-32 of the payload (corruption check; the key is the SHA-256).
_MAGIC = b"OPTOENC-EMB1"


def cache_dir(override: str | None = None) -> Path:
    """Cache folder: the setting, else ``$OPTOENC_CACHE_DIR``, else ``~/.cache/optoenc``."""
    root = override or os.environ.get(ENV) or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "optoenc"
    return Path(root) / "embeddings"


def _code_digest(objs: list[Any]) -> str:
    h = hashlib.sha256()
    for obj in objs:
        try:
            h.update(inspect.getsource(obj).encode())
        except (OSError, TypeError):
            h.update(repr(obj).encode())
    return h.hexdigest()


def embedding_key(encoder, dataset_config: Any, dataset_token: str = "") -> str:
    """A hex digest of everything that determines ``encoder``'s embeddings of a dataset."""
    from . import __version__, imaging
    from .encoders import base

    token = encoder.cache_token() if hasattr(encoder, "cache_token") else ""
    material = {
        "version": __version__,
        "encoder": encoder.name,
        "encoder_config": to_dict(encoder.config),
        "scene": to_dict(encoder.scene_config),
        "sensor": to_dict(encoder.sensor),
        "fidelity": encoder.knobs,
        "dataset": to_dict(dataset_config),
        "dataset_token": dataset_token,
        "encoder_token": token,
        "state": {k: hashlib.sha256(v.detach().cpu().contiguous().numpy().tobytes()).hexdigest() for k, v in encoder.state_dict().items()},
        "code": _code_digest([imaging, base, type(encoder)]),
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


def cached(key: str, compute: Callable[[], dict[str, torch.Tensor]], root: str | None = None, enabled: bool = True):
    """``load(key)`` if present, else ``compute()`` and store it. Returns ``(tensors, hit)``."""
    if enabled:
        hit = load(key, root)
        if hit is not None:
            return hit, True
    tensors = compute()
    if enabled:
        try:
            store(key, tensors, root)
        except OSError as err:  # a read-only or full disk must not stop a run
            warnings.warn(f"could not write the embedding cache ({err})", stacklevel=2)
    return tensors, False
