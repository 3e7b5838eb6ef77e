"""Joint refinement: noiseless recovery, noisy recovery within bounds tied to the noise, noise and
robot-noise estimation, outlier decisions, covariance coverage, options and exceptions."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import chi2

from handeye.errors import ConfigError, InputError
from handeye.frames import se3_exp, tangent_difference
from handeye.refine import RefineOptions, RefineView, refine
from handeye.sim.corners import make_corner_session
from handeye.camera import Intrinsics


def _views(s, image_points=None):
    pts = s.image_points if image_points is None else image_points
    return [RefineView(vid, ids, p, s.T_base_end_reported[k])
            for k, (vid, ids, p) in enumerate(zip(s.view_ids, s.corner_ids, pts))]


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


def _refine(s, T_x0, T_b0, intr, views=None, **opts):
    return refine(mode=s.mode, object_points=s.target.object_points(), views=_views(s) if views is None else views,
                  intrinsics=intr, T_x0=T_x0, T_board0=T_b0, options=RefineOptions(**opts))


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noiseless_recovery_from_perturbed_seed(mode):
    s = make_corner_session(mode=mode, n_views=12, seed=3, noise_px=0.0)
    T_x0, T_b0, intr0 = _perturbed_seed(s, np.random.default_rng(0))
    r = _refine(s, T_x0, T_b0, intr0)
    assert r.status == "ok", r.failure_reason
    xi = _xi_err(r.T_x, s.T_x_true)
    assert np.abs(xi).max() < 1e-8, f"{mode}: T_x off by {xi} (rad, m) on noiseless data"
    assert np.abs(_xi_err(r.T_board, s.T_board_true)).max() < 1e-8
    np.testing.assert_allclose(r.intrinsics.as_vector(), s.intrinsics.as_vector(), rtol=1e-8, atol=1e-9,
                               err_msg="intrinsics not recovered on noiseless data")
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
    # the reported uncertainty is of the size the noise implies: well under a millimetre / 0.2 deg here
    assert np.all(r.sigma_trans_mm < 1.0) and np.all(r.sigma_rot_deg < 0.2)
    assert abs(r.sigma_px / noise_px - 1.0) < 0.1, f"estimated pixel noise {r.sigma_px} vs {noise_px}"
    assert r.robot_sigma_mm < 0.05 and r.robot_sigma_deg < 0.01, "robot noise invented on exact robot poses"
    assert r.rms_px_after == pytest.approx(noise_px * np.sqrt(2), rel=0.1)
    assert not [o for o in r.outliers if o.kind != "corners"], f"views flagged on clean data: {r.outliers}"
    assert r.predicted_error_mm > 0 and np.isfinite(r.predicted_error_mm)
    np.testing.assert_allclose(np.diag(r.correlation_6x6), 1.0)


def test_robot_noise_is_estimated():
    s = make_corner_session(mode="eye_to_hand", n_views=30, seed=5, noise_px=0.2, robot_noise=(1.0, 0.2))
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics)
    assert r.status == "ok"
    assert r.robot_sigma_resolved == {"rot": True, "trans": True}
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
            assert o.size["trans_mm"] > 1.0 or o.size["rot_deg"] > 0.5
            assert "disagrees with the camera" in o.reason and o.view_id in o.reason
            assert r.per_view[o.view_id]["status"] == "robot_excluded"
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
    views = [RefineView(vid, i, p, s.T_base_end_reported[k]) for k, (vid, i, p) in enumerate(zip(s.view_ids, ids, pts))]
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


def test_covariance_coverage_small_monte_carlo():
    """30 noise draws on one 10-view geometry: the truth lies in the reported 95 % ellipsoid about as often."""
    s = make_corner_session(mode="eye_to_hand", n_views=10, seed=2, noise_px=0.0)
    rng = np.random.default_rng(3)
    inside = []
    for _ in range(30):
        pts = [p + rng.normal(0.0, 0.5, p.shape) for p in s.image_points]
        r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, views=_views(s, pts), outlier_loop=False,
                    loss="none", robot_noise="none")
        xi = _xi_err(r.T_x, s.T_x_true)
        inside.append(xi @ np.linalg.solve(r.cov_x_6x6, xi) <= chi2.ppf(0.95, 6))
    # binomial(30, 0.95): 24 or more inside with probability > 99.9 %; the reported sigma is estimated
    assert sum(inside) >= 24, f"only {sum(inside)}/30 inside the 95 % ellipsoid"


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
    r = _refine(s, s.T_x_true, s.T_board_true, intr0, intrinsics="prior", intrinsics_prior_sigma=tight,
                outlier_loop=False)
    np.testing.assert_allclose(r.intrinsics.as_vector(), v0, atol=1e-4)
    for robot_noise in ("none", "fixed"):
        r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics, robot_noise=robot_noise)
        assert r.status == "ok"
        if robot_noise == "fixed":
            assert (r.robot_sigma_mm, r.robot_sigma_deg) == (0.2, 0.05)


def test_to_dict_is_json_ready_and_names_frames():
    s = make_corner_session(mode="eye_to_hand", n_views=8, seed=1, noise_px=0.3, outlier_views=1)
    r = _refine(s, s.T_x_true, s.T_board_true, s.intrinsics)
    d = json.loads(json.dumps(r.to_dict()))
    assert d["x_name"] == "T_base_cam" and np.asarray(d["T_base_cam"]).shape == (4, 4)
    assert np.asarray(d["T_end_board"]).shape == (4, 4)
    assert np.asarray(d["cov_x_6x6"]).shape == (6, 6) and "rotation first" in d["cov_parametrisation"]
    for key in ("sigma_rot_deg", "sigma_trans_mm", "predicted_error_mm", "working_distance_m", "sigma_px",
                "robot_sigma_mm", "robot_sigma_deg", "rms_px_before", "rms_px_after", "per_view", "outliers",
                "iterations", "seconds", "seed"):
        assert key in d, key
    assert d["outliers"][0]["view_id"] == s.outlier_view_ids[0] and d["outliers"][0]["kind"] == "robot_pose"


def test_invalid_options_and_inputs_raise_one_line_errors():
    s = make_corner_session(mode="eye_in_hand", n_views=5, seed=0, noise_px=0.3)
    obj = s.target.object_points()
    for bad in (dict(intrinsics="guess"), dict(robot_noise="maybe"), dict(loss="tukey"), dict(fix=("f",)),
                dict(robot_sigma_mm=-1.0), dict(intrinsics_prior_sigma=(1.0, 2.0))):
        with pytest.raises(ConfigError) as e:
            refine(mode="eye_in_hand", object_points=obj, views=_views(s), intrinsics=s.intrinsics,
                   T_x0=s.T_x_true, T_board0=s.T_board_true, options=RefineOptions(**bad))
        assert "\n" not in str(e.value) and list(bad)[0] in str(e.value)
    with pytest.raises(ConfigError):
        refine(mode="hand_in_eye", object_points=obj, views=_views(s), intrinsics=s.intrinsics,
               T_x0=s.T_x_true, T_board0=s.T_board_true)
    T_bad = s.T_x_true.copy()
    T_bad[:3, :3] *= 2.0
    with pytest.raises(InputError, match="not a rigid"):
        refine(mode="eye_in_hand", object_points=obj, views=_views(s), intrinsics=s.intrinsics,
               T_x0=T_bad, T_board0=s.T_board_true)
    v = _views(s)
    with pytest.raises(InputError, match="duplicate view id"):
        refine(mode="eye_in_hand", object_points=obj, views=v + v[:1], intrinsics=s.intrinsics,
               T_x0=s.T_x_true, T_board0=s.T_board_true)
    with pytest.raises(InputError, match="at least 3 views"):
        refine(mode="eye_in_hand", object_points=obj, views=v[:2], intrinsics=s.intrinsics,
               T_x0=s.T_x_true, T_board0=s.T_board_true)
