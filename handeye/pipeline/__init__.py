"""The calibration stages, from images to the refinement, returning one :class:`CalibrationRun`.

Images -> detections -> intrinsics -> board poses -> motion check -> closed forms -> refinement.
Views are linked by id from start to end. A view that fails at any stage is dropped together with
its robot pose, and its outcome records why. The pipeline never raises for a session that cannot be
calibrated: it returns a :class:`CalibrationRun` with ``status="failed"`` and the structured error
(so that a report can still be written); the CLI turns that into a non-zero exit.

:func:`observe` (detection, intrinsics, board poses) is also what the diagnostics run on a session that
the strict reader refuses. The gates are in :mod:`.gates`, the solve stages in :mod:`.stages`.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from ..camera import Intrinsics
from ..detect import detect_views, size_survey  # observe's detector: tests and benchmarks replace it here
from ..errors import CalibrationError, DetectionError, HandeyeError
from ..initial import METHODS, board_poses, calibrate_intrinsics, chain_residuals
from ..mounting import mounting
from ..records import IMAGE_MISSING_REASON, SHIFT_UNPAIRED_REASON, Detection, Session, ViewOutcome, view_id_key
from ..targets import TargetSpec
from .gates import _mode_gate, _pairing_gate, _stated_source, shift_poses
from .records import MIN_VIEWS, CalibrateOptions, CalibrationRun, Detected, Observation, ordered_outcomes
from .stages import (
    _closed_forms,
    _final_outcomes,
    arm_accuracy_stage,
    refine_stage,
    refinement_error,
    session_arm,
    stated_accuracy,
    validate_pose_stage,
    validate_stage,
)

__all__ = [
    "MIN_VIEWS",
    "CalibrateOptions",
    "CalibrationRun",
    "Detected",
    "Observation",
    "detect_ahead",
    "detect_views",
    "failure_reason",
    "observe",
    "refine_stage",
    "run_calibration",
    "session_arm",
    "shift_poses",
    "target_text",
    "validate_pose_stage",
    "validate_stage",
]


def failure_reason(d) -> str:
    """The reason text of what detection returned for a view without the target."""
    return d if isinstance(d, str) else str(getattr(d, "reason", d))


def observe(
    *,
    target: TargetSpec,
    items: Sequence[tuple[str, Any]],
    intrinsics: Optional[Intrinsics] = None,
    intrinsics_prior: str = "fixed",
    M_by_id: Optional[Mapping[str, np.ndarray]] = None,
    options: "CalibrateOptions" = CalibrateOptions(),  # noqa: B008 - a frozen dataclass, imported
    intrinsics_source: str = "",
    progress: Callable[[str], None] | None = None,
    detected: Optional[Detected] = None,
    on_detected: Callable[[], None] | None = None,
) -> Observation:
    """Detect the target, calibrate the camera unless given and solve each view's board pose.

    Detect the target in ``items`` ((view_id, image path) pairs), calibrate the camera unless
    ``intrinsics`` are given, and solve each view's board pose.

    ``M_by_id`` (view_id -> robot motion ``M_i``, see :meth:`MountingMode.M_from_T_base_end`) orders
    the corners of symmetric boards consistently with the robot; without it each view keeps the
    detector's order. ``detected``: these items' detections made ahead (:func:`detect_ahead`), used
    instead of detecting again when they are of the same items and options. ``on_detected``: called once
    the images are detected (the workflow starts the report's figure process then: detection no longer
    needs the second core). Never raises for data that cannot be observed: the returned observation's
    ``error`` says why it stopped.
    """
    progress = progress or (lambda s: None)
    seconds: dict = {}
    t0 = time.perf_counter()
    if detected is not None and detected.fits(items, options.min_corners):
        progress(f"the target was detected in {len(items)} images ahead")
        det = dict(detected.results)
        t0 -= detected.seconds  # the detect stage's time is the time it took ahead
    else:
        progress(f"detecting the target in {len(items)} images")
        det = detect_views(list(items), target, workers=options.workers, min_corners=options.min_corners)
    if on_detected is not None:
        on_detected()
    outcomes: dict[str, ViewOutcome] = {}
    failures: dict = {}
    dets: dict[str, Detection] = {}
    for vid, path in items:
        d = det[vid]
        name = getattr(path, "name", str(path))
        if isinstance(d, Detection):
            dets[vid] = d
            outcomes[vid] = ViewOutcome(vid, name, True, "", len(d.corner_ids))
        else:
            failures[vid] = d
            outcomes[vid] = ViewOutcome(vid, name, False, failure_reason(d))
    seconds["detect"] = time.perf_counter() - t0
    obs = Observation(target, outcomes, dets, failures, seconds=seconds)
    if len(dets) < MIN_VIEWS or 2 * len(dets) < len(items):
        # too few views, or the stated board in a minority of them: when the others show another board
        # size, the few sightings of the stated one are the detector reading a grid into part of that board
        # (one more column along an edge against a dark background); the session states the wrong size
        survey = size_survey(det, (target.cols, target.rows)) if target.kind == "chessboard" else None
        if survey is not None and survey.likely_size is not None:  # the images show another board size
            return replace(
                obs,
                error=DetectionError(
                    f"the target was found in only {len(dets)} of {len(items)} images: {survey.text()}",
                    hint=survey.fix(),
                    code="target_not_found",
                ),
            )
    if len(dets) < MIN_VIEWS and len(dets) == len(items):  # every image shows the board: too few images
        return replace(
            obs,
            error=DetectionError(
                f"the session has {len(items)} image{'s' if len(items) != 1 else ''} "
                "(the board found in each); at least "
                f"{MIN_VIEWS} views are needed",
                hint="capture more views, with the robot turned between them",
                code="too_few_views",
            ),
        )
    if len(dets) < MIN_VIEWS:
        return replace(
            obs,
            error=DetectionError(
                f"the target was found in only {len(dets)} of {len(items)} images; at least {MIN_VIEWS} are needed",
                hint=f"check the board size in the session ({target_text(target)}) and that the whole board is visible "
                "and sharp",
                code="target_not_found",
            ),
        )
    # --- intrinsics
    t1 = time.perf_counter()
    w, h = next(iter(dets.values())).image_size
    if intrinsics is not None:
        if (intrinsics.width, intrinsics.height) != (w, h):
            return replace(
                obs,
                error=CalibrationError(
                    f"the given intrinsics are for {intrinsics.width}x{intrinsics.height} images but the images are "
                    f"{w}x{h}",
                    hint="fix intrinsics.image_size or drop the intrinsics",
                    code="intrinsics_size_mismatch",
                ),
            )
        intr, src, rms = intrinsics, intrinsics_source or f"given ({intrinsics_prior})", None
    else:
        progress("calibrating the camera intrinsics")
        try:
            intr, rms = calibrate_intrinsics(list(dets.values()), target.object_points(), fix_k3=options.fix_k3)
        except HandeyeError as e:
            return replace(obs, error=e)
        src = "calibrateCamera (OpenCV 5-coefficient model)"
    seconds["intrinsics"] = time.perf_counter() - t1
    obs = replace(obs, intrinsics=intr, intrinsics_source=src, intrinsics_rms_px=rms)
    # --- board poses
    t2 = time.perf_counter()
    ids = sorted(dets, key=view_id_key)
    try:
        if M_by_id is not None:
            poses = board_poses([dets[v] for v in ids], target, intr, M_by_id)
        else:  # no robot motions to compare with: symmetric boards keep the detector's corner order
            poses = _board_poses_as_detected([dets[v] for v in ids], target, intr)
    except HandeyeError as e:
        return replace(obs, error=e)
    outcomes = dict(outcomes)
    for vid, bp in poses.items():
        outcomes[vid] = replace(outcomes[vid], rms_px=bp.rms_px, orientation=bp.orientation)
    seconds["board_poses"] = time.perf_counter() - t2
    return replace(obs, outcomes=outcomes, board_poses=poses)


def _board_poses_as_detected(detections, target, intr) -> dict:
    """Board poses with every view in the detector's corner order (no robot motions to compare)."""
    from ..initial import BoardPose, solve_pnp

    obj = target.object_points()
    out = {}
    for d in detections:
        T, rms = solve_pnp(obj[d.corner_ids], d.image_points, intr)
        out[d.view_id] = BoardPose(d.view_id, T, rms, 0, d.corner_ids)
    return out


def target_text(t: TargetSpec) -> str:
    """The target in a few words, for messages."""
    if t.kind == "chessboard":
        return f"chessboard {t.cols}x{t.rows} inner corners, {t.square_m * 1000:g} mm"
    if t.kind == "circlegrid":
        return f"circle grid {t.cols}x{t.rows} dots, {t.spacing_m * 1000:g} mm spacing"
    if t.kind == "charuco":
        return f"ChArUco {t.squares_x}x{t.squares_y} squares"
    return t.describe()


def detect_ahead(
    session: Session,
    options: CalibrateOptions = CalibrateOptions(),  # noqa: B008 - a frozen dataclass, imported
) -> Optional[Detected]:
    """The target detected in a session's images as :func:`run_calibration` would, for it to take later.

    (A cell detects the next camera's images while it calibrates one: detection releases the GIL.) None
    for a session without images (target poses from a tracker). Raises what detection raises (unreadable
    images, images of different sizes).
    """
    if session.meta.get("pose_only"):
        return None
    s = shift_poses(session, int(options.shift_poses))[0] if options.shift_poses else session
    items = tuple((v.view_id, v.image_path) for v in s.views)
    t0 = time.perf_counter()
    det = detect_views(list(items), s.target, workers=options.workers, min_corners=options.min_corners)
    return Detected(items, options.min_corners, det, time.perf_counter() - t0)


def _closed_forms_on_used_views(mode, ids: list, C: np.ndarray, Ms: np.ndarray, refined) -> dict:
    """The closed forms solved again on the views the refinement kept, when it left some out (state's fields).

    The closed forms saw every view with a board pose, the views the refinement then found out of line (a wrong
    robot pose) among them: compared with the result, their offset would be those views', not a difference of
    method. Nothing when every view was kept or fewer than 3 remain.
    """
    from ..initial import all_methods

    kept = set(refined.used_view_ids)
    k = [i for i, v in enumerate(ids) if v in kept]
    if len(k) == len(ids) or len(k) < MIN_VIEWS:
        return {}
    return {"closed_forms": all_methods(mode, C[k], Ms[k]), "closed_form_views": tuple(ids[i] for i in k)}


def run_calibration(
    session: Session,
    options: CalibrateOptions = CalibrateOptions(),  # noqa: B008 - a frozen dataclass, imported
    *,
    progress: Callable[[str], None] | None = None,
    detected: Optional[Detected] = None,
    on_detected: Callable[[], None] | None = None,
) -> CalibrationRun:
    """All stages on a loaded session.

    A session that cannot be calibrated gives ``status="failed"`` with the error and every stage
    result reached so far (for the report). ``detected``: its images' detections made ahead
    (:func:`detect_ahead`; used when they are of the same images and options); ``on_detected``: see
    :func:`observe`.
    """
    state: dict = {}
    try:
        return _run(session, options, state, progress or (lambda s: None), detected, on_detected)
    except HandeyeError as e:
        s = state.pop("session", session)
        return CalibrationRun(session=s, options=options, status="failed", error=e, **state)


def missing_image_outcomes(s: Session) -> dict:
    """View id -> :class:`ViewOutcome` of the poses whose image file is missing (the loader dropped them)."""
    out = {}
    for vid, line in s.meta.get("missing_images", {}).items():
        name = Path(s.meta.get("missing_image_files", {}).get(vid, f"{vid}.jpg")).name
        where = f"pose line {line}" if line is not None else "its pose"
        out[vid] = ViewOutcome(vid, name, False, f"{IMAGE_MISSING_REASON} ({where} not used)")
    return out


def _run(s: Session, opts: CalibrateOptions, state: dict, progress, detected=None, on_detected=None) -> CalibrationRun:
    mode = mounting(s.mode)
    if opts.method not in METHODS:
        raise CalibrationError(f"unknown method {opts.method!r}", expected=" | ".join(METHODS), code="unknown_method")
    t0 = time.perf_counter()
    if s.meta.get("pose_only"):  # target poses from a tracker: no detection, no intrinsics
        from .poseonly import _run_pose_only  # imported on this path only (it imports the diagnostics)

        return _run_pose_only(s, opts, state, progress)
    # the arm session.yaml names is read before any work: a wrong table is one error line
    arm = session_arm(s, opts) if opts.refine else None
    accuracy = stated_accuracy(s, opts, arm is not None or opts.refine_options.get("arm") is not None)
    unpaired: list = []
    if opts.shift_poses:
        s, unpaired = shift_poses(s, int(opts.shift_poses))
        state["session"] = s
    given = s.intrinsics if (s.intrinsics is not None and s.intrinsics_prior in ("fixed", "prior")) else None
    # the corner ordering of symmetric boards compares pair invariants, which are the same in both modes
    M_all = {v.view_id: mode.M_from_T_base_end(v.T_base_end) for v in s.views}
    obs = observe(
        target=s.target,
        items=[(v.view_id, v.image_path) for v in s.views],
        intrinsics=given,
        intrinsics_prior=s.intrinsics_prior,
        M_by_id=M_all,
        options=opts,
        progress=progress,
        detected=detected,
        on_detected=on_detected,
    )
    outcomes = {**obs.outcomes, **missing_image_outcomes(s)}
    for v in unpaired:
        outcomes[v.view_id] = ViewOutcome(
            v.view_id,
            getattr(v.image_path, "name", str(v.image_path)),
            False,
            f"{SHIFT_UNPAIRED_REASON} {opts.shift_poses}",
        )

    def ordered():
        return ordered_outcomes(outcomes)

    seconds = dict(obs.seconds)
    state.update(
        outcomes=ordered(),
        detections=obs.detections,
        failures=obs.failures,
        seconds=seconds,
        intrinsics=obs.intrinsics,
        intrinsics_source=obs.intrinsics_source,
        intrinsics_rms_px=obs.intrinsics_rms_px,
        board_poses=obs.board_poses,
    )
    state["mode_decision"] = {"mode": s.mode, "mode_source": _stated_source(s)}
    if obs.error is not None:
        raise obs.error if obs.error.path is not None else obs.error.at(s.path)
    poses, dets, intr = obs.board_poses, obs.detections, obs.intrinsics
    assert intr is not None, "an observation without an error has the camera's intrinsics"
    session_mode = s.mode
    s = _mode_gate(s, obs, state, progress)
    mode = mounting(s.mode)
    M_all = {v.view_id: mode.M_from_T_base_end(v.T_base_end) for v in s.views}
    if mode.name != session_mode and getattr(s.target, "pose_ambiguous", False):
        # a single marker's planar pose is picked by the robot motion under a model: pick again under the mode found
        obs = replace(
            obs, board_poses=board_poses([dets[v] for v in sorted(dets, key=view_id_key)], s.target, intr, M_all)
        )
        poses = obs.board_poses
        for vid, bp in poses.items():
            outcomes[vid] = replace(outcomes[vid], rms_px=bp.rms_px, orientation=bp.orientation)
        state.update(board_poses=poses, outcomes=ordered())
    _pairing_gate(s, obs, M_all, state)
    ids = list(poses)
    C = np.stack([poses[v].T_cam_board for v in ids])
    Ms = np.stack([M_all[v] for v in ids])
    t1 = time.perf_counter()
    closed, start = _closed_forms(s, opts, mode, C, Ms, state, progress)
    T_base_end = {vid: s.view(vid).T_base_end for vid in ids}
    chain = chain_residuals(start, mode, s.target.object_points(), poses, dets, T_base_end, intr)
    seconds["closed_form"] = time.perf_counter() - t1
    refined = None
    if opts.refine:
        progress("joint refinement (GTSAM)")
        t2 = time.perf_counter()
        refined = refine_stage(s, opts, start, intr, poses, dets, T_base_end, closed_forms=closed, arm=arm)
        seconds["refine"] = time.perf_counter() - t2
        if refined.status != "ok":
            raise refinement_error(refined)
        state.update(refined=refined, T_x=refined.T_x, T_board=refined.T_board, intrinsics=refined.intrinsics)
        state.update(_closed_forms_on_used_views(mode, ids, C, Ms, refined))
        if opts.validate:
            progress("validation: refits without some views")
            t3 = time.perf_counter()
            state["validation"] = validate_stage(s, refined, poses, dets, T_base_end)
            seconds["validate"] = time.perf_counter() - t3
        state["arm_accuracy"] = arm_accuracy_stage(s, refined, accuracy)
    outcomes = _final_outcomes(outcomes, chain, refined)
    state["outcomes"] = ordered()
    seconds["calibrate"] = time.perf_counter() - t0
    state.pop("session", None)
    return CalibrationRun(session=s, options=opts, **state)
