"""The initial estimate: intrinsics, board poses, the motion gate and OpenCV's closed forms.

- ``intrinsics``: :func:`calibrate_intrinsics` (OpenCV calibrateCamera);
- ``board_poses``: :func:`solve_pnp`, :func:`board_poses`, :class:`BoardPose` (with the
  symmetric-board ordering);
- ``motion``: :func:`motion_quality` (the one degeneracy test; thresholds in configs/);
- ``closed_form``: :data:`METHODS`, :func:`solve_closed_form`, :func:`all_methods`,
  :func:`consistency`, :func:`chain_residuals`.
"""

from .board_poses import BoardPose, board_poses, reprojection_rms, solve_pnp
from .closed_form import METHODS, all_methods, chain_residuals, consistency, solve_closed_form
from .intrinsics import calibrate_intrinsics
from .motion import MotionQuality, axis_text, motion_quality, rotations_to_add

__all__ = [
    "METHODS",
    "calibrate_intrinsics",
    "solve_pnp",
    "reprojection_rms",
    "board_poses",
    "motion_quality",
    "rotations_to_add",
    "axis_text",
    "solve_closed_form",
    "all_methods",
    "chain_residuals",
    "consistency",
    "BoardPose",
    "MotionQuality",
]
