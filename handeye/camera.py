"""The camera model: intrinsics and THE projection (OpenCV's 5-coefficient model) with its Jacobians.

Every part of handeye that turns a point into a pixel calls :func:`pixels_from_cam_points` (the
factors, the closed-form stage, the diagnostics, the planner and the simulator). ``cv2.projectPoints``
is used only as a test oracle.

Intrinsics vector order: ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` (:data:`INTRINSIC_NAMES`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import numpy.typing as npt

from .frames import transform_points

INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera with OpenCV's 5-coefficient distortion (k1, k2, p1, p2, k3)."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    width: int = 0
    height: int = 0
    model: str = "opencv5"

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.width, self.height)

    def as_vector(self) -> np.ndarray:
        """(fx, fy, cx, cy, k1, k2, p1, p2, k3)."""
        return np.concatenate([[self.fx, self.fy, self.cx, self.cy], self.dist_array])

    @staticmethod
    def from_vector(v: npt.ArrayLike, width: int, height: int) -> "Intrinsics":
        v = np.asarray(v, float)
        return Intrinsics(
            float(v[0]), float(v[1]), float(v[2]), float(v[3]), tuple(float(x) for x in v[4:9]), int(width), int(height)
        )

    @staticmethod
    def from_K(K: np.ndarray, dist: npt.ArrayLike, width: int, height: int) -> "Intrinsics":
        d = np.zeros(5)
        dd = np.asarray(dist, float).reshape(-1)[:5]
        d[: dd.size] = dd
        return Intrinsics(
            float(K[0, 0]),
            float(K[1, 1]),
            float(K[0, 2]),
            float(K[1, 2]),
            tuple(float(x) for x in d),
            int(width),
            int(height),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "dist": dict(zip(DIST_NAMES, map(float, self.dist), strict=False)),
            "dist_order": "k1, k2, p1, p2, k3 (OpenCV)",
            "image_size": [self.width, self.height],
        }


# ------------------------------------------------------------------------------ projection
#: a pixel past this share of the fold's distorted radius (:func:`radial_fold`) sees nothing: the inverse
#: of the lens model is ill-conditioned at the fold
FOLD_SHARE = 0.98


def radial_fold(dist: Any) -> tuple[float, np.ndarray, np.ndarray]:
    """(distorted radius where the radial model folds over, its monotonic part's r and r_d tables).

    OpenCV's radial model ``r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` fitted to a lens holds where it rises;
    past its first maximum no undistorted ray maps there, so that part of an image sees nothing. ``inf``
    when it keeps rising up to r = 4 (76 degrees off the optical axis).
    """
    k1, k2, _, _, k3 = (float(v) for v in dist)
    r = np.linspace(0.0, 4.0, 40001)
    rd = r * (1.0 + r * r * (k1 + r * r * (k2 + r * r * k3)))
    falls = np.flatnonzero(np.diff(rd) <= 0.0)
    if not falls.size:
        return float("inf"), r, rd
    i = int(falls[0])
    return float(rd[i]), r[: i + 1], rd[: i + 1]


def project_opencv5(
    intrinsics_vec: np.ndarray, p_cam: np.ndarray, jacobians: bool
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """Pixels (N,2) and, when asked, the Jacobians laid out transposed for speed.

    Pixels (N,2) and, when asked, the Jacobians laid out transposed for speed:
    ``Jp_T`` (3, 2N) = (d uv / d p_cam)^T and ``Jk_T`` (9, 2N) = (d uv / d intrinsics)^T, with the
    2N columns interleaved (u0, v0, u1, v1, ...).
    """
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in intrinsics_vec)
    n = p_cam.shape[0]
    iz = 1.0 / p_cam[:, 2]
    x = p_cam[:, 0] * iz
    y = p_cam[:, 1] * iz
    xx, yy, xy = x * x, y * y, x * y
    r2 = xx + yy
    r4 = r2 * r2
    r6 = r4 * r2
    radial = 1.0 + k1 * r2 + k2 * r4 + k3 * r6
    a_x = r2 + 2.0 * xx  # d xd / d p2
    a_y = r2 + 2.0 * yy  # d yd / d p1
    xd = x * radial + 2.0 * p1 * xy + p2 * a_x
    yd = y * radial + p1 * a_y + 2.0 * p2 * xy
    uv = np.empty((n, 2))
    uv[:, 0] = fx * xd + cx
    uv[:, 1] = fy * yd + cy
    if not jacobians:
        return uv, None, None

    c = 2.0 * (k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4)  # 2 d radial / d r2
    cross = c * xy + 2.0 * (p1 * x + p2 * y)  # d xd / d y = d yd / d x
    Jp = np.empty((3, n, 2))  # [component of p_cam, corner, u|v]
    Jp[0, :, 0] = fx * (radial + c * xx + 2.0 * p1 * y + 6.0 * p2 * x) * iz
    Jp[1, :, 0] = fx * cross * iz
    Jp[0, :, 1] = fy * cross * iz
    Jp[1, :, 1] = fy * (radial + c * yy + 6.0 * p1 * y + 2.0 * p2 * x) * iz
    Jp[2] = -(Jp[0] * x[:, None] + Jp[1] * y[:, None])  # d(x, y)/dZ = -(x, y)/Z
    Jk = np.zeros((9, n, 2))
    Jk[0, :, 0] = xd
    Jk[1, :, 1] = yd
    Jk[2, :, 0] = 1.0
    Jk[3, :, 1] = 1.0
    fxx, fyy = fx * x, fy * y
    Jk[4, :, 0] = fxx * r2
    Jk[4, :, 1] = fyy * r2
    Jk[5, :, 0] = fxx * r4
    Jk[5, :, 1] = fyy * r4
    Jk[8, :, 0] = fxx * r6
    Jk[8, :, 1] = fyy * r6
    Jk[6, :, 0] = (2.0 * fx) * xy
    Jk[6, :, 1] = fy * a_y
    Jk[7, :, 0] = fx * a_x
    Jk[7, :, 1] = (2.0 * fy) * xy
    return uv, Jp.reshape(3, 2 * n), Jk.reshape(9, 2 * n)


def pixels_from_cam_points(
    intrinsics_vec: np.ndarray, p_cam: np.ndarray, *, jacobians: bool = True
) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """Project camera-frame points (N,3) with OpenCV's 5-coefficient model.

    Returns ``(uv, J_uv_p, J_uv_intr)``: pixels (N,2), d uv / d p_cam (N,2,3) and
    d uv / d intrinsics (N,2,9); the Jacobians are None when ``jacobians`` is False.
    """
    p_cam = np.asarray(p_cam, float)
    uv, Jp_T, Jk_T = project_opencv5(intrinsics_vec, p_cam, jacobians)
    if not jacobians:
        return uv, None, None
    assert Jp_T is not None and Jk_T is not None, "Jacobians asked for and computed"
    n = p_cam.shape[0]
    return uv, Jp_T.reshape(3, n, 2).transpose(1, 2, 0), Jk_T.reshape(9, n, 2).transpose(1, 2, 0)


def pixels_from_board_points(T_cam_board: np.ndarray, p_board: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Pixels (N,2) of board points (N,3) seen from a camera at ``T_cam_board``."""
    return project_opencv5(
        intrinsics.as_vector(), transform_points(T_cam_board, np.asarray(p_board, float).reshape(-1, 3)), False
    )[0]
