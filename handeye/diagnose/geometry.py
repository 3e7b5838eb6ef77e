"""Pure math behind the dataset diagnostics (:mod:`handeye.diagnose`).

Everything here works on the one model ``C_i = A · M_i · B`` (``C_i = T_cam_board_i`` from PnP,
``M_i`` the robot motion of :mod:`handeye.mounting`). Two facts carry most diagnostics:

* For any pair of views, ``C_i C_j^-1 = A (M_i M_j^-1) A^-1``: the camera's relative motion is the
  robot's relative motion seen through the unknown ``A``. Its rotation angle and its screw pitch
  (translation along the rotation axis) are invariant under that conjugation, so they must be equal
  for camera and robot *whatever* the hand-eye transform and the board transform are
  (:func:`pair_invariants`). A reading of the robot poses (units, Euler order, inversion, mounting
  mode, pairing) that is wrong breaks that equality for most pairs; a view whose robot pose is wrong
  breaks it for the pairs it is in; a board that moved breaks it for pairs across the move.
* Given ``A`` from the pairs alone (:func:`solve_A_from_pairs`, Park & Martin on any chosen set of
  pairs), each view implies its own board transform ``B_i = inv(A M_i) C_i`` and its own robot pose
  ``M_i* = inv(A) C_i inv(B)``, which give the size of a disagreement in mm and degrees.

No I/O, no printing, inputs never mutated.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import inv_T, make_T, mean_T, project_to_rotation
from ..stats import robust_noise_sigma  # noqa: F401 - part of this module's API

#: pairs whose relative rotation is outside this range (deg) give no usable screw pitch: the axis is
#: ill-defined for small angles and flips sign near 180 degrees
PITCH_ANGLE_RANGE_DEG = (12.0, 165.0)
#: nominal noise of the invariants, used to put angle and pitch residuals on one scale
NOMINAL_ANGLE_SIGMA_DEG = 0.2
NOMINAL_PITCH_SIGMA_MM = 2.0


def all_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays (i, j) of all pairs i < j."""
    return np.triu_indices(int(n), 1)


def pair_invariants(C: np.ndarray, M: np.ndarray, *, pairs: tuple | None = None) -> dict:
    """Rotation-angle and screw-pitch residuals of every view pair (camera motion vs robot motion).

    ``C`` (N,4,4) board poses ``T_cam_board``, ``M`` (N,4,4) robot motions of the mode. Returns
    ``i, j`` (P,), ``angle_deg`` (P,) the robot's relative rotation, ``angle_res_deg`` (P,),
    ``pitch_res_mm`` (P,) with NaN where the pitch is not usable, and ``score`` (P,): both residuals
    in units of their nominal noise, combined (``hypot``; angle only where there is no pitch).
    """
    C = np.asarray(C, float)
    M = np.asarray(M, float)
    i, j = all_pairs(len(C)) if pairs is None else (np.asarray(pairs[0]), np.asarray(pairs[1]))
    rc = C[i] @ inv_T(C[j])
    rm = M[i] @ inv_T(M[j])
    rv_c = Rotation.from_matrix(rc[:, :3, :3]).as_rotvec()
    rv_m = Rotation.from_matrix(rm[:, :3, :3]).as_rotvec()
    a_c = np.linalg.norm(rv_c, axis=1)
    a_m = np.linalg.norm(rv_m, axis=1)
    p_c = np.einsum("ni,ni->n", rv_c / np.maximum(a_c, 1e-12)[:, None], rc[:, :3, 3])
    p_m = np.einsum("ni,ni->n", rv_m / np.maximum(a_m, 1e-12)[:, None], rm[:, :3, 3])
    ang_res = np.degrees(np.abs(a_c - a_m))
    lo, hi = np.radians(PITCH_ANGLE_RANGE_DEG)
    ok = (a_m > lo) & (a_m < hi) & (a_c > lo) & (a_c < hi)
    pitch_res = np.where(ok, 1e3 * np.abs(p_c - p_m), np.nan)
    s_a = ang_res / NOMINAL_ANGLE_SIGMA_DEG
    s_p = np.where(ok, pitch_res / NOMINAL_PITCH_SIGMA_MM, 0.0)
    return {"i": i, "j": j, "angle_deg": np.degrees(a_m), "angle_res_deg": ang_res, "pitch_res_mm": pitch_res,
            "score": np.hypot(s_a, s_p)}


def summarize_invariants(inv: dict) -> dict:
    """Medians of a pair-invariant table (what a reading is judged by)."""
    pr = inv["pitch_res_mm"]
    pr = pr[np.isfinite(pr)]
    return {"n_pairs": int(len(inv["score"])),
            "median_angle_res_deg": float(np.median(inv["angle_res_deg"])) if len(inv["score"]) else float("nan"),
            "median_pitch_res_mm": float(np.median(pr)) if pr.size else float("nan"),
            "median_score": float(np.median(inv["score"])) if len(inv["score"]) else float("nan")}


def per_view_scores(inv: dict, n: int) -> np.ndarray:
    """Median pair score of each view with all others (N,). A wrong view stands out; an outlier
    among the others barely moves a median."""
    out = np.full(n, np.nan)
    for k in range(n):
        sel = (inv["i"] == k) | (inv["j"] == k)
        if sel.any():
            out[k] = float(np.median(inv["score"][sel]))
    return out


def score_matrix(inv: dict, n: int) -> np.ndarray:
    """Symmetric (N,N) matrix of pair scores (NaN on the diagonal)."""
    S = np.full((n, n), np.nan)
    S[inv["i"], inv["j"]] = inv["score"]
    S[inv["j"], inv["i"]] = inv["score"]
    return S


def solve_A_from_pairs(C: np.ndarray, M: np.ndarray, pairs: tuple) -> np.ndarray:
    """``A`` (4,4) of ``C_i C_j^-1 = A M_i M_j^-1 A^-1`` from the given pairs (Park & Martin).

    Rotation: the relative rotation vectors satisfy ``alpha = R_A beta`` (Kabsch). Translation:
    ``(R_Cij - I) t_A = R_A t_Mij - t_Cij`` in least squares.
    """
    i, j = np.asarray(pairs[0]), np.asarray(pairs[1])
    rc = C[i] @ inv_T(C[j])
    rm = M[i] @ inv_T(M[j])
    alpha = Rotation.from_matrix(rc[:, :3, :3]).as_rotvec()  # (P,3)
    beta = Rotation.from_matrix(rm[:, :3, :3]).as_rotvec()
    H = beta.T @ alpha  # sum beta alpha^T
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R_A = Vt.T @ D @ U.T
    lhs = (rc[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,pj->pi", R_A, rm[:, :3, 3]) - rc[:, :3, 3]).reshape(-1)
    t_A, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return make_T(R_A, t_A)


def implied_boards(A: np.ndarray, C: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Board transform ``B_i = inv(A M_i) C_i`` implied by each view (N,4,4)."""
    return inv_T(A @ M) @ C


def robust_mean_T(Ts: np.ndarray) -> np.ndarray:
    """Mean transform that ignores a minority of wild ones: chordal mean of those within 3x the median
    distance of the componentwise median."""
    Ts = np.asarray(Ts, float)
    if len(Ts) < 3:
        return mean_T(Ts)
    t_med = np.median(Ts[:, :3, 3], axis=0)
    R_med = project_to_rotation(np.median(Ts[:, :3, :3], axis=0))
    d = np.linalg.norm(Ts[:, :3, 3] - t_med, axis=1) / 0.01 + rotation_angles_deg(
        np.swapaxes(Ts[:, :3, :3], 1, 2) @ R_med) / 0.5
    keep = d <= 3.0 * max(np.median(d), 1e-9)
    return mean_T(Ts[keep])


def rotation_angles_deg(R: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(Rotation.from_matrix(np.asarray(R, float).reshape(-1, 3, 3)).as_rotvec(),
                                     axis=1))


def pose_differences(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rot_deg (N,), trans_mm (N,)) of ``inv(T_a) T_b``: the difference expressed in frame a's child."""
    d = inv_T(np.asarray(T_a, float)) @ np.asarray(T_b, float)
    return rotation_angles_deg(d[..., :3, :3]), 1e3 * np.linalg.norm(d[..., :3, 3].reshape(-1, 3), axis=1)


def jackknife_sigmas(deltas: np.ndarray, n_total: int, n_left_out: int) -> np.ndarray:
    """Delete-d jackknife standard deviation of each column of ``deltas`` (K folds, D params).

    ``deltas`` are the fold estimates minus the full estimate (or any common reference); the
    variance estimate is ``(n - d) / (d K) sum_k (theta_k - mean)^2``.
    """
    x = np.asarray(deltas, float)
    K = x.shape[0]
    d = max(int(n_left_out), 1)
    dev = x - x.mean(axis=0)
    return np.sqrt((n_total - d) / (d * K) * np.sum(dev ** 2, axis=0))


__all__ = ["pair_invariants", "summarize_invariants", "per_view_scores", "score_matrix", "solve_A_from_pairs",
           "implied_boards", "robust_mean_T", "pose_differences", "jackknife_sigmas", "all_pairs"]


# ------------------------------------------------------------------------------ per-view covariances
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))  # median of |e| / sigma for a 2-D Gaussian


def log6(T: np.ndarray) -> np.ndarray:
    """(rotation vector [rad], translation [m]) of (…,4,4) transforms, shape (…,6)."""
    T = np.asarray(T, float)
    rv = Rotation.from_matrix(T[..., :3, :3].reshape(-1, 3, 3)).as_rotvec().reshape(T.shape[:-2] + (3,))
    return np.concatenate([rv, T[..., :3, 3]], axis=-1)


def pnp_covariance(object_points: np.ndarray, image_points: np.ndarray, T_cam_board: np.ndarray, K: np.ndarray,
                   dist: np.ndarray, sigma_px: float) -> np.ndarray:
    """Covariance (6,6) of a view's board pose, parametrised as a left perturbation
    ``T_cam_board_true = Exp(xi) T_cam_board`` with ``xi = (omega, v)`` in the camera frame."""
    import cv2

    obj = np.asarray(object_points, float).reshape(-1, 3)
    R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
    p_cam = obj @ R.T + t
    _, J = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    # d(pixel)/d(omega, v) for points moved by Exp(xi): d p = -[p]x omega + v; projectPoints at rvec=0 gives
    # the Jacobian w.r.t. its own rvec (= omega) and tvec (= v) directly
    Jp = J[:, :6]
    H = Jp.T @ Jp
    try:
        return sigma_px ** 2 * np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)


def propagate(f, T0: np.ndarray, cov_left: np.ndarray, *, h: float = 1e-6) -> np.ndarray:
    """Covariance (6,6) of ``log6(inv(f(T0)) f(Exp(xi) T0))`` for ``xi ~ N(0, cov_left)`` (numeric Jacobian)."""
    y0 = f(T0)
    y0i = inv_T(y0)
    J = np.empty((6, 6))
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = h
        E = make_T(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])
        J[:, k] = log6(y0i @ f(E @ T0)) / h
    return J @ cov_left @ J.T


def camera_pose_covariances(corners, T_cam_board: np.ndarray, K: np.ndarray, dist: np.ndarray, sigma_px: float, *,
                            intrinsics_estimated: bool) -> np.ndarray:
    """Marginal covariance (N,6,6) of each view's board pose from the camera alone (left perturbation,
    camera frame), including the uncertainty of intrinsics estimated from the same corners.

    ``corners``: per view (object_points (K,3), image_points (K,2)). With ``intrinsics_estimated`` the
    normal matrix of all poses and the 9 intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3) is inverted
    by a Schur complement on the intrinsics; otherwise each view's own PnP information is inverted.
    """
    import cv2

    n = len(corners)
    Hpp, HKp = [], []
    HKK = np.zeros((9, 9))
    for (obj, _), T in zip(corners, T_cam_board):
        p_cam = np.asarray(obj, float).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
        _, J = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
        Jp, JK = J[:, :6], J[:, 6:15]
        Hpp.append(Jp.T @ Jp)
        HKp.append(JK.T @ Jp)
        HKK += JK.T @ JK
    Hpp_inv = []
    for H in Hpp:
        try:
            Hpp_inv.append(np.linalg.inv(H))
        except np.linalg.LinAlgError:
            Hpp_inv.append(np.full((6, 6), np.inf))
    if not intrinsics_estimated:
        return sigma_px ** 2 * np.stack(Hpp_inv)
    S = HKK - sum(HKp[i] @ Hpp_inv[i] @ HKp[i].T for i in range(n) if np.all(np.isfinite(Hpp_inv[i])))
    # a weak prior (50 px on fx..cy, 1 on each distortion coefficient) keeps unobservable ones finite;
    # H is information times sigma_px^2, so a prior sigma s adds sigma_px^2 / s^2
    prior = np.array([50.0] * 4 + [1.0] * 5)
    S = S + np.diag(sigma_px ** 2 / prior ** 2)
    try:
        SKK = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        SKK = np.linalg.pinv(S)
    out = np.empty((n, 6, 6))
    for i in range(n):
        G = Hpp_inv[i] @ HKp[i].T  # (6,9)
        out[i] = Hpp_inv[i] + G @ SKK @ G.T
    return sigma_px ** 2 * out
