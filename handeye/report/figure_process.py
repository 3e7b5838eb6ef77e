"""A process started with a command that imports matplotlib while the calibration runs, then draws the figures.

A report's figures cost matplotlib's import (about a quarter of a second) before the first line is drawn.
A command that will write a report forks this process where a second core is free: ``handeye report``
at once, ``handeye calibrate`` once its images are detected (detection uses both cores). The child
imports matplotlib, PIL and the figure modules while the parent works (the solver's imports, the
refinement, the validation, the diagnostics), then waits for the figures' inputs. When the report is
built, the parent sends them (pickled; about 0.3 MB for 20 views) and the child draws the figures with
:func:`handeye.report.figures.report_figures` (itself in two processes) and sends back the PNGs.

The figures are the same either way: the child runs the same code on the same inputs. Whatever the child
does not return (it could not start, failed, was killed or took too long) is drawn by the parent, as
without it. A command that ends without a report closes the child, which then leaves at once. Linux only
(fork) and only with a second core; ``HANDEYE_FIGURE_PROCESSES=1`` draws everything in the command's
process.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import signal
import time
from typing import TYPE_CHECKING, Iterator, Optional

if TYPE_CHECKING:
    from .figures import Plot

log = logging.getLogger(__name__)

#: how long the parent waits for the child's figures before it kills it and draws them itself
WAIT_S = 60.0


class FigureProcess:
    """The figure process of one command: :meth:`start` (forks, once), :meth:`figures` once, :meth:`close` always."""

    def __init__(self) -> None:
        self.pid: Optional[int] = None
        self._to_child: Optional[int] = None
        self._from_child: Optional[int] = None
        self._status: Optional[int] = None
        self._started = False

    def start(self) -> bool:
        """Fork the process now (it starts importing at once); only the first call forks. Whether it runs."""
        if not self._started:
            self._started = True
            forked = _fork()
            if forked is not None:
                self.pid, self._to_child, self._from_child = forked
        return self.pid is not None and self._status is None

    def figures(self, inputs: dict, *, wait_s: float = WAIT_S) -> Optional[list[Plot]]:
        """The report's figures of ``inputs`` (the keyword arguments of ``report_figures``) drawn by the child.

        None when the child cannot give them (it was used already, ended, failed, or took over ``wait_s``):
        the caller then draws them itself.
        """
        if self.pid is None or self._to_child is None or self._from_child is None:
            return None  # never started, or used already
        from .figures import Plot, read_all, write_all

        deadline = time.monotonic() + wait_s
        try:
            data = pickle.dumps(inputs, protocol=pickle.HIGHEST_PROTOCOL)
            if not write_all(self._to_child, data, deadline=deadline):
                raise TimeoutError(f"it read no inputs in {wait_s:g} s")
        except (OSError, pickle.PicklingError, TypeError, AttributeError) as e:
            log.debug("report: figures drawn here (the figure process did not take its inputs: %s)", e)
            self.close()
            return None
        finally:
            self._close_to_child()
        raw = read_all(self._from_child, deadline=deadline)
        self.close(kill=raw is None)  # at the end of its output the child is leaving: waited for, not killed
        if raw is None or self._status != 0:
            log.debug("report: figures drawn here (the figure process ended with status %s)", self._status)
            return None
        try:
            got = pickle.loads(raw)
        except (pickle.UnpicklingError, EOFError, ValueError, AttributeError):
            return None
        if not (isinstance(got, list) and all(isinstance(p, Plot) for p in got)):
            return None
        return got

    @property
    def exit_code(self) -> Optional[int]:
        """The child's exit code once reaped (0: it ended on its own; -9: it was killed), None before."""
        return self._status

    def _close_to_child(self) -> None:
        if self._to_child is not None:
            with contextlib.suppress(OSError):
                os.close(self._to_child)
            self._to_child = None

    def close(self, *, kill: bool = True) -> None:
        """End the child and reap it.

        It leaves on its own once it knows there are no inputs; with ``kill``, a child still running
        (importing, drawing figures no one will read, or stuck) is killed first.
        """
        self._close_to_child()
        if self._from_child is not None:
            with contextlib.suppress(OSError):
                os.close(self._from_child)
            self._from_child = None
        if self.pid is not None and self._status is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG if kill else 0)
                if pid == 0:
                    with contextlib.suppress(OSError):
                        os.kill(self.pid, signal.SIGKILL)
                    _, status = os.waitpid(self.pid, 0)
                self._status = os.waitstatus_to_exitcode(status)
            except ChildProcessError:  # reaped elsewhere (a caller's own wait): nothing left to end
                self._status = -1


def start() -> Optional[FigureProcess]:
    """A figure process forked now, or None where figures are drawn in one process."""
    proc = FigureProcess()
    return proc if proc.start() else None


def _fork() -> Optional[tuple[int, int, int]]:
    """(pid, the write end of its inputs, the read end of its figures), or None (one core, no fork)."""
    from .figures import fork_quietly, parallel_drawing

    if not parallel_drawing():
        return None
    try:
        inputs_r, inputs_w = os.pipe()
        out_r, out_w = os.pipe()
    except OSError:
        return None
    try:
        pid = fork_quietly()
    except OSError as e:
        log.debug("report: no figure process (fork: %s)", e)
        for fd in (inputs_r, inputs_w, out_r, out_w):
            os.close(fd)
        return None
    if pid == 0:
        _child(inputs_r, inputs_w, out_r, out_w)  # never returns
    os.close(inputs_r)
    os.close(out_w)
    return pid, inputs_w, out_r


@contextlib.contextmanager
def figure_process(enabled: bool = True, *, start_now: bool = False) -> Iterator[Optional[FigureProcess]]:
    """The command's :class:`FigureProcess`, closed (and reaped) when the block ends, however it ends.

    None when not ``enabled``, or with one core. ``start_now`` forks it at once; otherwise whoever knows
    when a core is free calls its ``start`` (the calibration once its images are detected).
    """
    proc = None
    if enabled:  # the figure modules are imported for a report only
        from .figures import parallel_drawing

        proc = FigureProcess() if parallel_drawing() else None
    if proc is not None and start_now:
        proc.start()
    try:
        yield proc
    finally:
        if proc is not None:
            proc.close()


def _child(inputs_r: int, inputs_w: int, out_r: int, out_w: int) -> None:
    """The figure process: import, wait for the inputs, draw, answer, and leave without any exit handler."""
    code = 1
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the command's to handle; it closes this process
        os.close(inputs_w)
        os.close(out_r)
        from .figures import read_all, report_figures, write_all
        from .plots.canvas import style

        with style():  # imports matplotlib, its Agg backend and PIL while the parent works
            pass
        raw = read_all(inputs_r, deadline=None)
        if raw:  # nothing: the command ends without a report
            plots = report_figures(**pickle.loads(raw))
            write_all(out_w, pickle.dumps(plots, protocol=pickle.HIGHEST_PROTOCOL))
        code = 0
    except BaseException:  # noqa: BLE001 - the child ends here whatever happens; the parent draws what it lacks
        pass
    finally:
        os._exit(code)
