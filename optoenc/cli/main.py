"""``optoenc`` command line: the top-level parser and the dispatch to each command group.

Bad input (unknown option, key or name, value out of range, corrupt file)
prints one line ``optoenc: error: ...`` and exits with code 2, without a
traceback.
"""

from __future__ import annotations

import sys
from typing import Sequence

from ..errors import Interrupted, OptoencError
from . import bench, fit, listings, privacy, sweep
from .args import Parser

__all__ = ["main", "build_parser", "command_names"]

#: Command groups, in the order ``optoenc --help`` lists their commands.
GROUPS = (fit, sweep, privacy, bench, listings)


def build_parser() -> Parser:
    """The ``optoenc`` parser: one subcommand per command, each with its own ``--help``."""
    return _build()[0]


def command_names() -> list[str]:
    """Every command ``optoenc`` takes (``fit``, ``bench``, ``encoders``, ...)."""
    return list(_build()[1].choices)


def _build():
    p = Parser(
        prog="optoenc",
        description="Design optical encoders end to end. Settings: --section.key=value (e.g. --encoder.d2=4e-3).",
        epilog="`optoenc COMMAND --help` lists a command's options; `optoenc encoders NAME` an encoder's settings.",
    )
    p.add_argument("--version", action="store_true", help="print versions of optoenc and its plugins")
    sub = p.add_subparsers(dest="command", title="commands", metavar="COMMAND")
    for group in GROUPS:
        group.add_parsers(sub)
    return p, sub


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``optoenc`` with ``argv`` (default: the process's arguments); returns the exit code."""
    try:
        parser = build_parser()
        args, extra = parser.parse_known_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)  # the command as typed (e.g. in generated docs)
        if args.version:
            return listings.version()
        if not args.command:
            parser.print_help()
            return 0
        if extra and not args.overrides:
            args.parser.error(f"unrecognized arguments: {' '.join(extra)}")
        from ..training.allocator import keep_freed_memory
        from ..training.resume import raise_on_signals

        keep_freed_memory()  # $OPTOENC_MALLOC (default keep): no page faults on every step's large tensors
        with raise_on_signals():
            return args.handler(args, extra)
    except OptoencError as err:
        print(f"optoenc: error: {err}", file=sys.stderr)
        return err.exit_code
    except OSError as err:  # a file system refusal not caught earlier: one line, naming the file
        print(f"optoenc: error: {err.filename or ''}: {err.strerror or err}", file=sys.stderr)
        return 2
    except Interrupted as err:
        print(f"optoenc: interrupted by {err.name}{' ' + err.where if err.where else ''}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print("optoenc: interrupted by SIGINT", file=sys.stderr)
        return 130
