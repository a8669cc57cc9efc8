"""Moved to :mod:`optoenc.plugins.registry`; this old import path is kept and is the same module object."""

import sys

from optoenc.plugins import registry as _moved

sys.modules[__name__] = _moved
