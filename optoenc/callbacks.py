"""Moved to :mod:`optoenc.training.callbacks`; this old import path is kept and is the same module object."""

import sys

from optoenc.training import callbacks as _moved

sys.modules[__name__] = _moved
