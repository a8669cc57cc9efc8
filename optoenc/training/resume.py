"""The resume contract: what may change when a run continues or is evaluated, and checkpoints read safely.

``optoenc fit --resume RUN`` continues the epochs of one configuration. The
stored ``config.yaml`` is compared with the new one: only the keys in
:data:`SAFE_ON_RESUME` may differ (how long, how fast, how verbosely); any
other difference is refused, naming every changed key, because the epochs
would silently mix two configurations. ``optoenc test | validate | export
--run RUN`` may change how the trained model is evaluated, but not the model
(:data:`FIXED_ON_EVALUATE`). Checkpoints are read here first, so a missing or
truncated file is a one-line error naming it and nothing is written before
the restore is known to work.
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import signal
import threading
import time
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError, Interrupted
from .rundir import RUN_FILES, write_json

__all__ = [
    "SAFE_ON_RESUME",
    "FIXED_ON_EVALUATE",
    "changed_keys",
    "check_resume",
    "check_evaluate",
    "read_checkpoint",
    "mark_interrupted",
    "clear_interrupted",
    "mark_failed",
    "raise_on_signals",
    "interrupted_note",
]

#: Keys ``fit --resume`` may change (glob patterns): none changes what an epoch computes.
SAFE_ON_RESUME = (
    "trainer.max_epochs",
    "trainer.threads",
    "trainer.progress",
    "trainer.cache",
    "trainer.cache_dir",
    "trainer.verify_preset",
    "trainer.test_every_epoch",
    "trainer.limit_test_batches",
    "trainer.logger",
    "trainer.mlflow_uri",
    "output.*",
)
#: Keys ``test | validate | export --run`` may not change (glob patterns): they define the trained model.
FIXED_ON_EVALUATE = (
    "encoder.*",
    "decoder.*",
    "scene.*",
    "augment.*",
    "sensor.pixel_pitch",
    "sensor.resolution",
    "sensor.embedding",
    "sensor.color",
)


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    from omegaconf import OmegaConf

    node = OmegaConf.to_container(tree, resolve=True) if not isinstance(tree, (dict, list)) else tree
    out: dict[str, Any] = {}
    if isinstance(node, dict):
        for k, v in node.items():
            key = f"{prefix}.{k}" if prefix else str(k)
            out.update(_flat(v, key) if isinstance(v, dict) and v else {key: v})
    return out


def changed_keys(old_tree: Any, new_tree: Any) -> dict[str, tuple[Any, Any]]:
    """``{dotted key: (old, new)}`` for every leaf that differs (``<absent>`` where one side lacks it)."""
    a, b = _flat(old_tree), _flat(new_tree)
    missing = "<absent>"
    return {k: (a.get(k, missing), b.get(k, missing)) for k in sorted(set(a) | set(b)) if a.get(k, missing) != b.get(k, missing)}


def _matches(key: str, patterns) -> bool:
    return any(fnmatch.fnmatchcase(key, p) for p in patterns)


def _describe(changes: dict[str, tuple[Any, Any]]) -> str:
    return "; ".join(f"{k}: {a!r} -> {b!r}" for k, (a, b) in changes.items())


def check_resume(run_dir: Path, old_tree: Any, new_tree: Any) -> None:
    """Refuse a resume that changes anything but :data:`SAFE_ON_RESUME`, naming the keys."""
    bad = {k: v for k, v in changed_keys(old_tree, new_tree).items() if not _matches(k, SAFE_ON_RESUME)}
    if bad:
        raise ConfigError(
            "--resume",
            str(run_dir),
            f"cannot continue with changed settings ({_describe(bad)}): the epochs would mix two configurations; "
            f"only {', '.join(SAFE_ON_RESUME)} may change on resume (start a new run for the others)",
        )


def check_evaluate(run_dir: Path, old_tree: Any, new_tree: Any) -> None:
    """Refuse evaluating a run with settings that change its trained model (:data:`FIXED_ON_EVALUATE`)."""
    bad = {k: v for k, v in changed_keys(old_tree, new_tree).items() if _matches(k, FIXED_ON_EVALUATE)}
    if bad:
        raise ConfigError(
            "--run",
            str(run_dir),
            f"the checkpoint was trained with other settings ({_describe(bad)}); the encoder, decoder, scene, "
            "augmentations and sensor geometry of a trained run cannot change (train a new run)",
        )


def read_checkpoint(path: Path, what: str = "checkpoint") -> dict:
    """A Lightning checkpoint, read fully; a missing, truncated or foreign file is a one-line DataError naming it."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: missing ({what})")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:
        msg = (str(err).strip().splitlines() or [type(err).__name__])[0].split(". ")[0]
        raise DataError(f"{path}: unreadable, truncated or corrupt ({what}; {msg})") from None
    if not isinstance(ckpt, dict) or not {"state_dict", "epoch"} <= set(ckpt):
        raise DataError(f"{path}: not an optoenc checkpoint (no state_dict / epoch)")
    return ckpt


def mark_interrupted(run_dir: Path, signal_name: str, epoch: int, resume_command: str) -> Path:
    """Write ``interrupted.json`` into the run directory (removed when the run completes)."""
    (Path(run_dir) / RUN_FILES["failed"]).unlink(missing_ok=True)
    return write_json(
        Path(run_dir) / RUN_FILES["interrupted"],
        {"signal": signal_name, "epoch": epoch, "time": time.strftime("%Y-%m-%d %H:%M:%S"), "resume": resume_command},
    )


def clear_interrupted(run_dir: Path) -> None:
    """Remove the run's ``interrupted.json`` and ``failed.json`` markers (the run completed)."""
    for marker in ("interrupted", "failed"):
        (Path(run_dir) / RUN_FILES[marker]).unlink(missing_ok=True)


def mark_failed(run_dir: Path, err: BaseException, epoch: int) -> Path:
    """Write ``failed.json`` into the run directory: the error that stopped training (removed when the run completes).

    Args:
        epoch: the 0-based epoch in progress when the run failed.
    """
    (Path(run_dir) / RUN_FILES["interrupted"]).unlink(missing_ok=True)
    line = (str(err).strip().splitlines() or [""])[0]
    return write_json(
        Path(run_dir) / RUN_FILES["failed"],
        {"state": "failed", "error": type(err).__name__, "message": line, "epoch": epoch,
         "exit_code": getattr(err, "exit_code", 1), "time": time.strftime("%Y-%m-%d %H:%M:%S")},
    )


def interrupted_info(run_dir: Path) -> dict | None:
    p = Path(run_dir) / RUN_FILES["interrupted"]
    return json.loads(p.read_text()) if p.is_file() else None


@contextlib.contextmanager
def raise_on_signals():
    """Within the block, SIGINT and SIGTERM raise :class:`~optoenc.errors.Interrupted` (main thread only).

    Lightning turns a KeyboardInterrupt into ``sys.exit(1)`` and a SIGTERM
    into a silent exit 0; an ``Interrupted`` passes through it, so the caller
    can say where the run is and exit with 130 / 143.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise Interrupted(signum)

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def interrupted_note(run_dir: Path, signal_name: str, max_epochs: int, epoch: int | None = None) -> str:
    """Mark ``run_dir`` interrupted (``interrupted.json``); the sentence saying where the run is and how to resume.

    Args:
        epoch: the 0-based epoch in progress (None: after training, e.g. while testing).
    """
    import shlex

    from .callbacks import read_metrics

    run_dir = Path(run_dir)
    done = len(read_metrics(run_dir / RUN_FILES["metrics"]))
    command = f"optoenc fit --resume {shlex.quote(str(run_dir))}"
    mark_interrupted(run_dir, signal_name, done if epoch is None else epoch, command)
    last = run_dir / RUN_FILES["checkpoints"] / "last.ckpt"
    where = f"after training ({done} of {max_epochs} epochs)" if epoch is None else f"during epoch {epoch + 1} of {max_epochs}"
    if done and last.exists():
        return f"{where} in {run_dir}; {done} epoch(s) complete in {last}; resume with: {command}"
    return f"{where} in {run_dir}; no epoch complete yet, nothing to resume: start the run again"
