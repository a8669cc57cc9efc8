"""Run directories and atomic file writes: nothing half-written is ever left behind."""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["atomic_write_bytes", "atomic_write_text", "write_json", "new_run_dir", "RUN_FILES"]

#: What a run directory holds.
RUN_FILES = {
    "config": "config.yaml",
    "metrics": "metrics.csv",
    "summary": "summary.json",
    "checkpoints": "checkpoints",
    "pictures": "pictures",
}


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def new_run_dir(root: str | Path, name: str | None, stem: str) -> Path:
    """Create ``root/name`` (or ``root/<stem>-<timestamp>``), never reusing an existing folder."""
    root = Path(root)
    base = name or f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, k = root / base, 1
    while path.exists():
        k += 1
        path = root / f"{base}-{k}"
    path.mkdir(parents=True)
    return path
