"""Pose-only sessions of a simulated arm: degenerate motion, a drifting target and a knocked target are
each named by their own finding, never as a pairing fault or one another."""

from __future__ import annotations

import json

import pytest

from handeye.errors import HandeyeError
from handeye.sim.arm_tracker import make_arm_tracker_session
from handeye.workflow import calibrate_session

WRONG_FOR_MOTION = {"pairs_shuffled", "pairs_shifted", "board_moved", "target_drift", "poses_do_not_fit"}


def _calibrate(tmp_path, **kw) -> dict:
    ts = make_arm_tracker_session(n_views=20, **kw)
    ts.write(tmp_path / "s", state_sigma=False)
    try:
        calibrate_session(tmp_path / "s", out_dir=tmp_path / "out", report=False)
    except HandeyeError as e:  # a refused or failed run still writes its result.json
        if not (tmp_path / "out" / "result.json").exists():
            raise AssertionError(f"no result.json ({e})") from e
    return json.loads((tmp_path / "out" / "result.json").read_text())


def _codes(res: dict) -> set:
    return {f["code"] for f in res.get("findings", []) if f.get("severity") in ("fail", "warn")}


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("seed", [0, 1])
def test_only_the_parallel_joints_moving_is_degenerate_motion(tmp_path, mode, seed):
    res = _calibrate(tmp_path, mode=mode, seed=seed, moving_joints=(1, 2, 3))
    assert res["status"] == "failed" and res["error"]["code"] == "motion_one_axis"
    assert "weak_motion" in _codes(res) and not _codes(res) & WRONG_FOR_MOTION, res["findings"]


@pytest.mark.parametrize(
    "mode, seed",
    # the last two: drifts the step test alone missed (their own test, diagnose/drift.py ramp_test, names them)
    [
        ("eye_to_hand", 0),
        ("eye_to_hand", 1),
        ("eye_in_hand", 3),
        ("eye_in_hand", 4),
        ("eye_in_hand", 5),
        ("eye_to_hand", 2),
    ],
)
def test_a_drifting_tracker_is_named_as_drift_where_it_starts(tmp_path, mode, seed):
    res = _calibrate(tmp_path, mode=mode, seed=seed, drift_mm_per_view=3.0, drift_start=10)
    codes = _codes(res)
    assert "target_drift" in codes and not codes & {"board_moved", "pairs_shuffled", "pairs_shifted"}, codes
    f = next(f for f in res["findings"] if f["code"] == "target_drift")
    start = int(f["view_ids"][0]) - 1  # the drifted views, from the first; ids 001.. are indices 0..
    assert 9 <= start <= 12 and "tracker" in f["title"]


@pytest.mark.parametrize(
    "mode, seed, arm, per_view, start",
    # drifts whose direction in the board's frame turns from view to view: fitted coordinate by coordinate (with
    # the step fit's outliers left out) a step explained them better; fitted to the deviations' sizes, a drift
    [
        ("eye_in_hand", 37, "ur5", 3.58, 13),
        ("eye_in_hand", 39, "ur16e", 3.32, 13),
        ("eye_to_hand", 13, "ur10e", 3.82, 10),
    ],
)
def test_a_drift_that_turns_with_the_views_is_still_a_drift(tmp_path, mode, seed, arm, per_view, start):
    res = _calibrate(
        tmp_path,
        mode=mode,
        seed=seed,
        arm=arm,
        sigma_mm=0.5,
        sigma_deg=0.1,
        drift_mm_per_view=per_view,
        drift_start=start,
    )
    codes = _codes(res)
    assert "target_drift" in codes and "board_moved" not in codes, codes
    f = next(f for f in res["findings"] if f["code"] == "target_drift")
    assert abs(int(f["view_ids"][0]) - 1 - start) <= 2


@pytest.mark.parametrize("mode, seed", [("eye_to_hand", 0), ("eye_in_hand", 3)])
def test_a_knocked_target_is_still_a_move_not_a_drift(tmp_path, mode, seed):
    res = _calibrate(tmp_path, mode=mode, seed=seed, step_mm=25.0, drift_start=10)
    assert "board_moved" in _codes(res) and "target_drift" not in _codes(res), res["findings"]


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_tracker_with_twice_the_scale_is_named_with_its_factor(tmp_path, mode):
    res = _calibrate(tmp_path, mode=mode, seed=0, scale=2.0)
    codes = _codes(res)
    assert "tracker_scale" in codes and not codes & {"board_moved", "poses_do_not_fit", "target_drift"}, codes
    f = next(f for f in res["diagnostics"]["findings"] if f["code"] == "tracker_scale")
    assert f["details"]["scale"] == pytest.approx(0.5, rel=0.01)
    assert f"{f['details']['scale']:.4f}" in f["action"] and f"{1 / f['details']['scale']:.4f}" in f["title"]


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_tracker_sessions_are_quiet(tmp_path, mode, seed):
    res = _calibrate(tmp_path, mode=mode, seed=seed)
    assert res["status"] == "ok" and not {f["code"] for f in res["findings"] if f["severity"] == "fail"}
    assert not _codes(res) & (WRONG_FOR_MOTION | {"tracker_scale", "weak_motion"}), res["findings"]


def test_a_view_whose_tracker_pose_is_wrong_is_named_against_the_tracker(tmp_path):
    truth = make_arm_tracker_session(n_views=20, seed=1, outlier_views=1, outlier_poses="tracker").truth
    res = _calibrate(tmp_path, seed=1, outlier_views=1, outlier_poses="tracker")
    f = next(f for f in res["findings"] if f["code"] == "robot_pose_disagrees")
    assert "the tracker's pose" in f["title"] and "camera saw" not in f["title"] and "tracker" in f["action"]
    assert list(f["view_ids"]) == list(truth.outlier_view_ids)


def test_a_drifting_board_s_fix_also_names_the_robot_s_poses():
    """A board that drifts relative to what holds it may not have moved: the robot's reported poses drift the
    same way (an arm warming up, a model whose error grows along the path). The fix names both."""
    from types import SimpleNamespace

    import numpy as np

    from handeye.diagnose.drift import drift_finding
    from handeye.targets import ChessboardSpec

    obs = SimpleNamespace(target=ChessboardSpec(9, 7, 0.02), ids=tuple(str(k) for k in range(1, 21)))
    v = np.zeros((20, 6))
    v[10:, 3] = np.arange(1, 11)  # 1 mm more per view from view 11 on
    f = drift_finding(obs, 10, 0.5, v)
    assert f.code == "target_drift" and f.title == "The board drifts from view 11 on"
    assert "fix it rigidly" in f.action and "reported poses drift" in f.action and "warm up" in f.action
