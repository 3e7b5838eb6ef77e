"""``python -m handeye.cli``: the same entry point as the ``handeye`` command."""

import sys

from . import main

sys.exit(main())
