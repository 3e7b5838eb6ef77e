"""Square fiducial markers: one ArUco / AprilTag marker, or Kalibr's AprilGrid, through cv2.aruco.

cv2.aruco finds the markers and their four corners (its order: top-left, top-right, bottom-right, bottom-left
of the print, :data:`handeye.targets.MARKER_CORNERS`) to about a pixel. Only the ids the target holds count; a
marker id seen twice (a second print in the scene) is left out. An AprilGrid's tags are read with Kalibr's two
border cells (or OpenCV's one), their corners' turn read off the grid (:func:`_grid_turn`); its tag corners touch
the gap squares: X junctions, refined with cornerSubPix in each tag's frontal frame (:mod:`.frontal`, through the
homography of its four corners: a tilted tag's cells are a few px across its foreshortened side in the image).
A single marker's corners are L corners (dark square, light margin): blur and the pixels' area round them, and
cornerSubPix (in a window sized from its border cell, configs/detection.yaml ``markers``) settles 0.1-0.3 px
towards the marker. They are taken where its two edges meet instead (:func:`edge_corners`, from cv2.aruco's
corners): each edge located across its step at every pixel along it, from beyond the rounding (three measured
edge widths from the corner) to a short distance (over which lens distortion bends a line by far less than its
noise), and a straight line fitted. The sides are then moved out by the shift the marker's own cells measure
(:mod:`.cell_shift`: a tone curve's, ink's).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from ..config import load_preset
from ..targets import AprilGridSpec, MarkerSpec
from .cell_shift import ink_shift_px, marker_cells
from .frontal import frontal_refined
from .geometry import apply_homography
from .options import DetectionOptions, default_options
from .quality import blur_record, edge_sigma_px, median_1d, profiles_across


@lru_cache(maxsize=8)
def _detector(dictionary: str, border_bits: int = 1) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # refined below, see the module docstring
    params.markerBorderBits = border_bits
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)), params)


def _found(gray: np.ndarray, dictionary: str, border_bits: int) -> tuple[list, list]:
    """(corners, ids) of the markers cv2.aruco finds with ``border_bits`` black border cells."""
    found, found_ids, _rejected = _detector(dictionary, border_bits).detectMarkers(gray)
    return list(found), ([] if found_ids is None else found_ids.reshape(-1).astype(int).tolist())


def _grid_turn(board: np.ndarray, quads: np.ndarray, default: int) -> int:
    """The quarter turns r that put each tag's corners (m,4,2, cv2.aruco's order) in the print's order.

    Corner c of the print is cv2.aruco's corner (c - r) mod 4: the turn whose corners one homography of the board
    ``board`` (4m,2) fits best. Kalibr prints the code as AprilTag lays it out, which OpenCV's dictionary holds
    turned by a half turn (r = 2); a grid made of OpenCV's own markers has r = 0. One tag cannot tell: ``default``.
    """
    if len(quads) < 2:
        return default
    misfit = []
    for r in range(4):
        img = np.roll(quads, r, axis=1).reshape(-1, 2)
        H = cv2.findHomography(board, img, 0)[0]
        misfit.append(
            np.inf if H is None else float(np.median(np.linalg.norm(apply_homography(H, board) - img, axis=1)))
        )
    return int(np.argmin(misfit))


@lru_cache(maxsize=1)
def _settings() -> dict:
    """configs/detection.yaml's ``markers`` section (read once per process)."""
    return load_preset("detection")["markers"]


def _cells(spec, border_bits: int = 1) -> int:
    """Cells across one marker of ``spec``: its code's and ``border_bits`` black border cells each side."""
    return _detector(spec.dictionary).getDictionary().markerSize + 2 * border_bits


def _border_cell_px(corners: np.ndarray, spec) -> float:
    """One cell of the smallest of the markers ``corners`` (m,4,2) in px: 1/(bits+2) of its side."""
    side_px = float(np.min(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).mean(axis=1)))
    return side_px / _cells(spec)


def subpix_half_window_px(corners: np.ndarray, spec, *, share: float, lo: int, hi: int) -> int:
    """The half window of cornerSubPix: ``share`` x the smallest of ``corners``' (m,4,2) border cells, in [lo, hi]."""
    return int(np.clip(np.floor(share * _border_cell_px(corners, spec)), lo, hi))


def _edge_points(
    gray: np.ndarray, P: np.ndarray, Q: np.ndarray, R: np.ndarray, *, reach_px: float, far_px: float
) -> np.ndarray:
    """Points (K,2) of the edge from corner ``P`` towards ``Q``, one per pixel along it, beyond the corner's rounding.

    Each point is where the grey-level profile across the edge crosses halfway between its two plateaus
    (``reach_px`` each side): the edge's own position for any symmetric blur of a linear camera response. Left
    out: profiles leaving the image, with a weak step, with more than one crossing, or dark on the side away
    from the marker (another edge), and profiles whose nearest sample lies within three measured edge widths
    of the corner's other edge (towards ``R``; at an acute corner the profile's inner end comes nearest).
    """
    L = float(np.linalg.norm(Q - P))
    d = (Q - P) / max(L, 1e-9)
    n = np.array([-d[1], d[0]])
    s = np.arange(1.0, min(far_px, 0.4 * L), 1.0)
    if len(s) < 6:
        return np.zeros((0, 2))
    centres = P[None] + s[:, None] * d[None]
    step = 0.25
    prof = profiles_across(gray, centres, np.broadcast_to(n, centres.shape), half_width=reach_px, step_px=step)
    h, w = gray.shape[:2]
    ends = np.concatenate([centres + reach_px * n, centres - reach_px * n])
    inside = np.all((ends >= 0) & (ends <= [w - 1, h - 1]), axis=1)
    inside = inside[: len(s)] & inside[len(s) :]
    k = max(2, prof.shape[1] // 6)
    lo, hi = prof[:, :k].mean(axis=1), prof[:, -k:].mean(axis=1)
    contrast = np.abs(hi - lo)
    above = (prof - (0.5 * (lo + hi))[:, None]) * np.sign(hi - lo)[:, None] > 0
    one_crossing = np.count_nonzero(above[:, 1:] != above[:, :-1], axis=1) == 1
    j = np.clip(np.argmax(above, axis=1), 1, prof.shape[1] - 1)
    r = np.arange(len(s))
    p0, p1 = prof[r, j - 1], prof[r, j]
    mid = 0.5 * (lo + hi)
    frac = np.clip((mid - p0) / np.where(np.abs(p1 - p0) > 1e-9, p1 - p0, 1.0), 0.0, 1.0)
    t = -reach_px + step * (j - 1 + frac)
    e = (R - P) / max(float(np.linalg.norm(R - P)), 1e-9)  # the corner's other edge
    dark_inside = np.sign(hi - lo) == -np.sign(n @ e)  # the profile runs along +n; the marker lies towards e
    good = inside & one_crossing & dark_inside & (contrast > 0.5 * median_1d(contrast))
    if good.sum() < 6:
        return np.zeros((0, 2))
    width = median_1d(edge_sigma_px(prof[good], step_px=step)[0])
    cos_t = float(np.clip(d @ e, -1.0, 1.0))
    good &= s * np.sqrt(1.0 - cos_t**2) - reach_px * max(cos_t, 0.0) >= 3.0 * width
    return (centres + t[:, None] * n[None])[good]


def _line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(a point, unit direction) of the total-least-squares line through ``points`` without its outliers.

    It starts from the least-median-of-squares line through two of the points, which a cluster of bad points
    (a glint or a speck of dirt on the edge) cannot tilt: points further from it than 3 robust sigmas (1.4826
    median distances), and at least 0.25 px, are left out. Then the line is fitted to the points kept and
    the points within 3 robust sigmas of it (at least 0.05 px) are kept, until they no longer change.
    """
    if len(points) < 6:
        return None
    a, b = np.triu_indices(len(points), 1)
    if len(a) > 300:  # an even subset of the pairs: a good pair is among them unless most points are bad
        a, b = a[:: len(a) // 300 + 1], b[:: len(b) // 300 + 1]
    dv = points[b] - points[a]
    nv = np.stack([-dv[:, 1], dv[:, 0]], axis=1) / np.maximum(np.linalg.norm(dv, axis=1, keepdims=True), 1e-9)
    dist = np.abs(nv @ points.T - np.sum(nv * points[a], axis=1)[:, None])  # (pairs, points)
    dist = dist[int(np.argmin(np.median(dist, axis=1)))]
    keep = dist <= max(3.0 * 1.4826 * median_1d(dist), 0.25)
    for _ in range(8):
        if keep.sum() < 6:
            return None
        c = points[keep].mean(axis=0)
        u = np.linalg.svd(points[keep] - c)[2][0]
        dist = np.abs((points - c) @ np.array([-u[1], u[0]]))
        new = dist <= 3.0 * max(1.4826 * median_1d(dist[keep]), 0.05)
        if np.array_equal(new, keep):
            break
        keep = new
    return c, u


def edge_corners(gray: np.ndarray, quad: np.ndarray, *, cell_px: float, far_px: float = 40.0) -> np.ndarray:
    """The four corners (4,2) of one isolated marker, each where its two edges meet.

    ``quad``: the corners to about a pixel, in order around the marker; ``cell_px``: its border cell in px
    (the profiles across an edge reach 0.45 of it each side, so they stay in the black border and the
    white margin). Each edge is fitted from its own corner out to ``far_px`` (at most 0.4 of the side);
    two rounds, the second along the edges through the first's corners. A corner whose edges cannot be
    fitted (too short, leaving the image, too little contrast, nearly parallel) keeps its ``quad`` value.
    """
    q = np.asarray(quad, float).copy()
    reach = float(np.clip(0.45 * cell_px, 2.0, 8.0))
    img = np.asarray(gray)
    for _ in range(2):
        out = q.copy()
        for i in range(4):
            nxt, prv = q[(i + 1) % 4], q[i - 1]
            one = _line(_edge_points(img, q[i], nxt, prv, reach_px=reach, far_px=far_px))
            two = _line(_edge_points(img, q[i], prv, nxt, reach_px=reach, far_px=far_px))
            if one is None or two is None:
                continue
            (c1, u1), (c2, u2) = one, two
            A = np.column_stack([u1, -u2])
            if abs(np.linalg.det(A)) < 0.1:  # edges within 6 degrees of each other: no corner between them
                continue
            out[i] = c1 + np.linalg.solve(A, c2 - c1)[0] * u1
        q = out
    return q


def widen(quad: np.ndarray, by_px: float) -> np.ndarray:
    """The corners (4,2) of the quadrilateral ``quad`` whose four sides are each moved ``by_px`` outwards."""
    q = np.asarray(quad, float)
    centre = q.mean(axis=0)
    normals = []
    for i in range(4):  # side i runs from corner i to corner i+1
        d = q[(i + 1) % 4] - q[i]
        nrm = np.array([d[1], -d[0]]) / max(float(np.linalg.norm(d)), 1e-12)
        normals.append(nrm if nrm @ (q[i] - centre) > 0 else -nrm)
    out = q.copy()
    for i in range(4):  # corner i lies on sides i - 1 and i
        A = np.stack([normals[i - 1], normals[i]])
        if abs(np.linalg.det(A)) > 1e-6:
            out[i] = q[i] + np.linalg.solve(A, np.array([by_px, by_px]))
    return out


def tag_ids(spec) -> np.ndarray:
    """The marker ids of the target, in corner-id order (tag k owns corner ids 4k..4k+3)."""
    if isinstance(spec, MarkerSpec):
        return np.array([spec.marker_id])
    return spec.first_id + np.arange(spec.n_tags)


def marker_blur(gray: np.ndarray, quad: np.ndarray, *, cell_px: float, sharp_edge_sigma_px: float) -> dict:
    """The blur record of one isolated marker's view (:func:`handeye.detect.quality.view_blur`'s fields).

    The edge width across the middle half of each side, every 2 px, in profiles that reach 0.45 of the border
    cell each side (the black border and the white margin, not the code inside); per direction of the marker
    (its top and bottom sides, its left and right ones) the median, the larger counting. ``square_px``: the
    marker's side. Nothing is measured when the border cell is under 6.7 px (profiles of less than 3 px).
    """
    q = np.asarray(quad, float)
    reach = 0.45 * cell_px
    side = np.roll(q, -1, axis=0) - q  # side i runs from corner i to corner i+1
    length = np.linalg.norm(side, axis=1)
    if reach < 3.0 or np.any(length < 8.0):
        return blur_record([], [], n_edges=0, square_px=float(np.mean(length)), sharp_edge_sigma_px=0.0)
    widths: list[list[float]] = [[], []]
    contrasts: list[list[float]] = [[], []]
    for i in range(4):
        d = side[i] / length[i]
        f = np.arange(0.25, 0.75, 2.0 / length[i])
        centres = q[i] + f[:, None] * side[i]
        prof = profiles_across(gray, centres, np.broadcast_to([-d[1], d[0]], centres.shape), half_width=reach)
        sig, con = edge_sigma_px(prof)
        widths[i % 2] += sig.tolist()
        contrasts[i % 2] += con.tolist()
    meds, cons = [], []
    for w, c in zip(widths, contrasts, strict=True):
        w_, c_ = np.asarray(w), np.asarray(c)
        good = c_ > 0.3 * median_1d(c_)
        if good.sum() >= 2:
            meds.append(median_1d(w_[good]))
            cons.append(median_1d(c_[good]))
    return blur_record(meds, cons, n_edges=4, square_px=float(np.mean(length)), sharp_edge_sigma_px=sharp_edge_sigma_px)


def marker_view_blur(gray: np.ndarray, pts: np.ndarray, spec: MarkerSpec, *, sharp_edge_sigma_px: float) -> dict:
    """:func:`marker_blur` of the marker ``spec`` whose corners (4,2) are ``pts``."""
    return marker_blur(
        gray, pts, cell_px=_border_cell_px(np.asarray(pts, float)[None], spec), sharp_edge_sigma_px=sharp_edge_sigma_px
    )


def _separated_tags(
    gray: np.ndarray, spec: AprilGridSpec, border_bits: int, corners: list, ids: list
) -> tuple[list, list]:
    """``corners``, ``ids`` with the tags a second search finds on the image's 2 x 2 grey-level maximum.

    An AprilGrid's tags touch its gap squares at their corners; where the tags are a few pixels a cell, blur
    joins a tag's border to the squares and cv2.aruco's contour is no quadrilateral (rendered 640x480 views with
    cells of about 5 px: 0-9 of 12 tags found in 6 of 12 views). The maximum thins every dark region by about a
    pixel and parts them (6-12 of 12 in those views). Its corners only start the refinement, which reads the
    image itself (the coarse window reaches 2-3 px); a tag already found, or found twice there, is not taken.
    """
    more, new = _found(cv2.dilate(gray, np.ones((2, 2), np.uint8)), spec.dictionary, border_bits)
    for c, m in zip(more, new, strict=True):
        if m not in ids and new.count(m) == 1:
            corners.append(c)
            ids.append(m)
    return corners, ids


def detect_markers(
    gray: np.ndarray, spec: MarkerSpec | AprilGridSpec, *, options: DetectionOptions | None = None
) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner ids sorted, image points (N,2) px) of the target's markers in ``gray``, or the reason.

    The windows: configs/detection.yaml's ``markers`` section (one marker); ``options`` (its detection section)
    gives the ``frontal_*`` ones (an AprilGrid) and the stopping rule.
    """
    o = options or default_options()
    border = spec.border_bits if isinstance(spec, AprilGridSpec) else 1
    corners, id_list = _found(gray, spec.dictionary, border)
    if isinstance(spec, AprilGridSpec):
        grid = set(tag_ids(spec).tolist())
        if len(grid & set(id_list)) < spec.n_tags:  # a grid of the other border (Kalibr's 2 cells, OpenCV's 1)?
            other = _found(gray, spec.dictionary, 3 - border)
            if len(grid & set(other[1])) > len(grid & set(id_list)):
                border, (corners, id_list) = 3 - border, other
        if len(grid & set(id_list)) < spec.n_tags:
            corners, id_list = _separated_tags(gray, spec, border, corners, id_list)
    if not id_list:
        return f"no {spec.dictionary} marker found"
    ids = np.asarray(id_list, int)
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
    contour = np.concatenate(out_pts).astype(np.float64)
    if isinstance(spec, AprilGridSpec):  # X junctions, in each tag's frontal frame (module docstring)
        board = spec.object_points()[cid, :2]
        turn = _grid_turn(board, contour.reshape(-1, 4, 2), default=2 if border == 2 else 0)
        contour = np.roll(contour.reshape(-1, 4, 2), turn, axis=1).reshape(-1, 2)
        quads = zip(
            board.astype(np.float32).reshape(-1, 4, 2), contour.astype(np.float32).reshape(-1, 4, 2), strict=True
        )
        H = [cv2.getPerspectiveTransform(src, dst) for src, dst in quads]
        pts = frontal_refined(
            gray,
            contour,
            np.repeat(np.stack(H), 4, axis=0),
            clear_m=min(border * spec.size_m / _cells(spec, border), spec.spacing * spec.size_m),
            apart_m=spec.spacing * spec.size_m,  # across a gap square
            criteria=o.subpix_criteria,
            min_clear_px=o.frontal_min_clear_px,
            reach_clear=o.frontal_reach_clear,
            share=o.frontal_window_share,
        )
    else:
        pts = _marker_corners(gray, contour, spec, o)
    order = np.argsort(cid, kind="stable")
    return cid[order], pts[order]


def _marker_corners(gray: np.ndarray, contour: np.ndarray, spec: MarkerSpec, o: DetectionOptions) -> np.ndarray:
    """One marker's four corners (4,2) from cv2.aruco's ``contour`` (4,2): where its edges meet (module docstring)."""
    cfg = _settings()
    win = subpix_half_window_px(
        contour[None],
        spec,
        share=float(cfg["subpix_window_share"]),
        lo=int(cfg["subpix_window_min_px"]),
        hi=int(cfg["subpix_window_max_px"]),
    )
    pts: np.ndarray = contour.astype(np.float32).reshape(-1, 1, 2)
    # cv2.aruco's contour corners can be 2-3 px off, outside a small window: a coarse pass with twice the window
    # (its extra edges bias it, but it reaches the corner), then the pass with the corner's own window
    coarse = min(2 * win, int(cfg["subpix_window_max_px"]))
    for w in (coarse, win):
        pts = cv2.cornerSubPix(gray, pts, (w, w), (-1, -1), o.subpix_criteria)
    pts = pts.reshape(-1, 2).astype(np.float64)
    # from the contour's corners: cornerSubPix's window can reach the corner of a narrow margin beyond the
    # marker's and settle there, 7-10 px off (measured); a fit that lands outside the coarse window found
    # some other edge, and cornerSubPix's corner stands
    fitted = edge_corners(
        gray, contour, cell_px=_border_cell_px(contour[None], spec), far_px=float(cfg["edge_fit_far_px"])
    )
    moved = np.linalg.norm(fitted - contour, axis=1) <= max(coarse, 1)
    shift = ink_shift_px(gray, fitted, marker_cells(spec.dictionary, spec.marker_id))
    if shift is not None:  # the edges as the cells place them (.cell_shift): each side moved out by the shift
        fitted = widen(fitted, shift[0])
    return np.where(moved[:, None], fitted, pts)
