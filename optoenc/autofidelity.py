"""Moved to :mod:`optoenc.fidelity.auto`; this old import path is kept and is the same module object."""

import sys

from optoenc.fidelity import auto as _moved

sys.modules[__name__] = _moved
