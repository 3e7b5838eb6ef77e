"""Is the board in the image? Pattern extent, the image in normalized coordinates, visibility tests.

Used by the pose planner (a planned view must show the whole pattern) and by the simulator (sampled
views show the whole pattern; hidden views none of it). Pixels come from THE projection
(:func:`handeye.camera.pixels_from_cam_points`); the undistorted image border comes from OpenCV's
iterative undistortion (an inverse mapping, not a projection).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from ..camera import FOLD_SHARE, Intrinsics, pixels_from_cam_points, radial_fold
from ..config import load_preset
from ..errors import ConfigError
from ..frames import transform_points
from ..targets import AprilGridSpec, CharucoSpec, ChessboardSpec, CircleGridSpec, MarkerSpec, TargetSpec

#: Margins and depth limit of a visible board (configs/collect.yaml ``visibility:``, with their origin).
_LIMITS = load_preset("collect")["visibility"]


def pattern_bounds(target: TargetSpec, *, margin_squares: float = 0.0) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) in metres of the printed pattern in the board frame.

    The pattern is the outer edge of the squares; ``margin_squares`` adds the white border.
    Chessboard: corner 0 is at (0,0), so the squares span [-L, cols*L] x [-L, rows*L].
    ChArUco: OpenCV's board spans [0, squares_x*L] x [0, squares_y*L].
    Circle grid: the dot centres plus one spacing on every side (room for the dots themselves).
    Marker: its black square, [0, size]^2. AprilGrid: the tags and the black squares in the gaps around them.
    """
    L = target.square_m
    m = margin_squares * L
    if isinstance(target, ChessboardSpec):
        return (-L - m, target.cols * L + m, -L - m, target.rows * L + m)
    if isinstance(target, CharucoSpec):
        return (-m, target.squares_x * L + m, -m, target.squares_y * L + m)
    if isinstance(target, MarkerSpec):
        return (-m, L + m, -m, L + m)
    if isinstance(target, AprilGridSpec):
        gap = target.spacing * L  # Kalibr's black squares sit in the gaps at every tag corner, the outer ones too
        return (-gap - m, target.cols * target.pitch_m + m, -gap - m, target.rows * target.pitch_m + m)
    if isinstance(target, CircleGridSpec):
        p = target.object_points()
        return (
            float(p[:, 0].min()) - L - m,
            float(p[:, 0].max()) + L + m,
            float(p[:, 1].min()) - L - m,
            float(p[:, 1].max()) + L + m,
        )
    raise ConfigError(
        "unknown target type",
        expected="a chessboard, ChArUco, circle grid, marker or AprilGrid spec",
        received=type(target).__name__,
    )


def board_center(target: TargetSpec) -> np.ndarray:
    """Centre (3,) of the printed pattern in the board frame, metres."""
    x0, x1, y0, y1 = pattern_bounds(target)
    return np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0])


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


def default_margin_px(intrinsics: Intrinsics) -> float:
    """Margin kept between the pattern and the image border.

    Margin kept between the pattern and the image border (configs/collect.yaml ``visibility:``:
    1.5 % of the width, at least 8 px).
    """
    return max(float(_LIMITS["min_margin_px"]), float(_LIMITS["margin_share_of_width"]) * intrinsics.width)


def image_normalized_extent(intrinsics: Intrinsics) -> dict:
    """Where the image lies in undistorted normalized coordinates (cached per intrinsics).

    Returns ``{"r2_max": ..., "x_min", "x_max", "y_min", "y_max"}`` from the undistorted image
    border. Raises ConfigError if the distortion folds back (is not monotonic) inside the image,
    because then a pixel no longer has a unique viewing ray.
    """
    return dict(
        _normalized_extent(
            intrinsics.fx,
            intrinsics.fy,
            intrinsics.cx,
            intrinsics.cy,
            tuple(float(d) for d in intrinsics.dist),
            int(intrinsics.width),
            int(intrinsics.height),
        )
    )


@functools.lru_cache(maxsize=16)
def _normalized_extent(fx: float, fy: float, cx: float, cy: float, dist: tuple, W: int, H: int) -> dict:
    if W <= 0 or H <= 0:
        raise ConfigError(
            "intrinsics without an image size",
            expected="width and height > 0",
            received=f"{W}x{H}",
            hint="give the intrinsics their image size",
        )
    n = 64
    uu = np.concatenate(
        [np.linspace(-0.5, W - 0.5, n), np.full(n, W - 0.5), np.linspace(W - 0.5, -0.5, n), np.full(n, -0.5)]
    )
    vv = np.concatenate(
        [np.full(n, -0.5), np.linspace(-0.5, H - 0.5, n), np.full(n, H - 0.5), np.linspace(H - 0.5, -0.5, n)]
    )
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    # a lens model that folds over inside the image (a fit from poorly spread corners) sees nothing past
    # its fold: the region is the image's boundary where it sees, and the fold's circle elsewhere
    rd_fold, r_table, rd_table = radial_fold(dist)
    rd = np.hypot((uu - cx) / fx, (vv - cy) / fy)
    sees = rd < FOLD_SHARE * rd_fold
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    xy = cv2.undistortPointsIter(  # type: ignore[call-overload]  # OpenCV's stubs: None for R and P
        np.stack([uu[sees], vv[sees]], -1).reshape(-1, 1, 2), K, np.asarray(dist, float), None, None, crit
    ).reshape(-1, 2)
    if not sees.all():
        r_fold = float(np.interp(FOLD_SHARE * rd_fold, rd_table, r_table))
        a = np.linspace(0.0, 2.0 * np.pi, 4 * n, endpoint=False)
        circle = r_fold * np.stack([np.cos(a), np.sin(a)], 1)
        k = np.array([fx, fy, cx, cy, *dist], float)
        uv = pixels_from_cam_points(k, np.c_[circle, np.ones(len(circle))], jacobians=False)[0]
        inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
        xy = np.concatenate([xy, circle[inside]])
    r2 = (xy**2).sum(axis=1)
    return {
        "r2_max": float(r2.max()),
        "x_min": float(xy[:, 0].min()),
        "x_max": float(xy[:, 0].max()),
        "y_min": float(xy[:, 1].min()),
        "y_max": float(xy[:, 1].max()),
    }


def board_in_image(
    target: TargetSpec, intrinsics: Intrinsics, T_cam_board: np.ndarray, *, margin_px: float | None = None
) -> bool:
    """True if the whole pattern (outer edge of the squares) is in the image with ``margin_px``.

    Also requires every outline point in front of the camera and inside the region where the lens
    model is one-to-one, so a point beyond the distortion fold can never count as visible.
    """
    margin = default_margin_px(intrinsics) if margin_px is None else float(margin_px)
    ext = image_normalized_extent(intrinsics)
    p_cam = transform_points(T_cam_board, _outline_points(target))  # shape (4n, 3)
    if np.any(p_cam[:, 2] <= float(_LIMITS["min_depth_m"])):
        return False
    r2 = (p_cam[:, 0] ** 2 + p_cam[:, 1] ** 2) / p_cam[:, 2] ** 2
    if np.any(r2 > ext["r2_max"]):
        return False
    uv = pixels_from_cam_points(intrinsics.as_vector(), p_cam, jacobians=False)[0]
    W, H = intrinsics.width, intrinsics.height
    u, v = uv[:, 0], uv[:, 1]
    return bool(np.all((u >= margin - 0.5) & (u <= W - 0.5 - margin) & (v >= margin - 0.5) & (v <= H - 0.5 - margin)))


def board_out_of_image(
    target: TargetSpec, intrinsics: Intrinsics, T_cam_board: np.ndarray, *, margin_squares: float = 1.0
) -> bool:
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
    inside = (
        (x >= ext["x_min"] - pad) & (x <= ext["x_max"] + pad) & (y >= ext["y_min"] - pad) & (y <= ext["y_max"] + pad)
    )
    return not bool(np.any(inside))
