"""``python -m optoenc.cli``: the ``optoenc`` command."""

import sys

from .main import main

sys.exit(main())
