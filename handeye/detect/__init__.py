"""Target detection: chessboard (sub-pixel corners) and ChArUco (partial views, corner ids).

Each result keeps its view id. A view whose target is not found comes back as a reason string,
so the caller drops it *together with its pose*. Images are read and detected in parallel threads
(OpenCV releases the GIL).
"""
from __future__ import annotations

import logging
from dataclasses import replace
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from ..errors import InputError
from ..targets import CharucoSpec, ChessboardSpec, CircleGridSpec, TargetSpec
from ..records import Detection

log = logging.getLogger(__name__)

#: fewest corners a view needs to be used (PnP needs 4; fewer than 6 gives unstable poses)
MIN_CORNERS = 6


def read_gray(path: Path) -> np.ndarray:
    """Read an image as 8-bit grayscale; one-line InputError when missing or corrupt."""
    path = Path(path)
    if not path.exists():
        raise InputError("image file missing", path=path, hint="restore it or remove its pose from the session")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise InputError("image cannot be decoded (corrupt or not an image)", path=path,
                         hint="re-capture the view or remove the image and its pose")
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return img


def _subpix_window(corners: np.ndarray, cols: int, rows: int) -> int:
    grid = corners.reshape(rows, cols, 2)
    d = []
    if cols > 1:
        d.append(np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    if rows > 1:
        d.append(np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    spacing = min(d) if d else 10.0
    return int(np.clip(spacing * 0.35, 2, 11))


def detect_chessboard(gray: np.ndarray, spec: ChessboardSpec) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner_ids, image_points (N,2)) or a reason string."""
    size = (spec.cols, spec.rows)
    h, w = gray.shape
    # Detect on a reduced image when large: several times faster, and FAST_CHECK rejects an
    # image without a board in milliseconds. Corners are then refined on the full image.
    scale = 1.0
    small = gray
    if max(h, w) > 1000:
        scale = 0.5
        small = cv2.resize(gray, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(small, size, flags=flags)
    if not found and scale != 1.0:
        scale = 1.0
        found, corners = cv2.findChessboardCorners(gray, size, flags=flags)
    if not found:
        found, corners = cv2.findChessboardCornersSB(gray, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return f"chessboard {spec.cols}x{spec.rows} not found"
        scale = 1.0
    pts = corners.reshape(-1, 2).astype(np.float32) / scale
    win = _subpix_window(pts, spec.cols, spec.rows)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    pts = cv2.cornerSubPix(gray, pts.reshape(-1, 1, 2), (win, win), (-1, -1), crit).reshape(-1, 2)
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


def normalize_chessboard_order(dets: dict, spec: ChessboardSpec) -> dict:
    """Give every view of an asymmetric chessboard the corner numbering most views have.

    OpenCV sometimes numbers a (blurred, oblique) board from the other end; the colour of the first
    square (``Detection.order_cue``) shows it. Symmetric boards (cols + rows even) are left to the
    motion-based resolution in seed.board_poses.
    """
    if (spec.cols + spec.rows) % 2 == 0:
        return dets
    cues = {v: d.order_cue for v, d in dets.items() if isinstance(d, Detection) and np.isfinite(d.order_cue)}
    if not cues:
        return dets
    majority = 1.0 if sum(np.sign(c) for c in cues.values()) >= 0 else -1.0
    out = dict(dets)
    for vid, c in cues.items():
        if np.sign(c) == -majority and abs(c) > 10.0:  # grey levels; a weak cue is left alone
            d = dets[vid]
            log.info("view %s: chessboard numbered from the other end; corner order reversed", vid)
            out[vid] = replace(d, image_points=d.image_points[::-1].copy(), order_cue=-c)
    return out


def charuco_board(spec: CharucoSpec):
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    board = cv2.aruco.CharucoBoard((spec.squares_x, spec.squares_y), spec.square_m, spec.marker_m, dictionary)
    if spec.legacy_pattern:
        board.setLegacyPattern(True)
    return board


def detect_charuco(gray: np.ndarray, spec: CharucoSpec) -> tuple[np.ndarray, np.ndarray] | str:
    board = charuco_board(spec)
    detector = cv2.aruco.CharucoDetector(board)
    ch_corners, ch_ids, marker_corners, marker_ids = detector.detectBoard(gray)
    if ch_ids is None or len(ch_ids) == 0:
        n_markers = 0 if marker_ids is None else len(marker_ids)
        return f"ChArUco board not found ({n_markers} markers seen)"
    ids = ch_ids.reshape(-1).astype(int)
    pts = ch_corners.reshape(-1, 2).astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    pts = cv2.cornerSubPix(gray, pts.reshape(-1, 1, 2), (5, 5), (-1, -1), crit).reshape(-1, 2)
    order = np.argsort(ids)
    return ids[order], pts[order].astype(np.float64)


#: a corner dot counts as the origin dot when its blob is this much larger than the grid's median dot
#: and than every other corner dot (a double-size dot measures ~2x; steep views ~1.45x and ~1.45x)
ORIGIN_DOT_RATIO = 1.3


def circle_blob_detector(image_size: tuple[int, int]) -> "cv2.SimpleBlobDetector":
    """Dark round blobs, as industrial_calibration's circle finder is configured (thresholds 20-220 in 10s,
    seen at 3+ thresholds, convex, area 25-5000 px² at 640x480, the upper bound scaled with the image)."""
    w, h = image_size
    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold, p.thresholdStep = 20, 220, 10
    p.minRepeatability = 3
    p.minDistBetweenBlobs = 5
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea, p.minArea = True, 25.0
    p.maxArea = 5000.0 * max(1.0, (w * h) / (640 * 480))
    p.filterByCircularity = False
    p.filterByInertia = False
    p.filterByConvexity, p.minConvexity = True, 0.95
    return cv2.SimpleBlobDetector_create(p)


def detect_circlegrid(gray: np.ndarray, spec: CircleGridSpec) -> tuple[np.ndarray, np.ndarray] | str:
    """(dot ids, image points (N,2)) of a circle grid, or a reason string.

    ``cv2.findCirclesGrid`` (CLUSTERING) on dark blobs. A symmetric grid's order is made to look
    like the board seen from its front (grid x cross grid y points into the image, the same
    handedness as the object points), so only in-plane turns remain; with ``spec.origin_dot`` the
    grid is turned so the corner dot that is clearly larger than the others gets id 0. Only the
    four corner dots are compared: elsewhere in the image (printed legends) there can be larger blobs.
    """
    h, w = gray.shape
    blobs = circle_blob_detector((w, h))
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if spec.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    found, centers = cv2.findCirclesGrid(gray, (spec.cols, spec.rows), flags=flags | cv2.CALIB_CB_CLUSTERING,
                                         blobDetector=blobs)
    if not found:
        found, centers = cv2.findCirclesGrid(gray, (spec.cols, spec.rows), flags=flags, blobDetector=blobs)
    if not found or centers is None or len(centers) != spec.n_corners:
        return f"circle grid {spec.cols}x{spec.rows} not found"
    pts = centers.reshape(-1, 2).astype(np.float64)
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
        k = _origin_corner(gray, pts, spec, blobs)
        if k is not None:
            for perm in spec.symmetries():
                if perm[k] == 0:
                    ids = perm
                    break
            else:
                log.debug("origin dot at detected index %d cannot be id 0 by a turn of this grid", k)
    order = np.argsort(ids)
    return ids[order], pts[order]


def _origin_corner(gray: np.ndarray, pts: np.ndarray, spec: CircleGridSpec, blobs) -> int | None:
    """Detected index of the corner dot that is clearly the largest, or None when none stands out."""
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
    if cs[best] >= ORIGIN_DOT_RATIO * med and cs[best] >= ORIGIN_DOT_RATIO * others.max():
        return int(corners[best])
    return None


def sharpness(gray: np.ndarray, pts: np.ndarray) -> float:
    """Variance of the Laplacian inside the target's bounding box (higher is sharper)."""
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int)
    roi = gray[max(y0, 0): y1 + 1, max(x0, 0): x1 + 1]
    if roi.size < 16:
        return float("nan")
    return float(cv2.Laplacian(roi, cv2.CV_64F).var())


def detect_image(view_id: str, path: Path, target: TargetSpec, *, min_corners: int = MIN_CORNERS) -> Detection | str:
    """Detect the target in one image file: a Detection or a reason string."""
    t0 = time.perf_counter()
    gray = read_gray(path)
    if isinstance(target, ChessboardSpec):
        out = detect_chessboard(gray, target)
    elif isinstance(target, CircleGridSpec):
        out = detect_circlegrid(gray, target)
    else:
        out = detect_charuco(gray, target)
    if isinstance(out, str):
        return out
    ids, pts = out
    if len(ids) < min_corners:
        return f"only {len(ids)} corners detected (need at least {min_corners})"
    cue = order_cue(gray, pts, target.cols, target.rows) if isinstance(target, ChessboardSpec) else float("nan")
    return Detection(view_id=view_id, corner_ids=ids, image_points=pts, image_size=(gray.shape[1], gray.shape[0]),
                     sharpness=sharpness(gray, pts), seconds=time.perf_counter() - t0, order_cue=cue)


def detect_views(items: Sequence[tuple[str, Path]], target: TargetSpec, *, workers: int | None = None,
                 min_corners: int = MIN_CORNERS,
                 progress: Callable[[int, int], None] | None = None) -> dict[str, Detection | str]:
    """Detect the target in every (view_id, image_path); results keyed by view id.

    Unreadable images raise InputError (naming the file) after all workers finish.
    """
    workers = workers or min(len(items), os.cpu_count() or 1) or 1
    results: dict[str, Detection | str] = {}

    def job(item):
        vid, path = item
        return vid, detect_image(vid, path, target, min_corners=min_corners)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for k, (vid, res) in enumerate(pool.map(job, items), start=1):
            results[vid] = res
            if progress:
                progress(k, len(items))
    if isinstance(target, ChessboardSpec):
        results = normalize_chessboard_order(results, target)
    sizes = {d.image_size for d in results.values() if isinstance(d, Detection)}
    if len(sizes) > 1:
        raise InputError(f"images have different sizes {sorted(sizes)}", path=Path(items[0][1]).parent,
                         hint="all views of a session must come from one camera at one resolution")
    return results
