"""Reprojection residual of board corners through the hand-eye chain, with analytic Jacobians.

Pure numpy, vectorised over the corners of one view. Both mounting modes are the one chain
``T_cam_board_i = inv(T_x) · M_i · B`` of :mod:`handeye.mounting`: :func:`chain_residual` takes
``T_x``, the robot pose ``T_base_end`` and ``T_board`` plus ``invert_robot``. Pixels follow OpenCV's
5-coefficient model; the residual is ``predicted - measured``, interleaved, shape (2N,); pose
Jacobians use GTSAM's Pose3 tangent (rotation first, right perturbation).

See docs/refinement.md.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from handeye.camera import project_opencv5


def _pose_jacobians_T(G: np.ndarray, Q: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """Pose Jacobians of k transforms at once, transposed: (k, 6, 2N).

    ``G`` (k, 3, 2N): (d uv / d point)^T, the point taken just after the perturbed transform in the
    transform's own frame; ``Q`` (k, 3, 2N): that point (repeated for u and v); ``sign`` (k,):
    +1 for a transform used as is (``d/dxi = [-[q]x, I]``), -1 for one used inverted
    (``[[q]x, -I]``). Row a of G gives rotation part ``sign · (q x a)`` and translation ``sign · a``.
    """
    J = np.empty((G.shape[0], 6, G.shape[2]))
    s = sign[:, None]
    J[:, 0] = s * (Q[:, 1] * G[:, 2] - Q[:, 2] * G[:, 1])
    J[:, 1] = s * (Q[:, 2] * G[:, 0] - Q[:, 0] * G[:, 2])
    J[:, 2] = s * (Q[:, 0] * G[:, 1] - Q[:, 1] * G[:, 0])
    J[:, 3:] = s[:, None] * G
    return J


_SIGN_ALL = {True: np.array([-1.0, -1.0, 1.0]), False: np.array([-1.0, 1.0, 1.0])}  # (T_x, robot, board)
_SIGN_ROBOT = {True: np.array([-1.0]), False: np.array([1.0])}


def chain_residual(
    *,
    T_x: np.ndarray,
    T_base_end: np.ndarray,
    T_board: np.ndarray,
    invert_robot: bool,
    intrinsics_vec: np.ndarray,
    object_points: np.ndarray,
    image_points: np.ndarray,
    jacobians: bool = True,
    robot_only: bool = False,
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray]]:
    """Reprojection residual of one view through ``inv(T_x) · M · T_board``.

    ``M = inv(T_base_end)`` when ``invert_robot`` (eye-in-hand) else ``T_base_end`` (eye-to-hand).
    object_points (N,3) in the board frame, image_points (N,2) measured pixels.

    Returns ``(residual, J_x, J_robot, J_board, J_intr)``: residual (2N,) = predicted - measured and
    Jacobians (2N,6), (2N,6), (2N,6), (2N,9) (Fortran-ordered) w.r.t. right perturbations of
    ``T_x``, ``T_base_end`` and ``T_board`` (GTSAM Pose3 tangent) and the 9 intrinsics; the Jacobians
    are None when ``jacobians`` is False. ``robot_only`` computes only ``J_robot`` (the others are
    None), for fitting one view's pose with everything else held.
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
    uv, Jp_T, Jk_T = project_opencv5(intrinsics_vec, p_c, jacobians)
    residual = (uv - image_points).reshape(-1)
    if not jacobians:
        return residual, None, None, None, None
    assert Jp_T is not None and Jk_T is not None, "Jacobians asked for and computed"

    G_A = R_A.T @ Jp_T  # (J_p · R_A)^T, shape (3, 2N)
    # the point just after the robot perturbation: q_m if M = inv(T_base_end), else q_b (after A·M)
    G_r, q_r = (G_A, q_m) if invert_robot else (R_M.T @ G_A, q_b)
    if robot_only:
        J = _pose_jacobians_T(G_r[None], np.repeat(q_r.T, 2, axis=1)[None], _SIGN_ROBOT[invert_robot])
        return residual, None, J[0].T, None, None
    G_b = (R_M @ R_B).T @ G_A
    G = np.stack([Jp_T, G_r, G_b])  # shape (3, 3, 2N)
    Q = np.repeat(np.stack([p_c.T, q_r.T, object_points.T]), 2, axis=2)  # shape (3, 3, 2N)
    J = _pose_jacobians_T(G, Q, _SIGN_ALL[invert_robot])
    return residual, J[0].T, J[1].T, J[2].T, Jk_T.T


def _stacked_points(
    T_x: np.ndarray,
    T_base_end: np.ndarray,
    T_board: np.ndarray,
    invert_robot: bool,
    object_points: np.ndarray,
    view_index: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The stacked corners along the chain: ``(R_A (3,3), R_M (M,3,3), q_b, q_m, p_c (M,3))``.

    ``R_A`` turns the middle frame into the camera's (the inverse of X), ``R_M`` is each corner's robot rotation
    as the chain uses it (inverted for ``invert_robot``), ``q_b`` / ``q_m`` / ``p_c`` the corner in the board's
    parent frame, after the robot pose and in the camera frame.
    """
    T_base_end = np.asarray(T_base_end, float)
    R_x, t_x = T_x[:3, :3], T_x[:3, 3]
    R_A, t_A = R_x.T, -R_x.T @ t_x
    R_r, t_r = T_base_end[:, :3, :3], T_base_end[:, :3, 3]
    if invert_robot:
        R_M = np.swapaxes(R_r, 1, 2)
        t_M = -np.einsum("nij,nj->ni", R_M, t_r)
    else:
        R_M, t_M = R_r, t_r
    R_M, t_M = R_M[view_index], t_M[view_index]  # shape (M, 3, 3), (M, 3)
    q_b = object_points @ T_board[:3, :3].T + T_board[:3, 3]  # shape (M, 3)
    q_m = np.einsum("mij,mj->mi", R_M, q_b) + t_M
    p_c = q_m @ R_A.T + t_A
    return R_A, R_M, q_b, q_m, p_c


def stacked_chain_residual(
    *,
    T_x: np.ndarray,
    T_base_end: np.ndarray,
    T_board: np.ndarray,
    invert_robot: bool,
    intrinsics_vec: np.ndarray,
    object_points: np.ndarray,
    image_points: np.ndarray,
    view_index: np.ndarray,
    robot_jacobian: bool = False,
) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """:func:`chain_residual` of many views at once, for the numpy parts of the refinement (no GTSAM).

    The corners of all views are stacked: ``object_points`` (M,3), ``image_points`` (M,2) and
    ``view_index`` (M,) the view of each corner, an index into ``T_base_end`` (n,4,4) (one robot
    pose per view); ``T_x`` and ``T_board`` are shared. Returns ``(residual (M,2), J_robot)``:
    ``predicted - measured`` per corner and, with ``robot_jacobian``, d residual / d xi (M,2,6) for
    a right perturbation of the corner's own robot pose (rotation first), else None.
    """
    R_A, R_M, q_b, q_m, p_c = _stacked_points(T_x, T_base_end, T_board, invert_robot, object_points, view_index)
    uv, Jp_T, _ = project_opencv5(intrinsics_vec, p_c, robot_jacobian)
    residual = uv - image_points
    if not robot_jacobian:
        return residual, None
    m = p_c.shape[0]
    G = (R_A.T @ Jp_T).reshape(3, m, 2)  # (d uv / d q_m)^T: [component, corner, u|v]
    if invert_robot:  # the point just after the perturbed (inverted) robot pose: q_m
        q, sign = q_m.T[:, :, None], -1.0
    else:  # T_base_end used as is: the point before it, q_b, and G through R_M
        G = np.einsum("mji,jmc->imc", R_M, G)
        q, sign = q_b.T[:, :, None], 1.0
    J = np.empty((m, 2, 6))
    J[:, :, 0] = sign * (q[1] * G[2] - q[2] * G[1])
    J[:, :, 1] = sign * (q[2] * G[0] - q[0] * G[2])
    J[:, :, 2] = sign * (q[0] * G[1] - q[1] * G[0])
    J[:, :, 3:] = sign * np.moveaxis(G, 0, -1)
    return residual, J


def stacked_chain_jacobians(
    *,
    T_x: np.ndarray,
    T_base_end: np.ndarray,
    T_board: np.ndarray,
    invert_robot: bool,
    intrinsics_vec: np.ndarray,
    object_points: np.ndarray,
    image_points: np.ndarray,
    view_index: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`chain_residual` of many views at once with every Jacobian (the layout of :func:`stacked_chain_residual`).

    Returns ``(residual (2M,), J_x (2M,6), J_robot (2M,6), J_board (2M,6), J_intr (2M,9))``, rows interleaved
    (u0, v0, u1, ...) in corner order, ``J_robot`` with respect to each corner's own robot pose.
    """
    R_A, R_Mc, q_b, q_m, p_c = _stacked_points(T_x, T_base_end, T_board, invert_robot, object_points, view_index)
    R_B = T_board[:3, :3]
    uv, Jp_T, Jk_T = project_opencv5(intrinsics_vec, p_c, True)
    assert Jp_T is not None and Jk_T is not None, "Jacobians asked for and computed"
    m = p_c.shape[0]
    G_A = (R_A.T @ Jp_T).reshape(3, m, 2)  # (d uv / d q_m)^T: [component, corner, u|v]
    G_MA = np.swapaxes(np.swapaxes(R_Mc, 1, 2) @ np.swapaxes(G_A, 0, 1), 0, 1)  # (d uv / d q_b)^T, shape (3, M, 2)
    G_r, q_r = (G_A, q_m) if invert_robot else (G_MA, q_b)
    G_b = np.einsum("ji,jmc->imc", R_B, G_MA)  # (d uv / d object point)^T
    G = np.stack([Jp_T, G_r.reshape(3, 2 * m), G_b.reshape(3, 2 * m)])  # shape (3, 3, 2M)
    Q = np.repeat(np.stack([p_c.T, q_r.T, object_points.T]), 2, axis=2)  # shape (3, 3, 2M)
    J = _pose_jacobians_T(G, Q, _SIGN_ALL[invert_robot])
    return (uv - image_points).reshape(-1), J[0].T, J[1].T, J[2].T, Jk_T.T


def eye_in_hand_residual(
    *,
    T_end_cam: np.ndarray,
    T_base_end: np.ndarray,
    T_base_board: np.ndarray,
    intrinsics_vec: np.ndarray,
    object_points: np.ndarray,
    image_points: np.ndarray,
    jacobians: bool = True,
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray]]:
    """Pixel = project(K, inv(T_base_end · T_end_cam) · T_base_board · p); see :func:`chain_residual`."""
    return chain_residual(
        T_x=T_end_cam,
        T_base_end=T_base_end,
        T_board=T_base_board,
        invert_robot=True,
        intrinsics_vec=intrinsics_vec,
        object_points=object_points,
        image_points=image_points,
        jacobians=jacobians,
    )


def eye_to_hand_residual(
    *,
    T_base_cam: np.ndarray,
    T_base_end: np.ndarray,
    T_end_board: np.ndarray,
    intrinsics_vec: np.ndarray,
    object_points: np.ndarray,
    image_points: np.ndarray,
    jacobians: bool = True,
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray], Optional[np.ndarray]]:
    """Pixel = project(K, inv(T_base_cam) · T_base_end · T_end_board · p); see :func:`chain_residual`."""
    return chain_residual(
        T_x=T_base_cam,
        T_base_end=T_base_end,
        T_board=T_end_board,
        invert_robot=False,
        intrinsics_vec=intrinsics_vec,
        object_points=object_points,
        image_points=image_points,
        jacobians=jacobians,
    )


# ------------------------------------------------------------------------------ robust losses
LOSSES = ("none", "huber", "cauchy")


def corner_robust_scales(
    residual: np.ndarray, *, sigma_px: float, loss: str, k: float
) -> tuple[np.ndarray, np.ndarray]:
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
