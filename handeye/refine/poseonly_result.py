"""The records of the pose-only refinement: a tracker's view and the refinement's result.

:class:`PoseView` is one view (the tracker's ``T_cam_board``, the reported robot pose, the joint readings);
:class:`PoseRefineResult` is :func:`handeye.refine.poseonly.refine_poses`' result, with the tracker's noise,
the degrees of freedom of its estimated sigmas, the arm's model and the tracker's scale when estimated.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Optional

import numpy as np

from .poseonly_robot import PoseRobotModel
from .result import RefineResult


@dataclass(frozen=True)
class PoseView:
    """One pose-only view: the tracker's ``T_cam_board`` and the reported robot pose ``T_base_end``."""

    view_id: str
    T_cam_board: np.ndarray  # (4, 4)
    T_base_end: np.ndarray  # (4, 4)
    joint_angles: Optional[np.ndarray] = None  # (n_joints,) the arm's joint readings (radians), when recorded


class _NoIntrinsics:
    """Stands in for the intrinsics of a pose-only result when it is written (there is no camera model)."""

    def to_dict(self) -> None:
        return None


@dataclass(frozen=True)
class PoseRefineResult(RefineResult):
    """A :class:`.result.RefineResult` of pose-only views: no intrinsics and no pixels.

    A :class:`.result.RefineResult` of pose-only views: no intrinsics and no pixels (``intrinsics`` is
    None, the pixel figures NaN); the tracker's noise instead.
    """

    tracker_sigma_deg: float = float("nan")
    tracker_sigma_mm: float = float("nan")  # across the camera's optical axis (x, y), per axis
    tracker_sigma_along_mm: float = float("nan")  # along the optical axis (z)
    tracker_sigma_source: str = ""  # stated | estimated
    tracker_sigma_resolved: dict[str, Any] = field(default_factory=dict)
    cov_board_6x6: Optional[np.ndarray] = None
    pose_robot: Optional[PoseRobotModel] = None  # the arm's kinematic model (--robot), for the refits
    dh_offset: Optional[np.ndarray] = None  # (m,) its DH offsets as estimated
    tracker_noise_dof: dict[str, float] = field(default_factory=dict)  # per estimated sigma: its redundancy
    cov_x_noise_dof: Optional[float] = None  # the F's of X's factor (:mod:`.tracker_dof`; None: the sigmas stated)
    cov_x_dof_factor: float = 1.0  # the plug-in covariance of X was multiplied by this (:mod:`.tracker_dof`)
    tracker_scale: Optional[float] = None  # the tracker's translation scale, when estimated
    tracker_scale_sigma: Optional[float] = None
    tracker_tail_dof: float = float("inf")  # the tracker's Student-t degrees of freedom (inf: Gaussian)
    view_weights: Optional[dict[str, float]] = None  # each view's EM weight under that t (:mod:`.tracker_tails`)

    def to_dict(self) -> dict[str, Any]:
        no = _NoIntrinsics()
        d = RefineResult.to_dict(replace(self, intrinsics=no, intrinsics_seed=no))  # type: ignore[arg-type]
        d["observations"] = "poses"
        d["tracker_noise"] = {
            "sigma_deg": self.tracker_sigma_deg,
            "sigma_mm": self.tracker_sigma_mm,
            "sigma_mm_along": self.tracker_sigma_along_mm,
            "source": self.tracker_sigma_source,
            "resolved": dict(self.tracker_sigma_resolved),
            # the views' noise a multivariate Student-t of these degrees of freedom (None: Gaussian), chosen by
            # its likelihood; X's covariance is that model's (handeye.refine.tracker_tails)
            "tail_dof": None if not np.isfinite(self.tracker_tail_dof) else self.tracker_tail_dof,
            "model": "T_cam_board_measured = T_cam_board_true · Exp(n): rotation noise sigma_deg per axis, "
            "translation noise in the camera frame sigma_mm per axis across the optical axis (x, y) and "
            "sigma_mm_along along it (z)"
            + ("" if not np.isfinite(self.tracker_tail_dof) else ", n a multivariate Student-t (scale sigma, tail_dof)")
            + "; "
            + (
                "robot poses through the arm's kinematic model (refinement.robot_model)"
                if self.pose_robot is not None
                else "robot poses taken as reported (their noise is part of it)"
            ),
        }
        if self.cov_board_6x6 is not None:
            d["cov_board_6x6"] = self.cov_board_6x6.tolist()
        d["tracker_noise_dof"] = dict(self.tracker_noise_dof)  # X's factor, its nu and method: RefineResult's
        if self.tracker_scale is not None:
            d["tracker_scale"] = {
                "value": self.tracker_scale,
                "sigma": self.tracker_scale_sigma,
                "model": "the tracker's translations are s x the true ones (T_cam_board's translation measured as "
                "s · t), s estimated jointly with the hand-eye transform and the target pose; X's covariance "
                "marginalises s",
            }
        return d
