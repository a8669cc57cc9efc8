"""From a spec's cell to a run configuration and a run directory, and the cell's state on disk."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..training.rundir import RUN_FILES, write_json
from .spec import PLUGIN_KEYS, Cell, SweepSpec, _flatten

__all__ = ["compose_cell", "cell_dir", "cell_state", "STATUS", "CLOCK", "CLAIM", "claim_cell", "release_cell", "add_clock",
           "read_clock", "VOLATILE_KEYS",
           "config_differences"]

#: The per-cell status file (``state``: running, finished, failed; ``error``; times).
STATUS = "status.json"
#: The per-cell claim: created exclusively by the sweep process that is about to run the cell (its pid and host).
CLAIM = "claim.json"
#: The per-cell machine clock, written by the sweep around each of the cell's processes (see :func:`add_clock`).
CLOCK = "clock.json"
#: Settings of the machine or worker, not of the experiment (like a thread count, they change at most
#: rounding), and where the cell is stored (a sweep directory copied or moved elsewhere, a cell renamed
#: when the spec grows an axis): they never make a finished cell stale.
VOLATILE_KEYS = ("trainer.threads", "trainer.progress", "trainer.accelerator", "output.root", "output.name")
#: Values that mean the same run (``limit_*_batches``: 1.0 and null are both "all batches").
_SAME = {"trainer.limit_train_batches": (1.0, None), "trainer.limit_val_batches": (1.0, None),
         "trainer.limit_test_batches": (1.0, None)}


def _value(v: Any) -> str:
    return json.dumps(v)


def compose_cell(spec: SweepSpec, cell: Cell, sweep_dir: str | Path):
    """The cell's :class:`~optoenc.config.RunConfig`: the spec's base, then the cell's values.

    The run writes to ``sweep_dir/cells/<cell name>``; progress bars are off
    unless the base turns them on (a cell's log is a file).
    """
    from omegaconf import OmegaConf

    from ..config import compose

    base = dict(spec.base)
    aug_tree = base.pop("augment", None)
    augment = None
    if aug_tree is not None and not isinstance(aug_tree, dict):  # names, as a cell gives them
        augment, aug_tree = _augment_names(aug_tree), None
    flat = _flatten(base)
    names = {k: flat.pop(k) for k in PLUGIN_KEYS if isinstance(flat.get(k), str)}
    seed = flat.pop("seed", None)
    overrides = [f"trainer.progress={_value(flat.pop('trainer.progress', False))}"]
    overrides += [f"{k}={_value(v)}" for k, v in flat.items()]
    for k, v in cell.values:
        if k in PLUGIN_KEYS:
            names[k] = v
        elif k == "seed":
            seed = v
        elif k == "augment":
            augment = _augment_names(v)
        else:
            overrides.append(f"{k}={_value(v)}")
    root = Path(sweep_dir) / "cells"
    overrides += [f"output.root={_value(str(root))}", f"output.name={_value(cell.name)}"]
    files = [OmegaConf.create({"augment": aug_tree})] if isinstance(aug_tree, dict) else []
    return compose(files, overrides, names, augment, seed)


def _augment_names(v: Any) -> list[str]:
    """Augmentation names from a list, a name or a comma-separated string (``''`` or null: none)."""
    return list(v) if isinstance(v, list) else [a.strip() for a in str(v or "").split(",") if a.strip()]


def cell_dir(sweep_dir: str | Path, cell: Cell) -> Path:
    return Path(sweep_dir) / "cells" / cell.name


def _leaves(tree, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in (tree or {}).items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            if key == "augment":  # which augmentations run is a setting of its own
                out[key] = sorted(v)
            out.update(_leaves(v, f"{key}."))
        else:
            out[key] = v
    return out


def comparable(text: str) -> dict[str, Any]:
    """A stored config's settings as ``{dotted key: value}``, without the volatile keys."""
    import yaml

    flat = _leaves(yaml.safe_load(text) or {})
    return {k: v for k, v in flat.items() if k not in VOLATILE_KEYS}


def config_differences(stored: str, new: str) -> list[str]:
    """Dotted keys whose values differ between two configs.

    Keys present in only one of them are settings added or removed by
    another version of optoenc (or a plugin) and are not compared: a finished
    cell stays finished when optoenc grows a setting.
    """
    a, b = comparable(stored), comparable(new)
    same = lambda k: a[k] == b[k] or (k in _SAME and a[k] in _SAME[k] and b[k] in _SAME[k])  # noqa: E731
    return sorted(k for k in set(a) & set(b) if not same(k))


def _alive(pid, host) -> bool:
    """Whether process ``pid`` on ``host`` (this machine's name when recorded here) still runs."""
    import os
    import socket

    if not pid or (host and host != socket.gethostname()):
        return bool(pid) and bool(host) and host != socket.gethostname()  # another machine's: assume alive
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def claim_cell(path: Path) -> str | None:
    """Claim the cell at ``path`` for this process before running it: None where the claim is ours, else why
    the cell is not to run here (another live process holds it, or it finished since it was planned).

    Two sweeps over one folder plan their cells independently; without a claim both would start the same
    cell and train it twice into one folder. The claim file is created with ``O_CREAT | O_EXCL``, so of
    two processes racing for a cell exactly one gets it; a claim whose process is gone is taken over.
    """
    import os
    import socket

    if (path / RUN_FILES["summary"]).is_file():
        return "finished by another sweep"
    me = json.dumps({"pid": os.getpid(), "host": socket.gethostname()})
    for _ in range(2):
        try:
            fd = os.open(path / CLAIM, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                owner = json.loads((path / CLAIM).read_text())
            except (OSError, ValueError):  # being written this instant: held
                return "claimed by another sweep"
            if _alive(owner.get("pid"), owner.get("host")):
                return f"run by another sweep (pid {owner.get('pid')})"
            (path / CLAIM).unlink(missing_ok=True)  # its process is gone: take it over
            continue
        with os.fdopen(fd, "w") as f:
            f.write(me)
        if (path / RUN_FILES["summary"]).is_file():  # finished between the check and the claim
            release_cell(path)
            return "finished by another sweep"
        return None
    return "claimed by another sweep"


def release_cell(path: Path) -> None:
    """Give up this process's claim on the cell at ``path`` (:func:`claim_cell`)."""
    (path / CLAIM).unlink(missing_ok=True)


def add_clock(path: Path, seconds: float) -> dict:
    """Add one segment of ``seconds`` to the cell's machine clock (``clock.json``: ``seconds``, ``segments``).

    The sweep times each process it starts for the cell, from launch to exit: the interpreter's start-up,
    composing the configuration, the run and its re-simulation at ``trainer.verify_preset``, pictures, and
    segments that were interrupted (their work is redone from the last checkpoint, but the machine spent it).
    The run's own ``wall_time_s`` counts its training and testing only. Only the sweep that owns the cell
    writes the file (a cell runs in one process at a time), atomically.
    """
    old = read_clock(path) or {"seconds": 0.0, "segments": 0}
    new = {"seconds": round(old["seconds"] + float(seconds), 2), "segments": int(old["segments"]) + 1}
    write_json(path / CLOCK, new)
    return new


def read_clock(path: Path) -> dict | None:
    """The cell's machine clock (:func:`add_clock`), or None where the sweep has not recorded one."""
    try:
        clock = json.loads((path / CLOCK).read_text())
        return {"seconds": float(clock["seconds"]), "segments": int(clock["segments"])}
    except (OSError, ValueError, KeyError, TypeError):
        return None


def cell_state(path: Path, config_yaml: str | None = None) -> str:
    """``new``, ``finished``, ``running``, ``interrupted`` (has a last checkpoint), ``failed`` or ``changed``.

    ``running``: its status names a live process (a second sweep over the
    same folder leaves it alone).

    ``changed``: the directory holds a run of another configuration than
    ``config_yaml`` (volatile keys aside).
    """
    cfg = path / RUN_FILES["config"]
    if config_yaml is not None and cfg.is_file() and config_differences(cfg.read_text(), config_yaml):
        return "changed"
    if (path / RUN_FILES["summary"]).is_file():
        return "finished"
    status = {}
    if (path / STATUS).is_file():
        try:
            status = json.loads((path / STATUS).read_text())
        except ValueError:
            status = {}
    if status.get("state") == "failed":
        return "failed"
    if status.get("state") == "running" and _alive(status.get("pid"), status.get("host")):
        return "running"  # another sweep process is training it right now
    if (path / RUN_FILES["checkpoints"] / "last.ckpt").is_file():
        return "interrupted"
    return "new"
