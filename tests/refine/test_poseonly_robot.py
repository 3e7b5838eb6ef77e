"""The arm's kinematic model on pose-only sessions (``--robot ARM`` on tracker data)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from scipy.special import chdtri

from handeye.factors.pose import pose_residual, pose_robot_residual
from handeye.frames import inv_T, se3_exp, se3_log
from handeye.initial import all_methods
from handeye.mounting import mounting
from handeye.refine import RefineOptions
from handeye.refine.poseonly import PoseView, refine_poses, refit_poses
from handeye.sim.arm_tracker import make_arm_tracker_session

Q95 = float(chdtri(6, 0.05))  # chi-square(6) 95 % point: the 95 % ellipsoid of X
ARM_ERROR = {"dh_length_error_mm": (0.1, 0.5), "dh_angle_error_deg": (0.01, 0.05), "encoder_sigma_deg": 0.005}


def _views(ts, joints=False):
    q = ts.truth.joints_reported_rad
    return [
        PoseView(v, ts.T_cam_board[k], ts.T_base_end[k], q[k] if joints else None) for k, v in enumerate(ts.view_ids)
    ]


def _refine(ts, arm=None, joints=False, **kw):
    m = mounting(ts.mode)
    cf = all_methods(m, ts.T_cam_board, np.stack([m.M_from_T_base_end(T) for T in ts.T_base_end]))
    views = _views(ts, joints)
    res = refine_poses(
        mode=ts.mode,
        views=views,
        T_x0=cf["tsai"].T_x,
        T_board0=cf["tsai"].T_board,
        starts=cf,
        options=RefineOptions(arm=arm),
        **kw,
    )
    assert res.status == "ok", res.failure_reason
    return res, views


def _m2(res, ts) -> float:
    xi = se3_log(inv_T(res.T_x) @ ts.truth.T_x_true)
    return float(xi @ np.linalg.solve(res.cov_x_6x6, xi))


# ------------------------------------------------------------------------------ the factor
@pytest.mark.parametrize("inverts_robot", [True, False])
def test_pose_robot_residual_jacobians_match_numeric(inverts_robot):
    rng = np.random.default_rng(2)
    T_x, T_b, T_be = (se3_exp(rng.normal(0, 0.5, 6)) for _ in range(3))
    M = inv_T(T_be) if inverts_robot else T_be
    C = inv_T(T_x) @ M @ T_b @ se3_exp(rng.normal(0, 0.02, 6))  # a residual of a refinement's size
    u = rng.normal(0, 0.01, 6)
    r, J_x, J_b, J_u = pose_robot_residual(
        T_x=T_x, T_base_end=T_be, u=u, T_board=T_b, T_cam_board_measured=C, inverts_robot=inverts_robot
    )

    def f(uu):
        return pose_robot_residual(
            T_x=T_x,
            T_base_end=T_be,
            u=uu,
            T_board=T_b,
            T_cam_board_measured=C,
            inverts_robot=inverts_robot,
            jacobians=False,
        )[0]

    h = 1e-6
    J_num = np.stack([(f(u + h * e) - f(u - h * e)) / (2 * h) for e in np.eye(6)], axis=1)
    assert np.abs(J_num - J_u).max() < 1e-6
    assert np.linalg.norm(r) > 0.01  # the test is not at a zero residual
    # u = 0: the pose residual of the reported pose
    r0, Jx0, Jb0 = pose_residual(T_x=T_x, M=M, T_board=T_b, T_cam_board_measured=C)
    r1, Jx1, Jb1, _ = pose_robot_residual(
        T_x=T_x, T_base_end=T_be, u=np.zeros(6), T_board=T_b, T_cam_board_measured=C, inverts_robot=inverts_robot
    )
    assert np.allclose(r0, r1, atol=1e-14) and np.allclose(Jx0, Jx1) and np.allclose(Jb0, Jb1)


# ------------------------------------------------------------------------------ the refinement
@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_an_exact_arm_and_tracker_give_the_truth_with_the_arm_model(mode):
    """Noiseless: the DH offsets stay at zero and X is the truth to 1e-8."""
    ts = make_arm_tracker_session(arm="ur5e", mode=mode, n_views=12, seed=5, sigma_mm=0.0, sigma_deg=0.0)
    res, _ = _refine(ts, arm="ur5e", tracker_sigma=(np.radians(0.01), 1e-5))
    xi = se3_log(inv_T(res.T_x) @ ts.truth.T_x_true)
    assert np.abs(xi).max() < 1e-8
    assert np.abs(res.dh_offset).max() < 1e-8


@pytest.mark.parametrize(
    "mode, seed, plain_outside", [("eye_in_hand", 0, True), ("eye_in_hand", 2, True), ("eye_to_hand", 0, False)]
)
def test_a_dh_error_lies_inside_the_95_region_with_the_arm_model(mode, seed, plain_outside):
    """A UR5e with DH errors of its prior's size: with the arm's model the truth is inside the reported 95 %
    ellipsoid (without it, outside for these eye-in-hand sessions) and the covariance of X grows by the DH
    offsets' uncertainty (marginalised) and the encoder noise."""
    ts = make_arm_tracker_session(arm="ur5e", mode=mode, seed=seed, **ARM_ERROR)
    plain, _ = _refine(ts)
    res, _ = _refine(ts, arm="ur5e")
    assert plain.robot_model["kind"] == "none" and plain.pose_robot is None and plain.dh_offset is None
    assert (_m2(plain, ts) > Q95) == plain_outside
    assert _m2(res, ts) < Q95
    # at one stated tracker noise, the arm's model only adds variance: the encoders' and the DH offsets'
    stated = (np.radians(ts.truth.sigma_deg), ts.truth.sigma_mm / 1000.0)
    grown = _refine(ts, arm="ur5e", tracker_sigma=stated)[0].cov_x_6x6 - _refine(ts, tracker_sigma=stated)[0].cov_x_6x6
    assert np.linalg.eigvalsh(grown).min() > -1e-15 and np.trace(grown[3:, 3:]) > 0
    rm = res.robot_model
    assert rm["kind"] == "kinematic" and rm["arm"] == "Universal Robots UR5e"
    assert rm["joint_angles"] == "inverse kinematics of the reported poses"
    po = rm["pose_only"]
    assert "cannot tell them apart" in po["encoder_noise"]
    assert len(po["dh_resolved"]) + len(po["dh_held_by_prior"]) == 24
    assert res.options.robot_noise == "fixed" and res.robot_sigma_mm > 0
    # the refined robot poses are the reported ones corrected by the estimated DH offsets
    km, vid = res.pose_robot.km, ts.view_ids[3]
    assert np.allclose(res.robot_poses[vid], ts.T_base_end[3] @ se3_exp(km.J_dh[3] @ res.dh_offset), atol=1e-12)
    assert not np.allclose(res.robot_poses[vid], ts.T_base_end[3], atol=1e-6)


def test_recorded_joints_give_the_inverse_kinematics_model():
    ts = make_arm_tracker_session(arm="ur5e", seed=1, n_views=12, **ARM_ERROR)
    ik, _ = _refine(ts, arm="ur5e")
    rec, _ = _refine(ts, arm="ur5e", joints=True)
    assert rec.robot_model["joint_angles"] == "recorded"
    assert np.array_equal(rec.pose_robot.km.joints, ts.truth.joints_reported_rad)
    # inverse kinematics finds the configuration the arm was in (the one nearest its home, then each view's
    # nearest the previous view's), not another reaching the same poses: the same model
    arm = ik.pose_robot.km.arm
    assert np.allclose(arm.T_base_end(ik.pose_robot.km.joints), ts.T_base_end, atol=1e-9)
    assert np.allclose(ik.pose_robot.km.joints, ts.truth.joints_reported_rad, atol=1e-7)
    xi = se3_log(inv_T(rec.T_x) @ ik.T_x)
    assert xi @ np.linalg.solve(rec.cov_x_6x6, xi) < 1e-6


def test_the_refits_use_the_arm_model():
    """A refit on every view is the full solution with its covariance; a fold keeps the arm's model."""
    ts = make_arm_tracker_session(arm="ur5e", seed=3, n_views=14, **ARM_ERROR)
    res, views = _refine(ts, arm="ur5e")
    every = refit_poses(res, views)
    assert every.status == "ok"
    assert np.allclose(every.T_x, res.T_x, atol=1e-9)
    plug_in = res.cov_x_6x6 / res.cov_x_dof_factor  # a refit holds the sigmas: no degrees-of-freedom factor
    assert np.allclose(every.cov_x, plug_in, rtol=1e-6, atol=1e-14)
    fold = refit_poses(res, views[2:])
    assert fold.status == "ok" and np.all(np.linalg.eigvalsh(fold.cov_x - plug_in) > -1e-15)


# ------------------------------------------------------------------------------ the command line
def test_calibrate_accepts_robot_on_a_pose_only_session(tmp_path):
    from handeye.cli import main

    ts = make_arm_tracker_session(arm="ur5e", seed=2, n_views=14, **ARM_ERROR)
    ts.write(tmp_path / "s", state_sigma=False)
    rc = main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--robot", "ur5e"])
    assert rc == 0
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    ref = res["refinement"]
    assert ref["robot_model"]["kind"] == "kinematic" and "pose_only" in ref["robot_model"]
    assert ref["options"]["arm"] == "ur5e" and ref["robot_noise_model"] == "fixed"
    assert "robot poses through the arm's kinematic model" in ref["tracker_noise"]["model"]
    assert ref["cov_x_6x6_verdict"] is not None and ref["validation"]["status"] == "ok"
    md = (tmp_path / "o" / "report.md").read_text()
    assert "Robot error model: **kinematic**" in md and "from poses alone: the encoder noise is held" in md


def test_session_yaml_robot_and_joints_name_the_arm(tmp_path):
    """``robot:`` in session.yaml and each view's ``joints:``: the arm's model with the recorded joint angles."""
    from handeye.workflow import calibrate_session

    ts = make_arm_tracker_session(arm="ur5e", seed=4, n_views=12, **ARM_ERROR)
    path = ts.write(tmp_path / "s", state_sigma=False)
    d = yaml.safe_load(path.read_text())
    d["robot"] = "ur5e"
    for v, q in zip(d["views"], ts.truth.joints_reported_rad, strict=True):
        v["joints"] = q.tolist()
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    calibrate_session(tmp_path / "s", out_dir=tmp_path / "o", report=False, diagnostics=False)
    rm = json.loads((tmp_path / "o" / "result.json").read_text())["refinement"]["robot_model"]
    assert rm["kind"] == "kinematic" and rm["joint_angles"] == "recorded"


def test_without_robot_a_pose_only_session_takes_the_robot_poses_as_reported(tmp_path):
    from handeye.cli import main

    ts = make_arm_tracker_session(arm="ur5e", seed=2, n_views=10, **ARM_ERROR)
    ts.write(tmp_path / "s", state_sigma=False)
    assert main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--no-report"]) == 0
    ref = json.loads((tmp_path / "o" / "result.json").read_text())["refinement"]
    assert ref["robot_model"]["kind"] == "none" and ref["robot_noise_model"] == "none"
    assert ref["robot_sigma_mm"] == 0.0


def test_the_robot_model_option_chooses_the_model_on_pose_only_views():
    """joint_space: encoder noise only (no DH offsets); iid: the robot's noise is part of the tracker's (none)."""
    ts = make_arm_tracker_session(arm="ur5e", seed=6, n_views=10, **ARM_ERROR)
    m = mounting(ts.mode)
    cf = all_methods(m, ts.T_cam_board, np.stack([m.M_from_T_base_end(T) for T in ts.T_base_end]))
    kw = {"mode": ts.mode, "views": _views(ts), "T_x0": cf["tsai"].T_x, "T_board0": cf["tsai"].T_board}
    enc = refine_poses(**kw, options=RefineOptions(arm="ur5e", robot_model="joint_space"))
    assert enc.status == "ok" and enc.robot_model["kind"] == "joint_space" and enc.dh_offset.size == 0
    assert set(enc.robot_model["pose_only"]) == {"encoder_noise"} and "dh_offset" not in enc.robot_model
    iid = refine_poses(**kw, options=RefineOptions(arm="ur5e", robot_model="iid"))
    assert iid.status == "ok" and iid.robot_model["kind"] == "none" and iid.pose_robot is None
