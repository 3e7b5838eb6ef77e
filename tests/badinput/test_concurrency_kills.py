"""Bad input, class "concurrency and kills": a second run into a folder in use is refused (the lock
names the holder's pid), a killed run's lock is stale and taken over, and SIGKILL at any point of a
calibration (a good one and a failing one) or of a report rebuild leaves the previous or the new
state, nothing half-written: every JSON file parses, the last good result is readable, a report
never describes another run than result.json's, and the next run leaves no temporary file behind.

The killed runs are forked from the test process (the imports are warm) and kill themselves at a
named write: before or after the n-th ``os.replace`` onto a file, or inside its ``fsync``."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from handeye.cli import main


def _kill_point(when: str, name: str, nth: int):
    """Patch os.replace / os.fsync (in the forked child only) to SIGKILL the process at the point."""
    count = {"replace": 0, "fsync": 0}
    real_replace, real_fsync = os.replace, os.fsync

    def die():
        os.kill(os.getpid(), signal.SIGKILL)

    def replace(src, dst):
        hit = os.path.basename(str(dst)) == name
        if hit:
            count["replace"] += 1
        if hit and count["replace"] == nth and when == "before":
            die()
        real_replace(src, dst)
        if hit and count["replace"] == nth and when == "after":
            die()

    def fsync(fd):
        if when == "fsync" and os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(f".{name}."):
            count["fsync"] += 1
            if count["fsync"] == nth:
                die()
        return real_fsync(fd)

    os.replace, os.fsync = replace, fsync


def _fast_diagnostics():
    import handeye.diagnose

    handeye.diagnose.diagnose_run = lambda run: {"findings": []}
    handeye.diagnose.diagnose_session_error = lambda *a, **k: {"findings": []}


def run_killed(argv: list, when: str, name: str, nth: int = 1) -> None:
    """Run ``handeye argv`` in a forked child that SIGKILLs itself at the point; assert it got there."""
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            _fast_diagnostics()
            _kill_point(when, name, nth)
            main(["-q", *map(str, argv)])
        finally:
            os._exit(0)
    deadline = time.monotonic() + 120
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail(f"the run did not reach {when} {name} #{nth} within 120 s")
        time.sleep(0.02)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, (
        f"the run ended without reaching {when} {name} #{nth}"
    )


def check_folder(out, *, old_run_id: str) -> dict:
    """Nothing half-written: every JSON parses, the last good result is the good one (or newer and
    good), the reports belong to result.json's run, observations.json is ignored unless of that run."""
    from handeye.report.folder import read_result_folder

    for p in out.glob("*.json"):
        json.loads(p.read_text())  # raises on a half-written file
    res = json.loads((out / "result.json").read_text())
    last = json.loads((out / "result.last-good.json").read_text())
    assert last["status"] == "ok" and last["verdict"] in ("PASS", "WARN")
    assert old_run_id in (res["run_id"], last["run_id"]) or last["run_id"] == res["run_id"]  # old, or all new
    for rep in ("report.html", "report.md"):
        if (out / rep).exists():
            assert res["run_id"] in (out / rep).read_text(), f"{rep} describes another run"
    folder = read_result_folder(out)
    assert not folder.observations or folder.observations.get("run_id") == res["run_id"]
    return res


def next_run_cleans(out, bad_session) -> None:
    """The next run (a failing one, quick) leaves no temporary file and no lock; last good survives."""
    _fast = __import__("handeye.diagnose", fromlist=["x"])
    real = _fast.diagnose_session_error
    _fast.diagnose_session_error = lambda *a, **k: {"findings": []}
    try:
        assert main(["-q", "calibrate", str(bad_session), "--out", str(out), "--no-report"]) == 2
    finally:
        _fast.diagnose_session_error = real
    stray = [p for p in out.rglob("*") if p.name.endswith(".tmp") or p.name == ".handeye.lock"]
    assert not stray, stray
    assert json.loads((out / "result.last-good.json").read_text())["status"] == "ok"


@pytest.fixture
def bad_session(tiny_vendor, tmp_path):
    s = tmp_path / "bad"
    shutil.copytree(tiny_vendor, s)
    (s / "poses.txt").write_text("0.5,0.1,0.4,0.1,0.2\n")
    return s


@pytest.fixture
def out(good_result, tmp_path):
    o = tmp_path / "out"
    shutil.copytree(good_result, o)
    return o


GOOD_RUN_POINTS = [  # result.json is written once
    ("before", "3.jpg", 1),
    ("after", "3.jpg", 1),
    ("before", "observations.json", 1),
    ("fsync", "observations.json", 1),
    ("after", "observations.json", 1),
    ("before", "result.json", 1),
    ("fsync", "result.json", 1),
    ("after", "result.json", 1),
    ("before", "result.last-good.json", 1),
    ("fsync", "result.last-good.json", 1),
    ("after", "result.last-good.json", 1),
]


@pytest.mark.parametrize("when, name, nth", GOOD_RUN_POINTS, ids=[f"{w}-{n}-{k}" for w, n, k in GOOD_RUN_POINTS])
def test_kill_a_calibration(when, name, nth, tiny_vendor, out, bad_session):
    old = json.loads((out / "result.json").read_text())["run_id"]
    run_killed(
        ["calibrate", tiny_vendor, "--out", out, "--no-refine", "--no-report", "--workers", "1"], when, name, nth
    )
    check_folder(out, old_run_id=old)
    next_run_cleans(out, bad_session)


FAILING_RUN_POINTS = [  # result.json once, then its reports
    ("before", "result.previous.json", 1),
    ("fsync", "result.previous.json", 1),
    ("after", "result.previous.json", 1),
    ("before", "result.json", 1),
    ("fsync", "result.json", 1),
    ("after", "result.json", 1),
    ("before", "report.html", 1),
    ("after", "report.html", 1),
    ("before", "report.md", 1),
]


@pytest.mark.parametrize("when, name, nth", FAILING_RUN_POINTS, ids=[f"{w}-{n}-{k}" for w, n, k in FAILING_RUN_POINTS])
def test_kill_a_failing_calibration(when, name, nth, out, bad_session):
    old = json.loads((out / "result.json").read_text())["run_id"]
    run_killed(["calibrate", bad_session, "--out", out], when, name, nth)
    res = check_folder(out, old_run_id=old)
    assert res["run_id"] == old or res["status"] == "failed"
    next_run_cleans(out, bad_session)


REPORT_POINTS = [("before", "report.html", 1), ("fsync", "report.md", 1), ("after", "report.html", 1)]


@pytest.mark.parametrize("when, name, nth", REPORT_POINTS, ids=[f"{w}-{n}-{k}" for w, n, k in REPORT_POINTS])
def test_kill_a_report_rebuild(when, name, nth, out, bad_session):
    old = json.loads((out / "result.json").read_text())["run_id"]
    run_killed(["report", out], when, name, nth)
    check_folder(out, old_run_id=old)
    assert (out / "report.md").exists() and (out / "report.html").exists()  # the old or the new report
    next_run_cleans(out, bad_session)


@pytest.fixture
def live_pid():
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield p.pid
    p.kill()
    p.wait()


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@pytest.mark.parametrize("command", ["calibrate", "report"])
def test_a_folder_in_use_is_refused(command, live_pid, out, tiny_vendor, run_cli, names):
    (out / ".handeye.lock").write_text(f"{live_pid}\n")
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    argv = ["calibrate", tiny_vendor, "--out", out, "--no-report"] if command == "calibrate" else ["report", out]
    rc, err = run_cli(*argv)
    assert rc == 2
    names(err, f"pid {live_pid}", "in use")
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before  # nothing touched


@pytest.mark.parametrize("content", ["dead", "", "garbage\n", "-5\n"])
def test_a_stale_lock_is_taken_over(content, out, bad_session, run_cli):
    (out / ".handeye.lock").write_text(f"{_dead_pid()}\n" if content == "dead" else content)
    rc, err = run_cli("calibrate", bad_session, "--out", out, "--no-report")
    assert rc == 2 and "in use" not in err
    assert not (out / ".handeye.lock").exists()


def _hold_the_lock(folder, start: float, held) -> None:
    """Take ``folder``'s lock at ``start`` (time.time()), hold it 0.2 s; ``held`` gets (taken, released)."""
    from handeye.errors import OutputError
    from handeye.output import FolderLock

    while time.time() < start:
        pass
    try:
        with FolderLock(folder):
            t0 = time.time()
            time.sleep(0.2)
            held.put((t0, time.time()))
    except OutputError:
        held.put(None)


@pytest.mark.parametrize("before", ["none", "stale"])
def test_runs_starting_together_never_hold_one_folder_at_once(out, before):
    """Four processes take one folder's lock at the same instant, with no lock file or a stale one: at most one
    holds it at any time (reading the holder, taking a stale lock over and writing the pid are one step)."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    for _ in range(3):
        if before == "stale":
            (out / ".handeye.lock").write_text(f"{_dead_pid()}\n")
        held = ctx.Queue()
        start = time.time() + 0.3
        procs = [ctx.Process(target=_hold_the_lock, args=(out, start, held)) for _ in range(4)]
        for p in procs:
            p.start()
        for p in procs:
            p.join()
        spans = [s for s in (held.get() for _ in procs) if s is not None]
        assert len(spans) >= 1
        assert not any(a[0] < b[1] and b[0] < a[1] for i, a in enumerate(spans) for b in spans[i + 1 :]), spans


def test_two_concurrent_runs_one_refused(out, tiny_vendor, tmp_path):
    """Two processes into one folder at once: one writes, the other is refused with exit code 2."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    code = (
        "import sys, time, handeye.workflow as w\n"
        "real = w._calibrate_locked\n"
        "def slow(*a, **k):\n    time.sleep(4)\n    return real(*a, **k)\n"
        "w._calibrate_locked = slow\n"
        "from handeye.cli import main\n"
        f"sys.exit(main(['-q', 'calibrate', {str(tiny_vendor)!r}, '--out', {str(out)!r}, '--no-refine', "
        "'--no-report']))"
    )
    first = subprocess.Popen([sys.executable, "-c", code], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (out / ".handeye.lock").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    rc = main(["-q", "calibrate", str(tiny_vendor), "--out", str(out), "--no-report"])
    assert rc == 2
    assert first.wait(timeout=120) == 0, first.stderr.read()
