"""Pure rigid-body math on 4x4 transforms ``T_a_b`` (maps points of frame b into frame a).

No I/O, no printing, inputs are never mutated. Rotations inside the package are 3x3 matrices,
rotation vectors (``rotvec``, radians) or quaternions; quaternions are always ``wxyz`` here
(conversion to other orders happens only in :mod:`handeye.conventions`).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


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
    return make_T(Rotation.from_rotvec(np.asarray(rotvec, float)).as_matrix(), t)


def rotvec_from_R(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(np.asarray(R, float)).as_rotvec()


def quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0."""
    q = Rotation.from_matrix(np.asarray(R, float)).as_quat()  # scipy: x, y, z, w
    q = np.array([q[3], q[0], q[1], q[2]])
    return q if q[0] >= 0 else -q


def R_from_quat_wxyz(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Map points (N,3) or (3,) from frame b to frame a."""
    p_b = np.asarray(p_b, float)
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def rotation_angle_rad(R: np.ndarray) -> np.ndarray:
    """Geodesic rotation angle of R (3,3) or (N,3,3), in radians, robust near 0 and pi."""
    R = np.asarray(R, float)
    return np.linalg.norm(Rotation.from_matrix(R).as_rotvec(), axis=-1)


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


def project_to_rotation(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD), for matrices that are rotations up to rounding."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    return U @ D @ Vt


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
    rv = Rotation.from_matrix(T[:, :3, :3]).as_rotvec()
    ang = np.linalg.norm(rv, axis=1)
    axis = rv / np.maximum(ang, 1e-12)[:, None]
    pitch = np.einsum("ni,ni->n", axis, T[:, :3, 3])
    return ang, pitch
