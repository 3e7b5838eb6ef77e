"""``python -m handeye``: the ``handeye`` command, for an environment whose scripts folder is not on the PATH."""

from handeye.cli import main

raise SystemExit(main())
