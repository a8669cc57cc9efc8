"""Listing commands: ``plugins``, one per plugin kind (``encoders``, ``decoders``, ...), and ``--version``."""

from __future__ import annotations

import argparse

from .. import __version__
from ..plugins.registry import KINDS
from .args import command

__all__ = ["KIND_COMMANDS", "add_parsers", "version"]

#: Listing command -> plugin kind (`optoenc encoders`, ...), one per kind of :data:`optoenc.plugins.registry.KINDS`.
KIND_COMMANDS = {f"{kind}s": kind for kind in KINDS}


def add_parsers(sub) -> None:
    """Add ``plugins`` and the listing of each plugin kind to the CLI's subparsers."""
    pl = sub.add_parser("plugins", help="list installed plugins and what they register",
                        description="List the installed plugins (built-ins and entry points), their versions and "
                        "what each registers.")
    pl.add_argument("--json", action="store_true", help="print JSON")
    command(pl, cmd_plugins)
    for cmd, kind in KIND_COMMANDS.items():
        s = sub.add_parser(cmd, help=f"list {cmd}, or show one {kind}'s settings",
                           description=f"List the registered {cmd} (name, plugin, summary), or show one {kind}'s "
                           "settings with their defaults, units and allowed values.")
        s.add_argument("pattern", nargs="?", help=f"a {kind} name (its settings) or a glob pattern")
        s.add_argument("--json", action="store_true", help="print JSON")
        command(s, cmd_list)


def cmd_list(args: argparse.Namespace, extra) -> int:
    from . import catalogue as listing

    print(listing.show(KIND_COMMANDS[args.command], args.pattern, as_json=args.json))
    return 0


def cmd_plugins(args: argparse.Namespace, extra) -> int:
    from . import catalogue as listing

    print(listing.plugins(as_json=args.json))
    return 0


def version() -> int:
    """``optoenc --version``: optoenc's version and each plugin's (with its load state)."""
    from ..plugins import get_host

    print(f"optoenc {__version__}")
    for info in get_host().plugins:
        state = "ok" if info.ok else f"FAILED: {info.error}"
        print(f"  plugin {info.name} {info.distribution} {info.version} ({state})")
    return 0
