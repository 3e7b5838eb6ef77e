"""``handeye batch ROOT --out OUT``: every session under ROOT, one Dask task each, then the fleet index.

stderr: a progress bar (sessions done / failed / skipped) and, per failed session, one line with
the reason (with ``--export``: "not exported", by design), per session whose export of a PASS or WARN result
failed one line with its error; stdout: the one-line summary (with the counts of sessions not exported and of
failed exports) and the index's paths; Dask's own log lines: OUT/batch.log. Folders under ROOT that discovery
did not enter (a link loop, a second link to one folder) are one stderr line each and listed in the index.
Exit code 0 when every session (run now or skipped as unchanged) is PASS or WARN and every result in the
index could be read, else 7 (:class:`handeye.errors.QAFailed`'s code); one bad session never stops the
batch. ``--index-only OUT`` rebuilds the index from the result folders in OUT; its exit code is the same
rule over the index's rows, and each row that makes it 7 is a stderr line with its verdict and reason.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
from pathlib import Path
from typing import Iterator

log = logging.getLogger(__name__)

#: handeye calibrate's arguments that the batch sets itself (the session, its output folder, threads)
_NOT_FROM_CALIBRATE = ("help", "session", "out", "workers")
#: the batch's own log in OUT: what the parts of Dask in this process (scheduler, nannies, client) logged
CLUSTER_LOG_NAME = "batch.log"
#: their loggers, and their event loop's
CLUSTER_LOGGERS = ("distributed", "tornado", "asyncio")


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..batch.run import DEFAULT_TIMEOUT_S, MAX_TIMEOUT_S
    from .calibrate import add_arguments as add_calibrate_arguments

    p.description = (
        "Calibrate every session under ROOT (folders with session.yaml or poses.txt), one Dask task "
        "per session, into OUT/<install>/<session>/ (the same files as handeye calibrate), then "
        "write the fleet index OUT/index.html, index.md and fleet.csv. The install of a session is "
        "session.yaml's 'install:' key, else the first folder under ROOT (ROOT/<install>/<session>/). "
        "Sessions whose inputs and options have not changed since their last result are skipped."
    )
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = (
        "exit codes: 0 every session PASS or WARN (with --index-only: every row of the index PASS, WARN or "
        "VALID); 7 a session FAIL, REFUSED, DRIFTED or without a result (timeout, crash, lost worker, a "
        "session that cannot be read), or a result under OUT that is damaged; 2 unusable input (the root, "
        "the output folder, the options, the site QA file)"
    )
    p.add_argument("root", type=Path, help="folder holding the sessions (with --index-only: the output folder)")
    p.add_argument("--out", type=Path, help="output folder (required unless --index-only)")
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="worker processes of the embedded Dask cluster (default: the CPU count)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="use the Dask cluster of this scheduler (tcp://HOST:8786) instead of an embedded one; "
        "its workers must see ROOT and OUT at the same paths, unless --upload",
    )
    p.add_argument(
        "--upload",
        action="store_true",
        help="send each session's files to the workers and their results back (workers that do not "
        "share the client's filesystem); default: workers read ROOT and write OUT themselves",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT_S,
        metavar="S",
        help=f"time limit of one session in seconds (default {DEFAULT_TIMEOUT_S:g}, at most {MAX_TIMEOUT_S:g}: a week)",
    )
    p.add_argument("--force", action="store_true", help="run every session, changed or not")
    p.add_argument("--index-only", action="store_true", help="only rebuild the index of the output folder ROOT")
    tmp = argparse.ArgumentParser(add_help=False)
    add_calibrate_arguments(tmp)
    group = p.add_argument_group("calibration options (as handeye calibrate)")
    for action in tmp._actions:
        if action.dest not in _NOT_FROM_CALIBRATE:
            group._add_action(action)
    p.set_defaults(func=run, calibrate_dests=[a.dest for a in tmp._actions if a.dest not in _NOT_FROM_CALIBRATE])


def calibrate_options(args) -> dict:
    """The ``handeye calibrate`` options of the batch, by argparse name, paths absolute."""
    return {
        d: (str(Path(v).resolve()) if isinstance(v, Path) else v)
        for d, v in ((d, getattr(args, d)) for d in args.calibrate_dests)
    }


def index_exit_code(out: Path, *, every_row: bool) -> int:
    """The exit code that the index written in ``out`` calls for.

    :class:`QAFailed`'s code when a row is damaged (a result that cannot be read) or, with ``every_row``,
    when a row is not PASS, WARN or VALID; else 0.
    """
    from ..errors import QAFailed

    return QAFailed.exit_code if failing_rows(out, every_row=every_row) else 0


def failing_rows(out: Path, *, every_row: bool) -> list[dict]:
    """The rows of the index in ``out`` that make its exit code 7 (see :func:`index_exit_code`)."""
    from ..batch.index import DAMAGED, read_fleet_csv

    rows = read_fleet_csv(out / "fleet.csv")
    return [r for r in rows if r["outcome"] == DAMAGED or (every_row and r["verdict"] not in ("PASS", "WARN", "VALID"))]


def run(args) -> int:
    from ..batch.index import DAMAGED, write_index, write_skipped
    from ..errors import InputError, QAFailed

    if args.index_only:
        if not args.root.is_dir():
            raise InputError("output folder not found", path=args.root, hint="pass the --out folder of a batch")
        for p in write_index(args.root):
            print(f"index: {p}")
        bad = failing_rows(args.root, every_row=True)
        for r in (r for r in bad if r["outcome"] != DAMAGED):  # why the exit code is 7 (a damaged row is named above)
            where = "/".join(x for x in (r.get("install"), r.get("session")) if x)
            print(
                f"{where}: {r['verdict'] or r['outcome']} - {r.get('reason') or 'no reason recorded'}", file=sys.stderr
            )
        return QAFailed.exit_code if bad else 0
    if args.out is None:
        raise InputError("--out is required", hint="handeye batch ROOT --out OUT")
    if args.workers is not None and args.workers < 1:
        raise InputError("--workers must be at least 1", received=str(args.workers))
    from ..batch.run import DEFAULT_TIMEOUT_S, MAX_TIMEOUT_S

    if not 0 < args.timeout <= MAX_TIMEOUT_S:  # False for nan too
        raise InputError(
            "--timeout must be a positive number of seconds",
            expected=f"at most {MAX_TIMEOUT_S:g} (a week)",
            received=str(args.timeout),
            hint=f"pass the time limit of one session, e.g. --timeout {DEFAULT_TIMEOUT_S:g}",
        )
    if args.board_unmoved and args.prior is None:  # as handeye calibrate refuses it
        raise InputError(
            "--board-unmoved says the board stayed since the earlier calibration given by --prior",
            expected="--prior RESULT with it",
            received="no --prior",
            hint="add --prior RESULT, or drop --board-unmoved",
        )
    if args.prior is not None:  # one file for every session: a missing or damaged one stops the batch here
        from ..contract import read_result

        read_result(args.prior)
    from ..batch.discover import discover_fleet
    from ..batch.run import run_batch
    from ..output import FolderLock, check_out_dir
    from ..report.qa import load_qa

    if not getattr(args, "verbose", False):  # Dask's INFO lines, in this process and the workers it starts
        os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    load_qa(args.qa)  # a bad site QA file stops the batch before any session runs
    from ..options import options_from_args

    options_from_args(args)  # so does a bad --config or option: before the output folder is made
    found = discover_fleet(args.root)
    jobs = found.jobs
    for s in found.skipped:
        print(f"{s.path}: skipped: {s.reason}", file=sys.stderr)
    if not jobs:
        raise InputError(
            "no sessions found",
            path=args.root,
            expected="folders with session.yaml or poses.txt (ROOT/<install>/<session>/)",
        )
    check_out_dir(args.out)  # a file, or a folder that cannot be written: before any session runs
    with FolderLock(args.out):  # one batch per output folder: a second one would run the same sessions again
        bar = _Progress(len(jobs), quiet=getattr(args, "quiet", False), export=bool(args.export))
        try:
            with cluster_log(args.out / CLUSTER_LOG_NAME, verbose=getattr(args, "verbose", False)):
                summary = run_batch(
                    jobs,
                    args.out.resolve(),
                    calibrate=calibrate_options(args),
                    scheduler=args.scheduler,
                    n_workers=args.workers,
                    timeout_s=args.timeout,
                    force=args.force,
                    upload=args.upload,
                    progress=bar.update,
                )
        finally:
            bar.close()
        write_skipped(args.out, found.skipped)
        paths = write_index(args.out)
        n_skipped = len(found.skipped)
        print(summary.line() + (f"; {n_skipped} folder{'s' if n_skipped != 1 else ''} skipped" if n_skipped else ""))
        for p in paths:
            print(f"index: {p}")
    return max(summary.exit_code, index_exit_code(args.out, every_row=False))


@contextlib.contextmanager
def cluster_log(path: Path, *, verbose: bool = False) -> Iterator[None]:
    """Within the block, the log lines of Dask's parts in this process go to ``path`` (appended), not to stderr.

    A worker that dies makes the scheduler, its nanny and the client log warnings and errors (a task lost and
    rescheduled, the worker restarted, the task given up): Dask's internals, where the user's account of the
    session is its one line (its record's reason). They are kept in ``path`` with their time and source, with
    Dask's INFO lines (how a worker process ended), under a line naming the batch. ``verbose``: on stderr too.
    Every logger of :data:`CLUSTER_LOGGERS` and below gets its handlers, level and propagation back after.
    """
    import distributed  # noqa: F401 - its logging set-up, done as it is imported, first: then this one

    from ..output import command_line

    handler = _LogFile(path)
    handler.handle(logging.makeLogRecord({"name": __name__, "levelname": "INFO", "msg": f"started: {command_line()}"}))
    names = [n for n in logging.Logger.manager.loggerDict if n.split(".")[0] in CLUSTER_LOGGERS]
    saved = []
    for name in sorted(set(names) | set(CLUSTER_LOGGERS)):
        logger = logging.getLogger(name)
        saved.append((logger, logger.handlers[:], logger.propagate, logger.level))
        if name in CLUSTER_LOGGERS:  # Dask's own stderr handlers (when it was imported before handeye's) go too
            logger.handlers, logger.propagate = [handler], verbose
        else:  # distributed.client and the like have their own handler and level: this file's instead
            logger.handlers, logger.propagate = [], True
    dask_log = logging.getLogger(CLUSTER_LOGGERS[0])
    dask_log.setLevel(min(dask_log.getEffectiveLevel(), logging.INFO))
    try:
        yield
    finally:
        for logger, handlers, propagate, level in saved:
            logger.handlers, logger.propagate = handlers, propagate
            logger.setLevel(level)
        handler.close()


class _LogFile(logging.Handler):
    """Log lines appended to a file: not a StreamHandler, whose level Dask's LocalCluster sets to WARNING."""

    def __init__(self, path: Path):
        super().__init__()
        self.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
        self.file = open(path, "a", encoding="utf-8")  # closed with the handler

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.file.write(self.format(record) + "\n")
            self.file.flush()
        except (OSError, ValueError):  # a full disk or a line that cannot be formatted: logging's own report
            self.handleError(record)

    def close(self) -> None:
        self.file.close()
        super().close()


class _Progress:
    """tqdm on stderr: sessions finished, with done / failed / skipped; a line per failed session."""

    def __init__(self, total: int, *, quiet: bool, export: bool = False):
        from collections import Counter

        from tqdm import tqdm

        self.export = export  # --export: a failed session's line says it is not exported
        self.counts: Counter[str] = Counter()
        self.bar = tqdm(total=total, unit="session", file=sys.stderr, disable=quiet, dynamic_ncols=True)

    def update(self, rec: dict) -> None:
        from ..batch.run import NOT_EXPORTED_VERDICTS, export_failed, record_state

        state = record_state(rec)
        self.counts[state] += 1
        if state == "failed":
            unexported = self.export and (rec.get("verdict") or "ERROR") in NOT_EXPORTED_VERDICTS
            self.bar.write(
                f"{rec['install']}/{rec['name']}: {rec.get('verdict')} ({rec.get('outcome')}): "
                f"{rec.get('reason') or ''}" + (" (not exported)" if unexported else ""),
                file=sys.stderr,
            )
        if export_failed(rec):  # a skipped session's export is still missing: said too
            self.bar.write(f"{rec['install']}/{rec['name']}: the export failed: {rec['export_error']}", file=sys.stderr)
        self.bar.set_postfix_str(
            f"done {self.counts['done']} · failed {self.counts['failed']} · skipped {self.counts['skipped']}",
            refresh=False,
        )
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()
