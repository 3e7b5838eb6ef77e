"""Recalibration commands on a cell: ``compare`` of two cells (each camera and pair), ``--camera`` elsewhere."""

import json
import shutil

import numpy as np
import pytest

from handeye.cli import main
from handeye.errors import DRIFTED_EXIT_CODE
from handeye.frames import inv_T
from handeye.recal.cells import compare_cells


def _moved_cell(cell, dest, camera="fixed1", dt=(0.005, 0.0, 0.0)):
    """A copy of the cell whose camera ``camera`` (eye-to-hand) moved by ``dt`` metres along the base axes."""
    shutil.copytree(cell["cell"], dest)
    d = json.loads((dest / "result.json").read_text())
    e = d["cameras"][camera]
    T = np.asarray(e["T_base_cam"])
    T[:3, 3] += dt
    e["T_base_cam"] = e["hand_eye"]["matrix"] = T.tolist()
    e["hand_eye"]["translation_mm"] = (1000.0 * T[:3, 3]).tolist()  # a translation: the rotation's forms stay
    for key, p in d["camera_pairs"].items():
        a, b = key.split("/")
        if camera in (a, b):
            Ts = {n: np.asarray(d["cameras"][n][d["cameras"][n]["hand_eye"]["name"]]) for n in (a, b)}
            p["matrix"] = (inv_T(Ts[a]) @ Ts[b]).tolist()
    (dest / "result.json").write_text(json.dumps(d))
    return dest


def test_a_cell_compared_with_itself_is_zero_for_every_camera_and_pair(cell, capsys):
    c = compare_cells(cell["cell"], cell["cell"])
    assert list(c.cameras) == ["wrist", "fixed1", "fixed2"] and list(c.pairs) == ["fixed1/fixed2"]
    for cc in c.cameras.values():
        assert cc.mahalanobis2 == pytest.approx(0.0, abs=1e-12) and cc.p_value == pytest.approx(1.0)
    assert c.pairs["fixed1/fixed2"]["mahalanobis2"] == pytest.approx(0.0, abs=1e-12)
    assert not c.drifted
    assert main(["compare", str(cell["cell"]), str(cell["cell"]), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["kind"] == "cell" and d["cameras"]["fixed2"]["p_value"] == pytest.approx(1.0) and d["moved"] == []


def test_a_moved_camera_is_named_with_its_pairs_and_the_others_stay(cell, tmp_path, capsys):
    moved = _moved_cell(cell, tmp_path / "moved")
    assert main(["compare", str(cell["cell"]), str(moved)]) == DRIFTED_EXIT_CODE
    out = capsys.readouterr().out
    assert "cell: DRIFTED (fixed1, fixed1/fixed2)" in out
    c = compare_cells(cell["cell"], moved)
    np.testing.assert_allclose(c.cameras["fixed1"].d_trans_mm, [5.0, 0.0, 0.0], atol=1e-9)
    assert c.cameras["fixed1"].p_value < 1e-6 and c.pairs["fixed1/fixed2"]["trans_mm"] == pytest.approx(5.0)
    assert c.cameras["wrist"].mahalanobis2 == pytest.approx(0.0, abs=1e-12) and not c.cameras["fixed2"].drifted


def test_a_cell_against_one_camera_takes_camera_and_names_it(cell, tmp_path, capsys):
    solo = cell["solo"]["fixed2"]
    assert main(["compare", str(solo), str(cell["cell"]), "--camera", "fixed2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("camera fixed2:\nT_base_cam: B - A") and "Mahalanobis^2 0.00" in out
    assert main(["compare", str(solo), str(cell["cell"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cell of 3 cameras (wrist, fixed1, fixed2)" in err[0] and "--camera NAME" in err[0]
    assert main(["compare", str(solo), str(cell["cell"]), "--camera", "wrist"]) == 2  # another mode: refused
    assert "mounting modes differ" in capsys.readouterr().err
    assert main(["compare", str(cell["cell"]), str(cell["cell"]), "--camera", "fixed1", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["camera"] == "fixed1" and d["mahalanobis2"] == pytest.approx(0.0, abs=1e-12)
    assert d["results"][0].endswith("result.json (camera fixed1)")


def test_verify_against_a_cell_takes_the_camera_of_the_session_folder(cell, tmp_path, capsys):
    wrist = cell["verify"]["wrist"]
    assert main(["verify", str(wrist), "--against", str(cell["cell"]), "--out", str(tmp_path / "w")]) == 0
    out = capsys.readouterr().out
    assert "still valid" in out
    d = json.loads((tmp_path / "w" / "verify.json").read_text())
    assert d["frame"] == "T_end_cam" and d["against"].endswith("result.json (camera wrist)")
    # the same check as against the camera's own result: the cell's X and covariance of that camera
    assert main(["verify", str(wrist), "--against", str(cell["solo"]["wrist"]), "--out", str(tmp_path / "s")]) == 0
    solo = json.loads((tmp_path / "s" / "verify.json").read_text())
    assert d["test"]["statistic"] == pytest.approx(solo["test"]["statistic"], rel=1e-9)
    capsys.readouterr()
    # a folder named after no camera needs --camera; --camera another mode's camera is refused in one line
    other = tmp_path / "session"
    shutil.copytree(wrist, other)
    assert main(["verify", str(other), "--against", str(cell["cell"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "names none of them" in err[0] and "--camera NAME" in err[0]
    assert main(["verify", str(other), "--against", str(cell["cell"]), "--camera", "fixed1"]) == 2
    assert "eye_to_hand" in capsys.readouterr().err
    assert main(["verify", str(other), "--against", str(cell["cell"]), "--camera", "wrist", "--no-report",
                 "--out", str(tmp_path / "o")]) == 0  # fmt: skip


def test_verify_several_cameras_of_a_cell_gives_a_verdict_per_camera_and_for_the_cell(cell, tmp_path, capsys):
    sessions = [str(cell["verify"][n]) for n in ("wrist", "fixed1")]
    rc = main(["verify", *sessions, "--against", str(cell["cell"]), "--out", str(tmp_path), "--no-report"])
    out = capsys.readouterr().out
    assert rc == 0 and "camera wrist:" in out and "camera fixed1:" in out
    assert out.strip().splitlines()[-1] == "cell: still valid (2 of 3 cameras verified)"
    for n, frame in (("wrist", "T_end_cam"), ("fixed1", "T_base_cam")):
        d = json.loads((tmp_path / n / "verify.json").read_text())
        assert d["frame"] == frame and d["verdict"] == "still valid"
    assert main(["verify", *sessions, "--against", str(cell["solo"]["wrist"])]) == 2
    assert "against a cell" in capsys.readouterr().err
    assert main(["verify", *sessions, "--against", str(cell["cell"]), "--json"]) == 2
    assert "--json prints one verification" in capsys.readouterr().err


def test_calibrate_prior_and_collect_take_the_cell_camera_of_the_session_folder(cell, tmp_path, capsys):
    wrist = cell["verify"]["wrist"]
    out = tmp_path / "upd"
    assert main(["-q", "calibrate", str(wrist), "--prior", str(cell["cell"]), "--out", str(out), "--no-report"]) == 0
    res = json.loads((out / "result.json").read_text())
    assert res["prior"]["source"].endswith("result.json (camera wrist)") and res["prior"]["frame"] == "T_end_cam"
    np.testing.assert_allclose(res["prior"]["T_end_cam"], json.loads((cell["cell"] / "result.json").read_text())[
        "cameras"]["wrist"]["T_end_cam"])  # fmt: skip
    other = tmp_path / "session"
    shutil.copytree(wrist, other)
    assert main(["-q", "calibrate", str(other), "--prior", str(cell["cell"]), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--prior is a cell of 3 cameras (wrist, fixed1, fixed2)" in err[0]
    args = ["collect", str(tmp_path / "c"), "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim"]
    assert main([*args, "--verify-against", str(cell["cell"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--verify-against is a cell of 3 cameras" in err[0] and "'c' names none" in err[0]
    assert main([*args[:1], str(tmp_path / "fixed1"), *args[2:], "--verify-against", str(cell["cell"])]) == 2
    assert "installed calibration is eye_to_hand" in capsys.readouterr().err  # the camera named by the folder


def test_verify_plan_against_a_cell_takes_camera(cell, capsys):
    assert main(["verify", "--plan", "--against", str(cell["cell"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cell of 3 cameras" in err[0] and "--camera NAME" in err[0]
    assert main(["verify", "--plan", "--against", str(cell["cell"]), "--camera", "wrist", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    solo = main(["verify", "--plan", "--against", str(cell["solo"]["wrist"]), "--json"])
    assert solo == 0 and plan == json.loads(capsys.readouterr().out)  # the cell's camera: its own X and covariance
