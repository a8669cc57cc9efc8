"""Moved to :mod:`optoenc.plugins.listing`; this old import path is kept and is the same module object."""

import sys

from optoenc.plugins import listing as _moved

sys.modules[__name__] = _moved
