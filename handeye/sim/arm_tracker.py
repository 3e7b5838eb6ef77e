"""Pose-only sessions of a simulated arm and tracker, with the effects real tracker data bring.

A joint-space motion program of a preset arm (all joints, or only some: e.g. a UR arm's three
parallel joints, a degenerate motion), the tracker's noise anisotropic in the camera frame (a
monocular marker tracker is noisier along its optical axis), a scale error of the tracker's
translations (monocular SLAM, a wrong marker size) and a drift of the target pose over the views
(visual odometry). Each session keeps its ground truth; see docs/simulation.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..frames import inv_T, se3_exp
from ..kinematics import T_base_end, load_arm
from .poses import TrackerSession

#: a comfortable UR-like start configuration (rad): elbow up, tool pointing down
HOME_RAD = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])


@dataclass(frozen=True)
class ArmTrackerTruth:
    """Ground truth of :func:`make_arm_tracker_session` (the names :class:`TrackerSession` users read)."""

    mode: str
    T_x_true: np.ndarray  # (4,4) T_end_cam (eye_in_hand) or T_base_cam (eye_to_hand)
    T_board_true: np.ndarray  # (4,4) T_base_board (eye_in_hand) or T_end_board (eye_to_hand)
    joints_rad: np.ndarray  # (N, 6)
    scale: float = 1.0
    drift_start: int | None = None  # index of the first drifted view
    outlier_view_ids: tuple = field(default_factory=tuple)


def _rig(rng: np.random.Generator, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """(T_x, T_board): a camera on the flange looking 0.4-0.6 m ahead, or fixed 1-1.5 m from the base."""
    if mode == "eye_in_hand":
        T_x = se3_exp(np.r_[rng.normal(0, 0.2, 3), rng.uniform(-0.08, 0.08, 2), rng.uniform(0.03, 0.1)])
        T_board = se3_exp(np.r_[rng.normal(0, 0.2, 3), rng.uniform(0.3, 0.6), rng.uniform(-0.3, 0.3), 0.0])
    else:
        T_x = se3_exp(np.r_[rng.normal(0, 0.5, 3), rng.uniform(0.8, 1.2), rng.uniform(-0.4, 0.4), 0.6])
        T_board = se3_exp(np.r_[rng.normal(0, 0.2, 3), rng.uniform(-0.05, 0.05, 2), rng.uniform(0.02, 0.08)])
    return T_x, T_board


def make_arm_tracker_session(
    *,
    arm: str = "ur5e",
    mode: str = "eye_in_hand",
    n_views: int = 20,
    seed: int = 0,
    moving_joints: Sequence[int] = (0, 1, 2, 3, 4, 5),
    joint_range_deg: float = 25.0,
    other_range_deg: float = 0.0,
    sigma_mm: float = 0.5,
    sigma_deg: float = 0.1,
    axial_factor: float = 1.0,
    scale: float = 1.0,
    drift_mm_per_view: float = 0.0,
    drift_start: int | None = None,
    step_mm: float = 0.0,
) -> TrackerSession:
    """A pose-only session of ``arm`` moved by a joint program, seen by a tracker.

    ``moving_joints`` move by up to ``joint_range_deg`` about the home configuration, the others by
    ``other_range_deg``. The tracker's noise is ``sigma_mm`` / ``sigma_deg`` per axis, its translation
    noise along the camera's z axis ``axial_factor`` times larger. ``scale`` multiplies every measured
    translation; ``drift_mm_per_view`` moves the target by that much per view from ``drift_start`` on
    (a drifting odometry), along a fixed direction drawn from the seed; ``step_mm`` moves it once, by
    that much, at ``drift_start`` (a target that was knocked).
    """
    rng = np.random.default_rng(seed)
    chain = load_arm(arm)
    moving = np.zeros(6, bool)
    moving[list(moving_joints)] = True
    span = np.where(moving, np.radians(joint_range_deg), np.radians(other_range_deg))
    q = HOME_RAD + rng.uniform(-1.0, 1.0, (n_views, 6)) * span
    T_be = np.stack([T_base_end(chain, qi) for qi in q])
    T_x, T_board = _rig(rng, mode)
    if mode == "eye_in_hand":
        C = inv_T(T_x)[None] @ inv_T(T_be) @ T_board[None]  # T_cam_board = T_cam_end T_end_base T_base_board
    else:
        C = inv_T(T_x)[None] @ T_be @ T_board[None]  # T_cam_board = T_cam_base T_base_end T_end_board
    start = n_views // 2 if drift_start is None else int(drift_start)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    noise_sd = np.r_[[np.radians(sigma_deg)] * 3, [sigma_mm / 1000.0] * 2, axial_factor * sigma_mm / 1000.0]
    measured = []
    for k in range(n_views):
        T = C[k].copy()
        if k >= start:
            T[:3, 3] += ((k - start + 1) * drift_mm_per_view + step_mm) / 1000.0 * direction
        n = rng.standard_normal(6) * noise_sd
        T = T @ se3_exp(np.r_[n[:3], 0.0, 0.0, 0.0])
        T[:3, 3] += n[3:]  # translation noise in the camera frame: z is the optical axis
        T[:3, 3] *= scale
        measured.append(T)
    truth = ArmTrackerTruth(mode, T_x, T_board, q, scale, start if drift_mm_per_view or step_mm else None)
    ids = tuple(f"{k + 1:03d}" for k in range(n_views))
    return TrackerSession(truth, ids, np.stack(measured), T_be, float(sigma_mm), float(sigma_deg))
