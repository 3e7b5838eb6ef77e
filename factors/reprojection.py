"""Reprojection residual of board corners through the hand-eye chain, with analytic Jacobians.

Pure numpy, vectorised over all corners of one view. Both mounting modes are the one chain of
:mod:`handeye.model`::

    T_cam_board_i = A · M_i · B,      A = inv(T_x)

==============  ==============  =========================  ==============
mode            T_x (variable)  M_i from robot variable    B (variable)
==============  ==============  =========================  ==============
eye_in_hand     T_end_cam       inv(T_base_end_i)          T_base_board
eye_to_hand     T_base_cam      T_base_end_i               T_end_board
==============  ==============  =========================  ==============

so :func:`chain_residual` takes the three variables as they are stored (``T_x``, the robot pose
``T_base_end`` and ``T_board``) plus ``invert_robot`` and is wrapped by two thin adapters.

Conventions
-----------
* Pixels: OpenCV's 5-coefficient model, intrinsics vector ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)``.
* Residual: ``predicted - measured`` in pixels, interleaved ``(u0, v0, u1, v1, ...)``, shape (2N,).
* Pose Jacobians follow GTSAM's Pose3 tangent: ``xi = (omega, v)``, rotation first, right
  perturbation ``T · Exp(xi)``. Exp(xi) acts on a point as ``p + omega x p + v`` to first order, so
  ``d(T Exp(xi) p)/dxi = R · [-[p]x, I]`` and, for a variable that enters inverted,
  ``d(inv(T Exp(xi)) p)/dxi = [[q]x, -I]`` with ``q = inv(T) p``.

Points behind the camera (z <= 0) give finite but meaningless residuals; the caller decides.
"""
from __future__ import annotations

import numpy as np

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
MODE_INVERTS_ROBOT = {"eye_in_hand": True, "eye_to_hand": False}


def pixels_from_cam_points(intrinsics_vec: np.ndarray, p_cam: np.ndarray, *, jacobians: bool = True):
    """Project camera-frame points (N,3) with OpenCV's 5-coefficient model.

    Returns ``(uv, J_uv_p, J_uv_intr)``: pixels (N,2), d uv / d p_cam (N,2,3) and
    d uv / d intrinsics (N,2,9); the Jacobians are None when ``jacobians`` is False.
    """
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = np.asarray(intrinsics_vec, float)
    X, Y, Z = p_cam[:, 0], p_cam[:, 1], p_cam[:, 2]
    iz = 1.0 / Z
    x, y = X * iz, Y * iz
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    r4 = r2 * r2
    r6 = r4 * r2
    radial = 1.0 + k1 * r2 + k2 * r4 + k3 * r6
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx)
    yd = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy
    uv = np.empty((p_cam.shape[0], 2))
    uv[:, 0] = fx * xd + cx
    uv[:, 1] = fy * yd + cy
    if not jacobians:
        return uv, None, None

    n = p_cam.shape[0]
    c = 2.0 * (k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4)  # d radial / d r2, times 2
    dxd_dx = radial + c * xx + 2.0 * p1 * y + 6.0 * p2 * x
    dxd_dy = c * xy + 2.0 * p1 * x + 2.0 * p2 * y
    dyd_dy = radial + c * yy + 6.0 * p1 * y + 2.0 * p2 * x
    # d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]
    J_p = np.empty((n, 2, 3))
    a, b, d = fx * dxd_dx * iz, fx * dxd_dy * iz, fy * dxd_dy * iz
    e = fy * dyd_dy * iz
    J_p[:, 0, 0] = a
    J_p[:, 0, 1] = b
    J_p[:, 0, 2] = -(a * x + b * y)
    J_p[:, 1, 0] = d
    J_p[:, 1, 1] = e
    J_p[:, 1, 2] = -(d * x + e * y)

    J_k = np.zeros((n, 2, 9))
    J_k[:, 0, 0] = xd
    J_k[:, 1, 1] = yd
    J_k[:, 0, 2] = 1.0
    J_k[:, 1, 3] = 1.0
    J_k[:, 0, 4] = fx * x * r2
    J_k[:, 1, 4] = fy * y * r2
    J_k[:, 0, 5] = fx * x * r4
    J_k[:, 1, 5] = fy * y * r4
    J_k[:, 0, 6] = fx * 2.0 * xy
    J_k[:, 1, 6] = fy * (r2 + 2.0 * yy)
    J_k[:, 0, 7] = fx * (r2 + 2.0 * xx)
    J_k[:, 1, 7] = fy * 2.0 * xy
    J_k[:, 0, 8] = fx * x * r6
    J_k[:, 1, 8] = fy * y * r6
    return uv, J_p, J_k


def _pose_jac(G: np.ndarray, q: np.ndarray, *, inverted: bool) -> np.ndarray:
    """Stack (N,2,6) from G = d uv/d(point after the perturbed transform, in its own frame) (N,2,3).

    Non-inverted: ``G · [-[q]x, I]``  (row a: a^T (-[q]x) = (q x a)^T);
    inverted:     ``G · [[q]x, -I]``  (row a: a^T [q]x = (a x q)^T).
    """
    J = np.empty(G.shape[:2] + (6,))
    qb = q[:, None, :]
    if inverted:
        J[..., :3] = np.cross(G, qb)
        J[..., 3:] = -G
    else:
        J[..., :3] = np.cross(qb, G)
        J[..., 3:] = G
    return J


def chain_residual(*, T_x: np.ndarray, T_base_end: np.ndarray, T_board: np.ndarray, invert_robot: bool,
                   intrinsics_vec: np.ndarray, object_points: np.ndarray, image_points: np.ndarray,
                   jacobians: bool = True):
    """Reprojection residual of one view through ``inv(T_x) · M · T_board``.

    ``M = inv(T_base_end)`` when ``invert_robot`` (eye-in-hand) else ``T_base_end`` (eye-to-hand).
    object_points (N,3) in the board frame, image_points (N,2) measured pixels.

    Returns ``(residual, J_x, J_robot, J_board, J_intr)``: residual (2N,) = predicted - measured and
    Jacobians (2N,6), (2N,6), (2N,6), (2N,9) w.r.t. right perturbations of ``T_x``, ``T_base_end``
    and ``T_board`` (GTSAM Pose3 tangent) and the 9 intrinsics; the Jacobians are None when
    ``jacobians`` is False.
    """
    R_x, t_x = T_x[:3, :3], T_x[:3, 3]
    R_A, t_A = R_x.T, -R_x.T @ t_x  # A = inv(T_x) = T_cam_<fixed>
    if invert_robot:
        R_r, t_r = T_base_end[:3, :3], T_base_end[:3, 3]
        R_M, t_M = R_r.T, -R_r.T @ t_r
    else:
        R_M, t_M = T_base_end[:3, :3], T_base_end[:3, 3]
    R_B, t_B = T_board[:3, :3], T_board[:3, 3]
    q_b = object_points @ R_B.T + t_B  # shape (N, 3): corners in the frame B maps into
    q_m = q_b @ R_M.T + t_M  # shape (N, 3): corners in the frame A maps from
    p_c = q_m @ R_A.T + t_A  # shape (N, 3): corners in the camera frame
    uv, J_p, J_k = pixels_from_cam_points(intrinsics_vec, p_c, jacobians=jacobians)
    residual = (uv - image_points).reshape(-1)
    if not jacobians:
        return residual, None, None, None, None

    n2 = residual.size
    J_x = _pose_jac(J_p, p_c, inverted=True)  # A = inv(T_x)
    G_A = J_p @ R_A  # shape (N, 2, 3)
    if invert_robot:  # M = inv(T_base_end): perturbation sits after A
        J_r = _pose_jac(G_A, q_m, inverted=True)
    else:  # M = T_base_end: perturbation sits after A · M
        J_r = _pose_jac(G_A @ R_M, q_b, inverted=False)
    J_b = _pose_jac(G_A @ (R_M @ R_B), object_points, inverted=False)
    return residual, J_x.reshape(n2, 6), J_r.reshape(n2, 6), J_b.reshape(n2, 6), J_k.reshape(n2, 9)


def eye_in_hand_residual(*, T_end_cam, T_base_end, T_base_board, intrinsics_vec, object_points, image_points,
                         jacobians: bool = True):
    """pixel = project(K, inv(T_base_end · T_end_cam) · T_base_board · p); see :func:`chain_residual`."""
    return chain_residual(T_x=T_end_cam, T_base_end=T_base_end, T_board=T_base_board, invert_robot=True,
                          intrinsics_vec=intrinsics_vec, object_points=object_points,
                          image_points=image_points, jacobians=jacobians)


def eye_to_hand_residual(*, T_base_cam, T_base_end, T_end_board, intrinsics_vec, object_points, image_points,
                         jacobians: bool = True):
    """pixel = project(K, inv(T_base_cam) · T_base_end · T_end_board · p); see :func:`chain_residual`."""
    return chain_residual(T_x=T_base_cam, T_base_end=T_base_end, T_board=T_end_board, invert_robot=False,
                          intrinsics_vec=intrinsics_vec, object_points=object_points,
                          image_points=image_points, jacobians=jacobians)


# ------------------------------------------------------------------------------ robust losses
LOSSES = ("none", "huber", "cauchy")


def corner_robust_scales(residual: np.ndarray, *, sigma_px: float, loss: str, k: float):
    """Per-corner factors that turn a (2N,) residual into a robust one, inside one view factor.

    With ``s = |e_corner| / sigma_px`` and the loss rho(s) (Huber or Cauchy with threshold ``k`` in
    sigmas), returns ``(cost_scale, irls_scale)``, both (N,):

    * ``cost_scale = sqrt(2 rho(s)) / s`` makes ``0.5 |scaled e / sigma|^2 = sum rho`` (the cost
      GTSAM compares between iterations);
    * ``irls_scale = sqrt(rho'(s) / s)`` scales residual and Jacobian rows for the linear step,
      exactly what GTSAM's ``noiseModel.Robust`` does for one whole factor, here per corner.
    """
    n = residual.size // 2
    if loss == "none":
        one = np.ones(n)
        return one, one
    e = residual.reshape(n, 2)
    s = np.sqrt(np.einsum("ij,ij->i", e, e)) / sigma_px
    s_safe = np.maximum(s, 1e-12)
    if loss == "huber":
        big = s > k
        rho2 = np.where(big, 2.0 * k * s - k * k, s * s)
        w = np.where(big, k / s_safe, 1.0)
    elif loss == "cauchy":
        rho2 = k * k * np.log1p((s / k) ** 2)
        w = 1.0 / (1.0 + (s / k) ** 2)
    else:
        raise ValueError(f"unknown loss {loss!r}; expected one of {LOSSES}")
    cost_scale = np.where(s > 1e-12, np.sqrt(rho2) / s_safe, 1.0)
    return cost_scale, np.sqrt(w)
