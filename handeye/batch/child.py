"""``python -m handeye.batch.child SPEC_JSON``: one session of a batch, in its own process.

Runs :func:`handeye.workflow.calibrate_session` with the ``handeye calibrate`` options of the spec
(:func:`handeye.options.options_from_args`: the single command's results, bit for bit) and
prints one JSON line on stdout: ``outcome`` (``done``, or ``error`` when the workflow raised),
``status``, ``verdict``, ``reason``, ``exit_code`` and ``peak_rss_mb`` (the process's peak memory).
Log lines go to stderr (the task keeps them in ``batch.log``). The process ends itself when its
parent (the Dask worker) is gone, so a killed worker leaves no session running behind it.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import threading
import time
from pathlib import Path

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
    from ..errors import HandeyeError
    from ..options import options_from_args
    from ..workflow import calibrate_session
    from .run import calibrate_namespace

    cal = spec["calibrate"]
    _wait_for_previous_attempt(spec["out_dir"])
    if spec.get("verify_against"):
        return run_verify(spec)
    args = calibrate_namespace(cal)
    try:  # as handeye calibrate runs it (handeye.cli.calibrate.run)
        wr = calibrate_session(
            spec["session"],
            options=options_from_args(args),
            out_dir=spec["out_dir"],
            report=not cal.get("no_report"),
            qa=cal.get("qa"),
            mode=cal.get("mode"),
            progress=lambda s: log.info("%s", s),
            allow_outside=bool(cal.get("allow_outside")),
            site_files=[f for f in (cal.get("config"), cal.get("qa")) if f],
            prior=cal.get("prior"),
            board_unmoved=bool(cal.get("board_unmoved")),
        )
    except HandeyeError as e:
        return {"outcome": "error", "status": "failed", "verdict": "ERROR", "reason": str(e), "exit_code": e.exit_code}
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


def _peak_rss_mb():
    """Peak resident memory of this process in MiB (None where the platform does not say)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Windows
        return None
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    return round(kib / 1024.0, 1)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    _exit_with_parent()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s", stream=sys.stderr)
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    reply = run(json.loads(argv[0]))
    reply["peak_rss_mb"] = _peak_rss_mb()
    sys.stdout.write(json.dumps(reply) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
