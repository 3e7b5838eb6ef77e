"""The long-lived session processes of a batch: one per worker thread, each running sessions one at a time.

A :class:`SessionProcess` is ``python -m handeye.batch.child --serve`` (handeye imported once), fed one
task spec per line; a session that kills it or hangs ends it, and the next session gets a fresh one. What
the process wrote on its own stderr while it ran a session it did not survive (an uncaught exception's
traceback: the session's log is its stderr only while the session runs) is added to that session's log.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from typing import IO, Optional

#: session on one core), the same on every worker, so a session's numbers do not depend on where it ran
SESSION_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: sessions one session process runs before it is replaced by a fresh one (bounds what a session may leave behind)
SESSIONS_PER_PROCESS = 100
#: seconds a session process that ended its replies without one gets to exit on its own (its exit code says how)
ENDING_WAIT_S = 5.0


class SessionProcess:
    """A long-lived ``python -m handeye.batch.child --serve`` process that runs sessions one at a time.

    Replaced by a fresh one when a session kills it or hangs, and after :data:`SESSIONS_PER_PROCESS` sessions.
    """

    def __init__(self) -> None:
        self.proc: Optional[subprocess.Popen] = None
        self.own_log: Optional[IO[bytes]] = None  # the process's stderr between sessions (its start-up)
        self.served = 0
        self._mark = 0  # the own log's size when the current session was sent

    def _start(self) -> subprocess.Popen:
        self.own_log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "handeye.batch.child", "--serve"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.own_log,
            start_new_session=True,
            env={**os.environ, **SESSION_ENV},
        )
        self.served = 0
        return self.proc

    def close(self, *, kill: bool = False) -> Optional[int]:
        """End the process (closing its stdin; ``kill``: at once) and return its exit code."""
        proc, self.proc = self.proc, None
        if proc is None:
            return None
        if kill:
            _kill_group(proc)
        for f in (proc.stdin, proc.stdout):
            try:
                if f is not None:
                    f.close()
            except OSError:
                pass
        try:
            code = proc.wait(timeout=None if kill else 10)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            code = proc.wait()
        if self.own_log is not None:
            self.own_log.close()
            self.own_log = None
        return code

    def _end_session(self, log: str, *, ending: bool) -> Optional[int]:
        """Kill the process during a session and add what it wrote on its own stderr since then to ``log``.

        That is its start-up for a fresh process, and an uncaught exception's traceback: the session's own log
        is its stderr only until the exception leaves the session. ``ending``: the process closed its replies,
        so it gets :data:`ENDING_WAIT_S` to exit on its own first. Returns the exit code.
        """
        own, self.own_log = self.own_log, None  # kept open until the process has ended
        if ending and self.proc is not None:
            try:
                self.proc.wait(timeout=ENDING_WAIT_S)
            except subprocess.TimeoutExpired:
                pass
        code = self.close(kill=True)  # its process group: what it started goes with it
        if own is not None:
            try:
                own.seek(self._mark)
                words = own.read()
            finally:
                own.close()
            if words.strip():
                with open(log, "ab") as f:
                    f.write(words if words.endswith(b"\n") else words + b"\n")
        return code

    def run(self, spec: dict, timeout_s: float) -> tuple[str, Optional[dict], Optional[int]]:
        """(``reply``, the reply, None) | (``timeout``, None, None) | (``died``, None, exit code) of one session.

        ``spec["log"]``: the session's log, which gets what the process wrote on its own stderr when it ends
        without a reply (:meth:`_end_session`).
        """
        proc = self.proc if self.proc is not None and self.proc.poll() is None else None
        if proc is None or self.served >= SESSIONS_PER_PROCESS:
            self.close()
            proc = self._start()
        assert proc.stdin is not None and proc.stdout is not None, "the process is started with pipes"
        try:
            proc.stdin.write((json.dumps(spec) + "\n").encode("utf-8"))
            proc.stdin.flush()
        except OSError:  # it died between two sessions: this session has not started, so in a fresh one
            self.close(kill=True)
            proc = self._start()
            assert proc.stdin is not None and proc.stdout is not None, "the process is started with pipes"
            proc.stdin.write((json.dumps(spec) + "\n").encode("utf-8"))
            proc.stdin.flush()
        self.served += 1
        assert self.own_log is not None, "the process is started with its own log"
        # where this session's part of the own log starts (a fresh process: with its start-up); its size, read
        # without moving the offset the process writes at
        self._mark = 0 if self.served == 1 else os.fstat(self.own_log.fileno()).st_size
        assert proc.stdout is not None, "the process is started with pipes"
        line = _read_line(proc.stdout.fileno(), time.monotonic() + timeout_s)
        if line is None:
            self._end_session(spec["log"], ending=False)
            return "timeout", None, None
        try:
            reply = json.loads(line) if line else None
        except ValueError:
            reply = None
        if not isinstance(reply, dict):
            return "died", None, self._end_session(spec["log"], ending=True)
        return "reply", reply, None


def _read_line(fd: int, deadline: float) -> Optional[bytes]:
    """One line from ``fd`` (b"" at its end) before ``deadline`` (time.monotonic), else None."""
    import select

    buf = b""
    while not buf.endswith(b"\n"):
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return None
        chunk = os.read(fd, 65536)
        if not chunk:
            return buf
        buf += chunk
    return buf


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
