"""Thin GTSAM wrappers around :mod:`.reprojection`: one ``CustomFactor`` per view, not per corner.

Variables (keys chosen by the caller): ``key_x`` (Pose3 ``T_x``), ``key_board`` (Pose3 ``T_board``),
``key_robot`` (Pose3, the view's true ``T_base_end``, or None to hold the reported pose) and
``key_intrinsics`` (a Vector of the free intrinsics in ``INTRINSIC_NAMES`` order; GTSAM's Cal3DS2 has
no k3). Pixel noise is isotropic ``sigma_px``, with an optional per-corner robust loss
(:func:`.reprojection.corner_robust_scales`).

See docs/refinement.md.
"""

from __future__ import annotations

from typing import Optional, Sequence

import gtsam
import numpy as np

from handeye.mounting import mounting

from .reprojection import chain_residual, corner_robust_scales


def with_huber(noise: gtsam.noiseModel.Base, robust_k: Optional[float]) -> gtsam.noiseModel.Base:
    """``noise`` in a Huber loss at ``robust_k`` whitened units (on the whitened vector's norm), as is when None."""
    if robust_k is None:
        return noise
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(robust_k)), noise)


def view_reprojection_factor(
    *,
    mode: str,
    key_x: int,
    key_board: int,
    key_robot: Optional[int],
    key_intrinsics: Optional[int],
    object_points: np.ndarray,
    image_points: np.ndarray,
    sigma_px: float,
    intrinsics_vec: np.ndarray,
    free_intrinsics: Sequence[int] | np.ndarray = (),
    T_base_end: Optional[np.ndarray] = None,
    loss: str = "none",
    loss_k: float = 3.0,
) -> gtsam.CustomFactor:
    """A ``CustomFactor`` for all corners of one view.

    ``intrinsics_vec`` (9,) holds the values of the fixed intrinsics (and the start of the free
    ones, which the variable overrides); ``free_intrinsics`` lists the indices the variable holds.
    ``T_base_end`` is required when ``key_robot`` is None (robot pose taken as exact).
    """
    invert_robot = mounting(mode).inverts_robot
    obj = np.ascontiguousarray(object_points, dtype=float)  # shape (N, 3)
    img = np.ascontiguousarray(image_points, dtype=float)  # shape (N, 2)
    n2 = 2 * obj.shape[0]
    free = np.asarray(free_intrinsics, dtype=int)
    if key_intrinsics is not None and free.size == 0:
        raise ValueError("key_intrinsics given but no free intrinsics")
    base_k = np.array(intrinsics_vec, dtype=float)
    if key_robot is None:
        if T_base_end is None:
            raise ValueError("T_base_end is required when the robot pose is not a variable")
        T_robot_fixed = np.array(T_base_end, dtype=float)

    keys = [key_x, key_board]
    if key_robot is not None:
        keys.append(key_robot)
    if key_intrinsics is not None:
        keys.append(key_intrinsics)
    # Jacobian buffers, Fortran order for Eigen; GTSAM copies them after the callback returns.
    H_x = np.zeros((n2, 6), order="F")
    H_b = np.zeros((n2, 6), order="F")
    H_r = np.zeros((n2, 6), order="F")
    H_k = np.zeros((n2, free.size), order="F")
    k_work = base_k.copy()

    def error_func(this: gtsam.CustomFactor, v: gtsam.Values, H: Optional[list[np.ndarray]]) -> np.ndarray:
        T_x = v.atPose3(key_x).matrix()
        T_board = v.atPose3(key_board).matrix()
        T_robot = v.atPose3(key_robot).matrix() if key_robot is not None else T_robot_fixed
        if key_intrinsics is not None:
            k_work[free] = v.atVector(key_intrinsics)
        want = H is not None
        r, J_x, J_r, J_b, J_k = chain_residual(
            T_x=T_x,
            T_base_end=T_robot,
            T_board=T_board,
            invert_robot=invert_robot,
            intrinsics_vec=k_work,
            object_points=obj,
            image_points=img,
            jacobians=want,
        )
        w = None
        if loss != "none":
            cost_scale, irls_scale = corner_robust_scales(r, sigma_px=sigma_px, loss=loss, k=loss_k)
            if not want:
                return r * np.repeat(cost_scale, 2)
            w = np.repeat(irls_scale, 2)[:, None]
        elif not want:
            return r
        assert H is not None and J_x is not None and J_b is not None, "Jacobians asked for and computed"
        blocks = [(H_x, J_x), (H_b, J_b)]
        if key_robot is not None:
            assert J_r is not None, "Jacobians asked for and computed"
            blocks.append((H_r, J_r))
        if key_intrinsics is not None:
            assert J_k is not None, "Jacobians asked for and computed"
            blocks.append((H_k, J_k[:, free]))
        for i, (buf, J) in enumerate(blocks):
            if w is None:
                buf[...] = J
            else:
                np.multiply(J, w, out=buf)
            H[i] = buf
        return r if w is None else r * w[:, 0]

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(n2, float(sigma_px)), keys, error_func)


def robot_pose_prior(
    *,
    key_robot: int,
    T_base_end_reported: np.ndarray,
    sigma_rot_rad: float,
    sigma_trans_m: float,
    robust_k: Optional[float] = None,
) -> gtsam.NonlinearFactor:
    """Prior tying the true robot pose variable to the reported one (GTSAM's PriorFactorPose3).

    The error is ``Log(inv(reported) · T_base_end)``: rotation (rad) then translation (m), both in
    the end frame. ``robust_k`` wraps it in a Huber loss on the whitened 6-vector norm.
    """
    sig = np.array([sigma_rot_rad] * 3 + [sigma_trans_m] * 3, dtype=float)
    noise: gtsam.noiseModel.Base = gtsam.noiseModel.Diagonal.Sigmas(sig)
    noise = with_huber(noise, robust_k)
    return gtsam.PriorFactorPose3(key_robot, gtsam.Pose3(np.asarray(T_base_end_reported, float)), noise)


def intrinsics_prior(*, key_intrinsics: int, prior_values: np.ndarray, sigmas: np.ndarray) -> gtsam.NonlinearFactor:
    """Gaussian prior on the free-intrinsics vector (same order and length as the variable)."""
    return gtsam.PriorFactorVector(
        key_intrinsics, np.asarray(prior_values, float), gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float))
    )


def gaussian_prior(*, key: int, mean: np.ndarray, cov: np.ndarray) -> gtsam.NonlinearFactor:
    """Gaussian prior with a full covariance on a Pose3.

    Gaussian prior with a full covariance on a Pose3 (``mean`` (4,4); ``cov`` (6,6) in its right
    tangent, rotation first: error ``Log(inv(mean) · T)``) or on a Vector (``mean`` (k,), ``cov`` (k,k)).
    """
    mean = np.asarray(mean, float)
    noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, float))
    if mean.shape == (4, 4):
        return gtsam.PriorFactorPose3(key, gtsam.Pose3(mean), noise)
    return gtsam.PriorFactorVector(key, mean, noise)


def joint_gaussian_prior(
    *, key_pose: int, key_vector: int, mean_pose: np.ndarray, mean_vector: np.ndarray, cov: np.ndarray
) -> gtsam.NonlinearFactor:
    """Gaussian prior on a Pose3 and a Vector together, with their cross-covariance.

    Gaussian prior on a Pose3 and a Vector together, with their cross-covariance (e.g. an earlier calibration's
    T_x and intrinsics, whose errors are correlated): error ``(Log(inv(mean_pose) · T), v - mean_vector)``
    (6 + k,) ~ N(0, ``cov``), the pose's block in its right tangent, rotation first.
    """
    mean_inv = gtsam.Pose3(np.asarray(mean_pose, float)).inverse()
    m = np.asarray(mean_vector, float)
    k = m.size
    noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, float))
    H_v = np.asfortranarray(np.vstack([np.zeros((6, k)), np.eye(k)]))

    def error_func(this: gtsam.CustomFactor, v: gtsam.Values, H: Optional[list[np.ndarray]]) -> np.ndarray:
        D = mean_inv.compose(v.atPose3(key_pose))
        if H is not None:
            H[0] = np.asfortranarray(np.vstack([gtsam.Pose3.LogmapDerivative(D), np.zeros((k, 6))]))
            H[1] = H_v
        return np.concatenate([gtsam.Pose3.Logmap(D), np.asarray(v.atVector(key_vector), float) - m])

    return gtsam.CustomFactor(noise, [key_pose, key_vector], error_func)


def kinematic_robot_prior(
    *,
    key_robot: int,
    key_dh: Optional[int],
    T_base_end_reported: np.ndarray,
    J_dh: np.ndarray,
    cov: np.ndarray,
    robust_k: Optional[float] = None,
) -> gtsam.NonlinearFactor:
    """Prior of the kinematic robot error model.

    Prior of the kinematic robot error model (:mod:`handeye.refine.robot_model`) tying the true robot
    pose to the reported one and the arm's DH offsets: error ``Log(inv(reported) · T_base_end) - J_dh · delta``
    (6,) (rotation then translation, end frame) ~ N(0, ``cov``), with ``delta`` the Vector at ``key_dh``
    (m,). ``key_dh`` None: no DH offsets (the joint-space model), a PriorFactorPose3 with covariance
    ``cov``. ``robust_k`` wraps it in a Huber loss on the whitened 6-vector norm.
    """
    noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov, float))
    noise = with_huber(noise, robust_k)
    if key_dh is None:
        return gtsam.PriorFactorPose3(key_robot, gtsam.Pose3(np.asarray(T_base_end_reported, float)), noise)
    reported_inv = gtsam.Pose3(np.asarray(T_base_end_reported, float)).inverse()
    J = np.asarray(J_dh, float)
    H_dh = np.asfortranarray(-J)

    def error_func(this: gtsam.CustomFactor, v: gtsam.Values, H: Optional[list[np.ndarray]]) -> np.ndarray:
        D = reported_inv.compose(v.atPose3(key_robot))
        r = gtsam.Pose3.Logmap(D) - J @ v.atVector(key_dh)
        if H is not None:
            H[0] = np.asfortranarray(gtsam.Pose3.LogmapDerivative(D))
            H[1] = H_dh
        return r

    return gtsam.CustomFactor(noise, [key_robot, key_dh], error_func)
