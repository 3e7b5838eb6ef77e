"""``python -m handeye.collect OUT ...``: the ``handeye collect`` command on its own."""

from __future__ import annotations

import sys

from ..cli import main as _cli_main


def main(argv=None) -> int:
    return _cli_main(["collect", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
