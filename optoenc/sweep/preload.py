"""What every sweep cell imports, loaded once by the forkserver its processes fork from (:mod:`.launch`).

Importing this module is the whole of its work: Lightning (which imports torch and its compiler
stack), the training code and the built-in plugins, colour-science (pandas) for the PSF pictures and
matplotlib with its Agg backend (as :mod:`optoenc.training.pictures` selects it). Nothing here starts a
thread or touches a device, so the forks are safe; a cell that needs more imports it itself.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg", force=False)

import colour  # noqa: E402,F401
import lightning.pytorch  # noqa: E402,F401
import matplotlib.pyplot  # noqa: E402,F401

from ..plugins import builtins  # noqa: E402,F401
from ..training import run  # noqa: E402,F401
from . import cell  # noqa: E402,F401
