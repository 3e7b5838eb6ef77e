"""What observations.json says about each view, as arrays (no fitting here).

observations.json holds, per detected view, the corners, the view's own board pose under the final
intrinsics (``T_cam_board_pnp``, ``residual_pnp_px``) and the board predicted through the reported
robot pose and the result (``T_cam_board_chain``, ``residual_chain_px``). The report reads them; it
never re-solves a pose. A view without them (a hand-edited file) shows no residuals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..frames import inv_T, pose_error, transform_points
from ..mounting import MountingMode


def finite(x) -> bool:
    try:
        return x is not None and bool(np.all(np.isfinite(np.asarray(x, float))))
    except (TypeError, ValueError):
        return False


def _finite_array(x, shape: tuple) -> Optional[np.ndarray]:
    """A float array of ``shape`` from nested lists, or None when absent, malformed or not finite."""
    if x is None:
        return None
    try:
        a = np.asarray(x, float)
    except (TypeError, ValueError):
        return None
    return a if a.shape == shape and np.all(np.isfinite(a)) else None


def as_T(x) -> Optional[np.ndarray]:
    """A 4x4 float array from nested lists, or None when absent or not a finite 4x4."""
    return _finite_array(x, (4, 4))


def as_cov6(x) -> Optional[np.ndarray]:
    C = _finite_array(x, (6, 6))
    return None if C is None else 0.5 * (C + C.T)


def rms_norm(r) -> float:
    r = np.asarray(r, float).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")


@dataclass(frozen=True)
class ViewFit:
    """One view's corners against the board pose its corners alone imply, and through the robot chain."""

    view_id: str
    corner_ids: np.ndarray  # (N,)
    image_points_px: np.ndarray  # (N, 2)
    residual_px: np.ndarray  # (N, 2) detected - predicted, camera-only fit (NaN when not recorded)
    T_cam_board: Optional[np.ndarray]
    residual_chain_px: Optional[np.ndarray]  # (N, 2) through the reported robot pose and the result
    T_cam_board_chain: Optional[np.ndarray]
    T_base_end: Optional[np.ndarray]  # the reported robot pose

    @property
    def rms_px(self) -> float:
        return rms_norm(self.residual_px)

    @property
    def max_px(self) -> float:
        r = np.linalg.norm(self.residual_px, axis=1) if len(self.residual_px) else np.zeros(0)
        return float(r.max()) if len(r) and np.all(np.isfinite(r)) else float("nan")

    @property
    def chain_rms_px(self) -> float:
        return rms_norm(self.residual_chain_px) if self.residual_chain_px is not None else float("nan")


def view_fits(obs: dict) -> dict[str, ViewFit]:
    """View id -> :class:`ViewFit` for every view observations.json describes."""
    out: dict[str, ViewFit] = {}
    for vid, v in (obs.get("views") or {}).items():
        try:
            ids = np.asarray(v["corner_ids"], int).reshape(-1)
            uv = np.asarray(v["image_points_px"], float).reshape(-1, 2)
        except (KeyError, TypeError, ValueError):
            continue
        resid = _finite_array(v.get("residual_pnp_px"), (len(ids), 2))
        chain = _finite_array(v.get("residual_chain_px"), (len(ids), 2))
        out[str(vid)] = ViewFit(
            str(vid),
            ids,
            uv,
            resid if resid is not None else np.full((len(ids), 2), np.nan),
            as_T(v.get("T_cam_board_pnp")),
            chain,
            as_T(v.get("T_cam_board_chain")),
            as_T(v.get("T_base_end_reported")),
        )
    return out


def board_disagreement(fit: ViewFit, board_centre_m: np.ndarray) -> tuple[float, float]:
    """(deg, mm) between the board pose the camera saw and the one predicted through the robot chain."""
    if fit.T_cam_board is None or fit.T_cam_board_chain is None:
        return float("nan"), float("nan")
    deg, _ = pose_error(fit.T_cam_board_chain, fit.T_cam_board)
    c = np.asarray(board_centre_m, float)
    mm = float(1e3 * np.linalg.norm(transform_points(fit.T_cam_board, c) - transform_points(fit.T_cam_board_chain, c)))
    return float(deg), mm


def median_board_distance_m(fits: dict[str, ViewFit], board_centre_m: np.ndarray) -> float:
    """Median distance along the optical axis from the camera to the board centre (the working distance)."""
    d = [float(transform_points(f.T_cam_board, board_centre_m)[2]) for f in fits.values() if f.T_cam_board is not None]
    return float(np.median(d)) if d else float("nan")


def coverage_counts(points_px: np.ndarray, *, width: int, height: int, cells_x: int) -> np.ndarray:
    """Corner counts in a grid of square-ish cells over the image.

    Corner counts in a grid of square-ish cells over the image (rows, cols); ``cells_x`` across the
    width (configs/qa.yaml ``coverage_grid_cells_x``), rows in proportion.
    """
    cells_y = max(1, int(round(cells_x * height / max(width, 1))))
    pts = np.asarray(points_px, float).reshape(-1, 2)
    counts = np.zeros((cells_y, cells_x), int)
    if len(pts):
        cx = np.clip((pts[:, 0] / width * cells_x).astype(int), 0, cells_x - 1)
        cy = np.clip((pts[:, 1] / height * cells_y).astype(int), 0, cells_y - 1)
        np.add.at(counts, (cy, cx), 1)
    return counts


def robot_motions(T_base_end: np.ndarray, mounting: MountingMode) -> np.ndarray:
    """The robot motions ``M_i`` (N,4,4) of the hand-eye model for reported poses (N,4,4)."""
    return mounting.M_from_T_base_end(np.asarray(T_base_end, float).reshape(-1, 4, 4))


def relative_rotvecs(M: np.ndarray) -> np.ndarray:
    """Rotation vectors (P, 3) of all pairwise robot motions ``M_i · M_j^-1`` (for the coverage figure)."""
    from ..frames import rotvec_from_R

    M = np.asarray(M, float).reshape(-1, 4, 4)
    if len(M) < 2:
        return np.zeros((0, 3))
    iu, ju = np.triu_indices(len(M), 1)
    return rotvec_from_R((M[iu] @ inv_T(M[ju]))[:, :3, :3]).reshape(-1, 3)
