"""``handeye calibrate`` of a cell (handeye.cell.workflow) on a rendered 3-camera cell with ground truth."""

import json
import shutil

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from handeye.cell import calibrate_cell, read_cell_file
from handeye.cli import main
from handeye.contract import read_result, single_camera
from handeye.errors import InputError, verdict_exit_code
from handeye.frames import inv_T, tangent_difference


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """``handeye simulate --cell 3`` then ``handeye calibrate CELL --out R``: (cell folder, result folder, rc)."""
    root = tmp_path_factory.mktemp("cell")
    folder, out = root / "cell", root / "result"
    assert main(["-q", "simulate", str(folder), "--cell", "3", "--views", "10", "--seed", "1"]) == 0
    rc = main(["-q", "calibrate", str(folder), "--out", str(out)])
    return folder, out, rc


def _m2(T, C, T_true):
    xi = tangent_difference(np.asarray(T), np.asarray(T_true))
    return float(xi @ np.linalg.solve(np.asarray(C), xi))


def test_simulate_writes_a_cell_folder(cell):
    folder, _out, _rc = cell
    sessions, robot = read_cell_file(folder)
    assert [p.name for p in sessions] == ["cam1", "cam2", "wrist"] and robot == "rm65"  # simulate's default arm
    for p in sessions:
        doc = yaml.safe_load((p / "session.yaml").read_text())
        assert doc["robot"] == "rm65" and all(len(v["joints"]) == 6 for v in doc["views"])
        assert (p / "ground_truth.json").is_file()
    assert json.loads((folder / "ground_truth.json").read_text())["kind"] == "cell"


def test_the_cell_result_is_one_contract_file_against_the_truth(cell):
    folder, out, rc = cell
    res = read_result(out)
    assert rc == verdict_exit_code(res.verdict)
    assert res.is_cell and res.mode == "cell" and res.camera_names == ["cam1", "cam2", "wrist"]
    truth = json.loads((folder / "ground_truth.json").read_text())
    bound = chi2.ppf(0.999, 6)  # one cell: inside the 99.9 % region (the benchmark measures the coverage)
    for name in res.camera_names:
        cam = single_camera(res, name)
        t = truth["cameras"][name]
        assert cam.x_name == ("T_end_cam" if name == "wrist" else "T_base_cam")
        raw = res.raw["cameras"][name]
        assert _m2(cam.T_x, raw["refinement"]["cov_x_6x6"], t[cam.x_name]) < bound
        assert raw["refinement"]["cov_x_6x6_verdict"] == raw["refinement"]["cov_x_6x6"]
        assert raw["refinement"]["solo"]["agreement"]["inside_95"]  # the joint X inside its solo 95 % region
        assert (out / "solo" / name / "result.json").is_file()
    pair = res.raw["camera_pairs"]["cam1/cam2"]
    T_true = inv_T(np.asarray(truth["cameras"]["cam1"]["T_base_cam"])) @ np.asarray(
        truth["cameras"]["cam2"]["T_base_cam"]
    )
    assert pair["name"] == "T_cam1_cam2" and _m2(pair["matrix"], pair["cov_6x6"], T_true) < bound
    jc = res.raw["joint_covariance"]
    assert (
        "cameras.cam1.T_base_cam" in jc["blocks"] and "T_end_board" in jc["blocks"] and "T_base_board" in jc["blocks"]
    )
    assert "board" not in res.raw  # two boards (flange and table): each camera's entry has its own
    assert (out / "report.md").read_text().startswith("# Cell of 3 cameras")
    html = (out / "report.html").read_text()
    assert "T_cam1_cam2" in html and "<th>" in html and "lang='en'" in html
    for name in res.camera_names:  # each camera's verdict with its reason, and a link to its own report
        link = f'<a href="solo/{name}/report.html">its report</a>'
        assert link in html and (out / "solo" / name / "report.html").is_file(), name
        assert res.raw["cameras"][name]["verdict_headline"].rstrip(".") in html.replace("&lt;", "<"), name


def test_sessions_named_one_by_one_are_the_same_cell(cell, tmp_path):
    folder, out, _rc = cell
    wr = calibrate_cell([folder / "cam1", folder / "cam2"], tmp_path / "two", report=False, diagnostics=False)
    assert list(wr.result["cameras"]) == ["cam1", "cam2"] and "board" in wr.result  # one flange board: top level
    assert wr.result["board"]["name"] == "T_end_board"
    joint3 = np.asarray(read_result(out).raw["cameras"]["cam1"]["T_base_cam"])
    assert np.linalg.norm(np.asarray(wr.result["cameras"]["cam1"]["T_base_cam"])[:3, 3] - joint3[:3, 3]) < 2e-3


def test_each_cameras_images_are_detected_once_ahead_and_its_solo_run_is_its_own(cell, tmp_path, monkeypatch):
    """The cell detects every camera's images once, in its detection thread, ahead of that camera's calibration;
    a camera's solo result is its session's calibrated alone."""
    import threading

    import handeye.pipeline as pipeline
    from handeye.workflow import calibrate_session

    folder, _out, _rc = cell
    alone = calibrate_session(folder / "cam2", out_dir=tmp_path / "alone", report=False, diagnostics=False)
    seen = []
    real = pipeline.detect_views

    def counting(items, *a, **k):
        seen.append((items[0][1].parent.name, threading.current_thread().name))
        return real(items, *a, **k)

    monkeypatch.setattr(pipeline, "detect_views", counting)
    wr = calibrate_cell([folder / "cam1", folder / "cam2"], tmp_path / "cell", report=False, diagnostics=False)
    assert sorted(cam for cam, _t in seen) == ["cam1", "cam2"]
    assert all(t.startswith("cell-detect") for _cam, t in seen)
    solo, one = (
        json.loads((p / "result.json").read_text()) for p in (tmp_path / "cell" / "solo" / "cam2", alone.out_dir)
    )
    assert solo["T_base_cam"] == one["T_base_cam"] and solo["views"] == one["views"]
    assert solo["refinement"]["cov_x_6x6"] == one["refinement"]["cov_x_6x6"]
    assert solo["seconds"]["detect"] > 0 and wr.result["cameras"]["cam2"]["status"] == "ok"


def test_a_cell_file_without_sessions_is_one_line_naming_it(tmp_path):
    (tmp_path / "cell.yaml").write_text("cell: {sessions: []}\n")
    with pytest.raises(InputError, match="cell.sessions must list") as e:
        read_cell_file(tmp_path)
    assert "cell.yaml" in str(e.value)
    assert main(["-q", "calibrate", str(tmp_path), "--out", str(tmp_path / "o")]) == 2


def test_two_sessions_of_one_name_are_refused(cell, tmp_path):
    folder, _out, _rc = cell
    other = tmp_path / "x" / "cam1"
    shutil.copytree(folder / "cam2", other)
    with pytest.raises(InputError, match="two sessions of the cell are named 'cam1'"):
        calibrate_cell([folder / "cam1", other], tmp_path / "o")
    assert main(["-q", "calibrate", str(folder / "cam1"), str(folder / "cam2")]) == 2  # a cell needs --out


def test_a_cell_s_sessions_are_checked_before_any_camera_is_calibrated(cell, tmp_path):
    """A camera folder that is not there, one view id at two robot poses, a pose that is NaN, a cell of one camera:
    each one line naming its file (exit 2) before any camera is calibrated, and no output folder. Before, the first
    three came after the other cameras' calibrations, which they left in OUT/solo."""
    folder, _out, _rc = cell
    cases = {}
    for case in ("missing", "moved", "nan", "one"):
        c = cases[case] = tmp_path / case
        shutil.copytree(folder, c)
    (cases["missing"] / "cell.yaml").write_text("cell: {sessions: [cam1, cam2, cam7]}\n")
    for case, edit in (("moved", lambda pose: pose[0] + 0.05), ("nan", lambda pose: float("nan"))):
        f = cases[case] / "cam2" / "session.yaml"
        doc = yaml.safe_load(f.read_text())
        doc["views"][4]["pose"][0] = edit(doc["views"][4]["pose"])
        f.write_text(yaml.safe_dump(doc, sort_keys=False))
    (cases["one"] / "cell.yaml").write_text("cell: {sessions: [cam1]}\n")
    expected = {
        "missing": ("cam7", "camera cam7: its session folder is not there"),
        "moved": ("cam2/session.yaml", "view 5: camera cam2 has another robot pose than the cell's other cameras"),
        "nan": ("cam2/session.yaml", "not a usable number"),
        "one": ("cam1", "a cell needs two cameras or more"),
    }
    for case, (path, what) in expected.items():
        out = tmp_path / f"out_{case}"
        with pytest.raises(InputError, match=what) as e:
            calibrate_cell([cases[case]], out, report=False)
        assert str(e.value).startswith(str(cases[case] / path)), (case, str(e.value))
        assert not out.exists(), case
        assert main(["-q", "calibrate", str(cases[case]), "--out", str(out)]) == 2 and not out.exists()


def test_an_earlier_cell_s_camera_is_not_left_beside_this_cell_s(cell, tmp_path):
    """Calibrating a cell of two cameras into the folder of an earlier three-camera result removes the third
    camera's solo result (a folder of this cell's result that names no camera of it); other folders stay."""
    folder, out, _rc = cell
    again = tmp_path / "result"
    shutil.copytree(out, again)
    (again / "solo" / "notes").mkdir()
    two = tmp_path / "two"
    shutil.copytree(folder, two)
    (two / "cell.yaml").write_text("cell: {sessions: [cam1, cam2]}\n")
    calibrate_cell([two], again, report=False, diagnostics=False)
    assert sorted(p.name for p in (again / "solo").iterdir()) == ["cam1", "cam2", "notes"]


def test_a_camera_that_cannot_be_calibrated_leaves_the_cell_with_a_finding(cell, tmp_path):
    folder, _out, _rc = cell
    broken = tmp_path / "cam9"
    shutil.copytree(folder / "cam1", broken)
    doc = yaml.safe_load((broken / "session.yaml").read_text())
    doc["views"] = doc["views"][:2]  # two views cannot calibrate a camera
    (broken / "session.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    wr = calibrate_cell([folder / "cam2", broken], tmp_path / "o", report=False, diagnostics=False)
    res = read_result(wr.out_dir)
    assert res.camera_names == ["cam2", "cam9"] and res.verdict == "FAIL"
    assert res.raw["cameras"]["cam9"]["status"] == "failed" and res.raw["cameras"]["cam2"]["status"] == "ok"
    failed = [f for f in res.raw["findings"] if f["code"] == "cell_camera_failed"]
    assert len(failed) == 1 and "cam9" in failed[0]["title"]
    assert not res.raw["camera_pairs"]


def test_calibrate_a_cell_with_export_writes_every_camera(cell, tmp_path, capsys):
    """``calibrate CELL --export urdf``: one URDF beside the cell's result, a joint per camera holding its X."""
    import xml.etree.ElementTree as ET

    from handeye.export.readback import _rpy_R

    folder, _out, _rc = cell
    out = tmp_path / "r"
    rc = main(["-q", "calibrate", str(folder), "--out", str(out), "--export", "urdf", "--no-report"])
    res = read_result(out)
    assert rc == verdict_exit_code(res.verdict) and "urdf: " in capsys.readouterr().out
    joints = {j.find("child").get("link"): j for j in ET.parse(out / "hand_eye.urdf").getroot().findall("joint")}
    assert set(joints) == {f"{n}_optical_frame" for n in res.camera_names}
    for name in res.camera_names:
        o, T = joints[f"{name}_optical_frame"].find("origin"), single_camera(res, name).T_x
        np.testing.assert_allclose([float(v) for v in o.get("xyz").split()], T[:3, 3], atol=1e-9)
        np.testing.assert_allclose(_rpy_R(*(float(v) for v in o.get("rpy").split())), T[:3, :3], atol=1e-9)


def test_a_simulated_check_of_a_cameras_kinematic_install_reads_the_arms_joints(cell, tmp_path):
    """``collect OUT/cam1 --robot sim --verify-against CELL``: the simulated arm is the install's arm (its table,
    its encoder noise), so the check's views carry joint angles and verify reads them through the same model."""
    _folder, out, _rc = cell
    args = ["-q", "collect", str(tmp_path / "cam1"), "--mode", "eye_to_hand", "--camera", "sim", "--robot", "sim"]
    rc = main([*args, "--auto", "--views", "4", "--yes", "--seed", "1", "--verify-against", str(out)])
    check = json.loads((tmp_path / "cam1" / "verify" / "verify.json").read_text())
    assert rc == (9 if check["drifted"] else 0) and "(camera cam1)" in check["against"]
    records = [yaml.safe_load(p.read_text()) for p in sorted((tmp_path / "cam1" / "views").glob("*.yaml"))]
    assert len(records) >= 4 and all(len(v["joints"]) == 6 for v in records)


def test_a_failing_cell_s_headline_gives_each_failing_camera_s_own_cause():
    """A cell that fails because its cameras fail (its own findings only warn) says why in its headline."""
    from handeye.cell.build import _headline

    cameras = {
        "cam1": {"verdict": "FAIL", "verdict_headline": "Squares look like 19.7 mm, not 20 mm. T_base_cam fails QA."},
        "cam2": {"verdict": "WARN", "verdict_headline": "T_base_cam passes with warnings."},
    }
    warn = [{"severity": "warn", "title": "Every camera disagrees with the reported robot pose of view 1"}]
    head = _headline("FAIL", cameras, warn)
    assert head == "Cell of 2 cameras: FAIL (cam1 FAIL, cam2 WARN); cam1: Squares look like 19.7 mm, not 20 mm. " + (
        "T_base_cam fails QA."
    )
    assert _headline("WARN", {"cam2": cameras["cam2"]}, warn) == (
        "Cell of 1 cameras: WARN (cam2 WARN); Every camera disagrees with the reported robot pose of view 1."
    )


def test_simulate_refuses_a_cell_over_a_session_unless_forced(tmp_path):
    """``simulate --cell`` into a folder holding a session of the user's is refused and leaves it as it was; with
    --force a cell written over a larger one keeps none of its images."""
    mine = tmp_path / "mine"
    (mine / "cam1").mkdir(parents=True)
    (mine / "cam1" / "session.yaml").write_text("mine\n")
    assert main(["-q", "simulate", str(mine), "--cell", "2", "--views", "4"]) == 2
    assert (mine / "cam1" / "session.yaml").read_text() == "mine\n" and not (mine / "cell.yaml").exists()
    cell = tmp_path / "cell"
    assert main(["-q", "simulate", str(cell), "--cell", "2", "--views", "6", "--seed", "3"]) == 0
    assert main(["-q", "simulate", str(cell), "--cell", "2", "--views", "6", "--seed", "3"]) == 2
    assert main(["-q", "simulate", str(cell), "--cell", "2", "--views", "4", "--seed", "3", "--force"]) == 0
    for cam in ("cam1", "cam2"):
        ids = {v["id"] for v in yaml.safe_load((cell / cam / "session.yaml").read_text())["views"]}
        assert {p.stem for p in (cell / cam).glob("*.png")} == ids, cam


def test_cameras_that_share_no_view_id_are_named(cell, tmp_path):
    """Two cameras whose view ids differ (the same arm poses, renumbered in one session) are still one cell, tied
    through the arm's model alone: an info finding says that their views of one pose cannot be compared."""
    folder, _out, _rc = cell
    two = tmp_path / "two"
    for cam in ("cam1", "cam2"):
        shutil.copytree(folder / cam, two / cam)
    f = two / "cam2" / "session.yaml"
    doc = yaml.safe_load(f.read_text())
    for v in doc["views"]:
        v["id"] = str(100 + int(v["id"]))
    f.write_text(yaml.safe_dump(doc, sort_keys=False))
    wr = calibrate_cell([two / "cam1", two / "cam2"], tmp_path / "o", report=False, diagnostics=False)
    found = [x for x in wr.result["findings"] if x["code"] == "cell_no_shared_views"]
    assert len(found) == 1 and found[0]["title"] == "The cameras share no view id" and found[0]["severity"] == "info"
    solo = calibrate_cell([folder / "cam1", folder / "cam2"], tmp_path / "p", report=False, diagnostics=False)
    assert not [x for x in solo.result["findings"] if x["code"] == "cell_no_shared_views"]
