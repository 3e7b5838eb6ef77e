"""One capture's checks and outcome, and the board's pose under each corner numbering a detector may give.

:class:`CaptureChecks` holds the acceptance thresholds (configs/collect.yaml ``capture:``),
:class:`Capture` the outcome of one attempt; :func:`pose_orderings` solves ``T_cam_board`` under each
of :func:`detector_orderings`, since a detector may number a symmetric target from either end.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from ..camera import Intrinsics
from ..config import load_preset
from ..frames import rotation_angle_rad
from ..initial import solve_pnp
from ..targets import ChessboardSpec, TargetSpec, grid_turns
from .robot import PoseReading

_CAPTURE = load_preset("collect")["capture"]  # the defaults below; configs/collect.yaml says where each comes from


@dataclass(frozen=True)
class CaptureChecks:
    """Acceptance thresholds for one capture (defaults: configs/collect.yaml ``capture:``)."""

    still_tol_mm: float = float(_CAPTURE["still_tol_mm"])  # the two pose reads around the frame agree within this
    still_tol_deg: float = float(_CAPTURE["still_tol_deg"])
    min_sharpness: float = float(_CAPTURE["min_sharpness"])  # variance of the Laplacian inside the target's box
    settle_timeout_s: float = float(_CAPTURE["settle_timeout_s"])  # after a motion, wait at most this long
    settle_interval_s: float = float(_CAPTURE["settle_interval_s"])  # between the two reads of the stillness check

    @staticmethod
    def from_config(cfg: dict) -> "CaptureChecks":
        """From a ``collect`` preset (``load_preset("collect")``, possibly merged with a site file)."""
        return CaptureChecks(**{k: float(v) for k, v in cfg["capture"].items()})


@dataclass(frozen=True)
class Capture:
    """Outcome of one capture attempt."""

    kept: bool
    reason: str = ""  # why it was rejected
    view_id: Optional[str] = None
    pose: Optional[PoseReading] = None
    corner_ids: Optional[np.ndarray] = None
    image_points: Optional[np.ndarray] = None
    sharpness: float = float("nan")
    T_cam_board: Optional[np.ndarray] = None  # from PnP with the camera's intrinsics, when known
    order_cue: float = float("nan")  # chessboard: which end the detector numbered from (detect.chessboard.order_cue)
    T_cam_board_orderings: Optional[np.ndarray] = None  # (k, 4, 4): T_cam_board under each detector_orderings()
    orientation: int = 0  # the index of T_cam_board in T_cam_board_orderings


def detector_orderings(target: TargetSpec) -> list[np.ndarray]:
    """Corner numberings a detector may give one view of ``target`` (maps a detected index to the corner id).

    The identity first. A chessboard may be numbered from either end (and a square one from any corner)
    whatever its colours: OpenCV's detector does not look at them, so an asymmetric chessboard (cols +
    rows odd) gets its half turn here too, and the colour of the first square
    (:func:`handeye.detect.chessboard.order_cue`) or the robot's motion tells which one a view has.
    Other targets: their symmetries.
    """
    if isinstance(target, ChessboardSpec):
        return grid_turns(target.cols, target.rows)
    return list(target.symmetries())


def pose_orderings(
    target: TargetSpec, intrinsics: Intrinsics, corner_ids: np.ndarray, image_points: np.ndarray
) -> np.ndarray:
    """``T_cam_board`` by PnP under each of :func:`detector_orderings`, shape (k, 4, 4)."""
    obj = target.object_points()
    return np.stack(
        [solve_pnp(obj[perm[corner_ids]], image_points, intrinsics)[0] for perm in detector_orderings(target)]
    )


def nearest_ordering(T_cam_board_orderings: np.ndarray, reference: np.ndarray) -> int:
    """The index of the pose (k, 4, 4) whose rotation is nearest to ``reference``'s."""
    d = [float(rotation_angle_rad(reference[:3, :3].T @ T[:3, :3])) for T in T_cam_board_orderings]
    return int(np.argmin(d))


def board_pose(
    target: TargetSpec,
    intrinsics: Intrinsics,
    corner_ids: np.ndarray,
    image_points: np.ndarray,
    *,
    reference: Optional[np.ndarray] = None,
) -> np.ndarray:
    """``T_cam_board`` by PnP; with ``reference``, under the corner ordering nearest to it (detector_orderings)."""
    Ts = pose_orderings(target, intrinsics, corner_ids, image_points)
    return Ts[0 if reference is None else nearest_ordering(Ts, reference)]


def _gray(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
