"""The solve stages: the motion check and closed forms, the refinement, the validation, the outcomes."""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Optional

import numpy as np

from ..camera import Intrinsics
from ..errors import CalibrationError, DegenerateMotionError, HandeyeError
from ..initial import METHODS, all_methods, motion_quality
from ..mounting import MountingMode
from ..records import HandEyeEstimate, Session
from .records import CalibrateOptions

log = logging.getLogger(__name__)


def _closed_forms(
    s: Session, opts: CalibrateOptions, mode: MountingMode, C: np.ndarray, Ms: np.ndarray, state: dict, progress
) -> tuple[dict, HandEyeEstimate]:
    """The motion check and the closed forms from board poses ``C`` and robot motions ``Ms`` (n,4,4).

    The motion check and the closed forms from board poses ``C`` and robot motions ``Ms`` (n,4,4):
    (every method's estimate, the chosen one); raises when the motion is degenerate or the method fails.
    """
    mq = motion_quality(
        Ms, frame=mode.fixed_frame, min_rotation_deg=opts.min_rotation_deg, min_axis_spread_deg=opts.min_axis_spread_deg
    )
    state.update(motion=mq)
    if mq.status != "ok":
        raise DegenerateMotionError(mq.reason, path=s.path, code=mq.code or None)
    progress(f"closed-form hand-eye ({', '.join(METHODS)})")
    closed = all_methods(mode, C, Ms)
    start = closed[opts.method]
    state.update(closed_forms=closed)
    if start.status != "ok":
        raise CalibrationError(
            f"the {opts.method} solver failed: {start.failure_reason}",
            hint="try another --method (e.g. park) or check the robot poses",
            code="closed_form_failed",
        )
    state.update(start=start, T_x=start.T_x, T_board=start.T_board)
    return closed, start


def refinement_error(refined) -> CalibrationError:
    """The error of a failed refinement, with what to try.

    When too few views keep a robot pose that agrees with the camera, the robot poses do not fit the images:
    a closed-form result (``--no-refine``) would only hide that, so the hint points at the poses.
    """
    if getattr(refined, "failure_code", "") == "too_few_robot_poses":
        hint = (
            "check how the robot poses were written (frame, units, rotation convention) and that each pairs with "
            "its image"
        )
    else:
        hint = "rerun with --no-refine to get the closed-form result"
    return CalibrationError(f"refinement failed: {refined.failure_reason}", hint=hint, code="refinement_failed")


def refine_stage(
    s: Session,
    opts: CalibrateOptions,
    start: HandEyeEstimate,
    intr: Intrinsics,
    poses: dict,
    dets: dict,
    T_base_end: dict,
    closed_forms: Optional[dict] = None,
    arm=None,
):
    """The joint refinement from the chosen closed form.

    The joint refinement from the chosen closed form (``arm``: the session's, when already read by
    :func:`session_arm`).
    """
    from ..refine import RefineOptions, RefineView, refine

    views = [
        RefineView(vid, poses[vid].corner_ids, dets[vid].image_points, T_base_end[vid], _joint_angles(s, vid))
        for vid in poses
    ]
    ro = dict(opts.refine_options)
    if ro.get("arm") is None:
        ro["arm"] = arm if arm is not None else session_arm(s, opts)
    if opts.fix_k3:
        ro["fix"] = tuple(sorted(set(ro.get("fix", ())) | {"k3"}))
    if s.intrinsics is not None and s.intrinsics_prior in ("fixed", "prior"):
        ro.setdefault("intrinsics", s.intrinsics_prior)
    return refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=views,
        intrinsics=intr,
        T_x0=start.T_x,
        T_board0=start.T_board,
        options=RefineOptions(**ro),
        starts=closed_forms,
    )


def session_arm(s: Session, opts: CalibrateOptions):
    """The arm session.yaml's ``robot:`` names.

    The arm session.yaml's ``robot:`` names (a preset, a DH table file relative to the session, or an
    inline table; :func:`handeye.kinematics.load_arm`) when the options name none, else None.
    """
    if opts.refine_options.get("arm") is not None or s.meta.get("robot") is None:
        return None
    from ..kinematics import load_arm

    return load_arm(s.meta["robot"], folder=s.path)


def _joint_angles(s: Session, vid: str):
    try:
        return s.view(vid).joint_angles
    except KeyError:
        return None


def _guarded_validation(run_validation):
    """``run_validation()``, or a not-run Validation when it fails: the refined result never depends on it."""
    from ..refine.validation import Validation

    try:
        return run_validation()
    except (HandeyeError, RuntimeError, np.linalg.LinAlgError) as e:  # the result stands on its model covariance
        log.warning("validation not run: %s", e)
        return Validation("not_run", f"{type(e).__name__}: {e}")
    except Exception as e:  # noqa: BLE001 - a bug in the validation must not lose the refined result
        log.error("validation crashed (%s: %s); the sigmas are the model's", type(e).__name__, e, exc_info=True)
        return Validation("not_run", f"crashed: {type(e).__name__}: {e}")


def validate_stage(s: Session, refined, poses: dict, dets: dict, T_base_end: dict):
    """The validated and verdict covariances of the refined result.

    The validated and verdict covariances of the refined result (:func:`handeye.refine.validation.validate`):
    refits without some views, from the refinement's own views.
    """
    from ..refine import RefineView
    from ..refine.validation import validate

    views = [RefineView(vid, poses[vid].corner_ids, dets[vid].image_points, T_base_end[vid]) for vid in poses]
    return _guarded_validation(lambda: validate(refined, object_points=s.target.object_points(), views=views))


def validate_pose_stage(refined, views: list):
    """The validated and verdict covariances of a pose-only result: refits without some views.

    The same folds and rule as for image sessions (:func:`handeye.refine.validation.validate`), each fold
    one solve of the pose graph with the tracker's sigmas held (:func:`handeye.refine.poseonly.refit_poses`).
    """
    from ..refine.poseonly import refit_poses
    from ..refine.validation import validate

    return _guarded_validation(
        lambda: validate(refined, views=views, refit_views=lambda sub, cov: refit_poses(refined, sub, cov))
    )


def _final_outcomes(outcomes, chain, refined):
    """Outcomes after the solve: residuals through the robot chain, and the refinement's decisions."""
    out = outcomes
    for vid, (_rms, mx) in chain.items():
        out[vid] = replace(out[vid], max_px=mx)
    if refined is None:
        return out
    flags: dict[str, list] = {}
    for o in refined.outliers:
        flags.setdefault(o.view_id, []).append(o)
    for vid, pv in refined.per_view.items():
        o = replace(out[vid], max_px=pv.get("max_px"), flags=tuple(f.reason for f in flags.get(vid, ())))
        if pv.get("status", "used") != "used":  # removed, or robot_excluded (corners kept for intrinsics)
            view_level = [f for f in flags.get(vid, ()) if not f.corner_ids]
            why = view_level[0].reason if view_level else "excluded by the refinement"
            o = replace(o, used=False, reason=f"outlier: {why}")
        out[vid] = o
    return out


def stated_accuracy(s: Session, opts: CalibrateOptions, arm_in_use: bool) -> Optional[tuple[float, float]]:
    """(mm, deg) of the arm's stated accuracy (``--robot-accuracy``, else session.yaml's ``robot_accuracy``).

    None when neither states it; ConfigError when it is malformed or comes with the arm's kinematic model,
    whose DH prior already states the arm's accuracy (:mod:`handeye.refine.arm_accuracy`).
    """
    from ..errors import ConfigError
    from ..session.fields import ROBOT_ACCURACY_FORM, mm_deg

    value = opts.robot_accuracy
    where = "--robot-accuracy"
    if value is None and s.meta.get("robot_accuracy") is not None:
        d = mm_deg(
            s.meta["robot_accuracy"], path=s.path / "session.yaml", field="robot_accuracy", expected=ROBOT_ACCURACY_FORM
        )
        value, where = (d["mm"], d["deg"]), "robot_accuracy"
    if value is None:
        return None
    if arm_in_use:
        raise ConfigError(
            f"{where} and the arm's kinematic model (--robot or robot:) both state the arm's accuracy",
            path=s.path,
            hint="keep the arm's model (its DH prior bounds the arm's error) or the stated accuracy, not both",
        )
    return float(value[0]), float(value[1])


def arm_accuracy_stage(s: Session, refined, stated: Optional[tuple[float, float]]):
    """The stated accuracy's covariance in X's tangent (:func:`handeye.refine.arm_accuracy.arm_accuracy`)."""
    if stated is None or refined is None or getattr(refined, "status", "") != "ok":
        return None
    from ..refine.arm_accuracy import arm_accuracy

    ids = [v for v, pv in refined.per_view.items() if pv.get("status", "used") == "used"]
    T_base_end = np.stack([s.view(v).T_base_end for v in ids])
    return arm_accuracy(s.mode, refined.T_x, T_base_end, stated)
