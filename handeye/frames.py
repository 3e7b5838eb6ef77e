"""Rigid-body math on 4x4 transforms ``T_a_b`` (maps points of frame b into frame a): THE SE(3) module.

No I/O, no printing, inputs are never mutated. Rotations inside the package are 3x3 matrices,
rotation vectors (``rotvec``, radians) or quaternions; quaternions are always ``wxyz`` here
(conversion to other orders happens only in :mod:`handeye.conventions`).

Tangent convention (the only one in handeye, GTSAM's Pose3): ``xi = (omega [rad], v [m])``,
rotation first, **right** perturbation ``T_true = T · Exp(xi)``. Every covariance of a pose that
handeye computes, stores or reads is in this tangent. :func:`se3_exp` / :func:`se3_log` are the
exact maps (not first-order approximations), :func:`se3_adjoint` moves a tangent vector between
frames (``T · Exp(xi) = Exp(Ad_T xi) · T``), :func:`tangent_jacobian` differentiates any function of
a pose in this convention.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 transform from a 3x3 rotation and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (works on (4,4) or stacked (N,4,4))."""
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    Ti[..., 3, 3] = 1.0
    return Ti


def T_from_rotvec(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
    return make_T(R_from_rotvec(rotvec), t)


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Map points (N,3) or (3,) from frame b to frame a."""
    p_b = np.asarray(p_b, float)
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def rotation_angle_rad(R: np.ndarray) -> np.ndarray:
    """Geodesic rotation angle of R (3,3) or (N,3,3), in radians, robust near 0 and pi."""
    R = np.asarray(R, float)
    return np.linalg.norm(rotvec_from_R(R), axis=-1)


def rot_err_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle between two rotations, in degrees."""
    return float(np.degrees(rotation_angle_rad(np.asarray(R_a).T @ np.asarray(R_b))))


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in mm) between two transforms."""
    return rot_err_deg(T_est[:3, :3], T_true[:3, :3]), float(1000.0 * np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))


def is_rotation(R: np.ndarray, *, tol: float = 1e-6) -> bool:
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return False
    return bool(np.allclose(R.T @ R, np.eye(3), atol=tol) and abs(np.linalg.det(R) - 1.0) < tol)


def is_rigid_transform(T: object, *, tol: float = 1e-6) -> bool:
    """``T`` is a finite 4x4 rigid transform: a rotation block (:func:`is_rotation`) and last row 0 0 0 1."""
    try:
        T = np.asarray(T, float)
    except (TypeError, ValueError):
        return False
    return (
        T.shape == (4, 4)
        and bool(np.all(np.isfinite(T)))
        and is_rotation(T[:3, :3], tol=tol)
        and bool(np.allclose(T[3], [0, 0, 0, 1]))
    )


def project_to_rotation(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD) of R (3,3) or (..., 3, 3), for matrices that are rotations up to rounding."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    d = np.ones(U.shape[:-1])
    d[..., 2] = np.linalg.det(U @ Vt)
    return (U * d[..., None, :]) @ Vt


def mean_T(Ts: np.ndarray) -> np.ndarray:
    """Chordal mean of rigid transforms (N,4,4): projected mean rotation, mean translation."""
    Ts = np.asarray(Ts, float)
    return make_T(project_to_rotation(Ts[:, :3, :3].sum(axis=0)), Ts[:, :3, 3].mean(axis=0))


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of v (3,) or stacked (N,3) -> (N,3,3)."""
    v = np.asarray(v, float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def screw_invariants(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angle (rad) and translation along the rotation axis (m) of (N,4,4) motions.

    Both are invariant under conjugation ``X T X^-1``, so they compare a camera motion with the
    robot motion that caused it without knowing the hand-eye transform.
    """
    T = np.asarray(T, float).reshape(-1, 4, 4)
    rv = rotvec_from_R(T[:, :3, :3])
    ang = np.linalg.norm(rv, axis=1)
    axis = rv / np.maximum(ang, 1e-12)[:, None]
    pitch = np.einsum("ni,ni->n", axis, T[:, :3, 3])
    return ang, pitch


# ------------------------------------------------------------------------------ rotation forms
# Pure numpy (no scipy.spatial at import time: the CLI's start-up stays light); vectorised over
# leading axes; robust near 0 and pi (quaternions by Shepperd's method).
def quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) (w, x, y, z) with w >= 0 of rotation(s) (3,3) or (...,3,3)."""
    R = np.asarray(R, float)
    if R.shape == (3, 3):  # one rotation: the same formulas on floats (numpy's per-call overhead is most of it)
        return _quat_wxyz_from_one_R(R.tolist())
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    cand = np.stack(
        [1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], axis=-1
    )
    k = np.argmax(cand, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300))
    d21, d02, d10 = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    s01, s02, s12 = R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1]
    q = np.stack(
        [
            np.select([k == 0, k == 1, k == 2], [s / 4, d21 / s, d02 / s], d10 / s),
            np.select([k == 0, k == 1, k == 2], [d21 / s, s / 4, s01 / s], s02 / s),
            np.select([k == 0, k == 1, k == 2], [d02 / s, s01 / s, s / 4], s12 / s),
            np.select([k == 0, k == 1, k == 2], [d10 / s, s02 / s, s12 / s], s / 4),
        ],
        axis=-1,
    )
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def _quat_wxyz_from_one_R(R: list[list[float]]) -> np.ndarray:
    """:func:`quat_wxyz_from_R` of one rotation given as nested lists: the largest of the four candidates."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = R
    cand = (1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22)
    k = max(range(4), key=cand.__getitem__)
    s = 2.0 * math.sqrt(max(cand[k], 1e-300))
    d21, d02, d10 = m21 - m12, m02 - m20, m10 - m01
    s01, s02, s12 = m01 + m10, m02 + m20, m12 + m21
    q = (
        (s / 4, d21 / s, d02 / s, d10 / s),
        (d21 / s, s / 4, s01 / s, s02 / s),
        (d02 / s, s01 / s, s / 4, s12 / s),
        (d10 / s, s02 / s, s12 / s, s / 4),
    )[k]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = -1.0 if q[0] < 0 else 1.0
    return np.array([sign * c / n for c in q])


def R_from_quat_wxyz(q: np.ndarray) -> np.ndarray:
    """Rotation(s) (...,3,3) of quaternion(s) (w, x, y, z) (normalised here)."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def R_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Rotation(s) (...,3,3) of rotation vector(s) (...,3) in radians (Rodrigues)."""
    rotvec = np.asarray(rotvec, float)
    th = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    W = skew(rotvec)
    small = th < 1e-5
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * W + b * (W @ W)


def rotvec_from_R(R: np.ndarray) -> np.ndarray:
    """Rotation vector(s) (...,3), angle in [0, pi], of rotation(s) (...,3,3)."""
    q = quat_wxyz_from_R(R)
    n = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(n, q[..., 0])
    scale = np.where(n < 1e-12, 2.0, angle / np.maximum(n, 1e-300))  # 2·v for tiny angles
    return q[..., 1:] * scale[..., None]


# ------------------------------------------------------------------------------ SE(3) tangent
def _so3_left_jacobian(omega: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3) at ``omega`` (..., 3) -> (..., 3, 3), exact with a series near 0."""
    omega = np.asarray(omega, float)
    th = np.linalg.norm(omega, axis=-1)[..., None, None]
    W = skew(omega)
    W2 = W @ W
    small = th < 1e-5
    ths = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (ths - np.sin(ths)) / ths**3)
    return np.eye(3) + a * W + b * W2


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Exp of a tangent vector ``xi = (omega, v)`` (6,) or (N,6) -> (4,4) or (N,4,4) (GTSAM's Pose3.Expmap)."""
    xi = np.asarray(xi, float)
    R = R_from_rotvec(xi[..., :3])
    t = np.einsum("...ij,...j->...i", _so3_left_jacobian(xi[..., :3]), xi[..., 3:])
    T = np.zeros(xi.shape[:-1] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """Log of a rigid transform (4,4) or (N,4,4) -> ``(omega, v)`` (6,) or (N,6); inverse of :func:`se3_exp`."""
    T = np.asarray(T, float)
    omega = rotvec_from_R(T[..., :3, :3])
    v = np.linalg.solve(_so3_left_jacobian(omega), T[..., :3, 3][..., None])[..., 0]
    return np.concatenate([omega, v], axis=-1)


def se3_adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoint (6,6) of ``T`` in the (rotation, translation) order: ``T · Exp(xi) · inv(T) = Exp(Ad_T xi)``."""
    T = np.asarray(T, float)
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = skew(t) @ R
    return Ad


def tangent_difference(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """``xi`` with ``T_b = T_a · Exp(xi)``: the right-tangent difference of (4,4) or stacked (N,4,4) poses."""
    return se3_log(inv_T(T_a) @ np.asarray(T_b, float))


def tangent_jacobian(f: Callable[[np.ndarray], np.ndarray], T: np.ndarray, *, h: float = 1e-6) -> np.ndarray:
    """Numeric Jacobian (m,6) of ``f(T · Exp(xi))`` at ``xi = 0`` (central differences, right tangent).

    ``f`` maps a (4,4) transform to a vector (m,). Used to propagate a pose covariance ``S`` to any
    derived quantity as ``J S J^T``.
    """
    T = np.asarray(T, float)
    cols = []
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        cols.append((np.asarray(f(T @ se3_exp(e)), float) - np.asarray(f(T @ se3_exp(-e)), float)) / (2.0 * h))
    return np.stack(cols, axis=-1)
