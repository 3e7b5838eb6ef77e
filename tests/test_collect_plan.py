"""Pose planner: Fisher information against Monte Carlo, orbit geometry, coverage of the greedy plan."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from handeye.sim import synth
from handeye.collect import plan as P
from handeye.errors import ConfigError
from handeye.frames import T_from_rotvec, inv_T, rotation_angle_rad
from handeye.mounting import mounting

INTR = synth.default_intrinsics(640, 360)
TARGET = synth.DEFAULT_TARGET


def _rig(mode, seed):
    rng = np.random.default_rng(seed)
    setup = synth.sample_setup(mode=mode, rng=rng, target=TARGET)
    T0 = synth.sample_view_poses(mode=mode, n_views=1, rng=rng, T_x=setup["T_x"], T_board=setup["T_board"],
                                 target=TARGET, intrinsics=INTR, tilt_deg=(0.0, 8.0), roll_deg=10.0)[0]
    return setup["T_x"], setup["T_board"], T0


def test_orbit_keeps_the_board_centre_on_the_optical_ray():
    T_x, T_b, T0 = _rig("eye_in_hand", 0)
    C0 = mounting("eye_in_hand").predict_T_cam_board(T_x, T_b, T0)
    c = P.board_center(TARGET)
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
        C = mount.predict_T_cam_board(X, B, E)
        return P.pixel_from_cam_points(obj @ C[:3, :3].T + C[:3, 3], INTR)

    Ls = []
    for E in Ts:  # per-view whitening from the pixel and robot-pose noise
        J = []
        for k in range(6):
            xi = np.zeros(6)
            xi[k] = 1e-6
            up = proj(T_x, T_b, E @ T_from_rotvec(xi[:3], xi[3:]))
            dn = proj(T_x, T_b, E @ T_from_rotvec(-xi[:3], -xi[3:]))
            J.append(((up - dn) / 2e-6).ravel())
        Jm = np.array(J).T
        S = np.diag([np.radians(robot_deg) ** 2] * 3 + [(robot_mm * 1e-3) ** 2] * 3)
        cov = noise_px ** 2 * np.eye(Jm.shape[0]) + Jm @ S @ Jm.T
        Ls.append(np.linalg.cholesky(np.linalg.inv(cov)).T if whiten else np.eye(Jm.shape[0]))
    rng = np.random.default_rng(seed)
    clean = [proj(T_x, T_b, E) for E in Ts]
    out = []
    for _ in range(trials):
        reported = [synth.perturb_T_base_end(E, rng=rng, sigma_mm=robot_mm, sigma_deg=robot_deg)[0] for E in Ts]
        obs = [o + rng.normal(0.0, noise_px, o.shape) for o in clean]

        def res(th):
            X = T_x @ T_from_rotvec(th[:3], th[3:6])
            B = T_b @ T_from_rotvec(th[6:9], th[9:12])
            return np.concatenate([L @ (proj(X, B, E) - o).ravel() for L, E, o in zip(Ls, reported, obs)])

        out.append(least_squares(res, np.zeros(12), method="lm", x_scale=1e-3).x[:6])
    return np.array(out)


@pytest.mark.parametrize("mode, robot", [("eye_in_hand", (0.0, 0.0)), ("eye_to_hand", (0.2, 0.05))])
def test_predicted_sigma_matches_monte_carlo(mode, robot):
    """The prediction is the Cramer-Rao bound: an estimator weighting pixel and robot noise attains it."""
    T_x, T_b, T0 = _rig(mode, 1)
    C0 = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    cfg = P.PlanConfig(pixel_noise_px=0.5, robot_noise_mm=robot[0], robot_noise_deg=robot[1])
    plan = P.make_plan(mode=mode, T_x=T_x, T_board=T_b, T_base_end_start=T0, T_cam_board_start=C0,
                       T_base_end_done=[T0], target=TARGET, intrinsics=INTR, n_views=4, config=cfg)
    Ts = [T0] + [pv.candidate.T_base_end for pv in plan.views]
    err = _fit_errors(mode, T_x, T_b, Ts, noise_px=0.5, robot_mm=robot[0], robot_deg=robot[1], trials=20,
                      seed=7, whiten=True)
    rot_deg = np.degrees(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))))
    trans_mm = 1e3 * np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))
    pv = plan.views[-1]
    print(f"predicted {pv.sigma_rot_deg:.4f} deg {pv.sigma_trans_mm:.3f} mm, Monte Carlo {rot_deg:.4f} deg {trans_mm:.3f} mm")
    # 20 trials: the root-mean-square of a 3-d error scatters by ~10 % around its expectation
    assert rot_deg == pytest.approx(pv.sigma_rot_deg, rel=0.35)
    assert trans_mm == pytest.approx(pv.sigma_trans_mm, rel=0.35)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_greedy_plan_rotates_about_all_three_axes_and_shrinks_sigma(mode):
    T_x, T_b, T0 = _rig(mode, 3)
    C0 = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    steps = []
    plan = P.make_plan(mode=mode, T_x=T_x, T_board=T_b, T_base_end_start=T0, T_cam_board_start=C0,
                       T_base_end_done=[T0], target=TARGET, intrinsics=INTR, n_views=6, on_step=steps.append)
    assert plan.status == "ok", plan.failure_reason
    assert len(plan.views) == 6 and [s.index for s in steps] == list(range(1, 7))
    assert np.all(plan.axis_rotation_deg >= 30.0)
    sig = [pv.sigma_trans_mm for pv in plan.views]
    assert all(b <= a + 1e-9 for a, b in zip(sig, sig[1:]))
    for pv in plan.views:  # every planned view shows the whole board, through the model
        C = mounting(mode).predict_T_cam_board(T_x, T_b, pv.candidate.T_base_end)
        np.testing.assert_allclose(C, pv.candidate.T_cam_board, atol=1e-9)
        assert synth.board_in_image(TARGET, INTR, C)
        assert np.linalg.norm(pv.candidate.T_base_end[:3, 3] - T0[:3, 3]) <= P.PlanConfig().max_travel_m


def test_greedy_beats_random_choice():
    mode = "eye_in_hand"
    T_x, T_b, T0 = _rig(mode, 4)
    C0 = mounting(mode).predict_T_cam_board(T_x, T_b, T0)
    cands = P.candidate_views(mode=mode, T_x=T_x, T_board=T_b, T_base_end_start=T0, T_cam_board_start=C0,
                              target=TARGET, intrinsics=INTR)
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
    info = P.information_of_views(mode="eye_to_hand", T_x=T_x, T_board=T_b, T_base_end=[T0], target=TARGET,
                                  intrinsics=INTR)
    np.testing.assert_allclose(info, info.T, rtol=1e-6, atol=1e-6 * np.abs(info).max())
    ev = np.linalg.eigvalsh(info)
    assert np.sum(ev > 1e-6 * ev.max()) == 6  # one view fixes T_cam_board only: 6 of 12 directions


def test_probe_poses_are_small_rotations_about_end_axes():
    T0 = synth.perturb_T_base_end(np.eye(4), rng=np.random.default_rng(0), sigma_mm=100, sigma_deg=30)[0]
    for k, pair in enumerate(P.probe_poses(T0, probe_deg=6.0)):
        for angle, T in zip((6.0, -6.0, 3.0, -3.0), pair):
            np.testing.assert_allclose((inv_T(T0) @ T)[:3, 3], 0.0, atol=1e-12)
            rv_deg = P.end_rotvec_deg(T0, T)
            assert np.argmax(np.abs(rv_deg)) == k and rv_deg[k] == pytest.approx(angle)
