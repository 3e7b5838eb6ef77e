"""Render synthetic target images through exactly OpenCV's lens model.

Every pixel is supersampled (s x s samples, each with its own x and y in the pixel, :func:`_pixel_samples`):
each sub-pixel sample is undistorted (Newton iterations on OpenCV's 5-coefficient model, round-trip checked),
intersected with the board plane and looked up in the board texture, and the samples are box-averaged, so the
image is anti-aliased and its geometry is that of ``cv2.projectPoints``. Pixel centres are at integer
coordinates (OpenCV's convention).

See docs/simulation.md.
"""

from __future__ import annotations

import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import Optional, Union

import cv2
import numpy as np

from ..camera import FOLD_SHARE, Intrinsics, pixels_from_cam_points, radial_fold
from ..collect.visibility import pattern_bounds
from ..errors import ConfigError
from ..targets import AprilGridSpec, CharucoSpec, ChessboardSpec, MarkerSpec, TargetSpec

log = logging.getLogger(__name__)

#: Grey levels of the printed board as a camera typically sees them (not 0/255: paper and ink).
BLACK_LEVEL = 30.0
WHITE_LEVEL = 225.0
BACKGROUND_LEVEL = 128.0
BOARD_BACK_LEVEL = 150.0  # the unprinted back of the board

_ROUNDTRIP_TOL_PX = 1e-6
_CHUNK_OUTPUT_ROWS = 32
_N_THREADS = 2

_grid_lock = threading.Lock()
_grid_cache: dict = {}  # key -> (Hs, Ws, 2) float32 undistorted normalized coordinates
_GRID_CACHE_MAX = 2
_bg_cache: dict = {}
_tex_cache: dict = {}


def _intrinsics_key(intrinsics: Intrinsics) -> tuple:
    return (
        float(intrinsics.fx),
        float(intrinsics.fy),
        float(intrinsics.cx),
        float(intrinsics.cy),
        tuple(float(d) for d in intrinsics.dist),
        int(intrinsics.width),
        int(intrinsics.height),
    )


#: the n-rooks permutations (p, q) of :func:`_pixel_samples` for 4 x 4 samples (the renderers' default): of the 64
#: pairs that keep the samples point-symmetric about the pixel centre (an X junction's corner then has no bias from
#: them), the one with the smallest worst edge error (averaged over 30 px of an edge, every 2.5 deg, 10 offsets)
_ROOKS = {4: ((1, 0, 3, 2), (2, 3, 0, 1))}


@lru_cache(maxsize=16)
def _pixel_samples(s: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) offsets (s, s) px from the pixel centre of its s^2 samples: one per row and column of an s^2 grid.

    Sample (j, i) (the i-th of the j-th row of the pixel's block) lies at x = (i + (p_j + 1/2) / s) / s, y = (j +
    (q_i + 1/2) / s) / s (less 1/2): every sample has its own x and y. On the plain s x s grid an edge near a
    pixel axis covered a pixel in steps of 1/s, the same pixel after pixel: 0.125 px off at 4 x 4, a ramp of that
    along an edge a degree off the axis, which tilted a single marker's fitted sides (0.25 px at a corner).
    p, q: :data:`_ROOKS`, else in order (a sheared grid); both keep the samples point-symmetric about the pixel's
    centre. Averaged over 30 px of an edge, 4 x 4 samples put it 0.037 px off at worst over every angle, 0.008 px
    RMS; the sheared grid 0.088 and 0.010, the plain grid 0.094 and 0.014.
    """
    p, q = (np.asarray(v) for v in _ROOKS.get(s, (range(s), range(s))))
    j, i = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    x = (i + (p[j] + 0.5) / s) / s - 0.5
    y = (j + (q[i] + 0.5) / s) / s - 0.5
    return x, y


def _sample_uv(W: int, H: int, s: int, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) px (r1 - r0, W*s) of the samples of sample rows r0..r1 (:func:`_pixel_samples` in every pixel)."""
    x, y = _pixel_samples(s)
    rows, cols = np.arange(r0, r1)[:, None], np.arange(W * s)[None, :]
    j, i = rows % s, cols % s
    return cols // s + x[j, i], rows // s + y[j, i]


def _newton_undistort(
    x: np.ndarray, y: np.ndarray, xt: np.ndarray, yt: np.ndarray, dist, *, iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Solve distort(x, y) = (xt, yt) by Newton steps from (x, y); all float64 arrays."""
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        xy = x * y
        ex = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x) - xt
        ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy - yt
        a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x  # d xd / dx
        b = 2.0 * xy * dradial + 2.0 * p1 * x + 2.0 * p2 * y  # d xd / dy = d yd / dx
        c = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x  # d yd / dy
        det = a * c - b * b
        x = x - (c * ex - b * ey) / det
        y = y - (a * ey - b * ex) / det
    return x, y


def _roundtrip_px(intrinsics: Intrinsics, x: np.ndarray, y: np.ndarray, u: np.ndarray, v: np.ndarray) -> float:
    """Largest |projection of the normalized points (x, y) - their pixels (u, v)|, in px (THE projection)."""
    x, y = np.broadcast_arrays(x, y)
    p_cam = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)
    uv = pixels_from_cam_points(intrinsics.as_vector(), p_cam, jacobians=False)[0]
    u, v = np.broadcast_to(u, x.shape).ravel(), np.broadcast_to(v, x.shape).ravel()
    return float(max(np.max(np.abs(uv[:, 0] - u)), np.max(np.abs(uv[:, 1] - v))))


def _build_grid(intrinsics: Intrinsics, s: int) -> np.ndarray:
    W, H = intrinsics.width, intrinsics.height
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    dist = intrinsics.dist
    rd_fold, r_table, rd_table = radial_fold(dist)
    corner_rd = max(np.hypot((u - cx) / fx, (v - cy) / fy) for u in (-1.0, W) for v in (-1.0, H))
    if corner_rd >= FOLD_SHARE * rd_fold:  # the model folds over inside the image (else: as every lens)
        return _build_folded_grid(intrinsics, s, rd_fold, r_table, rd_table)
    # Converged inverse on a coarse grid (every g px, one cell beyond the image), interpolated as the
    # start of one Newton step per sample.
    g = 2.0
    cxt = ((np.arange(-g, W - 1 + 2 * g, g) - cx) / fx)[None, :]
    cyt = ((np.arange(-g, H - 1 + 2 * g, g) - cy) / fy)[:, None]
    cxt, cyt = np.broadcast_arrays(cxt, cyt)
    x, y = _newton_undistort(cxt.copy(), cyt.copy(), cxt, cyt, dist, iterations=12)
    coarse = np.stack([x, y], axis=-1).astype(np.float32)
    grid = np.empty((H * s, W * s, 2), np.float32)

    def work(r0: int) -> float:
        r1 = min(H * s, r0 + s * _CHUNK_OUTPUT_ROWS)
        u_px, v_px = _sample_uv(W, H, s, r0, r1)
        map_u = np.ascontiguousarray(((u_px + g) / g).astype(np.float32))
        map_v = np.ascontiguousarray(((v_px + g) / g).astype(np.float32))
        start = cv2.remap(coarse, map_u, map_v, cv2.INTER_LINEAR)
        xt, yt = (u_px - cx) / fx, (v_px - cy) / fy
        x, y = _newton_undistort(start[..., 0].astype(float), start[..., 1].astype(float), xt, yt, dist, iterations=1)
        res_px = _roundtrip_px(intrinsics, x, y, u_px, v_px)
        if res_px > _ROUNDTRIP_TOL_PX:  # strong distortion near the border: polish further
            x, y = _newton_undistort(x, y, xt, yt, dist, iterations=4)
            res_px = _roundtrip_px(intrinsics, x, y, u_px, v_px)
        # Independent check of the float64 solution through cv2.projectPoints (every 97th sample).
        sub_x, sub_y = x.ravel()[::97], y.ravel()[::97]
        uv, _ = cv2.projectPoints(
            np.stack([sub_x, sub_y, np.ones_like(sub_x)], 1),
            np.zeros(3),
            np.zeros(3),
            intrinsics.K,
            intrinsics.dist_array,
        )
        want = np.stack([u_px.ravel()[::97], v_px.ravel()[::97]], 1)
        res_px = max(res_px, float(np.max(np.abs(uv.reshape(-1, 2) - want))))
        grid[r0:r1, :, 0] = x
        grid[r0:r1, :, 1] = y
        return res_px

    with ThreadPoolExecutor(_N_THREADS) as pool:
        worst_px = max(pool.map(work, range(0, H * s, s * _CHUNK_OUTPUT_ROWS)))
    if worst_px > _ROUNDTRIP_TOL_PX or not np.all(np.isfinite(grid)):
        raise ConfigError(
            "cannot invert the lens distortion for rendering",
            expected=f"round trip < {_ROUNDTRIP_TOL_PX} px",
            received=f"{worst_px:.2e} px",
            hint="use milder distortion coefficients",
        )
    log.debug("undistortion grid %dx%d (x%d): worst float64 round trip %.1e px", W, H, s, worst_px)
    return grid


def _build_folded_grid(
    intrinsics: Intrinsics, s: int, rd_fold: float, r_table: np.ndarray, rd_table: np.ndarray
) -> np.ndarray:
    """The grid of a lens model that folds over inside the image: samples past the fold are NaN (they see nothing).

    Each sample starts from the radial model's 1-D inverse (its monotonic part), then Newton steps take in
    the tangential terms; the round trip is checked on the samples that see.
    """
    W, H = intrinsics.width, intrinsics.height
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    grid = np.empty((H * s, W * s, 2), np.float32)
    worst_px = 0.0
    for r0 in range(0, H * s, s * _CHUNK_OUTPUT_ROWS):
        r1 = min(H * s, r0 + s * _CHUNK_OUTPUT_ROWS)
        u_px, v_px = _sample_uv(W, H, s, r0, r1)
        xt, yt = (u_px - cx) / fx, (v_px - cy) / fy
        rd = np.hypot(xt, yt)
        sees = rd < FOLD_SHARE * rd_fold
        r = np.interp(rd, rd_table, r_table)
        k = np.divide(r, rd, out=np.ones_like(rd), where=rd > 0)
        x, y = _newton_undistort(xt * k, yt * k, xt, yt, intrinsics.dist, iterations=8)
        if sees.any():
            worst_px = max(worst_px, _roundtrip_px(intrinsics, x[sees], y[sees], u_px[sees], v_px[sees]))
        grid[r0:r1, :, 0] = np.where(sees, x, np.nan)
        grid[r0:r1, :, 1] = np.where(sees, y, np.nan)
    if worst_px > _ROUNDTRIP_TOL_PX:
        raise ConfigError(
            "cannot invert the lens distortion for rendering",
            expected=f"round trip < {_ROUNDTRIP_TOL_PX} px where the lens model sees",
            received=f"{worst_px:.2e} px",
            hint="use milder distortion coefficients",
        )
    log.info(
        "the lens model folds over at %.3f (normalized radius): %.1f %% of the image sees nothing",
        rd_fold,
        100.0 * float(np.mean(np.isnan(grid[..., 0]))),
    )
    return grid


def undistorted_sample_grid(intrinsics: Intrinsics, *, supersample: int = 4) -> np.ndarray:
    """Undistorted normalized coordinates (H*s, W*s, 2) float32 of every sub-pixel sample (:func:`_sample_uv`).

    Cached per (intrinsics, supersample); the array is read-only. Solved in float64 to a round
    trip below 1e-6 px through OpenCV's model, then stored as float32 (rounding <= ~5e-5 px).
    """
    s = int(supersample)
    if s < 1 or s > 16:
        raise ConfigError("invalid supersample", expected="1..16 samples per pixel axis", received=str(supersample))
    if intrinsics.width <= 0 or intrinsics.height <= 0:
        raise ConfigError(
            "intrinsics without an image size",
            expected="width and height > 0",
            received=f"{intrinsics.width}x{intrinsics.height}",
        )
    key = _intrinsics_key(intrinsics) + (s,)
    with _grid_lock:
        grid = _grid_cache.get(key)
        if grid is None:
            grid = _build_grid(intrinsics, s)
            grid.setflags(write=False)
            while len(_grid_cache) >= _GRID_CACHE_MAX:
                _grid_cache.pop(next(iter(_grid_cache)))
            _grid_cache[key] = grid
    return grid


def roundtrip_error_px(intrinsics: Intrinsics, *, supersample: int = 4, stride: int = 997) -> float:
    """Max |cv2.projectPoints(undistorted sample) - sample pixel| over a strided subset, in px.

    Measures the cached float32 grid (so it includes the float32 storage rounding).
    """
    s = int(supersample)
    grid = undistorted_sample_grid(intrinsics, supersample=s)
    W = intrinsics.width * s
    idx = np.arange(0, grid.shape[0] * grid.shape[1], int(stride))
    idx = idx[np.isfinite(grid.reshape(-1, 2)[idx, 0])]  # samples past a lens model's fold see nothing
    rows, cols = np.divmod(idx, W)
    xy = grid.reshape(-1, 2)[idx].astype(float)
    uv, _ = cv2.projectPoints(
        np.c_[xy, np.ones(len(xy))], np.zeros(3), np.zeros(3), intrinsics.K, intrinsics.dist_array
    )
    x, y = _pixel_samples(s)  # the samples' own places (:func:`_sample_uv`)
    truth = np.stack([cols // s + x[rows % s, cols % s], rows // s + y[rows % s, cols % s]], 1)
    return float(np.max(np.abs(uv.reshape(-1, 2) - truth)))


# --------------------------------------------------------------------------------------------
# Textures
# --------------------------------------------------------------------------------------------


def board_texture(
    target: TargetSpec,
    *,
    margin_squares: int = 1,
    black: float = BLACK_LEVEL,
    white: float = WHITE_LEVEL,
    charuco_px_per_square: int = 120,
) -> tuple[np.ndarray, float]:
    """(texture (h, w, 2) float32 = (grey level, 1), texels per square) of the board with its white border.

    Texel (i, j) covers board x in [x0 + i, x0 + i + 1) / p squares (x0 = left edge of the white
    border), likewise for y. A chessboard uses one texel per square (exact squares); the
    pattern's top-left square is black. ChArUco uses OpenCV's ``CharucoBoard.generateImage``.
    """
    m = int(margin_squares)
    if m < 1:
        raise ConfigError("white border too small", expected="margin_squares >= 1", received=str(margin_squares))
    key = (target, m, float(black), float(white), int(charuco_px_per_square))
    if key in _tex_cache:
        return _tex_cache[key]
    if isinstance(target, ChessboardSpec):
        p = 1
        ny, nx = target.rows + 1 + 2 * m, target.cols + 1 + 2 * m
        jj, ii = np.indices((ny, nx)) - m
        inside = (ii >= 0) & (ii <= target.cols) & (jj >= 0) & (jj <= target.rows)
        dark = inside & ((ii + jj) % 2 == 0)
        grey = np.where(dark, black, white).astype(np.float32)
    elif isinstance(target, CharucoSpec):
        p = int(charuco_px_per_square)
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
        board = cv2.aruco.CharucoBoard(
            (target.squares_x, target.squares_y), target.square_m, target.marker_m, dictionary
        )
        board.setLegacyPattern(bool(target.legacy_pattern))
        size = ((target.squares_x + 2 * m) * p, (target.squares_y + 2 * m) * p)
        img = board.generateImage(size, marginSize=m * p, borderBits=1)
        grey = (black + (white - black) * (img.astype(np.float32) / 255.0)).astype(np.float32)
    elif isinstance(target, (MarkerSpec, AprilGridSpec)):
        p, grey = _marker_texture(target, m, black, white, int(charuco_px_per_square))
    else:
        raise ConfigError(
            "unknown target type",
            expected="a chessboard, ChArUco, marker or AprilGrid spec",
            received=type(target).__name__,
        )
    tex = np.dstack([grey, np.ones_like(grey)])
    tex.setflags(write=False)
    _tex_cache[key] = (tex, float(p))
    return tex, float(p)


def _marker_texture(target, m: int, black: float, white: float, p_min: int) -> tuple[int, np.ndarray]:
    """(texels per tag side, grey texture) of one marker or an AprilGrid with ``m`` tag sides of white border.

    Markers come from cv2.aruco's ``generateImageMarker``: one marker with one black border cell, the code inside;
    an AprilGrid's tags as Kalibr prints them, with ``border_bits`` black border cells (2) and the code as AprilTag
    lays it out, OpenCV's turned by a half turn (with 1 border cell: OpenCV's markers as they are). The texel count
    per tag side is chosen so that every tag corner and gap square falls on a texel edge (exact corners, as for a
    chessboard's squares).
    """
    spacing = getattr(target, "spacing", 0.0)
    border = getattr(target, "border_bits", 1)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
    cells = dictionary.markerSize + 2 * border
    p = next(
        (
            q
            for q in range(max(p_min, cells), cells * max(p_min, cells) + 1)
            if q % cells == 0 and abs(q * spacing - round(q * spacing)) < 1e-6
        ),
        None,
    )
    if p is None:
        raise ConfigError(
            "AprilGrid spacing cannot be rendered exactly",
            expected="a spacing with few decimals (e.g. 0.3)",
            received=repr(spacing),
        )
    x0, x1, y0, y1 = pattern_bounds(target, margin_squares=m)
    per_m = p / target.size_m
    grey = np.full((int(round((y1 - y0) * per_m)), int(round((x1 - x0) * per_m))), white, np.float32)

    def at(x: float, y: float) -> tuple[int, int]:
        return int(round((y - y0) * per_m)), int(round((x - x0) * per_m))

    if isinstance(target, MarkerSpec):
        ids, origins = [target.marker_id], [np.zeros(3)]
    else:
        ids, origins = target.first_id + np.arange(target.n_tags), target.tag_origins()
        g = int(round(spacing * p))
        for c in range(target.cols + 1):
            for r in range(target.rows + 1):
                i, j = at(c * target.pitch_m, r * target.pitch_m)
                grey[i - g : i, j - g : j] = black
    for tag, o in zip(ids, origins, strict=False):
        img = cv2.aruco.generateImageMarker(dictionary, int(tag), p, borderBits=border)
        if border == 2:  # Kalibr's print: the code as AprilTag lays it out
            img = img[::-1, ::-1]
        i, j = at(o[0], o[1])
        grey[i : i + p, j : j + p] = black + (white - black) * (img.astype(np.float32) / 255.0)
    return p, grey


def textured_background(width: int, height: int, *, level: float = BACKGROUND_LEVEL) -> np.ndarray:
    """A fixed mid-grey textured background (H, W) float32: soft blotches plus fine grain."""
    key = (int(width), int(height), float(level))
    if key not in _bg_cache:
        rng = np.random.default_rng(20240611)
        coarse = rng.normal(0.0, 1.0, (max(2, height // 48), max(2, width // 48))).astype(np.float32)
        soft = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
        soft = cv2.GaussianBlur(soft, (0, 0), 12.0)
        soft *= 18.0 / max(float(soft.std()), 1e-6)  # type: ignore[arg-type]  # cv2's stubs: float32 here
        grain = cv2.GaussianBlur(rng.normal(0.0, 6.0, (height, width)).astype(np.float32), (0, 0), 0.8)
        bg = np.clip(level + soft + grain, 40.0, 215.0).astype(np.float32)
        bg.setflags(write=False)
        _bg_cache[key] = bg
    return _bg_cache[key]


def _background(background, width: int, height: int) -> np.ndarray:
    if isinstance(background, str):
        if background == "textured":
            return textured_background(width, height)
        if background == "flat":
            return np.full((height, width), BACKGROUND_LEVEL, np.float32)
        raise ConfigError(
            "unknown background", expected="'textured' | 'flat' | grey level | image", received=repr(background)
        )
    if np.isscalar(background):
        return np.full((height, width), float(background), np.float32)  # type: ignore[arg-type]  # a scalar here
    bg = np.asarray(background)
    if bg.ndim == 3:
        bg = cv2.cvtColor(bg.astype(np.uint8), cv2.COLOR_BGR2GRAY)
    if bg.shape != (height, width):
        raise ConfigError(
            "background image has the wrong size", expected=f"{height}x{width}", received="x".join(map(str, bg.shape))
        )
    return bg.astype(np.float32)


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------


def _texture_from_normalized(
    target: TargetSpec, T_cam_board: np.ndarray, *, margin_squares: int, texels_per_square: float
) -> tuple[np.ndarray, np.ndarray]:
    """(H_tex (3,3), w_row (3,)): texel coords ~ H_tex @ (x, y, 1); ``w_row @ (x, y, 1)`` = 1/depth."""
    T = np.asarray(T_cam_board, float)
    H_cam_board = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])  # (X, Y, 1) -> z (x, y, 1)
    H_board_cam = np.linalg.inv(H_cam_board)  # (x, y, 1) -> (X, Y, 1) / z
    x0, _, y0, _ = pattern_bounds(target, margin_squares=margin_squares)
    k = texels_per_square / target.square_m
    A = np.array([[k, 0.0, -x0 * k - 0.5], [0.0, k, -y0 * k - 0.5], [0.0, 0.0, 1.0]])
    return A @ H_board_cam, H_board_cam[2]


def render_accumulate(
    target: TargetSpec,
    intrinsics: Intrinsics,
    T_cam_board: np.ndarray,
    *,
    supersample: int = 4,
    margin_squares: int = 1,
    black: float = BLACK_LEVEL,
    white: float = WHITE_LEVEL,
) -> tuple[np.ndarray, np.ndarray]:
    """(board grey premultiplied by coverage, coverage) per output pixel, both (H, W) float32.

    Coverage is the fraction of a pixel's samples that hit the board (white border included).
    The board is one-sided: seen from behind (camera on the board's +z side) it is a blank plate.
    """
    T_cam_board = np.asarray(T_cam_board, float)
    if T_cam_board.shape != (4, 4) or not np.all(np.isfinite(T_cam_board)):
        raise ConfigError("invalid T_cam_board", expected="a finite 4x4 transform", received=str(T_cam_board.shape))
    s = int(supersample)
    grid = undistorted_sample_grid(intrinsics, supersample=s)
    tex, p = board_texture(target, margin_squares=margin_squares, black=black, white=white)
    cam_in_board = -T_cam_board[:3, :3].T @ T_cam_board[:3, 3]
    if cam_in_board[2] > 0.0:  # camera behind the board (printed side faces board -z): blank plate
        tex = np.dstack([np.full(tex.shape[:2], BOARD_BACK_LEVEL, np.float32), tex[..., 1]])
    H_tex, w_row = _texture_from_normalized(target, T_cam_board, margin_squares=margin_squares, texels_per_square=p)
    W, H = intrinsics.width, intrinsics.height
    # 1/depth is linear in (x, y): its minimum over the grid's bounding box decides whether any
    # sample ray meets the plane behind the camera or near the horizon (then mask per sample).
    xmin, xmax = float(np.nanmin(grid[..., 0])), float(np.nanmax(grid[..., 0]))  # NaN: past a lens model's fold
    ymin, ymax = float(np.nanmin(grid[..., 1])), float(np.nanmax(grid[..., 1]))
    corners = np.array([[xmin, ymin, 1], [xmin, ymax, 1], [xmax, ymin, 1], [xmax, ymax, 1]])
    min_inv_depth = 1e-3  # rays meeting the plane beyond 1 km (or behind) see no board
    need_mask = bool(np.min(corners @ w_row) <= min_inv_depth)
    acc = np.empty((H, W, 2), np.float32)
    rows_per_chunk = s * _CHUNK_OUTPUT_ROWS

    def work(r0: int) -> None:
        r1 = min(H * s, r0 + rows_per_chunk)
        g = grid[r0:r1]
        m = cv2.perspectiveTransform(g.reshape(-1, 1, 2), H_tex).reshape(r1 - r0, W * s, 2)
        if need_mask:
            inv_depth = g[..., 0] * w_row[0] + g[..., 1] * w_row[1] + w_row[2]
            m[inv_depth <= min_inv_depth] = -1e6
        m[~np.isfinite(g[..., 0])] = -1e6  # a sample past the lens model's fold (NaN) sees nothing
        samples = cv2.remap(  # type: ignore[call-overload]  # cv2's stubs: map2 may be None
            tex, m, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0)
        )
        acc[r0 // s : r1 // s] = cv2.resize(samples, (W, (r1 - r0) // s), interpolation=cv2.INTER_AREA)

    with ThreadPoolExecutor(_N_THREADS) as pool:
        list(pool.map(work, range(0, H * s, rows_per_chunk)))
    return acc[..., 0], acc[..., 1]


def render_view(
    target: TargetSpec,
    intrinsics: Intrinsics,
    T_cam_board: np.ndarray,
    *,
    supersample: int = 4,
    blur_sigma_px: float = 0.0,
    noise_sigma: float = 0.0,
    rng: Optional[np.random.Generator] = None,
    background: Union[str, float, np.ndarray] = "textured",
    channels: int = 1,
    margin_squares: int = 1,
    black: float = BLACK_LEVEL,
    white: float = WHITE_LEVEL,
    gamma: float = 1.0,
) -> np.ndarray:
    r"""An 8-bit image (H, W) (``channels=1``) or BGR (H, W, 3) of the target seen from ``T_cam_board``.

    Anti-aliased with ``supersample``\ :sup:`2` samples per pixel through OpenCV's lens model, the
    board (pattern plus ``margin_squares`` of white border) over ``background`` ("textured" mid
    grey, "flat", a grey level or an (H, W) image), then an optional Gaussian blur
    (``blur_sigma_px``) and Gaussian noise of ``noise_sigma`` grey levels (needs ``rng``), all in light
    (grey levels proportional to it), then the camera's tone curve: grey = 255 (light / 255) ** (1 / ``gamma``)
    (1: none, the default; sRGB encodes about 2.2).
    """
    if channels not in (1, 3):
        raise ConfigError("invalid channels", expected="1 (grey) or 3 (BGR)", received=str(channels))
    if not (0 <= blur_sigma_px < np.inf and 0 <= noise_sigma < np.inf):  # nan too: it would render no noise
        raise ConfigError(
            "blur or noise not a finite number >= 0",
            expected="finite numbers >= 0",
            received=f"blur_sigma_px={blur_sigma_px}, noise_sigma={noise_sigma}",
        )
    if not 0 < gamma < np.inf:
        raise ConfigError("gamma not a finite number > 0", expected="1 (linear), 2.2 (sRGB)", received=repr(gamma))
    if noise_sigma > 0 and rng is None:
        raise ConfigError(
            "image noise needs a random generator", expected="rng=np.random.default_rng(seed)", received="rng=None"
        )
    W, H = intrinsics.width, intrinsics.height
    bg = _background(background, W, H)
    board, cover = render_accumulate(
        target,
        intrinsics,
        T_cam_board,
        supersample=supersample,
        margin_squares=margin_squares,
        black=black,
        white=white,
    )
    img = board + (1.0 - cover) * bg
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), float(blur_sigma_px))
    if noise_sigma > 0:
        assert rng is not None, "checked above"
        img = img + rng.normal(0.0, float(noise_sigma), img.shape).astype(np.float32)
    if gamma != 1.0:
        img = 255.0 * (np.clip(img, 0.0, 255.0) / 255.0) ** (1.0 / float(gamma))
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return cv2.cvtColor(out, cv2.COLOR_GRAY2BGR) if channels == 3 else out
