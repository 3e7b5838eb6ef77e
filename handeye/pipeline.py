"""The calibration stages, from images to the refinement, returning one :class:`CalibrationRun`.

Images -> detections -> intrinsics -> board poses -> motion check -> closed forms -> refinement.
Views are linked by id from start to end. A view that fails at any stage is dropped together with
its robot pose, and its outcome records why. The pipeline never raises for a session that cannot be
calibrated: it returns a :class:`CalibrationRun` with ``status="failed"`` and the structured error
(so that a report can still be written); the CLI turns that into a non-zero exit.

The observation stages (:func:`observe`: detection, intrinsics, board poses) are also what the
diagnostics run on a session that the strict reader refuses, so there is one pipeline.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np

from .camera import Intrinsics
from .detect import detect_views, size_survey
from .errors import CalibrationError, DegenerateMotionError, DetectionError, HandeyeError, SessionRefused
from .initial import METHODS, all_methods, board_poses, calibrate_intrinsics, chain_residuals, motion_quality
from .mounting import MountingMode, mounting
from .records import IMAGE_MISSING_REASON, Detection, HandEyeEstimate, Session, ViewOutcome, view_id_key
from .targets import TargetSpec

log = logging.getLogger(__name__)

#: fewer views with a detected target than this cannot be calibrated (3 relative motions, 2 independent)
MIN_VIEWS = 3


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


# ------------------------------------------------------------------------------ observation stages
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
        return tuple(self.outcomes[k] for k in sorted(self.outcomes, key=view_id_key))


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
    options: "CalibrateOptions" = CalibrateOptions(),
    intrinsics_source: str = "",
    progress: Callable[[str], None] | None = None,
) -> Observation:
    """Detect the target, calibrate the camera unless given and solve each view's board pose.

    Detect the target in ``items`` ((view_id, image path) pairs), calibrate the camera unless
    ``intrinsics`` are given, and solve each view's board pose.

    ``M_by_id`` (view_id -> robot motion ``M_i``, see :meth:`MountingMode.M_from_T_base_end`) orders
    the corners of symmetric boards consistently with the robot; without it each view keeps the
    detector's order. Never raises for data that cannot be observed: the returned observation's
    ``error`` says why it stopped.
    """
    progress = progress or (lambda s: None)
    seconds: dict = {}
    t0 = time.perf_counter()
    progress(f"detecting the target in {len(items)} images")
    det = detect_views(list(items), target, workers=options.workers, min_corners=options.min_corners)
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
    from .initial import BoardPose, solve_pnp

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


# ------------------------------------------------------------------------------ the run
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


def run_calibration(
    session: Session, options: CalibrateOptions = CalibrateOptions(), *, progress: Callable[[str], None] | None = None
) -> CalibrationRun:
    """All stages on a loaded session.

    A session that cannot be calibrated gives ``status="failed"`` with the error and every stage
    result reached so far (for the report).
    """
    state: dict = {}
    try:
        return _run(session, options, state, progress or (lambda s: None))
    except HandeyeError as e:
        s = state.pop("session", session)
        return CalibrationRun(session=s, options=options, status="failed", error=e, **state)


def _run(s: Session, opts: CalibrateOptions, state: dict, progress) -> CalibrationRun:
    mode = mounting(s.mode)
    if opts.method not in METHODS:
        raise CalibrationError(f"unknown method {opts.method!r}", expected=" | ".join(METHODS), code="unknown_method")
    t0 = time.perf_counter()
    if s.meta.get("pose_only"):  # target poses from a tracker: no detection, no intrinsics
        return _run_pose_only(s, opts, state, progress)
    # the arm session.yaml names is read before any work: a wrong table is one error line
    arm = session_arm(s, opts) if opts.refine else None
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
    )
    outcomes = dict(obs.outcomes)
    for vid, line in s.meta.get("missing_images", {}).items():  # poses whose image is missing (the loader)
        name = Path(s.meta.get("missing_image_files", {}).get(vid, f"{vid}.jpg")).name
        where = f"pose line {line}" if line is not None else "its pose"
        outcomes[vid] = ViewOutcome(vid, name, False, f"{IMAGE_MISSING_REASON} ({where} not used)")
    for v in unpaired:
        outcomes[v.view_id] = ViewOutcome(
            v.view_id,
            getattr(v.image_path, "name", str(v.image_path)),
            False,
            f"no pose line after --shift-poses {opts.shift_poses}",
        )

    def ordered():
        return tuple(outcomes[k] for k in sorted(outcomes, key=view_id_key))

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
            raise CalibrationError(
                f"refinement failed: {refined.failure_reason}",
                hint="rerun with --no-refine to get the closed-form result",
                code="refinement_failed",
            )
        state.update(refined=refined, T_x=refined.T_x, T_board=refined.T_board, intrinsics=refined.intrinsics)
        if opts.validate:
            progress("validation: refits without some views")
            t3 = time.perf_counter()
            state["validation"] = validate_stage(s, refined, poses, dets, T_base_end)
            seconds["validate"] = time.perf_counter() - t3
    outcomes = _final_outcomes(outcomes, chain, refined)
    state["outcomes"] = ordered()
    seconds["calibrate"] = time.perf_counter() - t0
    state.pop("session", None)
    return CalibrationRun(session=s, options=opts, **state)


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


def _run_pose_only(s: Session, opts: CalibrateOptions, state: dict, progress) -> CalibrationRun:
    """The stages of a pose-only session: each view's ``T_cam_board`` is the tracker's.

    The stages of a pose-only session: each view's ``T_cam_board`` is the tracker's (no detection,
    intrinsics or board poses to solve); the mode gate, the motion check and the closed forms as for
    images; the refinement on pose factors (:func:`handeye.refine.poseonly.refine_poses`).
    """
    from .initial import BoardPose

    t0 = time.perf_counter()
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
    closed, start = _closed_forms(s, opts, mode, C, Ms, state, progress)
    seconds["closed_form"] = time.perf_counter() - t1
    refined = None
    if opts.refine:
        from .refine import RefineOptions
        from .refine.poseonly import PoseView, refine_poses

        progress("joint refinement on the tracker's poses (GTSAM)")
        t2 = time.perf_counter()
        ro = {k: v for k, v in opts.refine_options.items() if k not in ("arm", "intrinsics", "fix")}
        refined = refine_poses(
            mode=s.mode,
            views=[PoseView(v, poses[v].T_cam_board, s.view(v).T_base_end) for v in ids],
            T_x0=start.T_x,
            T_board0=start.T_board,
            tracker_sigma=s.meta.get("tracker_sigma"),
            options=RefineOptions(**ro),
            starts=closed,
        )
        seconds["refine"] = time.perf_counter() - t2
        if refined.status != "ok":
            raise CalibrationError(
                f"refinement failed: {refined.failure_reason}",
                hint="rerun with --no-refine to get the closed-form result",
                code="refinement_failed",
            )
        state.update(refined=refined, T_x=refined.T_x, T_board=refined.T_board)
        if opts.validate:
            progress("validation: refits without some views")
            t3 = time.perf_counter()
            pose_views = [PoseView(v, poses[v].T_cam_board, s.view(v).T_base_end) for v in ids]
            state["validation"] = validate_pose_stage(refined, pose_views)
            seconds["validate"] = time.perf_counter() - t3
    state["outcomes"] = tuple(
        v for _, v in sorted(_final_outcomes(outcomes, {}, refined).items(), key=lambda kv: view_id_key(kv[0]))
    )
    seconds["calibrate"] = time.perf_counter() - t0
    state.pop("session", None)
    return CalibrationRun(session=s, options=opts, **state)


# ------------------------------------------------------------------------------ pose forensics gates
def _stated_source(s: Session) -> str:
    """Stated | flag | default: where the session's mode came from (the loader records it)."""
    return getattr(s, "mode_source", "stated") or "stated"


def _mode_gate(s: Session, obs: Observation, state: dict, progress) -> Session:
    """Decide the mode from the data when the session states none; refuse a stated mode the data contradict.

    Records ``state["mode_decision"]`` = {"mode", "mode_source", "evidence"} and, when the mode was
    detected, a session in that mode (``state["session"]``).
    """
    from .diagnose.mode import mode_evidence
    from .diagnose.observations import candidates_of

    source = _stated_source(s)
    ids = [v for v in sorted(obs.board_poses, key=view_id_key)]
    decision: dict[str, Any] = {"mode": s.mode, "mode_source": source}
    state["mode_decision"] = decision
    if len(ids) < 4:
        return s
    C = np.stack([obs.board_poses[v].T_cam_board for v in ids])
    T = np.stack([s.view(v).T_base_end for v in ids])
    ambiguous = bool(getattr(s.target, "pose_ambiguous", False))
    ev = mode_evidence(C, T, C_candidates=candidates_of(obs.board_poses, ids) if ambiguous else None)
    decision["evidence"] = ev.to_dict()
    if source == "default":
        # the diagnostics' mode-swap test on the mode about to be used: a mode they would refuse is never chosen
        chosen, summary = ev.decided or s.mode, ev.summary()
        swap = _swap_test(s, obs, ids, C, T, chosen)
        if swap is not None:
            chosen, why = swap
            summary = f"the mode-swap test: {why}" + (
                f" (the quick test said {ev.decided}: {summary})"
                if ev.decided is not None
                else f" (the quick test: {summary})"
            )
            decision["evidence"].update(decided=chosen, swap_test=why, summary=summary)
        if ev.decided is not None or swap is not None:
            progress(f"mode: {chosen}, detected from the data (the session states none): {summary}")
            decision.update(mode=chosen, mode_source="detected")
            if chosen != s.mode:
                s = replace(s, mode=chosen)
                state["session"] = s
        else:
            log.warning(
                "the session states no mounting mode and the data do not decide it; calibrating as %s "
                "(the default): %s",
                s.mode,
                ev.summary(),
            )
            progress(f"mode: {s.mode} (the default; the data do not decide it: {ev.summary()})")
        return s
    if ev.decided is not None and ev.decided != s.mode:
        stated = "--mode" if source == "flag" else "the session"
        raise SessionRefused(
            f"the data are {ev.decided} but {stated} says {s.mode}: {ev.summary()}",
            expected=f"robot and camera motions that fit {s.mode}",
            received=f"they fit {ev.decided}",
            hint=f"calibrate with --mode {ev.decided} (or set mode: {ev.decided} in the session); if the camera "
            f"really is {s.mode.replace('_', '-')}, the robot poses may be inverted (T_end_base)",
            code="mode_swapped",
        )
    return s


def _swap_test(s: Session, obs: Observation, ids: list, C: np.ndarray, T: np.ndarray, mode: str):
    """(the other mode, why) when the diagnostics' mode-swap finding would fire on a run in ``mode``, else None."""
    from .diagnose.mode import swapped_mode
    from .diagnose.observations import PoseObservations, candidates_of
    from .session.raw import raw_poses_of

    po = PoseObservations(
        mode,
        tuple(ids),
        C,
        T,
        raw_poses_of(s),
        {},
        target=s.target,
        C_candidates=candidates_of(obs.board_poses, ids),
        tracker=bool(s.meta.get("pose_only")),
    )
    return swapped_mode(po)


def _pairing_gate(s: Session, obs: Observation, M_all: dict, state: dict) -> None:
    """Refuse a session whose images and robot poses are shifted or shuffled (no result from wrong pairs).

    The search it made is the run's ``pairing`` (the diagnostics decide on it without searching again).
    """
    from .diagnose.fits import fit_boards
    from .diagnose.observations import PoseObservations, candidates_of
    from .diagnose.pairing import PairingSearch, pairing_findings
    from .diagnose.thresholds import thresholds
    from .session.raw import raw_poses_of

    ids = [v.view_id for v in s.views if v.view_id in obs.board_poses]
    if len(ids) < 5:
        return
    C = np.stack([obs.board_poses[v].T_cam_board for v in ids])
    try:
        fit = fit_boards(C, np.stack([M_all[v] for v in ids]))
    except np.linalg.LinAlgError:
        return
    if fit.cost <= thresholds().readings.bad_cost:
        return
    T = np.stack([s.view(v).T_base_end for v in ids])
    po = PoseObservations(
        s.mode, tuple(ids), C, T, raw_poses_of(s), {}, C_candidates=candidates_of(obs.board_poses, ids)
    )
    search = state["pairing"] = PairingSearch(po, po.raw.fmt)
    found = pairing_findings(po, po.raw.fmt, given_cost=fit.cost, search=search)
    if not found:
        return
    f = found[0]
    shift = f.details.get("shift")
    if shift is not None:
        raise SessionRefused(
            f"{f.title}: {f.evidence}",
            expected="each image paired with its own pose line",
            received=f"image k fits the pose written for image k{shift:+d}",
            hint=f"fix the pairing, or apply the shift with --shift-poses {shift} (image k takes the pose written "
            f"for image k{shift:+d})",
            code="pairs_shifted",
        )
    raise SessionRefused(
        f"{f.title}: {f.evidence}",
        expected="each image paired with its own robot pose",
        received="poses that belong to other images",
        hint=f.action,
        code="pairs_shuffled",
    )


def shift_poses(s: Session, shift: int) -> tuple[Session, list]:
    """The session with image k paired with the pose written for image k + ``shift``.

    The session with image k paired with the pose written for image k + ``shift`` (in the order the poses
    are written): (session, views left without a pose).
    """
    from .conventions import T_from_pose_values
    from .session.raw import raw_poses_of

    raw = raw_poses_of(s)
    pos = {v: k for k, v in enumerate(raw.order)}
    views, unpaired = [], []
    for v in s.views:
        p = pos.get(v.view_id, -1) + shift
        if v.view_id not in pos or not 0 <= p < len(raw.order):
            unpaired.append(v)
            continue
        T = T_from_pose_values(np.asarray(raw.values[raw.order[p]], float), raw.fmt)
        views.append(replace(v, T_base_end=T, source_line=None))
    meta = dict(s.meta, shift_poses=shift)
    return replace(s, views=tuple(views), meta=meta), unpaired


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
    from .refine import RefineOptions, RefineView, refine

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
    from .kinematics import load_arm

    return load_arm(s.meta["robot"], folder=s.path)


def _joint_angles(s: Session, vid: str):
    try:
        return s.view(vid).joint_angles
    except KeyError:
        return None


def validate_stage(s: Session, refined, poses: dict, dets: dict, T_base_end: dict):
    """The validated and verdict covariances of the refined result.

    The validated and verdict covariances of the refined result (:func:`handeye.refine.validation.validate`):
    refits without some views, from the refinement's own views.
    """
    from .refine import RefineView
    from .refine.validation import Validation, validate

    views = [RefineView(vid, poses[vid].corner_ids, dets[vid].image_points, T_base_end[vid]) for vid in poses]
    try:
        return validate(refined, object_points=s.target.object_points(), views=views)
    except (HandeyeError, RuntimeError, np.linalg.LinAlgError) as e:  # the result stands on its model covariance
        log.warning("validation not run: %s", e)
        return Validation("not_run", f"{type(e).__name__}: {e}")
    except Exception as e:  # noqa: BLE001 - a bug in the validation must not lose the refined result
        log.error("validation crashed (%s: %s); the sigmas are the model's", type(e).__name__, e, exc_info=True)
        return Validation("not_run", f"crashed: {type(e).__name__}: {e}")


def validate_pose_stage(refined, views: list):
    """The validated and verdict covariances of a pose-only result: refits without some views.

    The same folds and rule as for image sessions (:func:`handeye.refine.validation.validate`), each fold
    one solve of the pose graph with the tracker's sigmas held (:func:`handeye.refine.poseonly.refit_poses`).
    """
    from .refine.poseonly import refit_poses
    from .refine.validation import Validation, validate

    try:
        return validate(refined, views=views, refit_views=lambda sub, cov: refit_poses(refined, sub, cov))
    except (HandeyeError, RuntimeError, np.linalg.LinAlgError) as e:  # the result stands on its model covariance
        log.warning("validation not run: %s", e)
        return Validation("not_run", f"{type(e).__name__}: {e}")
    except Exception as e:  # noqa: BLE001 - a bug in the validation must not lose the refined result
        log.error("validation crashed (%s: %s); the sigmas are the model's", type(e).__name__, e, exc_info=True)
        return Validation("not_run", f"crashed: {type(e).__name__}: {e}")


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
