"""How far the halfway-grey rule puts a marker's edges into its ink, measured on the marker's own cells.

A single marker's corners are where its outer edges meet (:func:`handeye.detect.markers.edge_corners`), each
edge located where the grey level crosses halfway between its two sides: the edge itself only when grey levels
are proportional to light. A camera that encodes them (sRGB: a gamma of about 2.2) puts the halfway grey on the
ink's side, by a share of the blur (0.57 px on each corner at a blur of 1.2 px: a 48 mm marker looks 47.8 mm);
ink that spreads moves the printed edges into the paper. Either moves every edge between ink and paper one
distance towards the ink (or the paper): a run of ink cells measures two such shifts short, a run of paper cells
two long. One blurred edge cannot tell a tone curve (the power of a blurred step looks like a shifted blurred
step); the cells can tell the shift. :func:`ink_shift_px` reads the marker along lines through its rows and
columns of cells, locates each edge between ink and paper by the same rule, and fits the edges' positions with
a polynomial over the marker for each direction of the lines (the lens's bend, which the corners' homography
leaves) plus the one shift all edges share.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from .quality import _bilinear, edge_sigma_px, median_1d, profiles_across

#: where the lines cross each row (column) of cells, in cells from its side
_LINES = (0.3, 0.5, 0.7)
#: sample spacing along a line, cells
_STEP = 0.02
#: the paper read beyond the marker's outer edges, cells
_MARGIN = 0.6
#: plateaus are read from this many edge widths (sigma) from an edge
_CLEAR = 2.5
#: the total degree of the polynomials through the edges' positions
_DEGREE = 4


@lru_cache(maxsize=64)
def marker_cells(dictionary: str, marker_id: int) -> np.ndarray:
    """(n, n) bool: True where the printed marker is ink, its black border included (n = bits + 2; rows top down)."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = int(d.markerSize) + 2
    cells = np.asarray(cv2.aruco.generateImageMarker(d, int(marker_id), n)) < 128
    cells.setflags(write=False)
    return cells


def _project(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Image points (K,2) of the frame points ``pts`` (K,2) through the homography ``H``."""
    p = np.c_[pts, np.ones(len(pts))] @ H.T
    return p[:, :2] / p[:, 2:3]


def _cells_per_px(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(K,2): cells per px across the lines of constant frame x, and of constant y, at the frame points ``pts``.

    The norms of the image gradients of frame x and y: the rows of the inverse of d image / d frame.
    """
    p = np.c_[pts, np.ones(len(pts))] @ H.T
    img = p[:, :2] / p[:, 2:3]
    J = (H[None, :2, :2] - img[:, :, None] * H[None, 2:3, :2]) / p[:, 2, None, None]
    return np.linalg.norm(np.linalg.inv(J), axis=2)


def _edge_width_px(gray: np.ndarray, quad: np.ndarray, n: int) -> float:
    """The median edge width (sigma, px) across the middle halves of the marker's four sides.

    Profiles every 2 px (at most 40 a side), reaching 0.45 of the border cell each side, at most 16 px.
    """
    widths = []
    for i in range(4):
        side = quad[(i + 1) % 4] - quad[i]
        length = float(np.linalg.norm(side))
        cell = length / n
        if cell < 4.0:
            return float("nan")
        d = side / length
        f = np.linspace(0.25, 0.75, int(np.clip(length / 4.0, 2, 40)))
        centres = quad[i] + f[:, None] * side
        reach = min(0.45 * cell, 16.0)
        prof = profiles_across(gray, centres, np.broadcast_to([-d[1], d[0]], centres.shape), half_width=reach)
        widths += edge_sigma_px(prof)[0].tolist()
    return median_1d(widths)


def _crossings(prof: np.ndarray, edges: np.ndarray, width: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, ...]:
    """(positions along the line (cells), contrasts, found) of the halfway crossing at each edge of one line.

    ``edges``: the edges' numbers (their positions in cells, 0..n); ``width``: each edge's width (sigma) in
    cells. Plateaus: the samples from ``_CLEAR`` widths off the edge to as far as its run allows (``_CLEAR``
    widths short of the next edge, at most one cell); an edge whose runs leave no plateau, or whose profile
    crosses halfway more than once near it, is not found.
    """
    bounds = np.r_[-_MARGIN, edges.astype(float), s[-1]]
    pos, con, ok = np.zeros(len(edges)), np.zeros(len(edges)), np.zeros(len(edges), bool)
    for i, e in enumerate(edges):
        clear = _CLEAR * width[i]
        left = (s >= max(bounds[i] + clear, e - 1.0)) & (s <= e - clear)
        right = (s >= e + clear) & (s <= min(bounds[i + 2] - clear, e + 1.0))
        if left.sum() < 3 or right.sum() < 3:
            continue
        lo, hi = prof[left].mean(), prof[right].mean()
        near = np.flatnonzero((s > e - clear) & (s < e + clear))
        if len(near) < 3:
            continue
        side = prof[near] > 0.5 * (lo + hi)
        flips = np.flatnonzero(side[1:] != side[:-1])
        if len(flips) != 1:
            continue
        j = near[flips[0]]
        a, b = prof[j] - 0.5 * (lo + hi), prof[j + 1] - 0.5 * (lo + hi)
        pos[i] = s[j] + (s[j + 1] - s[j]) * a / (a - b)
        con[i], ok[i] = abs(hi - lo), True
    return pos, con, ok


def ink_shift_px(gray: np.ndarray, quad: np.ndarray, cells: np.ndarray) -> tuple[float, float] | None:
    """(shift, its sigma) in px by which the halfway rule puts the edges between ink and paper into the ink.

    Negative: into the paper. ``quad``: the marker's corners (4,2) in the dictionary's order (top-left,
    top-right, bottom-right, bottom-left of the print), to a fraction of a pixel; ``cells``: its ink
    (:func:`marker_cells`). None when the edges read are too few to tell the shift from the polynomials
    (:func:`_shared_shift`): cells under 4 px or about five edge widths, lines leaving the image.
    """
    g = np.asarray(gray)
    q = np.asarray(quad, float)
    n = len(cells)
    width_px = _edge_width_px(g, q, n)
    if not np.isfinite(width_px):
        return None
    frame = np.array([[0, 0], [n, 0], [n, n], [0, n]], np.float32)
    H = cv2.getPerspectiveTransform(frame, q.astype(np.float32)).astype(float)
    s = np.arange(-_MARGIN, n + _MARGIN + 1e-9, _STEP)
    plan = []  # (axis, its cross position, edge numbers, +1 where the ink lies beyond the edge)
    for axis in (0, 1):  # 0: lines along x, through a row of cells; 1: along y, through a column
        for k in range(n):
            ink = np.r_[False, cells[k, :] if axis == 0 else cells[:, k], False]  # paper beyond the marker
            edges = np.flatnonzero(ink[1:] != ink[:-1])
            if len(edges) >= 2:
                plan += [(axis, k + f, edges, np.where(ink[edges + 1], 1.0, -1.0)) for f in _LINES]
    if not plan:
        return None
    along = [np.c_[s, np.full_like(s, c)] if axis == 0 else np.c_[np.full_like(s, c), s] for axis, c, _, _ in plan]
    img = _project(H, np.concatenate(along))
    h, w = g.shape[:2]
    img = img.reshape(len(plan), len(s), 2)
    inside = np.all((img >= 0) & (img <= [w - 1, h - 1]), axis=(1, 2))
    prof = _bilinear(g, img[..., 0].ravel(), img[..., 1].ravel()).reshape(len(plan), len(s))
    at_edges = [np.c_[e, np.full(len(e), c)] if axis == 0 else np.c_[np.full(len(e), c), e] for axis, c, e, _ in plan]
    scale = _cells_per_px(H, np.concatenate(at_edges).astype(float))
    rows = []  # per edge read: (axis, edge number, the line's cross position, position along it, z, contrast)
    first = 0
    for i, (axis, c, edges, towards) in enumerate(plan):
        per_px = scale[first : first + len(edges), axis]  # cells per px across each edge
        first += len(edges)
        if not inside[i]:
            continue
        pos, con, ok = _crossings(prof[i], edges, width_px * per_px, s)
        read = zip(edges[ok], pos[ok], towards[ok] * per_px[ok], con[ok], strict=True)
        rows += [(axis, e, c, x, z, k) for e, x, z, k in read]
    if len(rows) < 8:
        return None
    table = np.array(rows, float)
    table = table[table[:, 5] > 0.5 * median_1d(table[:, 5])]  # a weak step is no edge between ink and paper
    return _shared_shift(table, n)


def _monomials(e: np.ndarray, c: np.ndarray, n: int) -> np.ndarray:
    """(K, terms): the monomials of total degree up to ``_DEGREE`` in e and c, both scaled to [-1, 1] over 0..n."""
    u, v = 2.0 * e / n - 1.0, 2.0 * c / n - 1.0
    return np.stack([u**i * v**j for i in range(_DEGREE + 1) for j in range(_DEGREE + 1 - i)], axis=1)


def _shared_shift(table: np.ndarray, n: int) -> tuple[float, float] | None:
    """Least squares of x = P_axis(e, c) + shift * z over the edges read, robust; (shift, its sigma) px or None.

    ``table`` rows: (axis, edge number e, the line's cross position c, position x along it, z, contrast).
    P_axis: a polynomial in e and c of total degree ``_DEGREE`` for each direction of the lines (the lens's bend
    across the marker, which the corners' homography leaves, is smooth over both). Edges further than 3 robust
    sigmas (at least 0.002 cells) from the fit are left out and the fit repeated. None with fewer than 8 edges
    left beyond the polynomials' terms, or with edges of one kind only (no shift to tell).
    """
    axis = table[:, 0].astype(int)
    mono = _monomials(table[:, 1], table[:, 2], n)
    A = np.zeros((len(table), 2 * mono.shape[1] + 1))
    for a in (0, 1):
        A[axis == a, a * mono.shape[1] : (a + 1) * mono.shape[1]] = mono[axis == a]
    A[:, -1] = table[:, 4]
    x = table[:, 3]
    keep = np.ones(len(x), bool)
    for _ in range(5):
        cols = np.any(A[keep] != 0, axis=0)  # a direction without edges has no polynomial
        if keep.sum() < cols.sum() + 8 or not cols[-1]:
            return None
        coef, *_ = np.linalg.lstsq(A[keep][:, cols], x[keep], rcond=None)
        res = x - A[:, cols] @ coef
        sigma = max(1.4826 * median_1d(np.abs(res[keep])), 0.002)
        new = np.abs(res) <= 3.0 * sigma
        if np.array_equal(new, keep):
            break
        keep = new
    Ak = A[keep][:, cols]
    rms = float(np.sqrt(np.sum(res[keep] ** 2) / max(len(Ak) - Ak.shape[1], 1)))
    cov = np.linalg.pinv(Ak.T @ Ak)
    return float(coef[-1]), rms * float(np.sqrt(cov[-1, -1]))
