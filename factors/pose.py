"""Pose factors: a tracker's measured ``T_cam_board`` against the one the hand-eye chain predicts.

The chain is ``T_cam_board_i = inv(T_x) · M_i · T_board`` (:mod:`handeye.mounting`). Residual (6,),
GTSAM's Pose3 tangent (rotation [rad] first, right perturbation):
``r_i = Log(inv(T_cam_board_measured_i) · T_cam_board_predicted_i)``. A tracker whose measured pose
is the true one times ``Exp(n)``, ``n ~ N(0, diag(s_rot^2 I3, s_trans^2 I3))``, gives ``r_i = -n`` at
the truth; for isotropic noise the frame of ``n`` does not matter. The residual and its Jacobians
are pure numpy (:func:`pose_residual`); :func:`pose_factor` is the thin ``CustomFactor`` wrapper.
With an arm's kinematic model the true flange pose is ``T_base_end_reported · Exp(J_dh · delta)``
(:mod:`handeye.refine.robot_model`): :func:`pose_robot_residual` and :func:`pose_dh_factor`.
A tracker whose translations are a factor ``s`` off (a wrong marker size, monocular SLAM) measures
``D_s(T_cam_board)``, its translation times ``s``: :func:`scaled_pose_residual` and
:func:`scaled_pose_factor` with ``log(s)`` as one more unknown.
"""

from __future__ import annotations

from typing import Optional

import gtsam
import numpy as np

from handeye.frames import inv_T, se3_adjoint, se3_exp, se3_log, skew

from .gtsam_factors import with_huber


def se3_ad(xi: np.ndarray) -> np.ndarray:
    """(6,6) the adjoint action ``ad(xi)`` of a tangent vector ``(omega, v)``: [[omega^, 0], [v^, omega^]]."""
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = skew(xi[:3])
    A[3:, :3] = skew(xi[3:])
    return A


def se3_right_jacobian_inverse(xi: np.ndarray) -> np.ndarray:
    """The inverse right Jacobian (6,6) of SE(3) by its series.

    (6,6) ``d Log(Exp(xi) · Exp(d)) / d d`` at ``d = 0`` (the inverse right Jacobian of SE(3)) by its
    series ``I + ad/2 + ad^2/12 - ad^4/720 + ad^6/30240`` (Bernoulli numbers); the first left-out term is
    ``ad^8/1209600``: below 1e-13 at |xi| = 0.1 (the residuals of a refinement), 1e-8 at |xi| = 0.5.
    """
    A = se3_ad(np.asarray(xi, float))
    A2 = A @ A
    A4 = A2 @ A2
    return np.eye(6) + 0.5 * A + A2 / 12.0 - A4 / 720.0 + A4 @ A2 / 30240.0


def pose_residual(
    *, T_x: np.ndarray, M: np.ndarray, T_board: np.ndarray, T_cam_board_measured: np.ndarray, jacobians: bool = True
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """Residual (6,) of one measured pose and, with ``jacobians``, its Jacobians.

    Residual (6,) of one measured pose and, with ``jacobians``, its Jacobians (6,6) in the right
    tangents of ``T_x`` and ``T_board``: (r, J_x, J_board) (Jacobians None without ``jacobians``).

    ``M`` is the view's robot motion (``inv(T_base_end)`` eye-in-hand, ``T_base_end`` eye-to-hand).
    ``T_x · Exp(xi)`` moves the prediction to ``Exp(-xi) · C = C · Exp(-Ad(inv(C)) xi)``;
    ``T_board · Exp(eta)`` to ``C · Exp(eta)``.
    """
    C = inv_T(T_x) @ M @ T_board
    r = se3_log(inv_T(T_cam_board_measured) @ C)
    if not jacobians:
        return r, None, None
    Jr_inv = se3_right_jacobian_inverse(r)
    return r, -Jr_inv @ se3_adjoint(inv_T(C)), Jr_inv


def scaled_pose_residual(
    *,
    T_x: np.ndarray,
    M: np.ndarray,
    T_board: np.ndarray,
    T_cam_board_measured: np.ndarray,
    log_scale: float,
    jacobians: bool = True,
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray]]:
    """Residual (6,) of one pose measured by a tracker whose translations are ``exp(log_scale)`` x the true.

    ``r = Log(inv(T_cam_board_measured) · D_s(inv(T_x) · M · T_board))`` with ``D_s`` scaling the
    translation by ``s = exp(log_scale)``; with ``jacobians`` also (J_x (6,6), J_board (6,6), J_log_scale
    (6,1)). ``D_s`` maps the right tangent ``(omega, v)`` of the prediction to ``(omega, s v)``, and
    ``log_scale + d`` moves the scaled prediction by ``(0, d · R^T s t)`` in its right tangent.
    """
    C = inv_T(T_x) @ M @ T_board
    s = float(np.exp(log_scale))
    C_s = C.copy()
    C_s[:3, 3] *= s
    r = se3_log(inv_T(T_cam_board_measured) @ C_s)
    if not jacobians:
        return r, None, None, None
    Jr_inv = se3_right_jacobian_inverse(r)
    D = np.diag(np.r_[1.0, 1.0, 1.0, s, s, s])
    J_board = Jr_inv @ D
    J_s = Jr_inv @ np.r_[0.0, 0.0, 0.0, C[:3, :3].T @ C_s[:3, 3]][:, None]
    return r, -J_board @ se3_adjoint(inv_T(C)), J_board, J_s


def scaled_pose_factor(
    *,
    key_x: int,
    key_board: int,
    key_log_scale: int,
    M: np.ndarray,
    T_cam_board_measured: np.ndarray,
    covariance: np.ndarray,
    robust_k: Optional[float] = None,
) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on (``T_x``, ``T_board``, ``log(s)`` a 1-vector) for one measured ``T_cam_board``.

    :func:`scaled_pose_residual` with the residual's ``covariance`` (6,6); ``robust_k``: a Huber loss.
    """
    M = np.array(M, float)
    C_meas = np.array(T_cam_board_measured, float)
    noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance, float))
    noise = with_huber(noise, robust_k)

    def error_func(this: gtsam.CustomFactor, v: gtsam.Values, H: Optional[list[np.ndarray]]) -> np.ndarray:
        r, J_x, J_b, J_s = scaled_pose_residual(
            T_x=v.atPose3(key_x).matrix(),
            M=M,
            T_board=v.atPose3(key_board).matrix(),
            T_cam_board_measured=C_meas,
            log_scale=float(v.atVector(key_log_scale)[0]),
            jacobians=H is not None,
        )
        if H is not None:
            H[0] = np.asfortranarray(J_x)
            H[1] = np.asfortranarray(J_b)
            H[2] = np.asfortranarray(J_s)
        return r

    return gtsam.CustomFactor(noise, [key_x, key_board, key_log_scale], error_func)


def pose_factor(
    *,
    key_x: int,
    key_board: int,
    M: np.ndarray,
    T_cam_board_measured: np.ndarray,
    sigma_rot_rad: Optional[float] = None,
    sigma_trans_m: Optional[float] = None,
    covariance: Optional[np.ndarray] = None,
    robust_k: Optional[float] = None,
) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on (``T_x``, ``T_board``) for one measured ``T_cam_board``.

    The tracker's noise: isotropic sigmas, or the residual's ``covariance`` (6,6) when given; ``robust_k``
    wraps it in a Huber loss at that many sigmas (on the whitened 6-vector).
    """
    M = np.array(M, float)
    C_meas = np.array(T_cam_board_measured, float)
    noise: gtsam.noiseModel.Base
    if covariance is not None:  # the residual's full covariance (a tracker noisier along its optical axis)
        noise = gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance, float))
    else:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sigma_rot_rad] * 3, [sigma_trans_m] * 3])
    noise = with_huber(noise, robust_k)

    def error_func(this: gtsam.CustomFactor, v: gtsam.Values, H: Optional[list[np.ndarray]]) -> np.ndarray:
        r, J_x, J_b = pose_residual(
            T_x=v.atPose3(key_x).matrix(),
            M=M,
            T_board=v.atPose3(key_board).matrix(),
            T_cam_board_measured=C_meas,
            jacobians=H is not None,
        )
        if H is not None:
            H[0] = np.asfortranarray(J_x)
            H[1] = np.asfortranarray(J_b)
        return r

    return gtsam.CustomFactor(noise, [key_x, key_board], error_func)


def se3_right_jacobian(xi: np.ndarray) -> np.ndarray:
    """(6,6) the right Jacobian of SE(3): ``Exp(xi + d) = Exp(xi) · Exp(Jr(xi) d)`` to first order."""
    return np.linalg.inv(se3_right_jacobian_inverse(xi))


def pose_robot_residual(
    *,
    T_x: np.ndarray,
    T_base_end: np.ndarray,
    u: np.ndarray,
    T_board: np.ndarray,
    T_cam_board_measured: np.ndarray,
    inverts_robot: bool,
    jacobians: bool = True,
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray]]:
    """Residual (6,) of one measured pose whose true flange pose is ``T_base_end · Exp(u)``, and its Jacobians.

    (r, J_x, J_board, J_u), the Jacobians (6,6) in the right tangents of ``T_x``, ``T_board`` and in ``u``
    (None without ``jacobians``). ``inverts_robot``: ``M = inv(T_base_end)`` (eye-in-hand), else
    ``M = T_base_end``. A flange error ``w`` moves the chain as ``T_x · Exp(Ad(inv(T_x)) w)`` does
    eye-in-hand (``inv(T_x) · Exp(-w) = Exp(-Ad(inv(T_x)) w) · inv(T_x)``) and as
    ``T_board · Exp(Ad(inv(T_board)) w)`` eye-to-hand; ``d w = Jr(u) d u``.
    """
    u = np.asarray(u, float)
    T_true = np.asarray(T_base_end, float) @ se3_exp(u)
    M = inv_T(T_true) if inverts_robot else T_true
    r, J_x, J_b = pose_residual(
        T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=T_cam_board_measured, jacobians=jacobians
    )
    if not jacobians:
        return r, None, None, None
    assert J_x is not None and J_b is not None, "pose_residual gives Jacobians when asked"
    J_w = J_x @ se3_adjoint(inv_T(T_x)) if inverts_robot else J_b @ se3_adjoint(inv_T(T_board))
    return r, J_x, J_b, J_w @ se3_right_jacobian(u)


def pose_dh_factor(
    *,
    key_x: int,
    key_board: int,
    key_dh: int,
    T_base_end: np.ndarray,
    J_dh: np.ndarray,
    inverts_robot: bool,
    T_cam_board_measured: np.ndarray,
    covariance: np.ndarray,
    robust_k: Optional[float] = None,
) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on (``T_x``, ``T_board``, the DH offsets) for one measured ``T_cam_board``.

    The true flange pose is ``T_base_end · Exp(J_dh · delta)`` (``J_dh`` (6,m): the view's Jacobian of the
    flange tangent in the arm's DH offsets ``delta``); ``covariance`` (6,6): the residual's, the tracker's
    noise and the encoder noise through the chain together; ``robust_k`` as for :func:`pose_factor`.
    """
    T_be = np.array(T_base_end, float)
    J_dh = np.array(J_dh, float)
    C_meas = np.array(T_cam_board_measured, float)
    noise: gtsam.noiseModel.Base = gtsam.noiseModel.Gaussian.Covariance(np.asarray(covariance, float))
    noise = with_huber(noise, robust_k)

    def error_func(this: gtsam.CustomFactor, v: gtsam.Values, H: Optional[list[np.ndarray]]) -> np.ndarray:
        r, J_x, J_b, J_u = pose_robot_residual(
            T_x=v.atPose3(key_x).matrix(),
            T_base_end=T_be,
            u=J_dh @ np.asarray(v.atVector(key_dh), float),
            T_board=v.atPose3(key_board).matrix(),
            T_cam_board_measured=C_meas,
            inverts_robot=inverts_robot,
            jacobians=H is not None,
        )
        if H is not None:
            assert J_x is not None and J_b is not None and J_u is not None, "asked for the Jacobians"
            H[0] = np.asfortranarray(J_x)
            H[1] = np.asfortranarray(J_b)
            H[2] = np.asfortranarray(J_u @ J_dh)
        return r

    return gtsam.CustomFactor(noise, [key_x, key_board, key_dh], error_func)
