"""Moved to :mod:`optoenc.fidelity.choose`; this old import path is kept and is the same module object."""

import sys

from optoenc.fidelity import choose as _moved

sys.modules[__name__] = _moved
