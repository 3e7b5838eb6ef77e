"""handeye.report.figures: the figures drawn in two processes are the ones drawn in one, and none is lost."""

from __future__ import annotations

import os
import sys

import pytest

from handeye.report import figures

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the forked drawing is Linux only")


def _draws(parent_pid: int, *, die_in_child: str = "", fail: str = "") -> dict:
    """Five 'figures' whose bytes name the figure (and not the process that drew it)."""

    def draw(key: str):
        def f() -> bytes:
            if key == fail:
                raise ValueError("cannot draw this one")
            if key == die_in_child and os.getpid() != parent_pid:
                os._exit(3)  # the child dies without sending anything
            return f"png of {key}".encode()

        return f

    return {k: draw(k) for k in ("a", "b", "c", "d", "e")}


@pytest.fixture
def two_processes(monkeypatch):
    monkeypatch.delenv("HANDEYE_FIGURE_PROCESSES", raising=False)
    monkeypatch.setattr(figures, "parallel_drawing", lambda: True)


def test_two_processes_draw_what_one_draws(two_processes, monkeypatch):
    got = figures.draw_figures(_draws(os.getpid()))
    monkeypatch.setenv("HANDEYE_FIGURE_PROCESSES", "1")
    monkeypatch.setattr(figures, "parallel_drawing", lambda: False)
    assert got == figures.draw_figures(_draws(os.getpid()))
    assert list(got) == ["a", "b", "c", "d", "e"] and got["d"] == b"png of d"


def test_the_child_draws_every_other_figure(two_processes, monkeypatch):
    """The child's figures come back from the child: drawn here, they would say so."""
    me = os.getpid()
    where = {k: (lambda k=k: f"{k} by {'parent' if os.getpid() == me else 'child'}".encode()) for k in "abcd"}
    got = figures.draw_figures(where)
    assert got == {"a": b"a by parent", "b": b"b by child", "c": b"c by parent", "d": b"d by child"}


def test_a_child_that_dies_costs_no_figure(two_processes, caplog):
    """The child exits before sending (a crash): its figures are drawn in this process."""
    got = figures.draw_figures(_draws(os.getpid(), die_in_child="b"))
    assert got == {k: f"png of {k}".encode() for k in "abcde"}


def test_a_figure_that_fails_is_left_out_in_either_process(two_processes, caplog):
    got = figures.draw_figures(_draws(os.getpid(), fail="d"))  # "d" is the child's
    assert got["d"] is None and all(got[k] == f"png of {k}".encode() for k in "abce")
    got = figures.draw_figures(_draws(os.getpid(), fail="c"))  # "c" is this process's
    assert got["c"] is None and got["d"] == b"png of d"
    assert "figure c left out" in caplog.text


def test_one_figure_or_the_switch_draws_here(monkeypatch):
    monkeypatch.setattr(figures, "_fork_drawing", lambda draws: pytest.fail("no child for one figure"))
    assert figures.draw_figures({"x": lambda: b"x"}) == {"x": b"x"}
    monkeypatch.setenv("HANDEYE_FIGURE_PROCESSES", "1")
    assert figures.parallel_drawing() is False


def test_a_child_that_hangs_is_ended_and_its_figures_drawn_here(two_processes, monkeypatch):
    """A child stuck at a lock (fork with threads) does not hang the report: it is killed, its figures redrawn."""
    import time

    monkeypatch.setattr(figures, "CHILD_GRACE_S", 0.5)
    me = os.getpid()

    def hang_in_child() -> bytes:
        if os.getpid() != me:
            time.sleep(600)
        return b"png of b"

    draws = {"a": lambda: b"png of a", "b": hang_in_child}
    t0 = time.monotonic()
    assert figures.draw_figures(draws) == {"a": b"png of a", "b": b"png of b"}
    assert time.monotonic() - t0 < 60  # ended at its limit, not after the child's 600 s


def test_the_child_inherits_the_drawing_modules():
    """Inside the report's style the child finds matplotlib's figure and Agg modules already imported.

    A fresh process: importing the report's figures module imports no matplotlib; the forked child's draw
    sees the modules every figure draws with in sys.modules before it imports anything (it would import them a
    second time otherwise: 0.2 s of CPU).
    """
    import subprocess

    code = """
import os, sys
from handeye.report import figures
from handeye.report.plots import style
assert "matplotlib" not in sys.modules
figures.parallel_drawing = lambda: True
parent = os.getpid()
def seen():
    assert os.getpid() != parent
    mods = ("matplotlib.figure", "matplotlib.backends.backend_agg", "PIL.Image")
    return repr([m in sys.modules for m in mods]).encode()
with style():
    got = figures.draw_figures({"a": lambda: b"", "b": seen})
print(got["b"].decode())
"""
    env = {k: v for k, v in os.environ.items() if k != "HANDEYE_FIGURE_PROCESSES"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert p.stdout.split() == ["[True,", "True,", "True]"]


def test_the_per_view_bars_draw_a_qa_limit_only_within_the_axis_and_keep_off_scale_labels_clear(monkeypatch):
    """A QA limit just above the bars was put in the legend and drawn above the axis, where no one sees it; an
    off-scale bar's printed value was crossed by the QA fail line. A limit is drawn (and in the legend) only within
    the axis, and an off-scale value sits on a patch of its bar's colour, over the lines."""
    from matplotlib.axes import Axes

    from handeye.report.plots.residuals import per_view_bars

    drawn, texts = [], []
    axhline, text = Axes.axhline, Axes.text
    monkeypatch.setattr(
        Axes, "axhline", lambda self, y, **kw: drawn.append((y, kw.get("label"))) or axhline(self, y, **kw)
    )
    monkeypatch.setattr(Axes, "text", lambda self, *a, **kw: texts.append((a, kw)) or text(self, *a, **kw))
    # bars up to 1.0 px: the axis ends at 1.1; the warn limit 1.2 is above it, the fail limit 0.9 within
    per_view_bars(["1", "2", "3"], [0.8, 1.0, 0.9], [None, None, None], ["used"] * 3, warn_px=1.2, fail_px=0.9)
    assert [label for _, label in drawn] == ["QA fail 0.9 px"], drawn
    drawn.clear()
    # one gross view, cut at 1.3 x the fail limit: its value is printed over the lines
    ids, cam, chain = [str(k) for k in range(1, 9)], [0.2, 0.3, 0.25] * 2 + [0.3, 166.0], [0.4] * 7 + [155.0]
    per_view_bars(ids, cam, chain, ["used"] * 8, warn_px=0.5, fail_px=1.0)
    assert [label for _, label in drawn] == ["QA warn 0.5 px", "QA fail 1 px"], drawn
    off = [(a[2], kw) for a, kw in texts if "px ↑" in str(a[2])]
    assert [t for t, _ in off] == ["166 px ↑", "155 px ↑"], texts
    assert all(kw["zorder"] > 2 and kw["bbox"]["facecolor"] != "none" for _, kw in off), off
