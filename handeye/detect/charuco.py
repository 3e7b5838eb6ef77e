"""ChArUco boards: corner ids from the markers (partial views allowed), sub-pixel corners."""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ..targets import CharucoSpec
from .chessboard import refine_corners
from .frontal import frontal_refined
from .geometry import check_corners, search_copy
from .options import DetectionOptions, default_options

log = logging.getLogger(__name__)


def charuco_board(spec: CharucoSpec):
    """OpenCV's board object for ``spec``."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    board = cv2.aruco.CharucoBoard((spec.squares_x, spec.squares_y), spec.square_m, spec.marker_m, dictionary)
    if spec.legacy_pattern:
        board.setLegacyPattern(True)
    return board


def detect_charuco(
    gray: np.ndarray, spec: CharucoSpec, *, options: DetectionOptions | None = None, dropped: list | None = None
) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner ids sorted, image points (N,2)) or a reason string.

    Images above ``search_max_megapixels_charuco_circles`` are searched on a reduced copy (the marker
    search's time grows with the area), and the corners refined there first; on the full image they are refined
    in the board's frontal frame (:mod:`.frontal`: a tilted board's white band between a square's corner and its
    marker is a few px across, and a square window in the image reaches the marker). Corners that fail the
    geometric check are dropped (:func:`off_grid_corners_removed`); ``dropped`` receives their (corner id, reason).
    """
    o = options or default_options()
    search, scale = search_copy(gray, max_megapixels=o.search_max_megapixels_charuco_circles)
    detector = cv2.aruco.CharucoDetector(charuco_board(spec))
    ch_corners, ch_ids, marker_corners, marker_ids = detector.detectBoard(search)
    if ch_ids is None or len(ch_ids) == 0:
        n_markers = 0 if marker_ids is None else len(marker_ids)
        where = "" if np.all(scale == 1.0) else f", searched at {search.shape[1]}x{search.shape[0]}"
        return f"ChArUco board not found ({n_markers} markers seen{where})"
    ids = ch_ids.reshape(-1).astype(int)
    pts = ch_corners.reshape(-1, 2).astype(np.float64)
    if np.any(scale != 1.0):  # refined on the copy first: OpenCV's corners there, a few px on the full image
        pts = (refine_corners(search, pts, np.full(len(pts), o.charuco_subpix_window_px), o) + 0.5) / scale - 0.5
    pts = _refined(gray, pts, spec.object_points()[ids, :2], spec, o)
    order = np.argsort(ids)
    ids, pts = ids[order], pts[order]
    keep = off_grid_corners_removed(spec.object_points()[ids, :2], pts, o)
    if not keep.all():
        log.info(
            "ChArUco corners %s dropped: off the homography of their neighbours (geometric check)", ids[~keep].tolist()
        )
        if dropped is not None:
            dropped.extend((int(k), "off the homography of its neighbours (geometric check)") for k in ids[~keep])
    return ids[keep], pts[keep]


def _refined(
    gray: np.ndarray, pts: np.ndarray, board_xy: np.ndarray, spec: CharucoSpec, o: DetectionOptions
) -> np.ndarray:
    """The corners ``pts`` (N,2) refined in the board's frontal frame (:mod:`.frontal`).

    Through the homography of all of them; with fewer than four, all on one line, or no homography fitted, by
    cornerSubPix in the image (OpenCV's default window).
    """
    spread = len(pts) >= 4 and np.linalg.matrix_rank(board_xy - board_xy.mean(axis=0), tol=1e-9) == 2
    H = cv2.findHomography(board_xy, pts, 0)[0] if spread else None
    if H is None:
        return refine_corners(gray, pts, np.full(len(pts), o.charuco_subpix_window_px), o)
    return frontal_refined(
        gray,
        pts,
        H,
        clear_m=0.5 * (spec.square_m - spec.marker_m),
        apart_m=spec.square_m,
        criteria=o.subpix_criteria,
        min_clear_px=o.frontal_min_clear_px,
        reach_clear=o.frontal_reach_clear,
        share=o.frontal_window_share,
    )


def off_grid_corners_removed(board_xy: np.ndarray, pts: np.ndarray, options: DetectionOptions) -> np.ndarray:
    """Mask (N,) of the corners kept after the geometric check.

    Mask (N,) of the corners kept after the geometric check (:func:`.geometry.grid_check`): the corner
    farthest over its limit is removed, and the check repeated without it (one wrong corner also moves
    its neighbours' predictions), until all pass.
    """
    keep = np.ones(len(pts), bool)
    while keep.sum() > 0:
        idx = np.flatnonzero(keep)
        check = check_corners(board_xy[idx], pts[idx], options)
        if check.passed:
            break
        keep[idx[check.worst]] = False
    return keep
