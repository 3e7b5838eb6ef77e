"""The records the calibration stages pass: the options, what the camera saw and the run."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from ..camera import Intrinsics
from ..errors import HandeyeError
from ..mounting import MountingMode, mounting
from ..records import HandEyeEstimate, Session, view_id_key
from ..targets import TargetSpec

#: fewer views with a detected target than this cannot be calibrated (3 relative motions, 2 independent)
MIN_VIEWS = 3


def ordered_outcomes(outcomes: dict) -> tuple:
    """The outcomes (view id -> :class:`handeye.records.ViewOutcome`) in view-id order."""
    return tuple(outcomes[k] for k in sorted(outcomes, key=view_id_key))


@dataclass(frozen=True)
class CalibrateOptions:
    method: str = "tsai"
    refine: bool = True
    fix_k3: bool = False
    workers: Optional[int] = None
    min_corners: Optional[int] = None  # None: configs/detection.yaml detection.min_corners
    min_rotation_deg: Optional[float] = None  # None: configs/calibration.yaml motion.min_rotation_deg
    min_axis_spread_deg: Optional[float] = None  # None: configs/calibration.yaml motion.min_axis_spread_deg
    refine_options: dict = field(default_factory=dict)
    shift_poses: int = 0  # pair image k with the pose written for image k + shift_poses (a known constant shift)
    validate: bool = True  # refit without some views for the validated and verdict covariances (refined runs)
    estimate_scale: bool = False  # pose-only sessions: the tracker's translation scale as one more unknown
    robot_accuracy: Optional[tuple] = None  # (mm, deg): the arm's stated accuracy (handeye.refine.arm_accuracy)

    @staticmethod
    def from_config(cfg: dict, **overrides) -> "CalibrateOptions":
        """Options from a calibration preset (configs/calibration.yaml) plus explicit overrides.

        Options from a calibration preset (configs/calibration.yaml) plus explicit overrides
        (an override of None keeps the preset's value).
        """
        motion = cfg.get("motion") or {}
        kw = {
            "method": cfg.get("method", "tsai"),
            "refine": bool(cfg.get("refine", True)),
            "fix_k3": bool(cfg.get("fix_k3", False)),
            "min_corners": None if cfg.get("min_corners") is None else int(cfg["min_corners"]),
            "min_rotation_deg": _float_or_none(motion.get("min_rotation_deg")),
            "min_axis_spread_deg": _float_or_none(motion.get("min_axis_spread_deg")),
            "refine_options": {k: v for k, v in (cfg.get("refine_options") or {}).items() if v is not None},
        }
        ro = overrides.pop("refine_options", None) or {}
        kw["refine_options"].update(ro)
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return CalibrateOptions(**kw)


def _float_or_none(v):
    return None if v is None else float(v)


@dataclass(frozen=True)
class Observation:
    """What the camera saw: detections, intrinsics and board poses, per view id.

    ``error`` is set (and later fields left empty) when the stages could not go on: fewer than
    :data:`MIN_VIEWS` detected views, given intrinsics for another image size, a failed camera
    calibration.
    """

    target: TargetSpec
    outcomes: dict  # view_id -> ViewOutcome, for every item
    detections: dict  # view_id -> Detection (detected views only)
    failures: dict  # view_id -> what detection returned for a view without the target (reason or record)
    intrinsics: Optional[Intrinsics] = None
    intrinsics_source: str = ""
    intrinsics_rms_px: Optional[float] = None
    board_poses: dict = field(default_factory=dict)  # view_id -> BoardPose
    seconds: dict = field(default_factory=dict)
    error: Optional[HandeyeError] = None

    def ordered_outcomes(self) -> tuple:
        return ordered_outcomes(self.outcomes)


@dataclass(frozen=True)
class Detected:
    """The target detected in a session's images ahead of its calibration (:func:`handeye.pipeline.detect_ahead`).

    ``results``: what :func:`handeye.detect.detect_views` returned for ``items`` ((view id, image path) pairs, in
    the session's order) with ``min_corners``; ``seconds``: the wall time it took. :func:`handeye.pipeline.observe`
    takes it in place of detecting again when it was made for the same items and options.
    """

    items: tuple
    min_corners: Optional[int]
    results: dict
    seconds: float = 0.0

    def fits(self, items, min_corners: Optional[int]) -> bool:
        """Whether these are the detections of ``items`` with ``min_corners``."""
        return self.min_corners == min_corners and self.items == tuple((vid, path) for vid, path in items)


@dataclass(frozen=True)
class CalibrationRun:
    session: Session
    options: CalibrateOptions
    status: str = "ok"
    error: Optional[HandeyeError] = None  # why a failed run stopped
    outcomes: tuple = ()  # ViewOutcome per session view, in view-id order
    detections: dict = field(default_factory=dict)  # view_id -> Detection (used views only)
    failures: dict = field(default_factory=dict)  # view_id -> detection failure (reason or record)
    intrinsics: Optional[Intrinsics] = None
    intrinsics_source: str = ""
    intrinsics_rms_px: Optional[float] = None
    board_poses: dict = field(default_factory=dict)
    motion: Any = None
    closed_forms: dict = field(default_factory=dict)  # method -> HandEyeEstimate
    # the views the closed forms solved (None: every view with a board pose); after the refinement left views out,
    # the result's own, so that the comparison with the result is on the same views
    closed_form_views: Optional[tuple] = None
    start: Optional[HandEyeEstimate] = None  # the chosen closed form the refinement starts from
    refined: Any = None  # handeye.refine.RefineResult when refined
    validation: Any = None  # handeye.refine.validation.Validation when refined and validated
    T_x: Optional[np.ndarray] = None
    T_board: Optional[np.ndarray] = None
    seconds: dict = field(default_factory=dict)
    # how the mounting mode was chosen: {"mode", "mode_source": stated | flag | detected | default, "evidence"}
    mode_decision: dict = field(default_factory=dict)
    # the pairing gate's search (handeye.diagnose.pairing.PairingSearch), when it searched: the diagnostics reuse it
    pairing: Any = None
    # the arm's stated accuracy (handeye.refine.arm_accuracy.ArmAccuracy), added to the verdict covariance
    arm_accuracy: Any = None

    @property
    def failure_reason(self) -> str:
        return "" if self.error is None else str(self.error)

    @property
    def exit_code(self) -> int:
        return 0 if self.error is None else self.error.exit_code

    @property
    def mode(self) -> MountingMode:
        return mounting(self.session.mode)

    @property
    def used_ids(self) -> list[str]:
        return [o.view_id for o in self.outcomes if o.used]
