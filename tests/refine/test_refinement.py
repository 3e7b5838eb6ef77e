"""Joint refinement: noiseless recovery, noisy recovery within bounds tied to the noise (the
Cramer-Rao bound of the model at the truth), noise and robot-noise estimation, outlier decisions,
the robot-pose test shared with the diagnostics, covariance calibration, options and exceptions."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from handeye.camera import Intrinsics
from handeye.errors import ConfigError, InputError
from handeye.factors.reprojection import chain_residual
from handeye.frames import se3_exp, skew, tangent_difference
from handeye.mounting import mounting
from handeye.refine import RefineOptions, RefineView, refine, refit
from handeye.refine.options import Prior
from handeye.refine.outliers import RobotPoseGates, leave_one_out, robot_pose_test, view_variance_factor
from handeye.sim.corners import make_corner_session


def _views(s, image_points=None):
    pts = s.image_points if image_points is None else image_points
    return [
        RefineView(vid, ids, p, s.T_base_end_reported[k])
        for k, (vid, ids, p) in enumerate(zip(s.view_ids, s.corner_ids, pts, strict=False))
    ]


def _perturbed_seed(s, rng, *, rot_deg=1.0, trans_mm=5.0):
    """Truth moved by a random rotation/translation of the given size (board too), and intrinsics off by ~1 %."""

    def move(T):
        w = rng.normal(size=3)
        v = rng.normal(size=3)
        xi = np.r_[np.radians(rot_deg) * w / np.linalg.norm(w), 1e-3 * trans_mm * v / np.linalg.norm(v)]
        return T @ se3_exp(xi)

    k = s.intrinsics.as_vector() * np.r_[1.01, 0.99, 1.0, 1.0, [0.0] * 5] + np.r_[0, 0, 4.0, -3.0, [0.0] * 5]
    return move(s.T_x_true), move(s.T_board_true), Intrinsics.from_vector(k, s.intrinsics.width, s.intrinsics.height)


def _xi_err(T_est, T_true):
    return tangent_difference(T_est, T_true)


def _crb_x(s, sigma_px):
    """Cramer-Rao bound (6x6, the tangent of cov_x_6x6) of T_x at the truth with exact robot poses and
    the 9 intrinsics estimated jointly: inverse Fisher information from the analytic Jacobians."""
    obj, k = s.target.object_points(), s.intrinsics.as_vector()
    H = np.zeros((21, 21))
    for i in range(s.n_views):
        _, J_x, _, J_b, J_k = chain_residual(
            T_x=s.T_x_true,
            T_base_end=s.T_base_end_true[i],
            T_board=s.T_board_true,
            invert_robot=mounting(s.mode).inverts_robot,
            intrinsics_vec=k,
            object_points=obj[s.corner_ids[i]],
            image_points=np.zeros((len(s.corner_ids[i]), 2)),
        )
        J = np.hstack([J_x, J_b, J_k]) / sigma_px
        H += J.T @ J
    return np.linalg.inv(H)[:6, :6]


def _refine(s, T_x0, T_b0, intr, views=None, **opts):
    return refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=_views(s) if views is None else views,
        intrinsics=intr,
        T_x0=T_x0,
        T_board0=T_b0,
        options=RefineOptions(**opts),
    )


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noiseless_recovery_from_perturbed_seed(mode):
    s = make_corner_session(mode=mode, n_views=12, seed=3, noise_px=0.0)
    T_x0, T_b0, intr0 = _perturbed_seed(s, np.random.default_rng(0))
    r = _refine(s, T_x0, T_b0, intr0)
    assert r.status == "ok", r.failure_reason
    xi = _xi_err(r.T_x, s.T_x_true)
    assert np.abs(xi).max() < 1e-8, f"{mode}: T_x off by {xi} (rad, m) on noiseless data"
    assert np.abs(_xi_err(r.T_board, s.T_board_true)).max() < 1e-8
    np.testing.assert_allclose(
        r.intrinsics.as_vector(),
        s.intrinsics.as_vector(),
        rtol=1e-8,
        atol=1e-9,
        err_msg="intrinsics not recovered on noiseless data",
    )
    assert r.rms_px_after < 1e-6 < r.rms_px_before
    assert not r.outliers, f"outliers flagged on noiseless data: {r.outliers}"


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noisy_recovery_within_reported_uncertainty(mode):
    noise_px = 0.3
    s = make_corner_session(mode=mode, n_views=20, seed=11, noise_px=noise_px)
    T_x0, T_b0, intr0 = _perturbed_seed(s, np.random.default_rng(1), rot_deg=0.5, trans_mm=3.0)
    r = _refine(s, T_x0, T_b0, intr0)
    assert r.status == "ok", r.failure_reason
    xi = _xi_err(r.T_x, s.T_x_true)
    m2 = xi @ np.linalg.solve(r.cov_x_6x6, xi)
    assert m2 < chi2.ppf(0.999, 6), f"{mode}: error {xi} outside the 99.9 % ellipsoid (Mahalanobis^2 {m2:.1f})"
    # the reported uncertainty is the one the noise implies: each sigma against the Cramer-Rao bound of the
    # model at the truth. Never overconfident beyond the 2 % error of the estimated sigma_px; at most 30 % over,
    # which is what the robot noise held at its unresolved upper value (~0.01 mm / 0.001 deg) adds to the
    # translation here (rotation: 1 %). A covariance 2x too large or too small fails.
    ratio = np.sqrt(np.diag(r.cov_x_6x6) / np.diag(_crb_x(s, noise_px)))
    assert np.all(ratio > 0.95) and np.all(ratio < 1.3), f"{mode}: reported sigma / CRB {ratio.round(3)}"
    # sigma_px from ~3500 residual degrees of freedom: relative sd 1/sqrt(2 * 3500) = 1.2 %; 5 sd
    n_obs = 2 * sum(len(c) for c in s.corner_ids)
    tol = 5.0 / np.sqrt(2.0 * n_obs)
    assert abs(r.sigma_px / noise_px - 1.0) < tol, f"estimated pixel noise {r.sigma_px} vs {noise_px}"
    # RMS of the 2-D residual: sqrt(2) sigma times sqrt(redundancy / count) (21 core + 0 robot unknowns here)
    assert r.rms_px_after / (noise_px * np.sqrt(2.0 * (n_obs - 21) / n_obs)) == pytest.approx(1.0, abs=tol)
    # exact robot poses: any robot noise found must be far below the camera's resolution (0.02 mm / 0.005 deg,
    # a tenth of the CRB of T_x) or flagged unresolved
    for part, value, limit in (("trans", r.robot_sigma_mm, 0.02), ("rot", r.robot_sigma_deg, 0.005)):
        assert value < limit or not r.robot_sigma_resolved[part], f"robot {part} noise invented: {value}"
    assert not [o for o in r.outliers if o.kind != "corners"], f"views flagged on clean data: {r.outliers}"
    # the derived forms are those of cov_x_6x6: sigmas, correlation, error at the working distance
    cov, R = r.cov_x_6x6, r.T_x[:3, :3]
    np.testing.assert_allclose(r.sigma_rot_deg, np.degrees(np.sqrt(np.diag(cov)[:3])), rtol=1e-12)
    np.testing.assert_allclose(r.sigma_trans_mm, 1000 * np.sqrt(np.diag(R @ cov[3:, 3:] @ R.T)), rtol=1e-12)
    J = R @ np.hstack([-skew([0.0, 0.0, r.working_distance_m]), np.eye(3)])
    assert r.predicted_error_mm == pytest.approx(1000 * np.sqrt(np.trace(J @ cov @ J.T)), rel=1e-12)
    depth = np.median([(T[:3, :3] @ s.target.object_points().mean(axis=0) + T[:3, 3])[2] for T in s.T_cam_board_true])
    assert r.working_distance_m == pytest.approx(depth, rel=1e-3), "working distance is not the median board depth"


def test_robot_noise_is_estimated():
    s = make_corner_session(mode="eye_to_hand", n_views=30, seed=5, noise_px=0.2, robot_noise=(1.0, 0.2))
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics)
    assert r.status == "ok"
    assert r.robot_sigma_resolved == {"rot": True, "trans": True}
    # each robot sigma from ~3 x 30 redundant equations: relative sd ~1/sqrt(2 * 90) = 7.5 %; 4 sd
    assert r.robot_sigma_mm == pytest.approx(1.0, rel=0.3), f"robot translation sigma {r.robot_sigma_mm} mm vs 1.0"
    assert r.robot_sigma_deg == pytest.approx(0.2, rel=0.3), f"robot rotation sigma {r.robot_sigma_deg} deg vs 0.2"
    xi = _xi_err(r.T_x, s.T_x_true)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) < chi2.ppf(0.999, 6)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_wrong_robot_poses_are_flagged_and_do_not_pull_the_result(mode):
    s = make_corner_session(mode=mode, n_views=20, seed=7, noise_px=0.3, outlier_views=2)
    T_x0, T_b0, intr0 = _perturbed_seed(s, np.random.default_rng(2), rot_deg=2.0, trans_mm=10.0)
    r = _refine(s, T_x0, T_b0, intr0)
    assert r.status == "ok"
    flagged = {o.view_id for o in r.outliers if o.kind == "robot_pose"}
    assert flagged == set(s.outlier_view_ids), f"flagged {flagged}, wrong poses in {s.outlier_view_ids}"
    for o in r.outliers:
        if o.kind == "robot_pose":
            # the reported size is the simulated gross error, within 5 x the RMS size of the prediction's error
            k = s.view_ids.index(o.view_id)
            xi = tangent_difference(s.T_base_end_reported[k], s.T_base_end_true[k])
            assert abs(o.size["rot_deg"] - np.degrees(np.linalg.norm(xi[:3]))) < 5 * o.size["sigma_rot_deg"], o.size
            assert abs(o.size["trans_mm"] - 1000 * np.linalg.norm(xi[3:])) < 5 * o.size["sigma_trans_mm"], o.size
            assert o.size["p_value"] < RefineOptions().view_outlier_p
            assert r.per_view[o.view_id]["status"] == "robot_excluded"
    xi = _xi_err(r.T_x, s.T_x_true)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) < chi2.ppf(0.999, 6)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_robot_pose_of_another_view_is_a_robot_pose_outlier_not_an_undetermined_view(mode):
    """Two views' robot poses swapped: each view's own fit starts from a pose far off (most corners outside
    the robust gate there), restarts from its PnP pose and is judged as what it is, a wrong robot pose."""
    s = make_corner_session(mode=mode, n_views=20, seed=7, noise_px=0.3)
    T = s.T_base_end_reported.copy()
    T[[2, 8]] = T[[8, 2]]
    views = [
        RefineView(vid, i, p, T[k])
        for k, (vid, i, p) in enumerate(zip(s.view_ids, s.corner_ids, s.image_points, strict=False))
    ]
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, views=views)
    assert r.status == "ok"
    assert {(o.view_id, o.kind) for o in r.outliers} == {("3", "robot_pose"), ("9", "robot_pose")}
    xi = _xi_err(r.T_x, s.T_x_true)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) < chi2.ppf(0.999, 6)


def test_corner_outliers_bad_views_and_sparse_views_get_reasons():
    s = make_corner_session(mode="eye_in_hand", n_views=15, seed=4, noise_px=0.3)
    pts = [p.copy() for p in s.image_points]
    ids = [c.copy() for c in s.corner_ids]
    pts[2][[5, 40, 77]] += np.array([12.0, -9.0])  # three bad corners in view "3"
    pts[6] = pts[6][np.random.default_rng(0).permutation(len(pts[6]))]  # view "7": corners mis-ordered
    ids[9], pts[9] = ids[9][:5], pts[9][:5]  # view "10": only 5 corners
    ids[11], pts[11] = ids[11][:0], pts[11][:0]  # view "12": none (the board was not seen)
    views = [
        RefineView(vid, i, p, s.T_base_end_reported[k])
        for k, (vid, i, p) in enumerate(zip(s.view_ids, ids, pts, strict=False))
    ]
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, views=views)
    assert r.status == "ok"
    by_kind = {}
    for o in r.outliers:
        by_kind.setdefault(o.kind, []).append(o)
    assert [(o.view_id, o.corner_ids) for o in by_kind["corners"]] == [("3", (5, 40, 77))]
    assert [o.view_id for o in by_kind["reprojection"]] == ["7"]
    assert [o.view_id for o in by_kind["too_few_corners"]] == ["10", "12"]
    assert "robot_pose" not in by_kind
    assert r.per_view["7"]["status"] == "removed" and r.per_view["10"]["status"] == "removed"
    assert r.per_view["3"]["n_used"] == r.per_view["3"]["n_corners"] - 3
    xi = _xi_err(r.T_x, s.T_x_true)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) < chi2.ppf(0.999, 6)


def test_covariance_is_calibrated_small_monte_carlo():
    """30 noise draws on one 10-view geometry: the normalised errors d2 = xi^T C^-1 xi are chi-square(6)."""
    s = make_corner_session(mode="eye_to_hand", n_views=10, seed=2, noise_px=0.0)
    rng = np.random.default_rng(3)
    d2 = []
    for _ in range(30):
        pts = [p + rng.normal(0.0, 0.5, p.shape) for p in s.image_points]
        r = _refine(
            s,
            s.T_x_true,
            s.T_board_true,
            s.intrinsics,
            views=_views(s, pts),
            outlier_loop=False,
            loss="none",
            robot_noise="none",
        )
        xi = _xi_err(r.T_x, s.T_x_true)
        d2.append(xi @ np.linalg.solve(r.cov_x_6x6, xi))
    # the sum of 30 chi-square(6) draws is chi-square(180): two-sided 0.1 % band [126, 247]. A covariance 2x too
    # large halves the sum (~90), 2x too small doubles it (~360): both fail.
    total = float(np.sum(d2))
    assert chi2.ppf(0.0005, 180) < total < chi2.ppf(0.9995, 180), f"sum of d2 {total:.0f} (expected ~180)"


def test_intrinsics_options_fixed_subset_and_prior():
    s = make_corner_session(mode="eye_in_hand", n_views=10, seed=8, noise_px=0.3)
    _, _, intr0 = _perturbed_seed(s, np.random.default_rng(4))
    r = _refine(s, s.T_x_true, s.T_board_true, intr0, fix=("k3", "p1", "p2"), outlier_loop=False)
    v0, v = intr0.as_vector(), r.intrinsics.as_vector()
    assert v[6:].tolist() == v0[6:].tolist(), "fixed intrinsics moved"
    assert set(r.intrinsics_sigma) == {"fx", "fy", "cx", "cy", "k1", "k2"}
    r = _refine(s, s.T_x_true, s.T_board_true, intr0, intrinsics="fixed", outlier_loop=False)
    assert r.intrinsics.as_vector().tolist() == v0.tolist() and r.intrinsics_sigma == {}
    tight = tuple([1e-6] * 9)
    r = _refine(
        s, s.T_x_true, s.T_board_true, intr0, intrinsics="prior", intrinsics_prior_sigma=tight, outlier_loop=False
    )
    np.testing.assert_allclose(r.intrinsics.as_vector(), v0, atol=1e-4)
    for robot_noise in ("none", "fixed"):
        r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, robot_noise=robot_noise)
        assert r.status == "ok"
        # no level estimated: X's covariance is the plug-in one
        assert r.cov_x_dof_factor == 1.0 and r.cov_x_noise_dof is None
        if robot_noise == "fixed":
            assert (r.robot_sigma_mm, r.robot_sigma_deg) == (0.2, 0.05)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_prior_on_x_tight_pins_it_loose_changes_nothing(mode):
    s = make_corner_session(mode=mode, n_views=10, seed=12, noise_px=0.3)
    free = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics)
    assert free.status == "ok"
    # robot sigmas the views resolve are estimated from 10 views (15-30 degrees of freedom each): X's covariance is
    # widened to the 95 % point of 6 F(6, nu), nu at least the smallest level's (Satterthwaite over shares that
    # sum to <= 1); none resolved (this noise-free arm, eye-in-hand): the plug-in covariance
    if free.robot_noise_dof:
        from scipy.stats import f as f_dist

        assert min(free.robot_noise_dof.values()) <= free.cov_x_noise_dof
        expected = 6 * f_dist.ppf(0.95, 6, free.cov_x_noise_dof) / chi2.ppf(0.95, 6)
        assert free.cov_x_dof_factor == pytest.approx(expected, rel=1e-8) and free.cov_x_dof_factor > 1.0
    else:
        assert free.cov_x_dof_factor == 1.0 and free.cov_x_noise_dof is None
    assert (mode == "eye_to_hand") == bool(free.robot_noise_dof)  # both branches run
    d = free.to_dict()
    assert d["cov_x_dof_factor"] == free.cov_x_dof_factor and d["cov_x_noise_dof"] == free.cov_x_noise_dof
    # a tight prior 0.3 deg / 3 mm off the truth (about 10-100 sigma of the data): X sits on it, its
    # covariance is the prior's
    T_p = s.T_x_true @ se3_exp(np.r_[np.radians(0.3) * np.array([0.6, 0.0, 0.8]), 0.003, -0.001, 0.0])
    cov_tight = np.diag([1e-7**2] * 3 + [1e-7**2] * 3)
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=Prior(T_p, cov_tight))
    assert r.status == "ok", r.failure_reason
    assert np.abs(_xi_err(r.T_x, T_p)).max() < 1e-6, f"{mode}: tight prior did not pin X: {_xi_err(r.T_x, T_p)}"
    np.testing.assert_allclose(np.sqrt(np.diag(r.cov_x_6x6)), 1e-7, rtol=0.01)
    # a loose prior (1 rad, 1 m) at the same place: X moves by less than 1 % of its sigma
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=Prior(T_p, np.eye(6)))
    xi = _xi_err(r.T_x, free.T_x)
    assert np.all(np.abs(xi) < 0.01 * np.sqrt(np.diag(free.cov_x_6x6))), f"{mode}: loose prior moved X by {xi}"
    np.testing.assert_allclose(r.cov_x_6x6, free.cov_x_6x6, rtol=0.01, atol=1e-3 * np.abs(free.cov_x_6x6).max())
    # intrinsics prior: tight on fx, fy, cx, cy 5 px away, loose elsewhere
    k_p = s.intrinsics.as_vector() + np.r_[5.0, -5.0, 5.0, -5.0, [0.0] * 5]
    cov_k = np.diag(np.r_[[1e-4**2] * 4, [1.0] * 5])
    r = _refine(
        s,
        s.T_x_true,
        s.T_board_true,
        s.intrinsics,
        prior=Prior(s.T_x_true, np.eye(6), Intrinsics.from_vector(k_p, s.intrinsics.width, s.intrinsics.height), cov_k),
    )
    np.testing.assert_allclose(r.intrinsics.as_vector()[:4], k_p[:4], atol=1e-3)
    with pytest.raises(ConfigError, match="prior.cov_x"):
        _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=Prior(T_p, -np.eye(6)))
    with pytest.raises(ConfigError, match="prior.cov_intrinsics"):
        _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=Prior(T_p, np.eye(6), s.intrinsics, None))


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_joint_prior_on_x_and_the_intrinsics_keeps_their_correlation(mode):
    """An earlier calibration's X and intrinsics are correlated: as one joint Gaussian prior that dominates the
    data, the refinement sits on its means and reports its covariance, cross terms included; without the
    cross-covariance (zeros) it is the two separate priors."""
    from handeye.camera import INTRINSIC_NAMES

    s = make_corner_session(mode=mode, n_views=10, seed=12, noise_px=0.3)
    rng = np.random.default_rng(5)
    A = rng.normal(size=(15, 15))
    R = A @ A.T + 3 * np.eye(15)
    d = 1.0 / np.sqrt(np.diag(R))
    scale = np.r_[[1e-6] * 6, [1e-3] * 4, [1e-6] * 5]  # far tighter than 10 views tell (rad, m, px, -)
    J = (scale * d)[:, None] * R * (scale * d)[None, :]
    T_p = s.T_x_true @ se3_exp(np.r_[1e-4, -2e-4, 1e-4, 5e-4, 2e-4, -3e-4])
    k_p = s.intrinsics.as_vector() + np.r_[0.5, -0.5, 0.4, -0.3, [0.0] * 5]
    K_p = Intrinsics.from_vector(k_p, s.intrinsics.width, s.intrinsics.height)
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=Prior(T_p, J[:6, :6], K_p, J[6:, 6:], J[:6, 6:]))
    assert r.status == "ok", r.failure_reason
    assert np.abs(_xi_err(r.T_x, T_p)).max() < 1e-5
    names = r.cov_x_intrinsics["intrinsics"]
    idx = [INTRINSIC_NAMES.index(n) for n in names]
    assert {"fx", "fy", "cx", "cy"} <= set(names)
    np.testing.assert_allclose(r.intrinsics.as_vector()[idx], k_p[idx], atol=1e-2)
    cross = np.asarray(r.cov_x_intrinsics["cross_6xk"])
    np.testing.assert_allclose(cross, J[:6, 6:][:, idx], rtol=0.05, atol=0.02 * np.abs(cross).max())
    # zero cross-covariance: the same as the two separate priors
    a = _refine(
        s,
        s.T_x_true,
        s.T_board_true,
        s.intrinsics,
        prior=Prior(T_p, np.eye(6) * 1e-6, K_p, np.eye(9), np.zeros((6, 9))),
    )
    b = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=Prior(T_p, np.eye(6) * 1e-6, K_p, np.eye(9)))
    assert np.abs(_xi_err(a.T_x, b.T_x)).max() < 1e-9
    np.testing.assert_allclose(a.cov_x_6x6, b.cov_x_6x6, rtol=1e-6, atol=1e-15)
    with pytest.raises(ConfigError, match="prior.cov_x_intrinsics"):
        _refine(
            s,
            s.T_x_true,
            s.T_board_true,
            s.intrinsics,
            prior=Prior(T_p, J[:6, :6], K_p, J[6:, 6:], 10 * J[:6, 6:] + 1.0),
        )


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_joint_prior_on_the_board_and_the_intrinsics_keeps_their_correlation(mode):
    """An earlier calibration's board pose (a board that has not moved) and intrinsics as one joint Gaussian prior,
    X free: the refinement sits on the board's mean and reports the prior's covariance of the board and its
    cross-covariance with the intrinsics; both joint priors at once are refused."""
    from handeye.camera import INTRINSIC_NAMES

    s = make_corner_session(mode=mode, n_views=10, seed=12, noise_px=0.3)
    rng = np.random.default_rng(6)
    A = rng.normal(size=(15, 15))
    R = A @ A.T + 3 * np.eye(15)
    d = 1.0 / np.sqrt(np.diag(R))
    scale = np.r_[[1e-6] * 6, [1e-3] * 4, [1e-6] * 5]
    J = (scale * d)[:, None] * R * (scale * d)[None, :]
    T_bp = s.T_board_true @ se3_exp(np.r_[1e-4, -2e-4, 1e-4, 5e-4, 2e-4, -3e-4])
    k_p = s.intrinsics.as_vector() + np.r_[0.5, -0.5, 0.4, -0.3, [0.0] * 5]
    K_p = Intrinsics.from_vector(k_p, s.intrinsics.width, s.intrinsics.height)
    prior = Prior(
        s.T_x_true, np.eye(6), K_p, J[6:, 6:], T_board=T_bp, cov_board=J[:6, :6], cov_board_intrinsics=J[:6, 6:]
    )
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=prior)
    assert r.status == "ok", r.failure_reason
    assert np.abs(_xi_err(r.T_board, T_bp)).max() < 1e-5
    names = r.cov_x_intrinsics["intrinsics"]
    idx = [INTRINSIC_NAMES.index(n) for n in names]
    np.testing.assert_allclose(r.intrinsics.as_vector()[idx], k_p[idx], atol=1e-2)
    np.testing.assert_allclose(r.cov_board_6x6, J[:6, :6], rtol=0.05, atol=0.02 * np.abs(J[:6, :6]).max())
    cross = np.asarray(r.cov_x_intrinsics["cross_board_6xk"])
    np.testing.assert_allclose(cross, J[:6, 6:][:, idx], rtol=0.05, atol=0.02 * np.abs(cross).max())
    # the robot noise held: the solve and its covariance are the graph's alone (no noise estimation's core terms)
    g = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=prior, robot_noise="fixed", outlier_loop=False)
    assert g.status == "ok", g.failure_reason
    assert np.abs(_xi_err(g.T_board, T_bp)).max() < 1e-5
    np.testing.assert_allclose(g.intrinsics.as_vector()[idx], k_p[idx], atol=1e-2)
    np.testing.assert_allclose(
        np.asarray(g.cov_x_intrinsics["cross_board_6xk"]), J[:6, 6:][:, idx], rtol=0.05, atol=0.02 * np.abs(cross).max()
    )
    with pytest.raises(ConfigError, match="prior.cov_board_intrinsics"):
        _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, prior=replace(prior, cov_x_intrinsics=np.zeros((6, 9))))


def test_to_dict_is_json_ready_and_names_frames():
    s = make_corner_session(mode="eye_to_hand", n_views=8, seed=1, noise_px=0.3, outlier_views=1)
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics)
    d = json.loads(json.dumps(r.to_dict()))
    assert d["x_name"] == "T_base_cam" and np.asarray(d["T_base_cam"]).shape == (4, 4)
    assert np.asarray(d["T_end_board"]).shape == (4, 4)
    assert np.asarray(d["cov_x_6x6"]).shape == (6, 6) and "rotation first" in d["cov_parametrisation"]
    for key in (
        "sigma_rot_deg",
        "sigma_trans_mm",
        "predicted_error_mm",
        "working_distance_m",
        "sigma_px",
        "robot_sigma_mm",
        "robot_sigma_deg",
        "rms_px_before",
        "rms_px_after",
        "iterations",
    ):
        np.testing.assert_array_equal(d[key], getattr(r, key), err_msg=key)
    np.testing.assert_allclose(d["seed"]["T_base_cam"], s.T_x_true, atol=1e-12)  # the seed, re-orthonormalised
    assert set(d["per_view"]) == set(s.view_ids) and d["per_view"] == json.loads(json.dumps(r.per_view))
    assert d["outliers"][0]["view_id"] == s.outlier_view_ids[0] and d["outliers"][0]["kind"] == "robot_pose"


def test_invalid_options_and_inputs_raise_one_line_errors():
    s = make_corner_session(mode="eye_in_hand", n_views=5, seed=0, noise_px=0.3)
    obj = s.target.object_points()
    for bad in (
        dict(intrinsics="guess"),
        dict(robot_noise="maybe"),
        dict(loss="tukey"),
        dict(fix=("f",)),
        dict(robot_sigma_mm=-1.0),
        dict(intrinsics_prior_sigma=(1.0, 2.0)),
    ):
        with pytest.raises(ConfigError) as e:
            refine(
                mode="eye_in_hand",
                object_points=obj,
                views=_views(s),
                intrinsics=s.intrinsics,
                T_x0=s.T_x_true,
                T_board0=s.T_board_true,
                options=RefineOptions(**bad),
            )
        assert "\n" not in str(e.value) and list(bad)[0] in str(e.value)
    with pytest.raises(ConfigError):
        refine(
            mode="hand_in_eye",
            object_points=obj,
            views=_views(s),
            intrinsics=s.intrinsics,
            T_x0=s.T_x_true,
            T_board0=s.T_board_true,
        )
    T_bad = s.T_x_true.copy()
    T_bad[:3, :3] *= 2.0
    with pytest.raises(InputError, match="not a rigid"):
        refine(
            mode="eye_in_hand",
            object_points=obj,
            views=_views(s),
            intrinsics=s.intrinsics,
            T_x0=T_bad,
            T_board0=s.T_board_true,
        )
    v = _views(s)
    with pytest.raises(InputError, match="duplicate view id"):
        refine(
            mode="eye_in_hand",
            object_points=obj,
            views=v + v[:1],
            intrinsics=s.intrinsics,
            T_x0=s.T_x_true,
            T_board0=s.T_board_true,
        )
    with pytest.raises(InputError, match="at least 3 views"):
        refine(
            mode="eye_in_hand",
            object_points=obj,
            views=v[:2],
            intrinsics=s.intrinsics,
            T_x0=s.T_x_true,
            T_board0=s.T_board_true,
        )


# ------------------------------------------------------------------------------ the robot-pose test
def test_robot_pose_test_is_chi_square_for_correct_poses_and_flags_by_size():
    """Correct poses: d ~ N(0, C + R), the statistic chi-square(6), p-values uniform; flags need both
    p < alpha and a large disagreement."""
    rng = np.random.default_rng(0)
    n = 4000
    A = rng.normal(size=(n, 6, 6)) * np.r_[[1e-3] * 3, [1e-4] * 3][None, :, None]
    C = A @ np.swapaxes(A, 1, 2)  # per-view prediction covariances, shape (n, 6, 6)
    s_rot, s_trans = 2e-3, 3e-4
    R = np.diag([s_rot**2] * 3 + [s_trans**2] * 3)
    d = np.stack([rng.multivariate_normal(np.zeros(6), c + R) for c in C])
    gates = RobotPoseGates(alpha=0.01, min_rot_deg=0.0, min_trans_mm=0.0)
    t = robot_pose_test(d, C, robot_sigma_rot_rad=s_rot, robot_sigma_trans_m=s_trans, gates=gates)
    # mean of n chi-square(6): 6 +- 4 sd of sqrt(12 / n); flagged share 1 % +- 4 binomial sd
    assert abs(t.statistic.mean() - 6.0) < 4 * np.sqrt(12.0 / n)
    assert abs(t.flagged.mean() - 0.01) < 4 * np.sqrt(0.01 * 0.99 / n)
    np.testing.assert_allclose(t.p_value, chi2.sf(t.statistic, 6), rtol=1e-9)
    k = 7
    assert t.statistic[k] == pytest.approx(d[k] @ np.linalg.solve(C[k] + R, d[k]), rel=1e-10)
    assert t.rot_deg[k] == pytest.approx(np.degrees(np.linalg.norm(d[k, :3])))
    # the size floors: a 40-sigma disagreement of 0.05 deg / 0.05 mm is not flagged above 0.1 deg / 0.5 mm floors
    big = np.r_[np.radians(0.05) / np.sqrt(3) * np.ones(3), 5e-5 / np.sqrt(3) * np.ones(3)]
    tiny = np.diag([1e-12] * 6)[None]
    floors = RobotPoseGates(alpha=1e-4, min_rot_deg=0.1, min_trans_mm=0.5)
    t = robot_pose_test(big[None], tiny, robot_sigma_rot_rad=1e-5, robot_sigma_trans_m=1e-6, gates=floors)
    assert t.p_value[0] < 1e-10 and not t.flagged[0]
    t = robot_pose_test(
        2 * np.r_[big[:3] * 2.5, big[3:] * 6][None],
        tiny,
        robot_sigma_rot_rad=1e-5,
        robot_sigma_trans_m=1e-6,
        gates=floors,
    )
    assert t.flagged[0] and t.rot_deg[0] > 0.1
    # rows without a prediction are not tested
    t = robot_pose_test(np.full((1, 6), np.nan), tiny, robot_sigma_rot_rad=1e-3, robot_sigma_trans_m=1e-3, gates=floors)
    assert np.isnan(t.statistic[0]) and not t.flagged[0]


def test_robot_pose_test_null_is_heavier_tailed_for_an_unmodelled_arm():
    """An arm whose kinematic error is not modelled: the null is a multivariate t (configs/refine.yaml
    iid_tail_dof, variance matched), so a view 6.3 sigma off is within its tail while a gross one is not;
    with a kinematic model (or a tracker) the null stays chi-square(6) and the same view is flagged."""
    from scipy.stats import f

    rng = np.random.default_rng(5)
    n = 24
    C = np.broadcast_to(np.eye(6) * 1e-12, (n, 6, 6))
    d = rng.normal(size=(n, 6))
    d[0] = np.full(6, np.sqrt(40.0 / 6.0))  # statistic 40: beyond chi-square(6)'s 27.9 at p = 1e-4
    d[1] = np.full(6, 30.0 / np.sqrt(6.0))  # 30 sigma
    unmodelled = RobotPoseGates.from_config()
    nu = unmodelled.tail_dof
    assert np.isfinite(nu) and RobotPoseGates.from_config(unmodelled_arm=False).tail_dof == np.inf
    t = robot_pose_test(d, C, robot_sigma_rot_rad=1.0, robot_sigma_trans_m=1.0, gates=unmodelled)
    # statistic * (nu / (nu - 2)) / 6 ~ F(6, nu)
    np.testing.assert_allclose(t.p_value, f.sf(t.statistic * nu / (nu - 2) / 6, 6, nu), rtol=1e-9)
    assert t.threshold > chi2.isf(1e-4, 6)
    assert f.sf(t.threshold * nu / (nu - 2) / 6, 6, nu) == pytest.approx(1e-4, rel=1e-6)
    assert not t.flagged[0] and t.flagged[1]
    t = robot_pose_test(
        d, C, robot_sigma_rot_rad=1.0, robot_sigma_trans_m=1.0, gates=RobotPoseGates.from_config(unmodelled_arm=False)
    )
    assert t.flagged[0] and t.flagged[1]
    assert t.threshold == pytest.approx(chi2.isf(1e-4, 6))


def test_leave_one_out_prediction_matches_the_solve_without_the_prior():
    """A linear Gaussian robot pose: camera prediction p_loo (covariance S_loo) and reported r (covariance R).
    The solve with the prior gives P and S_p; leave_one_out recovers p_loo - r and S_loo exactly."""
    rng = np.random.default_rng(1)
    B = rng.normal(size=(6, 6)) * 1e-3
    S_loo = B @ B.T + 1e-8 * np.eye(6)
    R = np.diag(rng.uniform(1e-7, 1e-5, 6))
    d_true = rng.normal(size=6) * 1e-3  # p_loo - r
    S_p = np.linalg.inv(np.linalg.inv(S_loo) + np.linalg.inv(R))
    e = S_p @ np.linalg.solve(S_loo, d_true)  # P - r, with P = S_p (S_loo^-1 p_loo + R^-1 r)
    d, C = leave_one_out(e, R, S_p)
    np.testing.assert_allclose(d, d_true, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(C, S_loo, rtol=1e-5, atol=1e-14)
    assert d @ np.linalg.solve(C + R, d) == pytest.approx(e @ np.linalg.solve(R - S_p, e), rel=1e-6)
    with pytest.raises(np.linalg.LinAlgError):
        leave_one_out(e, R, S_p + 2 * R)  # a solve that weighed the prior more than R says


def test_starts_choose_the_closed_form_the_views_agree_with():
    """A start 30 deg off is replaced by the candidate that explains the views; without candidates it is kept."""
    from handeye.records import HandEyeEstimate

    s = make_corner_session(mode="eye_in_hand", n_views=12, seed=9, noise_px=0.3)
    bad_x = s.T_x_true @ se3_exp(np.r_[np.radians(30.0), 0.0, 0.0, 0.05, 0.0, 0.0])
    good = HandEyeEstimate(
        mode=s.mode, method="park", T_x=s.T_x_true @ se3_exp(np.r_[1e-3, 0, 0, 1e-3, 0, 0]), T_board=s.T_board_true
    )
    failed = HandEyeEstimate(
        mode=s.mode, method="li", T_x=np.full((4, 4), np.nan), T_board=np.eye(4), status="failed", failure_reason="test"
    )
    r = refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=_views(s),
        intrinsics=s.intrinsics,
        T_x0=bad_x,
        T_board0=s.T_board_true,
        starts={"li": failed, "park": good},
    )
    assert r.status == "ok" and r.start_method == "park"
    xi = _xi_err(r.T_x, s.T_x_true)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) < chi2.ppf(0.999, 6)
    r = refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=_views(s),
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true,
        T_board0=s.T_board_true,
        starts={"park": good},
    )
    assert r.start_method == "given"


def test_aitken_step_lands_on_the_fixed_point_of_a_linear_iteration():
    """The noise estimation's extrapolation: for x_{k+1} = a + rho (x_k - a) (log-sigmas) it returns exp(a)
    exactly, per component; a component that oscillates or has stopped is left at its last iterate."""
    from handeye.refine.noise import _aitken

    a, rho = np.log([0.3, 1e-4, 2e-5]), np.array([0.93, 0.5, -0.4])
    x0 = np.log([1.0, 1e-3, 1e-4])
    x1 = a + rho * (x0 - a)
    x2 = a + rho * (x1 - a)
    out = np.log(_aitken(x0, x1, x2))
    np.testing.assert_allclose(out[:2], a[:2], rtol=1e-12)
    assert out[2] == x2[2], "an oscillating component must not be extrapolated"
    np.testing.assert_array_equal(_aitken(x0, x0, x0), np.exp(x0))


def test_view_variance_factor_is_the_views_own_corner_variance_never_below_one():
    rng = np.random.default_rng(5)
    sigma = 0.1
    # 2-D Gaussian corners of sd 3 sigma per axis: |e|^2 sums to 2 N (3 sigma)^2, over 2 N - 6 dof
    e = np.linalg.norm(rng.normal(scale=3 * sigma, size=(4000, 2)), axis=1)
    f = view_variance_factor(e, sigma_px=sigma)
    assert f == pytest.approx(9.0 * 8000 / 7994, rel=0.05)  # relative sd of the estimate: sqrt(2 / 8000)
    assert view_variance_factor(0.5 * e, sigma_px=sigma) == pytest.approx(2.25 * 8000 / 7994, rel=0.05)
    assert view_variance_factor(0.1 * e, sigma_px=sigma) == 1.0  # quieter than the run: held to the run's level
    assert view_variance_factor(e[:3], sigma_px=sigma) == 1.0  # no redundancy (6 equations, 6 unknowns)


def test_refit_on_all_views_stays_and_on_a_subset_moves_within_its_sigma():
    s = make_corner_session(mode="eye_to_hand", n_views=14, seed=9, noise_px=0.3, outlier_views=1)
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics)
    assert r.status == "ok"
    obj = s.target.object_points()
    used = [v for v in _views(s) if r.per_view[v.view_id]["status"] != "removed"]
    # all views, decisions held: the full solution is the optimum, so the one solve stays there
    # (within a small fraction of the reported sigma; the solver's tolerance is relative 1e-6 of the cost)
    full = refit(r, object_points=obj, views=used)
    assert full.status == "ok" and full.view_ids == tuple(v.view_id for v in used)
    xi = tangent_difference(r.T_x, full.T_x)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) < 1e-3
    # one view left out: the estimate moves by about one view's share of the information, well within
    # 3 sigma of the full result (chi-square(6) 0.999 quantile)
    fold = refit(r, object_points=obj, views=used[1:])
    xi = tangent_difference(r.T_x, fold.T_x)
    assert 0 < xi @ np.linalg.solve(r.cov_x_6x6, xi) < chi2.ppf(0.999, 6)
    assert fold.intrinsics.fx != r.intrinsics.fx  # the intrinsics are re-estimated too
    with pytest.raises(InputError, match="cannot be refitted"):
        refit(r, object_points=obj, views=[RefineView("99", np.arange(4), np.zeros((4, 2)), np.eye(4))] + used)
