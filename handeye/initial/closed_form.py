"""OpenCV's closed-form hand-eye solvers through the one generic model ``C_i = A · M_i · B``.

Also their agreement with the data (board consistency, residuals through the robot chain). OpenCV
names its inputs ``X2Y`` (the pose of X in Y); they are translated into handeye's names only in
:func:`solve_closed_form` (``R_gripper2base`` -> ``inv(M_i)``, ``R_target2cam`` -> ``C_i``,
``R_cam2gripper`` -> ``inv(A) = X``; the table is in docs/detection.md).

See docs/detection.md.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Mapping

import cv2
import numpy as np

from ..camera import Intrinsics, pixels_from_board_points
from ..errors import CalibrationError
from ..frames import inv_T, is_rotation, make_T, mean_T, rotation_angle_rad
from ..machine import usable_cores
from ..mounting import MountingMode
from ..records import METHOD_NAMES, Detection, HandEyeEstimate
from .board_poses import BoardPose

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
#: OpenCV's hand-eye methods (``HAND_EYE_METHODS``) use every pair of the views they are given: their cost grows
#: with the square of the views. Above this many views they get a subset spread over the robot rotations
#: (:func:`spread_views`); the robot-world methods, linear in the views, always get every view.
MAX_PAIRED_VIEWS = 60
if METHODS != tuple(HAND_EYE_METHODS) + tuple(ROBOT_WORLD_METHODS):  # pragma: no cover - a programming error
    raise ImportError("records.METHOD_NAMES and the OpenCV method tables are out of step")


def spread_views(M: np.ndarray, k: int) -> np.ndarray:
    """Sorted indices of ``k`` of the robot motions ``M`` (N,4,4) spread over their rotations.

    Farthest-point sampling on the rotations (chordal distance ``|R_i - R_j|``), from the first view on,
    ties to the earliest view: deterministic, O(N k), and the chosen views' pairs have the large, varied
    relative rotations that condition the hand-eye solve. All views when ``k >= N``.
    """
    M = np.asarray(M, float)
    n = len(M)
    if k >= n:
        return np.arange(n)
    R = M[:, :3, :3].reshape(n, 9)
    chosen = [0]
    d2 = np.sum((R - R[0]) ** 2, axis=1)  # squared chordal distance to the nearest chosen view
    for _ in range(1, max(int(k), 1)):
        c = int(np.argmax(d2))
        chosen.append(c)
        d2 = np.minimum(d2, np.sum((R - R[c]) ** 2, axis=1))
    return np.sort(np.asarray(chosen))


def solve_closed_form(mode: MountingMode, C: np.ndarray, M: np.ndarray, *, method: str = "tsai") -> HandEyeEstimate:
    """One OpenCV closed-form solve of ``C_i = A · M_i · B`` for either mounting mode.

    ``C`` (N,4,4) board poses ``T_cam_board_i``; ``M`` (N,4,4) robot motions from
    ``mode.M_from_T_base_end``. Returns X (``T_end_cam``/``T_base_cam``) and the board transform. A
    hand-eye method sees at most :data:`MAX_PAIRED_VIEWS` views (:func:`spread_views`), so its cost stays
    bounded; the board transform is then the mean over every view.
    """
    method = method.lower()
    if method not in METHODS:
        raise CalibrationError(f"unknown method {method!r}", expected=" | ".join(METHODS), code="unknown_method")
    if method in HAND_EYE_METHODS:
        sub = spread_views(M, MAX_PAIRED_VIEWS)
        G = inv_T(M[sub])  # "gripper2base"
        R, t = cv2.calibrateHandEye(
            list(G[:, :3, :3]),
            list(G[:, :3, 3]),
            list(C[sub, :3, :3]),
            list(C[sub, :3, 3]),
            method=HAND_EYE_METHODS[method],
        )
        X = make_T(R, t.reshape(3))  # "cam2gripper" = inv(A)
        if not np.all(np.isfinite(X)):
            return HandEyeEstimate(
                mode.name, method, np.eye(4), np.eye(4), "failed", "solver returned non-finite values"
            )
        A = inv_T(X)
        B = mean_T(inv_T(A @ M) @ C)
    else:
        R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
            list(C[:, :3, :3]),
            list(C[:, :3, 3]),
            list(M[:, :3, :3]),
            list(M[:, :3, 3]),
            method=ROBOT_WORLD_METHODS[method],
        )
        A = make_T(R_gc, t_gc.reshape(3))  # "gripper2cam"
        B = inv_T(make_T(R_bw, t_bw.reshape(3)))  # inv("base2world")
        X = inv_T(A)
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(B))):
        return HandEyeEstimate(mode.name, method, np.eye(4), np.eye(4), "failed", "solver returned non-finite values")
    if not (is_rotation(X[:3, :3], tol=1e-4) and is_rotation(B[:3, :3], tol=1e-4)):
        # e.g. Andreff/Li on inconsistent data can return a reflection: not a usable result
        return HandEyeEstimate(
            mode.name,
            method,
            np.eye(4),
            np.eye(4),
            "failed",
            "solver returned a matrix that is not a rotation (data inconsistent with the model)",
        )
    return HandEyeEstimate(mode.name, method, X, B)


def all_methods(mode: MountingMode, C: np.ndarray, M: np.ndarray) -> dict[str, HandEyeEstimate]:
    """Every OpenCV closed-form method; a method that raises is recorded as failed.

    The methods run on up to one thread per usable core: OpenCV releases the GIL. The hand-eye methods use
    every pair of the views they get, at most :data:`MAX_PAIRED_VIEWS` (tens of milliseconds each).
    """

    def one(m: str) -> HandEyeEstimate:
        try:
            return solve_closed_form(mode, C, M, method=m)
        except (cv2.error, np.linalg.LinAlgError, ValueError) as e:  # one method failing must not stop the others
            msg = (str(e).strip().splitlines() or [type(e).__name__])[-1][:200]
            return HandEyeEstimate(mode.name, m, np.eye(4), np.eye(4), "failed", msg)

    cores = usable_cores()
    if cores < 2:
        return {m: one(m) for m in METHODS}
    with ThreadPoolExecutor(max_workers=min(cores, len(METHODS))) as pool:
        return dict(zip(METHODS, pool.map(one, METHODS), strict=True))


def chain_residuals(
    est: HandEyeEstimate,
    mode: MountingMode,
    obj: np.ndarray,
    poses: Mapping[str, BoardPose],
    detections: Mapping[str, Detection],
    T_base_end: Mapping[str, np.ndarray],
    intr: Intrinsics,
) -> dict[str, tuple[float, float]]:
    """Per view (rms_px, max_px) of the corners predicted through robot pose + hand-eye + board."""
    out = {}
    for vid, bp in poses.items():
        C = mode.predict_T_cam_board(est.T_x, est.T_board, T_base_end[vid])
        r = np.linalg.norm(pixels_from_board_points(C, obj[bp.corner_ids], intr) - detections[vid].image_points, axis=1)
        out[vid] = (float(np.sqrt(np.mean(r**2))), float(r.max()))
    return out


def consistency(est: HandEyeEstimate, mode: MountingMode, C: np.ndarray, M: np.ndarray) -> tuple[float, float]:
    """RMS scatter (mm, deg) of the board transform implied by each view under this solution."""
    Bs = inv_T(inv_T(est.T_x) @ M) @ C
    t = Bs[:, :3, 3]
    dt = 1e3 * np.sqrt(np.mean(np.sum((t - t.mean(0)) ** 2, axis=1)))
    dr = np.degrees(np.sqrt(np.mean(rotation_angle_rad(np.swapaxes(est.T_board[:3, :3], -1, -2) @ Bs[:, :3, :3]) ** 2)))
    return float(dt), float(dr)
