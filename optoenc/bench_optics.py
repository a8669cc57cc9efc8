"""Moved to :mod:`optoenc.bench.optics`; this old import path is kept and is the same module object."""

import sys

from optoenc.bench import optics as _moved

sys.modules[__name__] = _moved
