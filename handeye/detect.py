"""Target detection: chessboard (sub-pixel corners) and ChArUco (partial views, corner ids).

Each result keeps its view id. A view whose target is not found comes back as a reason string,
so the caller drops it *together with its pose*. Images are read and detected in parallel threads
(OpenCV releases the GIL).
"""
from __future__ import annotations

import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from .errors import InputError
from .types import CharucoSpec, ChessboardSpec, Detection, TargetSpec

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
    else:
        out = detect_charuco(gray, target)
    if isinstance(out, str):
        return out
    ids, pts = out
    if len(ids) < min_corners:
        return f"only {len(ids)} corners detected (need at least {min_corners})"
    return Detection(view_id=view_id, corner_ids=ids, image_points=pts, image_size=(gray.shape[1], gray.shape[0]),
                     sharpness=sharpness(gray, pts), seconds=time.perf_counter() - t0)


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
    sizes = {d.image_size for d in results.values() if isinstance(d, Detection)}
    if len(sizes) > 1:
        raise InputError(f"images have different sizes {sorted(sizes)}", path=Path(items[0][1]).parent,
                         hint="all views of a session must come from one camera at one resolution")
    return results
