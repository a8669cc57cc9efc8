"""Argument helpers shared by the command groups: the parser class, run options, settings overrides, output paths.

Settings are given as ``--section.key=value`` after a command's own options;
:func:`split_overrides` turns them into ``section.key=value`` strings for
:func:`optoenc.config.compose`, and :func:`compose` builds the run
configuration from the parsed options and those overrides.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Sequence

from ..errors import ConfigError, OptoencError

__all__ = [
    "Parser",
    "UsageError",
    "run_options",
    "split_overrides",
    "compose",
    "out_file",
    "out_dir",
    "names",
    "command",
]


class UsageError(OptoencError):
    """A command line argparse refuses (unknown option, missing value, wrong type): one line, exit code 2."""


class _Formatter(argparse.HelpFormatter):
    """argparse's help layout with room for the longest command name (``augmentations``) beside its help."""

    def __init__(self, prog: str):
        super().__init__(prog, max_help_position=32)

    def add_argument(self, action: argparse.Action) -> None:
        super().add_argument(action)
        if isinstance(action.choices, dict):  # subcommands: argparse measures them one indent short of where it prints them
            self._action_max_length += 2


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose refusals raise :class:`UsageError` (one line, exit 2) instead of printing usage."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D102 - argparse's hook
        command = self.prog.partition(" ")[2]  # "optoenc bench speed" -> "bench speed"
        raise UsageError(f"{command + ': ' if command else ''}{message} (see `{self.prog} --help`)")


def run_options(p: argparse.ArgumentParser) -> None:
    """The options that choose a run's plugins and seed (fit, psf, simulate)."""
    p.add_argument("--config", action="append", default=[], metavar="YAML", help="run config file (repeatable; later wins)")
    p.add_argument("--encoder", help="optical encoder (see `optoenc encoders`)")
    p.add_argument("--decoder", help="digital decoder (see `optoenc decoders`)")
    p.add_argument("--dataset", help="dataset (see `optoenc datasets`)")
    p.add_argument("--task", help="what the decoder is trained for: classification (default) or reconstruction "
                   "(see `optoenc tasks`)")
    p.add_argument("--augment", help="comma-separated augmentations (see `optoenc augmentations`); '' for none")
    p.add_argument("--seed", type=int, help="run seed")
    p.add_argument("--print-config", action="store_true", help="print the resolved config and exit")


def split_overrides(extra: Sequence[str]) -> list[str]:
    """``--a.b=v`` / ``--a.b v`` / ``a.b=v`` tokens -> ``["a.b=v", ...]``."""
    out, i, extra = [], 0, list(extra)
    while i < len(extra):
        tok = extra[i]
        key = tok[2:] if tok.startswith("--") else tok
        if "=" in key:
            out.append(key)
        elif tok.startswith("--") and "." in key and i + 1 < len(extra):
            out.append(f"{key}={extra[i + 1]}")
            i += 1
        else:
            raise ConfigError(key or tok, "", "not an option; settings are given as --section.key=value")
        i += 1
    return out


def compose(args: argparse.Namespace, extra: Sequence[str]):
    """The :class:`~optoenc.config.RunConfig` of the parsed options (``--config``, ``--encoder``, ...) and overrides."""
    from ..config import compose as compose_run, load_yaml

    plugins = {k: getattr(args, k, None) for k in ("encoder", "decoder", "dataset", "task")}
    files = [load_yaml(c) for c in getattr(args, "config", [])]
    augment = None if getattr(args, "augment", None) is None else [a.strip() for a in args.augment.split(",")]
    return compose_run(files, split_overrides(extra), plugins, augment, getattr(args, "seed", None))


def out_file(path: str) -> Path:
    """``--out FILE``: refused up front if it names a folder or lies under a file."""
    out = Path(path)
    if out.is_dir():
        raise ConfigError("--out", path, "is a folder; give a file name (e.g. psf.png)")
    if any(p.exists() and not p.is_dir() for p in out.parents):
        raise ConfigError("--out", path, "lies under a file, not a folder")
    return out


def out_dir(path: str) -> Path:
    """``--out DIR``: refused up front if it names a file or lies under one."""
    out = Path(path)
    if any(p.exists() and not p.is_dir() for p in (out, *out.parents)):
        raise ConfigError("--out", path, "is (or lies under) a file; give a folder")
    return out


def names(text: str) -> list[str]:
    """``"a, b,,c"`` -> ``["a", "b", "c"]``."""
    return [v.strip() for v in text.split(",") if v.strip()]


def command(p: argparse.ArgumentParser, handler, overrides: bool = False) -> None:
    """Make ``p`` run ``handler(args, extra)``; ``overrides``: it takes ``--section.key=value`` settings as ``extra``."""
    p.set_defaults(handler=handler, overrides=overrides, parser=p)
