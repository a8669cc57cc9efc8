"""Run directories and atomic file writes: nothing half-written is ever left behind."""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError

__all__ = ["atomic_write_bytes", "atomic_write_text", "atomic_torch_save", "write_json", "new_run_dir", "remove_if_empty", "RUN_FILES"]

#: What a run directory holds.
RUN_FILES = {
    "config": "config.yaml",
    "metrics": "metrics.csv",
    "summary": "summary.json",
    "checkpoints": "checkpoints",
    "pictures": "pictures",
    "interrupted": "interrupted.json",
    "failed": "failed.json",
}


def _umask() -> int:
    """The process umask (read without changing it where /proc allows)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    old = os.umask(0o022)  # pragma: no cover - no /proc: read by setting and restoring
    os.umask(old)
    return old


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename.

    The file gets the permissions a plain ``open(path, "w")`` would give: those
    of the file it replaces, else ``0o666`` less the umask (``mkstemp``'s
    private ``0o600`` is not kept).

    Raises:
        DataError: ``path`` is a folder, or its folder cannot be created or written.
    """
    path = Path(path)
    if path.is_dir():
        raise DataError(f"{path}: is a folder; give a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    except OSError as err:
        raise DataError(f"{path}: cannot write ({err.strerror or err})") from None
    try:
        mode = path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_umask()
        os.fchmod(fd, mode)
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


def atomic_torch_save(path: str | Path, obj: Any) -> Path:
    """``torch.save(obj)`` to ``path`` atomically (:func:`atomic_write_bytes`)."""
    import io

    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    return atomic_write_bytes(path, buf.getvalue())


def write_json(path: str | Path, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def new_run_dir(root: str | Path, name: str | None, stem: str) -> Path:
    """Create ``root/name`` (or ``root/<stem>-<timestamp>``), never reusing an existing folder.

    Raises:
        ConfigError: ``output.root`` is a file or not writable.
    """
    root = Path(root)
    for parent in (root, *root.parents):
        if parent.exists():
            if not parent.is_dir():
                raise ConfigError("output.root", str(root), f"{parent} is a file, not a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise ConfigError("output.root", str(root), f"cannot create a run directory: {parent} is not writable")
            break
    base = name or f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    path, k = root / base, 1
    while True:
        try:
            path.mkdir(parents=True)
            return path
        except FileExistsError:
            k += 1
            path = root / f"{base}-{k}"
        except OSError as err:
            raise ConfigError("output.root", str(root), f"cannot create a run directory ({err.strerror or err})") from None


def remove_if_empty(path: str | Path) -> None:
    """Remove a run directory that a failed start left empty (never one holding files)."""
    try:
        Path(path).rmdir()
    except OSError:
        pass
