"""Image-quality measures of one view: sharpness, edge blur, exposure and a small JPEG thumbnail.

They are taken from the decoded grey image during detection, so no later stage decodes the image
again. Blur is measured as the width of the board's own edges: across the edge between two
neighbouring corners a step of contrast ``D`` blurred by a Gaussian of ``sigma`` has a largest slope
``D / (sigma sqrt(2 pi))``, so ``sigma = D / (sqrt(2 pi) max|dI/ds|)``. A sharp, anti-aliased image
gives about 0.5 px (pixel area and sampling, ``sharp_edge_sigma_px`` in configs/detection.yaml);
a blur adds in quadrature.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from .options import default_options

SQRT_2PI = float(np.sqrt(2.0 * np.pi))
_NAN_BLUR = {"edge_sigma_px": float("nan"), "blur_sigma_px": float("nan"), "contrast": float("nan"), "n_edges": 0}


def sharpness(gray: np.ndarray, pts: np.ndarray) -> float:
    """Variance of the Laplacian inside the target's bounding box (higher is sharper)."""
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int)
    roi = gray[max(y0, 0) : y1 + 1, max(x0, 0) : x1 + 1]
    if roi.size < 16:
        return float("nan")
    _, std = cv2.meanStdDev(cv2.Laplacian(roi, cv2.CV_64F))
    return float(std[0, 0] ** 2)


def neighbour_pairs(
    object_points: np.ndarray, corner_ids: np.ndarray, square_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (into ``corner_ids``) of corners one square apart along the board's x or y axis.

    Index pairs (into ``corner_ids``) of corners one square apart along the board's x or y axis,
    ordered by the first corner, its x neighbour before its y neighbour.
    """
    P = np.asarray(object_points, float)[np.asarray(corner_ids)]
    if len(P) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    g = np.round(P[:, :2] / square_m).astype(np.int64)  # (N, 2) grid coordinates
    g -= g.min(axis=0)
    span = int(g[:, 1].max()) + 2  # a y step never wraps into the next x column
    key = g[:, 0] * span + g[:, 1]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    hit = np.zeros((len(P), 2), bool)
    other = np.zeros((len(P), 2), int)
    for d, step in enumerate((span, 1)):  # +1 square in x, +1 square in y
        j = np.minimum(np.searchsorted(sorted_key, key + step), len(P) - 1)
        hit[:, d] = sorted_key[j] == key + step
        other[:, d] = order[j]
    a = np.repeat(np.arange(len(P))[:, None], 2, axis=1)[hit]
    return a.astype(int), other[hit].astype(int)


def edge_profiles(
    gray: np.ndarray, p0: np.ndarray, p1: np.ndarray, *, half_width: float, step_px: float = 0.25
) -> np.ndarray:
    """Grey-level profiles (K, S) across the edge through the middle of each corner pair (p0, p1: (K,2)).

    Bilinear samples; outside the image the border pixels are repeated.
    """
    e = p1 - p0
    L = np.linalg.norm(e, axis=1, keepdims=True)
    nrm = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.maximum(L, 1e-9)
    return profiles_across(gray, 0.5 * (p0 + p1), nrm, half_width=half_width, step_px=step_px)


def profiles_across(
    gray: np.ndarray, centres: np.ndarray, normals: np.ndarray, *, half_width: float, step_px: float = 0.25
) -> np.ndarray:
    """Grey-level profiles (K, S) through ``centres`` (K,2) along unit ``normals`` (K,2), at offsets -hw..hw.

    Bilinear samples; outside the image the border pixels are repeated.
    """
    s = np.arange(-half_width, half_width + 1e-9, step_px)
    x = centres[:, 0:1] + s[None, :] * normals[:, 0:1]  # (K, S) sample positions
    y = centres[:, 1:2] + s[None, :] * normals[:, 1:2]
    vals = _bilinear(gray, x.ravel(), y.ravel())
    return vals.reshape(len(centres), len(s))


def _bilinear(gray: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear grey values at (x, y) px, the border pixels repeated outside the image.

    Bilinear grey values at (x, y) px, the border pixels repeated outside the image (as
    ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``).
    """
    h, w = gray.shape[:2]
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    # top-left neighbour, kept one pixel inside the last row/column so its right/lower neighbour exists
    x0 = np.minimum(x.astype(np.intp), max(w - 2, 0))
    y0 = np.minimum(y.astype(np.intp), max(h - 2, 0))
    fx, fy = x - x0, y - y0
    flat = np.asarray(gray).reshape(-1)
    i = y0 * w + x0
    dx, dy = (1 if w > 1 else 0), (w if h > 1 else 0)
    top = flat[i] + fx * (flat[i + dx] - flat[i].astype(np.float64))
    bottom = flat[i + dy] + fx * (flat[i + dy + dx] - flat[i + dy].astype(np.float64))
    return top + fy * (bottom - top)


def edge_sigma_px(profiles: np.ndarray, *, step_px: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """(edge width sigma in px, contrast in grey levels) per profile."""
    P = np.asarray(profiles, float)
    S = P.shape[1]
    q = max(2, S // 7)
    contrast = np.abs(P[:, -q:].mean(axis=1) - P[:, :q].mean(axis=1))
    # central difference over 1 px (4 samples) tames the noise
    h = int(round(1.0 / step_px))
    g = np.abs(P[:, 2 * h :] - P[:, : -2 * h]) / (2 * h * step_px)
    gmax = g.max(axis=1) if g.shape[1] else np.zeros(len(P))
    sigma = contrast / (SQRT_2PI * np.maximum(gmax, 1e-9))
    # the 1-px central difference itself widens a step by a box of 2 px (sigma^2 += 1/3)
    sigma = np.sqrt(np.maximum(sigma**2 - 1.0 / 3.0, 0.0))
    return sigma, contrast


def median_1d(v: npt.ArrayLike) -> float:
    """np.median of a 1-D array without its per-call overhead (called ~10 times per view)."""
    v = np.sort(np.asarray(v, float).ravel())
    n = len(v)
    if n == 0 or np.isnan(v[-1]):
        return float("nan")
    return float(0.5 * (v[(n - 1) // 2] + v[n // 2]))


def view_blur(
    gray: np.ndarray,
    image_points: np.ndarray,
    corner_ids: np.ndarray,
    object_points: np.ndarray,
    square_m: float,
    *,
    charuco: bool = False,
    sharp_edge_sigma_px: float | None = None,
) -> dict:
    """Edge width of one view: ``{"edge_sigma_px", "blur_sigma_px", "contrast", "n_edges", "square_px"}``.

    Per direction of the board (x and y) the median over its edges; the larger of the two is reported,
    so motion blur along one direction shows. ``blur_sigma_px`` removes the sharp-image width
    (``sharp_edge_sigma_px``, default from configs/detection.yaml). ChArUco squares hold markers, so
    their profiles stay closer to the edge.
    """
    sharp = default_options().sharp_edge_sigma_px if sharp_edge_sigma_px is None else sharp_edge_sigma_px
    a, b = neighbour_pairs(object_points, corner_ids, square_m)
    if len(a) < 4:
        return dict(_NAN_BLUR)
    pts = np.asarray(image_points, float)
    p0, p1 = pts[a], pts[b]
    spacing = np.linalg.norm(p1 - p0, axis=1)
    frac = 0.2 if charuco else 0.33
    meds = []
    contrasts = []
    obj = np.asarray(object_points, float)[np.asarray(corner_ids)]
    along_x = np.abs(obj[b, 0] - obj[a, 0]) > 0.5 * square_m
    for sel in (along_x, ~along_x):
        sel = sel & (spacing * frac >= 3.0)
        if sel.sum() < 2:
            continue
        hw = float(median_1d(spacing[sel]) * frac)
        prof = edge_profiles(gray, p0[sel], p1[sel], half_width=hw)
        sig, con = edge_sigma_px(prof)
        good = con > 0.3 * median_1d(con)
        if good.sum() >= 2:
            meds.append(float(median_1d(sig[good])))
            contrasts.append(float(median_1d(con[good])))
    return blur_record(meds, contrasts, n_edges=len(a), square_px=float(median_1d(spacing)), sharp_edge_sigma_px=sharp)


def blur_record(
    medians: list[float], contrasts: list[float], *, n_edges: int, square_px: float, sharp_edge_sigma_px: float
) -> dict:
    """A view's blur record from its per-direction median edge widths and contrasts (the larger width counts)."""
    if not medians:
        return dict(_NAN_BLUR)
    e = max(medians)
    return {
        "edge_sigma_px": e,
        "blur_sigma_px": float(np.sqrt(max(e**2 - sharp_edge_sigma_px**2, 0.0))),
        "contrast": float(median_1d(contrasts)),
        "n_edges": int(n_edges),
        "square_px": float(square_px),
    }


def _hull(image_points: np.ndarray, grow: float) -> np.ndarray:
    pts = np.asarray(image_points, float)
    c = pts.mean(axis=0)
    pts = c + (pts - c) * (1.0 + grow)
    return cv2.convexHull(np.round(pts).astype(np.int32).reshape(-1, 1, 2))


def board_mask(shape: tuple, image_points: np.ndarray, *, grow: float = 0.0) -> np.ndarray:
    """Boolean mask of the convex hull of the corners (optionally grown by ``grow`` x its size)."""
    m = np.zeros(shape[:2], np.uint8)
    cv2.fillConvexPoly(m, _hull(image_points, grow), 1)
    return m.astype(bool)


def _board_histogram(gray: np.ndarray, image_points: np.ndarray) -> np.ndarray:
    """Counts (256,) of the grey levels inside the corners' convex hull.

    Counts (256,) of the grey levels inside the corners' convex hull (the pixels of
    :func:`board_mask`), read from the hull's bounding box only.
    """
    hull = _hull(image_points, 0.0)
    h, w = gray.shape[:2]
    x, y, bw, bh = cv2.boundingRect(hull)
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + bw, w), min(y + bh, h)
    if x1 <= x0 or y1 <= y0:
        return np.zeros(256)
    m = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillConvexPoly(m, hull - np.array([x0, y0], np.int32), 1)
    return _histogram(np.ascontiguousarray(gray[y0:y1, x0:x1]), m)


def _histogram(gray: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    return cv2.calcHist([gray], [0], mask, [256], [0, 256]).reshape(-1)


def _exposure(counts: np.ndarray, saturated_grey: int | None) -> dict:
    """Saturated share and 5th/95th percentiles (numpy's linear rule) from a histogram of 8-bit grey levels."""
    sat = default_options().saturated_grey if saturated_grey is None else saturated_grey
    cum = np.cumsum(np.asarray(counts, np.int64) if counts.dtype.kind in "iu" else np.rint(counts).astype(np.int64))
    n = int(cum[-1])
    if n == 0:
        return {"saturated_share": float("nan"), "p5": float("nan"), "p95": float("nan")}

    def percentile(q):
        pos = q / 100.0 * (n - 1)
        lo = int(np.floor(pos))
        v_lo = int(np.searchsorted(cum, lo, side="right"))  # the lo-th smallest value (0-based)
        v_hi = int(np.searchsorted(cum, min(lo + 1, n - 1), side="right"))
        return float(v_lo + (pos - lo) * (v_hi - v_lo))

    n_sat = n - (int(cum[sat - 1]) if sat > 0 else 0)
    return {"saturated_share": n_sat / n, "p5": percentile(5), "p95": percentile(95)}


def view_exposure(gray: np.ndarray, image_points: np.ndarray, *, saturated_grey: int | None = None) -> dict:
    """Saturated share and grey levels (5th/95th percentile) inside the board's hull (8-bit image)."""
    return _exposure(_board_histogram(gray, image_points), saturated_grey)


def image_exposure(gray: np.ndarray, *, saturated_grey: int | None = None) -> dict:
    """:func:`view_exposure` over the whole image (for a view whose target was not found)."""
    return _exposure(_histogram(np.ascontiguousarray(gray)), saturated_grey)


def thumbnail_jpeg(gray: np.ndarray, *, width_px: int | None = None, quality: int | None = None) -> bytes:
    """A small grey JPEG of the view (``width_px`` wide, aspect kept; defaults from configs/detection.yaml)."""
    o = default_options()
    width_px = o.thumbnail_width_px if width_px is None else width_px
    quality = o.thumbnail_jpeg_quality if quality is None else quality
    h, w = gray.shape[:2]
    size = (max(1, min(width_px, w)), max(1, round(h * min(width_px, w) / w)))
    small = gray
    while small.shape[1] >= 2 * size[0] and small.shape[0] >= 2:  # halving by area: OpenCV's fast path
        small = cv2.resize(small, (small.shape[1] // 2, small.shape[0] // 2), interpolation=cv2.INTER_AREA)
    small = cv2.resize(small, size, interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    return buf.tobytes() if ok else b""
