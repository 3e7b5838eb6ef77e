"""``python -m handeye.collect OUT ...``: the ``handeye collect`` command on its own."""
from __future__ import annotations

import argparse
import logging
import sys

from ..errors import HandeyeError
from .cli_entry import add_collect_arguments, run_collect


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m handeye.collect")
    add_collect_arguments(parser)
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    try:
        return run_collect(args)
    except HandeyeError as e:
        if args.debug:
            raise
        print(f"handeye: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("handeye: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
