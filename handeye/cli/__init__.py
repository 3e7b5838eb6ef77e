"""The ``handeye`` command line: the parser, the error mapping and one thin module per command.

:data:`COMMANDS` is the command table: calibrate, simulate, demo, apply, import (module ``import_``),
report, collect, batch, export, compare and verify, each with its module in this package and its line
in ``handeye --help``. Only the chosen command's module is imported; it adds its own arguments.

Progress goes to stderr, results to stdout and files. A user mistake ends in one line on stderr and
an exit code from :data:`handeye.errors.EXIT_CODES`, never a traceback (``--debug`` prints it first).

See docs/cli.md.
"""

from __future__ import annotations

import argparse
import atexit
import errno
import gc
import importlib
import logging
import os
import sys

from ..errors import INTERRUPTED_EXIT_CODE, OUTPUT_CLOSED_EXIT_CODE, HandeyeError, exit_codes_text
from ..machine import keep_freed_memory

log = logging.getLogger("handeye")

#: command -> (module in handeye.cli, the line ``handeye --help`` shows), in the order it lists them.
#: Each module has ``add_arguments(parser)`` (description, arguments and ``func``).
COMMANDS = {
    "calibrate": ("calibrate", "calibrate a session folder (vendor layout or session.yaml)"),
    "simulate": ("simulate", "write a synthetic session with rendered images and ground truth"),
    "demo": ("demo", "simulate a rendered session and calibrate it (the README's first command)"),
    "apply": ("apply", "map a point or pose seen by the camera into the robot base frame"),
    "import": ("import_", "write a session for another tool's data (ViSP, industrial_calibration, ROS bags, samples)"),
    "report": ("report", "(re)build report.html and report.md from a result folder"),
    "collect": ("collect", "collect a session with a camera and a robot (or their simulators)"),
    "batch": ("batch", "calibrate every session under a folder on Dask, resumable, and write the fleet index"),
    "export": ("export", "write a result for ROS 2, URDF, MoveIt, easy_handeye2, YAML or JSON"),
    "compare": ("compare", "compare two calibrations of one rig: difference, Mahalanobis distance, p-value"),
    "verify": ("verify", "check a short session against an installed calibration (still valid / drifted)"),
}


class _Version(argparse.Action):
    """``--version``: the version is read (importlib.metadata) only when it is asked for."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from .. import __version__

        print(f"handeye {__version__}")
        parser.exit()


class _LazyCommands(argparse._SubParsersAction):
    """The sub-command action: a command's module and arguments are loaded only when it is parsed.

    The sub-command action: a command's module is imported, and its arguments added to its
    (until then empty) parser, only when that command is parsed.
    """

    def __call__(self, parser, namespace, values, option_string=None):
        name = values[0] if values else None
        if name in COMMANDS:
            add_command_arguments(self._name_parser_map[name], name)
        super().__call__(parser, namespace, values, option_string)


def add_command_arguments(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    """Import command ``name``'s module and let it fill ``parser`` (once)."""
    if not getattr(parser, "_handeye_loaded", False):
        module = importlib.import_module(f"{__name__}.{COMMANDS[name][0]}")
        module.add_arguments(parser)
        parser._handeye_loaded = True  # type: ignore[attr-defined]  # a marker on the parser
    return parser


def build_parser() -> argparse.ArgumentParser:
    """The ``handeye`` parser; every command is listed, and loaded when it is parsed."""
    p = argparse.ArgumentParser(
        prog="handeye",
        description="Robot hand-eye calibration with honest uncertainty.",
        epilog=exit_codes_text(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--version", action=_Version, help="show program's version number and exit")
    p.add_argument("-v", "--verbose", action="store_true", help="more progress detail on stderr")
    p.add_argument("-q", "--quiet", action="store_true", help="only errors on stderr")
    p.add_argument("--debug", action="store_true", help="show tracebacks and the libraries' debug lines")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", action=_LazyCommands)
    sub.required = True
    for name, (_, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text)
    return p


#: whether main() registered the exit hook already
_exit_collection_skipped = False


def _skip_the_exit_collection() -> None:
    """At exit, leave the heap to the operating system instead of a last garbage collection over it.

    The interpreter's collections at shutdown traverse every object of the run (matplotlib's and the
    calibration's): 0.2-0.3 s of a ``calibrate`` run's wall time after its last line (measured on a 20-view
    session with reports), for nothing a command needs: its files are written and closed by then. Objects
    that are not in a reference cycle are still freed (and finalised) as the modules are torn down.
    """
    global _exit_collection_skipped
    if not _exit_collection_skipped:
        atexit.register(gc.freeze)  # runs before the handlers registered earlier (logging's flush still runs)
        _exit_collection_skipped = True


#: whether the objects of the command's imports were moved out of the collector's passes already
_imports_frozen = False


def freeze_imports() -> None:
    """Move every object alive now (the imported modules' classes, functions, constants) out of the collector's way.

    A command calls it once its imports are done. A fresh process's imports leave tens of thousands of
    long-lived objects that CPython's cyclic collector counts as pending; they trigger a full collection that
    traverses all of them during the run (about 30 ms of CPU of a ``calibrate --no-report``, which a warm
    process does not pay). ``gc.freeze`` moves them to the permanent generation, which no collection
    traverses; the ones a command makes later are collected as before. Once per process (a later call
    would also freeze the previous run's garbage).
    """
    global _imports_frozen
    if not _imports_frozen:
        gc.freeze()
        _imports_frozen = True


#: the variables OpenBLAS reads for its thread count, in the order it reads them
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def _one_blas_thread() -> None:
    """A fresh ``handeye`` process does its linear algebra on one BLAS thread, unless the environment says.

    handeye's matrices are small (a view's Jacobian, X's 6x6, a few hundred views' normal equations): on
    them OpenBLAS's worker threads buy no time, but they spin waiting for work after numpy loads and after
    every call, on the core the report's figure process, the detection threads or a batch's other worker
    would use (0.3-0.5 s of CPU of a 20-view ``calibrate``; the 300-view command is no slower on one
    thread). Set before numpy is imported, it holds for this process and the processes it starts (a batch's
    Dask workers); ``OPENBLAS_NUM_THREADS`` (or ``GOTO_NUM_THREADS``, ``OMP_NUM_THREADS``) set by the user
    is kept, and a process that imported numpy already (``main`` called from Python) is left as it is.
    """
    if "numpy" not in sys.modules and not any(v in os.environ for v in BLAS_THREAD_VARIABLES):
        os.environ["OPENBLAS_NUM_THREADS"] = "1"


def _no_pydantic_plugins() -> None:
    """A ``handeye`` process does not look for pydantic plugins, unless the environment says.

    pydantic reads every installed package's entry points for plugins when it builds its first validator (those
    of result.json and observations.json, which every calibration writes): about 20 ms of CPU of a ``calibrate``,
    for plugins no command uses. ``PYDANTIC_DISABLE_PLUGINS`` set by the user is kept; it holds for this process
    and the processes it starts.
    """
    os.environ.setdefault("PYDANTIC_DISABLE_PLUGINS", "__all__")


def prepare_process() -> None:
    """What a ``handeye`` command sets first: one BLAS thread, no pydantic plugins and the freed memory kept.

    :func:`_one_blas_thread`, :func:`_no_pydantic_plugins` and :func:`handeye.machine.keep_freed_memory`; a
    benchmark that runs the workflow in its own process calls it to measure what the command runs.
    """
    _one_blas_thread()
    _no_pydantic_plugins()
    keep_freed_memory()


def configure_logging(*, quiet: bool = False, verbose: bool = False, debug: bool = False) -> None:
    """Lines on stderr: handeye's at INFO (WARNING with ``quiet``, DEBUG with ``verbose``); the libraries' at WARNING.

    ``verbose`` is handeye's own detail: the libraries' debug lines (PIL's PNG chunks, matplotlib's font
    search) are shown only with ``debug``, which sets every logger to DEBUG.
    """
    level = logging.WARNING if quiet else logging.INFO
    logging.basicConfig(level=logging.DEBUG if debug else level, format="%(message)s", stream=sys.stderr)
    log.setLevel(logging.DEBUG if verbose and not quiet else logging.NOTSET)
    for library in ("matplotlib", "PIL"):  # with debug: as the root (a run before in this process set them)
        logging.getLogger(library).setLevel(logging.NOTSET if debug else logging.WARNING)


def main(argv=None) -> int:
    prepare_process()
    _skip_the_exit_collection()
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(quiet=args.quiet, verbose=args.verbose, debug=args.debug)
    try:
        return int(args.func(args) or 0)
    except HandeyeError as e:
        _traceback(args)
        print(f"handeye: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("handeye: interrupted", file=sys.stderr)
        return INTERRUPTED_EXIT_CODE
    except BrokenPipeError as e:
        if not _stdout_closed():
            return _os_error(args, e)
        return OUTPUT_CLOSED_EXIT_CODE  # `handeye ... | head`: the reader has what it wanted, nothing to say
    except OSError as e:  # the file system refused (disk full, permissions, a file vanished): name the file
        return _os_error(args, e)
    except Exception as e:  # noqa: BLE001 - a bug: one line, the traceback with --debug
        _traceback(args)
        msg = " ".join(f"{type(e).__name__}: {e}".split())[:300]
        print(
            f"handeye: internal error ({msg}); this is a bug -> rerun with --debug and report the traceback",
            file=sys.stderr,
        )
        return 1


def _traceback(args) -> None:
    """With ``--debug``, the traceback of the exception being handled (the exit code stays the error's)."""
    if args.debug:
        import traceback

        traceback.print_exc(file=sys.stderr)


def _os_error(args, e: OSError) -> int:
    _traceback(args)
    print(f"handeye: error: {os_error_line(e)}", file=sys.stderr)
    return HandeyeError.exit_code


def _stdout_closed() -> bool:
    """Whether standard output is a pipe whose reader went away; if so, stdout is pointed at the null device.

    Asked of the pipe itself (poll's POLLERR; where there is no poll, whether a flush fails). Pointed at the
    null device, the interpreter's last flush at exit has nowhere to fail.
    """
    import select

    try:
        fd = sys.stdout.fileno()
        if hasattr(select, "poll"):
            poller = select.poll()
            poller.register(fd, select.POLLOUT)
            closed = any(ev & select.POLLERR for _, ev in poller.poll(0))
        else:
            try:
                sys.stdout.flush()
                closed = False
            except BrokenPipeError:
                closed = True
        if closed:
            os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
        return closed
    except (OSError, ValueError):  # a stdout without a file descriptor (a test's capture)
        return False


#: what only a write is refused with: the disk or quota is full, the file system read-only, the file too large
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})


def os_error_line(e: OSError) -> str:
    """The one line for a refusal of the file system, for a write or for a read.

    The one line for a refusal of the file system: a write (:class:`handeye.output.OutputWriteError`, or
    an error only a write gets) names the output and how to make it writable; a read names the file read
    and how to make it readable.
    """
    from ..output import OutputWriteError

    why = e.strerror or str(e)
    if isinstance(e, OutputWriteError) or e.errno in WRITE_ERRNOS:
        fix = (
            "free space on its disk"
            if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
            else "make its folder writable (its permissions, a read-only mount)"
            if e.errno in (errno.EACCES, errno.EPERM, errno.EROFS)
            else "check that path"
        )
        return (
            f"cannot write {e.filename or 'the output'} ({why}) -> {fix} or choose another output folder; "
            "the previous result files are unchanged"
        )
    if e.filename:
        return (
            f"cannot read {e.filename} ({why}) -> check that the file exists and that this user may read it "
            "(its permissions and those of its folders), then run again"
        )
    return (
        f"the file system refused ({why}) -> check that the input files are readable and the output folder "
        "writable, then run again"
    )


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
