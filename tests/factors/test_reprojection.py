"""Reprojection factors: analytic Jacobians against numerical derivatives on the manifold, the
projection against OpenCV and GTSAM, and the CustomFactor wrapper against the numpy residual."""

from __future__ import annotations

import cv2
import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import numericalDerivative11

from handeye.camera import pixels_from_cam_points
from handeye.errors import ConfigError
from handeye.factors.gtsam_factors import robot_pose_prior, view_reprojection_factor
from handeye.factors.reprojection import (
    chain_residual,
    corner_robust_scales,
    eye_in_hand_residual,
    eye_to_hand_residual,
    stacked_chain_jacobians,
    stacked_chain_residual,
)
from handeye.mounting import mounting

K9 = np.array([910.0, 905.0, 641.0, 362.0, -0.21, 0.09, 0.0012, -0.0008, 0.03])


def _random_pose(rng, *, rot_scale=1.0, trans_m=0.3) -> np.ndarray:
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * rot_scale), rng.normal(size=3) * trans_m).matrix()


def _chain_setup(rng, mode: str):
    """Random T_x, T_board and a robot pose that puts a 0.1 m board 0.5-0.7 m in front of the camera."""
    T_x, T_board = _random_pose(rng), _random_pose(rng)
    T_cam_board = gtsam.Pose3(
        gtsam.Rot3.Expmap([np.pi, 0.0, 0.0]).compose(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.3)),
        np.array([-0.05, -0.04, 0.6]) + rng.normal(size=3) * 0.02,
    ).matrix()
    M = T_x @ T_cam_board @ np.linalg.inv(T_board)  # T_cam_board = inv(T_x) M T_board
    T_base_end = mounting(mode).T_base_end_from_M(M)
    obj = np.c_[rng.uniform(0.0, 0.1, (7, 2)), np.zeros(7)]  # shape (7, 3)
    img = rng.uniform(0.0, 720.0, (7, 2))
    return T_x, T_board, T_base_end, obj, img


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_pose_jacobians_match_numerical_derivative_on_manifold(mode):
    rng = np.random.default_rng(1)
    T_x, T_board, T_robot, obj, img = _chain_setup(rng, mode)
    inv = mounting(mode).inverts_robot

    def res(Tx, Tr, Tb, k=K9):
        return chain_residual(
            T_x=Tx,
            T_base_end=Tr,
            T_board=Tb,
            invert_robot=inv,
            intrinsics_vec=k,
            object_points=obj,
            image_points=img,
            jacobians=False,
        )[0]

    _, J_x, J_r, J_b, J_k = chain_residual(
        T_x=T_x,
        T_base_end=T_robot,
        T_board=T_board,
        invert_robot=inv,
        intrinsics_vec=K9,
        object_points=obj,
        image_points=img,
    )
    num_x = numericalDerivative11(lambda P: res(P.matrix(), T_robot, T_board), gtsam.Pose3(T_x), delta=1e-6)
    num_r = numericalDerivative11(lambda P: res(T_x, P.matrix(), T_board), gtsam.Pose3(T_robot), delta=1e-6)
    num_b = numericalDerivative11(lambda P: res(T_x, T_robot, P.matrix()), gtsam.Pose3(T_board), delta=1e-6)
    num_k = numericalDerivative11(lambda k: res(T_x, T_robot, T_board, k), K9.copy(), delta=1e-7)
    for name, J, num in (("T_x", J_x, num_x), ("robot", J_r, num_r), ("board", J_b, num_b), ("intrinsics", J_k, num_k)):
        scale = np.abs(num).max()
        assert np.abs(J - num).max() <= 1e-6 * scale, f"{mode} Jacobian w.r.t. {name} differs from numerical"


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_stacked_residual_of_many_views_equals_the_per_view_chain(mode):
    """The numpy evaluation of every view at once (residuals and robot-pose Jacobians) is chain_residual
    view by view, to rounding; its robot Jacobian also matches a numerical derivative on the manifold."""
    rng = np.random.default_rng(7)
    inv = mounting(mode).inverts_robot
    T_x, T_board, _, obj, img = _chain_setup(rng, mode)
    setups = [_chain_setup(np.random.default_rng(20 + k), mode) for k in range(3)]
    # same T_x and board for all views: robot poses that put the board in front of the camera for each
    mount = mounting(mode)
    robots = np.stack(
        [
            mount.T_base_end_from_M(
                T_x @ np.linalg.inv(Tx_k) @ mount.M_from_T_base_end(Tr_k) @ Tb_k @ np.linalg.inv(T_board)
            )
            for Tx_k, Tb_k, Tr_k, _, _ in setups
        ]
    )
    counts = [7, 5, 6]
    objs = [np.c_[rng.uniform(0.0, 0.1, (c, 2)), np.zeros(c)] for c in counts]
    imgs = [rng.uniform(0.0, 720.0, (c, 2)) for c in counts]
    vi = np.repeat(np.arange(3), counts)
    shared = dict(T_x=T_x, T_board=T_board, invert_robot=inv, intrinsics_vec=K9)
    stacked = dict(shared, object_points=np.concatenate(objs), image_points=np.concatenate(imgs), view_index=vi)
    r, J = stacked_chain_residual(T_base_end=robots, robot_jacobian=True, **stacked)
    for k in range(3):
        r_k, _, J_r, _, _ = chain_residual(T_base_end=robots[k], object_points=objs[k], image_points=imgs[k], **shared)
        scale = np.abs(J_r).max()
        np.testing.assert_allclose(r[vi == k].reshape(-1), r_k, rtol=0, atol=1e-9)
        np.testing.assert_allclose(J[vi == k].reshape(-1, 6), J_r, rtol=0, atol=1e-12 * scale)
    num = numericalDerivative11(
        lambda P: stacked_chain_residual(T_base_end=np.stack([robots[0], robots[1], P.matrix()]), **stacked)[0][
            vi == 2
        ].reshape(-1),
        gtsam.Pose3(robots[2]),
        delta=1e-6,
    )
    assert np.abs(J[vi == 2].reshape(-1, 6) - num).max() <= 1e-6 * np.abs(num).max()
    # with every Jacobian (the refits' linearisation): chain_residual's, view by view, rows interleaved
    full = stacked_chain_jacobians(T_base_end=robots, **stacked)
    for k in range(3):
        per_view = chain_residual(T_base_end=robots[k], object_points=objs[k], image_points=imgs[k], **shared)
        rows = np.repeat(vi == k, 2)
        for stacked, own in zip(full, per_view, strict=True):
            np.testing.assert_allclose(stacked[rows], own, rtol=0, atol=1e-12 * max(np.abs(own).max(), 1.0))


def test_mode_adapters_are_the_generic_chain():
    rng = np.random.default_rng(2)
    for mode, fn, names in (
        ("eye_in_hand", eye_in_hand_residual, ("T_end_cam", "T_base_board")),
        ("eye_to_hand", eye_to_hand_residual, ("T_base_cam", "T_end_board")),
    ):
        T_x, T_board, T_robot, obj, img = _chain_setup(rng, mode)
        a = fn(
            **{names[0]: T_x, names[1]: T_board},
            T_base_end=T_robot,
            intrinsics_vec=K9,
            object_points=obj,
            image_points=img,
        )
        b = chain_residual(
            T_x=T_x,
            T_base_end=T_robot,
            T_board=T_board,
            invert_robot=mounting(mode).inverts_robot,
            intrinsics_vec=K9,
            object_points=obj,
            image_points=img,
        )
        for x, y in zip(a, b, strict=False):
            np.testing.assert_array_equal(x, y, err_msg=f"{mode} adapter differs from chain_residual")
        # the pixel prediction equals projecting inv(T_x) M T_board p with OpenCV
        M = mounting(mode).M_from_T_base_end(T_robot)
        T_cam_board = np.linalg.inv(T_x) @ M @ T_board
        rvec, _ = cv2.Rodrigues(T_cam_board[:3, :3])
        K = np.array([[K9[0], 0, K9[2]], [0, K9[1], K9[3]], [0, 0, 1]])
        uv_cv, _ = cv2.projectPoints(obj, rvec, T_cam_board[:3, 3], K, K9[4:])
        np.testing.assert_allclose(
            a[0],
            (uv_cv.reshape(-1, 2) - img).reshape(-1),
            atol=1e-9,
            err_msg=f"{mode}: projection differs from cv2.projectPoints (k3 != 0)",
        )


def test_projection_matches_gtsam_pinhole_cal3ds2_with_k3_zero():
    rng = np.random.default_rng(3)
    k = K9.copy()
    k[8] = 0.0
    cal = gtsam.Cal3DS2(k[0], k[1], 0.0, k[2], k[3], k[4], k[5], k[6], k[7])
    # eye-to-hand with T_base_end = T_end_board = I: the chain is inv(T_base_cam) p, a plain camera
    T_base_cam = gtsam.Pose3(gtsam.Rot3.Expmap([0.1, -0.2, 0.05]), [0.02, -0.01, -0.6]).matrix()
    pts = np.c_[rng.uniform(-0.1, 0.1, (9, 2)), rng.uniform(-0.05, 0.05, 9)]  # shape (9, 3)
    cam = gtsam.PinholeCameraCal3DS2(gtsam.Pose3(T_base_cam), cal)
    uv_ref = np.zeros((9, 2))
    Dpose_ref = np.zeros((18, 6))
    Dcal_ref = np.zeros((18, 9))
    for i, p in enumerate(pts):
        Dp, Dpt, Dc = np.zeros((2, 6), order="F"), np.zeros((2, 3), order="F"), np.zeros((2, 9), order="F")
        uv_ref[i] = cam.project(p, Dp, Dpt, Dc)
        Dpose_ref[2 * i : 2 * i + 2], Dcal_ref[2 * i : 2 * i + 2] = Dp, Dc
    r, J_x, _, _, J_k = eye_to_hand_residual(
        T_base_cam=T_base_cam,
        T_base_end=np.eye(4),
        T_end_board=np.eye(4),
        intrinsics_vec=k,
        object_points=pts,
        image_points=np.zeros((9, 2)),
    )
    np.testing.assert_allclose(r.reshape(-1, 2), uv_ref, atol=1e-9, err_msg="pixels differ from PinholeCameraCal3DS2")
    np.testing.assert_allclose(
        J_x,
        Dpose_ref,
        atol=1e-6 * np.abs(Dpose_ref).max(),
        err_msg="camera-pose Jacobian differs from GTSAM's project() Dpose",
    )
    # GTSAM's Cal3DS2 order: fx, fy, s, u0, v0, k1, k2, p1, p2
    np.testing.assert_allclose(
        J_k[:, :8],
        Dcal_ref[:, [0, 1, 3, 4, 5, 6, 7, 8]],
        atol=1e-6 * np.abs(Dcal_ref).max(),
        err_msg="intrinsics Jacobian differs from GTSAM's project() Dcal",
    )

    # and the whole factor against GenericProjectionFactorCal3DS2, one corner at a time
    key_x, key_b, key_k = 1, 2, 3
    values = gtsam.Values()
    values.insert(key_x, gtsam.Pose3(T_base_cam))
    values.insert(key_b, gtsam.Pose3())
    values.insert(key_k, k[:8].copy())
    meas = uv_ref + rng.normal(size=uv_ref.shape)
    f = view_reprojection_factor(
        mode="eye_to_hand",
        key_x=key_x,
        key_board=key_b,
        key_robot=None,
        key_intrinsics=key_k,
        object_points=pts,
        image_points=meas,
        sigma_px=0.5,
        intrinsics_vec=k,
        free_intrinsics=range(8),
        T_base_end=np.eye(4),
    )
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 0.5)
    landmark_key = 100
    total = 0.0
    for i, p in enumerate(pts):
        g = gtsam.GenericProjectionFactorCal3DS2(meas[i], noise, key_x, landmark_key, cal)
        vv = gtsam.Values()
        vv.insert(key_x, gtsam.Pose3(T_base_cam))
        vv.insert(landmark_key, p)
        total += g.error(vv)
    assert f.error(values) == pytest.approx(total, rel=1e-9), "view factor error differs from GTSAM's factors"


def test_custom_factor_linearization_equals_whitened_numpy_jacobians():
    rng = np.random.default_rng(4)
    mode = "eye_in_hand"
    T_x, T_board, T_robot, obj, img = _chain_setup(rng, mode)
    free = [0, 1, 2, 3, 4, 5, 8]  # p1, p2 fixed
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3(T_x))
    values.insert(1, gtsam.Pose3(T_board))
    values.insert(2, gtsam.Pose3(T_robot))
    values.insert(3, K9[free].copy())
    sigma = 0.3
    f = view_reprojection_factor(
        mode=mode,
        key_x=0,
        key_board=1,
        key_robot=2,
        key_intrinsics=3,
        object_points=obj,
        image_points=img,
        sigma_px=sigma,
        intrinsics_vec=K9,
        free_intrinsics=free,
    )
    A, b = f.linearize(values).jacobian()
    r, J_x, J_r, J_b, J_k = eye_in_hand_residual(
        T_end_cam=T_x, T_base_end=T_robot, T_base_board=T_board, intrinsics_vec=K9, object_points=obj, image_points=img
    )
    np.testing.assert_allclose(A, np.hstack([J_x, J_b, J_r, J_k[:, free]]) / sigma, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(b, -r / sigma, rtol=1e-12, atol=1e-9)
    assert f.error(values) == pytest.approx(0.5 * np.sum((r / sigma) ** 2), rel=1e-12)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_view_factor_cost_is_sum_of_per_corner_losses(loss):
    rng = np.random.default_rng(5)
    T_x, T_board, T_robot, obj, img = _chain_setup(rng, "eye_to_hand")
    r = eye_to_hand_residual(
        T_base_cam=T_x,
        T_base_end=T_robot,
        T_end_board=T_board,
        intrinsics_vec=K9,
        object_points=obj,
        image_points=img,
        jacobians=False,
    )[0]
    sigma, k = 40.0, 3.0
    s = np.linalg.norm(r.reshape(-1, 2), axis=1) / sigma
    if loss == "huber":
        rho = np.where(s <= k, 0.5 * s * s, k * s - 0.5 * k * k)
    else:
        rho = 0.5 * k * k * np.log1p((s / k) ** 2)
    values = gtsam.Values()
    for key, T in enumerate((T_x, T_board, T_robot)):
        values.insert(key, gtsam.Pose3(T))
    f = view_reprojection_factor(
        mode="eye_to_hand",
        key_x=0,
        key_board=1,
        key_robot=2,
        key_intrinsics=None,
        object_points=obj,
        image_points=img,
        sigma_px=sigma,
        intrinsics_vec=K9,
        loss=loss,
        loss_k=k,
    )
    assert (s > k).any() and (s < k).any(), "test needs corners on both sides of the threshold"
    assert f.error(values) == pytest.approx(rho.sum(), rel=1e-12)
    # IRLS weights: Huber = min(1, k/s), Cauchy = 1/(1+(s/k)^2)
    _, irls = corner_robust_scales(r, sigma_px=sigma, loss=loss, k=k)
    w = np.minimum(1.0, k / s) if loss == "huber" else 1.0 / (1.0 + (s / k) ** 2)
    np.testing.assert_allclose(irls**2, w, rtol=1e-12)


def test_robot_prior_error_is_log_of_relative_pose():
    rng = np.random.default_rng(6)
    T_rep = _random_pose(rng)
    xi = np.array([1e-3, -2e-3, 5e-4, 1e-3, 2e-4, -3e-4])
    T_true = gtsam.Pose3(T_rep).retract(xi)
    f = robot_pose_prior(key_robot=7, T_base_end_reported=T_rep, sigma_rot_rad=1e-3, sigma_trans_m=1e-4)
    v = gtsam.Values()
    v.insert(7, T_true)
    expected = 0.5 * np.sum((xi / np.array([1e-3] * 3 + [1e-4] * 3)) ** 2)
    assert f.error(v) == pytest.approx(expected, rel=1e-6)


def test_projection_shapes_and_no_jacobians():
    p = np.array([[0.0, 0.0, 1.0], [0.1, -0.1, 2.0]])
    uv, J_p, J_k = pixels_from_cam_points(K9, p)
    assert uv.shape == (2, 2) and J_p.shape == (2, 2, 3) and J_k.shape == (2, 2, 9)
    np.testing.assert_allclose(uv[0], K9[2:4])
    uv2, a, b = pixels_from_cam_points(K9, p, jacobians=False)
    assert a is None and b is None
    np.testing.assert_array_equal(uv, uv2)


def test_factor_rejects_missing_robot_pose_and_unknown_loss():
    obj, img = np.zeros((3, 3)), np.zeros((3, 2))
    with pytest.raises(ValueError, match="T_base_end is required"):
        view_reprojection_factor(
            mode="eye_in_hand",
            key_x=0,
            key_board=1,
            key_robot=None,
            key_intrinsics=None,
            object_points=obj,
            image_points=img,
            sigma_px=1.0,
            intrinsics_vec=K9,
        )
    with pytest.raises(ValueError, match="unknown loss"):
        corner_robust_scales(np.zeros(6), sigma_px=1.0, loss="tukey", k=3.0)
    with pytest.raises(ConfigError, match="unknown mounting mode"):
        view_reprojection_factor(
            mode="hand_in_eye",
            key_x=0,
            key_board=1,
            key_robot=2,
            key_intrinsics=None,
            object_points=obj,
            image_points=img,
            sigma_px=1.0,
            intrinsics_vec=K9,
        )
