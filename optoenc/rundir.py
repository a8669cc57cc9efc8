"""Moved to :mod:`optoenc.training.rundir`; this old import path is kept and is the same module object."""

import sys

from optoenc.training import rundir as _moved

sys.modules[__name__] = _moved
