"""Sweep specifications: a base configuration plus axes and explicit cells, expanded to named cells.

A spec is a YAML file::

    name: table1                      # optional; default: the file's stem
    base:                             # any run configuration (nested or dotted keys)
      trainer: {max_epochs: 50}
    axes:                             # cartesian product, in this order
      encoder: [lens, diffuser]       # plugin names: encoder, decoder, dataset
      sensor.embedding: [[24, 32], [3, 4]]
      decoder: [logistic, fcnn]
      seed: [0, 1, 2]
    # or a list of such blocks, each its own cartesian product, run in order:
    # axes: [{encoder: [lens], ...}, {encoder: [learned_slm], trainer.verify_preset: [reference]}]
    cells:                            # explicit extra cells (each a mapping of the same keys)
      - {encoder: learned_slm, sensor.embedding: [24, 32], decoder: fcnn}
    paper:                            # optional figures to print beside ours
      - {where: {encoder: lens, sensor.embedding: [24, 32], decoder: fcnn}, acc: 97.7}

Keys are ``seed``, ``encoder``, ``decoder``, ``dataset``, ``augment`` (a
name, a comma-separated list, or a list; ``''`` for none) or any dotted
setting (``trainer.max_epochs``, ``augment.rotate.max_angle``). A cell is
named from its values along the keys that vary (``encoder=lens,embedding=24x32``).
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError

__all__ = ["SweepSpec", "Cell", "load_spec", "PLUGIN_KEYS"]

#: Keys that choose a plugin by name rather than set a value.
PLUGIN_KEYS = ("encoder", "decoder", "dataset")
_TOP = {"name", "base", "axes", "cells", "paper", "description"}


@dataclass(frozen=True)
class Cell:
    """One run of a sweep: its name (a folder name) and the values it sets, in spec key order."""

    name: str
    values: tuple[tuple[str, Any], ...]

    def get(self, key: str, default: Any = None) -> Any:
        return dict(self.values).get(key, default)


@dataclass
class SweepSpec:
    """A parsed sweep: ``base`` config, ``axes`` (ordered), explicit ``cells``, ``paper`` figures."""

    name: str
    base: dict[str, Any]
    axes: list[dict[str, list[Any]]] = field(default_factory=list)
    cells: list[dict[str, Any]] = field(default_factory=list)
    paper: list[dict[str, Any]] = field(default_factory=list)
    description: str = ""

    def expand(self) -> list[Cell]:
        """Every cell: the cartesian product of the axes, then the explicit cells (duplicates dropped)."""
        rows = []
        for block in self.axes:
            keys = list(block)
            rows += [dict(zip(keys, combo)) for combo in itertools.product(*block.values())] if keys else []
        rows += [dict(c) for c in self.cells]
        varied = self.varied_keys(rows)
        out, seen = [], set()
        for row in rows:
            cell = Cell(_cell_name(row, varied), tuple(row.items()))
            if cell.name in seen:
                continue
            seen.add(cell.name)
            out.append(cell)
        if not out:
            out.append(Cell("base", ()))
        return out

    @staticmethod
    def varied_keys(rows: list[dict[str, Any]]) -> list[str]:
        """Keys whose value differs between cells (or that only some cells set), in first-seen order."""
        keys: list[str] = []
        for r in rows:
            keys += [k for k in r if k not in keys]
        return [k for k in keys if len({_fmt(r.get(k, "\0")) for r in rows}) > 1]

    def paper_figure(self, cell: Cell) -> float | None:
        """The paper's figure whose ``where`` matches the cell's values (or the base's), if any."""
        values = {**{k: v for k, v in _flatten(self.base).items()}, **dict(cell.values)}
        for entry in self.paper:
            where = entry.get("where", {})
            if all(k in values and _fmt(values[k]) == _fmt(v) for k, v in where.items()):
                return float(entry["acc"])
        return None


def _flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and k not in ("augment",):
            out.update(_flatten(v, f"{key}."))
        else:
            out[key] = v
    return out


def _fmt(value: Any) -> str:
    """A short, filesystem-safe text for a value: ``[24, 32]`` -> ``24x32``."""
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, (int, float)) for v in value) and value:
            return "x".join(_fmt(v) for v in value)
        return "+".join(_fmt(v) for v in value) or "none"
    if value is None or value == "":
        return "none"
    if isinstance(value, float):
        return f"{value:g}"
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", str(value))


def _short(key: str) -> str:
    return key.rsplit(".", 1)[-1]


def _cell_name(row: dict[str, Any], varied: list[str]) -> str:
    shown = [k for k in varied if k in row]
    shorts = [_short(k) for k in shown]
    labels = [k if shorts.count(_short(k)) > 1 else _short(k) for k in shown]
    return ",".join(f"{label}={_fmt(row[k])}" for label, k in zip(labels, shown)) or "base"


def load_spec(path: str | Path) -> SweepSpec:
    """Parse and check a spec file (structure only; each cell's settings are checked when composed)."""
    from omegaconf import OmegaConf

    p = Path(path)
    if not p.is_file():
        raise ConfigError("sweep spec", str(path), "file not found")
    try:
        raw = OmegaConf.to_container(OmegaConf.load(p), resolve=True)
    except Exception as err:
        raise ConfigError("sweep spec", str(path), f"not valid YAML ({str(err).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise ConfigError("sweep spec", str(path), "top level must be a mapping with base, axes, cells, paper")
    unknown = sorted(set(raw) - _TOP)
    if unknown:
        raise ConfigError(f"sweep.{unknown[0]}", raw[unknown[0]], f"unknown key; allowed: {', '.join(sorted(_TOP))}")
    axes = raw.get("axes") or []
    blocks = [axes] if isinstance(axes, dict) else axes
    if not isinstance(blocks, list) or not all(isinstance(b, dict) for b in blocks):
        raise ConfigError("sweep.axes", axes, "must map a setting key to a list of values (or be a list of such maps)")
    for b in blocks:
        for k, v in b.items():
            if not isinstance(v, list) or not v:
                raise ConfigError(f"sweep.axes.{k}", v, "must be a non-empty list of values")
    cells = raw.get("cells") or []
    if not isinstance(cells, list) or not all(isinstance(c, dict) for c in cells):
        raise ConfigError("sweep.cells", cells, "must be a list of mappings (setting key -> value)")
    paper = raw.get("paper") or []
    for i, e in enumerate(paper):
        if not isinstance(e, dict) or "acc" not in e or not isinstance(e.get("where", {}), dict):
            raise ConfigError(f"sweep.paper[{i}]", e, "must be {where: {key: value, ...}, acc: NUMBER}")
    base = raw.get("base") or {}
    if not isinstance(base, dict):
        raise ConfigError("sweep.base", base, "must be a mapping (a run configuration)")
    return SweepSpec(str(raw.get("name") or p.stem), base, [dict(b) for b in blocks], cells, paper,
                     str(raw.get("description") or ""))
