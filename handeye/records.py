"""Frozen records of the data that flows through the pipeline.

Views, sessions, detections, outcomes and closed-form estimates. Views are identified by ``view_id``
(a string such as "7" for ``7.jpg``), never by list position.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from .camera import Intrinsics
from .targets import TargetSpec


def view_id_key(view_id) -> tuple:
    """Sort key for view ids: numeric ids in numeric order ("2" before "10"), then the others by name."""
    vid = str(view_id)
    return (0, int(vid), "") if vid.isdigit() else (1, 0, vid)


#: OpenCV's closed-form solvers by handeye name (hand-eye AX=XB ones, then robot-world AX=ZB ones)
METHOD_NAMES = ("tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li")


@dataclass(frozen=True)
class View:
    """One capture: an image and the reported robot pose ``T_base_end`` (metres)."""

    view_id: str
    image_path: Path
    T_base_end: np.ndarray  # (4, 4)
    source_line: Optional[int] = None  # line in poses.txt, for messages
    t_image: Optional[float] = None
    t_pose: Optional[float] = None
    joint_angles: Optional[tuple] = None  # the arm's joint angles at this view (radians), when recorded
    # pose-only views: the camera -> target pose measured by an external tracker (image_path is None)
    T_cam_board: Optional[np.ndarray] = None  # (4, 4)


@dataclass(frozen=True)
class Session:
    """A calibration session as read from disk, converted to handeye conventions."""

    path: Path
    format: str  # "vendor" | "native"
    mode: str
    target: TargetSpec
    views: tuple  # tuple[View, ...]
    intrinsics: Optional[Intrinsics] = None
    intrinsics_prior: str = "estimate"  # estimate | fixed | prior
    pose_format: str = ""
    meta: dict = field(default_factory=dict)
    mode_source: str = "stated"  # stated (in the session) | flag (--mode) | default (none: decided from the data)

    def view(self, view_id: str) -> View:
        for v in self.views:
            if v.view_id == view_id:
                return v
        raise KeyError(view_id)


@dataclass(frozen=True)
class Detection:
    """Target corners found in one view. ``corner_ids`` index ``target.object_points()``."""

    view_id: str
    corner_ids: np.ndarray  # (N,) int
    image_points: np.ndarray  # (N, 2) float64 pixels
    image_size: tuple  # (width, height)
    sharpness: float = float("nan")  # variance of the Laplacian around the target
    order_cue: float = float("nan")  # chessboard: grey of the first inner square minus the last one
    seconds: float = 0.0
    # measured on the decoded image during detection (handeye.detect.quality), so later stages never
    # decode it again: edge blur {"edge_sigma_px", "blur_sigma_px", "contrast", "n_edges", "square_px"},
    # exposure inside the board's hull {"saturated_share", "p5", "p95"}, and a small grey JPEG
    blur: Optional[dict] = None
    exposure: Optional[dict] = None
    thumbnail_jpeg: Optional[bytes] = None
    # corners the detector found but does not use, as (corner id, reason): the refinement stages disagree,
    # no saddle point, off the homography of the neighbours (handeye.detect.chessboard / charuco)
    dropped_corners: tuple = ()
    sha256: Optional[str] = None  # of the image file's bytes as decoded (result.json's provenance.inputs)


@dataclass(frozen=True)
class DetectionFailure:
    """A view whose target was not found: why, and what was measured on its image anyway.

    A view whose target was not found: why, and what was measured on its image anyway
    (exposure over the whole image {"saturated_share", "p5", "p95"}, a small grey JPEG).
    """

    view_id: str
    reason: str
    thumbnail_jpeg: Optional[bytes] = None
    exposure: Optional[dict] = None
    image_size: Optional[tuple] = None  # (width, height)
    seconds: float = 0.0
    # chessboards: the inner-corner sizes (cols, rows) seen in this image when the stated size was not
    # found (handeye.detect.board_size; every searched chessboard image records them); None when not checked
    seen_sizes: Optional[tuple] = None
    sha256: Optional[str] = None  # of the image file's bytes as decoded (result.json's provenance.inputs)


#: the start of the reason of a view whose image file is missing (its pose line or entry has no image): the
#: diagnostics and the report tell such a view from one whose image showed no target by it
IMAGE_MISSING_REASON = "image file missing"
#: the start of the reason of an image left without a pose by ``--shift-poses N`` (its pose would be past the last
#: line): its target was never looked for, so it is neither "not found" nor an image looked at
SHIFT_UNPAIRED_REASON = "no pose line after --shift-poses"
#: words in the reason of a view whose board was found but whose corners (or dots) fail the detector's geometric
#: check (:func:`handeye.detect.geometry.grid_check`): not a view without its board
FAILS_GRID_CHECK = "fail the geometric check"


@dataclass(frozen=True)
class ViewOutcome:
    """What happened to one view: used or dropped, and why."""

    view_id: str
    image: str
    used: bool
    reason: str = ""
    n_corners: int = 0
    rms_px: Optional[float] = None
    max_px: Optional[float] = None
    orientation: int = 0  # index into target.symmetries() chosen for this view
    flags: tuple = ()  # reasons of outlier decisions (corner- or view-level)


@dataclass(frozen=True)
class HandEyeEstimate:
    """A hand-eye solution in the generic form ``T_cam_board_i = A · M_i · B``, named per mode."""

    mode: str
    method: str
    T_x: np.ndarray  # T_end_cam (eye-in-hand) or T_base_cam (eye-to-hand)
    T_board: np.ndarray  # T_base_board (eye-in-hand) or T_end_board (eye-to-hand)
    status: str = "ok"
    failure_reason: str = ""
