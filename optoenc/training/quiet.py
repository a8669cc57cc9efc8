"""Lightning's console chatter off, for the command line's processes (the library itself leaves logging alone)."""

from __future__ import annotations

import logging
import os
import warnings

__all__ = ["quiet_lightning", "QUIET_ENV", "quiet_if_asked"]

#: Set by :func:`quiet_lightning` for the processes Lightning spawns (``ddp_spawn``), which start afresh:
#: :func:`quiet_if_asked`, called as the training module is set up in each of them, quiets them too.
QUIET_ENV = "OPTOENC_QUIET_LIGHTNING"


def quiet_lightning() -> None:
    """Lightning's info lines (GPU available, limits, tips) and its notices irrelevant here, silenced.

    Kept: warnings and errors. Dropped: "does not have many workers" (the data is in memory),
    the ``LeafSpec`` deprecation of Lightning's own code, "exists and is not empty" (a resumed run).
    """
    for name in ("lightning", "lightning.pytorch", "lightning.fabric", "lightning_utilities"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=".*(does not have many workers|LeafSpec|exists and is not empty).*")
    # processes Lightning spawns (ddp_spawn) start a fresh interpreter: they read the filter from the environment
    os.environ[QUIET_ENV] = "1"
    spawned = "ignore:`isinstance(treespec"  # a prefix of the message: the variable splits its entries at commas
    current = os.environ.get("PYTHONWARNINGS", "")
    if spawned not in current.split(","):
        os.environ["PYTHONWARNINGS"] = ",".join(filter(None, [current, spawned]))


def quiet_if_asked() -> None:
    """:func:`quiet_lightning` in a process whose parent asked for it (a command-line run's spawned workers)."""
    if os.environ.get(QUIET_ENV) == "1":
        quiet_lightning()
