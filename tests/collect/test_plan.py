"""Pose planner: Fisher information against Monte Carlo, orbit geometry, coverage of the greedy plan."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from handeye.camera import pixels_from_board_points
from handeye.collect import plan as P
from handeye.collect.visibility import board_center, board_in_image
from handeye.errors import ConfigError
from handeye.frames import inv_T, rotation_angle_rad, se3_exp
from handeye.mounting import mounting
from handeye.sim import scenarios

INTR = scenarios.default_intrinsics(640, 360)
TARGET = scenarios.DEFAULT_TARGET


def _rig(mode, seed):
    rng = np.random.default_rng(seed)
    setup = scenarios.sample_setup(mode=mode, rng=rng, target=TARGET)
    T0 = scenarios.sample_view_poses(
        mode=mode,
        n_views=1,
        rng=rng,
        T_x=setup["T_x"],
        T_board=setup["T_board"],
        target=TARGET,
        intrinsics=INTR,
        tilt_deg=(0.0, 8.0),
        roll_deg=10.0,
    )[0]
    return setup["T_x"], setup["T_board"], T0


def test_orbit_keeps_the_board_centre_on_the_optical_ray():
    T_x, T_b, T0 = _rig("eye_in_hand", 0)
    C0 = mounting("eye_in_hand").predict_T_cam_board(T_x, T_b, T0)
    c = board_center(TARGET)
    C = P.orbit_T_cam_board(C0, center_board=c, rotvec_cam=np.radians([30, -20, 10]), distance_scale=0.8)
    p0, p = C0[:3, :3] @ c + C0[:3, 3], C[:3, :3] @ c + C[:3, 3]
    np.testing.assert_allclose(p / np.linalg.norm(p), p0 / np.linalg.norm(p0), atol=1e-12)
    assert np.linalg.norm(p) == pytest.approx(0.8 * np.linalg.norm(p0), rel=1e-12)
    ang = np.degrees(rotation_angle_rad(C0[:3, :3].T @ C[:3, :3]))
    assert ang == pytest.approx(np.degrees(np.linalg.norm(np.radians([30, -20, 10]))), rel=1e-9)


def _fit_errors(mode, T_x, T_b, Ts, *, noise_px, robot_mm, robot_deg, trials, seed, whiten):
    """Monte Carlo: errors (trials, 6) of T_x fitted to noisy corners (GLS when ``whiten``)."""
    mount = mounting(mode)
    obj = TARGET.object_points()

    def proj(X, B, E):
        return pixels_from_board_points(mount.predict_T_cam_board(X, B, E), obj, INTR)

    Ls = []
    for E in Ts:  # per-view whitening from the pixel and robot-pose noise
        J = []
        for k in range(6):
            xi = np.zeros(6)
            xi[k] = 1e-6
            up = proj(T_x, T_b, E @ se3_exp(xi))
            dn = proj(T_x, T_b, E @ se3_exp(-xi))
            J.append(((up - dn) / 2e-6).ravel())
        Jm = np.array(J).T
        S = np.diag([np.radians(robot_deg) ** 2] * 3 + [(robot_mm * 1e-3) ** 2] * 3)
        cov = noise_px**2 * np.eye(Jm.shape[0]) + Jm @ S @ Jm.T
        Ls.append(np.linalg.cholesky(np.linalg.inv(cov)).T if whiten else np.eye(Jm.shape[0]))
    rng = np.random.default_rng(seed)
    clean = [proj(T_x, T_b, E) for E in Ts]
    out = []
    for _ in range(trials):
        reported = [scenarios.perturb_T_base_end(E, rng=rng, sigma_mm=robot_mm, sigma_deg=robot_deg)[0] for E in Ts]
        obs = [o + rng.normal(0.0, noise_px, o.shape) for o in clean]

        def res(th, reported=reported, obs=obs):
            X = T_x @ se3_exp(th[:6])
            B = T_b @ se3_exp(th[6:])
            return np.concatenate([L @ (proj(X, B, E) - o).ravel() for L, E, o in zip(Ls, reported, obs, strict=False)])

        out.append(least_squares(res, np.zeros(12), method="lm", x_scale=1e-3).x[:6])
    return np.array(out)


@pytest.mark.parametrize("mode, robot", [("eye_in_hand", (0.0, 0.0)), ("eye_to_hand", (0.2, 0.05))])
def test_predicted_sigma_matches_monte_carlo(mode, robot):
    """The prediction is the Cramer-Rao bound: an estimator weighting pixel and robot noise attains it."""
    T_x, T_b, T0 = _rig(mode, 1)
    C0 = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    cfg = P.PlanConfig(pixel_noise_px=0.5, robot_noise_mm=robot[0], robot_noise_deg=robot[1])
    plan = P.make_plan(
        mode=mode,
        T_x=T_x,
        T_board=T_b,
        T_base_end_start=T0,
        T_cam_board_start=C0,
        T_base_end_done=[T0],
        target=TARGET,
        intrinsics=INTR,
        n_views=4,
        config=cfg,
    )
    Ts = [T0] + [pv.candidate.T_base_end for pv in plan.views]
    err = _fit_errors(
        mode, T_x, T_b, Ts, noise_px=0.5, robot_mm=robot[0], robot_deg=robot[1], trials=20, seed=7, whiten=True
    )
    rot_deg = np.degrees(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))))
    trans_mm = 1e3 * np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))
    pv = plan.views[-1]
    print(
        f"predicted {pv.sigma_rot_deg:.4f} deg {pv.sigma_trans_mm:.3f} mm, "
        f"Monte Carlo {rot_deg:.4f} deg {trans_mm:.3f} mm"
    )
    # 20 trials: the root-mean-square of a 3-d error scatters by ~10 % around its expectation
    assert rot_deg == pytest.approx(pv.sigma_rot_deg, rel=0.35)
    assert trans_mm == pytest.approx(pv.sigma_trans_mm, rel=0.35)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_greedy_plan_rotates_about_all_three_axes_and_shrinks_sigma(mode):
    T_x, T_b, T0 = _rig(mode, 3)
    C0 = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    steps = []
    plan = P.make_plan(
        mode=mode,
        T_x=T_x,
        T_board=T_b,
        T_base_end_start=T0,
        T_cam_board_start=C0,
        T_base_end_done=[T0],
        target=TARGET,
        intrinsics=INTR,
        n_views=6,
        on_step=steps.append,
    )
    assert plan.status == "ok", plan.failure_reason
    assert len(plan.views) == 6 and [s.index for s in steps] == list(range(1, 7))
    assert np.all(plan.axis_rotation_deg >= 30.0)
    sig = [pv.sigma_trans_mm for pv in plan.views]
    assert all(b <= a + 1e-9 for a, b in zip(sig, sig[1:], strict=False))
    for pv in plan.views:  # every planned view shows the whole board, through the model
        C = mounting(mode).predict_T_cam_board(T_x, T_b, pv.candidate.T_base_end)
        np.testing.assert_allclose(C, pv.candidate.T_cam_board, atol=1e-9)
        assert board_in_image(TARGET, INTR, C)
        assert np.linalg.norm(pv.candidate.T_base_end[:3, 3] - T0[:3, 3]) <= P.PlanConfig().max_travel_m


def test_greedy_beats_random_choice():
    mode = "eye_in_hand"
    T_x, T_b, T0 = _rig(mode, 4)
    C0 = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    cands = P.candidate_views(
        mode=mode, T_x=T_x, T_board=T_b, T_base_end_start=T0, T_cam_board_start=C0, target=TARGET, intrinsics=INTR
    )
    info0 = P.information_of_views(mode=mode, T_x=T_x, T_board=T_b, T_base_end=[T0], target=TARGET, intrinsics=INTR)
    plan = P.greedy_plan(cands, n_views=5, info_start=info0)
    rng = np.random.default_rng(0)
    random_sigma = []
    for _ in range(20):
        pick = rng.choice(len(cands), 5, replace=False)
        random_sigma.append(P.predicted_sigma(info0 + sum(cands[i].info for i in pick))[1])
    assert plan.views[-1].sigma_trans_mm < np.median(random_sigma)


def test_plan_needs_views():
    with pytest.raises(ConfigError):
        P.greedy_plan([], n_views=0, info_start=np.zeros((12, 12)))


def test_information_is_symmetric_and_rank_limited_for_one_view():
    T_x, T_b, T0 = _rig("eye_to_hand", 2)
    info = P.information_of_views(
        mode="eye_to_hand", T_x=T_x, T_board=T_b, T_base_end=[T0], target=TARGET, intrinsics=INTR
    )
    np.testing.assert_allclose(info, info.T, rtol=1e-6, atol=1e-6 * np.abs(info).max())
    ev = np.linalg.eigvalsh(info)
    assert np.sum(ev > 1e-6 * ev.max()) == 6  # one view fixes T_cam_board only: 6 of 12 directions


def test_probe_poses_are_small_rotations_about_end_axes():
    T0 = scenarios.perturb_T_base_end(np.eye(4), rng=np.random.default_rng(0), sigma_mm=100, sigma_deg=30)[0]
    for k, pair in enumerate(P.probe_poses(T0, probe_deg=6.0)):
        for angle, T in zip((6.0, -6.0, 3.0, -3.0), pair, strict=False):
            np.testing.assert_allclose((inv_T(T0) @ T)[:3, 3], 0.0, atol=1e-12)
            rv_deg = P.end_rotvec_deg(T0, T)
            assert np.argmax(np.abs(rv_deg)) == k and rv_deg[k] == pytest.approx(angle)


def test_plan_defaults_come_from_the_collect_preset():
    from handeye.config import load_preset

    preset = load_preset("collect")["plan"]
    cfg = P.PlanConfig()
    assert (cfg.pixel_noise_px, cfg.robot_noise_mm, cfg.robot_noise_deg) == (
        preset["pixel_noise_px"],
        preset["robot_noise_mm"],
        preset["robot_noise_deg"],
    )
    assert cfg.tilt_deg == tuple(preset["tilt_deg"]) and cfg.max_travel_m == preset["max_travel_m"]
    preset["max_travel_m"] = 0.25
    assert P.PlanConfig.from_config({"plan": preset}).max_travel_m == 0.25


def _cv2_outline_inside(target, intr, T_cam_board, margin_px):
    """Oracle for board_in_image: the outline through cv2.projectPoints, in the image with the margin."""
    import cv2
    from scipy.spatial.transform import Rotation

    from handeye.collect.visibility import _outline_points

    pts = _outline_points(target)
    if np.any((pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3])[:, 2] <= 0.05):
        return False
    uv, _ = cv2.projectPoints(
        pts, Rotation.from_matrix(T_cam_board[:3, :3]).as_rotvec(), T_cam_board[:3, 3].copy(), intr.K, intr.dist_array
    )
    u, v = uv.reshape(-1, 2).T
    return bool(
        np.all(
            (u >= margin_px - 0.5)
            & (u <= intr.width - 0.5 - margin_px)
            & (v >= margin_px - 0.5)
            & (v <= intr.height - 0.5 - margin_px)
        )
    )


def test_board_in_image_agrees_with_cv2_on_views_near_the_border():
    T_x, T_b, T0 = _rig("eye_in_hand", 5)
    C0 = mounting("eye_in_hand").predict_T_cam_board(T_x, T_b, T0)
    rng = np.random.default_rng(3)
    verdicts = []
    for _ in range(300):  # orbits of up to 45 deg and shifts of the board: about half leave the image
        C = P.orbit_T_cam_board(
            C0,
            center_board=board_center(TARGET),
            rotvec_cam=np.radians(rng.uniform(-45, 45, 3)),
            distance_scale=rng.uniform(0.5, 1.2),
        )
        C[:3, 3] += rng.uniform(-0.08, 0.08, 3) * [1, 1, 0]
        got = board_in_image(TARGET, INTR, C, margin_px=8.0)
        assert got == _cv2_outline_inside(TARGET, INTR, C, 8.0)
        verdicts.append(got)
    assert 0.2 < np.mean(verdicts) < 0.8  # both answers were exercised


def test_circle_grid_pattern_bounds_hold_every_dot_with_a_spacing_to_spare():
    from handeye.collect.visibility import pattern_bounds
    from handeye.targets import CircleGridSpec

    for grid in (CircleGridSpec(4, 11, 0.02, asymmetric=True), CircleGridSpec(7, 5, 0.03)):
        x0, x1, y0, y1 = pattern_bounds(grid)
        p = grid.object_points()
        assert np.isclose(p[:, 0].min() - x0, grid.spacing_m) and np.isclose(x1 - p[:, 0].max(), grid.spacing_m)
        assert np.isclose(p[:, 1].min() - y0, grid.spacing_m) and np.isclose(y1 - p[:, 1].max(), grid.spacing_m)


def test_view_information_board_block_matches_the_analytic_projection_jacobian():
    """No robot noise: the T_board block of a view's information is J^T J / sigma^2 with J from the
    projection's own Jacobian (camera.pixels_from_cam_points) and the right perturbation
    p_cam = R_cam_board (p_board + omega x p_board + v) + t."""
    from handeye.camera import pixels_from_cam_points
    from handeye.frames import skew

    mode = "eye_to_hand"
    T_x, T_b, T0 = _rig(mode, 2)
    info = P.view_information(
        mode=mode,
        T_x=T_x,
        T_board=T_b,
        T_base_end=T0,
        object_points=TARGET.object_points(),
        intrinsics=INTR,
        pixel_noise_px=0.5,
        robot_noise_mm=0.0,
        robot_noise_deg=0.0,
    )
    C = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    p_b = TARGET.object_points()
    _, J_uv_p, _ = pixels_from_cam_points(INTR.as_vector(), p_b @ C[:3, :3].T + C[:3, 3])  # (N, 2, 3)
    J_p_xi = np.concatenate([-C[:3, :3] @ skew(p_b), np.broadcast_to(C[:3, :3], (len(p_b), 3, 3))], axis=2)
    J = (J_uv_p @ J_p_xi).reshape(-1, 6)  # (2N, 6)
    expected = J.T @ J / 0.5**2
    # central differences with h = 1e-6 on pixel values ~1e2-1e3: relative error ~1e-6
    np.testing.assert_allclose(info[6:, 6:], expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
