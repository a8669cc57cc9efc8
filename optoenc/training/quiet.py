"""Lightning's console chatter off, for the command line's processes (the library itself leaves logging alone)."""

from __future__ import annotations

import logging
import warnings

__all__ = ["quiet_lightning"]


def quiet_lightning() -> None:
    """Lightning's info lines (GPU available, limits, tips) and its notices irrelevant here, silenced.

    Kept: warnings and errors. Dropped: "does not have many workers" (the data is in memory),
    the ``LeafSpec`` deprecation of Lightning's own code, "exists and is not empty" (a resumed run).
    """
    for name in ("lightning", "lightning.pytorch", "lightning.fabric", "lightning_utilities"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=".*(does not have many workers|LeafSpec|exists and is not empty).*")
