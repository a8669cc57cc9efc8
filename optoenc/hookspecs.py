"""Moved to :mod:`optoenc.plugins.hookspecs`; this old import path is kept and is the same module object."""

import sys

from optoenc.plugins import hookspecs as _moved

sys.modules[__name__] = _moved
