"""Intrinsics, per-view board poses, symmetric-board ordering, degeneracy checks and the
OpenCV closed-form hand-eye seed, all through the one generic model ``C_i = A · M_i · B``.

OpenCV names its inputs ``X2Y`` (the pose of X in Y). The translation into handeye's names happens
only in :func:`solve_closed_form`:

=====================================  ======================================================
OpenCV argument                        handeye quantity (generic model)
=====================================  ======================================================
calibrateHandEye ``R_gripper2base``    ``inv(M_i)`` (eye-in-hand: T_base_end_i)
calibrateHandEye ``R_target2cam``      ``C_i = T_cam_board_i``
calibrateHandEye ``R_cam2gripper``     ``inv(A) = X`` (T_end_cam or T_base_cam)
calibrateRobotWorldHandEye world2cam   ``C_i``
calibrateRobotWorldHandEye base2grip.  ``M_i``
... output ``gripper2cam``             ``A``
... output ``base2world``              ``inv(B)``
=====================================  ======================================================
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Mapping, Sequence

import cv2
import numpy as np

from ..errors import CalibrationError, DegenerateMotionError, DetectionError
from ..frames import inv_T, is_rotation, make_T, mean_T, rotation_angle_rad, screw_invariants
from ..mounting import MountingMode
from ..records import METHOD_NAMES, Detection, HandEyeEstimate
from ..camera import Intrinsics
from ..targets import TargetSpec

log = logging.getLogger(__name__)

HAND_EYE_METHODS = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}
ROBOT_WORLD_METHODS = {
    "shah": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "li": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}
METHODS = METHOD_NAMES
assert METHODS == tuple(HAND_EYE_METHODS) + tuple(ROBOT_WORLD_METHODS), "method tables out of step"

#: smallest useful relative rotation between two views, and smallest spread of rotation axes
MIN_ROTATION_DEG = 10.0
MIN_AXIS_SPREAD_DEG = 5.0


# ------------------------------------------------------------------------------ intrinsics
def calibrate_intrinsics(detections: Sequence[Detection], object_points: np.ndarray, *,
                         fix_k3: bool = False) -> tuple[Intrinsics, float]:
    """OpenCV calibrateCamera (5-coefficient model) on the detected views: (intrinsics, rms_px)."""
    if len(detections) < 3:
        raise DetectionError(f"only {len(detections)} views with a detected target; calibrating the camera needs 3+",
                             hint="capture more views with the whole board visible")
    obj = [object_points[d.corner_ids].astype(np.float32) for d in detections]
    img = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in detections]
    size = detections[0].image_size
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    w, h = size
    # Planar targets need an initial guess for non-planar-free init; OpenCV handles planar boards.
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, (int(w), int(h)), None, None, flags=flags,
                                             criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12))
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0:
        raise CalibrationError("camera calibration failed", hint="check the board size in the config and the images")
    return Intrinsics.from_K(K, dist, w, h), float(rms)


# ------------------------------------------------------------------------------ board poses
def solve_pnp(object_points: np.ndarray, image_points: np.ndarray, intr: Intrinsics) -> tuple[np.ndarray, float]:
    """``T_cam_board`` from one view's corners, refined (Levenberg-Marquardt): (T, rms_px)."""
    obj = object_points.astype(np.float64).reshape(-1, 1, 3)
    img = image_points.astype(np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(obj, img, intr.K, intr.dist_array, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("solvePnP failed for a view")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, intr.K, intr.dist_array, rvec, tvec)
    T = make_T(cv2.Rodrigues(rvec)[0], tvec.reshape(3))
    return T, reprojection_rms(object_points, image_points, T, intr)


def project(object_points: np.ndarray, T_cam_board: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """pixel_from_board_point through ``T_cam_board`` with OpenCV's model: (N,2)."""
    rvec = cv2.Rodrigues(T_cam_board[:3, :3])[0]
    px, _ = cv2.projectPoints(object_points.astype(np.float64).reshape(-1, 1, 3), rvec, T_cam_board[:3, 3],
                              intr.K, intr.dist_array)
    return px.reshape(-1, 2)


def reprojection_rms(object_points, image_points, T_cam_board, intr) -> float:
    r = project(object_points, T_cam_board, intr) - image_points
    return float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


@dataclass(frozen=True)
class BoardPose:
    view_id: str
    T_cam_board: np.ndarray
    rms_px: float
    orientation: int  # index into target.symmetries()
    corner_ids: np.ndarray  # ids after resolving the orientation


def board_poses(detections: Sequence[Detection], target: TargetSpec, intr: Intrinsics,
                M: Mapping[str, np.ndarray]) -> dict[str, BoardPose]:
    """Per-view ``T_cam_board``, with the corner ordering of symmetric boards made consistent.

    A symmetric board's detector ordering may be turned by 180 (or 90) degrees in some views. For
    each view every admissible ordering is solved; then the combination is chosen whose camera
    motions agree with the robot motions ``M`` (rotation angle and screw pitch of each relative
    motion are invariant under the unknown transforms).
    """
    obj = target.object_points()
    syms = target.symmetries()
    cands: dict[str, list[tuple[np.ndarray, float, np.ndarray]]] = {}
    for d in detections:
        cands[d.view_id] = []
        for perm in syms:
            ids = perm[d.corner_ids]
            T, rms = solve_pnp(obj[ids], d.image_points, intr)
            cands[d.view_id].append((T, rms, ids))
    labels = {vid: 0 for vid in cands}
    if len(syms) > 1 and len(cands) >= 2:
        labels = _resolve_orientation(cands, M)
    return {vid: BoardPose(vid, cands[vid][c][0], cands[vid][c][1], c, cands[vid][c][2]) for vid, c in labels.items()}


def _resolve_orientation(cands, M) -> dict[str, int]:
    vids = list(cands)
    n = len(vids)
    k = len(cands[vids[0]])
    Ms = np.stack([M[v] for v in vids])
    # robot relative-motion invariants for all pairs
    rel_M = Ms[:, None] @ inv_T(Ms)[None, :]  # (n,n,4,4) M_i M_j^-1
    ang_M, pitch_M = screw_invariants(rel_M.reshape(-1, 4, 4))
    Cs = np.stack([[c[0] for c in cands[v]] for v in vids])  # (n,k,4,4)
    # cost[i,a,j,b]: disagreement when view i uses ordering a and view j ordering b
    rel_C = Cs[:, :, None, None] @ inv_T(Cs)[None, None]  # (n,k,n,k,4,4)
    ang_C, pitch_C = screw_invariants(rel_C.reshape(-1, 4, 4))
    ang_C = ang_C.reshape(n, k, n, k)
    pitch_C = pitch_C.reshape(n, k, n, k)
    am = ang_M.reshape(n, 1, n, 1)
    pm = pitch_M.reshape(n, 1, n, 1)
    # pitch's sign follows the axis direction, which is defined consistently by the rotation vector
    cost = np.abs(ang_C - am) + np.abs(pitch_C - pm) / 0.1
    best, best_cost = None, np.inf
    for r in range(n):
        lab = np.argmin(cost[:, :, r, 0], axis=1)
        lab[r] = 0
        for _ in range(3):  # a few rounds of iterated conditional modes
            for i in range(n):
                tot = [sum(cost[i, a, j, lab[j]] for j in range(n) if j != i) for a in range(k)]
                lab[i] = int(np.argmin(tot))
        c = sum(cost[i, lab[i], j, lab[j]] for i in range(n) for j in range(n) if i != j)
        if c < best_cost:
            best, best_cost = lab.copy(), c
    return {v: int(lab) for v, lab in zip(vids, _majority_frame(best, k))}


def _majority_frame(labels: np.ndarray, k: int) -> np.ndarray:
    """Re-express consistent orientation labels so that the detector's own order is the majority.

    Turning every view by the same symmetry is a change of the board frame only; choose the one
    that keeps most views as detected (so an asymmetric board keeps OpenCV's origin). Labels index
    ``ChessboardSpec.symmetries()``: turns of 0, 180, 90, 270 degrees.
    """
    turns = np.array([0, 2, 1, 3])[:k] if k in (2, 4) else None
    if turns is None:
        return labels
    q = turns[labels]
    shift = np.bincount(q, minlength=4).argmax()
    q = (q - shift) % 4
    back = {t: i for i, t in enumerate(turns)}
    return np.array([back[t] for t in q])


# ------------------------------------------------------------------------------ motion checks
@dataclass(frozen=True)
class MotionQuality:
    n_views: int
    max_rotation_deg: float
    axis_spread_deg: float  # how far the relative rotation axes leave their main direction
    main_axis: np.ndarray  # (3,) in the frame where M's rotations act
    weak_axes: np.ndarray  # (2,3) directions with little rotation
    status: str
    reason: str


def motion_quality(M: np.ndarray, *, frame: str, min_rotation_deg: float = MIN_ROTATION_DEG,
                   min_axis_spread_deg: float = MIN_AXIS_SPREAD_DEG) -> MotionQuality:
    """Rotation coverage of the robot motions ``M`` (N,4,4) for the hand-eye problem.

    The relative motions ``M_i M_j^-1`` must include rotations about at least two different axes.
    ``frame`` names the frame the axes are expressed in (for the message).
    """
    n = len(M)
    if n < 3:
        return MotionQuality(n, 0.0, 0.0, np.zeros(3), np.eye(3)[:2], "degenerate",
                             f"only {n} usable views; the hand-eye solution needs at least 3 (10-20 recommended)")
    iu, ju = np.triu_indices(n, 1)
    rel = M[iu] @ inv_T(M[ju])
    from scipy.spatial.transform import Rotation

    rv = Rotation.from_matrix(rel[:, :3, :3]).as_rotvec()
    ang = np.linalg.norm(rv, axis=1)
    max_deg = float(np.degrees(ang.max()))
    W = rv * np.minimum(ang, np.pi / 2)[:, None] / np.maximum(ang, 1e-12)[:, None]  # sin-like weights
    S = W.T @ W
    evals, evecs = np.linalg.eigh(S)  # ascending
    main = evecs[:, 2]
    spread = float(np.degrees(np.arctan2(np.sqrt(max(evals[1], 0)), np.sqrt(max(evals[2], 1e-30)))))
    weak = evecs[:, :2].T
    if max_deg < min_rotation_deg:
        return MotionQuality(n, max_deg, spread, main, weak, "degenerate",
                             f"the robot rotates at most {max_deg:.1f} deg between views; add views tilted by "
                             f"20-45 deg about two different axes of the {frame} frame")
    if spread < min_axis_spread_deg:
        return MotionQuality(n, max_deg, spread, main, weak, "degenerate",
                             f"all rotations are about one axis ({_fmt_axis(main)} in the {frame} frame, spread "
                             f"{spread:.1f} deg); add views rotated 20-45 deg about {_fmt_axis(weak[1])} and "
                             f"{_fmt_axis(weak[0])}")
    return MotionQuality(n, max_deg, spread, main, weak, "ok", "")


def _fmt_axis(a: np.ndarray) -> str:
    a = a / np.linalg.norm(a)
    a = a if a[np.argmax(np.abs(a))] >= 0 else -a
    return "[" + ", ".join(f"{x:+.2f}" for x in a) + "]"


# ------------------------------------------------------------------------------ closed form
def solve_closed_form(mode: MountingMode, C: np.ndarray, M: np.ndarray, *, method: str = "tsai") -> HandEyeEstimate:
    """One OpenCV closed-form solve of ``C_i = A · M_i · B`` for either mounting mode.

    ``C`` (N,4,4) board poses ``T_cam_board_i``; ``M`` (N,4,4) robot motions from
    ``mode.M_from_T_base_end``. Returns X (``T_end_cam``/``T_base_cam``) and the board transform.
    """
    method = method.lower()
    if method not in METHODS:
        raise CalibrationError(f"unknown method {method!r}", expected=" | ".join(METHODS))
    if method in HAND_EYE_METHODS:
        G = inv_T(M)  # "gripper2base"
        R, t = cv2.calibrateHandEye(list(G[:, :3, :3]), list(G[:, :3, 3]), list(C[:, :3, :3]), list(C[:, :3, 3]),
                                    method=HAND_EYE_METHODS[method])
        X = make_T(R, t.reshape(3))  # "cam2gripper" = inv(A)
        if not np.all(np.isfinite(X)):
            return HandEyeEstimate(mode.name, method, np.eye(4), np.eye(4), "failed", "solver returned non-finite values")
        A = inv_T(X)
        B = mean_T(inv_T(A @ M) @ C)
    else:
        R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
            list(C[:, :3, :3]), list(C[:, :3, 3]), list(M[:, :3, :3]), list(M[:, :3, 3]),
            method=ROBOT_WORLD_METHODS[method])
        A = make_T(R_gc, t_gc.reshape(3))  # "gripper2cam"
        B = inv_T(make_T(R_bw, t_bw.reshape(3)))  # inv("base2world")
        X = inv_T(A)
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(B))):
        return HandEyeEstimate(mode.name, method, np.eye(4), np.eye(4), "failed", "solver returned non-finite values")
    if not (is_rotation(X[:3, :3], tol=1e-4) and is_rotation(B[:3, :3], tol=1e-4)):
        # e.g. Andreff/Li on inconsistent data can return a reflection: not a usable result
        return HandEyeEstimate(mode.name, method, np.eye(4), np.eye(4), "failed",
                               "solver returned a matrix that is not a rotation (data inconsistent with the model)")
    return HandEyeEstimate(mode.name, method, X, B)


def chain_residuals(est: HandEyeEstimate, mode: MountingMode, obj: np.ndarray, poses: Mapping[str, BoardPose],
                    detections: Mapping[str, Detection], T_base_end: Mapping[str, np.ndarray],
                    intr: Intrinsics) -> dict[str, tuple[float, float]]:
    """Per view (rms_px, max_px) of the corners predicted through robot pose + hand-eye + board."""
    out = {}
    for vid, bp in poses.items():
        C = mode.predict_T_cam_board(est.T_x, est.T_board, T_base_end[vid])
        r = np.linalg.norm(project(obj[bp.corner_ids], C, intr) - detections[vid].image_points, axis=1)
        out[vid] = (float(np.sqrt(np.mean(r ** 2))), float(r.max()))
    return out


def consistency(est: HandEyeEstimate, mode: MountingMode, C: np.ndarray, M: np.ndarray) -> tuple[float, float]:
    """RMS scatter (mm, deg) of the board transform implied by each view under this solution."""
    Bs = inv_T(inv_T(est.T_x) @ M) @ C
    t = Bs[:, :3, 3]
    dt = 1e3 * np.sqrt(np.mean(np.sum((t - t.mean(0)) ** 2, axis=1)))
    dr = np.degrees(np.sqrt(np.mean(rotation_angle_rad(np.swapaxes(est.T_board[:3, :3], -1, -2) @ Bs[:, :3, :3]) ** 2)))
    return float(dt), float(dr)


def all_methods(mode: MountingMode, C: np.ndarray, M: np.ndarray) -> dict[str, HandEyeEstimate]:
    """Every OpenCV closed-form method; a method that raises is recorded as failed."""
    out = {}
    for m in METHODS:
        try:
            out[m] = solve_closed_form(mode, C, M, method=m)
        except (cv2.error, np.linalg.LinAlgError, ValueError) as e:  # one method failing must not stop the others
            msg = (str(e).strip().splitlines() or [type(e).__name__])[-1][:200]
            out[m] = HandEyeEstimate(mode.name, m, np.eye(4), np.eye(4), "failed", msg)
    return out


__all__ = ["METHODS", "calibrate_intrinsics", "solve_pnp", "project", "board_poses", "motion_quality",
           "solve_closed_form", "all_methods", "chain_residuals", "consistency", "BoardPose", "MotionQuality"]
