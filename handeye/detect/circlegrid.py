"""Circle grids (symmetric, asymmetric, and symmetric with a larger origin dot).

Dot centres by OpenCV's blob detector and grid finder, numbered as the board seen from its front.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ..records import FAILS_GRID_CHECK
from ..targets import CircleGridSpec
from .geometry import TimeBudget, check_corners, search_copy
from .options import CircleBlobOptions, DetectionOptions, default_options

log = logging.getLogger(__name__)


def circle_blob_detector(
    image_size: tuple[int, int], options: CircleBlobOptions | None = None
) -> "cv2.SimpleBlobDetector":
    """Dark round blobs, set up as industrial_calibration's circle finder.

    Dark round blobs, set up as industrial_calibration's circle finder (configs/detection.yaml
    ``circle_blobs``); the largest blob area grows with the image area beyond 640x480.
    """
    o = options or default_options().circle_blobs
    w, h = image_size
    p = cv2.SimpleBlobDetector_Params()  # type: ignore[attr-defined]  # missing from OpenCV's stubs
    p.minThreshold, p.maxThreshold, p.thresholdStep = o.min_threshold, o.max_threshold, o.threshold_step
    p.minRepeatability = o.min_repeatability
    p.minDistBetweenBlobs = o.min_dist_px
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea, p.minArea = True, o.min_area_px2
    p.maxArea = o.max_area_px2_at_640x480 * max(1.0, (w * h) / (640 * 480))
    p.filterByCircularity = False
    p.filterByInertia = False
    p.filterByConvexity, p.minConvexity = True, o.min_convexity
    return cv2.SimpleBlobDetector_create(p)  # type: ignore[attr-defined]  # missing from OpenCV's stubs


def detect_circlegrid(
    gray: np.ndarray, spec: CircleGridSpec, *, options: DetectionOptions | None = None, budget: TimeBudget | None = None
) -> tuple[np.ndarray, np.ndarray] | str:
    """(dot ids, image points (N,2)) of a circle grid, or a reason string (:func:`find_circlegrid`).

    Images above ``search_max_megapixels_charuco_circles`` are searched on a reduced copy (the blob
    search's time grows with the area) and the dot centres scaled back to the full image.
    """
    o = options or default_options()
    search, scale = search_copy(gray, max_megapixels=o.search_max_megapixels_charuco_circles)
    out = find_circlegrid(search, spec, options=o, budget=budget)
    if np.all(scale == 1.0):
        return out
    if isinstance(out, str):
        return (
            f"{out} (searched at {search.shape[1]}x{search.shape[0]}: the image is above "
            f"{o.search_max_megapixels_charuco_circles:g} MP)"
        )
    ids, pts = out
    return ids, (pts + 0.5) / scale - 0.5  # pixel centres at integers in both images


def find_circlegrid(
    gray: np.ndarray, spec: CircleGridSpec, *, options: DetectionOptions | None = None, budget: TimeBudget | None = None
) -> tuple[np.ndarray, np.ndarray] | str:
    """(dot ids, image points (N,2)) of a circle grid, or a reason string.

    ``cv2.findCirclesGrid`` (CLUSTERING) on dark blobs. A symmetric grid's order is made to look
    like the board seen from its front (grid x cross grid y points into the image, the same
    handedness as the object points), so only in-plane turns remain; with ``spec.origin_dot`` the
    grid is turned so the corner dot that is clearly larger than the others gets id 0. Only the
    four corner dots are compared: elsewhere in the image (printed legends) there can be larger blobs.
    The second search (without clustering) is skipped once ``budget`` is spent; a grid with a dot off
    the homography of its neighbours (:func:`.geometry.grid_check`) is dropped.
    """
    o = options or default_options()
    budget = budget or TimeBudget(o.time_budget_s)
    h, w = gray.shape
    blobs = circle_blob_detector((w, h), o.circle_blobs)
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if spec.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    found, centers = cv2.findCirclesGrid(
        gray, (spec.cols, spec.rows), flags=flags | cv2.CALIB_CB_CLUSTERING, blobDetector=blobs
    )
    if not found:
        if budget.spent():
            return budget.timed_out("the circle-grid search without clustering")
        found, centers = cv2.findCirclesGrid(gray, (spec.cols, spec.rows), flags=flags, blobDetector=blobs)
    if not found or centers is None or len(centers) != spec.n_corners:
        return f"circle grid {spec.cols}x{spec.rows} not found"
    pts = centers.reshape(-1, 2).astype(np.float64)
    check = check_corners(spec.object_points()[:, :2], pts, o)
    if not check.passed:
        return f"circle grid dots {FAILS_GRID_CHECK}: {check.text('dot')} (in the order found)"
    if spec.asymmetric:
        return np.arange(spec.n_corners), pts
    grid = pts.reshape(spec.rows, spec.cols, 2)
    if spec.cols > 1 and spec.rows > 1:
        ax = (grid[:, 1:] - grid[:, :-1]).mean(axis=(0, 1))
        ay = (grid[1:] - grid[:-1]).mean(axis=(0, 1))
        if ax[0] * ay[1] - ax[1] * ay[0] < 0:  # seen mirrored: number each row the other way
            grid = grid[:, ::-1]
    pts = np.ascontiguousarray(grid.reshape(-1, 2))
    ids = np.arange(spec.n_corners)
    if spec.origin_dot:
        k = origin_corner(gray, pts, spec, blobs, ratio=o.origin_dot_ratio)
        if k is not None:
            for perm in spec.symmetries():
                if perm[k] == 0:
                    ids = perm
                    break
            else:
                log.debug("origin dot at detected index %d cannot be id 0 by a turn of this grid", k)
    order = np.argsort(ids)
    return ids[order], pts[order]


def origin_corner(gray: np.ndarray, pts: np.ndarray, spec: CircleGridSpec, blobs, *, ratio: float) -> int | None:
    """Detected index of the corner dot that stands out by its size, or None.

    Detected index of the corner dot whose blob is ``ratio`` times larger than the grid's median dot
    and than every other corner dot, or None when none stands out.
    """
    kps = blobs.detect(gray)
    if not kps:
        return None
    kp_xy = np.array([k.pt for k in kps])
    kp_size = np.array([k.size for k in kps])
    near = np.linalg.norm(pts[:, None, :] - kp_xy[None], axis=2)  # (n_dots, n_blobs)
    j = near.argmin(axis=1)
    g = pts.reshape(spec.rows, spec.cols, 2)
    pitch = float(np.median(np.linalg.norm(np.diff(g, axis=1), axis=2))) if spec.cols > 1 else 10.0
    size = np.where(near[np.arange(len(pts)), j] < 0.25 * pitch, kp_size[j], np.nan)
    n, c = spec.n_corners, spec.cols
    corners = np.array([0, c - 1, n - c, n - 1])
    cs = size[corners]
    if not np.all(np.isfinite(cs)):
        return None
    best = int(np.argmax(cs))
    others = np.delete(cs, best)
    med = float(np.nanmedian(size))
    if cs[best] >= ratio * med and cs[best] >= ratio * others.max():
        return int(corners[best])
    return None
