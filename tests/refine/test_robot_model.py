"""The refinement's kinematic robot error model: the factor against numerical derivatives, recovery of a
known joint-offset error, the DH prior's share in the covariance of X where the views cannot resolve
it, joint angles by inverse kinematics and through a tool offset, and the errors of bad input."""

from __future__ import annotations

import json
from dataclasses import replace

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative21, numericalDerivative22
from scipy.stats import chi2

from handeye.errors import ConfigError
from handeye.factors.gtsam_factors import kinematic_robot_prior
from handeye.frames import se3_exp, tangent_difference
from handeye.kinematics import load_arm, solve_ik
from handeye.refine import RefineOptions, refine
from handeye.sim.corners import make_corner_session

ARM = load_arm("rm65")
THETA_3 = 4 * 2 + 3  # index of theta_offset_3 among the DH offsets (a, alpha, d, theta_offset per joint)


def _refine(s, views, **opts):
    return refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=views,
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true,
        T_board0=s.T_board_true,
        options=RefineOptions(**opts),
    )


def _m2(r, s):
    xi = tangent_difference(r.T_x, s.T_x_true)
    return float(xi @ np.linalg.solve(r.cov_x_6x6, xi))


def _exact_arm_session(mode, seed, *, n_views=15, noise_px=0.1):
    """A session of the nominal RM65-B with exact encoders: reported = true, joint angles recorded."""
    return make_corner_session(
        mode=mode,
        n_views=n_views,
        seed=seed,
        noise_px=noise_px,
        robot_error="kinematic",
        dh_length_error_mm=(0.0, 0.0),
        dh_angle_error_deg=(0.0, 0.0),
        encoder_sigma_deg=0.0,
    )


def test_kinematic_prior_factor_jacobians_match_numerical_derivatives():
    rng = np.random.default_rng(3)
    T_rep = se3_exp(rng.normal(size=6) * 0.5)
    P = gtsam.Pose3(T_rep @ se3_exp(rng.normal(size=6) * 1e-2))
    J = rng.normal(size=(6, 24)) * 0.3
    dh = rng.normal(size=24) * 1e-3
    f = kinematic_robot_prior(key_robot=1, key_dh=2, T_base_end_reported=T_rep, J_dh=J, cov=np.eye(6))
    v = gtsam.Values()
    v.insert(1, P)
    v.insert(2, dh)
    lin = f.linearize(v)
    A, b = lin.jacobian()

    def err(p, d):
        return tangent_difference(T_rep, p.matrix()) - J @ d

    np.testing.assert_allclose(-b, err(P, dh), atol=1e-12)
    np.testing.assert_allclose(A[:, :6], numericalDerivative21(err, P, dh), atol=1e-7)
    np.testing.assert_allclose(A[:, 6:], numericalDerivative22(err, P, dh), atol=1e-7)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_known_joint_offset_error_is_recovered(mode):
    """Joint 3's encoder reads 0.1 deg short: the true arm is the nominal one with theta_offset_3 off by
    +0.1 deg. The kinematic model finds that offset within its sigma and keeps X within its ellipsoid;
    the iid model, blind to the structure, is further off."""
    s = _exact_arm_session(mode, seed=4)
    off = np.radians(0.1)
    q_rep = np.array(s.joints_true) - off * np.eye(6)[2]
    T_rep = ARM.T_base_end(q_rep)
    r = _refine(s, s.refine_views(q_rep, T_rep), arm="rm65")
    assert r.status == "ok", r.failure_reason
    assert r.robot_model["kind"] == "kinematic" and r.robot_model["joint_angles"] == "recorded"
    est = np.asarray(r.robot_model["dh_offset"])[2, 3]  # joint 3, theta_offset, deg
    sd = np.asarray(r.robot_model["dh_offset_sigma"])[2, 3]
    assert sd < 0.02, f"{mode}: theta_offset_3 not resolved (sigma {sd:.4f} deg)"
    assert abs(est - 0.1) < 4 * sd, f"{mode}: theta_offset_3 {est:.4f} +- {sd:.4f} deg, truth 0.1"
    assert _m2(r, s) < chi2.ppf(0.999, 6)
    iid = _refine(s, s.refine_views(None, T_rep), robot_model="iid")
    err = lambda res: np.linalg.norm(tangent_difference(res.T_x, s.T_x_true)[3:])  # noqa: E731
    assert err(r) < err(iid), f"{mode}: kinematic {err(r) * 1e3:.3f} mm vs iid {err(iid) * 1e3:.3f} mm"


def test_an_unresolved_flange_length_error_is_in_the_covariance_of_x():
    """Eye-in-hand, a flange-length error (d_6) moves the flange along its z exactly as X's translation
    does: no view can tell them apart, so X's translation sigma along the flange z must keep the DH
    prior's 0.3 mm instead of claiming the camera's precision; and the truth lies in the ellipsoid."""
    s = _exact_arm_session("eye_in_hand", seed=2, noise_px=0.05)
    true_arm = ARM.with_dh(ARM.dh + 0.0003 * np.outer(np.eye(6)[5], [0, 0, 1, 0]))  # d_6 + 0.3 mm
    # the flange is at the session's true poses, reached by the true arm; the controller reports the
    # nominal arm's pose at those joint angles
    q = np.stack([solve_ik(true_arm, T, seeds=[q0]) for T, q0 in zip(s.T_base_end_true, s.joints_true, strict=False)])
    T_rep = ARM.T_base_end(q)
    r = _refine(s, s.refine_views(q, T_rep), arm="rm65")
    kin_sd = r.robot_model["dh_offset_sigma"][5][2]
    assert kin_sd == pytest.approx(0.3, rel=0.05), f"d_6 should stay at its prior, sigma {kin_sd} mm"
    assert r.sigma_trans_mm[2] >= 0.29, f"X's translation along the flange z claims {r.sigma_trans_mm[2]:.3f} mm"
    assert _m2(r, s) < chi2.ppf(0.999, 6)
    no_model = _refine(s, s.refine_views(None, T_rep), robot_noise="none")
    assert no_model.sigma_trans_mm[2] < 0.1, "without the model the error is hidden behind a small sigma"


def test_joint_angles_by_inverse_kinematics_and_through_a_tool_offset():
    s = make_corner_session(mode="eye_to_hand", n_views=10, seed=1, noise_px=0.2, robot_error="kinematic")
    q = np.asarray(s.joints_encoder)
    base = _refine(s, s.refine_views(q), arm="rm65")
    ik = _refine(s, s.refine_views(None), arm="rm65")  # vendor session: joints from the reported poses
    assert ik.robot_model["joint_angles"] == "inverse kinematics of the reported poses"
    assert _m2(ik, s) < chi2.ppf(0.999, 6)  # the arm's configuration may differ from the recorded one
    # a tool frame 0.1 m out on the flange z: reported poses are the tool's, the model carries it
    T_tool = se3_exp(np.r_[0.0, 0.0, 0.3, 0.0, 0.0, 0.1])
    tool_views = s.refine_views(q, s.T_base_end_reported @ T_tool)
    tooled = refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=tool_views,
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true,
        T_board0=np.linalg.inv(T_tool) @ s.T_board_true,
        options=RefineOptions(arm="rm65"),
    )
    np.testing.assert_allclose(tangent_difference(tooled.T_x, base.T_x), 0.0, atol=1e-6)
    np.testing.assert_allclose(tooled.robot_model["tool_offset_T_flange_reported"], T_tool, atol=1e-9)
    assert np.allclose(tooled.cov_x_6x6, base.cov_x_6x6, rtol=1e-3, atol=1e-12)
    d = json.loads(json.dumps(base.to_dict()))
    assert d["robot_model"]["kind"] == "kinematic" and len(d["robot_model"]["dh_offset"]) == 6


def test_model_choice_and_bad_input():
    s = make_corner_session(mode="eye_in_hand", n_views=6, seed=0, noise_px=0.3, robot_error="kinematic")
    q = np.asarray(s.joints_encoder)
    assert _refine(s, s.refine_views(q)).robot_model["kind"] == "iid"  # no arm named: the iid model
    assert _refine(s, s.refine_views(q), robot_noise="none").robot_model["kind"] == "none"
    js = _refine(s, s.refine_views(q), arm="rm65", robot_model="joint_space")
    assert js.robot_model["kind"] == "joint_space" and "dh_offset" not in js.robot_model
    with pytest.raises(ConfigError, match="robot_model kinematic needs"):
        _refine(s, s.refine_views(q), robot_model="kinematic")
    with pytest.raises(ConfigError, match="robot_model"):
        _refine(s, s.refine_views(q), robot_model="dh")
    with pytest.raises(ConfigError, match="unknown robot model"):
        _refine(s, s.refine_views(q), arm="kuka")
    bad = q.copy()
    bad[:4, 1] += np.radians(1.0)  # most views' joints do not give their reported poses: not this arm's table
    with pytest.raises(ConfigError, match="joint angles do not give the reported poses"):
        _refine(s, s.refine_views(bad), arm="rm65")


def test_a_wrong_robot_pose_is_flagged_under_the_kinematic_model():
    s = make_corner_session(
        mode="eye_in_hand", n_views=12, seed=7, noise_px=0.3, robot_error="kinematic", outlier_views=1
    )
    r = _refine(s, s.refine_views(np.asarray(s.joints_encoder)), arm="rm65")
    assert r.robot_model["joints_disagree_view_ids"] == list(s.outlier_view_ids)
    flagged = [o.view_id for o in r.outliers if o.kind == "robot_pose"]
    assert flagged == list(s.outlier_view_ids), f"flagged {flagged}, wrong pose {s.outlier_view_ids}"
    assert _m2(r, s) < chi2.ppf(0.999, 6)


def _refine_stage_inputs(tmp_path, mode, seed, robot):
    """A simulated kinematic session as refine_stage takes it (session with ``robot:``, board poses,
    detections, flange poses, start): its images do not exist."""
    from types import SimpleNamespace

    from handeye.records import HandEyeEstimate, Session, View

    s = make_corner_session(mode=mode, n_views=6, seed=seed, noise_px=0.3, robot_error="kinematic")
    views = tuple(
        View(vid, tmp_path / f"{vid}.png", s.T_base_end_reported[k], joint_angles=tuple(s.joints_encoder[k]))
        for k, vid in enumerate(s.view_ids)
    )
    sess = Session(path=tmp_path, format="native", mode=s.mode, target=s.target, views=views, meta={"robot": robot})
    poses = {vid: SimpleNamespace(corner_ids=s.corner_ids[k]) for k, vid in enumerate(s.view_ids)}
    dets = {vid: SimpleNamespace(image_points=s.image_points[k]) for k, vid in enumerate(s.view_ids)}
    T = {vid: s.T_base_end_reported[k] for k, vid in enumerate(s.view_ids)}
    start = HandEyeEstimate(mode=s.mode, method="tsai", T_x=s.T_x_true, T_board=s.T_board_true)
    return sess, start, s.intrinsics, poses, dets, T


def test_the_pipeline_uses_the_arm_a_session_names(tmp_path):
    """session.yaml ``robot: rm65`` and the views' joint angles reach the refinement (refine_stage)."""
    from handeye.pipeline import CalibrateOptions, refine_stage

    sess, start, intr, poses, dets, T = _refine_stage_inputs(tmp_path, "eye_in_hand", 0, "rm65")
    r = refine_stage(sess, CalibrateOptions(), start, intr, poses, dets, T)
    assert r.robot_model["kind"] == "kinematic" and r.robot_model["joint_angles"] == "recorded"
    with pytest.raises(ConfigError, match="unknown robot model"):
        refine_stage(replace(sess, meta={"robot": "kuka"}), CalibrateOptions(), start, intr, poses, dets, T)


def test_a_session_names_a_json_dh_table_and_a_broken_one_fails_before_detection(tmp_path):
    """``robot: arm.json`` (relative to the session) in the JSON form other tools write reaches the
    refinement; a table that cannot be read stops the run with its one error before any image is read."""
    from handeye.kinematics import load_arm
    from handeye.pipeline import CalibrateOptions, refine_stage, run_calibration

    arm = load_arm("rm65")
    table = {
        "robot_name": "RM65 as JSON",
        "dh_convention": arm.convention,
        "units": {"length": "m", "angle": "rad"},
        "joints": [dict(zip(("a", "alpha", "d", "theta_offset"), map(float, row), strict=False)) for row in arm.dh],
    }
    (tmp_path / "arm.json").write_text(json.dumps(table))
    sess, start, intr, poses, dets, T = _refine_stage_inputs(tmp_path, "eye_to_hand", 1, "arm.json")
    r = refine_stage(sess, CalibrateOptions(), start, intr, poses, dets, T)
    assert r.robot_model["kind"] == "kinematic" and r.robot_model["arm"] == "RM65 as JSON"
    assert r.cov_board_6x6.shape == (6, 6) and np.all(np.linalg.eigvalsh(r.cov_board_6x6) > 0)
    (tmp_path / "arm.json").write_text(json.dumps(table)[:-3])
    run = run_calibration(sess, CalibrateOptions())  # the images do not exist: the table is what stops it
    assert run.status == "failed" and isinstance(run.error, ConfigError), run.failure_reason
    assert "cannot read the DH table" in str(run.error) and run.error.path == str(tmp_path / "arm.json")


def test_a_simulated_kinematic_session_names_its_arm_and_records_joint_angles(tmp_path):
    import yaml

    from handeye.session.native import read_native_document, view_joint_angles
    from handeye.sim.robot_error import write_native_session

    truth = {
        "mode": "eye_to_hand",
        "target": {"type": "chessboard", "inner_corners": [11, 8], "square_m": 0.03},
        "robot_error": {"model": "kinematic", "arm": "rm65"},
        "views": {
            "1": {"image": "1.jpg", "joints_encoder": [0.1, -0.4, 1.2, 0.0, 1.0, 0.2]},
            "2": {"image": "2.jpg", "joints_encoder": [0.2, -0.3, 1.1, 0.1, 0.9, 0.3]},
        },
    }
    (tmp_path / "ground_truth.json").write_text(json.dumps(truth))
    (tmp_path / "poses.txt").write_text("0.4,0.0,0.3,3.1,0.0,0.1\n0.5,0.1,0.3,3.0,0.1,0.0\n")
    doc = read_native_document(write_native_session(tmp_path))
    assert doc.data["robot"] == "rm65" and doc.mode == "eye_to_hand"
    assert [view_joint_angles(e) for e in doc.entries] == [tuple(v["joints_encoder"]) for v in truth["views"].values()]
    assert yaml.safe_load((tmp_path / "session.yaml").read_text())["views"][1]["pose"] == [0.5, 0.1, 0.3, 3.0, 0.1, 0.0]
    # a target the vendor layout cannot describe has its session.yaml already: it gets the joints and the arm,
    # keeping its target and intrinsics (else calibrate --robot would take the joints by inverse kinematics)
    native = tmp_path / "native"
    native.mkdir()
    (native / "ground_truth.json").write_text(json.dumps(truth))
    marker = {"type": "aruco", "dictionary": "DICT_4X4_50", "marker_id": 3, "marker_m": 0.1}
    views = [
        {"id": "1", "image": "1.jpg", "pose": [0.4, 0, 0.3, 3.1, 0, 0.1]},
        {"id": "2", "image": "2.jpg", "pose": [0.5] * 6},
    ]
    session = {"handeye_session": 1, "mode": "eye_to_hand", "target": marker, "pose_format": {"rotation": "euler"}}
    (native / "session.yaml").write_text(yaml.safe_dump({**session, "intrinsics": {"fx": 600.0}, "views": views}))
    doc = yaml.safe_load(write_native_session(native).read_text())
    assert doc["robot"] == "rm65" and doc["target"] == marker and doc["intrinsics"] == {"fx": 600.0}
    assert [v["joints"] for v in doc["views"]] == [v["joints_encoder"] for v in truth["views"].values()]
    assert [v["pose"] for v in doc["views"]] == [v["pose"] for v in views]
    truth["robot_error"] = {"model": "iid"}
    (tmp_path / "ground_truth.json").write_text(json.dumps(truth))
    with pytest.raises(ConfigError, match="not a kinematic simulated session"):
        write_native_session(tmp_path)


def _kinematic_session_refined(mode, seed, far):
    """A 20-view session of an arm whose DH errors are ``far`` times the RM65 preset's stated prior (0.3 mm /
    0.03 deg; drawn from 0.1-0.5 mm / 0.01-0.05 deg times ``far``), refined with the preset."""
    s = make_corner_session(
        mode=mode,
        n_views=20,
        seed=seed,
        noise_px=0.3,
        robot_error="kinematic",
        dh_length_error_mm=(0.1 * far, 0.5 * far),
        dh_angle_error_deg=(0.01 * far, 0.05 * far),
    )
    return s, _refine(s, s.refine_views(s.joints_encoder), arm="rm65")


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_an_arm_further_from_its_table_than_its_prior_states_widens_the_prior(mode, monkeypatch):
    """The arm's DH errors are 5x what its preset states. The DH offsets the views resolve contradict the
    stated prior (chi-square test), so its scale is estimated (~5) and X's ellipsoid holds the truth; held at
    the stated prior, the encoder noise takes up the misfit (several times its true 0.005 deg) and X's
    covariance is too small for its error. An arm within its stated prior keeps it (scale 1)."""
    import handeye.refine.noise as noise

    s, r = _kinematic_session_refined(mode, 0, 5.0)
    rm = r.robot_model
    assert rm["dh_prior_test"]["contradicted"] and rm["dh_prior_test"]["p_value"] < 1e-6, rm["dh_prior_test"]
    assert 3.0 < rm["dh_prior_scale"] < 8.0
    assert rm["dh_prior_sigma"]["length_mm"] == pytest.approx(0.3 * rm["dh_prior_scale"])
    assert rm["dh_prior_sigma_stated"] == {"length_mm": pytest.approx(0.3), "angle_deg": pytest.approx(0.03)}
    assert "dh_prior_scale" in rm["estimated"]
    # the test at the stated prior; the scale's own degrees of freedom at the widened one (verify's F reference)
    assert 0 < rm["dh_prior_test"]["redundancy"] <= rm["dh_prior_test"]["dof"]
    assert rm["dh_prior_test"]["redundancy"] < rm["dh_prior_scale_dof"]
    assert r.robot_noise_dof["dh_scale"] == pytest.approx(rm["dh_prior_scale_dof"])
    assert rm["encoder_sigma_deg"] < 0.008
    assert _m2(r, s) < chi2.ppf(0.999, 6)
    # a refit (a validation fold) holds the widened prior with the noise: on all views it is the full run
    from handeye.refine.refitting import refit

    again = refit(r, object_points=s.target.object_points(), views=s.refine_views(s.joints_encoder))
    # (the refit's is the plug-in covariance; the run's carries the estimated levels' degrees of freedom)
    assert r.cov_x_dof_factor > 1.0
    plug_in = r.cov_x_6x6 / r.cov_x_dof_factor
    np.testing.assert_allclose(np.sqrt(np.diag(again.cov_x)), np.sqrt(np.diag(plug_in)), rtol=0.02)

    cfg = noise._cfg()
    monkeypatch.setattr(noise, "_cfg", lambda: {**cfg, "dh_prior_alpha": 0.0})  # the stated prior, never tested
    _, held = _kinematic_session_refined(mode, 0, 5.0)
    assert held.robot_model["dh_prior_scale"] == 1.0
    assert held.robot_model["encoder_sigma_deg"] > 1.5 * rm["encoder_sigma_deg"]
    assert _m2(held, s) > chi2.ppf(0.999, 6)
    monkeypatch.undo()

    _, within = _kinematic_session_refined(mode, 0, 1.0)
    assert within.robot_model["dh_prior_scale"] == 1.0 and "dh_scale" not in within.robot_noise_dof
    assert within.robot_model["dh_prior_scale_dof"] is None
    assert not within.robot_model["dh_prior_test"]["contradicted"]


def test_the_dh_prior_test_holds_its_level_where_the_views_resolve_offsets_partly():
    """The statistic of the DH prior test is sum lambda_i z_i^2 with weights between 0 (an offset left to its
    prior) and 1 (one the views fix). Its reference (Satterthwaite's scaled chi-square) rejects at about the
    nominal rate for any such weights; plain chi2(sum lambda) would reject far less often than nominal."""
    from handeye.stats import weighted_chi2_sf

    rng = np.random.default_rng(11)
    for lam in (rng.uniform(0.0, 1.0, 24), np.full(24, 0.2), np.r_[np.ones(8), np.zeros(16)]):
        e = (rng.standard_normal((20000, lam.size)) ** 2 * lam).sum(axis=1)
        p = np.array([weighted_chi2_sf(x, lam)[0] for x in e])
        assert 0.007 < np.mean(p < 0.01) < 0.014 and 0.04 < np.mean(p < 0.05) < 0.06, lam
        if lam.max() < 1.0:
            assert np.mean(chi2.sf(e, lam.sum()) < 0.01) < 0.005  # the plain reference: too few rejections
