"""Pose-only sessions of a simulated arm and tracker, with the effects real tracker data bring.

A joint-space motion program of a preset arm (all joints, or only some: e.g. a UR arm's three
parallel joints, a degenerate motion); the arm's systematic error (a true DH table off the nominal
one, encoder noise: :mod:`.robot_error`); the tracker's noise anisotropic in the camera frame (a
monocular marker tracker is noisier along its optical axis), Gaussian or heavy-tailed (Student-t);
gross errors on a few robot or tracker poses; a time offset between robot and tracker; a scale
error of the tracker's translations (monocular SLAM, a wrong marker size) and a drift of the target
pose (visual odometry). Each session keeps its ground truth; see docs/simulation.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..frames import inv_T, se3_exp
from ..kinematics import T_base_end, load_arm
from .poses import TrackerSession
from .robot_error import make_kinematic_error, report_poses

OUTLIER_POSES = ("robot", "tracker", "both")

#: a comfortable UR-like start configuration (rad): elbow up, tool pointing down
HOME_RAD = np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])


@dataclass(frozen=True)
class ArmTrackerTruth:
    """Ground truth of :func:`make_arm_tracker_session` (the names :class:`TrackerSession` users read)."""

    mode: str
    T_x_true: np.ndarray  # (4,4) T_end_cam (eye_in_hand) or T_base_cam (eye_to_hand)
    T_board_true: np.ndarray  # (4,4) T_base_board (eye_in_hand) or T_end_board (eye_to_hand)
    joints_rad: np.ndarray  # (N, 6): the true joint angles at capture
    scale: float = 1.0
    drift_start: int | None = None  # index of the first drifted view
    outlier_view_ids: tuple = field(default_factory=tuple)
    arm: str = "ur5e"
    #: per outlier view id: which pose has the gross error ("robot" or "tracker")
    outlier_poses: dict = field(default_factory=dict)
    #: the true flange poses at capture (N,4,4); the session's T_base_end are the reported ones
    T_base_end_true: np.ndarray | None = None
    joints_reported_rad: np.ndarray | None = None  # (N, 6): the encoder readings of the commanded joints
    robot_error: dict | None = None  # :meth:`.robot_error.KinematicRobotError.describe`, or None (exact arm)
    sigma_mm: float = 0.0  # the tracker's noise (scale of the Student-t when tracker_dof is set)
    sigma_deg: float = 0.0
    axial_factor: float = 1.0
    tracker_dof: float | None = None  # Student-t degrees of freedom of the tracker's noise; None: Gaussian
    time_offset: float = 0.0  # fraction of the move to the next configuration the arm had made at capture


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
    dh_length_error_mm: tuple[float, float] | None = None,
    dh_angle_error_deg: tuple[float, float] | None = None,
    encoder_sigma_deg: float = 0.0,
    tracker_dof: float | None = None,
    outlier_views: int = 0,
    outlier_poses: str = "both",
    outlier_mm: tuple[float, float] = (20.0, 50.0),
    outlier_deg: tuple[float, float] = (2.0, 5.0),
    time_offset: float = 0.0,
) -> TrackerSession:
    """A pose-only session of ``arm`` moved by a joint program, seen by a tracker.

    ``moving_joints`` move by up to ``joint_range_deg`` about the home configuration, the others by
    ``other_range_deg``. The tracker's noise is ``sigma_mm`` / ``sigma_deg`` per axis, its translation
    noise along the camera's z axis ``axial_factor`` times larger. ``scale`` multiplies every measured
    translation; ``drift_mm_per_view`` moves the target by that much per view from ``drift_start`` on
    (a drifting odometry), along a fixed direction drawn from the seed; ``step_mm`` moves it once, by
    that much, at ``drift_start`` (a target that was knocked).

    The arm's error: a true arm whose a and d are off the nominal ones by a magnitude uniform in
    ``dh_length_error_mm`` and alpha and theta_offset by one in ``dh_angle_error_deg`` (random signs),
    read by encoders with ``encoder_sigma_deg`` of noise; the reported ``T_base_end`` is the nominal
    model's forward kinematics of the encoder angles, the flange is at the true arm's.
    ``tracker_dof``: the tracker's noise is Student-t with that many degrees of freedom (one scale
    factor per view: a bad detection spoils the whole pose), ``sigma_mm`` / ``sigma_deg`` its scale.
    ``outlier_views`` views get a gross error (a rotation uniform in ``outlier_deg`` about a random axis
    and a translation uniform in ``outlier_mm`` along a random direction) on the robot pose, the
    tracker pose, or (``outlier_poses="both"``) either, drawn per view. ``time_offset``: at capture the
    arm has made that fraction of its move to the next configuration, while the robot reports the
    configuration it was commanded to (a robot moving while the tracker captures).
    The new options draw from their own random stream: without them a seed gives the session it gave.
    """
    if outlier_poses not in OUTLIER_POSES:
        raise ValueError(f"outlier_poses must be one of {OUTLIER_POSES}, not {outlier_poses!r}")
    rng = np.random.default_rng(seed)
    rng2 = np.random.default_rng([int(seed), 26])  # the options added later: the old stream unchanged
    chain = load_arm(arm)
    moving = np.zeros(6, bool)
    moving[list(moving_joints)] = True
    span = np.where(moving, np.radians(joint_range_deg), np.radians(other_range_deg))
    q = HOME_RAD + rng.uniform(-1.0, 1.0, (n_views, 6)) * span
    q_true = q
    if time_offset:
        q_next = np.vstack([q[1:], HOME_RAD + rng2.uniform(-1.0, 1.0, 6) * span])
        q_true = q + float(time_offset) * (q_next - q)
    error = None
    if dh_length_error_mm is not None or dh_angle_error_deg is not None or encoder_sigma_deg:
        error = make_kinematic_error(
            rng=rng2,
            arm=arm,
            length_error_mm=dh_length_error_mm or (0.0, 0.0),
            angle_error_deg=dh_angle_error_deg or (0.0, 0.0),
            encoder_sigma_deg=encoder_sigma_deg,
        )
        T_true = error.true.T_base_end(q_true).reshape(-1, 4, 4)
        q_rep, T_be = report_poses(error, q, rng=rng2)
    else:
        T_true = np.stack([T_base_end(chain, qi) for qi in q_true])
        q_rep, T_be = q, np.stack([T_base_end(chain, qi) for qi in q])
    T_x, T_board = _rig(rng, mode)
    if mode == "eye_in_hand":
        C = inv_T(T_x)[None] @ inv_T(T_true) @ T_board[None]  # T_cam_board = T_cam_end T_end_base T_base_board
    else:
        C = inv_T(T_x)[None] @ T_true @ T_board[None]  # T_cam_board = T_cam_base T_base_end T_end_board
    start = n_views // 2 if drift_start is None else int(drift_start)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    noise_sd = np.r_[[np.radians(sigma_deg)] * 3, [sigma_mm / 1000.0] * 2, axial_factor * sigma_mm / 1000.0]
    rows = []
    for k in range(n_views):
        T = C[k].copy()
        if k >= start:
            T[:3, 3] += ((k - start + 1) * drift_mm_per_view + step_mm) / 1000.0 * direction
        n = rng.standard_normal(6) * noise_sd
        if tracker_dof is not None:
            n /= np.sqrt(rng2.chisquare(float(tracker_dof)) / float(tracker_dof))
        T = T @ se3_exp(np.r_[n[:3], 0.0, 0.0, 0.0])
        T[:3, 3] += n[3:]  # translation noise in the camera frame: z is the optical axis
        T[:3, 3] *= scale
        rows.append(T)
    measured = np.stack(rows)
    ids = tuple(f"{k + 1:03d}" for k in range(n_views))
    hit: dict = {}
    if outlier_views:
        T_be = T_be.copy()
        for k in np.sort(rng2.choice(n_views, size=int(outlier_views), replace=False)):
            which = outlier_poses if outlier_poses != "both" else ("robot", "tracker")[int(rng2.integers(2))]
            axis, direction = rng2.normal(size=3), rng2.normal(size=3)
            rot = np.radians(rng2.uniform(*outlier_deg)) * axis / np.linalg.norm(axis)
            move = rng2.uniform(*outlier_mm) / 1000.0 * direction / np.linalg.norm(direction)
            E = se3_exp(np.r_[rot, 0.0, 0.0, 0.0])
            E[:3, 3] = move
            if which == "robot":
                T_be[k] = T_be[k] @ E
            else:
                measured[k] = measured[k] @ E
            hit[ids[k]] = which
    truth = ArmTrackerTruth(
        mode,
        T_x,
        T_board,
        q_true,
        scale,
        start if drift_mm_per_view or step_mm else None,
        outlier_view_ids=tuple(hit),
        arm=arm,
        outlier_poses=hit,
        T_base_end_true=T_true,
        joints_reported_rad=q_rep,
        robot_error=None if error is None else error.describe(),
        sigma_mm=float(sigma_mm),
        sigma_deg=float(sigma_deg),
        axial_factor=float(axial_factor),
        tracker_dof=None if tracker_dof is None else float(tracker_dof),
        time_offset=float(time_offset),
    )
    along = float(axial_factor * sigma_mm) if axial_factor != 1.0 else None
    return TrackerSession(truth, ids, measured, T_be, float(sigma_mm), float(sigma_deg), sigma_mm_along=along)
