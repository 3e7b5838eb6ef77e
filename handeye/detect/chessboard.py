"""Chessboard corners: OpenCV's searches, two refinement stages, the geometric check and the corner order.

Corners are found by OpenCV's searches (at half size first in large images, on a reduced copy in very
large ones), refined on the full image in windows set from the square size by cornerSubPix and then
by the centre of point symmetry (:mod:`.saddle`; a corner the two put far apart is not used), checked
against the board's own geometry (re-detected by the accurate search when they fail), and the corner
order of boards whose colours tell their orientation is fixed.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any, Sequence

import cv2
import numpy as np

from ..records import FAILS_GRID_CHECK, Detection
from ..targets import ChessboardSpec
from .geometry import TimeBudget, apply_homography, board_homography, check_corners, search_copy, square_px
from .options import DetectionOptions, default_options
from .saddle import shading_free, symmetric_corners

log = logging.getLogger(__name__)


_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
_ACCURATE_FLAGS = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE


def board_squares(spec: ChessboardSpec) -> np.ndarray:
    """Board-plane position of every inner corner in squares, shape (N, 2)."""
    return spec.object_points()[:, :2] / spec.square_m


def subpix_windows(board_xy: np.ndarray, pts: np.ndarray, options: DetectionOptions) -> tuple[np.ndarray, np.ndarray]:
    """(start points (N,2), cornerSubPix half window of each corner (N,) px) for coarse corners ``pts``.

    The board homography is fitted to the coarse corners (:func:`.geometry.board_homography`; robustly
    when a least-squares fit leaves a corner off); the window is ``subpix_window_factor`` x the square's
    size in px at each corner, clipped to [min, max] px; a coarse corner farther than
    ``coarse_outlier_squares`` from the homography's prediction starts from the prediction.
    """
    o = options
    for robust in (False, True):
        H = board_homography(board_xy, pts, robust=robust)
        if H is None:
            return pts, np.full(len(pts), o.subpix_window_min_px)
        sq = square_px(H, board_xy, 1.0)
        pred = apply_homography(H, board_xy)
        off = np.linalg.norm(pts - pred, axis=1) > o.coarse_outlier_squares * sq
        if not off.any():
            break
    if off.any():
        log.debug("%d coarse corners off the board homography restart from it", int(off.sum()))
    start = np.where(off[:, None], pred, pts)
    win = np.clip(np.floor(o.subpix_window_factor * sq), o.subpix_window_min_px, o.subpix_window_max_px).astype(int)
    return start, win


def refine_corners(gray: np.ndarray, pts: np.ndarray, win: np.ndarray, options: DetectionOptions) -> np.ndarray:
    """CornerSubPix of every corner with its own half window (corners of one window size together)."""
    out = np.asarray(pts, np.float32).reshape(-1, 2).copy()
    for w in np.unique(win):
        k = np.flatnonzero(win == w)
        out[k] = cv2.cornerSubPix(
            gray, out[k].reshape(-1, 1, 2), (int(w), int(w)), (-1, -1), options.subpix_criteria
        ).reshape(-1, 2)
    return out.astype(np.float64)


def refine_chessboard(
    gray: np.ndarray,
    search: np.ndarray,
    scale: np.ndarray,
    coarse: np.ndarray,
    spec: ChessboardSpec,
    options: DetectionOptions,
    dropped: list | None = None,
) -> np.ndarray:
    """Full-resolution corners (N,2) from ``coarse`` corners found in ``search``.

    Full-resolution corners (N,2) from ``coarse`` corners found in ``search`` (``gray`` reduced by
    ``scale``, per axis), with windows from the square size; on a reduced search image the corners are first
    refined there, so the full-size windows only correct what the reduction lost. Corners that are not
    trusted (:func:`final_corners`) are NaN (their (id, reason) appended to ``dropped``).
    """
    bxy = board_squares(spec)
    start, win = subpix_windows(bxy, np.asarray(coarse, float).reshape(-1, 2), options)
    if np.any(scale != 1.0):
        start = (refine_corners(search, start, win, options) + 0.5) / scale - 0.5  # pixel centres at integers
        start, win = subpix_windows(bxy, start, options)
    return final_corners(gray, bxy, start, win, options, dropped)


def final_corners(
    gray: np.ndarray,
    board_xy: np.ndarray,
    start: np.ndarray,
    win: np.ndarray,
    options: DetectionOptions,
    dropped: list | None = None,
) -> np.ndarray:
    """The two refinement stages on the full image.

    The two refinement stages on the full image (:mod:`.saddle`), on the part of it around the corners:
    cornerSubPix from ``start`` in half windows ``win``, then the centre of point symmetry in half windows
    of ``saddle_window_factor`` x the square's size, both on the image smoothed by ``subpix_blur_sigma_px``.
    A corner where the two disagree by more than ``corner_disagreement_max_px``, or where the second finds
    no saddle, is NaN (not used), and logged with its reason; (index, reason) of each is appended to
    ``dropped`` when given.
    """
    o = options
    reach = int(np.max(win)) + o.saddle_shading_box_px + int(np.ceil(4 * o.subpix_blur_sigma_px)) + 2
    h, w = gray.shape
    x0, y0 = (max(int(np.floor(v)) - reach, 0) for v in np.nanmin(start, axis=0))
    x1, y1 = (min(int(np.ceil(v)) + reach + 1, n) for v, n in zip(np.nanmax(start, axis=0), (w, h), strict=False))
    shift = np.array([x0, y0], float)
    smooth = cv2.GaussianBlur(gray[y0:y1, x0:x1], (0, 0), o.subpix_blur_sigma_px)
    first = refine_corners(smooth, start - shift, win, o)
    H = board_homography(board_xy, first, robust=False)
    half = (
        win
        if H is None
        else np.clip(
            np.floor(o.saddle_window_factor * square_px(H, board_xy, 1.0)),
            o.subpix_window_min_px,
            o.subpix_window_max_px,
        ).astype(int)
    )
    second, saddle = symmetric_corners(
        shading_free(smooth, box_px=o.saddle_shading_box_px), first, half, iterations=o.saddle_iterations
    )
    apart = np.linalg.norm(second - first, axis=1)
    bad = ~saddle | ~(apart <= o.corner_disagreement_max_px)
    for k in np.flatnonzero(bad):
        why = (
            "no saddle point in its window"
            if not saddle[k]
            else f"cornerSubPix and the symmetry fit put it {apart[k]:.2f} px apart (limit "
            f"{o.corner_disagreement_max_px:g} px, configs/detection.yaml corner_disagreement_max_px)"
        )
        if dropped is None:  # with a list, the caller says it with the view's id
            log.info("corner %d not used: %s", k, why)
        else:
            dropped.append((int(k), why))
    return np.where(bad[:, None], np.nan, second + shift)


def find_chessboard_fast(
    gray: np.ndarray, spec: ChessboardSpec, *, options: DetectionOptions | None = None, budget: TimeBudget | None = None
) -> np.ndarray | None:
    """Corners (N,2) in ``gray``'s pixels as the fast search finds them (not refined), or None.

    Detect on a half-size image first when large: several times faster, and FAST_CHECK rejects an image
    without a board in milliseconds. The full-size search follows unless ``budget`` is spent.
    """
    o = options or default_options()
    size = (spec.cols, spec.rows)
    h, w = gray.shape
    if max(h, w) > o.half_size_above_px:
        small = cv2.resize(gray, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        found, corners = cv2.findChessboardCorners(small, size, flags=_CLASSIC_FLAGS)
        if found:
            return (corners.reshape(-1, 2) + 0.5) * np.array([w / (w // 2), h / (h // 2)]) - 0.5
        if budget is not None and budget.spent():
            return None
    found, corners = cv2.findChessboardCorners(gray, size, flags=_CLASSIC_FLAGS)
    return corners.reshape(-1, 2).astype(np.float64) if found else None


def detect_chessboard(
    gray: np.ndarray,
    spec: ChessboardSpec,
    *,
    options: DetectionOptions | None = None,
    budget: TimeBudget | None = None,
    dropped: list | None = None,
) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner_ids, image points (N,2)) or a reason string.

    The searches run on the image, or on a reduced copy above ``search_max_megapixels``
    (:func:`.geometry.search_copy`); the corners found are refined on the full image with windows
    from the square size (:func:`refine_chessboard`) and must pass the geometric check
    (:func:`.geometry.grid_check`). Corners that fail it are searched again by ``findChessboardCornersSB`` with
    EXHAUSTIVE | ACCURACY; corners that fail it again drop the view with the reason. ``budget`` (default:
    ``time_budget_s``) skips the slower searches once spent: the view is dropped as timed out. ``dropped``:
    a list that receives (corner id, reason) of the corners the returned view does not use.
    """
    o = options or default_options()
    budget = budget or TimeBudget(o.time_budget_s)
    size = (spec.cols, spec.rows)
    notes: list = []
    search, scale = search_copy(gray, max_megapixels=o.search_max_megapixels)
    where = (
        ""
        if np.all(scale == 1.0)
        else (f" (searched at {search.shape[1]}x{search.shape[0]}: the image is above {o.search_max_megapixels:g} MP)")
    )
    coarse = find_chessboard_fast(search, spec, options=o, budget=budget)
    if coarse is None:
        if budget.spent():
            return budget.timed_out("the full-size chessboard searches") + where
        found, corners = cv2.findChessboardCornersSB(search, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return f"chessboard {spec.cols}x{spec.rows} not found{where}"
        coarse = corners.reshape(-1, 2)
    bxy = board_squares(spec)
    pts = refine_chessboard(gray, search, scale, coarse, spec, o, notes)
    edge = _edge_line(bxy, pts)
    if edge:
        return f"chessboard {spec.cols}x{spec.rows} not found: {edge}{where}"
    check = _check(bxy, pts, o)
    if check.passed:
        return _used(pts, notes, dropped)
    log.info("chessboard corners fail the geometric check (%s): searched again by the accurate detector", check.text())
    if budget.spent():
        return budget.timed_out(f"the accurate search after the geometric check failed ({check.text()})") + where
    found, corners = cv2.findChessboardCornersSB(search, size, flags=_ACCURATE_FLAGS)
    if not found:
        return f"chessboard corners {FAILS_GRID_CHECK} ({check.text()}) and the accurate detector finds no board{where}"
    notes.clear()  # the corners of the accurate search replace those of the first
    pts = refine_chessboard(gray, search, scale, corners.reshape(-1, 2).astype(np.float64), spec, o, notes)
    edge = _edge_line(bxy, pts)
    if edge:
        return f"chessboard {spec.cols}x{spec.rows} not found: {edge}{where}"
    again = _check(bxy, pts, o)
    if not again.passed:
        return f"chessboard corners {FAILS_GRID_CHECK}, also from the accurate detector: {again.text()}{where}"
    return _used(pts, notes, dropped)


def _edge_line(board_xy: np.ndarray, pts: np.ndarray) -> str | None:
    """Why the grid is not the board when every corner of one of its outer rows or columns was left out, else None.

    OpenCV's searches can fit a grid one row or column larger than the board: its outer line then lies on the
    board's edge, where squares meet the margin (no saddle; the symmetry fit moves each 2-3 px), and every
    other corner would take its neighbour's id. The view is not used; the caller names the size the image shows.
    """
    lost = ~np.isfinite(pts[:, 0])
    for axis, name in ((0, "column"), (1, "row")):
        for end in (board_xy[:, axis].min(), board_xy[:, axis].max()):
            line = np.isclose(board_xy[:, axis], end)
            if lost[line].all():
                return f"the grid found has an outer {name} of no chessboard corners (the board's edge?)"
    return None


def _check(board_xy: np.ndarray, pts: np.ndarray, options: DetectionOptions):
    """The geometric check of the corners that are used (rows of ``pts`` that are not NaN)."""
    keep = np.flatnonzero(np.isfinite(pts[:, 0]))
    c = check_corners(board_xy[keep], pts[keep], options)
    res, lim = np.full(len(pts), np.nan), np.full(len(pts), np.inf)
    res[keep], lim[keep] = c.residual_px, c.limit_px
    return replace(c, residual_px=res, limit_px=lim, worst=int(keep[c.worst]) if c.worst >= 0 else -1)


def _used(
    pts: np.ndarray, notes: Sequence[Any] = (), dropped: list[Any] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(corner ids, image points) of the corners that are used (not NaN).

    (corner ids, image points) of the corners that are used (not NaN); ``notes`` (the reasons of the
    others) go to ``dropped`` when given.
    """
    if dropped is not None:
        dropped.extend(notes)
    else:  # no caller to say them with the view's id
        for k, why in notes:
            log.info("corner %d not used: %s", k, why)
    ids = np.flatnonzero(np.isfinite(pts[:, 0]))
    return ids, pts[ids]


def order_cue(gray: np.ndarray, pts: np.ndarray, cols: int, rows: int, ids: np.ndarray | None = None) -> float:
    """Grey level of the square between the first four corners minus that of the last square.

    On a chessboard with cols + rows odd these two squares have opposite colours, so the sign tells
    from which end the detector numbered the corners. ``ids``: the corner ids of ``pts`` when some
    corners were not used; the missing ones are placed by the board homography of the others.
    """
    if cols < 2 or rows < 2:
        return float("nan")
    if ids is not None and len(ids) < cols * rows:
        bxy = np.stack(np.divmod(np.arange(cols * rows), cols)[::-1], axis=1).astype(float)
        H = board_homography(bxy[ids], pts, robust=False)
        if H is None:
            return float("nan")
        full = apply_homography(H, bxy)
        full[ids] = pts
        pts = full
    grid = pts.reshape(rows, cols, 2)

    def grey(quad):
        c = quad.reshape(-1, 2).mean(axis=0)
        r = max(1, int(0.15 * np.linalg.norm(quad[0, 0] - quad[1, 1])))
        x, y = int(round(c[0])), int(round(c[1]))
        win = gray[max(y - r, 0) : y + r + 1, max(x - r, 0) : x + r + 1]
        return float(win.mean()) if win.size else float("nan")

    return grey(grid[:2, :2]) - grey(grid[-2:, -2:])


def board_order(det: Detection, spec: ChessboardSpec, *, min_grey: float) -> Detection:
    """One view of an asymmetric chessboard numbered from the end whose first square is dark.

    OpenCV sometimes numbers a (blurred, oblique) board from the other end; on a board with cols + rows
    odd the square between the first four corners and the last one have opposite colours, so the colour
    of the first square (``Detection.order_cue``: its grey minus the last one's) tells the end. The board's
    print fixes the numbering (corner 0 at the corner of a dark square, as the boards handeye renders and
    as OpenCV numbers the real ViSP board), so a view's order depends on its own image only, never on the
    other views. A cue weaker than ``min_grey`` (grey levels) leaves the view as found; symmetric boards
    (cols + rows even) are left to the motion-based resolution in :func:`handeye.initial.board_poses`.
    """
    c = det.order_cue
    if (spec.cols + spec.rows) % 2 == 0 or not np.isfinite(c) or c <= min_grey:
        return det
    log.info("view %s: chessboard numbered from its light end; corner order reversed", det.view_id)
    n = spec.n_corners  # corner k of one numbering is corner n - 1 - k of the other
    return replace(
        det,
        corner_ids=(n - 1 - det.corner_ids)[::-1].copy(),
        image_points=det.image_points[::-1].copy(),
        order_cue=-c,
        dropped_corners=tuple(sorted((n - 1 - k, why) for k, why in det.dropped_corners)),
    )


def normalize_chessboard_order(dets: dict, spec: ChessboardSpec, *, options: DetectionOptions | None = None) -> dict:
    """:func:`board_order` applied to every detection of ``dets`` (failures are passed through).

    Each view is turned by its own first square's colour, so the result of a view does not depend on
    the others in ``dets``; symmetric boards are returned as given.
    """
    if (spec.cols + spec.rows) % 2 == 0:
        return dets
    min_grey = (options or default_options()).order_cue_min_grey
    return {v: board_order(d, spec, min_grey=min_grey) if isinstance(d, Detection) else d for v, d in dets.items()}
