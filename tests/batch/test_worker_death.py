"""handeye batch when a Dask worker dies: stderr holds handeye's one line for the session, Dask's own log lines
about the death (a task lost and rescheduled, the worker restarted, the task given up) go to OUT/batch.log, and
the session's record keeps its reason."""

from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _session(folder: Path) -> Path:
    """A vendor session without its image (a quick FAIL, were it run)."""
    folder.mkdir(parents=True)
    (folder / "poses.txt").write_text("0.5,0.1,0.6,2.7,-0.2,0.1\n")
    (folder / "config.yaml").write_text("checkerboard_args:\n  XX: 11\n  YY: 8\n  L: 0.03\nmode: eye_in_hand\n")
    return folder


def _stderr_lines(err: str) -> list[str]:
    """The lines of stderr without the progress bar's redrawn states."""
    parts = (p.strip() for p in re.split(r"[\r\n]", err))
    return [p for p in parts if p and not re.search(r"\d+%\|", p)]


def test_a_worker_killed_by_its_session_leaves_handeye_s_line_on_stderr_and_dask_s_in_batch_log(
    tmp_path, worker_killing_hook
):
    """The session process of every session named ``*crash*`` kills its parent, the Dask worker (a hook on the
    session processes' PYTHONPATH), until Dask gives the task up. Before, the nanny's and the scheduler's warnings
    and errors about it (the worker restarted, the task given up) reached the user's stderr among handeye's lines.
    The session after it, on the same one worker, runs to its own end: before, Dask gave the worker a second task
    while it ran the first, counted each death against both, and lost the second with the first."""
    root, out = tmp_path / "root", tmp_path / "out"
    _session(root / "cell" / "2026-03-02-crash")
    _session(root / "cell" / "2026-03-03-next")  # waits for the one worker: the deaths are not counted against it
    hook = worker_killing_hook(tmp_path / "hook", "'crash' in spec['session']")
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(p for p in (str(hook), str(REPO), os.environ.get("PYTHONPATH")) if p),
        "DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "1",  # given up after two deaths: a shorter test
    }
    env.pop("DASK_LOGGING__DISTRIBUTED", None)  # as a user runs it
    argv = [sys.executable, "-m", "handeye", "batch", str(root), "--out", str(out), "--workers", "1", "--no-report"]
    p = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert p.returncode == 7, p.stdout + p.stderr
    lines = _stderr_lines(p.stderr)
    assert lines[0] == f"2 sessions in 1 installs under {root}", p.stderr
    assert sorted(lines[1:]) == [  # no line of Dask's
        "cell/2026-03-02-crash: ERROR (lost): the workers running it died, 2 in a row; Dask's account is in its "
        "batch.log",
        f"cell/2026-03-03-next: FAIL (done): {root / 'cell' / '2026-03-03-next'}: no numbered images (1.jpg, 2.jpg, "
        "...) in the folder",
    ], p.stderr
    nxt = json.loads((out / "cell" / "2026-03-03-next" / "batch.json").read_text())
    assert nxt["outcome"] == "done" and nxt["verdict"] == "FAIL", nxt  # its own outcome, not lost with the other

    rec = json.loads((out / "cell" / "2026-03-02-crash" / "batch.json").read_text())
    assert rec["outcome"] == "lost" and rec["verdict"] == "ERROR", rec
    assert rec["reason"] == "the workers running it died, 2 in a row; Dask's account is in its batch.log"
    session_log = (out / "cell" / "2026-03-02-crash" / "batch.log").read_text()
    assert "KilledWorker: Attempted to run task" in session_log, session_log
    batch_log = (out / "batch.log").read_text()
    assert "started: python -m handeye batch" in batch_log
    assert "distributed.nanny INFO: Worker process" in batch_log and "was killed by signal 9" in batch_log
    assert re.search(r"distributed\.scheduler ERROR: Task run_session-\S+ marked as failed", batch_log), batch_log
    row = next(r for r in (out / "fleet.csv").read_text().splitlines() if "2026-03-02-crash" in r)
    assert "the workers running it died" in row


def test_the_cluster_log_takes_dask_s_handlers_and_gives_them_back(tmp_path, capfd):
    """Dask imported before handeye configured logging has its own stderr handlers (``distributed``,
    ``distributed.client``): within the block its lines go to the file only, after it every logger is as it was."""
    import distributed  # noqa: F401 - its loggers and their handlers

    from handeye.cli.batch import CLUSTER_LOGGERS, cluster_log

    names = [n for n in logging.Logger.manager.loggerDict if n.split(".")[0] in CLUSTER_LOGGERS]
    loggers = [logging.getLogger(n) for n in {*names, *CLUSTER_LOGGERS}]
    before = {lg.name: (lg.handlers[:], lg.propagate, lg.level) for lg in loggers}
    stderr_handler = logging.StreamHandler(sys.stderr)
    logging.getLogger("distributed.client").addHandler(stderr_handler)  # as Dask's own set-up may leave it
    before["distributed.client"] = (
        logging.getLogger("distributed.client").handlers[:],
        *before["distributed.client"][1:],
    )
    capfd.readouterr()
    try:
        with cluster_log(tmp_path / "batch.log"):
            logging.getLogger("distributed.client").warning("Couldn't gather 1 keys, rescheduling")
            logging.getLogger("distributed.scheduler").error("Couldn't gather keys")
            logging.getLogger("distributed.nanny").info("Worker process 12 was killed by signal 9")
        assert capfd.readouterr().err == ""
        text = (tmp_path / "batch.log").read_text()
        for line in (
            "distributed.client WARNING: Couldn't gather 1 keys, rescheduling",
            "distributed.scheduler ERROR: Couldn't gather keys",
            "distributed.nanny INFO: Worker process 12 was killed by signal 9",
        ):
            assert line in text, text
        assert {lg.name: (lg.handlers[:], lg.propagate, lg.level) for lg in loggers} == before
    finally:
        logging.getLogger("distributed.client").removeHandler(stderr_handler)
