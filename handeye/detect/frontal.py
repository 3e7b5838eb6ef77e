"""Corners refined in the board's frontal frame: cornerSubPix on the image resampled through a homography.

A corner where a tag touches a gap square (AprilGrid) or two squares meet between markers (ChArUco) is
point-symmetric only out to the clear margin around it (a border cell, the white band beside a marker). In
the image that margin shrinks with the board's tilt along one direction, and with blur the structures beyond
it merge in: a square window in the image sized for the margin either holds too little or reaches the code
cells. Resampled through a homography of the board plane (bilinear) at the image's own resolution, and at
least ``min_clear_px`` across the margin, the corner is seen head-on whatever the tilt, the window fits the
margin, and the corner maps back through the same homography. A junction stays the junction under any smooth
map, so the homography's own error (lens distortion, rough corners) does not move the corner; it only decides
which image pixels are read.
"""

from __future__ import annotations

import cv2
import numpy as np


def frontal_refined(
    gray: np.ndarray,
    start: np.ndarray,
    H: np.ndarray,
    *,
    clear_m: float,
    apart_m: float,
    criteria,
    min_clear_px: float,
    reach_clear: float,
    share: float,
) -> np.ndarray:
    """Corners (N, 2) px refined from ``start`` (N, 2) px, each in the board's frontal frame around it.

    ``H`` (3, 3), or one per corner (N, 3, 3): a homography board plane (m) -> image (px) the patches are
    resampled through, each centred where it puts its start (a global homography can be px off a corner where
    the lens bends the board); ``clear_m``: the clear margin around a corner on the board; ``apart_m``: the
    distance to the nearest other corner. Each patch reaches ``reach_clear`` margins around its corner at the
    larger of the image's local scale and ``min_clear_px`` per margin; cornerSubPix runs there twice, with a half
    window of twice ``share`` x the margin (it reaches a start a few px off; at most half of ``apart_m``, so it stays
    on the corner's side of the midpoint to the next one) and then once.
    """
    start = np.asarray(start, float).reshape(-1, 2)
    Hs = np.broadcast_to(np.asarray(H, float), (len(start), 3, 3))
    out = start.copy()
    for i, (p, Hi) in enumerate(zip(start, Hs, strict=True)):
        b = np.linalg.solve(Hi, np.array([p[0], p[1], 1.0]))
        b = b[:2] / b[2]  # the patch's centre on the board: where the homography puts the start
        x = Hi @ np.array([b[0], b[1], 1.0])
        J = (Hi[:2, :2] * x[2] - np.outer(x[:2], Hi[2, :2])) / x[2] ** 2  # px per m at the corner
        scale = max(float(np.linalg.svd(J, compute_uv=False)[0]), min_clear_px / clear_m)  # patch px per m
        clear_px = clear_m * scale
        half = max(int(share * clear_px), 2)
        reach = int(np.ceil(reach_clear * clear_px))
        M = Hi @ np.array([[1 / scale, 0, b[0] - reach / scale], [0, 1 / scale, b[1] - reach / scale], [0, 0, 1]])
        patch = cv2.warpPerspective(  # patch px -> image px is M
            gray,
            M,
            (2 * reach + 1, 2 * reach + 1),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REPLICATE,
        )
        c: np.ndarray = np.full((1, 1, 2), reach, np.float32)
        for w in (max(min(2 * half, int(0.5 * apart_m * scale), reach - 1), half), half):
            c = cv2.cornerSubPix(patch, c, (w, w), (-1, -1), criteria)
        y = M @ np.array([c[0, 0, 0], c[0, 0, 1], 1.0])
        out[i] = y[:2] / y[2]
    return out
