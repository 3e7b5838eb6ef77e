"""Square fiducial markers: one ArUco / AprilTag marker, or Kalibr's AprilGrid, through cv2.aruco.

cv2.aruco finds the markers and their four corners (its order: top-left, top-right, bottom-right,
bottom-left of the print, :data:`handeye.targets.MARKER_CORNERS`) to about a pixel; each corner is then
refined with ``cv2.cornerSubPix`` in a window sized from the marker's own border cell (and the AprilGrid's
gap) in pixels (configs/detection.yaml ``markers``, where the measured alternatives are listed). Only the
ids the target holds count; a marker id seen twice (a second print in the scene) is left out.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from ..config import load_preset
from ..targets import AprilGridSpec, MarkerSpec
from .options import DetectionOptions, default_options


@lru_cache(maxsize=8)
def _detector(dictionary: str) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # refined below, see the module docstring
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)


@lru_cache(maxsize=1)
def _settings() -> dict:
    """configs/detection.yaml's ``markers`` section (read once per process)."""
    return load_preset("detection")["markers"]


def subpix_half_window_px(corners: np.ndarray, spec, *, share: float, lo: int, hi: int) -> int:
    """Half window for cornerSubPix on the markers ``corners``.

    Half window for cornerSubPix on the markers ``corners`` (m,4,2): ``share`` x the smallest of the border
    cell and (AprilGrid) the gap between tags, in px on the smallest marker, clipped to [lo, hi].
    """
    side_px = float(np.min(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).mean(axis=1)))
    bits = _detector(spec.dictionary).getDictionary().markerSize
    feature = side_px / (bits + 2)
    if isinstance(spec, AprilGridSpec):
        feature = min(feature, spec.spacing * side_px)
    return int(np.clip(np.floor(share * feature), lo, hi))


def tag_ids(spec) -> np.ndarray:
    """The marker ids of the target, in corner-id order (tag k owns corner ids 4k..4k+3)."""
    if isinstance(spec, MarkerSpec):
        return np.array([spec.marker_id])
    return spec.first_id + np.arange(spec.n_tags)


def detect_markers(
    gray: np.ndarray, spec: MarkerSpec | AprilGridSpec, *, options: DetectionOptions | None = None
) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner ids sorted, image points (N,2) px) of the target's markers in ``gray``, or the reason.

    The window settings are configs/detection.yaml's ``markers`` section; ``options`` gives the stopping rule.
    """
    o = options or default_options()
    corners, ids, _rejected = _detector(spec.dictionary).detectMarkers(gray)
    if ids is None or len(ids) == 0:
        return f"no {spec.dictionary} marker found"
    ids = ids.reshape(-1).astype(int)
    wanted = {int(t): k for k, t in enumerate(tag_ids(spec))}
    seen, counts = np.unique(ids, return_counts=True)
    twice = set(seen[counts > 1].tolist())
    out_ids, out_pts = [], []
    for m, c in zip(ids, corners, strict=False):
        k = wanted.get(int(m))
        if k is None or int(m) in twice:
            continue
        out_ids.append(4 * k + np.arange(4))
        out_pts.append(np.asarray(c, float).reshape(4, 2))
    if not out_ids:
        others = ", ".join(str(i) for i in sorted(set(ids.tolist()))[:8])
        why = (
            f"marker id {sorted(twice)} seen more than once"
            if twice & set(wanted)
            else f"none of the target's marker ids among those seen ({others})"
        )
        return f"{spec.describe()}: {why}"
    cid = np.concatenate(out_ids)
    cfg = _settings()
    win = subpix_half_window_px(
        np.stack(out_pts),
        spec,
        share=float(cfg["subpix_window_share"]),
        lo=int(cfg["subpix_window_min_px"]),
        hi=int(cfg["subpix_window_max_px"]),
    )
    pts: np.ndarray = np.concatenate(out_pts).astype(np.float32).reshape(-1, 1, 2)
    # cv2.aruco's contour corners can be 2-3 px off, outside a small window: a coarse pass with twice the window
    # (its extra edges bias it, but it reaches the corner), then the pass with the corner's own window
    for w in (min(2 * win, int(cfg["subpix_window_max_px"])), win):
        pts = cv2.cornerSubPix(gray, pts, (w, w), (-1, -1), o.subpix_criteria)
    pts = pts.reshape(-1, 2).astype(np.float64)
    order = np.argsort(cid, kind="stable")
    return cid[order], pts[order]
