"""handeye.batch.run: a session that cannot run is recorded as failed with its reason and the batch goes on."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading

import numpy as np
import yaml

from handeye.batch.discover import discover
from handeye.batch.run import RECORD_NAME, plan_batch, run_batch
from handeye.cli import build_parser
from handeye.cli.batch import calibrate_options


def test_a_session_that_cannot_run_is_a_failed_record_and_no_worker_is_started(tmp_path):
    root, out = tmp_path / "root", tmp_path / "out"
    folder = root / "cell" / "2026-03-01"
    folder.mkdir(parents=True)
    views = [{"id": "1", "image": "1.jpg", "pose": [0] * 6, "t_image": 1.0e20}]
    (folder / "session.yaml").write_text(yaml.safe_dump({"handeye_session": 1, "verify_against": 5, "views": views}))
    calibrate = calibrate_options(build_parser().parse_args(["batch", str(root), "--out", str(out)]))
    jobs = discover(root)
    plan = plan_batch(jobs, out, calibrate=calibrate)
    assert plan.specs == [] and plan.skipped == [] and len(plan.refused) == 1
    rec = json.loads((out / "cell" / "2026-03-01" / RECORD_NAME).read_text())
    assert rec["outcome"] == "error" and rec["verdict"] == "ERROR" and "verify_against must be a path" in rec["reason"]
    assert rec["time_utc"] == "2026-03-01T00:00:00+00:00" and "t_image 1e+20 is not a time" in rec["warnings"][0]
    seen = []
    summary = run_batch(jobs, out, calibrate=calibrate, progress=seen.append)  # no task: no cluster is started
    assert [r["name"] for r in seen] == ["2026-03-01"] and summary.exit_code == 7
    assert summary.line().startswith("1 sessions: 0 done, 1 failed, 0 skipped (1 ERROR)")


def _hook_session_processes(tmp_path, monkeypatch, name: str, imports: str, *lines: str) -> None:
    """A hook on the session processes' PYTHONPATH (a sitecustomize): a session whose name holds ``name`` runs
    ``lines`` (after ``imports``) instead of its calibration; this thread's session process starts afresh."""
    from handeye.batch import run as batch_run

    hook = tmp_path / "hook"
    hook.mkdir()
    body = "".join(f"            {line}\n" for line in lines)
    (hook / "sitecustomize.py").write_text(
        "import sys\n"
        "if 'handeye.batch.child' in sys.orig_argv:\n"
        + (f"    {imports}\n" if imports else "")
        + "    import handeye.batch.child as c\n"
        "    _run = c.run\n"
        "    def run(spec):\n"
        f"        if {name!r} in spec['session']:\n" + body + "        return _run(spec)\n"
        "    c.run = run\n"
    )
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(hook), os.environ.get("PYTHONPATH")) if p))
    monkeypatch.setattr(batch_run, "_session_processes", threading.local())


def test_sessions_share_a_session_process_and_a_crash_takes_only_its_own(tmp_path, monkeypatch):
    """Four sessions handed one after the other to this thread's session process: the first two run in one
    process (handeye imported once); the third kills its process with a segfault (a hook on the process's
    PYTHONPATH, acting on sessions named ``*crash*``) and is recorded as crashed with the signal and its last
    log line; the fourth (the second again) is the first of a fresh process and gives the same result."""
    from handeye.batch import run as batch_run
    from handeye.sim.fleet import write_fleet

    root, out = tmp_path / "root", tmp_path / "out"
    write_fleet(root, n_installs=1, sessions_per_install=1, n_views=8)
    first = next(p for p in root.glob("*/*") if p.is_dir())
    for name in ("2027-01-01-crash", "2027-02-01"):
        shutil.copytree(first, first.parent / name)
    _hook_session_processes(
        tmp_path,
        monkeypatch,
        "crash",
        "import logging, os, signal",
        "logging.getLogger('hook').error('about to crash')",
        "os.kill(os.getpid(), signal.SIGSEGV)",
    )
    calibrate = calibrate_options(build_parser().parse_args(["batch", str(root), "--out", str(out), "--no-report"]))
    plan = plan_batch(discover(root), out, calibrate=calibrate)
    specs = sorted(plan.specs, key=lambda s: s["name"])
    assert [s["name"].endswith("crash") for s in specs] == [False, True, False]

    def x_of(spec):
        return json.loads((out / spec["install"] / spec["name"] / "result.json").read_text())["T_end_cam"]

    try:
        recs = [batch_run.run_session(s) for s in (specs[0], specs[2], specs[1])]
        x_reused = x_of(specs[2])  # the second session of its process
        recs.append(batch_run.run_session(specs[2]))  # the same session, the first of a fresh process
    finally:
        batch_run.session_process().close()
    done1, done2, crashed, again = recs
    assert done1["outcome"] == done2["outcome"] == again["outcome"] == "done", recs
    assert done1["process"] == done2["process"], "the second session ran in the first one's process"
    assert crashed["outcome"] == "crashed" and crashed["verdict"] == "ERROR"
    assert f"killed by signal {int(signal.SIGSEGV)}" in crashed["reason"] and "about to crash" in crashed["reason"]
    assert again["process"] != done1["process"], "the crashed process was replaced"
    assert done1["verdict"] == again["verdict"] and done1["peak_rss_mb"] > 0
    # two fresh ``handeye calibrate`` runs of one session differ at 1e-15 (the solver's summation order): the same
    np.testing.assert_allclose(x_of(specs[2]), x_reused, rtol=0, atol=1e-12)
    log = (out / specs[0]["install"] / specs[0]["name"] / "batch.log").read_text()
    assert "about to crash" not in log, "each session's log holds its own lines only"


def test_an_uncaught_exception_in_the_session_process_is_its_row_with_the_traceback_in_its_log(tmp_path, monkeypatch):
    """A session whose process dies of an exception that is not a handeye error (a hook on the process's
    PYTHONPATH raises it for sessions named ``*raise*``, before the session logs a line): its record says how the
    process ended and the exception's last line, and its batch.log holds the traceback, which the process writes
    on its own stderr once the exception has left the session."""
    from handeye.batch import run as batch_run

    root, out = tmp_path / "root", tmp_path / "out"
    (root / "cell" / "2027-01-01-raise").mkdir(parents=True)
    (root / "cell" / "2027-01-01-raise" / "poses.txt").write_text("0,0,0,0,0,0\n")
    _hook_session_processes(tmp_path, monkeypatch, "raise", "", "raise ValueError('day is out of range for month')")
    calibrate = calibrate_options(build_parser().parse_args(["batch", str(root), "--out", str(out), "--no-report"]))
    (spec,) = plan_batch(discover(root), out, calibrate=calibrate).specs
    try:
        rec = batch_run.run_session(spec)
    finally:
        batch_run.session_process().close()
    assert rec["outcome"] == "crashed" and rec["verdict"] == "ERROR", rec
    assert rec["reason"] == (
        "the session's process ended without a result (exit code 1): ValueError: day is out of range for month"
    )
    assert json.loads((out / "cell" / "2027-01-01-raise" / RECORD_NAME).read_text())["reason"] == rec["reason"]
    log = (out / "cell" / "2027-01-01-raise" / "batch.log").read_text()
    assert "Traceback (most recent call last)" in log and "raise ValueError('day is out of range for month')" in log
    assert batch_run.session_process().proc is None and batch_run.session_process().own_log is None


def test_a_fleet_wide_robot_noise_flag_is_refused_for_a_pose_only_session(tmp_path):
    """``batch --robot-noise fixed`` over a pose-only session: its row names the flag that does not apply, as
    ``handeye calibrate`` does, instead of ignoring it."""
    from handeye.batch import child
    from handeye.sim.poses import make_tracker_session

    root, out = tmp_path / "root", tmp_path / "out"
    make_tracker_session(n_views=8, seed=3).write(root / "cell" / "tracker")
    argv = ["batch", str(root), "--out", str(out), "--robot-noise", "fixed", "--no-report"]
    calibrate = calibrate_options(build_parser().parse_args(argv))
    (spec,) = plan_batch(discover(root), out, calibrate=calibrate).specs
    reply = child.run(spec)
    assert reply["outcome"] == "error" and reply["exit_code"] == 2
    assert "--robot-noise does not apply to a pose-only session" in reply["reason"]
    assert not (out / "cell" / "tracker" / "result.json").exists()


def test_a_fleet_wide_robot_flag_models_the_arm_of_a_pose_only_session(tmp_path):
    """``batch --robot ARM`` over a pose-only session: the arm's kinematic model enters its pose graph."""
    from handeye.batch import child
    from handeye.sim.arm_tracker import make_arm_tracker_session

    root, out = tmp_path / "root", tmp_path / "out"
    make_arm_tracker_session(arm="ur5e", n_views=12, seed=3).write(root / "cell" / "tracker", state_sigma=False)
    argv = ["batch", str(root), "--out", str(out), "--robot", "ur5e", "--no-report"]
    calibrate = calibrate_options(build_parser().parse_args(argv))
    (spec,) = plan_batch(discover(root), out, calibrate=calibrate).specs
    reply = child.run(spec)
    assert reply["outcome"] == "done", reply
    res = json.loads((out / "cell" / "tracker" / "result.json").read_text())
    assert res["refinement"]["robot_model"]["kind"] == "kinematic"
    assert res["refinement"]["robot_model"]["arm"] == "Universal Robots UR5e"


def test_a_fail_result_s_export_is_not_a_failed_export_whichever_way_it_failed(tmp_path, monkeypatch, capsys):
    """``batch --export``: a FAIL result is not exported by design, whether it has a result.json (its export was
    refused) or not; each failed session's line says so alike, the summary counts them apart from the exports that
    failed (of a PASS or WARN result), and the refusal is not kept as an export error in batch.json."""
    from handeye.batch import run as batch_run
    from handeye.batch.run import BatchSummary
    from handeye.cli.batch import _Progress

    refused = "/out/c/s2/result.json: the result's verdict is FAIL (T_end_cam fails QA) -> fix the calibration"

    class Replies:
        def run(self, spec, timeout_s):
            return (
                "reply",
                {
                    "outcome": "done",
                    "status": "ok",
                    "verdict": "FAIL",
                    "reason": "fails QA",
                    "exit_code": 7,
                    "export_error": refused,
                },
                None,
            )

    monkeypatch.setattr(batch_run, "session_process", Replies)
    spec = {
        "session": str(tmp_path / "s2"),
        "out_dir": str(tmp_path / "out" / "c" / "s2"),
        "install": "c",
        "name": "s2",
        "time_utc": None,
        "time_source": "none",
        "key": {},
        "timeout_s": 60.0,
    }
    rec = batch_run.run_session(spec)
    assert rec["verdict"] == "FAIL" and "export_error" not in rec
    assert "export_error" not in json.loads((tmp_path / "out" / "c" / "s2" / RECORD_NAME).read_text())

    pass_ = {"install": "c", "name": "s0", "outcome": "done", "verdict": "PASS", "reason": ""}
    disk = "/out/c/s1/hand_eye.urdf: cannot be written (No space left on device)"
    warn = {"install": "c", "name": "s1", "outcome": "done", "verdict": "WARN", "reason": "", "export_error": disk}
    no_result = {"install": "c", "name": "s3", "outcome": "done", "verdict": "FAIL", "reason": "bad pose"}
    old = {**rec, "name": "s4", "skipped": True, "export_error": refused}  # an earlier batch kept the refusal
    records = (pass_, warn, rec, no_result, old)
    summary = BatchSummary(records, 3.0, export="urdf")
    assert summary.export_errors == [warn] and summary.not_exported == [rec, no_result, old]
    assert summary.line() == (
        "5 sessions: 2 done, 2 failed, 1 skipped (1 PASS, 1 WARN, 3 FAIL) in 3 s; 3 not exported (FAIL, REFUSED or "
        "no result); the export failed for 1 session"
    )
    assert BatchSummary(records, 3.0).line() == (
        "5 sessions: 2 done, 2 failed, 1 skipped (1 PASS, 1 WARN, 3 FAIL) in 3 s; the export failed for 1 session"
    )
    capsys.readouterr()
    bar = _Progress(len(records), quiet=True, export=True)
    for r in records:
        bar.update(r)
    bar.close()
    assert capsys.readouterr().err.splitlines() == [
        f"c/s1: the export failed: {disk}",
        "c/s2: FAIL (done): fails QA (not exported)",
        "c/s3: FAIL (done): bad pose (not exported)",
    ]
