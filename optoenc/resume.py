"""Moved to :mod:`optoenc.training.resume`; this old import path is kept and is the same module object."""

import sys

from optoenc.training import resume as _moved

sys.modules[__name__] = _moved
