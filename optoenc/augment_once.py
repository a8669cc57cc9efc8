"""Moved to :mod:`optoenc.training.augment_once`; this old import path is kept and is the same module object."""

import sys

from optoenc.training import augment_once as _moved

sys.modules[__name__] = _moved
