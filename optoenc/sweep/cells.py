"""From a spec's cell to a run configuration and a run directory, and the cell's state on disk."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..rundir import RUN_FILES
from .spec import PLUGIN_KEYS, Cell, SweepSpec, _flatten

__all__ = ["compose_cell", "cell_dir", "cell_state", "STATUS", "VOLATILE_KEYS", "comparable_yaml"]

#: The per-cell status file (``state``: running, finished, failed; ``error``; times).
STATUS = "status.json"
#: Settings a sweep sets per machine or worker; they never make a finished cell stale.
VOLATILE_KEYS = ("trainer.threads", "trainer.progress")


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
    flat = _flatten(base)
    names = {k: flat.pop(k) for k in PLUGIN_KEYS if isinstance(flat.get(k), str)}
    seed = flat.pop("seed", None)
    augment = None
    overrides = [f"trainer.progress={_value(flat.pop('trainer.progress', False))}"]
    overrides += [f"{k}={_value(v)}" for k, v in flat.items()]
    for k, v in cell.values:
        if k in PLUGIN_KEYS:
            names[k] = v
        elif k == "seed":
            seed = v
        elif k == "augment":
            augment = v if isinstance(v, list) else [a.strip() for a in str(v or "").split(",") if a.strip()]
        else:
            overrides.append(f"{k}={_value(v)}")
    root = Path(sweep_dir) / "cells"
    overrides += [f"output.root={_value(str(root))}", f"output.name={_value(cell.name)}"]
    files = [OmegaConf.create({"augment": aug_tree})] if isinstance(aug_tree, dict) else []
    return compose(files, overrides, names, augment, seed)


def cell_dir(sweep_dir: str | Path, cell: Cell) -> Path:
    return Path(sweep_dir) / "cells" / cell.name


def comparable_yaml(text: str) -> str:
    """A stored config without the volatile keys, for staleness checks."""
    from omegaconf import OmegaConf

    tree = OmegaConf.create(text)
    for key in VOLATILE_KEYS:
        section, leaf = key.split(".")
        if section in tree and leaf in tree[section]:
            tree[section][leaf] = None
    return OmegaConf.to_yaml(tree)


def cell_state(path: Path, config_yaml: str | None = None) -> str:
    """``new``, ``finished``, ``interrupted`` (has a last checkpoint), ``failed`` or ``changed``.

    ``changed``: the directory holds a run of another configuration than
    ``config_yaml`` (volatile keys aside).
    """
    cfg = path / RUN_FILES["config"]
    if config_yaml is not None and cfg.is_file() and comparable_yaml(cfg.read_text()) != comparable_yaml(config_yaml):
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
    if (path / RUN_FILES["checkpoints"] / "last.ckpt").is_file():
        return "interrupted"
    return "new"
