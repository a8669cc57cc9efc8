"""Moved to :mod:`optoenc.training.loaders`; this old import path is kept and is the same module object."""

import sys

from optoenc.training import loaders as _moved

sys.modules[__name__] = _moved
