"""handeye batch --upload: the record of a session calibrated in the worker's temporary copy names the session
as the client gave it, and its files go to the worker without passing through the scheduler with the task."""

from __future__ import annotations

import json
import warnings

import dask
import distributed  # noqa: F401 - its config defaults first: dask.config.set restores the config as it found it

from handeye.cli import main


def _unloadable_session(root, *, image_bytes: int):
    """ROOT/cell/2026-03-01: a vendor session whose pose line has five numbers (it does not load: its reason
    names the line), with an image of ``image_bytes`` zeros (never read: the poses are first)."""
    session = root / "cell" / "2026-03-01"
    session.mkdir(parents=True)
    (session / "poses.txt").write_text("0.5,0.1,0.6,2.7,-0.2\n")
    (session / "config.yaml").write_text("checkerboard_args:\n  XX: 11\n  YY: 8\n  L: 0.03\nmode: eye_in_hand\n")
    (session / "1.jpg").write_bytes(bytes(image_bytes))
    return session


def test_an_uploaded_session_s_reason_names_the_original_session_and_no_large_graph_is_sent(
    tmp_path, monkeypatch, capsys
):
    """A session with a pose line of five numbers (it does not load: its reason names the line) and a 300 kB
    image, uploaded to an embedded one-worker cluster whose large-graph warning is set at 100 kB."""
    monkeypatch.setenv("DASK_LOGGING__DISTRIBUTED", "warning")
    root, out = tmp_path / "root", tmp_path / "out"
    session = _unloadable_session(root, image_bytes=300_000)
    with (
        dask.config.set({"distributed.admin.large-graph-warning-threshold": "100kB"}),
        warnings.catch_warnings(record=True) as caught,
    ):
        warnings.simplefilter("always")
        rc = main(["batch", str(root), "--out", str(out), "--workers", "1", "--upload", "--no-report"])
    assert rc == 7
    assert not [w for w in caught if "large graph" in str(w.message)], [str(w.message) for w in caught]
    rec = json.loads((out / "cell" / "2026-03-01" / "batch.json").read_text())
    assert rec["session"] == str(session) and rec["outcome"] == "done" and rec["verdict"] == "FAIL"
    assert rec["reason"].startswith(f"{session / 'poses.txt'}:1: bad pose: expected 6 numbers"), rec["reason"]
    err = capsys.readouterr().err
    assert f"cell/2026-03-01: FAIL (done): {session / 'poses.txt'}:1: bad pose" in err, err
    for name in ("batch.json",):
        assert "handeye-batch-" not in (out / "cell" / "2026-03-01" / name).read_text()
    for name in ("fleet.csv", "index.md", "index.html"):
        text = (out / name).read_text()
        assert f"{session / 'poses.txt'}:1: bad pose" in text and "handeye-batch-" not in text, name


def test_the_worker_s_paths_are_put_back_in_the_record_s_texts():
    """The session, the output folder and a site file (a --prior folder sent as its result.json) of the worker's
    temporary copy, in every field of a record that may name one; other fields are left as they are."""
    from handeye.batch.upload import client_paths

    tmp = "/worker/scratch/handeye-batch-x1"  # a worker's temporary copy
    paths = {
        f"{tmp}/session": "/data/cell/s1",
        f"{tmp}/out": "/qa/cell/s1",
        f"{tmp}/site_prior/result.json": "/qa/cell/s0/result.json",
    }
    rec = {
        "session": f"{tmp}/session",
        "reason": f"{tmp}/session/poses.txt:3: bad pose; prior {tmp}/site_prior/result.json: damaged",
        "export_error": f"{tmp}/out/result.json: the result is not fit for use",
        "exported": [f"{tmp}/out/handeye.urdf"],
        "worker": f"host:{tmp}/session",
    }
    assert client_paths(rec, paths) == {
        "session": "/data/cell/s1",
        "reason": "/data/cell/s1/poses.txt:3: bad pose; prior /qa/cell/s0/result.json: damaged",
        "export_error": "/qa/cell/s1/result.json: the result is not fit for use",
        "exported": ["/qa/cell/s1/handeye.urdf"],
        "worker": f"host:{tmp}/session",
    }


def test_an_uploaded_session_whose_files_were_lost_with_their_worker_is_sent_again(
    tmp_path, worker_killing_hook, monkeypatch
):
    """The Dask worker holding an uploaded session's scattered files dies while the session runs (a hook on the
    session process's PYTHONPATH kills its parent, the worker, once): Dask cancels the task, whose files are
    gone; the batch sends the session again and it gets its record as any other."""
    import os

    monkeypatch.setenv("DASK_LOGGING__DISTRIBUTED", "error")
    root, out = tmp_path / "root", tmp_path / "out"
    session = _unloadable_session(root, image_bytes=1000)
    hook, mark = tmp_path / "hook", tmp_path / "worker-killed"
    # once: the hook marks the first session process it kills the worker of
    worker_killing_hook(hook, f"not os.path.exists({str(mark)!r}) and open({str(mark)!r}, 'w').close() is None")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(hook), os.environ.get("PYTHONPATH")) if p))
    rc = main(["batch", str(root), "--out", str(out), "--workers", "1", "--upload", "--no-report"])
    assert rc == 7 and mark.exists()
    rec = json.loads((out / "cell" / "2026-03-01" / "batch.json").read_text())
    assert rec["outcome"] == "done" and rec["verdict"] == "FAIL", rec
    assert rec["reason"].startswith(f"{session / 'poses.txt'}:1: bad pose: expected 6 numbers"), rec["reason"]


def test_an_uploaded_session_s_result_files_name_the_client_s_session_and_the_batch_command(tmp_path, monkeypatch):
    """A session that calibrates, uploaded: result.json, observations.json, the reports and batch.log name the
    session where the client has it (``handeye report`` there finds its images), and the provenance's command line
    is the batch's, not the worker's session process; a cell's result names its cameras' sessions there. Without
    --upload the command line is the batch's too."""
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session

    monkeypatch.setenv("DASK_LOGGING__DISTRIBUTED", "warning")
    root = tmp_path / "root"
    session = write_vendor_session(
        root / "cell" / "2026-03-02", n_views=8, seed=3, intrinsics=default_intrinsics(400, 300), supersample=2
    )
    two = root / "two_cameras"  # a cell of two cameras: its result's provenance names each camera's session
    assert main(["simulate", str(two), "--cell", "2", "--views", "8", "--seed", "2"]) == 0
    for upload in (True, False):
        out = tmp_path / f"out_{upload}"
        argv = ["batch", str(root), "--out", str(out), "--workers", "1"] + (["--upload"] if upload else ["--no-report"])
        monkeypatch.setattr("sys.argv", ["/usr/local/bin/handeye", *argv])
        assert main(argv) == 0
        folder = out / "cell" / "2026-03-02"
        res = json.loads((folder / "result.json").read_text())
        assert res["session"]["path"] == str(session)
        assert res["provenance"]["command_line"] == "handeye " + " ".join(argv)
        obs = json.loads((folder / "observations.json").read_text())
        assert {v["image"] for v in obs["views"].values()} == {str(session / f"{k}.jpg") for k in range(1, 9)}
        written = [p for p in folder.rglob("*") if p.is_file() and p.suffix in (".json", ".log", ".md", ".html")]
        assert len(written) >= (6 if upload else 4), written
        assert not [p for p in written if "handeye-batch-" in p.read_text(errors="replace")]
        cell = json.loads(next(out.rglob("two_cameras/result.json")).read_text())
        assert cell["provenance"]["sessions"] == {c: str(two / c) for c in ("cam1", "cam2")}


def test_recorded_paths_and_command_line_are_the_user_s_inside_recorded_as(monkeypatch):
    """Inside ``recorded_as`` a path in a run's copy is recorded in the user's folder (the longest copy first), any
    other path as it is, and the provenance's command line is the one given; outside, the process's own."""
    from handeye.output import provenance, recorded_as, recorded_path

    monkeypatch.setattr("sys.argv", ["/opt/venv/bin/handeye", "calibrate", "s1"])
    copies = {"/scratch/tmp1/session": "/data/s1", "/scratch/tmp1/session/sub": "/elsewhere/sub"}
    with recorded_as(command_line="handeye batch /data --out /qa", paths=copies):
        assert recorded_path("/scratch/tmp1/session") == "/data/s1"
        assert recorded_path("/scratch/tmp1/session/3.jpg") == "/data/s1/3.jpg"
        assert recorded_path("/scratch/tmp1/session/sub/x.png") == "/elsewhere/sub/x.png"
        assert recorded_path("/scratch/tmp1/session2/3.jpg") == "/scratch/tmp1/session2/3.jpg"  # not inside it
        assert provenance()["command_line"] == "handeye batch /data --out /qa"
    assert recorded_path("/scratch/tmp1/session/3.jpg") == "/scratch/tmp1/session/3.jpg"
    assert provenance()["command_line"] == "handeye calibrate s1"


def test_command_line_of_python_m_handeye_is_recorded_as_typed(monkeypatch):
    """``python -m handeye calibrate s1`` runs handeye/__main__.py; the provenance names the module, not that file."""
    from handeye.output import provenance

    monkeypatch.setattr("sys.argv", ["/opt/venv/lib/python3.11/site-packages/handeye/__main__.py", "calibrate", "s1"])
    assert provenance()["command_line"] == "python -m handeye calibrate s1"
