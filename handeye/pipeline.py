"""The calibration pipeline: session -> detections -> intrinsics -> board poses -> seed -> refinement.

Views are linked by id from start to end. A view that fails at any stage is dropped together with
its robot pose, and its outcome records why. The pipeline never raises for a session that cannot be
calibrated: it returns a :class:`CalibrationRun` with ``status="failed"`` and the reason (so a report
can still be written); the CLI turns that into a non-zero exit.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from .conventions import pose_forms
from .detect import detect_views
from .errors import CalibrationError, DegenerateMotionError, DetectionError, HandeyeError
from .frames import pose_error
from .mounting import MountingMode, mounting
from .output import hash_files, provenance
from .initial import (METHODS, all_methods, board_poses, calibrate_intrinsics, chain_residuals, consistency,
                   motion_quality)
from .records import Detection, HandEyeEstimate, Session, ViewOutcome, view_id_key
from .camera import Intrinsics

log = logging.getLogger(__name__)

FRAME_DOC = {
    "T_end_cam": "pose of the camera (optical frame: x right, y down, z forward) in the end/flange frame; "
                 "p_end = T_end_cam @ p_cam",
    "T_base_cam": "pose of the camera (optical frame) in the robot base frame; p_base = T_base_cam @ p_cam",
    "T_base_board": "pose of the calibration board in the robot base frame; p_base = T_base_board @ p_board",
    "T_end_board": "pose of the calibration board in the end/flange frame; p_end = T_end_board @ p_board",
}


@dataclass(frozen=True)
class CalibrateOptions:
    method: str = "tsai"
    refine: bool = True
    fix_k3: bool = False
    workers: Optional[int] = None
    min_corners: int = 6
    min_rotation_deg: float = 10.0
    min_axis_spread_deg: float = 5.0
    refine_options: dict = field(default_factory=dict)

    @staticmethod
    def from_config(cfg: dict, **overrides) -> "CalibrateOptions":
        """Options from a calibration preset (configs/calibration.yaml) plus explicit overrides."""
        kw = {"method": cfg.get("method", "tsai"), "refine": bool(cfg.get("refine", True)),
              "fix_k3": bool(cfg.get("fix_k3", False)), "min_corners": int(cfg.get("min_corners", 6)),
              "min_rotation_deg": float(cfg.get("motion", {}).get("min_rotation_deg", 10.0)),
              "min_axis_spread_deg": float(cfg.get("motion", {}).get("min_axis_spread_deg", 5.0)),
              "refine_options": dict(cfg.get("refine_options", {}))}
        ro = overrides.pop("refine_options", None) or {}
        kw["refine_options"].update(ro)
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return CalibrateOptions(**kw)


@dataclass(frozen=True)
class CalibrationRun:
    session: Session
    options: CalibrateOptions
    status: str = "ok"
    failure_reason: str = ""
    error_type: str = ""
    exit_code: int = 0
    outcomes: tuple = ()  # ViewOutcome per session view, in session order
    detections: dict = field(default_factory=dict)  # view_id -> Detection (used views only)
    intrinsics: Optional[Intrinsics] = None
    intrinsics_source: str = ""
    intrinsics_rms_px: Optional[float] = None
    board_poses: dict = field(default_factory=dict)
    motion: Any = None
    seeds: dict = field(default_factory=dict)  # method -> HandEyeEstimate
    seed: Optional[HandEyeEstimate] = None
    refined: Any = None  # handeye.refine.RefineResult when refined
    T_x: Optional[np.ndarray] = None
    T_board: Optional[np.ndarray] = None
    seconds: dict = field(default_factory=dict)

    @property
    def mode(self) -> MountingMode:
        return mounting(self.session.mode)

    @property
    def used_ids(self) -> list[str]:
        return [o.view_id for o in self.outcomes if o.used]


def run_calibration(session: Session, options: CalibrateOptions = CalibrateOptions(), *,
                    progress: Callable[[str], None] | None = None) -> CalibrationRun:
    state: dict = {}  # stage results, kept for failed runs so that a report can show how far it got
    try:
        return _run(session, options, state, progress or (lambda s: None))
    except HandeyeError as e:
        return CalibrationRun(session=session, options=options, status="failed", failure_reason=str(e),
                              error_type=type(e).__name__, exit_code=e.exit_code, **state)


def _run(s: Session, opts: CalibrateOptions, state: dict, progress) -> CalibrationRun:
    mode = mounting(s.mode)
    if opts.method not in METHODS:
        raise CalibrationError(f"unknown method {opts.method!r}", expected=" | ".join(METHODS))
    t0 = time.perf_counter()
    progress(f"detecting the target in {len(s.views)} images")
    det = detect_views([(v.view_id, v.image_path) for v in s.views], s.target, workers=opts.workers,
                       min_corners=opts.min_corners)
    outcomes: dict[str, ViewOutcome] = {}
    for v in s.views:
        d = det[v.view_id]
        if isinstance(d, Detection):
            outcomes[v.view_id] = ViewOutcome(v.view_id, v.image_path.name, True, "", len(d.corner_ids))
        else:
            outcomes[v.view_id] = ViewOutcome(v.view_id, v.image_path.name, False, d)
    for vid, line in s.meta.get("missing_images", {}).items():
        outcomes[vid] = ViewOutcome(vid, f"{vid}.jpg", False, f"image file missing (pose line {line} not used)")

    def ordered():
        return tuple(outcomes[k] for k in sorted(outcomes, key=view_id_key))

    dets = {vid: d for vid, d in det.items() if isinstance(d, Detection)}
    seconds = {"detect": time.perf_counter() - t0}
    state.update(outcomes=ordered(), detections=dets, seconds=seconds)
    if len(dets) < 3:
        raise DetectionError(f"the target was found in only {len(dets)} of {len(s.views)} images; at least 3 are needed",
                             path=s.path, hint=f"check the board size in the session ({_target_text(s)}) "
                                               "and that the whole board is visible and sharp")
    obj = s.target.object_points()
    # --- intrinsics
    t1 = time.perf_counter()
    if s.intrinsics is not None and s.intrinsics_prior in ("fixed", "prior"):
        intr, intr_src, intr_rms = s.intrinsics, f"given ({s.intrinsics_prior})", None
        w, h = next(iter(dets.values())).image_size
        if (intr.width, intr.height) != (w, h):
            raise CalibrationError(f"the given intrinsics are for {intr.width}x{intr.height} images but the images are "
                                   f"{w}x{h}", path=s.path, hint="fix intrinsics.image_size or drop the intrinsics")
    else:
        progress("calibrating the camera intrinsics")
        intr, intr_rms = calibrate_intrinsics(list(dets.values()), obj, fix_k3=opts.fix_k3)
        intr_src = "calibrateCamera (OpenCV 5-coefficient model)"
    M = {vid: mode.M_from_T_base_end(s.view(vid).T_base_end) for vid in dets}
    poses = board_poses([dets[v] for v in dets], s.target, intr, M)
    for vid, bp in poses.items():
        outcomes[vid] = replace(outcomes[vid], rms_px=bp.rms_px, orientation=bp.orientation)
    state.update(outcomes=ordered(), intrinsics=intr, intrinsics_source=intr_src, intrinsics_rms_px=intr_rms,
                 board_poses=poses)
    ids = list(poses)
    C = np.stack([poses[v].T_cam_board for v in ids])
    Ms = np.stack([M[v] for v in ids])
    # --- motion
    mq = motion_quality(Ms, frame=mode.fixed_frame, min_rotation_deg=opts.min_rotation_deg,
                        min_axis_spread_deg=opts.min_axis_spread_deg)
    state.update(motion=mq)
    if mq.status != "ok":
        raise DegenerateMotionError(mq.reason, path=s.path)
    # --- closed form
    progress(f"closed-form hand-eye ({', '.join(METHODS)})")
    seeds = all_methods(mode, C, Ms)
    seed = seeds[opts.method]
    state.update(seeds=seeds)
    if seed.status != "ok":
        raise CalibrationError(f"the {opts.method} solver failed: {seed.failure_reason}",
                               hint="try another --method (e.g. park) or check the robot poses")
    seconds["seed"] = time.perf_counter() - t1
    state.update(seed=seed, T_x=seed.T_x, T_board=seed.T_board)
    T_base_end = {vid: s.view(vid).T_base_end for vid in ids}
    chain = chain_residuals(seed, mode, obj, poses, dets, T_base_end, intr)
    refined = None
    if opts.refine:
        progress("joint refinement (GTSAM)")
        t2 = time.perf_counter()
        refined = _refine(s, opts, seed, intr, obj, poses, dets, T_base_end)
        seconds["refine"] = time.perf_counter() - t2
        if refined.status != "ok":
            raise CalibrationError(f"refinement failed: {refined.failure_reason}",
                                   hint="rerun with --no-refine to get the closed-form result")
        state.update(refined=refined, T_x=refined.T_x, T_board=refined.T_board, intrinsics=refined.intrinsics)
    outcomes = _final_outcomes(outcomes, chain, refined)
    state["outcomes"] = ordered()
    seconds["total"] = time.perf_counter() - t0
    return CalibrationRun(session=s, options=opts, **state)


def _refine(s, opts, seed, intr, obj, poses, dets, T_base_end):
    from .refine import RefineOptions, RefineView, refine

    views = [RefineView(vid, poses[vid].corner_ids, dets[vid].image_points, T_base_end[vid]) for vid in poses]
    ro = dict(opts.refine_options)
    if opts.fix_k3:
        ro["fix"] = tuple(sorted(set(ro.get("fix", ())) | {"k3"}))
    if s.intrinsics is not None and s.intrinsics_prior in ("fixed", "prior"):
        ro.setdefault("intrinsics", s.intrinsics_prior)
    return refine(mode=s.mode, object_points=obj, views=views, intrinsics=intr, T_x0=seed.T_x,
                  T_board0=seed.T_board, options=RefineOptions(**ro))


def _final_outcomes(outcomes, chain, refined):
    """Outcomes after the solve: residuals through the robot chain, and the refinement's decisions."""
    out = dict(outcomes)
    for vid, (rms, mx) in chain.items():
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


def _target_text(s: Session) -> str:
    t = s.target
    if t.kind == "chessboard":
        return f"chessboard {t.cols}x{t.rows} inner corners, {t.square_m * 1000:g} mm"
    if t.kind == "circlegrid":
        return f"circle grid {t.cols}x{t.rows} dots, {t.spacing_m * 1000:g} mm spacing"
    return f"ChArUco {t.squares_x}x{t.squares_y} squares"


# ------------------------------------------------------------------------------ result.json
def session_inputs(session: Session) -> list[Path]:
    files = [v.image_path for v in session.views]
    for name in ("poses.txt", "config.yaml", "session.yaml"):
        if (session.path / name).exists():
            files.append(session.path / name)
    return files


def observations_dict(run: CalibrationRun) -> dict:
    """Per used view: detected corners and their residuals under the final solution (observations.json).

    ``residual_chain_px`` predicts the board through the reported robot pose and the hand-eye result
    (what the robot will experience); ``residual_pnp_px`` through the view's own board pose (what the
    camera alone explains).
    """
    from .initial import project, solve_pnp

    s = run.session
    obj = s.target.object_points()
    mode = mounting(s.mode)
    views = {}
    intr = run.intrinsics
    for vid, det in run.detections.items():
        bp = run.board_poses.get(vid)
        ids = bp.corner_ids if bp is not None else det.corner_ids
        v = {"corner_ids": ids.tolist(), "image_points_px": det.image_points.tolist(),
             "sharpness": det.sharpness, "image": str(s.view(vid).image_path)}
        if bp is not None and intr is not None:
            # the view's own pose under the final intrinsics (bp was fitted with the seed's intrinsics)
            T_pnp = solve_pnp(obj[ids], det.image_points, intr)[0]
            v["T_cam_board_pnp"] = T_pnp.tolist()
            v["residual_pnp_px"] = (det.image_points - project(obj[ids], T_pnp, intr)).tolist()
            if run.T_x is not None:
                C = mode.predict_T_cam_board(run.T_x, run.T_board, s.view(vid).T_base_end)
                v["T_cam_board_chain"] = C.tolist()
                v["residual_chain_px"] = (det.image_points - project(obj[ids], C, intr)).tolist()
        v["T_base_end_reported"] = s.view(vid).T_base_end.tolist()
        views[vid] = v
    return {"handeye_observations": 1, "mode": s.mode, "target": s.target.to_dict(),
            "object_points_m": obj.tolist(),
            "image_size": list(intr.image_size) if intr is not None else None, "views": views}


def result_dict(run: CalibrationRun) -> dict:
    """Everything result.json holds. A failed run has ``status: failed`` and no result matrix."""
    s = run.session
    mode = mounting(s.mode)
    d: dict[str, Any] = {
        "handeye_result": 1,
        "status": run.status,
        "failure_reason": run.failure_reason,
        "mode": s.mode,
        "method": run.options.method,
        "refined": run.refined is not None,
    }
    if run.status == "ok":
        d[mode.x_name] = run.T_x.tolist()
        d[mode.board_name] = run.T_board.tolist()
        d["frames"] = {mode.x_name: FRAME_DOC[mode.x_name], mode.board_name: FRAME_DOC[mode.board_name],
                       "units": "metres; angles in radians unless the key says _deg"}
        d["hand_eye"] = dict(name=mode.x_name, **pose_forms(run.T_x))
        d["board"] = dict(name=mode.board_name, **pose_forms(run.T_board))
    if run.seed is not None:
        d["seed"] = {"method": run.seed.method, mode.x_name: run.seed.T_x.tolist(),
                     mode.board_name: run.seed.T_board.tolist()}
    if run.seeds:
        cf = {}
        C = np.stack([bp.T_cam_board for bp in run.board_poses.values()])
        Ms = np.stack([mode.M_from_T_base_end(s.view(v).T_base_end) for v in run.board_poses])
        for m, est in run.seeds.items():
            e = {"status": est.status}
            if est.status == "ok":
                dt, dr = consistency(est, mode, C, Ms)
                e.update({mode.x_name: est.T_x.tolist(), "translation_mm": (est.T_x[:3, 3] * 1e3).tolist(),
                          "rotvec_deg": pose_forms(est.T_x)["rotvec_deg"],
                          "board_consistency_mm": dt, "board_consistency_deg": dr})
                if run.T_x is not None:
                    r, t = pose_error(est.T_x, run.T_x)
                    e["diff_to_result_deg"], e["diff_to_result_mm"] = r, t
            else:
                e["failure_reason"] = est.failure_reason
            cf[m] = e
        d["closed_form"] = cf
    if run.intrinsics is not None:
        d["intrinsics"] = dict(run.intrinsics.to_dict(), source=run.intrinsics_source,
                               calibrate_camera_rms_px=run.intrinsics_rms_px)
    d["views"] = [{"id": o.view_id, "image": o.image, "used": o.used, "reason": o.reason, "n_corners": o.n_corners,
                   "pnp_rms_px": o.rms_px, "chain_max_px": o.max_px, "orientation": o.orientation,
                   "flags": list(o.flags)}
                  for o in run.outcomes]
    d["n_views"] = {"total": len(run.outcomes), "used": sum(o.used for o in run.outcomes)}
    if run.motion is not None:
        d["motion"] = {"n_views": run.motion.n_views, "max_rotation_deg": run.motion.max_rotation_deg,
                       "axis_spread_deg": run.motion.axis_spread_deg, "status": run.motion.status,
                       "reason": run.motion.reason}
    if run.refined is not None and hasattr(run.refined, "to_dict"):
        d["refinement"] = run.refined.to_dict()
    d["target"] = s.target.to_dict()
    d["session"] = {"path": str(s.path), "format": s.format, "pose_format": s.pose_format,
                    "intrinsics_given": s.intrinsics is not None}
    d["seconds"] = run.seconds
    d["provenance"] = provenance(inputs_sha256=hash_files(session_inputs(s)),
                                 extra={"options": {"method": run.options.method, "refine": run.options.refine,
                                                    "fix_k3": run.options.fix_k3,
                                                    **run.options.refine_options}})
    return d
