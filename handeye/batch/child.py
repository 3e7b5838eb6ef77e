"""The process that runs a batch's sessions: ``python -m handeye.batch.child --serve`` (or ``SPEC_JSON``: one).

A long-lived session process (:class:`handeye.batch.process.SessionProcess`) imports handeye once, then reads
task specs on stdin, one JSON line each, and answers each with one JSON line (``outcome``, ``status``,
``verdict``, ``reason``, ``exit_code``, ``peak_rss_mb``, ``process``). It runs
:func:`handeye.workflow.calibrate_session` with the ``handeye calibrate`` options of the spec
(:func:`handeye.options.options_from_args`); a session's stdout and stderr go to its ``batch.log``. A crash
or a hang takes this process down with its one session; the task records it and starts a fresh process.
The process ends itself when its parent (the Dask worker) is gone or closes its stdin.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
import time
from pathlib import Path

from ..machine import keep_freed_memory, release_freed_memory

log = logging.getLogger(__name__)

#: seconds between two looks at the parent process
PARENT_POLL_S = 0.5
#: seconds a retried task waits for its first attempt's process to end (an attempt whose worker was killed ends
#: itself within PARENT_POLL_S, or when a long native call that holds the interpreter returns); a bound, after
#: which the output folder's lock refuses the run as for any second run into one folder
PREVIOUS_ATTEMPT_WAIT_S = 60.0


def _exit_with_parent() -> None:
    parent = os.getppid()

    def watch():
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent:
                os._exit(70)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _earlier_attempt(pid: int) -> bool:
    """Whether ``pid`` is a session process of a batch.

    Whether ``pid`` is a session process of a batch (``handeye.batch.child``) started by another process than
    this one's: an earlier attempt of this task, whose worker was killed (Dask runs a task once at a time, so a
    live attempt under another parent is a leftover; its parent is init or a subreaper by now). False where
    /proc cannot tell (another system, another user's process).
    """
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        ppid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return False
    return any(b"handeye.batch.child" in c for c in cmd) and ppid != os.getppid()


def _wait_for_previous_attempt(out_dir) -> None:
    """Wait for an earlier attempt's session process that still holds the output folder's lock.

    A task retried after its worker was killed can start while the first attempt's session process is still
    ending; it holds the output folder's lock until then. Wait for that holder (up to PREVIOUS_ATTEMPT_WAIT_S)
    instead of refusing the folder; any other holder (a live run) is left to the lock, which refuses at once.
    """
    from ..output import LOCK_NAME, _pid_alive

    lock = Path(out_dir) / LOCK_NAME
    deadline = time.monotonic() + PREVIOUS_ATTEMPT_WAIT_S
    told = False
    while time.monotonic() < deadline:
        try:
            holder = int(lock.read_text(encoding="utf-8").split()[0])
        except (OSError, ValueError, IndexError):
            return  # no lock, or one the run will take over or report
        if holder == os.getpid() or not _pid_alive(holder) or not _earlier_attempt(holder):
            return
        if not told:
            log.info("waiting for pid %d (an earlier attempt of this session whose worker is gone) to end", holder)
            told = True
        time.sleep(PARENT_POLL_S)


def run(spec: dict) -> dict:
    """The reply of one task ``spec``: a verification, a cell or a session, run as ``handeye`` runs it."""
    from ..output import recorded_as

    _wait_for_previous_attempt(spec["out_dir"])
    # recorded as the user ran it: the batch's command line, and an uploaded session's paths as the client's
    with recorded_as(command_line=spec.get("command_line"), paths=spec.get("recorded_paths")):
        if spec.get("verify_against"):
            return run_verify(spec)
        if spec.get("layout") == "cell":
            return run_cell(spec)
        return _run_session(spec)


def _run_session(spec: dict) -> dict:
    from ..errors import HandeyeError
    from ..options import refuse_pose_only_flags
    from ..workflow import calibrate_session
    from .run import calibrate_namespace

    cal = spec["calibrate"]
    args = calibrate_namespace(cal)
    try:  # as handeye calibrate runs it (handeye.cli.calibrate.run)
        refuse_pose_only_flags(argparse.Namespace(**{**vars(args), "session": spec["session"]}))
        wr = calibrate_session(
            spec["session"],
            out_dir=spec["out_dir"],
            **run_options(cal),
            prior=cal.get("prior"),
            board_unmoved=bool(cal.get("board_unmoved")),
        )
    except HandeyeError as e:
        return {"outcome": "error", "status": "failed", "verdict": "ERROR", "reason": str(e), "exit_code": e.exit_code}
    return done_reply(wr, cal)


def run_options(cal: dict) -> dict:
    """The keyword arguments a session's and a cell's calibration share, from the batch's calibrate options."""
    from ..options import options_from_args
    from .run import calibrate_namespace

    return dict(
        options=options_from_args(calibrate_namespace(cal)),
        report=not cal.get("no_report"),
        qa=cal.get("qa"),
        mode=cal.get("mode"),
        progress=lambda s: log.info("%s", s),
        allow_outside=bool(cal.get("allow_outside")),
        site_files=[f for f in (cal.get("config"), cal.get("qa")) if f],
    )


def done_reply(wr, cal: dict) -> dict:
    """The reply of a finished calibration ``wr`` (a session's or a cell's), its export done when asked for."""
    from ..errors import HandeyeError

    reason = wr.result.get("failure_reason") or (
        "" if wr.verdict in ("PASS", "WARN") else wr.result.get("verdict_headline", "")
    )
    reply = {"outcome": "done", "status": wr.status, "verdict": wr.verdict, "reason": reason, "exit_code": wr.exit_code}
    if cal.get("export") and wr.status == "ok":  # calibrate --export: next to the result, when usable
        from ..export import export_result

        try:
            reply["exported"] = [str(p) for p in export_result(wr.out_dir, cal["export"])]
        except HandeyeError as e:
            reply["export_error"] = str(e)
    return reply


def run_cell(spec: dict) -> dict:
    """A cell folder (``cell.yaml``), as ``handeye calibrate CELL_DIR`` runs it: one result.json of its cameras.

    ``--prior`` is refused (one session's); ``--export`` writes every camera (:func:`handeye.export.export_cell`).
    """
    from ..cell import calibrate_cell
    from ..errors import HandeyeError, InputError

    cal = spec["calibrate"]
    try:
        if cal.get("prior"):
            raise InputError("--prior is for one session, not a cell", path=spec["session"], hint="batch without it")
        wr = calibrate_cell([spec["session"]], spec["out_dir"], **run_options(cal))
    except HandeyeError as e:
        return {"outcome": "error", "status": "failed", "verdict": "ERROR", "reason": str(e), "exit_code": e.exit_code}
    return done_reply(wr, cal)


def run_verify(spec: dict) -> dict:
    """A verification session (``verify_against`` in its session.yaml), as ``handeye verify`` runs it.

    Verify.json and its reports in the session's output folder; verdict VALID or DRIFTED.
    """
    from pathlib import Path

    from ..contract import Verify, write_validated
    from ..errors import DRIFTED_EXIT_CODE, HandeyeError
    from ..recal.report import write_verify_reports
    from ..recal.verify import VerifyOptions, verify_dict, verify_session
    from .run import VERIFY_VERDICTS

    cal, out = spec["calibrate"], Path(spec["out_dir"])
    try:
        sv = verify_session(
            spec["session"],
            spec["verify_against"],
            options=VerifyOptions.from_config(),
            mode=cal.get("mode"),
            progress=lambda s: log.info("%s", s),
        )
        write_validated(out / "verify.json", verify_dict(sv), Verify)
        if not cal.get("no_report"):
            write_verify_reports(out)
    except HandeyeError as e:
        return {"outcome": "error", "status": "failed", "verdict": "ERROR", "reason": str(e), "exit_code": e.exit_code}
    v = sv.verification
    return {
        "outcome": "done",
        "status": "ok",
        "verdict": VERIFY_VERDICTS[v.verdict],
        "reason": "" if not v.drifted else v.headline,
        "exit_code": DRIFTED_EXIT_CODE if v.drifted else 0,
    }


#: Linux: writing this to /proc/self/clear_refs resets the peak resident memory (VmHWM) to the current
CLEAR_PEAK_RSS = "5"


def _reset_peak_rss() -> None:
    """Start a session's peak memory from the process's current memory (Linux); elsewhere the peak is the process's."""
    try:
        Path("/proc/self/clear_refs").write_text(CLEAR_PEAK_RSS)
    except OSError:
        pass


def _peak_rss_mb():
    """Peak resident memory in MiB since the last :func:`_reset_peak_rss` (None where the platform does not say)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024.0, 1)
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Windows
        return None
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    return round(kib / 1024.0, 1)


def _setup_logging() -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    logging.getLogger("matplotlib").setLevel(logging.WARNING)


def run_logged(spec: dict) -> dict:
    """One session with this process's stdout and stderr (and so its log lines) in ``spec["log"]``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(spec["log"], "ab") as log_file:
        os.dup2(log_file.fileno(), 1)
        os.dup2(log_file.fileno(), 2)
    try:
        release_freed_memory()  # what the session before kept: this session's peak is its own
        _reset_peak_rss()
        reply = run(spec)
        reply["peak_rss_mb"] = _peak_rss_mb()
        reply["process"] = os.getpid()
        return reply
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])


def serve() -> int:
    """Run the sessions sent on stdin, one at a time, until stdin closes (module docstring)."""
    replies = os.fdopen(os.dup(1), "w", encoding="utf-8")  # the replies' own channel ...
    os.dup2(2, 1)  # ... so that what a session prints cannot mix into them
    _setup_logging()
    from ..workflow import calibrate_session  # noqa: F401 - imported once here, not in the first session

    for line in sys.stdin.buffer:
        reply = run_logged(json.loads(line))
        replies.write(json.dumps(reply) + "\n")
        replies.flush()
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    keep_freed_memory()  # a session process detects and solves as the command does
    _exit_with_parent()
    if argv == ["--serve"]:
        return serve()
    _setup_logging()
    reply = run(json.loads(argv[0]))
    reply["peak_rss_mb"] = _peak_rss_mb()
    sys.stdout.write(json.dumps(reply) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":  # pragma: no cover - run as the imported module: one copy of its functions
    from handeye.batch.child import main as _main

    sys.exit(_main())
