"""handeye.report.figure_process: the figures a command's early-forked process draws are the ones drawn here.

Whatever that process cannot give (it died, its inputs cannot be sent) is drawn in the command's process, and
the process is always reaped: no figure lost, no process left behind.
"""

from __future__ import annotations

import os
import sys

import pytest

from handeye.cli import main as cli_main
from handeye.pipeline import CalibrateOptions
from handeye.report import build_report_context, figure_process, figures
from handeye.report.context import add_figures
from handeye.sim.scenarios import default_intrinsics
from handeye.sim.vendor import write_vendor_session
from handeye.workflow import calibrate_session

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the figure process is Linux only")

KEYS = ["residuals", "per_view", "coverage", "poses", "rotations", "uncertainty"]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("figure_process")
    return write_vendor_session(
        root / "session", n_views=8, seed=2, image_noise=1.0, intrinsics=default_intrinsics(640, 480)
    )


@pytest.fixture(scope="module")
def inputs(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("figure_process_result")
    wf = calibrate_session(session, options=CalibrateOptions(refine=True), out_dir=out, report=False)
    assert wf.status == "ok", wf.result.get("failure_reason")
    return build_report_context(out, make_plots=False)["figure_inputs"]


@pytest.fixture
def two_cores(monkeypatch):
    monkeypatch.delenv("HANDEYE_FIGURE_PROCESSES", raising=False)
    monkeypatch.setattr(figures, "parallel_drawing", lambda: True)


def _here(inputs, monkeypatch) -> list:
    monkeypatch.setattr(figures, "parallel_drawing", lambda: False)
    return figures.report_figures(**inputs)


def _gone(pid: int) -> bool:
    """Reaped: not a child of this process any more (a zombie would still be waitable)."""
    try:
        os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return True
    return False


def test_the_process_draws_the_figures_drawn_here(inputs, two_cores, monkeypatch):
    proc = figure_process.start()
    assert proc is not None
    got = proc.figures(inputs)
    assert proc.exit_code == 0 and _gone(proc.pid)
    assert got is not None and [p.key for p in got] == KEYS
    assert got == _here(inputs, monkeypatch)  # key, title, caption and the PNG bytes


def test_a_process_that_died_costs_no_figure(inputs, two_cores, monkeypatch):
    import signal

    proc = figure_process.start()
    assert proc is not None
    os.kill(proc.pid, signal.SIGKILL)
    ctx = add_figures({"figure_inputs": inputs}, proc)  # it cannot answer: drawn here
    assert proc.exit_code == -signal.SIGKILL and _gone(proc.pid)
    assert ctx["plots"] == _here(inputs, monkeypatch)


def test_inputs_that_cannot_be_sent_are_drawn_here(inputs, two_cores):
    proc = figure_process.start()
    assert proc is not None
    assert proc.figures({**inputs, "notes": {"f": lambda: None}}) is None  # a lambda does not pickle
    assert proc.exit_code is not None and _gone(proc.pid)


def test_an_unused_process_is_reaped(two_cores):
    with figure_process.figure_process(start_now=True) as proc:
        assert proc is not None and proc.pid is not None
        pid = proc.pid
        assert proc.start()  # running: a second start forks nothing
        assert proc.pid == pid
    assert _gone(pid) and proc.exit_code is not None
    proc.close()  # closing twice is harmless
    with figure_process.figure_process(enabled=False) as none:
        assert none is None


def test_a_process_never_started_forks_nothing_and_draws_nothing(inputs, two_cores):
    with figure_process.figure_process() as proc:
        assert proc is not None and proc.pid is None
        assert proc.figures(inputs) is None  # the caller draws them
    assert proc.pid is None and proc.exit_code is None


def test_one_core_or_the_switch_starts_no_process(monkeypatch):
    monkeypatch.setattr(figures, "parallel_drawing", lambda: False)
    assert figure_process.start() is None


@pytest.mark.parametrize("no_report", [False, True])
def test_calibrate_draws_its_report_in_the_process(session, tmp_path, two_cores, monkeypatch, no_report):
    """``handeye calibrate`` starts the process once its images are detected, and its report has every figure
    from it; ``--no-report`` starts none."""
    import handeye.pipeline as pipeline

    started: list = []
    detected: list = []
    start = figure_process.FigureProcess.start
    detect = pipeline.detect_views

    def spy(self):
        started.append((self, len(detected)))  # how many detections had run when it forked
        return start(self)

    def detect_spy(*a, **kw):
        detected.append(1)
        return detect(*a, **kw)

    monkeypatch.setattr(figure_process.FigureProcess, "start", spy)
    monkeypatch.setattr(pipeline, "detect_views", detect_spy)
    out = tmp_path / "out"
    code = cli_main(["-q", "calibrate", str(session), "--out", str(out), *(["--no-report"] if no_report else [])])
    assert code == 0
    if no_report:
        assert started == [] and not (out / "report.html").exists()
        return
    proc, n_detected = started[0]
    assert n_detected == 1  # after the detection
    assert proc.pid is not None and proc.exit_code == 0 and _gone(proc.pid)  # it answered, then ended on its own
    html = (out / "report.html").read_text(encoding="utf-8")
    assert html.count('src="data:image/png;base64,') >= len(KEYS)


def test_a_stuck_process_is_ended_and_the_figures_drawn_here(inputs, two_cores, monkeypatch):
    """A child that reads nothing (stopped here; a lock another thread held at the fork) costs its wait only."""
    import pickle
    import signal
    import time

    assert len(pickle.dumps(inputs)) > 1 << 16  # more than a pipe holds: the write itself would wait
    proc = figure_process.start()
    assert proc is not None
    os.kill(proc.pid, signal.SIGSTOP)
    t0 = time.monotonic()
    assert proc.figures(inputs, wait_s=1.0) is None  # the inputs (over a pipe's buffer) are never read
    assert time.monotonic() - t0 < 30
    assert proc.exit_code == -signal.SIGKILL and _gone(proc.pid)
