"""The second refinement stage of chessboard corners: the centre of point symmetry around each corner.

An ideal corner seen through any point-symmetric blur is point-symmetric about the corner, so the
corner is where the odd part of the image around it vanishes: the saddle point of a quadratic fitted
with symmetric weights to the smoothed, shading-free intensity. A corner that this stage and
cornerSubPix put more than ``corner_disagreement_max_px`` apart is not used
(:func:`handeye.detect.chessboard.final_corners`).

See docs/detection.md.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

_CONVERGED_PX = 1e-3  # a step this small leaves the corner where it is (far below its noise)


@functools.lru_cache(maxsize=64)
def _fit_rows(half_win: int, grid_half: int) -> np.ndarray:
    """P (6, M): the weighted least-squares map from grid samples to a quadratic's coefficients.

    P (6, M): the weighted least-squares map from the samples of a (2 g + 1)^2 grid (g = ``grid_half``,
    row-major) to the coefficients (x^2, xy, y^2, x, y, 1) of a quadratic, with Gaussian weights of sigma =
    ``half_win`` / 2 inside the window of half size ``half_win`` (symmetric about the centre) and 0
    outside it.
    """
    d = np.arange(-grid_half, grid_half + 1, dtype=float)
    dx, dy = (a.ravel() for a in np.meshgrid(d, d))
    inside = (np.abs(dx) <= half_win) & (np.abs(dy) <= half_win)
    w = np.where(inside, np.exp(-0.5 * (dx**2 + dy**2) / (0.5 * half_win) ** 2), 0.0)
    A = np.stack([dx * dx, dx * dy, dy * dy, dx, dy, np.ones_like(dx)], axis=1)  # shape (M, 6)
    Aw = A * w[:, None]
    return np.linalg.solve(A.T @ Aw, Aw.T)


def _patches(padded: np.ndarray, c: np.ndarray, g: int) -> np.ndarray:
    """Bilinear samples of ``padded`` on a (2g+1)^2 grid around each corner, shape (n, (2g+1)^2).

    Bilinear samples of ``padded`` at ``c[i] + (dx, dy)``, dx, dy in -g..g, shape (n, (2g+1)^2), row-major.
    All samples of a corner share its fractional position, so they are four weighted shifts of one integer
    block (cv2.remap would round the positions to 1/32 px, a shift of up to 0.016 px common to the window).
    ``c`` must keep the blocks inside ``padded``.
    """
    f = np.floor(c).astype(int)
    fx, fy = (c - f).T[:, :, None, None]  # shape (n, 1, 1) each
    r = np.arange(-g, g + 2)
    offsets = (r[:, None] * padded.shape[1] + r[None, :]).ravel()
    block = np.take(padded, (f[:, 1] * padded.shape[1] + f[:, 0])[:, None] + offsets[None, :])
    block = block.reshape(len(c), 2 * g + 2, 2 * g + 2).astype(float)
    v = (1 - fy) * ((1 - fx) * block[:, :-1, :-1] + fx * block[:, :-1, 1:]) + fy * (
        (1 - fx) * block[:, 1:, :-1] + fx * block[:, 1:, 1:]
    )
    return v.reshape(len(c), -1)


def shading_free(smooth: np.ndarray, *, box_px: int) -> np.ndarray:
    """``smooth`` minus its ``box_px`` x ``box_px`` box average, float32 (a linear shading cancels)."""
    box = cv2.boxFilter(smooth, cv2.CV_32F, (int(box_px), int(box_px)), borderType=cv2.BORDER_REPLICATE)
    return cv2.subtract(smooth, box, dtype=cv2.CV_32F)


def symmetric_corners(
    image: np.ndarray, pts: np.ndarray, half_win: np.ndarray, *, iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """(corners (N, 2), ok (N,) bool): each point moved to the saddle point of a fitted quadratic.

    (corners (N, 2), ok (N,) bool): each of ``pts`` moved to the saddle point of the quadratic fitted
    to ``image`` (float32, shading removed: :func:`shading_free`) in its window of half size ``half_win``
    px, re-centred up to ``iterations`` times (until no corner moves by 0.001 px). ``ok`` is False where
    the fit is no saddle (the window holds no corner) or the estimate left its window.
    """
    start = np.asarray(pts, float).reshape(-1, 2)
    half_win = np.asarray(half_win, int)
    g = int(half_win.max())
    pad = g + iterations + 2  # each step moves a corner by 1 px at most
    padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    sizes, which = np.unique(half_win, return_inverse=True)
    P = np.stack([_fit_rows(int(h), g) for h in sizes])[which]  # shape (N, 6, M)
    c = start + pad
    saddle = np.ones(len(c), bool)
    moving = np.arange(len(c))  # the corners still moving
    for _ in range(iterations):
        q = np.einsum("nm,nkm->nk", _patches(padded, c[moving], g), P[moving])  # shape (n, 6)
        a, b, cc, d, e = q[:, 0], q[:, 1], q[:, 2], q[:, 3], q[:, 4]
        det = 4.0 * a * cc - b * b  # negative at a saddle
        saddle[moving] = det < 0
        det = np.where(det < 0, det, -1.0)
        step = np.stack([(b * e - 2.0 * cc * d) / det, (b * d - 2.0 * a * e) / det], axis=1)
        step = np.where(saddle[moving, None], np.clip(step, -1.0, 1.0), 0.0)
        c[moving] += step
        moving = moving[np.abs(step).max(axis=1) >= _CONVERGED_PX]
        if not len(moving):
            break
    c = c - pad
    return c, saddle & (np.linalg.norm(c - start, axis=1) <= half_win)
