"""What the pose-level checks work on: the views with a board pose, in session order.

:class:`PoseObservations` holds them with the robot pose numbers as written, built from a calibration
run or from a leniently read session.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..camera import Intrinsics, pixels_from_board_points
from ..frames import inv_T
from ..mounting import mounting
from ..session.raw import RawPoses, raw_poses_of
from .geometry import RAYLEIGH_MEDIAN, camera_pose_covariances
from .thresholds import thresholds


@dataclass(frozen=True)
class PoseObservations:
    mode: str
    ids: tuple
    C: np.ndarray  # (N,4,4) T_cam_board from PnP
    T: np.ndarray  # (N,4,4) reported T_base_end as loaded
    raw: RawPoses
    times: dict  # view id -> (t_image, t_pose) where recorded
    corners: tuple = ()  # per view (object_points (K,3), image_points (K,2)) for the PnP covariances
    intrinsics: Optional[Intrinsics] = None
    target: object = None
    intrinsics_estimated: bool = True  # intrinsics come from these corners (their uncertainty counts)
    C_candidates: Optional[np.ndarray] = None  # (N,k,4,4) symmetric boards: T_cam_board under every ordering
    tracker: bool = False  # the poses come from a tracker (pose-only session), not from an arm

    @property
    def n(self) -> int:
        return len(self.ids)

    @property
    def candidates_are_turns(self) -> bool:
        """Whether ``C_candidates`` are turns of a symmetric board.

        ``C_candidates`` are turns of a symmetric board (False: the two poses of a single marker's planar
        ambiguity), for :func:`handeye.initial.board_poses.orientation_labels`.
        """
        return not getattr(self.target, "pose_ambiguous", False)

    @property
    def mounting(self):
        return mounting(self.mode)

    def pnp_covariances(self, *, with_intrinsics: bool = True) -> Optional[np.ndarray]:
        """(N,6,6) covariance of each view's board pose.

        (N,6,6) covariance of each view's board pose (right tangent of :mod:`handeye.frames`), with the
        pixel noise taken robustly from all PnP residuals; None without corners. ``with_intrinsics``: add
        the uncertainty of intrinsics estimated from the same corners (when they were).
        """
        if not self.corners or self.intrinsics is None:
            return None
        return camera_pose_covariances(
            self.corners,
            self.C,
            self.intrinsics.as_vector(),
            self.pixel_sigma(),
            intrinsics_estimated=with_intrinsics and self.intrinsics_estimated,
        )

    def pixel_sigma(self) -> float:
        """The corners' pixel noise, robustly from all PnP residuals, never below ``pixel_sigma_floor_px``."""
        assert self.corners and self.intrinsics is not None, "corners and intrinsics"
        res = [
            np.linalg.norm(pixels_from_board_points(C, o, self.intrinsics) - im, axis=1)
            for (o, im), C in zip(self.corners, self.C, strict=False)
        ]
        return max(
            float(np.median(np.concatenate(res))) / RAYLEIGH_MEDIAN, thresholds().robot_pose.pixel_sigma_floor_px
        )

    def M(self, T: Optional[np.ndarray] = None, *, invert: bool = False) -> np.ndarray:
        """Robot motions of the mode for poses ``T`` (default: as loaded); ``invert``: of the inverted poses."""
        M = self.mounting.M_from_T_base_end(self.T if T is None else T)
        return inv_T(M) if invert else M


def observations_from_run(run) -> Optional[PoseObservations]:
    """The run's views with a board pose (None below the minimum view count).

    A tracker's poses whose translation scale the refinement estimated (``--estimate-scale``) are seen
    rescaled to metric, as the refinement models them.
    """
    s = run.session
    ids = [v.view_id for v in s.views if v.view_id in (run.board_poses or {})]
    if len(ids) < thresholds().views.min_fail:
        return None
    C = np.stack([run.board_poses[v].T_cam_board for v in ids])
    T = np.stack([s.view(v).T_base_end for v in ids])
    times = {v.view_id: (v.t_image, v.t_pose) for v in s.views if v.t_image is not None and v.t_pose is not None}
    obj = s.target.object_points()
    corners = (
        tuple((obj[run.board_poses[v].corner_ids], run.detections[v].image_points) for v in ids)
        if run.detections and all(v in run.detections for v in ids)
        else ()
    )
    estimated = not (s.intrinsics is not None and s.intrinsics_prior == "fixed")
    # the intrinsics the board poses were solved with (a refinement replaces run.intrinsics by its own)
    refined = run.refined if (run.refined is not None and getattr(run.refined, "status", "") == "ok") else None
    intrinsics = getattr(refined, "intrinsics_seed", None) if refined is not None else run.intrinsics
    scale = getattr(refined, "tracker_scale", None)
    if scale is not None and np.isfinite(scale) and scale > 0:
        C = C.copy()
        C[:, :3, 3] /= scale
    return PoseObservations(
        s.mode,
        tuple(ids),
        C,
        T,
        raw_poses_of(s),
        times,
        corners,
        intrinsics or run.intrinsics,
        s.target,
        estimated,
        candidates_of(run.board_poses, ids),
        tracker=bool(s.meta.get("pose_only")),
    )


def candidates_of(board_poses: dict, ids) -> Optional[np.ndarray]:
    """(N,k,4,4) board poses under every ordering of a symmetric board, or None (asymmetric board)."""
    cands = [getattr(board_poses[v], "candidates", ()) for v in ids]
    if not cands or any(len(c) < 2 for c in cands) or len({len(c) for c in cands}) != 1:
        return None
    return np.stack([np.stack(c) for c in cands])
