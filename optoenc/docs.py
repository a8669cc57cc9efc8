"""Moved to :mod:`optoenc.plugins.docs`; this old import path is kept and is the same module object."""

import sys

from optoenc.plugins import docs as _moved

if __name__ == "__main__":  # ``python -m optoenc.docs``
    sys.exit(_moved.main())

sys.modules[__name__] = _moved
