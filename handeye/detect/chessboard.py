"""Chessboards: corners by OpenCV (at half size in large images, then sub-pixel on the full image) and
the corner order of boards whose colours tell their orientation."""
from __future__ import annotations

import logging
from dataclasses import replace

import cv2
import numpy as np

from ..records import Detection
from ..targets import ChessboardSpec
from .options import DetectionOptions, default_options

log = logging.getLogger(__name__)


def subpix_window(corners: np.ndarray, cols: int, rows: int, options: DetectionOptions) -> int:
    """cornerSubPix half window (px): a share of the smallest corner spacing, so it stays in one square."""
    grid = corners.reshape(rows, cols, 2)
    d = []
    if cols > 1:
        d.append(np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    if rows > 1:
        d.append(np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    spacing = min(d) if d else 10.0
    o = options
    return int(np.clip(spacing * o.subpix_window_factor, o.subpix_window_min_px, o.subpix_window_max_px))


def find_chessboard_fast(gray: np.ndarray, spec: ChessboardSpec, *, options: DetectionOptions | None = None):
    """(corners (N,1,2) as found, scale of the image they were found in) by the fast search, or None.

    Detect on a reduced image when large: several times faster, and FAST_CHECK rejects an image without
    a board in milliseconds. Views this misses go to the slow search (:func:`detect_chessboard`)."""
    o = options or default_options()
    size = (spec.cols, spec.rows)
    h, w = gray.shape
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    if max(h, w) > o.half_size_above_px:
        small = cv2.resize(gray, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        found, corners = cv2.findChessboardCorners(small, size, flags=flags)
        if found:
            return corners, 0.5
    found, corners = cv2.findChessboardCorners(gray, size, flags=flags)
    return (corners, 1.0) if found else None


def detect_chessboard(gray: np.ndarray, spec: ChessboardSpec, *, options: DetectionOptions | None = None
                      ) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner_ids, image_points (N,2)) or a reason string. Corners are refined on the full image."""
    o = options or default_options()
    fast = find_chessboard_fast(gray, spec, options=o)
    if fast is not None:
        corners, scale = fast
    else:
        found, corners = cv2.findChessboardCornersSB(gray, (spec.cols, spec.rows), flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return f"chessboard {spec.cols}x{spec.rows} not found"
        scale = 1.0
    pts = corners.reshape(-1, 2).astype(np.float32) / scale
    win = subpix_window(pts, spec.cols, spec.rows, o)
    pts = cv2.cornerSubPix(gray, pts.reshape(-1, 1, 2), (win, win), (-1, -1), o.subpix_criteria).reshape(-1, 2)
    return np.arange(spec.n_corners), pts.astype(np.float64)


def order_cue(gray: np.ndarray, pts: np.ndarray, cols: int, rows: int) -> float:
    """Grey level of the square between the first four corners minus that of the last square.

    On a chessboard with cols + rows odd these two squares have opposite colours, so the sign tells
    from which end the detector numbered the corners.
    """
    if cols < 2 or rows < 2:
        return float("nan")
    grid = pts.reshape(rows, cols, 2)

    def grey(quad):
        c = quad.reshape(-1, 2).mean(axis=0)
        r = max(1, int(0.15 * np.linalg.norm(quad[0, 0] - quad[1, 1])))
        x, y = int(round(c[0])), int(round(c[1]))
        win = gray[max(y - r, 0): y + r + 1, max(x - r, 0): x + r + 1]
        return float(win.mean()) if win.size else float("nan")

    return grey(grid[:2, :2]) - grey(grid[-2:, -2:])


def normalize_chessboard_order(dets: dict, spec: ChessboardSpec, *, options: DetectionOptions | None = None) -> dict:
    """Give every view of an asymmetric chessboard the corner numbering most views have.

    OpenCV sometimes numbers a (blurred, oblique) board from the other end; the colour of the first
    square (``Detection.order_cue``) shows it. Symmetric boards (cols + rows even) are left to the
    motion-based resolution in :func:`handeye.initial.board_poses`. Entries that are not detections
    (failures) are passed through.
    """
    if (spec.cols + spec.rows) % 2 == 0:
        return dets
    min_grey = (options or default_options()).order_cue_min_grey
    cues = {v: d.order_cue for v, d in dets.items() if isinstance(d, Detection) and np.isfinite(d.order_cue)}
    if not cues:
        return dets
    majority = 1.0 if sum(np.sign(c) for c in cues.values()) >= 0 else -1.0
    out = dict(dets)
    for vid, c in cues.items():
        if np.sign(c) == -majority and abs(c) > min_grey:  # a weak cue is left alone
            d = dets[vid]
            log.info("view %s: chessboard numbered from the other end; corner order reversed", vid)
            out[vid] = replace(d, image_points=d.image_points[::-1].copy(), order_cue=-c)
    return out
