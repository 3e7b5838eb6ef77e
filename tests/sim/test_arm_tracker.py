"""The pose-level arm/tracker simulator: each option does what it says, with its ground truth."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.stats import kurtosis

from handeye.frames import inv_T, se3_log
from handeye.kinematics import T_base_end, load_arm
from handeye.sim.arm_tracker import make_arm_tracker_session


def _tracker_noise(ts) -> np.ndarray:
    """(N, 6) the tracker's error from the truth: rotation (right tangent), translation in the camera frame."""
    t = ts.truth
    if ts.mode == "eye_in_hand":
        C = inv_T(t.T_x_true)[None] @ inv_T(t.T_base_end_true) @ t.T_board_true[None]
    else:
        C = inv_T(t.T_x_true)[None] @ t.T_base_end_true @ t.T_board_true[None]
    rot = np.stack([se3_log(inv_T(C[k]) @ ts.T_cam_board[k])[:3] for k in range(len(C))])
    return np.hstack([rot, ts.T_cam_board[:, :3, 3] - C[:, :3, 3]])


def test_defaults_are_unchanged_and_the_reported_poses_are_the_true_ones():
    ts = make_arm_tracker_session(seed=3)
    chain = load_arm("ur5e")
    T = np.stack([T_base_end(chain, q) for q in ts.truth.joints_rad])
    np.testing.assert_allclose(ts.T_base_end, T, atol=1e-12)
    np.testing.assert_allclose(ts.truth.T_base_end_true, T, atol=1e-12)
    assert ts.truth.robot_error is None and ts.truth.outlier_view_ids == () and ts.truth.time_offset == 0.0


@pytest.mark.parametrize("arm", ["ur3", "ur10e", "ur16e", "rm65"])
def test_every_preset_arm_gives_a_session(arm):
    ts = make_arm_tracker_session(arm=arm, mode="eye_to_hand", n_views=6, seed=1)
    assert ts.truth.arm == arm and ts.T_base_end.shape == (6, 4, 4) and ts.T_cam_board.shape == (6, 4, 4)


def test_heavy_tails_give_a_larger_kurtosis():
    kw = {"n_views": 400, "seed": 5, "sigma_mm": 0.5, "sigma_deg": 0.1}
    gauss = _tracker_noise(make_arm_tracker_session(**kw))
    heavy = _tracker_noise(make_arm_tracker_session(tracker_dof=3.0, **kw))
    kg, kh = kurtosis(gauss, axis=0), kurtosis(heavy, axis=0)  # excess kurtosis per component
    assert np.all(np.abs(kg) < 1.0) and np.all(kh > 2.0), (kg, kh)


def test_anisotropic_noise_is_larger_along_the_optical_axis_and_stated_as_mm_along(tmp_path):
    ts = make_arm_tracker_session(n_views=400, seed=2, sigma_mm=0.5, axial_factor=4.0)
    n = _tracker_noise(ts)
    sd = n[:, 3:].std(axis=0) * 1e3  # camera frame: z is the optical axis
    assert sd[0] == pytest.approx(0.5, rel=0.15) and sd[2] == pytest.approx(2.0, rel=0.15), sd
    d = yaml.safe_load(ts.write(tmp_path / "s", state_sigma=True).read_text())
    assert d["tracker_sigma"] == {"mm": 0.5, "deg": 0.1, "mm_along": 2.0}


@pytest.mark.parametrize("which", ["robot", "tracker"])
def test_outliers_are_in_the_truth_and_only_there(which):
    clean = make_arm_tracker_session(seed=4, sigma_mm=0.0, sigma_deg=0.0)
    ts = make_arm_tracker_session(seed=4, sigma_mm=0.0, sigma_deg=0.0, outlier_views=3, outlier_poses=which)
    assert len(ts.truth.outlier_view_ids) == 3 and set(ts.truth.outlier_poses.values()) == {which}
    moved = ts.T_base_end if which == "robot" else ts.T_cam_board
    ref = clean.T_base_end if which == "robot" else clean.T_cam_board
    dist = np.array([np.linalg.norm(se3_log(inv_T(ref[k]) @ moved[k])[3:]) for k in range(len(ref))]) * 1e3
    bad = [ts.view_ids.index(v) for v in ts.truth.outlier_view_ids]
    assert np.all(dist[bad] >= 19.0) and np.all(np.delete(dist, bad) < 1e-9)


def test_a_systematic_arm_error_differs_from_the_truth_by_a_pose_dependent_amount():
    ts = make_arm_tracker_session(
        seed=6, arm="ur10", dh_length_error_mm=(0.3, 0.5), dh_angle_error_deg=(0.03, 0.05), encoder_sigma_deg=0.0
    )
    t = ts.truth
    d = np.stack([se3_log(inv_T(t.T_base_end_true[k]) @ ts.T_base_end[k]) for k in range(len(ts.view_ids))])
    mm = np.linalg.norm(d[:, 3:], axis=1) * 1e3
    assert 0.2 < np.median(mm) < 10.0  # a DH error of a few tenths of a mm and deg over a 1.3 m arm
    assert np.std(d[:, 3:] * 1e3, axis=0).max() > 0.1  # not one fixed offset: it depends on the pose
    assert t.robot_error["model"] == "kinematic" and t.robot_error["arm"] == "ur10"
    np.testing.assert_allclose(t.joints_reported_rad, t.joints_rad, atol=0)  # no encoder noise: same joints


def test_a_time_offset_shifts_the_true_configuration_towards_the_next_one():
    a = make_arm_tracker_session(seed=7)
    b = make_arm_tracker_session(seed=7, time_offset=0.05)
    np.testing.assert_allclose(b.T_base_end, a.T_base_end, atol=1e-12)  # the robot reports the commanded joints
    step = b.truth.joints_rad[:-1] - a.truth.joints_rad[:-1]
    np.testing.assert_allclose(step, 0.05 * (a.truth.joints_rad[1:] - a.truth.joints_rad[:-1]), atol=1e-12)
    assert not np.allclose(b.T_cam_board, a.T_cam_board)  # the tracker saw the arm where it really was
    assert b.truth.time_offset == 0.05
