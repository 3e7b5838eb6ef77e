"""Synthetic calibration sessions with known ground truth.

Two levels, sharing one geometry for a given seed:

* :func:`make_corner_session` -- corner positions projected through the truth (plus optional
  pixel noise), robot poses with optional noise and outliers. No images.
* :func:`write_vendor_session` -- the same session rendered to images (see
  :mod:`handeye.synth_render`) and written in the vendor layout with a ``ground_truth.json``.

Geometry goes through the one model in :mod:`handeye.mounting`:
``T_cam_board_i = inv(T_x) · M_i · T_board`` (``mounting(mode).predict_T_cam_board``).

Randomness: one ``seed`` feeds independent streams (``np.random.SeedSequence(seed).spawn``) for
the setup and view poses, the pixel noise, the robot noise, the outlier choice and the image noise,
so changing a noise level never changes the geometry of the session.

Robot noise convention: the reported pose is ``T_base_end_reported = T_base_end_true @ dT`` where
``dT`` is a small transform expressed in the *end* frame (rotation vector with sigma_deg per axis,
translation with sigma_mm per axis).
"""
from __future__ import annotations

import logging
import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from ..conventions import VENDOR_POSE_FORMAT, pose_values_from_T
from ..errors import ConfigError, DegenerateMotionError
from ..frames import inv_T, make_T, T_from_rotvec, transform_points
from ..mounting import mounting
from ..output import atomic_write_bytes, atomic_write_text, provenance, to_json
from ..mounting import MODES
from ..targets import ChessboardSpec, CharucoSpec, TargetSpec
from ..records import Detection
from ..camera import Intrinsics

log = logging.getLogger(__name__)

DEFAULT_TARGET = ChessboardSpec(11, 8, 0.03)

#: Streams spawned from one seed (index into SeedSequence(seed).spawn(len(_STREAMS))).
_STREAMS = ("geometry", "pixel_noise", "robot_noise", "outliers", "image_noise", "hidden")


def _streams(seed: int) -> dict:
    children = np.random.SeedSequence(int(seed)).spawn(len(_STREAMS))
    return {name: np.random.default_rng(ss) for name, ss in zip(_STREAMS, children)}


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
        raise ConfigError("image size too small", expected="width and height >= 16 px",
                          received=f"{width}x{height}", hint="use e.g. 1280x720 or 640x360")
    s = float(height) / 720.0
    return Intrinsics(fx=_D435_F_PX_AT_720[0] * s, fy=_D435_F_PX_AT_720[1] * s,
                      cx=(width - 1) / 2.0 + _D435_PP_OFFSET_AT_720[0] * s,
                      cy=(height - 1) / 2.0 + _D435_PP_OFFSET_AT_720[1] * s,
                      dist=tuple(float(x) for x in dist), width=int(width), height=int(height))


DEFAULT_INTRINSICS = default_intrinsics()


def distort_normalized(x: np.ndarray, y: np.ndarray, dist: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's 5-coefficient distortion applied to normalized coordinates (same formula as cv2)."""
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    return xd, yd


def pixel_from_cam_point(p_cam: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Pixels (N,2) of camera-frame points (N,3) through ``cv2.projectPoints`` (full 5-coeff model)."""
    p = np.ascontiguousarray(np.asarray(p_cam, float).reshape(-1, 3))
    if p.shape[0] == 0:
        return np.zeros((0, 2))
    uv, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), intrinsics.K, intrinsics.dist_array)
    return uv.reshape(-1, 2)


def pixel_from_board_point(T_cam_board: np.ndarray, p_board: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Pixels (N,2) of board points (N,3) seen from ``T_cam_board``."""
    return pixel_from_cam_point(transform_points(T_cam_board, p_board), intrinsics)


def _fast_pixels(p_cam: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, r2) with the same model as cv2.projectPoints, in numpy (for visibility checks)."""
    z = p_cam[:, 2]
    zs = np.where(z > 1e-9, z, np.nan)
    x, y = p_cam[:, 0] / zs, p_cam[:, 1] / zs
    xd, yd = distort_normalized(x, y, intrinsics.dist)
    return intrinsics.fx * xd + intrinsics.cx, intrinsics.fy * yd + intrinsics.cy, x * x + y * y


_R2_CACHE: dict = {}


def image_normalized_extent(intrinsics: Intrinsics) -> dict:
    """Where the image lies in undistorted normalized coordinates (cached per intrinsics).

    Returns ``{"r2_max": ..., "x_min", "x_max", "y_min", "y_max"}`` from the undistorted image
    border. Raises ConfigError if the distortion folds back (is not monotonic) inside the image,
    because then a pixel no longer has a unique viewing ray.
    """
    key = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, tuple(intrinsics.dist),
           intrinsics.width, intrinsics.height)
    if key in _R2_CACHE:
        return _R2_CACHE[key]
    W, H = intrinsics.width, intrinsics.height
    if W <= 0 or H <= 0:
        raise ConfigError("intrinsics without an image size", expected="width and height > 0",
                          received=f"{W}x{H}", hint="build intrinsics with default_intrinsics(width, height)")
    n = 64
    uu = np.concatenate([np.linspace(-0.5, W - 0.5, n), np.full(n, W - 0.5), np.linspace(W - 0.5, -0.5, n),
                         np.full(n, -0.5)])
    vv = np.concatenate([np.full(n, -0.5), np.linspace(-0.5, H - 0.5, n), np.full(n, H - 0.5),
                         np.linspace(H - 0.5, -0.5, n)])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    xy = cv2.undistortPointsIter(np.stack([uu, vv], -1).reshape(-1, 1, 2), intrinsics.K, intrinsics.dist_array,
                                 None, None, crit).reshape(-1, 2)
    r2 = (xy ** 2).sum(axis=1)
    # d(r * radial(r)) / dr must stay positive up to the image corners (plus a little).
    k1, k2, _, _, k3 = intrinsics.dist
    rr2 = np.linspace(0.0, 1.2 * r2.max(), 200)
    slope = 1.0 + 3 * k1 * rr2 + 5 * k2 * rr2 ** 2 + 7 * k3 * rr2 ** 3
    if np.any(slope <= 0.05):
        raise ConfigError("lens distortion folds back inside the image", expected="monotonic radial distortion",
                          received=f"dist={tuple(intrinsics.dist)}", hint="use milder k1/k2/k3")
    out = {"r2_max": float(r2.max()), "x_min": float(xy[:, 0].min()), "x_max": float(xy[:, 0].max()),
           "y_min": float(xy[:, 1].min()), "y_max": float(xy[:, 1].max())}
    _R2_CACHE[key] = out
    return out


# --------------------------------------------------------------------------------------------
# Target geometry
# --------------------------------------------------------------------------------------------

def pattern_bounds(target: TargetSpec, *, margin_squares: float = 0.0) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) in metres of the printed pattern in the board frame.

    The pattern is the outer edge of the squares; ``margin_squares`` adds the white border.
    Chessboard: corner 0 is at (0,0), so the squares span [-L, cols*L] x [-L, rows*L].
    ChArUco: OpenCV's board spans [0, squares_x*L] x [0, squares_y*L].
    """
    L = target.square_m
    m = margin_squares * L
    if isinstance(target, ChessboardSpec):
        return (-L - m, target.cols * L + m, -L - m, target.rows * L + m)
    if isinstance(target, CharucoSpec):
        return (-m, target.squares_x * L + m, -m, target.squares_y * L + m)
    raise ConfigError("unknown target type", expected="ChessboardSpec | CharucoSpec", received=type(target).__name__)


def _outline_points(target: TargetSpec, *, margin_squares: float = 0.0, n_per_edge: int = 24) -> np.ndarray:
    """Points (4*n, 3) along the pattern's outer edge (dense, since distortion bends lines)."""
    x0, x1, y0, y1 = pattern_bounds(target, margin_squares=margin_squares)
    t = np.linspace(0.0, 1.0, n_per_edge, endpoint=False)
    xs = np.concatenate([x0 + (x1 - x0) * t, np.full_like(t, x1), x1 - (x1 - x0) * t, np.full_like(t, x0)])
    ys = np.concatenate([np.full_like(t, y0), y0 + (y1 - y0) * t, np.full_like(t, y1), y1 - (y1 - y0) * t])
    return np.stack([xs, ys, np.zeros_like(xs)], axis=1)


def _board_grid_points(target: TargetSpec, *, margin_squares: float, step_m: float = 0.01) -> np.ndarray:
    x0, x1, y0, y1 = pattern_bounds(target, margin_squares=margin_squares)
    xs = np.linspace(x0, x1, max(2, int(np.ceil((x1 - x0) / step_m)) + 1))
    ys = np.linspace(y0, y1, max(2, int(np.ceil((y1 - y0) / step_m)) + 1))
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)


def _board_center(target: TargetSpec) -> np.ndarray:
    x0, x1, y0, y1 = pattern_bounds(target)
    return np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0])


def default_margin_px(intrinsics: Intrinsics) -> float:
    """Margin kept between the pattern and the image border: 1.5 % of the width, at least 8 px."""
    return max(8.0, 0.015 * intrinsics.width)


def board_in_image(target: TargetSpec, intrinsics: Intrinsics, T_cam_board: np.ndarray, *,
                   margin_px: Optional[float] = None) -> bool:
    """True if the whole pattern (outer edge of the squares) is in the image with ``margin_px``.

    Also requires every outline point in front of the camera and inside the region where the lens
    model is one-to-one, so a point beyond the distortion fold can never count as visible.
    """
    margin = default_margin_px(intrinsics) if margin_px is None else float(margin_px)
    ext = image_normalized_extent(intrinsics)
    p_cam = transform_points(T_cam_board, _outline_points(target))
    if np.any(p_cam[:, 2] <= 0.05):
        return False
    u, v, r2 = _fast_pixels(p_cam, intrinsics)
    if np.any(r2 > ext["r2_max"]):
        return False
    W, H = intrinsics.width, intrinsics.height
    return bool(np.all((u >= margin - 0.5) & (u <= W - 0.5 - margin) & (v >= margin - 0.5) & (v <= H - 0.5 - margin)))


def board_out_of_image(target: TargetSpec, intrinsics: Intrinsics, T_cam_board: np.ndarray, *,
                       margin_squares: float = 1.0) -> bool:
    """True if no part of the board (white border included) can appear in the image.

    Checked on a 1 cm grid of board points against the bounding box of the image in undistorted
    normalized coordinates (a superset of the image), so the answer is conservative.
    """
    ext = image_normalized_extent(intrinsics)
    p_cam = transform_points(T_cam_board, _board_grid_points(target, margin_squares=margin_squares))
    front = p_cam[:, 2] > 1e-6
    if not np.any(front):
        return True
    x = p_cam[front, 0] / p_cam[front, 2]
    y = p_cam[front, 1] / p_cam[front, 2]
    pad = 0.02
    inside = ((x >= ext["x_min"] - pad) & (x <= ext["x_max"] + pad) & (y >= ext["y_min"] - pad)
              & (y <= ext["y_max"] + pad))
    return not bool(np.any(inside))


# --------------------------------------------------------------------------------------------
# Setup and view poses
# --------------------------------------------------------------------------------------------

def _Rz(a: float) -> np.ndarray:
    return Rotation.from_rotvec([0.0, 0.0, a]).as_matrix()


def _Rx(a: float) -> np.ndarray:
    return Rotation.from_rotvec([a, 0.0, 0.0]).as_matrix()


def _small_tilt(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    """Rotation about a random in-plane (x/y) axis by up to ``max_deg``."""
    phi = rng.uniform(0.0, 2 * np.pi)
    ang = np.radians(rng.uniform(0.0, max_deg))
    return Rotation.from_rotvec(ang * np.array([np.cos(phi), np.sin(phi), 0.0])).as_matrix()


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        mounting(mode)  # raises the standard ConfigError


def sample_setup(*, mode: str, rng: np.random.Generator, target: TargetSpec = DEFAULT_TARGET) -> dict:
    """A plausible ground-truth rig for ``mode``.

    eye_in_hand: camera on the flange (``T_end_cam``: 5-10 cm offset, optical axis within 10 deg
    of the flange z, any rotation about it) and a board lying face-up on the table 0.5-0.7 m in
    front of the base (``T_base_board``; board z points down, into the table).
    eye_to_hand: a fixed camera 1.0-1.5 m from the workspace centre (down to 0.6-0.9 m for
    patterns smaller than 0.36 m, so the board can be shown close up), looking at it from 25-65 deg
    elevation with the image's up roughly up (``T_base_cam``), and a board held by the gripper
    2-5 cm in front of the flange with its printed face along the flange z (``T_end_board``).

    Base frame: x forward, z up, origin on the table top. Returns
    ``{"mode", "x_name", "board_name", "T_x", "T_board"}`` where ``T_x``/``T_board`` are the
    transforms named by ``x_name``/``board_name`` (as in :class:`handeye.records.HandEyeEstimate`).
    """
    _check_mode(mode)
    mount = mounting(mode)
    c_board = _board_center(target)
    if mode == "eye_in_hand":
        while True:
            radial = rng.uniform(0.04, 0.08)
            axial = rng.uniform(0.0, 0.06)
            if 0.05 <= np.hypot(radial, axial) <= 0.10:
                break
        az = rng.uniform(0.0, 2 * np.pi)
        t_end_cam = np.array([radial * np.cos(az), radial * np.sin(az), axial])
        R_end_cam = _Rz(rng.uniform(-np.pi, np.pi)) @ _small_tilt(rng, 10.0)
        T_x = make_T(R_end_cam, t_end_cam)
        center_base = np.array([rng.uniform(0.5, 0.7), rng.uniform(-0.15, 0.15), rng.uniform(0.0, 0.02)])
        R_base_board = _Rz(rng.uniform(-np.pi, np.pi)) @ _Rx(np.pi) @ _small_tilt(rng, 2.0)
        T_board = make_T(R_base_board, center_base - R_base_board @ c_board)
    else:
        work = np.array([rng.uniform(0.4, 0.6), rng.uniform(-0.1, 0.1), rng.uniform(0.15, 0.35)])
        # 1.0-1.5 m; closer for boards smaller than the default, which must come near the camera
        board_scale = default_distance_m(target)[1] / 0.9
        dist = rng.uniform(1.0, 1.5) * float(np.clip(board_scale, 0.6, 1.0))
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
    return {"mode": mode, "x_name": mount.x_name, "board_name": mount.board_name, "T_x": T_x, "T_board": T_board}


def default_distance_m(target: TargetSpec) -> tuple[float, float]:
    """Camera-to-board-centre range: 0.35-0.9 m for a 0.36 m pattern, scaled with the pattern size."""
    x0, x1, y0, y1 = pattern_bounds(target)
    s = max(x1 - x0, y1 - y0) / 0.36
    return (0.35 * s, 0.9 * s)


def _T_cam_board_from_view(target: TargetSpec, *, distance_m: float, tilt_rad: float, tilt_dir_rad: float,
                           roll_rad: float, aim_x_rad: float, aim_y_rad: float) -> np.ndarray:
    """Camera aimed at the board centre from ``distance_m``, tilted and rolled, then panned slightly."""
    c = _board_center(target)
    R_tilt = Rotation.from_rotvec(tilt_rad * np.array([np.cos(tilt_dir_rad), np.sin(tilt_dir_rad), 0.0])).as_matrix()
    R_board_cam = R_tilt @ _Rz(roll_rad)  # roll about the optical axis
    o_board = c - distance_m * R_board_cam[:, 2]
    R_board_cam = R_board_cam @ Rotation.from_rotvec([aim_x_rad, aim_y_rad, 0.0]).as_matrix()
    return inv_T(make_T(R_board_cam, o_board))


def _T_base_end_from_T_cam_board(mode: str, T_x: np.ndarray, T_board: np.ndarray, T_cam_board: np.ndarray) -> np.ndarray:
    """Invert the model: T_cam_board = inv(T_x) · M · T_board  ->  M  ->  T_base_end."""
    mount = mounting(mode)
    M = T_x @ T_cam_board @ inv_T(T_board)
    return mount.T_base_end_from_M(M)


def _plausible_robot_pose(mode: str, T_base_end: np.ndarray, reach_m: tuple[float, float]) -> bool:
    p = T_base_end[:3, 3]
    r = float(np.linalg.norm(p))
    return reach_m[0] <= r <= reach_m[1] and p[2] > 0.05


def rotation_spread_deg(T_cam_board: np.ndarray) -> float:
    """How well the relative rotations of the views span all three axes, in degrees.

    sqrt of the smallest eigenvalue of the mean outer product of the relative rotation vectors of
    all view pairs. 0 when every relative rotation shares one axis or one plane (hand-eye
    degenerate); the typical relative rotation size when the motion is rich.
    """
    T = np.asarray(T_cam_board, float).reshape(-1, 4, 4)
    if T.shape[0] < 2:
        return 0.0
    i, j = np.triu_indices(T.shape[0], k=1)
    R_rel = np.einsum("nji,njk->nik", T[i, :3, :3], T[j, :3, :3])  # R_i^T R_j
    rv = Rotation.from_matrix(R_rel).as_rotvec()  # (P, 3)
    S = rv.T @ rv / rv.shape[0]
    return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(S)[0], 0.0))))


def sample_view_poses(*, mode: str, n_views: int, rng: np.random.Generator, T_x: np.ndarray, T_board: np.ndarray,
                      target: TargetSpec = DEFAULT_TARGET, intrinsics: Optional[Intrinsics] = None,
                      distance_m: Optional[tuple[float, float]] = None, tilt_deg: tuple[float, float] = (15.0, 40.0),
                      roll_deg: float = 80.0, aim_deg: float = 6.0, margin_px: Optional[float] = None,
                      reach_m: tuple[float, float] = (0.15, 1.3), min_spread_deg: float = 5.0,
                      max_tries: int = 3000) -> np.ndarray:
    """(N,4,4) robot poses ``T_base_end`` that show the board the way users are told to.

    Per view: camera-to-board-centre distance in ``distance_m`` (default
    :func:`default_distance_m`), a tilt of the viewing direction of ``tilt_deg`` (magnitude) in a
    direction spread over all azimuths (so about both board axes), a roll about the optical axis
    within +-``roll_deg``, a small pan of up to ``aim_deg`` so the board is not always centred.
    Distances, rolls and tilt directions are stratified across views. A view is resampled until
    the whole pattern is in the image with ``margin_px`` and the flange is within ``reach_m`` of
    the base origin and above the table. With 3 or more views the relative rotations must span all
    three axes (:func:`rotation_spread_deg` >= ``min_spread_deg``), else the set is redrawn.
    """
    _check_mode(mode)
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

    for _attempt in range(20):
        u_d, u_roll, u_dir = strata(), strata(), strata()
        out = np.empty((n_views, 4, 4))
        T_cb = np.empty((n_views, 4, 4))
        for k in range(n_views):
            for tries in range(max_tries):
                if tries < 40:  # stay in this view's strata, jitter the rest
                    jd, jr, jp = u_d[k], u_roll[k], u_dir[k]
                else:
                    jd, jr, jp = rng.uniform(size=3)
                T_cam_board = _T_cam_board_from_view(
                    target, distance_m=d_lo + (d_hi - d_lo) * jd, tilt_rad=rng.uniform(t_lo, t_hi),
                    tilt_dir_rad=2 * np.pi * jp, roll_rad=roll * (2 * jr - 1),
                    aim_x_rad=rng.uniform(-aim, aim), aim_y_rad=rng.uniform(-aim, aim))
                if not board_in_image(target, intrinsics, T_cam_board, margin_px=margin_px):
                    continue
                T_base_end = _T_base_end_from_T_cam_board(mode, T_x, T_board, T_cam_board)
                if not _plausible_robot_pose(mode, T_base_end, reach_m):
                    continue
                out[k], T_cb[k] = T_base_end, T_cam_board
                break
            else:
                raise ConfigError("cannot place the board in the image", expected=(
                    f"a view at {d_lo:.2f}-{d_hi:.2f} m showing the whole pattern with {margin_px:.0f} px margin"),
                    received=f"{max_tries} rejected samples",
                    hint="increase distance_m, reduce tilt_deg/roll_deg or use a smaller target")
        if n_views < 3 or rotation_spread_deg(T_cb) >= min_spread_deg:
            return out
    raise DegenerateMotionError("sampled views do not rotate about all three axes",
                                expected=f"rotation spread >= {min_spread_deg} deg",
                                received=f"{rotation_spread_deg(T_cb):.2f} deg after 20 draws",
                                hint="widen tilt_deg and roll_deg")


def sample_hidden_view_pose(*, mode: str, rng: np.random.Generator, T_x: np.ndarray, T_board: np.ndarray,
                            target: TargetSpec = DEFAULT_TARGET, intrinsics: Optional[Intrinsics] = None,
                            reach_m: tuple[float, float] = (0.15, 1.3), max_tries: int = 3000) -> np.ndarray:
    """A robot pose ``T_base_end`` (4,4) at which no part of the board is in the image.

    A view of the board (distance up to twice the normal range) whose camera is then turned
    40-100 deg about an axis in its image plane: for eye_in_hand the wrist looks away, for
    eye_to_hand the gripper carries the board out of the fixed camera's field of view.
    """
    _check_mode(mode)
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    d_lo, d_hi = default_distance_m(target)
    for _ in range(max_tries):
        T_cam_board = _T_cam_board_from_view(
            target, distance_m=rng.uniform(d_lo, 2.0 * d_hi), tilt_rad=np.radians(rng.uniform(0.0, 30.0)),
            tilt_dir_rad=rng.uniform(0, 2 * np.pi), roll_rad=np.radians(rng.uniform(-80, 80)),
            aim_x_rad=0.0, aim_y_rad=0.0)
        phi = rng.uniform(0.0, 2 * np.pi)
        turn = np.radians(rng.uniform(40.0, 100.0)) * np.array([np.cos(phi), np.sin(phi), 0.0])
        T_cam_board = make_T(Rotation.from_rotvec(turn).as_matrix(), np.zeros(3)) @ T_cam_board
        if not board_out_of_image(target, intrinsics, T_cam_board):
            continue
        T_base_end = _T_base_end_from_T_cam_board(mode, T_x, T_board, T_cam_board)
        if _plausible_robot_pose(mode, T_base_end, reach_m):
            return T_base_end
    raise ConfigError("cannot sample a pose that hides the board", expected="a reachable pose looking away",
                      received=f"{max_tries} rejected samples", hint="widen reach_m")


# --------------------------------------------------------------------------------------------
# Robot noise and outliers
# --------------------------------------------------------------------------------------------

def perturb_T_base_end(T_base_end: np.ndarray, *, rng: np.random.Generator, sigma_mm: float,
                       sigma_deg: float) -> np.ndarray:
    """``T_base_end @ dT`` with dT in the end frame: rotation vector ~ N(0, sigma_deg) and
    translation ~ N(0, sigma_mm) per axis. Input (N,4,4), output a new (N,4,4)."""
    T = np.asarray(T_base_end, float).reshape(-1, 4, 4)
    n = T.shape[0]
    rv = rng.normal(0.0, np.radians(sigma_deg), size=(n, 3))
    t = rng.normal(0.0, sigma_mm * 1e-3, size=(n, 3))
    dT = np.stack([T_from_rotvec(rv[i], t[i]) for i in range(n)]) if n else np.zeros((0, 4, 4))
    return T @ dT


def outlier_offset(rng: np.random.Generator, *, trans_mm: tuple[float, float] = (5.0, 30.0),
                   rot_deg: tuple[float, float] = (2.0, 10.0)) -> np.ndarray:
    """A gross pose error dT (4,4): random direction, |t| in ``trans_mm``, angle in ``rot_deg``."""
    def unit() -> np.ndarray:
        v = rng.normal(size=3)
        return v / np.linalg.norm(v)
    return T_from_rotvec(np.radians(rng.uniform(*rot_deg)) * unit(), 1e-3 * rng.uniform(*trans_mm) * unit())


# --------------------------------------------------------------------------------------------
# Corner-level session
# --------------------------------------------------------------------------------------------

def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class CornerSession:
    """A synthetic session at corner level, with its ground truth.

    Per view (same order as ``view_ids``; look views up by id with :meth:`index`):
    ``corner_ids`` (n,) ints into ``target.object_points()``, ``image_points`` (n,2) noisy pixels
    (empty for hidden views), ``T_base_end_true`` / ``T_base_end_reported`` (N,4,4).
    ``T_x_true`` is ``T_end_cam`` (eye_in_hand) or ``T_base_cam`` (eye_to_hand); ``T_board_true``
    is ``T_base_board`` or ``T_end_board`` (see ``x_name``/``board_name``).
    Reported = true @ dT (end frame) with robot noise ``robot_noise`` = (sigma_mm, sigma_deg) per
    axis, plus a gross error on ``outlier_view_ids``.
    """

    mode: str
    target: TargetSpec
    intrinsics: Intrinsics
    T_x_true: np.ndarray
    T_board_true: np.ndarray
    view_ids: tuple
    corner_ids: tuple
    image_points: tuple
    T_base_end_true: np.ndarray
    T_base_end_reported: np.ndarray
    outlier_view_ids: tuple = ()
    hidden_view_ids: tuple = ()
    noise_px: float = 0.0
    robot_noise: tuple = (0.0, 0.0)
    seed: int = 0

    @property
    def x_name(self) -> str:
        return mounting(self.mode).x_name

    @property
    def board_name(self) -> str:
        return mounting(self.mode).board_name

    @property
    def n_views(self) -> int:
        return len(self.view_ids)

    def index(self, view_id: str) -> int:
        try:
            return self.view_ids.index(str(view_id))
        except ValueError:
            raise KeyError(view_id) from None

    @property
    def T_cam_board_true(self) -> np.ndarray:  # (N, 4, 4)
        return mounting(self.mode).predict_T_cam_board(self.T_x_true, self.T_board_true, self.T_base_end_true)

    def detections(self) -> tuple:
        """:class:`handeye.records.Detection` per visible view (hidden views have none)."""
        size = (self.intrinsics.width, self.intrinsics.height)
        return tuple(Detection(view_id=vid, corner_ids=ids, image_points=pts, image_size=size)
                     for vid, ids, pts in zip(self.view_ids, self.corner_ids, self.image_points) if len(ids))


def _resolve_view_ids(n_views: int, ids, what: str) -> tuple:
    valid = {str(k) for k in range(1, n_views + 1)}
    out = tuple(str(v) for v in ids)
    bad = [v for v in out if v not in valid]
    if bad:
        raise ConfigError(f"unknown view ids in {what}", expected=f"ids among 1..{n_views}", received=repr(bad))
    if len(set(out)) != len(out):
        raise ConfigError(f"duplicate view ids in {what}", expected="each id once", received=repr(list(out)))
    return tuple(sorted(out, key=int))


def make_corner_session(*, mode: str = "eye_in_hand", n_views: int = 20, seed: int = 0,
                        target: TargetSpec = DEFAULT_TARGET, intrinsics: Optional[Intrinsics] = None,
                        noise_px: float = 0.3, robot_noise: tuple[float, float] = (0.0, 0.0),
                        outlier_views: Union[int, Sequence[str]] = 0, hidden_views: Sequence[str] = (),
                        outlier_trans_mm: tuple[float, float] = (5.0, 30.0),
                        outlier_rot_deg: tuple[float, float] = (2.0, 10.0), **view_options) -> CornerSession:
    """A corner-level synthetic session with ground truth (see module docstring for seeding).

    ``noise_px``: Gaussian sigma (px, per coordinate) added to the projected corners.
    ``robot_noise``: (sigma_mm, sigma_deg) per axis on the reported ``T_base_end`` (end frame).
    ``outlier_views``: a count (ids drawn at random among visible views) or explicit ids; those
    views' reported pose gets an extra gross error (``outlier_trans_mm``, ``outlier_rot_deg``).
    ``hidden_views``: ids whose robot pose turns the camera away (no corners, detection fails).
    ``view_options`` go to :func:`sample_view_poses` (distance_m, tilt_deg, roll_deg, ...).
    All corners are projected with ``cv2.projectPoints`` through
    ``mounting(mode).predict_T_cam_board(T_x_true, T_board_true, T_base_end_true)``.
    """
    _check_mode(mode)
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    n_views = int(n_views)
    if noise_px < 0 or robot_noise[0] < 0 or robot_noise[1] < 0:
        raise ConfigError("negative noise level", expected="noise_px, robot_noise >= 0",
                          received=f"noise_px={noise_px}, robot_noise={tuple(robot_noise)}")
    view_ids = tuple(str(k) for k in range(1, n_views + 1))
    hidden = _resolve_view_ids(n_views, hidden_views, "hidden_views")
    rngs = _streams(seed)
    visible = [v for v in view_ids if v not in hidden]
    if isinstance(outlier_views, (int, np.integer)):
        if not 0 <= int(outlier_views) <= len(visible):
            raise ConfigError("too many outlier views", expected=f"0..{len(visible)} (visible views)",
                              received=str(outlier_views))
        picked = rngs["outliers"].choice(len(visible), size=int(outlier_views), replace=False)
        outliers = tuple(sorted((visible[i] for i in picked), key=int))
    else:
        outliers = _resolve_view_ids(n_views, outlier_views, "outlier_views")
        if set(outliers) & set(hidden):
            raise ConfigError("a view cannot be both hidden and an outlier", expected="disjoint id sets",
                              received=repr(sorted(set(outliers) & set(hidden), key=int)))

    geo = rngs["geometry"]
    setup = sample_setup(mode=mode, rng=geo, target=target)
    T_x, T_board = setup["T_x"], setup["T_board"]
    T_vis = sample_view_poses(mode=mode, n_views=len(visible), rng=geo, T_x=T_x, T_board=T_board, target=target,
                              intrinsics=intrinsics, **view_options)
    T_true = np.empty((n_views, 4, 4))
    it = iter(T_vis)
    hid_rng = rngs["hidden"]
    for k, vid in enumerate(view_ids):
        if vid in hidden:
            T_true[k] = sample_hidden_view_pose(mode=mode, rng=hid_rng, T_x=T_x, T_board=T_board, target=target,
                                                intrinsics=intrinsics)
        else:
            T_true[k] = next(it)

    T_rep = perturb_T_base_end(T_true, rng=rngs["robot_noise"], sigma_mm=float(robot_noise[0]),
                               sigma_deg=float(robot_noise[1]))
    out_rng = rngs["outliers"]
    for vid in outliers:
        k = view_ids.index(vid)
        T_rep[k] = T_rep[k] @ outlier_offset(out_rng, trans_mm=outlier_trans_mm, rot_deg=outlier_rot_deg)

    T_cam_board = mounting(mode).predict_T_cam_board(T_x, T_board, T_true)
    obj = target.object_points()
    all_ids = np.arange(target.n_corners)
    px_rng = rngs["pixel_noise"]
    ids_out, pts_out = [], []
    for k, vid in enumerate(view_ids):
        if vid in hidden:
            ids_out.append(_frozen(np.zeros(0, dtype=int)))
            pts_out.append(_frozen(np.zeros((0, 2))))
            continue
        uv = pixel_from_board_point(T_cam_board[k], obj, intrinsics)
        uv = uv + px_rng.normal(0.0, float(noise_px), size=uv.shape) if noise_px > 0 else uv
        ids_out.append(_frozen(all_ids))
        pts_out.append(_frozen(uv))
    return CornerSession(mode=mode, target=target, intrinsics=intrinsics, T_x_true=_frozen(T_x),
                         T_board_true=_frozen(T_board), view_ids=view_ids, corner_ids=tuple(ids_out),
                         image_points=tuple(pts_out), T_base_end_true=_frozen(T_true),
                         T_base_end_reported=_frozen(T_rep), outlier_view_ids=outliers, hidden_view_ids=hidden,
                         noise_px=float(noise_px), robot_noise=(float(robot_noise[0]), float(robot_noise[1])),
                         seed=int(seed))


# --------------------------------------------------------------------------------------------
# Vendor-layout session on disk (rendered images)
# --------------------------------------------------------------------------------------------

_VENDOR_FILE_RE = r"^\d+\.(jpg|png)$"


def _clear_previous_session(out: Path, *, overwrite: bool) -> None:
    names = [p.name for p in out.iterdir()] if out.exists() else []
    ours = [n for n in names if re.match(_VENDOR_FILE_RE, n) or n in ("poses.txt", "config.yaml",
                                                                        "ground_truth.json")]
    if not ours:
        return
    if not overwrite:
        raise ConfigError("output folder already holds a session", path=out,
                          expected="an empty or new folder", received=f"{len(ours)} session files (e.g. {ours[0]})",
                          hint="choose another folder or pass overwrite=True")
    for n in ours:
        (out / n).unlink()


def write_vendor_session(out_dir, *, mode: str = "eye_in_hand", n_views: int = 20, seed: int = 0,
                         image_noise: float = 0.0, blur_sigma_px: float = 0.0,
                         robot_noise: tuple[float, float] = (0.0, 0.0), hidden_views: Sequence[str] = (),
                         outlier_views: Union[int, Sequence[str]] = 0, image_format: str = "jpg",
                         target: ChessboardSpec = DEFAULT_TARGET, intrinsics: Optional[Intrinsics] = None,
                         supersample: int = 4, jpeg_quality: int = 95, overwrite: bool = False,
                         workers: int = 2, **view_options) -> Path:
    """Render a synthetic session in the vendor layout and return its folder.

    Writes ``1.jpg .. N.jpg`` (or ``.png``; BGR, JPEG quality ``jpeg_quality``), ``poses.txt``
    (line k = reported ``T_base_end`` of k.jpg as ``x,y,z,rx,ry,rz``, metres and radians,
    R = Rz·Ry·Rx, ``%.9f``), ``config.yaml`` (``checkerboard_args: {XX, YY, L}`` and ``mode``) and
    ``ground_truth.json`` (true hand-eye and board under their frame names, intrinsics, per-view
    true/reported robot poses, true ``T_cam_board``, hidden/outlier flags, noise settings, seed).
    Every file is written atomically (temporary name in the folder, then ``os.replace``).

    The geometry is that of ``make_corner_session(mode=..., n_views=..., seed=..., ...)`` with the
    same arguments, so corner-level and image-level experiments share their ground truth.
    ``image_noise``: Gaussian noise sigma in grey levels; ``blur_sigma_px``: Gaussian blur;
    ``hidden_views``: ids whose robot pose turns the camera away from the board (detection must
    fail there); ``outlier_views``: count or ids given a gross robot pose error.
    """
    from . import render as synth_render  # imported here: the renderer builds on this module

    if not isinstance(target, ChessboardSpec):
        raise ConfigError("the vendor layout describes chessboards only", expected="a ChessboardSpec target",
                          received=type(target).__name__, hint="render ChArUco boards with synth_render.render_view")
    fmt = str(image_format).lower().lstrip(".")
    if fmt == "jpeg":
        fmt = "jpg"
    if fmt not in ("jpg", "png"):
        raise ConfigError("unsupported image format", expected="jpg | png", received=repr(image_format))
    if image_noise < 0 or blur_sigma_px < 0:
        raise ConfigError("negative image noise or blur", expected=">= 0",
                          received=f"image_noise={image_noise}, blur_sigma_px={blur_sigma_px}")
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    session = make_corner_session(mode=mode, n_views=n_views, seed=seed, target=target, intrinsics=intrinsics,
                                  noise_px=0.0, robot_noise=robot_noise, outlier_views=outlier_views,
                                  hidden_views=hidden_views, **view_options)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _clear_previous_session(out, overwrite=overwrite)

    T_cam_board = session.T_cam_board_true
    view_rngs = _streams(seed)["image_noise"].spawn(session.n_views)
    encode_params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if fmt == "jpg" else []
    synth_render.undistorted_sample_grid(intrinsics, supersample=supersample)  # build the cache once

    def render_one(k: int) -> str:
        img = synth_render.render_view(target, intrinsics, T_cam_board[k], supersample=supersample,
                                       blur_sigma_px=blur_sigma_px, noise_sigma=image_noise, rng=view_rngs[k],
                                       channels=3)
        ok, buf = cv2.imencode("." + fmt, img, encode_params)
        if not ok:  # pragma: no cover - cv2 always encodes jpg/png
            raise ConfigError("image encoding failed", expected=f"a .{fmt} image", received="cv2.imencode False")
        name = f"{session.view_ids[k]}.{fmt}"
        atomic_write_bytes(out / name, buf.tobytes())
        log.debug("rendered %s", name)
        return name

    with ThreadPoolExecutor(max(1, int(workers))) as pool:
        names = list(pool.map(render_one, range(session.n_views)))

    lines = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT))
             for T in session.T_base_end_reported]
    atomic_write_text(out / "poses.txt", "\n".join(lines) + "\n")
    config = {"checkerboard_args": {"XX": int(target.cols), "YY": int(target.rows), "L": float(target.square_m)},
              "mode": mode}
    atomic_write_text(out / "config.yaml", yaml.safe_dump(config, sort_keys=False))

    mount = mounting(mode)
    views = {}
    for k, vid in enumerate(session.view_ids):
        views[vid] = {"image": names[k], "T_base_end_true": session.T_base_end_true[k].tolist(),
                      "T_base_end_reported": session.T_base_end_reported[k].tolist(),
                      "T_cam_board_true": T_cam_board[k].tolist(), "hidden": vid in session.hidden_view_ids,
                      "outlier": vid in session.outlier_view_ids}
    truth = {
        "handeye_synthetic_ground_truth": 1,
        "mode": mode,
        "frames": ("T_a_b maps points of frame b into frame a (p_a = T_a_b @ p_b), metres; cam is the optical "
                   "frame (x right, y down, z forward); T_cam_board_i = inv(" + mount.x_name + ") . M_i . "
                   + mount.board_name),
        mount.x_name: session.T_x_true.tolist(),
        mount.board_name: session.T_board_true.tolist(),
        "target": target.to_dict(),
        "intrinsics": intrinsics.to_dict(),
        "views": views,
        "hidden_view_ids": list(session.hidden_view_ids),
        "outlier_view_ids": list(session.outlier_view_ids),
        "noise": {
            "image_noise_grey_levels": float(image_noise),
            "blur_sigma_px": float(blur_sigma_px),
            "robot_noise_mm": float(session.robot_noise[0]),
            "robot_noise_deg": float(session.robot_noise[1]),
            "robot_noise_convention": ("T_base_end_reported = T_base_end_true @ dT, dT in the end frame: "
                                       "per-axis Gaussian rotation vector (deg) and translation (mm)"),
            "outlier_trans_mm": list(view_options.get("outlier_trans_mm", (5.0, 30.0))),
            "outlier_rot_deg": list(view_options.get("outlier_rot_deg", (2.0, 10.0))),
            "render_supersample": int(supersample),
            "jpeg_quality": int(jpeg_quality) if fmt == "jpg" else None,
        },
        "seed": int(seed),
        "provenance": provenance(extra={"generator": "handeye.sim.synth.write_vendor_session"}),
    }
    atomic_write_text(out / "ground_truth.json", to_json(truth) + "\n")
    log.info("wrote synthetic %s session with %d views to %s", mode, session.n_views, out)
    return out
