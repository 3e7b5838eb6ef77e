"""The ``handeye`` command line: the parser, the error mapping and one thin module per command.

==============  ====================================================================
command         module
==============  ====================================================================
calibrate       :mod:`.calibrate` (through :func:`handeye.workflow.calibrate_session`)
simulate        :mod:`.simulate`
demo            :mod:`.demo`
apply           :mod:`.apply`
import          :mod:`.import_`
report          :mod:`.report`
collect         :mod:`.collect`
==============  ====================================================================

Progress and log lines go to stderr, results to stdout and files. A user mistake ends in one line
on stderr and a non-zero exit code (:attr:`handeye.errors.HandeyeError.exit_code`), never a
traceback (``--debug`` shows it). Command modules import their heavy dependencies inside ``run``,
so that ``handeye --help`` stays quick.
"""
from __future__ import annotations

import argparse
import logging
import sys

from .. import __version__
from ..errors import HandeyeError
from . import apply, calibrate, collect, demo, import_, report, simulate

log = logging.getLogger("handeye")

#: command modules in the order ``handeye --help`` lists them; each has ``add_parser(subparsers)``
COMMANDS = (calibrate, simulate, demo, apply, import_, report, collect)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="handeye", description="Robot hand-eye calibration with honest uncertainty.")
    p.add_argument("--version", action="version", version=f"handeye {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="more progress detail on stderr")
    p.add_argument("-q", "--quiet", action="store_true", help="only errors on stderr")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for command in COMMANDS:
        command.add_parser(sub)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else (logging.DEBUG if args.verbose else logging.INFO)
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr)
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    try:
        return int(args.func(args) or 0)
    except HandeyeError as e:
        if args.debug:
            raise
        print(f"handeye: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("handeye: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
