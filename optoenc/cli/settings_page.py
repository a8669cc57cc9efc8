"""Generate the settings reference, ``docs/settings.md``, from the registries.

Usage::

    python -m optoenc.cli.settings_page            # rewrite docs/settings.md (atomically)
    python -m optoenc.cli.settings_page --check    # exit 1 if it is stale
    python -m optoenc.cli.settings_page --installed --output my-settings.md   # include installed plugins

The committed reference documents optoenc's built-ins only, so it does not
depend on which third-party plugins happen to be installed; regenerate it
whenever a built-in plugin, a ``Config`` or a shared settings group changes
(``tests/test_docs.py`` fails until you do).
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import sys
from pathlib import Path
from typing import Iterator, Sequence

__all__ = ["SETTINGS_MD", "generate", "main"]

#: The generated page, in a source checkout.
SETTINGS_MD = Path(__file__).resolve().parents[2] / "docs" / "settings.md"


@contextlib.contextmanager
def _builtins_only() -> Iterator[None]:
    """Temporarily make the process-wide host one that loaded only optoenc's built-ins."""
    from ..plugins import host as plugins

    with plugins._lock:
        saved = plugins._host
        plugins._host = plugins.PluginHost(entry_points=False)
    try:
        yield
    finally:
        with plugins._lock:
            plugins._host = saved


def generate(installed: bool = False) -> str:
    """The text of ``docs/settings.md`` (built-ins only unless ``installed``)."""
    from .catalogue import settings_reference

    if installed:
        return settings_reference() + "\n"
    with _builtins_only():
        return settings_reference() + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m optoenc.cli.settings_page", description=__doc__.splitlines()[0])
    p.add_argument("--output", type=Path, default=SETTINGS_MD, help=f"where to write (default {SETTINGS_MD})")
    p.add_argument("--check", action="store_true", help="do not write; exit 1 if the file is stale")
    p.add_argument("--installed", action="store_true", help="also document the installed third-party plugins")
    args = p.parse_args(argv)
    text = generate(installed=args.installed)
    current = args.output.read_text(encoding="utf-8") if args.output.is_file() else ""
    if args.check:
        if current == text:
            print(f"{args.output} is up to date")
            return 0
        diff = difflib.unified_diff(current.splitlines(), text.splitlines(), str(args.output), "generated", lineterm="", n=1)
        print("\n".join(list(diff)[:40]))
        print(f"{args.output} is stale: run `python -m optoenc.cli.settings_page`", file=sys.stderr)
        return 1
    if current == text:
        print(f"{args.output} unchanged")
        return 0
    from ..training.rundir import atomic_write_text

    args.output.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.output, text)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
