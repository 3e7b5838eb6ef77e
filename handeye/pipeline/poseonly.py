"""The stages of a pose-only session, whose target poses come from a tracker."""

from __future__ import annotations

import time

import numpy as np

from ..diagnose.scale import rescaled
from ..errors import CalibrationError
from ..mounting import mounting
from ..records import Session, ViewOutcome, view_id_key
from .gates import _mode_gate, _stated_source
from .records import MIN_VIEWS, CalibrateOptions, CalibrationRun, Observation
from .stages import (
    _closed_forms,
    _final_outcomes,
    _joint_angles,
    arm_accuracy_stage,
    refinement_error,
    session_arm,
    stated_accuracy,
    validate_pose_stage,
)


def tracker_scale_start(C: np.ndarray, Ms: np.ndarray) -> float:
    """Log of the tracker's translation scale in closed form (:func:`handeye.diagnose.scale.estimate_scale`).

    ``C`` (n,4,4) the tracker's poses, ``Ms`` (n,4,4) the robot motions; 0 (metric) when the closed form
    gives no positive scale.
    """
    from ..diagnose.scale import estimate_scale

    est = estimate_scale(C, Ms)
    if est is None or not np.isfinite(est.k) or est.k <= 0:
        return 0.0
    return float(-np.log(est.k))  # the robot's motions are k x the tracker's: the tracker's scale is 1 / k


def _run_pose_only(s: Session, opts: CalibrateOptions, state: dict, progress) -> CalibrationRun:
    """The stages of a pose-only session: each view's ``T_cam_board`` is the tracker's.

    The stages of a pose-only session: each view's ``T_cam_board`` is the tracker's (no detection,
    intrinsics or board poses to solve); the mode gate, the motion check and the closed forms as for
    images; the refinement on pose factors (:func:`handeye.refine.poseonly.refine_poses`), with the arm's
    kinematic model when ``--robot`` or session.yaml's ``robot:`` names one. With ``--estimate-scale`` (or
    ``estimate_scale: true``) the tracker's translation scale is one more unknown, started from the
    closed-form scale (:func:`tracker_scale_start`), the closed forms on the poses rescaled.
    """
    from ..initial import BoardPose

    t0 = time.perf_counter()
    # before any work, as for images: a stated accuracy with the arm's model (--robot or robot:) is refused
    accuracy = stated_accuracy(s, opts, opts.refine_options.get("arm") is not None or s.meta.get("robot") is not None)
    outcomes = {v.view_id: ViewOutcome(v.view_id, "", True, "", 0) for v in s.views}
    poses = {v.view_id: BoardPose(v.view_id, v.T_cam_board, float("nan"), 0, np.zeros(0, int)) for v in s.views}
    seconds: dict = {}
    state.update(
        outcomes=tuple(outcomes[k] for k in sorted(outcomes, key=view_id_key)),
        board_poses=poses,
        seconds=seconds,
        intrinsics_source="none (pose-only session: target poses from a tracker)",
    )
    state["mode_decision"] = {"mode": s.mode, "mode_source": _stated_source(s)}
    if len(poses) < MIN_VIEWS:
        raise CalibrationError(
            f"the session has {len(poses)} views; at least {MIN_VIEWS} are needed",
            hint="add views",
            code="too_few_views",
            path=s.path,
        )
    obs = Observation(s.target, outcomes, {}, {}, board_poses=poses)
    s = _mode_gate(s, obs, state, progress)
    mode = mounting(s.mode)
    ids = sorted(poses, key=view_id_key)
    C = np.stack([poses[v].T_cam_board for v in ids])
    Ms = np.stack([mode.M_from_T_base_end(s.view(v).T_base_end) for v in ids])
    t1 = time.perf_counter()
    log_scale0 = tracker_scale_start(C, Ms) if opts.estimate_scale or s.meta.get("estimate_scale") else None
    C_start = C if log_scale0 is None else rescaled(C, float(np.exp(-log_scale0)))
    closed, start = _closed_forms(s, opts, mode, C_start, Ms, state, progress)
    seconds["closed_form"] = time.perf_counter() - t1
    refined = None
    if opts.refine:
        from ..refine import RefineOptions
        from ..refine.poseonly import PoseView, refine_poses

        progress("joint refinement on the tracker's poses (GTSAM)")
        t2 = time.perf_counter()
        ro = {k: v for k, v in opts.refine_options.items() if k not in ("intrinsics", "fix")}
        if ro.get("arm") is None:  # --robot, else session.yaml's robot: the arm's kinematic model
            ro["arm"] = session_arm(s, opts)
        pose_views = [PoseView(v, poses[v].T_cam_board, s.view(v).T_base_end, _joint_angles(s, v)) for v in ids]
        refined = refine_poses(
            mode=s.mode,
            views=pose_views,
            T_x0=start.T_x,
            T_board0=start.T_board,
            tracker_sigma=s.meta.get("tracker_sigma"),
            options=RefineOptions(**ro),
            starts=closed,
            log_scale0=log_scale0,
        )
        seconds["refine"] = time.perf_counter() - t2
        if refined.status != "ok":
            raise refinement_error(refined)
        state.update(refined=refined, T_x=refined.T_x, T_board=refined.T_board)
        if opts.validate:
            progress("validation: refits without some views")
            t3 = time.perf_counter()
            state["validation"] = validate_pose_stage(refined, pose_views)
            seconds["validate"] = time.perf_counter() - t3
        state["arm_accuracy"] = arm_accuracy_stage(s, refined, accuracy)
    state["outcomes"] = tuple(
        v for _, v in sorted(_final_outcomes(outcomes, {}, refined).items(), key=lambda kv: view_id_key(kv[0]))
    )
    seconds["calibrate"] = time.perf_counter() - t0
    state.pop("session", None)
    return CalibrationRun(session=s, options=opts, **state)
