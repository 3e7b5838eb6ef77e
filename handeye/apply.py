"""Using a hand-eye result: points and poses seen by the camera, expressed in the robot base.

Eye-in-hand: ``p_base = T_base_end @ T_end_cam @ p_cam`` (needs the end pose at capture time).
Eye-to-hand: ``p_base = T_base_cam @ p_cam`` (the end pose is not needed).
The difference lives in :meth:`handeye.mounting.MountingMode.T_base_cam`.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError, clip
from .frames import is_rigid_transform, is_rotation, transform_points
from .mounting import MODES, mounting


def T_base_cam_from_result(mode: str, T_x: np.ndarray, T_base_end: np.ndarray | None = None) -> np.ndarray:
    """Camera pose in the base frame for a result ``T_x`` (T_end_cam or T_base_cam)."""
    return mounting(mode).T_base_cam(T_x, T_base_end)


def points_cam_to_base(
    p_cam: np.ndarray, *, mode: str, T_x: np.ndarray, T_base_end: np.ndarray | None = None
) -> np.ndarray:
    """Points (N,3) or (3,) in the camera frame (metres) -> robot base frame (metres)."""
    p = np.asarray(p_cam, float)
    if p.shape[-1] != 3 or not np.all(np.isfinite(p)):
        raise InputError("points must be finite x, y, z in metres", received=clip(p.tolist(), 60))
    return transform_points(T_base_cam_from_result(mode, T_x, T_base_end), p)


def pose_cam_to_base(
    T_cam_obj: np.ndarray, *, mode: str, T_x: np.ndarray, T_base_end: np.ndarray | None = None
) -> np.ndarray:
    """An object pose seen by the camera, ``T_cam_obj``, as ``T_base_obj``."""
    T = np.asarray(T_cam_obj, float)
    if T.shape != (4, 4) or not is_rotation(T[:3, :3], tol=1e-6):
        raise InputError("object pose must be a 4x4 rigid transform")
    return T_base_cam_from_result(mode, T_x, T_base_end) @ T


def result_transform(result: dict) -> tuple[str, np.ndarray]:
    """(mode, T_x) from a loaded result.json, with checks."""
    mode = result.get("mode")
    if result.get("status", "ok") != "ok":
        raise InputError(
            f"the result is a failed calibration ({str(result.get('failure_reason', '')).strip()})",
            hint="calibrate again and apply a successful result",
            code="failed_result",
        )
    if mode not in MODES:
        raise InputError("result.json has no valid mounting mode", expected=" | ".join(MODES), received=repr(mode))
    key = mounting(mode).x_name
    if key not in result:
        raise InputError(f"result.json has no hand-eye transform {key}", expected=f"mode {mode} and {key}")
    if not is_rigid_transform(result[key]):
        raise InputError(
            f"damaged: {key} is not a finite 4x4 rigid transform",
            code="result_damaged",
            hint="the file was edited or damaged: restore it or calibrate again",
        )
    return mode, np.asarray(result[key], float)
