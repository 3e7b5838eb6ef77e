"""The board's own geometry applied to detected corners, and the limits of one image's detection.

A homography of the board plane, the size of a square in pixels from it, the geometric check of a
view's corners, the reduced copy of a large image that the searches run on, and the time budget of
one image's detection. The check (:func:`grid_check`) predicts every corner from its neighbours on
the board (those within ``radius`` grid steps) through the homography they fit, plus the bend of the
image that lens distortion adds across them, and measures how far the detected corner lies from that
prediction. A corner placed on the wrong saddle point or pulled off by a wrong neighbour stands out by
pixels while well-placed corners stay near their noise.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

log = logging.getLogger(__name__)


def _homographies(nb: "_Neighbourhoods", dst: np.ndarray) -> np.ndarray:
    """Least-squares homographies board -> image of every neighbourhood, shape (M, 3, 3).

    Least-squares homographies board -> image of every neighbourhood, shape (M, 3, 3): the linear (DLT)
    fit with h33 = 1 on coordinates normalised to mean 0 and RMS sqrt(2) (where h33 stays far from 0).

    dst: image points of the neighbours, shape (M, k, 2) (rows outside ``nb.mask`` are ignored).
    """
    dn, Td = _normalise_masked(dst, nb.mask)
    x, y, one, w = nb.x, nb.y, nb.mask, nb.mask
    u, v = dn[..., 0], dn[..., 1]
    zero = np.zeros_like(x)
    r1 = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y], axis=2)
    r2 = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y], axis=2)
    A = np.concatenate([r1, r2], axis=1)  # shape (M, 2k, 8), zero rows outside the mask
    b = np.concatenate([u * w, v * w], axis=1)  # shape (M, 2k)
    At = A.transpose(0, 2, 1)
    h = np.linalg.solve(At @ A, (At @ b[..., None]))[..., 0]  # shape (M, 8)
    Hn = np.concatenate([h, np.ones((len(h), 1))], axis=1).reshape(-1, 3, 3)
    return np.linalg.inv(Td) @ Hn @ nb.Ts


def _normalise_masked(pts: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point sets moved to mean 0 and scaled to RMS sqrt(2), with their (M, 3, 3) transforms.

    (points of each set moved to mean 0 and scaled to RMS sqrt(2), zero outside ``mask``; the (M, 3, 3)
    transforms); pts shape (M, k, 2), mask (M, k) of 0/1.
    """
    m = mask[..., None]
    n = np.maximum(m.sum(axis=1, keepdims=True), 1.0)
    c = (pts * m).sum(axis=1, keepdims=True) / n
    rms = np.sqrt(((np.sum((pts - c) ** 2, axis=2, keepdims=True)) * m).sum(axis=1, keepdims=True) / n)
    s = np.sqrt(2.0) / np.maximum(rms, 1e-12)  # shape (M, 1, 1)
    T = np.zeros((len(pts), 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = s[:, 0, 0]
    T[:, :2, 2] = -s[:, 0] * c[:, 0]
    T[:, 2, 2] = 1.0
    return (pts - c) * s * m, T


@dataclass(frozen=True)
class _Neighbourhoods:
    """The board neighbours of every checkable corner, and what of their fit depends on the board alone."""

    step: float  # grid step (smallest distance between two board points)
    idx: np.ndarray  # (M,) the corners checked
    order: np.ndarray  # (M, k) their neighbours' indices (first mask.sum() of each row are neighbours)
    mask: np.ndarray  # (M, k) 1.0 for a neighbour, 0.0 for padding
    x: np.ndarray  # (M, k) normalised board coordinates of the neighbours (0 outside the mask)
    y: np.ndarray
    Ts: np.ndarray  # (M, 3, 3) their normalising transforms


@functools.lru_cache(maxsize=32)
def _neighbourhoods_cached(key: bytes, n: int, radius_steps: float, min_neighbours: int) -> _Neighbourhoods:
    board_xy = np.frombuffer(key, dtype=float).reshape(n, 2)
    d = np.linalg.norm(board_xy[:, None, :] - board_xy[None, :, :], axis=2)  # shape (N, N)
    step = float(np.min(d + np.diag(np.full(n, np.inf))))
    near = (d / step <= radius_steps) & ~np.eye(n, dtype=bool)
    k = max(int(near.sum(axis=1).max()), 1)
    order = np.argsort(~near, axis=1, kind="stable")[:, :k]  # neighbours first, shape (N, k)
    mask = np.take_along_axis(near, order, axis=1).astype(float)
    src = board_xy[order]  # shape (N, k, 2)
    ok = mask.sum(axis=1) >= min_neighbours
    # neighbours on one line fit no homography: need spread across both board directions
    c = (src * mask[..., None]).sum(axis=1) / np.maximum(mask.sum(axis=1), 1)[:, None]
    dev = (src - c[:, None]) * mask[..., None]
    ok &= np.linalg.eigvalsh(dev.transpose(0, 2, 1) @ dev)[:, 0] > 1e-6 * step**2
    sn, Ts = _normalise_masked(src[ok], mask[ok])
    return _Neighbourhoods(
        step=step, idx=np.flatnonzero(ok), order=order[ok], mask=mask[ok], x=sn[..., 0], y=sn[..., 1], Ts=Ts
    )


def _neighbourhoods(board_xy: np.ndarray, radius_steps: float, min_neighbours: int) -> _Neighbourhoods:
    """:class:`_Neighbourhoods` of a board layout (cached: a session's views share their layout)."""
    b = np.ascontiguousarray(board_xy, dtype=float)
    return _neighbourhoods_cached(b.tobytes(), len(b), float(radius_steps), int(min_neighbours))


def apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Points ``xy`` (N, 2) mapped by ``H`` (3, 3), or each by its own ``H`` (N, 3, 3)."""
    p = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    q = (H @ p[..., None])[..., 0] if H.ndim == 3 else p @ H.T
    return q[:, :2] / q[:, 2:3]


@dataclass(frozen=True)
class GridCheck:
    """The geometric check of one view's corners (:func:`grid_check`)."""

    residual_px: np.ndarray  # (N,) distance of each corner from its neighbours' prediction; NaN: not checked
    limit_px: np.ndarray  # (N,) the largest distance allowed there
    worst: int  # index of the corner farthest over (or nearest to) its limit; -1 when none was checked

    @property
    def passed(self) -> bool:
        return self.worst < 0 or bool(self.residual_px[self.worst] <= self.limit_px[self.worst])

    def text(self, what: str = "corner") -> str:
        """e.g. "corner 13 lies 3.0 px from where its neighbours put it (limit 1.8 px)"."""
        k = self.worst
        return (
            f"{what} {k} lies {self.residual_px[k]:.1f} px from where its neighbours put it "
            f"(limit {self.limit_px[k]:.1f} px, configs/detection.yaml grid_check_max_px and _share)"
        )


def grid_check(
    board_xy: np.ndarray,
    image_xy: np.ndarray,
    *,
    radius_steps: float,
    max_px: float,
    max_share: float,
    min_neighbours: int = 6,
) -> GridCheck:
    """Each detected corner against the homography of its board neighbours.

    board_xy: (N, 2) board-plane positions of the detected corners (any unit); image_xy: (N, 2) px.
    Neighbours: the other detected corners within ``radius_steps`` grid steps on the board. A corner
    may lie ``max_px + max_share x`` (the size of one grid step there, px) from its prediction (the
    homography plus :func:`_curvature`): the first term for the corner noise, the second for the lens
    distortion the quadratic leaves. Corners with fewer than ``min_neighbours`` neighbours, or
    neighbours all on one line, are not checked (NaN).
    """
    board_xy = np.asarray(board_xy, float)
    image_xy = np.asarray(image_xy, float)
    n = len(board_xy)
    res, limit = np.full(n, np.nan), np.full(n, np.inf)
    if n >= min_neighbours + 1:
        nb = _neighbourhoods(board_xy, radius_steps, min_neighbours)
        if len(nb.idx):
            H = _homographies(nb, image_xy[nb.order])
            predicted = apply_homography(H, board_xy[nb.idx]) + _curvature(nb, H, board_xy, image_xy)
            res[nb.idx] = np.linalg.norm(predicted - image_xy[nb.idx], axis=1)
            limit[nb.idx] = max_px + max_share * _step_px(H, board_xy[nb.idx], nb.step)
    ratio = res / limit
    worst = int(np.nanargmax(ratio)) if np.isfinite(ratio).any() else -1
    return GridCheck(residual_px=res, limit_px=limit, worst=worst)


def _curvature(nb: "_Neighbourhoods", H: np.ndarray, board_xy: np.ndarray, image_xy: np.ndarray) -> np.ndarray:
    """What the bend of the image across each neighbourhood adds at its corner, px, shape (M, 2).

    A homography is the image of a plane through a pinhole; lens distortion bends it, by an amount that
    grows with the square of the neighbourhood's size, so a homography fitted to the neighbours is off
    at the corner they surround by about the mean bend across them. The neighbours' own misfit to it is
    fitted with a quadratic of their board offset from the corner (1, dx, dy, dx², dx·dy, dy²), whose
    constant is that offset at the corner. Only where the corner lies within its neighbours' extent on
    both axes (interpolated, not extrapolated) and they are at least two per coefficient; elsewhere 0.
    """
    board = board_xy[nb.order]  # shape (M, k, 2)
    p = np.concatenate([board, np.ones(board.shape[:2] + (1,))], axis=2)
    q = np.einsum("mij,mkj->mki", H, p)
    e = (image_xy[nb.order] - q[..., :2] / q[..., 2:3]) * nb.mask[..., None]  # neighbours' misfit, (M, k, 2)
    d = (board - board_xy[nb.idx][:, None, :]) / nb.step
    dx, dy, m = d[..., 0], d[..., 1], nb.mask
    D = np.stack([m, dx * m, dy * m, dx * dx * m, dx * dy * m, dy * dy * m], axis=2)  # shape (M, k, 6)
    big = np.where(m > 0, 1.0, np.nan)
    around = (np.nanmin(dx * big, axis=1) <= 0) & (np.nanmax(dx * big, axis=1) >= 0)
    around &= (np.nanmin(dy * big, axis=1) <= 0) & (np.nanmax(dy * big, axis=1) >= 0)
    around &= m.sum(axis=1) >= 2 * D.shape[2]  # two neighbours per coefficient, or the fit's noise would dominate
    N = D.transpose(0, 2, 1) @ D
    around &= np.linalg.eigvalsh(N)[:, 0] > 1e-6 * np.trace(N, axis1=1, axis2=2)
    out = np.zeros((len(nb.idx), 2))
    if around.any():
        coef = np.linalg.solve(N[around], D[around].transpose(0, 2, 1) @ e[around])  # shape (A, 6, 2)
        out[around] = coef[:, 0, :]
    return out


def check_corners(board_xy: np.ndarray, image_xy: np.ndarray, options) -> GridCheck:
    """:func:`grid_check` with the settings of ``options`` (a :class:`.options.DetectionOptions`)."""
    return grid_check(
        board_xy,
        image_xy,
        radius_steps=options.grid_check_radius_steps,
        max_px=options.grid_check_max_px,
        max_share=options.grid_check_max_share,
    )


def _step_px(H: np.ndarray, board_xy: np.ndarray, step: float) -> np.ndarray:
    """Shortest image length (px) of one grid step at each board point under a homography.

    Shortest image length (px) of one grid step at each board point under its own (N, 3, 3) or a
    common (3, 3) homography: the smallest singular value of the Jacobian there, shape (N,).
    """
    Hs = np.broadcast_to(H, (len(board_xy), 3, 3))
    p = (Hs @ np.concatenate([board_xy, np.ones((len(board_xy), 1))], axis=1)[..., None])[..., 0]  # (N, 3)
    w = p[:, 2]
    # d(u, v)/d(x, y) of (H p)[:2] / (H p)[2]
    J = (Hs[:, :2, :2] * w[:, None, None] - p[:, :2, None] * Hs[:, 2:3, :2]) / (w**2)[:, None, None]
    # smallest singular value of a 2x2 matrix: sqrt of the smaller eigenvalue of J^T J
    a, b, c = (J**2).sum(axis=1)[:, 0], (J[:, :, 0] * J[:, :, 1]).sum(axis=1), (J**2).sum(axis=1)[:, 1]
    lo = 0.5 * (a + c) - np.sqrt(0.25 * (a - c) ** 2 + b**2)
    return np.sqrt(np.maximum(lo, 0.0)) * step


def board_homography(board_xy: np.ndarray, image_xy: np.ndarray, *, robust: bool = True) -> np.ndarray | None:
    """Homography board plane -> image, or None when it cannot be fitted.

    ``robust``: least median of squares (up to half of the corners may be wrong); otherwise least
    squares (faster, for corners that are all right).
    """
    if len(board_xy) < 4:
        return None
    H, _ = cv2.findHomography(
        np.asarray(board_xy, np.float64), np.asarray(image_xy, np.float64), cv2.LMEDS if robust else 0
    )
    return H


def square_px(H: np.ndarray, board_xy: np.ndarray, step: float) -> np.ndarray:
    """Size in px of a grid step at each board point under ``H``.

    The shortest image length of one step in any direction, shape (N,).
    """
    return _step_px(H, board_xy, step)


def search_copy(gray: np.ndarray, *, max_megapixels: float) -> tuple[np.ndarray, np.ndarray]:
    """The image the searches run on and its scale (x, y): the image itself or a reduced copy.

    (the image the searches run on, its scale (x, y)): the image itself, or, above ``max_megapixels``,
    a copy reduced to that area (the searches' time grows faster than the area; the corners are refined
    on the full image afterwards).
    """
    h, w = gray.shape[:2]
    mp = w * h / 1e6
    if mp <= max_megapixels:
        return gray, np.ones(2)
    scale = float(np.sqrt(max_megapixels / mp))
    size = (max(1, int(w * scale)), max(1, int(h * scale)))
    log.info(
        "image %dx%d (%.1f MP) is above the %.g MP search limit: searched at %dx%d, refined at full size",
        w,
        h,
        mp,
        max_megapixels,
        *size,
    )
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA), np.array([size[0] / w, size[1] / h])


@dataclass
class TimeBudget:
    """Time one image's detection may take before its slower searches are skipped.

    CPU time of the thread that detects it (from the creation of the budget), so that one image gives
    the same outcome on an idle and on a loaded machine (wall-clock time there also counts the other
    threads' work).
    """

    seconds: float
    start: float = field(default_factory=time.thread_time)

    def elapsed(self) -> float:
        return time.thread_time() - self.start

    def spent(self) -> bool:
        return self.elapsed() >= self.seconds

    def timed_out(self, skipped: str) -> str:
        """The reason of a view dropped because the budget was spent before ``skipped`` could run."""
        return (
            f"detection timed out: {self.elapsed():.3g} s of CPU time spent of the {self.seconds:g} s budget "
            f"(configs/detection.yaml time_budget_s), {skipped} skipped"
        )
