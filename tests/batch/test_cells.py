"""A cell in the batch and the fleet index: one row per camera and one for the cell; a cell folder is one job."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from handeye.batch.discover import discover_fleet
from handeye.batch.index import read_fleet_csv, write_index
from handeye.contract import read_result


def _cell_copy(cell, dest, *, time, moved_mm=0.0):
    """The cell's result.json in ``dest`` at ``time``; camera fixed1 moved by ``moved_mm`` along the base x."""
    dest.mkdir(parents=True)
    d = json.loads((cell["cell"] / "result.json").read_text())
    d["provenance"] = {"time_utc": time}
    e = d["cameras"]["fixed1"]
    T = np.asarray(e["T_base_cam"])
    T[0, 3] += moved_mm / 1000.0
    e["T_base_cam"] = e["hand_eye"]["matrix"] = T.tolist()
    e["hand_eye"]["translation_mm"] = (1000.0 * T[:3, 3]).tolist()
    for c in d["cameras"].values():
        c.setdefault("provenance", {})["time_utc"] = time
    (dest / "result.json").write_text(json.dumps(d))
    return dest


def test_the_index_lists_a_cell_as_a_row_per_camera_and_one_for_the_cell(cell, tmp_path):
    out = tmp_path / "out"
    _cell_copy(cell, out / "line1" / "c1", time="2026-03-01T00:00:00+00:00")
    _cell_copy(cell, out / "line1" / "c2", time="2026-04-01T00:00:00+00:00", moved_mm=5.0)
    write_index(out, plots=False)
    rows = read_fleet_csv(out / "fleet.csv")
    assert [(r["session"], r["camera"], r["mode"]) for r in rows[:4]] == [
        ("c1/fixed1", "fixed1", "eye_to_hand"),
        ("c1/fixed2", "fixed2", "eye_to_hand"),
        ("c1/wrist", "wrist", "eye_in_hand"),
        ("c1", None, "cell"),
    ]  # a cell's cameras by name, then the cell
    res = read_result(cell["cell"])
    by = {r["session"]: r for r in rows}
    for name in res.camera_names:
        one = res.camera_result(name)
        r = by[f"c1/{name}"]
        assert r["x_name"] == one.x_name and r["verdict"] == one.verdict and r["result_dir"] == "line1/c1"
        np.testing.assert_allclose([r["tx_mm"], r["ty_mm"], r["tz_mm"]], 1000.0 * one.T_x[:3, 3], atol=1e-6)
    assert by["c1"]["verdict"] == res.raw["verdict"] and by["c1"]["tx_mm"] is None
    assert "a cell of 3 cameras (wrist, fixed1, fixed2)" in (by["c1"]["reason"] or "")
    # the drift: each camera against the same camera of the install's earlier cell, never another camera
    md = (out / "index.md").read_text()
    from handeye.batch.index import install_summaries
    from handeye.batch.rows import fleet_rows

    (inst,) = install_summaries(out, fleet_rows(out), plots=False)
    pairs = {(d["from"], d["to"]): d for d in inst["drifts"]}
    assert set(pairs) == {(f"c1/{n}", f"c2/{n}") for n in res.camera_names}
    assert pairs[("c1/fixed1", "c2/fixed1")]["drifted"] and pairs[("c1/fixed1", "c2/fixed1")][
        "trans_mm"
    ] == pytest.approx(5.0)
    assert not pairs[("c1/wrist", "c2/wrist")]["drifted"] and not pairs[("c1/fixed2", "c2/fixed2")]["drifted"]
    assert inst["latest"]["session"] == "c2" and "c2/fixed1" in md


def test_discovery_takes_a_cell_folder_as_one_job_not_its_camera_folders(cell, tmp_path):
    root = tmp_path / "root"
    cell_dir = root / "line1" / "cellA"
    for name in ("wrist", "fixed2"):
        shutil.copytree(cell["sessions"] / name, cell_dir / name)
    (cell_dir / "cell.yaml").write_text("cell: {sessions: [wrist, fixed2]}\ntime: 2026-05-01T10:00:00Z\n")
    shutil.copytree(cell["sessions"] / "fixed1", root / "line1" / "solo")
    jobs = discover_fleet(root).jobs
    assert sorted((j.install, j.name, j.layout) for j in jobs) == [
        ("line1", "cellA", "cell"),
        ("line1", "solo", "vendor"),
    ]
    (job,) = [j for j in jobs if j.layout == "cell"]
    assert job.time_utc == "2026-05-01T10:00:00+00:00" and job.time_source == "session.yaml time"


@pytest.mark.slow
def test_batch_runs_a_cell_folder_as_one_job_and_exports_every_camera(cell, tmp_path, capsys):
    from handeye.cli import main
    from handeye.sim.cell import write_cell

    root = tmp_path / "root"
    write_cell(root / "line1" / "cellA", 2, n_views=8, seed=1, workers=1)
    shutil.copytree(cell["sessions"] / "fixed2", root / "line1" / "solo")
    out = tmp_path / "out"
    rc = main(["batch", str(root), "--out", str(out), "--workers", "1", "--export", "urdf"])
    printed = capsys.readouterr().out
    assert rc == 0 and "2 sessions: 2 done" in printed
    res = read_result(out / "line1" / "cellA")
    assert res.is_cell and res.camera_names == ["cam1", "cam2"]
    rec = json.loads((out / "line1" / "cellA" / "batch.json").read_text())
    assert rec["outcome"] == "done" and rec["verdict"] == res.raw["verdict"]
    urdf = (out / "line1" / "cellA" / "hand_eye.urdf").read_text()
    assert urdf.count("<joint ") == 2 and "cam2_optical_frame" in urdf
    rows = {r["session"]: r for r in read_fleet_csv(out / "fleet.csv")}
    assert set(rows) == {"cellA/cam1", "cellA/cam2", "cellA", "solo"}
    assert rows["cellA"]["mode"] == "cell" and rows["cellA/cam2"]["camera"] == "cam2"
    np.testing.assert_allclose(
        [rows["cellA/cam1"][k] for k in ("tx_mm", "ty_mm", "tz_mm")], 1e3 * res.camera_result("cam1").T_x[:3, 3]
    )
    assert main(["batch", str(root), "--out", str(out), "--workers", "1", "--export", "urdf"]) == 0
    assert "2 skipped" in capsys.readouterr().out  # the cell's key: every file under its folder
