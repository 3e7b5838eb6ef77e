"""Scenarios: the ground truth of a synthetic rig and the robot poses it is shown from.

The default camera and target, independent seeded random streams (a noise level never changes the
geometry), a plausible rig per mounting mode, view poses that show or hide the board, and robot pose
noise and outliers. Geometry goes through :mod:`handeye.mounting`; the reported pose is
``T_base_end_true @ dT`` with ``dT`` a small transform in the end frame.

See docs/simulation.md.
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import numpy as np

from ..camera import Intrinsics
from ..collect.visibility import board_center, board_in_image, board_out_of_image, default_margin_px, pattern_bounds
from ..errors import ConfigError, DegenerateMotionError
from ..frames import R_from_quat_wxyz, R_from_rotvec, T_from_rotvec, inv_T, make_T
from ..initial.motion import MotionQuality, motion_quality
from ..mounting import mounting
from ..targets import ChessboardSpec, TargetSpec

DEFAULT_TARGET = ChessboardSpec(11, 8, 0.03)

#: Streams spawned from one seed (index into SeedSequence(seed).spawn(len(STREAMS))). Append new
#: streams at the end: the existing ones (and so every seeded session) stay as they are.
STREAMS = ("geometry", "pixel_noise", "robot_noise", "outliers", "image_noise", "hidden", "robot_model")


def random_streams(seed: int) -> dict:
    """One independent ``np.random.Generator`` per name in :data:`STREAMS`, all from ``seed``."""
    children = np.random.SeedSequence(int(seed)).spawn(len(STREAMS))
    return {name: np.random.default_rng(ss) for name, ss in zip(STREAMS, children, strict=False)}


# --------------------------------------------------------------------------------------------
# Camera
# --------------------------------------------------------------------------------------------

# RealSense-D435-like colour camera at 1280x720. The D435 colour sensor's 4:3 modes are crops of
# the 16:9 ones, so the focal length scales with the image height (640x480 -> fx ~ 607).
_D435_F_PX_AT_720 = (910.5, 909.8)  # fx, fy
_D435_PP_OFFSET_AT_720 = (3.2, 1.7)  # principal point minus image centre (px)
_DEFAULT_DIST = (0.10, -0.25, 1.0e-3, 8.0e-4, 0.10)  # k1, k2, p1, p2, k3 (mild, monotonic in the image)


def default_intrinsics(width: int = 1280, height: int = 720, *, dist: Sequence[float] = _DEFAULT_DIST) -> Intrinsics:
    """D435-like colour intrinsics for an image of ``width`` x ``height`` pixels.

    At 1280x720: fx=910.5, fy=909.8, cx=643.2, cy=361.7, dist (k1, k2, p1, p2, k3) =
    (0.10, -0.25, 1e-3, 8e-4, 0.10). Other sizes keep the vertical field of view (focal length
    and principal-point offset scale with ``height / 720``), like the real sensor's modes.
    """
    if int(width) < 16 or int(height) < 16:
        raise ConfigError(
            "image size too small",
            expected="width and height >= 16 px",
            received=f"{width}x{height}",
            hint="use e.g. 1280x720 or 640x360",
        )
    s = float(height) / 720.0
    return Intrinsics(
        fx=_D435_F_PX_AT_720[0] * s,
        fy=_D435_F_PX_AT_720[1] * s,
        cx=(width - 1) / 2.0 + _D435_PP_OFFSET_AT_720[0] * s,
        cy=(height - 1) / 2.0 + _D435_PP_OFFSET_AT_720[1] * s,
        dist=tuple(float(x) for x in dist),
        width=int(width),
        height=int(height),
    )


DEFAULT_INTRINSICS = default_intrinsics()


# --------------------------------------------------------------------------------------------
# Setup and view poses
# --------------------------------------------------------------------------------------------


def _Rz(a: float) -> np.ndarray:
    return R_from_rotvec(np.array([0.0, 0.0, a]))


def _Rx(a: float) -> np.ndarray:
    return R_from_rotvec(np.array([a, 0.0, 0.0]))


def _small_tilt(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    """Rotation about a random in-plane (x/y) axis by up to ``max_deg``."""
    phi = rng.uniform(0.0, 2 * np.pi)
    ang = np.radians(rng.uniform(0.0, max_deg))
    return R_from_rotvec(ang * np.array([np.cos(phi), np.sin(phi), 0.0]))


def _camera_on_flange(rng: np.random.Generator, c_board: np.ndarray, target: TargetSpec, scale: float = 1.0) -> tuple:
    """(T_end_cam, T_base_board): camera on the flange, board lying face-up on the table."""
    while True:
        radial = rng.uniform(0.04, 0.08)
        axial = rng.uniform(0.0, 0.06)
        if 0.05 <= np.hypot(radial, axial) <= 0.10:
            break
    az = rng.uniform(0.0, 2 * np.pi)
    t_end_cam = np.array([radial * np.cos(az), radial * np.sin(az), axial])
    R_end_cam = _Rz(rng.uniform(-np.pi, np.pi)) @ _small_tilt(rng, 10.0)
    T_x = make_T(R_end_cam, t_end_cam)
    center_base = np.array([rng.uniform(0.5, 0.7) * scale, rng.uniform(-0.15, 0.15) * scale, rng.uniform(0.0, 0.02)])
    R_base_board = _Rz(rng.uniform(-np.pi, np.pi)) @ _Rx(np.pi) @ _small_tilt(rng, 2.0)
    T_board = make_T(R_base_board, center_base - R_base_board @ c_board)
    return T_x, T_board


def _camera_beside_robot(
    rng: np.random.Generator, c_board: np.ndarray, target: TargetSpec, scale: float = 1.0
) -> tuple:
    """(T_base_cam, T_end_board): a fixed camera looking at the workspace, board in the gripper."""
    work = np.array([rng.uniform(0.4, 0.6), rng.uniform(-0.1, 0.1), rng.uniform(0.15, 0.35)]) * scale
    # 1.0-1.5 m; closer for boards smaller than the default, which must come near the camera
    board_scale = default_distance_m(target)[1] / 0.9
    dist = rng.uniform(1.0, 1.5) * float(np.clip(board_scale, 0.6, 1.0)) * scale
    az = np.radians(rng.uniform(-100.0, 100.0))
    el = np.radians(rng.uniform(25.0, 65.0))
    cam = work + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    z = (work - cam) / np.linalg.norm(work - cam)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_base_cam = np.stack([x, y, z], axis=1) @ _Rz(np.radians(rng.uniform(-10.0, 10.0)))
    T_x = make_T(R_base_cam, cam)
    R_end_board = _Rx(np.pi) @ _Rz(rng.uniform(-np.pi, np.pi)) @ _small_tilt(rng, 3.0)
    center_end = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.02, 0.05)])
    T_board = make_T(R_end_board, center_end - R_end_board @ c_board)
    return T_x, T_board


#: Rig samplers by the frame the camera is rigid to (``MountingMode.fixed_frame``).
_RIG_BY_CAMERA_FRAME = {"end": _camera_on_flange, "base": _camera_beside_robot}


def sample_setup(
    *, mode: str, rng: np.random.Generator, target: TargetSpec = DEFAULT_TARGET, workspace_scale: float = 1.0
) -> dict:
    """A plausible ground-truth rig for ``mode``.

    eye_in_hand: camera on the flange (``T_end_cam``: 5-10 cm offset, optical axis within 10 deg
    of the flange z, any rotation about it) and a board lying face-up on the table 0.5-0.7 m in
    front of the base (``T_base_board``; board z points down, into the table).
    eye_to_hand: a fixed camera 1.0-1.5 m from the workspace centre (down to 0.6-0.9 m for
    patterns smaller than 0.36 m, so the board can be shown close up), looking at it from 25-65 deg
    elevation with the image's up roughly up (``T_base_cam``), and a board held by the gripper
    2-5 cm in front of the flange with its printed face along the flange z (``T_end_board``).

    ``workspace_scale`` < 1 shrinks the rig for a smaller arm (:func:`handeye.sim.robot_error.workspace_scale`):
    the board (eye_in_hand) or workspace centre (eye_to_hand) positions scale with it, the fixed
    camera's distance too.

    Base frame: x forward, z up, origin on the table top. Returns
    ``{"mode", "x_name", "board_name", "T_x", "T_board"}`` where ``T_x``/``T_board`` are the
    transforms named by ``x_name``/``board_name`` (as in :class:`handeye.records.HandEyeEstimate`).
    """
    mount = mounting(mode)
    if not 0.1 <= float(workspace_scale) <= 1.0:
        raise ConfigError("invalid workspace scale", expected="0.1 <= scale <= 1", received=str(workspace_scale))
    if float(workspace_scale) == 1.0:  # the seeded geometry of every existing session stays as it was
        T_x, T_board = _RIG_BY_CAMERA_FRAME[mount.fixed_frame](rng, board_center(target), target)
    else:
        T_x, T_board = _RIG_BY_CAMERA_FRAME[mount.fixed_frame](
            rng, board_center(target), target, float(workspace_scale)
        )
    return {"mode": mode, "x_name": mount.x_name, "board_name": mount.board_name, "T_x": T_x, "T_board": T_board}


def default_distance_m(target: TargetSpec) -> tuple[float, float]:
    """Camera-to-board-centre range: 0.35-0.9 m for a 0.36 m pattern, scaled with the pattern size."""
    x0, x1, y0, y1 = pattern_bounds(target)
    s = max(x1 - x0, y1 - y0) / 0.36
    return (0.35 * s, 0.9 * s)


def arm_workspace(arm: str, *, mode: str, target: TargetSpec) -> tuple[float, dict]:
    """(workspace scale, view options) of a rig sized for the arm ``arm``.

    (workspace scale, view options) of a rig sized for the arm ``arm`` (a preset of
    :mod:`handeye.kinematics`): the scale for :func:`sample_setup` (:func:`handeye.sim.robot_error.workspace_scale`)
    and, with the camera on the arm, the camera-to-board distances (``distance_m`` of
    :func:`sample_view_poses`) shrunk with the rig, never below 1.5 times the nearest.
    """
    from .robot_error import workspace_scale

    scale = workspace_scale(arm)
    if mounting(mode).fixed_frame != "end":
        return scale, {}
    d_lo, d_hi = default_distance_m(target)
    return scale, {"distance_m": (d_lo, max(1.5 * d_lo, d_hi * scale))}


def _T_cam_board_from_view(
    target: TargetSpec,
    *,
    distance_m: float,
    tilt_rad: float,
    tilt_dir_rad: float,
    roll_rad: float,
    aim_x_rad: float,
    aim_y_rad: float,
) -> np.ndarray:
    """Camera aimed at the board centre from ``distance_m``, tilted and rolled, then panned slightly."""
    c = board_center(target)
    R_tilt = R_from_rotvec(tilt_rad * np.array([np.cos(tilt_dir_rad), np.sin(tilt_dir_rad), 0.0]))
    R_board_cam = R_tilt @ _Rz(roll_rad)  # roll about the optical axis
    o_board = c - distance_m * R_board_cam[:, 2]
    R_board_cam = R_board_cam @ R_from_rotvec(np.array([aim_x_rad, aim_y_rad, 0.0]))
    return inv_T(make_T(R_board_cam, o_board))


def _T_base_end_from_T_cam_board(
    mode: str, T_x: np.ndarray, T_board: np.ndarray, T_cam_board: np.ndarray
) -> np.ndarray:
    """Invert the model: T_cam_board = inv(T_x) · M · T_board  ->  M  ->  T_base_end."""
    mount = mounting(mode)
    M = T_x @ T_cam_board @ inv_T(T_board)
    return mount.T_base_end_from_M(M)


#: The simulated arm's reach: flange distance from the base origin (m), and its lowest height above the table.
REACH_M = (0.15, 1.3)
MIN_FLANGE_HEIGHT_M = 0.05


def plausible_robot_pose(T_base_end: np.ndarray, reach_m: tuple[float, float] = REACH_M) -> bool:
    """The flange within ``reach_m`` of the base origin and above the table."""
    p = T_base_end[:3, 3]
    r = float(np.linalg.norm(p))
    return reach_m[0] <= r <= reach_m[1] and p[2] > MIN_FLANGE_HEIGHT_M


def sample_view_poses(
    *,
    mode: str,
    n_views: int,
    rng: np.random.Generator,
    T_x: np.ndarray,
    T_board: np.ndarray,
    target: TargetSpec = DEFAULT_TARGET,
    intrinsics: Optional[Intrinsics] = None,
    distance_m: Optional[tuple[float, float]] = None,
    tilt_deg: tuple[float, float] = (15.0, 40.0),
    roll_deg: float = 80.0,
    aim_deg: float = 6.0,
    margin_px: Optional[float] = None,
    reach_m: tuple[float, float] = REACH_M,
    min_axis_spread_deg: Optional[float] = None,
    max_tries: int = 3000,
    pose_ok: Optional[Callable[[np.ndarray], bool]] = None,
) -> np.ndarray:
    """(N,4,4) robot poses ``T_base_end`` that show the board the way users are told to.

    Per view: camera-to-board-centre distance in ``distance_m`` (default
    :func:`default_distance_m`), a tilt of the viewing direction of ``tilt_deg`` (magnitude) in a
    direction spread over all azimuths (so about both board axes), a roll about the optical axis
    within +-``roll_deg``, a small pan of up to ``aim_deg`` so the board is not always centred.
    Distances, rolls and tilt directions are stratified across views. A view is resampled until
    the whole pattern is in the image with ``margin_px`` and the flange is within ``reach_m`` of
    the base origin and above the table. With 3 or more views the robot motions must pass the
    calibration's own degeneracy gates (:func:`handeye.initial.motion.motion_quality`; None takes
    ``min_axis_spread_deg`` from configs/calibration.yaml), else the set is redrawn. ``pose_ok``
    (optional) is one more test of each ``T_base_end``, e.g. that a kinematic arm reaches it.
    """
    mount = mounting(mode)
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    n_views = int(n_views)
    if n_views < 1:
        raise ConfigError("too few views", expected="n_views >= 1", received=str(n_views))
    d_lo, d_hi = default_distance_m(target) if distance_m is None else (float(distance_m[0]), float(distance_m[1]))
    if not 0.0 < d_lo <= d_hi:
        raise ConfigError("invalid distance range", expected="0 < min <= max metres", received=f"({d_lo}, {d_hi})")
    margin_px = default_margin_px(intrinsics) if margin_px is None else float(margin_px)
    t_lo, t_hi = np.radians(tilt_deg[0]), np.radians(tilt_deg[1])
    roll = np.radians(roll_deg)
    aim = np.radians(aim_deg)

    def strata() -> np.ndarray:  # (n,) values in [0, 1), one per stratum, shuffled
        return (rng.permutation(n_views) + rng.uniform(0.0, 1.0, n_views)) / n_views

    quality: Optional[MotionQuality] = None
    for _attempt in range(20):
        u_d, u_roll, u_dir = strata(), strata(), strata()
        out = np.empty((n_views, 4, 4))
        for k in range(n_views):
            for tries in range(max_tries):
                if tries < 40:  # stay in this view's strata, jitter the rest
                    jd, jr, jp = u_d[k], u_roll[k], u_dir[k]
                else:
                    jd, jr, jp = rng.uniform(size=3)
                T_cam_board = _T_cam_board_from_view(
                    target,
                    distance_m=d_lo + (d_hi - d_lo) * jd,
                    tilt_rad=rng.uniform(t_lo, t_hi),
                    tilt_dir_rad=2 * np.pi * jp,
                    roll_rad=roll * (2 * jr - 1),
                    aim_x_rad=rng.uniform(-aim, aim),
                    aim_y_rad=rng.uniform(-aim, aim),
                )
                if not board_in_image(target, intrinsics, T_cam_board, margin_px=margin_px):
                    continue
                T_base_end = _T_base_end_from_T_cam_board(mode, T_x, T_board, T_cam_board)
                if not plausible_robot_pose(T_base_end, reach_m):
                    continue
                if pose_ok is not None and not pose_ok(T_base_end):
                    continue
                out[k] = T_base_end
                break
            else:
                raise ConfigError(
                    "cannot place the board in the image",
                    expected=(
                        f"a view at {d_lo:.2f}-{d_hi:.2f} m showing the whole pattern with {margin_px:.0f} px margin"
                    ),
                    received=f"{max_tries} rejected samples",
                    hint="increase distance_m, reduce tilt_deg/roll_deg or use a smaller target",
                )
        if n_views < 3:
            return out
        quality = motion_quality(
            mount.M_from_T_base_end(out), frame=mount.fixed_frame, min_axis_spread_deg=min_axis_spread_deg
        )
        if quality.status == "ok":
            return out
    assert quality is not None, "20 draws made"
    raise DegenerateMotionError(
        "sampled views do not rotate about two different axes",
        expected=f"motion that passes the calibration's gates (rotation >= "
        f"{quality.min_rotation_deg:g} deg, axis spread >= "
        f"{quality.min_axis_spread_deg:g} deg)",
        received=f"{quality.reason} (after 20 draws)",
        hint="widen tilt_deg and roll_deg",
    )


def _reachable_flange_pose(rng: np.random.Generator, reach_m: tuple[float, float]) -> np.ndarray:
    """A flange pose (4,4) uniform over the reach above the table, its orientation uniform.

    The reach is :func:`plausible_robot_pose`'s; the orientation a Gaussian quaternion's.
    """
    while True:
        T = make_T(R_from_quat_wxyz(rng.normal(size=4)), rng.uniform(-reach_m[1], reach_m[1], 3))
        if plausible_robot_pose(T, reach_m):
            return T


def sample_hidden_view_pose(
    *,
    mode: str,
    rng: np.random.Generator,
    T_x: np.ndarray,
    T_board: np.ndarray,
    target: TargetSpec = DEFAULT_TARGET,
    intrinsics: Optional[Intrinsics] = None,
    reach_m: tuple[float, float] = REACH_M,
    max_tries: int = 3000,
    pose_ok: Optional[Callable[[np.ndarray], bool]] = None,
    draw_pose: Optional[Callable[[np.random.Generator], Optional[np.ndarray]]] = None,
) -> np.ndarray:
    """A robot pose ``T_base_end`` (4,4) at which no part of the board is in the image.

    A view of the board (distance up to twice the normal range) whose camera is then turned
    40-100 deg about an axis in its image plane: for eye_in_hand the wrist looks away, for
    eye_to_hand the gripper carries the board out of the fixed camera's field of view. Where none of
    ``max_tries`` such poses is within reach (a fixed camera far from the base, whose field of view
    spans most of what the arm reaches), flange poses drawn over the reach (any orientation) are tried
    as many times, each kept when the board is out of the image. Then, with ``draw_pose`` (an arm's joint
    moves in its configuration, :meth:`handeye.sim.robot_error.OneConfiguration.draw_pose`, where few of
    the poses drawn over the reach are the configuration's), the poses it draws, as many times.
    """
    mounting(mode)  # an unknown mode is a ConfigError
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    d_lo, d_hi = default_distance_m(target)
    for _ in range(max_tries):
        T_cam_board = _T_cam_board_from_view(
            target,
            distance_m=rng.uniform(d_lo, 2.0 * d_hi),
            tilt_rad=np.radians(rng.uniform(0.0, 30.0)),
            tilt_dir_rad=rng.uniform(0, 2 * np.pi),
            roll_rad=np.radians(rng.uniform(-80, 80)),
            aim_x_rad=0.0,
            aim_y_rad=0.0,
        )
        phi = rng.uniform(0.0, 2 * np.pi)
        turn = np.radians(rng.uniform(40.0, 100.0)) * np.array([np.cos(phi), np.sin(phi), 0.0])
        T_cam_board = make_T(R_from_rotvec(turn), np.zeros(3)) @ T_cam_board
        if not board_out_of_image(target, intrinsics, T_cam_board):
            continue
        T_base_end = _T_base_end_from_T_cam_board(mode, T_x, T_board, T_cam_board)
        if plausible_robot_pose(T_base_end, reach_m) and (pose_ok is None or pose_ok(T_base_end)):
            return T_base_end
    mount = mounting(mode)
    drawers: list[Callable[[np.random.Generator], Optional[np.ndarray]]] = [
        lambda r: _reachable_flange_pose(r, reach_m)  # anywhere the arm reaches
    ]
    if draw_pose is not None:
        drawers.append(draw_pose)  # the arm's own moves
    for draw in drawers:
        for _ in range(max_tries):  # each kept when plausible, in the arm's configuration, the board out of the image
            T_drawn = draw(rng)
            if T_drawn is None or not plausible_robot_pose(T_drawn, reach_m):
                continue
            T_cam_board = mount.predict_T_cam_board(T_x, T_board, T_drawn[None])[0]
            if board_out_of_image(target, intrinsics, T_cam_board) and (pose_ok is None or pose_ok(T_drawn)):
                return T_drawn
    raise ConfigError(
        "cannot sample a pose that hides the board",
        expected="a reachable pose looking away",
        received=f"{max_tries} rejected samples",
        hint="the camera sees all the arm reaches in its configuration: simulate another --seed, or no --hidden view",
    )


# --------------------------------------------------------------------------------------------
# Robot noise and outliers
# --------------------------------------------------------------------------------------------


def perturb_T_base_end(
    T_base_end: np.ndarray, *, rng: np.random.Generator, sigma_mm: float, sigma_deg: float
) -> np.ndarray:
    """``T_base_end @ dT`` with dT in the end frame.

    Rotation vector ~ N(0, sigma_deg) and translation ~ N(0, sigma_mm) per axis. Input (N,4,4),
    output a new (N,4,4).
    """
    T = np.asarray(T_base_end, float).reshape(-1, 4, 4)
    n = T.shape[0]
    rv = rng.normal(0.0, np.radians(sigma_deg), size=(n, 3))
    t = rng.normal(0.0, sigma_mm * 1e-3, size=(n, 3))
    dT = np.stack([T_from_rotvec(rv[i], t[i]) for i in range(n)]) if n else np.zeros((0, 4, 4))
    return T @ dT


def outlier_offset(
    rng: np.random.Generator, *, trans_mm: tuple[float, float] = (5.0, 30.0), rot_deg: tuple[float, float] = (2.0, 10.0)
) -> np.ndarray:
    """A gross pose error dT (4,4): random direction, |t| in ``trans_mm``, angle in ``rot_deg``."""

    def unit() -> np.ndarray:
        v = rng.normal(size=3)
        return v / np.linalg.norm(v)

    return T_from_rotvec(np.radians(rng.uniform(*rot_deg)) * unit(), 1e-3 * rng.uniform(*trans_mm) * unit())
