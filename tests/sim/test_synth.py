"""Tests for handeye.sim: scenarios, corner sessions, the renderer and the vendor writer, against ground truth."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from handeye.collect.visibility import board_in_image, board_out_of_image
from handeye.conventions import VENDOR_POSE_FORMAT, T_from_pose_values
from handeye.errors import ConfigError, DegenerateMotionError
from handeye.frames import inv_T, is_rotation, make_T, rotation_angle_rad, tangent_difference
from handeye.initial.motion import motion_quality
from handeye.mounting import mounting
from handeye.sim import render, scenarios
from handeye.sim.corners import make_corner_session
from handeye.sim.vendor import write_vendor_session
from handeye.targets import CharucoSpec, ChessboardSpec, CircleGridSpec, MarkerSpec

MODES = ("eye_in_hand", "eye_to_hand")


# ---------------------------------------------------------------- setup and view poses


@pytest.mark.parametrize("mode", MODES)
def test_sample_setup_is_plausible(mode):
    rng = np.random.default_rng(1)
    s = scenarios.sample_setup(mode=mode, rng=rng)
    assert s["x_name"] == mounting(mode).x_name and s["board_name"] == mounting(mode).board_name
    T_x, T_board = s["T_x"], s["T_board"]
    assert is_rotation(T_x[:3, :3]) and is_rotation(T_board[:3, :3])
    if mode == "eye_in_hand":
        offset = np.linalg.norm(T_x[:3, 3])
        assert 0.05 <= offset <= 0.10, f"camera offset on the flange {offset:.3f} m"
        tilt_deg = np.degrees(np.arccos(T_x[2, 2]))  # optical axis vs flange z
        assert tilt_deg <= 10.0 + 1e-9, f"optical axis {tilt_deg:.1f} deg from flange z"
    else:
        cam_dist = np.linalg.norm(T_x[:3, 3] - np.array([0.5, 0.0, 0.25]))
        assert 0.7 <= cam_dist <= 1.8, f"fixed camera {cam_dist:.2f} m from the workspace"


@pytest.mark.parametrize("mode", MODES)
def test_view_poses_show_whole_board_and_pass_the_motion_gates(mode):
    rng = np.random.default_rng(2)
    s = scenarios.sample_setup(mode=mode, rng=rng)
    T_base_end = scenarios.sample_view_poses(
        mode=mode,
        n_views=12,
        rng=rng,
        T_x=s["T_x"],
        T_board=s["T_board"],
        target=scenarios.DEFAULT_TARGET,
        intrinsics=scenarios.DEFAULT_INTRINSICS,
    )
    assert T_base_end.shape == (12, 4, 4)
    T_cam_board = mounting(mode).predict_T_cam_board(s["T_x"], s["T_board"], T_base_end)
    for T in T_cam_board:
        assert board_in_image(scenarios.DEFAULT_TARGET, scenarios.DEFAULT_INTRINSICS, T)
    mount = mounting(mode)
    quality = motion_quality(mount.M_from_T_base_end(T_base_end), frame=mount.fixed_frame)
    assert quality.status == "ok", quality.reason
    # the axis spread is far above the 5 deg gate, not just over it: tilts of 15-40 deg in all directions
    assert quality.axis_spread_deg > 20.0, quality.axis_spread_deg
    # rolls about the optical axis cover a wide range (stratified over +-80 deg)
    roll_deg = np.degrees(np.arctan2(T_cam_board[:, 1, 0], T_cam_board[:, 0, 0]))
    assert np.ptp(roll_deg) > 90.0, f"roll range {np.ptp(roll_deg):.0f} deg"


def test_view_poses_without_roll_or_tilt_are_degenerate():
    rng = np.random.default_rng(3)
    s = scenarios.sample_setup(mode="eye_in_hand", rng=rng)
    with pytest.raises(DegenerateMotionError):
        scenarios.sample_view_poses(
            mode="eye_in_hand",
            n_views=8,
            rng=rng,
            T_x=s["T_x"],
            T_board=s["T_board"],
            tilt_deg=(0.0, 0.0),
            roll_deg=0.0,
            aim_deg=3.0,
        )


def test_view_poses_reject_bad_options():
    rng = np.random.default_rng(0)
    s = scenarios.sample_setup(mode="eye_in_hand", rng=rng)
    with pytest.raises(ConfigError):
        scenarios.sample_view_poses(mode="eye_on_hand", n_views=5, rng=rng, T_x=s["T_x"], T_board=s["T_board"])
    with pytest.raises(ConfigError):
        scenarios.sample_view_poses(
            mode="eye_in_hand", n_views=5, rng=rng, T_x=s["T_x"], T_board=s["T_board"], distance_m=(0.9, 0.3)
        )
    with pytest.raises(ConfigError):  # a 0.36 m pattern cannot fill 0.1 m of view
        scenarios.sample_view_poses(
            mode="eye_in_hand",
            n_views=2,
            rng=rng,
            T_x=s["T_x"],
            T_board=s["T_board"],
            distance_m=(0.1, 0.12),
            max_tries=50,
        )


def test_default_intrinsics_scale_with_height():
    k = scenarios.default_intrinsics()
    assert (k.width, k.height) == (1280, 720) and abs(k.fx - 910.5) < 1e-9
    small = scenarios.default_intrinsics(640, 360)
    assert abs(small.fx - k.fx / 2) < 1e-9 and abs(small.cx - (319.5 + 1.6)) < 1e-9
    with pytest.raises(ConfigError):
        scenarios.default_intrinsics(8, 8)


# ---------------------------------------------------------------- corner-level sessions


@pytest.mark.parametrize("mode", MODES)
def test_noiseless_corners_reproject_exactly_through_truth(mode):
    s = make_corner_session(mode=mode, n_views=8, seed=4, noise_px=0.0)
    assert s.view_ids == tuple(str(k) for k in range(1, 9))
    T_cam_board = mounting(mode).predict_T_cam_board(s.T_x_true, s.T_board_true, s.T_base_end_true)
    obj = s.target.object_points()
    for k, vid in enumerate(s.view_ids):
        uv = _cv2_pixels(T_cam_board[k], obj[s.corner_ids[k]], s.intrinsics)
        assert np.max(np.abs(uv - s.image_points[k])) < 1e-9, f"view {vid}"  # float64 rounding only
    # no robot noise -> reported == true
    np.testing.assert_array_equal(s.T_base_end_reported, s.T_base_end_true)
    assert len(s.detections()) == 8


def test_pixel_noise_matches_sigma_and_keeps_geometry():
    clean = make_corner_session(n_views=10, seed=5, noise_px=0.0)
    noisy = make_corner_session(n_views=10, seed=5, noise_px=0.5)
    np.testing.assert_array_equal(clean.T_base_end_true, noisy.T_base_end_true)  # noise never moves geometry
    d = np.concatenate([a - b for a, b in zip(noisy.image_points, clean.image_points, strict=False)]).ravel()
    n = d.size  # 10 views * 88 corners * 2
    assert abs(d.std() - 0.5) < 0.5 * 5 / np.sqrt(2 * n), f"pixel noise std {d.std():.4f}"


@pytest.mark.parametrize("mode", MODES)
def test_robot_noise_statistics_match_sigma(mode):
    sigma_mm, sigma_deg = 1.0, 0.2
    s = make_corner_session(mode=mode, n_views=40, seed=6, noise_px=0.0, robot_noise=(sigma_mm, sigma_deg))
    dT = inv_T(s.T_base_end_true) @ s.T_base_end_reported  # end-frame perturbation
    t_mm = 1e3 * dT[:, :3, 3].ravel()
    rv_deg = np.degrees(np.array([_rotvec(R) for R in dT[:, :3, :3]])).ravel()
    n = t_mm.size  # 120 samples; std of the sample std is sigma/sqrt(2n)
    tol = 5.0 / np.sqrt(2 * n)
    assert abs(t_mm.std() / sigma_mm - 1) < tol, f"translation std {t_mm.std():.3f} mm"
    assert abs(rv_deg.std() / sigma_deg - 1) < tol, f"rotation std {rv_deg.std():.4f} deg"
    assert abs(t_mm.mean()) < 5 * sigma_mm / np.sqrt(n)
    assert abs(rv_deg.mean()) < 5 * sigma_deg / np.sqrt(n)
    # the corners still follow the *true* poses
    T_cam_board = s.T_cam_board_true
    uv = _cv2_pixels(T_cam_board[0], s.target.object_points(), s.intrinsics)
    assert np.max(np.abs(uv - s.image_points[0])) < 1e-9


def _rotvec(R):
    return Rotation.from_matrix(R).as_rotvec()


def _cv2_pixels(T_cam_board, p_board, intr):
    """cv2.projectPoints as the independent oracle of the projection the sessions are made with."""
    rvec = Rotation.from_matrix(T_cam_board[:3, :3]).as_rotvec()
    uv, _ = cv2.projectPoints(
        np.ascontiguousarray(p_board, float), rvec, T_cam_board[:3, 3].copy(), intr.K, intr.dist_array
    )
    return uv.reshape(-1, 2)


def test_outliers_get_gross_errors_in_range():
    s = make_corner_session(n_views=12, seed=7, noise_px=0.0, outlier_views=3)
    assert len(s.outlier_view_ids) == 3
    for vid in s.view_ids:
        k = s.index(vid)
        dT = inv_T(s.T_base_end_true[k]) @ s.T_base_end_reported[k]
        t_mm = 1e3 * np.linalg.norm(dT[:3, 3])
        ang_deg = np.degrees(rotation_angle_rad(dT[:3, :3]))
        if vid in s.outlier_view_ids:
            assert 5.0 <= t_mm <= 30.0 and 2.0 <= ang_deg <= 10.0, (vid, t_mm, ang_deg)
        else:
            assert t_mm < 1e-9 and ang_deg < 1e-9
    explicit = make_corner_session(n_views=6, seed=7, outlier_views=["2", "5"])
    assert explicit.outlier_view_ids == ("2", "5")


def test_hidden_views_have_no_corners_and_board_out_of_view():
    s = make_corner_session(mode="eye_to_hand", n_views=6, seed=8, hidden_views=["3"])
    k = s.index("3")
    assert s.hidden_view_ids == ("3",) and len(s.corner_ids[k]) == 0 and s.image_points[k].shape == (0, 2)
    assert board_out_of_image(s.target, s.intrinsics, s.T_cam_board_true[k])
    assert "3" not in [d.view_id for d in s.detections()]


def test_a_fixed_camera_far_from_the_base_still_gets_its_hidden_view():
    """This rig's camera stands 2 m from the base, looking over the whole reach: no turn of a board view away
    from the camera is within reach, so the hidden view is a flange pose drawn over the reach instead."""
    s = make_corner_session(mode="eye_to_hand", n_views=22, seed=2341, robot_noise=(0.2, 0.05), hidden_views=["7"])
    assert np.linalg.norm(s.T_x_true[:3, 3]) > 1.9
    k = s.index("7")
    assert board_out_of_image(s.target, s.intrinsics, s.T_cam_board_true[k]) and len(s.corner_ids[k]) == 0
    assert scenarios.plausible_robot_pose(s.T_base_end_true[k])


def test_an_arm_whose_camera_sees_its_whole_configuration_gets_its_hidden_view_by_a_joint_move():
    """This UR5e's fixed camera sees every pose of the arm's configuration that a turn away from a board view or
    a flange pose drawn over the reach gives: the hidden view is a move of the arm's joints, in its configuration."""
    from handeye.kinematics import load_arm

    kw = {"robot_error": "kinematic", "arm": "ur5e", "hidden_views": ["8"], "outlier_views": 2}
    s = make_corner_session(mode="eye_to_hand", n_views=11, seed=57, **kw)
    k = s.index("8")
    assert board_out_of_image(s.target, s.intrinsics, s.T_cam_board_true[k]) and len(s.corner_ids[k]) == 0
    assert scenarios.plausible_robot_pose(s.T_base_end_true[k])
    true = load_arm("ur5e").with_dh(np.array(s.robot_model["dh_true"]))
    np.testing.assert_allclose(true.T_base_end(s.joints_true), s.T_base_end_true, atol=1e-9)
    q = np.asarray(s.joints_true)
    path = q[0] + np.linspace(0.0, 1.0, 16)[:, None] * (q[k] - q[0])  # no flip from the first view's configuration
    det = np.array([np.linalg.det(true.jacobian_joints(p)) for p in path])
    assert true.within_limits(q[k]) and (np.all(det > 0) or np.all(det < 0))


def test_a_rig_where_the_arm_cannot_show_the_board_is_drawn_again():
    """Seed 409's first eye-to-hand rig leaves no pose of the UR5e in front of the camera at a working distance, in
    any configuration: the session is drawn on another rig, every view showing the whole board."""
    s = make_corner_session(mode="eye_to_hand", n_views=12, seed=409, robot_error="kinematic", arm="ur5e")
    first = scenarios.sample_setup(
        mode="eye_to_hand",
        rng=scenarios.random_streams(409)["geometry"],
        target=s.target,
        workspace_scale=scenarios.arm_workspace("ur5e", mode="eye_to_hand", target=s.target)[0],
    )
    assert not np.allclose(first["T_x"], s.T_x_true)
    assert all(len(ids) == s.target.n_corners for ids in s.corner_ids)
    assert all(board_in_image(s.target, s.intrinsics, T) for T in s.T_cam_board_true)


def test_a_fixed_camera_the_arm_cannot_bring_a_small_marker_to_is_drawn_again():
    """Seed 6021's first eye-to-hand rig puts the camera where no reachable flange holds the 48 mm marker 5-12 cm
    in front of it (iid robot error: no arm model): the session is drawn on another rig, not refused."""
    marker = MarkerSpec(0.048)
    first = scenarios.sample_setup(mode="eye_to_hand", rng=scenarios.random_streams(6021)["geometry"], target=marker)
    with pytest.raises(ConfigError, match="cannot place the board"):
        scenarios.sample_view_poses(
            mode="eye_to_hand",
            n_views=14,
            rng=scenarios.random_streams(6021)["geometry"],
            T_x=first["T_x"],
            T_board=first["T_board"],
            target=marker,
        )
    s = make_corner_session(mode="eye_to_hand", n_views=14, seed=6021, target=marker, noise_px=0.0)
    assert not np.allclose(first["T_x"], s.T_x_true)
    assert all(len(ids) == 4 for ids in s.corner_ids)
    assert all(scenarios.plausible_robot_pose(T) for T in s.T_base_end_true)


def test_corner_session_rejects_bad_ids_and_levels():
    with pytest.raises(ConfigError):
        make_corner_session(n_views=4, hidden_views=["5"])
    with pytest.raises(ConfigError):
        make_corner_session(n_views=4, hidden_views=["2"], outlier_views=["2"])
    with pytest.raises(ConfigError):
        make_corner_session(n_views=4, outlier_views=5)
    with pytest.raises(ConfigError):
        make_corner_session(n_views=4, noise_px=-1.0)
    with pytest.raises(ConfigError):
        make_corner_session(mode="hand_in_eye", n_views=4)


def test_corner_session_is_frozen_and_deterministic():
    a = make_corner_session(n_views=5, seed=9, target=ChessboardSpec(9, 6, 0.025))
    b = make_corner_session(n_views=5, seed=9, target=ChessboardSpec(9, 6, 0.025))
    np.testing.assert_array_equal(a.T_base_end_true, b.T_base_end_true)
    np.testing.assert_array_equal(a.image_points[2], b.image_points[2])
    with pytest.raises(ValueError):
        a.image_points[0][0, 0] = 1.0


# ---------------------------------------------------------------- rendering
SMALL = scenarios.default_intrinsics(640, 360)  # same field of view as 1280x720, 4x fewer pixels


def test_newton_undistortion_round_trips_through_cv2_project_points():
    k = scenarios.DEFAULT_INTRINSICS
    rng = np.random.default_rng(10)
    uv = np.stack([rng.uniform(-0.5, k.width - 0.5, 2000), rng.uniform(-0.5, k.height - 0.5, 2000)], 1)
    xt, yt = (uv[:, 0] - k.cx) / k.fx, (uv[:, 1] - k.cy) / k.fy
    x, y = render._newton_undistort(xt.copy(), yt.copy(), xt, yt, k.dist, iterations=8)  # from the distorted point
    back, _ = cv2.projectPoints(np.stack([x, y, np.ones_like(x)], 1), np.zeros(3), np.zeros(3), k.K, k.dist_array)
    assert np.max(np.abs(back.reshape(-1, 2) - uv)) < 1e-6


def test_cached_sample_grid_round_trips():
    # float64 solution is checked < 1e-6 px inside; the cache stores float32 (measured 2.7e-5 px max)
    assert render.roundtrip_error_px(SMALL, supersample=4, stride=101) < 1e-4
    g = render.undistorted_sample_grid(SMALL, supersample=4)
    assert g.shape == (360 * 4, 640 * 4, 2) and not g.flags.writeable
    with pytest.raises(ConfigError):
        render.undistorted_sample_grid(SMALL, supersample=0)


def test_every_sample_of_a_pixel_has_its_own_place_along_each_axis():
    """4 x 4 samples take 16 places along x and 16 along y (1/16 px apart), point-symmetric about the pixel's centre
    (an X junction gets no bias from them); any other count a sheared grid of the same kind."""
    for s in (1, 2, 3, 4, 5):
        x, y = render._pixel_samples(s)
        for v in (x, y):
            assert np.allclose(np.sort(v.ravel()), (np.arange(s * s) + 0.5) / (s * s) - 0.5)
        assert np.allclose(x, -x[::-1, ::-1]) and np.allclose(y, -y[::-1, ::-1])


def test_an_edge_near_a_pixel_axis_is_rendered_where_it_is():
    """A single marker facing the camera, turned 0.3-2 deg about its axis: on the plain 4 x 4 grid its sides near
    the pixel axes moved in steps of 1/4 px along themselves, which tilted the fitted sides and put corners up to
    0.25 px off (measured); with the samples' own places, at most 0.057 px."""
    from handeye.detect.markers import detect_markers
    from handeye.frames import R_from_rotvec

    intr, spec = scenarios.default_intrinsics(1280, 720), MarkerSpec(0.048)
    worst = 0.0
    for deg in (0.3, 0.6, 1.0, 2.0):
        for dx in (0.0, 0.0007):
            T = make_T(R_from_rotvec(np.array([0.0, 0.0, np.radians(deg)])), np.array([-0.024 + dx, -0.024, 0.3]))
            ids, pts = detect_markers(render.render_view(spec, intr, T, blur_sigma_px=1.0), spec)
            rv = cv2.Rodrigues(T[:3, :3])[0]
            truth = cv2.projectPoints(spec.object_points(), rv, T[:3, 3], intr.K, intr.dist_array)[0].reshape(-1, 2)
            worst = max(worst, float(np.linalg.norm(pts - truth[ids], axis=1).max()))
    assert worst < 0.09, worst


def test_a_camera_tone_curve_encodes_the_light_rendered():
    """gamma 2.2: grey = 255 (light / 255) ** (1 / 2.2), noise and blur in light before it; gamma 1 is the light."""
    s = make_corner_session(n_views=1, seed=12, intrinsics=SMALL)
    T = s.T_cam_board_true[0]
    light = render.render_view(s.target, SMALL, T, background="flat").astype(float)
    grey = render.render_view(s.target, SMALL, T, background="flat", gamma=2.2).astype(float)
    assert np.max(np.abs(grey - 255.0 * (light / 255.0) ** (1 / 2.2))) <= 1.0  # the rounding of each
    with pytest.raises(ConfigError, match="gamma"):
        render.render_view(s.target, SMALL, T, gamma=0.0)


def _detect_chessboard(img, target):
    ok, c = cv2.findChessboardCorners(img, (target.cols, target.rows))
    if not ok:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    return cv2.cornerSubPix(img, c, (4, 4), (-1, -1), crit).reshape(-1, 2)


def test_rendered_chessboard_corners_match_projected_truth():
    s = make_corner_session(n_views=2, seed=0, noise_px=0.0, intrinsics=SMALL)
    for k in range(s.n_views):
        img = render.render_view(s.target, SMALL, s.T_cam_board_true[k])
        assert img.shape == (360, 640) and img.dtype == np.uint8
        found = _detect_chessboard(img, s.target)
        assert found is not None, f"view {s.view_ids[k]}: chessboard not found"
        truth = s.image_points[k]
        nearest = np.linalg.norm(found[:, None] - truth[None], axis=2).argmin(axis=1)
        assert len(set(nearest)) == s.target.n_corners
        rms_px = np.sqrt(np.mean(np.sum((found - truth[nearest]) ** 2, axis=1)))
        # measured: 0.043 and 0.050 px (seed 0, 640x360, supersample 4; 0.04-0.09 px over 36 views at
        # 640x360 and 0.035-0.064 px at 1280x720, limited by cornerSubPix, not by the renderer)
        assert rms_px < 0.08, f"view {s.view_ids[k]}: rms {rms_px:.4f} px"


def test_rendered_charuco_ids_and_corners_match_truth():
    target = CharucoSpec(7, 5, 0.05, 0.037, "DICT_4X4_50")
    s = make_corner_session(n_views=1, seed=1, noise_px=0.0, intrinsics=SMALL, target=target)
    img = render.render_view(target, SMALL, s.T_cam_board_true[0], channels=3)
    assert img.shape == (360, 640, 3)
    board = cv2.aruco.CharucoBoard((7, 5), 0.05, 0.037, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(img)
    assert ids is not None and len(ids) == target.n_corners
    err = corners.reshape(-1, 2) - s.image_points[0][ids.ravel()]
    rms_px = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert rms_px < 0.15, f"rms {rms_px:.4f} px"  # measured 0.046 (0.036-0.134 over 8 views)


def test_hidden_view_renders_no_board():
    s = make_corner_session(n_views=3, seed=11, intrinsics=SMALL, hidden_views=["2"])
    T = s.T_cam_board_true[s.index("2")]
    _, coverage = render.render_accumulate(s.target, SMALL, T)
    assert coverage.max() == 0.0
    img = render.render_view(s.target, SMALL, T, noise_sigma=2.0, rng=np.random.default_rng(0))
    assert _detect_chessboard(img, s.target) is None


def test_board_behind_camera_or_seen_from_the_back_shows_no_pattern():
    target = scenarios.DEFAULT_TARGET
    center = np.array([0.165, 0.105, 0.0])  # centre of the 11x8 pattern (squares span -0.03..0.33, -0.03..0.24)
    behind = np.eye(4)
    behind[:3, 3] = -center + [0.0, 0.0, -0.6]  # rays meet the plane behind the camera: nothing drawn
    _, coverage = render.render_accumulate(target, SMALL, behind)
    assert coverage.max() == 0.0
    back = np.diag([-1.0, 1.0, -1.0, 1.0])  # turned 180 deg about y: camera sees the unprinted side
    back[:3, 3] = back[:3, :3] @ -center + [0.0, 0.0, 0.6]
    img = render.render_view(target, SMALL, back, background="flat")
    assert render.render_accumulate(target, SMALL, back)[1].max() == 1.0
    assert _detect_chessboard(img, target) is None


def test_render_view_blur_noise_and_bad_options():
    s = make_corner_session(n_views=1, seed=12, intrinsics=SMALL)
    T = s.T_cam_board_true[0]
    clean = render.render_view(s.target, SMALL, T, background="flat").astype(float)
    blurred = render.render_view(s.target, SMALL, T, background="flat", blur_sigma_px=1.5).astype(float)
    lap = lambda im: cv2.Laplacian(im, cv2.CV_64F).var()  # noqa: E731
    assert lap(blurred) < 0.5 * lap(clean)
    noisy = render.render_view(
        s.target, SMALL, T, background="flat", noise_sigma=3.0, rng=np.random.default_rng(1)
    ).astype(float)
    # Gaussian noise of 3 grey levels plus the rounding to integers (uniform, variance 1/12): std
    # sqrt(9 + 1/12) = 3.014; over 640 x 360 pixels the sample std scatters by 3 / sqrt(2 n) = 0.0044
    assert abs(np.std(noisy - clean) - np.sqrt(9.0 + 1.0 / 12.0)) < 5 * 3.0 / np.sqrt(2 * noisy.size)
    with pytest.raises(ConfigError):
        render.render_view(s.target, SMALL, T, noise_sigma=1.0)  # no rng
    with pytest.raises(ConfigError):
        render.render_view(s.target, SMALL, T, channels=2)
    with pytest.raises(ConfigError):
        render.render_view(s.target, SMALL, T, background="sky")
    for blur, noise in ((float("nan"), 0.0), (0.0, float("nan")), (float("inf"), 0.0), (0.0, -1.0)):
        with pytest.raises(ConfigError, match="not a finite number >= 0"):  # nan noise rendered none before
            render.render_view(s.target, SMALL, T, blur_sigma_px=blur, noise_sigma=noise, rng=np.random.default_rng(1))


# ---------------------------------------------------------------- vendor-layout writer


@pytest.mark.parametrize(
    "levels",
    [
        {"robot_noise": (float("nan"), 0.0)},
        {"robot_noise": (0.1, float("inf"))},
        {"image_noise": float("nan")},
        {"blur_sigma_px": float("nan")},
        {"blur_sigma_px": -1.0},
    ],
)
def test_vendor_session_refuses_noise_that_is_not_a_finite_number(tmp_path, levels):
    """A nan robot noise wrote poses.txt full of nan and a ground_truth.json that is not JSON; nothing is written."""
    with pytest.raises(ConfigError, match="not a finite number >= 0"):
        write_vendor_session(tmp_path / "s", n_views=3, intrinsics=SMALL, **levels)
    assert not (tmp_path / "s").exists()


def test_vendor_session_files_poses_and_hidden_views(tmp_path):
    out = write_vendor_session(
        tmp_path / "s",
        mode="eye_to_hand",
        n_views=4,
        seed=13,
        image_noise=1.0,
        blur_sigma_px=0.3,
        robot_noise=(1.0, 0.1),
        hidden_views=["2"],
        outlier_views=1,
        intrinsics=SMALL,
    )
    names = sorted(p.name for p in out.iterdir())
    assert names == ["1.jpg", "2.jpg", "3.jpg", "4.jpg", "config.yaml", "ground_truth.json", "poses.txt"], names
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg == {"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}, "mode": "eye_to_hand"}
    truth = json.loads((out / "ground_truth.json").read_text())
    assert truth["mode"] == "eye_to_hand" and truth["seed"] == 13
    assert truth["hidden_view_ids"] == ["2"] and truth["views"]["2"]["hidden"]
    assert len(truth["outlier_view_ids"]) == 1 and truth["views"][truth["outlier_view_ids"][0]]["outlier"]
    assert np.asarray(truth["T_base_cam"]).shape == (4, 4) and np.asarray(truth["T_end_board"]).shape == (4, 4)
    assert truth["intrinsics"] == SMALL.to_dict()

    # poses.txt line k -> k.jpg, parses back to the reported poses (%.9f: <= 5e-10 per value, so
    # <= 1.5e-9 per matrix entry from three rounded angles)
    lines = (out / "poses.txt").read_text().splitlines()
    assert len(lines) == 4
    same = make_corner_session(
        mode="eye_to_hand",
        n_views=4,
        seed=13,
        robot_noise=(1.0, 0.1),
        hidden_views=["2"],
        outlier_views=1,
        intrinsics=SMALL,
    )
    for k, line in enumerate(lines, start=1):
        T_file = T_from_pose_values([float(v) for v in line.split(",")], VENDOR_POSE_FORMAT)
        T_rep = np.asarray(truth["views"][str(k)]["T_base_end_reported"])
        assert np.max(np.abs(T_file[:3, 3] - T_rep[:3, 3])) <= 5e-10 + 1e-15
        assert np.max(np.abs(T_file - T_rep)) < 1.5e-9
        np.testing.assert_array_equal(T_rep, same.T_base_end_reported[k - 1])  # same geometry as corner level

    # the hidden view has no detectable board; the others do
    for vid in ("1", "2", "3", "4"):
        img = cv2.imread(str(out / f"{vid}.jpg"), cv2.IMREAD_GRAYSCALE)
        assert img.shape == (360, 640)
        found = _detect_chessboard(img, scenarios.DEFAULT_TARGET)
        assert (found is None) == (vid == "2"), f"view {vid}"


def test_vendor_session_refuses_to_overwrite_and_bad_options(tmp_path):
    kw = dict(n_views=3, seed=14, intrinsics=SMALL, image_format="png")
    out = write_vendor_session(tmp_path, **kw)
    assert (out / "3.png").exists()
    with pytest.raises(ConfigError):
        write_vendor_session(tmp_path, **kw)
    write_vendor_session(tmp_path, overwrite=True, **kw)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left
    with pytest.raises(ConfigError, match="unknown target type"):  # no renderer for circle grids
        write_vendor_session(tmp_path / "x", target=CircleGridSpec(5, 4, 0.04), n_views=3)
    with pytest.raises(ConfigError):
        write_vendor_session(tmp_path / "y", image_format="tiff", n_views=3)


# ---------------------------------------------------------------- kinematic robot error


def test_kinematic_session_poses_are_the_two_arms_forward_kinematics():
    from handeye.kinematics import load_arm

    s = make_corner_session(mode="eye_in_hand", n_views=8, seed=2, robot_error="kinematic")
    m = s.robot_model
    assert s.robot_error == "kinematic" and m["arm"] == "rm65"
    nominal, true = load_arm("rm65"), load_arm("rm65").with_dh(np.array(m["dh_true"]))
    assert s.joints_true.shape == s.joints_encoder.shape == (8, 6)
    # the flange is where the TRUE arm puts it; the arm reports the NOMINAL model of its encoder readings
    np.testing.assert_allclose(true.T_base_end(s.joints_true), s.T_base_end_true, atol=1e-9)
    np.testing.assert_allclose(nominal.T_base_end(s.joints_encoder), s.T_base_end_reported, atol=1e-12)
    # every DH error within the ranges drawn from: lengths 0.1-0.5 mm, angles 0.01-0.05 deg
    err = np.abs(np.array(m["dh_error_mm_deg"]))
    assert np.all(err[:, [0, 2]] >= 0.1 - 1e-9) and np.all(err[:, [0, 2]] <= 0.5 + 1e-9)
    assert np.all(err[:, [1, 3]] >= 0.01 - 1e-12) and np.all(err[:, [1, 3]] <= 0.05 + 1e-12)
    for q in s.joints_true:
        assert nominal.within_limits(q)


def test_kinematic_error_is_the_dh_jacobian_times_the_dh_error():
    """Without encoder noise, reported-vs-true of every view is J_dh(q) · (dh_nominal - dh_true) to first
    order: one shared 24-vector explains all views (correlated), unlike iid noise."""
    from handeye.kinematics import load_arm

    s = make_corner_session(mode="eye_in_hand", n_views=10, seed=4, robot_error="kinematic", encoder_sigma_deg=0.0)
    np.testing.assert_allclose(s.joints_encoder, s.joints_true, atol=0)
    nominal = load_arm("rm65")
    delta = nominal.dh - np.array(s.robot_model["dh_true"])  # (6, 4), |.| <= 0.5 mm / 0.05 deg
    xi = tangent_difference(s.T_base_end_true, s.T_base_end_reported)  # (N, 6)
    pred = np.stack([nominal.jacobian_dh(q) @ delta.reshape(-1) for q in s.joints_true])
    # second-order remainder: |delta|^2 times lever arms below 1 m, i.e. below ~1e-6 (1 um, 1e-4 deg)
    np.testing.assert_allclose(xi, pred, atol=2e-6)
    assert 0.1 < np.sqrt(np.mean(np.sum(xi[:, 3:] ** 2, axis=1))) * 1e3 < 3.0  # mm: the size the ranges give

    # correlated across views: the base-frame position errors point the same way (mean pairwise cosine)
    def mean_cosine(sess):
        d = sess.T_base_end_reported[:, :3, 3] - sess.T_base_end_true[:, :3, 3]
        u = d / np.linalg.norm(d, axis=1, keepdims=True)
        n = len(u)
        return (np.sum(u @ u.T) - n) / (n * (n - 1))

    iid = make_corner_session(mode="eye_in_hand", n_views=10, seed=4, robot_noise=(0.5, 0.05))
    assert mean_cosine(s) > 0.5
    assert abs(mean_cosine(iid)) < 0.3


def test_encoder_noise_has_its_sigma():
    s = make_corner_session(mode="eye_to_hand", n_views=20, seed=1, robot_error="kinematic", encoder_sigma_deg=0.02)
    e = np.degrees(s.joints_encoder - s.joints_true)  # 120 draws of N(0, 0.02 deg)
    assert 0.015 < np.std(e) < 0.025 and abs(np.mean(e)) < 0.006


def test_kinematic_session_views_are_in_one_arm_configuration():
    """A capture sequence keeps the arm's configuration (shoulder, elbow, wrist on one side): every view's
    true joints are reached from the first view's without crossing a singularity (det J keeps its sign along
    the straight joint-space move), so all views carry the same kind of kinematic error."""
    from handeye.kinematics import load_arm

    for arm, mode in (("rm65", "eye_to_hand"), ("ur5e", "eye_in_hand")):
        s = make_corner_session(mode=mode, n_views=20, seed=5, robot_error="kinematic", arm=arm)
        chain = load_arm(arm)
        q = np.asarray(s.joints_true)
        for k in range(1, len(q)):
            path = q[0] + np.linspace(0.0, 1.0, 16)[:, None] * (q[k] - q[0])
            det = np.array([np.linalg.det(chain.jacobian_joints(p)) for p in path])
            assert np.all(det > 0) or np.all(det < 0), (arm, k, det)


def test_kinematic_sessions_are_reproducible_by_seed():
    a = make_corner_session(mode="eye_in_hand", n_views=5, seed=9, robot_error="kinematic", arm="ur5e")
    b = make_corner_session(mode="eye_in_hand", n_views=5, seed=9, robot_error="kinematic", arm="ur5e")
    c = make_corner_session(mode="eye_in_hand", n_views=5, seed=10, robot_error="kinematic", arm="ur5e")
    np.testing.assert_array_equal(a.T_base_end_reported, b.T_base_end_reported)
    np.testing.assert_array_equal(a.joints_encoder, b.joints_encoder)
    assert a.robot_model == b.robot_model and a.robot_model["arm"] == "ur5e"
    assert not np.allclose(a.robot_model["dh_true"], c.robot_model["dh_true"])


def test_none_model_reports_the_truth_and_bad_model_options_are_refused():
    s = make_corner_session(mode="eye_in_hand", n_views=4, seed=0, robot_error="none")
    np.testing.assert_array_equal(s.T_base_end_reported, s.T_base_end_true)
    assert s.joints_encoder is None
    with pytest.raises(ConfigError, match="robot error model"):
        make_corner_session(n_views=4, robot_error="gaussian")
    with pytest.raises(ConfigError, match="iid model"):
        make_corner_session(n_views=4, robot_error="kinematic", robot_noise=(0.1, 0.0))
    with pytest.raises(ConfigError, match="encoder"):
        make_corner_session(n_views=4, robot_error="kinematic", encoder_sigma_deg=-1.0)


def test_vendor_session_records_the_kinematic_model_and_joints(tmp_path):
    out = write_vendor_session(tmp_path / "s", n_views=3, seed=0, robot_error="kinematic", supersample=1)
    truth = json.loads((out / "ground_truth.json").read_text())
    assert truth["robot_error"]["model"] == "kinematic" and len(truth["robot_error"]["dh_true"]) == 6
    assert len(truth["views"]["1"]["joints_encoder"]) == 6
    iid = write_vendor_session(tmp_path / "t", n_views=3, seed=0, supersample=1)
    assert json.loads((iid / "ground_truth.json").read_text())["robot_error"] == {"model": "iid"}


def test_charuco_session_is_written_as_a_native_session_that_loads(tmp_path):
    from handeye.session import load_session

    target = CharucoSpec(7, 5, 0.05, 0.037, "DICT_4X4_50")
    folder = write_vendor_session(tmp_path / "c", n_views=3, target=target, intrinsics=SMALL, mode="eye_to_hand")
    assert not (folder / "poses.txt").exists() and not (folder / "config.yaml").exists()
    s = load_session(folder)
    truth = json.loads((folder / "ground_truth.json").read_text())
    assert s.target == target and s.mode == "eye_to_hand" and [v.view_id for v in s.views] == ["1", "2", "3"]
    for v in s.views:  # the poses read back are the reported ones (9 decimals written)
        assert np.allclose(v.T_base_end, truth["views"][v.view_id]["T_base_end_reported"], atol=1e-8)
