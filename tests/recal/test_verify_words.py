"""What verify prints and writes for people: words, not result.json's keys or Python's reprs.

verify.md and verify.html named the installed covariance by its key (``cov_x_6x6_verdict``), pointed the change's
definition at ``test.kind``, gave a view left out for its robot pose the status ``robot_excluded``, said "drifted
below 0.05" beside a p-value that is not, and "the robot poses of views 3"; ``verify --plan SESSION`` printed the
sessions as a Python list.
"""

from __future__ import annotations

import json
import re

import pytest

from handeye.cli import main

KEYS = re.compile(r"cov_x_6x6|robot_excluded|robot_accuracy|test\.kind|\['|\bTrue\b|\bFalse\b|\bNone\b")


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> dict:
    """An installed eye-in-hand calibration (8 rendered views at 400x300) and a 5-view session of its rig whose view
    3 has a wrong robot pose."""
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session
    from handeye.workflow import calibrate_session

    root = tmp_path_factory.mktemp("verify_words")
    intr = default_intrinsics(400, 300)
    session = write_vendor_session(root / "install", n_views=8, seed=3, intrinsics=intr, supersample=2, workers=1)
    calibrate_session(session, out_dir=root / "installed", report=False)
    truth = json.loads((session / "ground_truth.json").read_text())
    check = write_vendor_session(
        root / "check",
        n_views=5,
        seed=303,
        image_noise=2.0,
        outlier_views=["3"],
        outlier_trans_mm=(15.0, 20.0),
        intrinsics=intr,
        supersample=2,
        workers=1,
        rig=(truth["T_end_cam"], truth["T_base_board"]),
    )
    return {"installed": root / "installed", "check": check, "session": session}


def test_verify_says_in_words_which_covariance_and_which_views_it_used(rig, tmp_path, capsys):
    out = tmp_path / "v"
    rc = main(["-q", "verify", str(rig["check"]), "--against", str(rig["installed"]), "--out", str(out)])
    printed = capsys.readouterr().out
    d = json.loads((out / "verify.json").read_text())
    assert rc == 0 and d["views"]["3"]["status"] == "robot_excluded" and d["robot"]["views"] == ["3"], d["robot"]
    assert d["test"]["covariance_used"] == "cov_x_6x6_verdict"  # verify.json keeps result.json's key
    md = (out / "verify.md").read_text()
    page = (out / "verify.html").read_text()
    text = " ".join(re.sub(r"<[^>]+>", " ", page.split("<body>")[1]).split())
    for shown in (md, text, printed):
        assert not KEYS.search(shown), KEYS.search(shown)
    for shown in (md, text):
        assert "covariance of the installed result: its verdict covariance;" in shown
        assert "not used: its robot pose disagrees with the camera" in shown
        assert "pose of view 3 disagrees with the camera" in shown and "views 3" not in shown
        assert "drifted if below 0.05" in shown
        assert "new minus installed, as the test estimates it" in shown.lower()
        assert "mm along the flange axes, deg about the camera axes" in shown
    assert "- the robot pose of view 3 disagrees with the camera" in printed and "that view was not used" in printed


def test_verify_plan_names_a_session_it_does_not_take_as_typed(rig, capsys):
    rc = main(["-q", "verify", "--plan", str(rig["check"]), "--against", str(rig["installed"])])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and f"--plan takes no session; got {rig['check']} ->" in err[0], err


def test_the_installed_covariance_and_a_removed_view_are_said_in_words():
    from handeye.recal.report import verify_context
    from handeye.results import cov_source_words

    assert cov_source_words("cov_x_6x6") == "its model covariance (the result has no verdict covariance)"
    less = cov_source_words("cov_x_6x6_verdict less robot_accuracy.cov_x_6x6")
    assert less.startswith("its verdict covariance, less the arm's stated accuracy") and not KEYS.search(less)
    v = {
        "frame": "T_base_cam",
        "test": {"covariance_used": "cov_x_6x6_verdict"},
        "views": {"1": {"status": "used"}, "2": {"status": "removed"}, "3": {"status": "robot_excluded"}},
        "robot": {"views": ["3", "5"]},
    }
    ctx = verify_context(v)
    assert ctx["status_text"] == {
        "1": "used",
        "2": "not used: its corners do not fit or are too few",
        "3": "not used: its robot pose disagrees with the camera",
    }
    assert ctx["robot_text"] == "poses of views 3, 5 disagree with the camera"
    assert ctx["change_text"].endswith("mm along the robot base axes, deg about the camera axes")


def test_a_pose_only_session_against_images_is_refused_for_having_no_images(rig, tmp_path, capsys):
    """It was refused as 'the session's board (tracked target ...) is not the installed calibration's' with the hint
    to verify with the board the rig was calibrated with: a tracker's session has no images to verify with."""
    from handeye.sim.poses import make_tracker_session

    make_tracker_session(mode="eye_in_hand", n_views=6, seed=4).write(tmp_path / "tracked")
    rc = main(
        ["-q", "verify", str(tmp_path / "tracked"), "--against", str(rig["installed"]), "--out", str(tmp_path / "v")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "a pose-only session" in err[0] and "handeye compare" in err[0], err
    assert "board" not in err[0] and not (tmp_path / "v").exists()


def test_verify_plan_says_what_the_installed_result_lacks(rig, tmp_path, capsys):
    """It said 'lacks X, its covariance, the board or the intrinsics -> plan against a refined result with status
    ok' for each: a closed-form-only result lacks the covariance, a tracker's calibration the intrinsics."""
    from handeye.pipeline import CalibrateOptions
    from handeye.sim.poses import make_tracker_session
    from handeye.workflow import calibrate_session

    calibrate_session(rig["session"], options=CalibrateOptions(refine=False), out_dir=tmp_path / "closed", report=False)
    make_tracker_session(mode="eye_in_hand", n_views=8, seed=4).write(tmp_path / "tracked")
    calibrate_session(tmp_path / "tracked", out_dir=tmp_path / "tracker", report=False)
    for result, lacks in (
        ("closed", "lacks the covariance of X (calibrated with --no-refine) ->"),
        ("tracker", "lacks camera intrinsics (calibrated from a tracker's poses) ->"),
    ):
        rc = main(["-q", "verify", "--plan", "--against", str(tmp_path / result)])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and lacks in err[0] and "status" not in err[0], err


def test_verify_against_a_failed_calibration_says_it_failed(rig, tmp_path, capsys):
    """It said 'has no hand-eye matrix (status failed) -> verify against a result with status ok'."""
    import shutil

    import yaml

    from handeye.workflow import calibrate_session

    wrong = tmp_path / "wrong_board"
    shutil.copytree(rig["session"], wrong)
    cfg = yaml.safe_load((wrong / "config.yaml").read_text())
    cfg["checkerboard_args"]["XX"] += 2  # a board the images do not show: the calibration fails
    (wrong / "config.yaml").write_text(yaml.safe_dump(cfg))
    assert calibrate_session(wrong, out_dir=tmp_path / "failed", report=False).status == "failed"
    rc = main(["-q", "verify", str(rig["check"]), "--against", str(tmp_path / "failed"), "--out", str(tmp_path / "v")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "the installed calibration failed: its result has no hand-eye matrix" in err[0]
    assert "status" not in err[0], err
    # collect --verify-against says the same (it said "(status failed)")
    args = ["-q", "collect", str(tmp_path / "c"), "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim"]
    assert main([*args, "--verify-against", str(tmp_path / "failed")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the installed calibration failed: its result has no hand-eye matrix" in err[0], err


def test_the_calibration_report_says_the_prior_s_covariance_in_words():
    """A ``calibrate --prior`` report names the earlier result's covariance as verify's report does, not by its key."""
    from handeye.report.context import _prior_block

    block = _prior_block({"prior": {"source": "old/result.json", "covariance_used": "cov_x_6x6_verdict"}}, "T_end_cam")
    assert block["covariance_used"] == "its verdict covariance"
    assert _prior_block({"prior": {"source": "old/result.json"}}, "T_end_cam")["covariance_used"] == ""


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_verify_says_when_most_views_were_left_out_that_the_verdict_rests_on_the_rest(mode):
    """A real eye-to-hand check (the UR3 set's camera 1 against its own calibration, whose board slipped in the
    gripper) kept 5 of 14 views and said only "the camera moved" and "the robot poses of views ... disagree (a
    collision, a changed tool frame or a robot fault)". Past half the views, the ones left out are no longer
    exceptions: the first line says so, and names the board moving in its place and poses of another frame."""
    from handeye.recal.verification import what_moved

    change = {"trans_mm": 38.1, "rot_deg": 1.94}
    kw = dict(mode=mode, frame="X", drifted=True, change=change, board={}, intrinsics={}, dof=6, n_views=6)
    half = what_moved(robot={"views": ["1", "3", "5"]}, **kw)
    where = "on the table" if mode == "eye_in_hand" else "in the gripper"
    assert half[0] == (
        "only 3 of the 6 views agree with one another (3 left out for their robot poses), and the verdict rests on "
        f"those 3: when so many views disagree, more often the board moved {where} during the check or the poses "
        "are not this robot's flange poses; check both and capture the views again"
    ), half
    assert "camera moved" in half[1] and "robot poses of views 1, 3, 5" in half[2], half
    fewer = what_moved(robot={"views": ["1", "3"]}, **kw)  # 2 of 6: outliers a robust solve tells from the rule
    assert not any("agree with one another" in line for line in fewer), fewer
    assert "camera moved" in fewer[0], fewer


def test_verify_reports_link_the_installed_result_s_report(tmp_path):
    """verify.html and verify.md named the installed result by its absolute path alone: a QA engineer reading a
    check had no way to its calibration's report. They link it, relative to the check's folder, when it exists."""
    from handeye.recal.report import installed_report_link

    inst = tmp_path / "installs" / "cell1"
    inst.mkdir(parents=True)
    (inst / "report.html").write_text("<html></html>")
    v = {"against": str(inst / "result.json")}
    assert installed_report_link(v, tmp_path / "checks" / "2026-12") == "../../installs/cell1/report.html"
    assert installed_report_link({"against": str(inst)}, tmp_path / "v") == "../installs/cell1/report.html"
    (inst / "report.html").unlink()  # a result calibrated with --no-report
    assert installed_report_link(v, tmp_path / "v") == ""


def test_verify_s_change_lines_give_a_small_sigma_its_digits():
    """verify printed "z: -0.000 +- 0.003 mm" and a sigma below the digits as 0.0000: a sigma is never shown as
    zero, and a change of zero has no sign of its own."""
    from handeye.cli.verify import verification_lines

    d = {
        "headline": "T_end_cam still valid",
        "frame": "T_end_cam",
        "n_views": 6,
        "what_moved": [],
        "test": {"statistic": 1.0, "dof": 6, "p_value": 0.98, "alpha": 0.05, "reference": "chi-square(6)"},
        "change": {
            "d_trans_mm": [0.0123, -0.0004, -0.0],
            "sigma_trans_mm": [0.004, 0.0003, 0.003],
            "d_rot_deg": [0.0, 0.0, 0.0],
            "sigma_rot_deg": [0.00002, 0.001, 0.001],
        },
    }
    lines = verification_lines(d)
    assert lines[2] == "  x:   +0.012 +- 0.004 mm    +0.0000 +- 0.000020 deg", lines
    assert lines[3] == "  y: -0.00040 +- 0.00030 mm    +0.0000 +- 0.0010 deg", lines
    assert lines[4] == "  z:   +0.000 +- 0.003 mm    +0.0000 +- 0.0010 deg", lines
