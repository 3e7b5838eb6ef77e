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
