"""Device constants: a thin re-export of :mod:`optoenc.devices`, the one source of truth.

Kept so that ``from optoenc.encoders import constants as K`` keeps working;
define new constants in :mod:`optoenc.devices`.
"""

from __future__ import annotations

from ..devices import *  # noqa: F401,F403  (re-exported)
from ..devices import __all__  # noqa: F401
