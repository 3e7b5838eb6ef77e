"""What a calibration leaves behind: result.json and observations.json.

Both are plain JSON written atomically (:mod:`handeye.output`) and read by everything after a
calibration. A failed run still has a result.json with ``status: failed``, ``failure_reason`` and the
structured ``error``. ``status`` says only whether a matrix was computed; whether to use it is the
``verdict`` (:func:`verdict_fields`: ``verdict``, ``verdict_headline``, ``qa``, ``findings``,
``mode_source``, ``mode_evidence``).

See docs/calibrate.md.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Optional

import numpy as np

from .camera import pixels_from_board_points
from .contract import OBSERVATIONS_VERSION, RESULT_VERSION  # the versions live with the models
from .conventions import pose_forms
from .diagnose.findings import PAIRS_OUT_OF_STEP, ROOT_CAUSE_LABELS, is_out_of_step
from .errors import HandeyeError, SessionRefused
from .frames import pose_error, tangent_difference
from .mounting import mounting
from .output import hash_files, plain, provenance, recorded_path
from .records import Session

FRAME_DOC = {
    "T_end_cam": "pose of the camera (optical frame: x right, y down, z forward) in the end/flange frame; "
    "p_end = T_end_cam @ p_cam",
    "T_base_cam": "pose of the camera (optical frame) in the robot base frame; p_base = T_base_cam @ p_cam",
    "T_base_board": "pose of the calibration board in the robot base frame; p_base = T_base_board @ p_board",
    "T_end_board": "pose of the calibration board in the end/flange frame; p_end = T_end_board @ p_board",
}


def session_inputs(session: Session) -> list[Path]:
    """The files a session's result depends on (images, poses and config), for the inputs hash."""
    files = [v.image_path for v in session.views if v.image_path is not None]  # pose-only views have none
    for name in ("poses.txt", "config.yaml", "session.yaml"):
        if (session.path / name).exists():
            files.append(session.path / name)
    return files


def own_view_reason(reason: str, view_id: str) -> str:
    """A view's reason without its own id: ``outlier: view 3: reported ...`` -> ``outlier: reported ...``.

    The refinement's outlier reasons name their view; in the view's own record the id is said already (the
    command prints ``view 3 (3.jpg) dropped: outlier: reported ...``, not ``view 3`` twice).
    """
    return re.sub(rf"^(outlier: )?view {re.escape(str(view_id))}: ", r"\1", str(reason or ""))


def observations_dict(run) -> dict:
    """Per used view: detected corners and their residuals under the final solution (observations.json).

    ``residual_chain_px`` predicts the board through the reported robot pose and the hand-eye result
    (what the robot will experience); ``residual_pnp_px`` through the view's own board pose (what the
    camera alone explains). ``failed_views`` holds the views without the target: the reason and the
    image's exposure. Thumbnails of all views are in ``thumbnails/<view_id>.jpg``.
    """
    from .initial import solve_pnp

    s = run.session
    obj = s.target.object_points()
    mode = mounting(s.mode)
    views = {}
    intr = run.intrinsics
    for vid, det in run.detections.items():
        bp = run.board_poses.get(vid)
        ids = bp.corner_ids if bp is not None else det.corner_ids
        v = {
            "corner_ids": ids.tolist(),
            "image_points_px": det.image_points.tolist(),
            "sharpness": det.sharpness,
            "image": recorded_path(s.view(vid).image_path),
        }
        for key in ("blur", "exposure"):
            if getattr(det, key, None) is not None:
                v[key] = getattr(det, key)
        if bp is not None and intr is not None:
            # the view's own pose under the final intrinsics (bp was fitted with the initial intrinsics)
            T_pnp = solve_pnp(obj[ids], det.image_points, intr)[0]
            v["T_cam_board_pnp"] = T_pnp.tolist()
            v["residual_pnp_px"] = (det.image_points - pixels_from_board_points(T_pnp, obj[ids], intr)).tolist()
            if run.T_x is not None:
                C = mode.predict_T_cam_board(run.T_x, run.T_board, s.view(vid).T_base_end)
                v["T_cam_board_chain"] = C.tolist()
                v["residual_chain_px"] = (det.image_points - pixels_from_board_points(C, obj[ids], intr)).tolist()
        v["T_base_end_reported"] = s.view(vid).T_base_end.tolist()
        views[vid] = v
    failed = {}  # views without the target: why, and what detection measured of the image
    reasons = {o.view_id: o.reason for o in run.outcomes}
    for vid, f in run.failures.items():
        failed[vid] = {"reason": reasons.get(vid, ""), "image": recorded_path(s.view(vid).image_path)}
        if getattr(f, "exposure", None) is not None:
            failed[vid]["exposure"] = f.exposure
    return {
        "handeye_observations": OBSERVATIONS_VERSION,
        "mode": s.mode,
        "target": s.target.to_dict(),
        "object_points_m": obj.tolist(),
        "image_size": list(intr.image_size) if intr is not None else None,
        "views": views,
        "failed_views": failed,
    }


def dropped_corners(run, view_id: str) -> list:
    """[{"corner_id", "reason"}] of the corners the detector found in the view but did not use.

    [{"corner_id", "reason"}] of the corners the detector found in the view but did not use, numbered as
    the view's used corners are (its board orientation resolved); [] when none or not detected.
    """
    det = (getattr(run, "detections", None) or {}).get(view_id)
    if det is None or not getattr(det, "dropped_corners", ()):
        return []
    bp = (getattr(run, "board_poses", None) or {}).get(view_id)
    syms = run.session.target.symmetries() if bp is not None else None
    perm = syms[bp.orientation] if bp is not None and syms is not None and 0 <= bp.orientation < len(syms) else None
    return [
        {"corner_id": int(perm[k]) if perm is not None else int(k), "reason": why} for k, why in det.dropped_corners
    ]


def mode_source(run, mode_flag: Optional[str] = None) -> tuple[Optional[str], Optional[dict]]:
    """(``mode_source``, ``mode_evidence``): how the mounting mode was chosen.

    (``mode_source``, ``mode_evidence``): how the mounting mode was chosen (``stated`` | ``flag`` |
    ``detected`` | ``default``) as the run's ``mode_decision`` (or its session) records it, and the
    evidence of the mode test (a dict with its ``summary`` line) when it ran; ``flag`` when the mode
    came from ``--mode`` and nothing else is recorded.
    """
    decision = getattr(run, "mode_decision", None) or {}
    src = decision.get("mode_source") or getattr(run.session, "mode_source", None)
    if mode_flag is not None and src in (None, "stated"):
        src = "flag"
    ev = decision.get("evidence")
    return (None if src is None else str(src)), (ev if isinstance(ev, dict) else None)


def result_dict(run, *, mode_flag: Optional[str] = None) -> dict:
    """Everything result.json holds but the verdict (:func:`verdict_fields`).

    A failed run has ``status: failed``, the error and no result matrix. ``mode_flag``: the
    ``--mode`` given, if any.
    """
    s = run.session
    mode = mounting(s.mode)
    src, evidence = mode_source(run, mode_flag)
    d: dict[str, Any] = {
        "handeye_result": RESULT_VERSION,
        "status": run.status,
        "failure_reason": run.failure_reason,
        "mode": s.mode,
        "mode_source": src,
        "method": run.options.method,
        "refined": run.refined is not None,
    }
    if evidence is not None:
        d["mode_evidence"] = evidence
    if run.error is not None:
        d["error"] = run.error.to_dict()
    if run.status == "ok":
        d[mode.x_name] = run.T_x.tolist()
        d[mode.board_name] = run.T_board.tolist()
        d["frames"] = {
            mode.x_name: FRAME_DOC[mode.x_name],
            mode.board_name: FRAME_DOC[mode.board_name],
            "units": "metres; angles in radians unless the key says _deg",
        }
        d["hand_eye"] = dict(name=mode.x_name, **pose_forms(run.T_x))
        d["board"] = dict(name=mode.board_name, **pose_forms(run.T_board))
    if run.start is not None:
        d["seed"] = {
            "method": run.start.method,
            mode.x_name: run.start.T_x.tolist(),
            mode.board_name: run.start.T_board.tolist(),
        }
    if run.closed_forms:
        d["closed_form"] = _closed_forms_dict(run, mode)
        if run.closed_form_views is not None:  # solved again on the views the refinement kept
            d["closed_form_views"] = list(run.closed_form_views)
    if run.intrinsics is not None:
        d["intrinsics"] = dict(
            run.intrinsics.to_dict(), source=run.intrinsics_source, calibrate_camera_rms_px=run.intrinsics_rms_px
        )
    d["views"] = [
        {
            "id": o.view_id,
            "image": o.image,
            "used": o.used,
            "reason": own_view_reason(o.reason, o.view_id),
            "n_corners": o.n_corners,
            "pnp_rms_px": o.rms_px,
            "chain_max_px": o.max_px,
            "orientation": o.orientation,
            "flags": list(o.flags),
            "corners_dropped": dropped_corners(run, o.view_id),
        }
        for o in run.outcomes
    ]
    d["n_views"] = {"total": len(run.outcomes), "used": sum(o.used for o in run.outcomes)}
    if run.motion is not None:
        m = run.motion
        d["motion"] = {
            "n_views": m.n_views,
            "max_rotation_deg": m.max_rotation_deg,
            "axis_spread_deg": m.axis_spread_deg,
            "status": m.status,
            "reason": m.reason,
            "min_rotation_deg": m.min_rotation_deg,
            "min_axis_spread_deg": m.min_axis_spread_deg,
        }
    if run.refined is not None and hasattr(run.refined, "to_dict"):
        d["refinement"] = run.refined.to_dict()
        if run.refined.status == "ok":
            d["refinement"].update(
                validation_fields(run.refined, getattr(run, "validation", None), getattr(run, "arm_accuracy", None))
            )
    d["target"] = s.target.to_dict()
    d["session"] = {
        "path": recorded_path(s.path),
        "format": s.format,
        "pose_format": s.pose_format,
        "intrinsics_given": s.intrinsics is not None,
    }
    d["seconds"] = dict(run.seconds)
    d["provenance"] = provenance(
        inputs_sha256=hash_files(session_inputs(s)),
        extra={
            "options": {
                "method": run.options.method,
                "refine": run.options.refine,
                "fix_k3": run.options.fix_k3,
                **run.options.refine_options,
            }
        },
    )
    return d


def _closed_forms_dict(run, mode) -> dict:
    from .initial import consistency

    s = run.session
    ids = list(run.board_poses) if run.closed_form_views is None else list(run.closed_form_views)
    C = np.stack([run.board_poses[v].T_cam_board for v in ids])
    Ms = np.stack([mode.M_from_T_base_end(s.view(v).T_base_end) for v in ids])
    cf = {}
    cov = verdict_cov_x(run)
    for m, est in run.closed_forms.items():
        e = {"status": est.status}
        if est.status == "ok":
            dt, dr = consistency(est, mode, C, Ms)
            e.update(
                {
                    mode.x_name: est.T_x.tolist(),
                    "translation_mm": (est.T_x[:3, 3] * 1e3).tolist(),
                    "rotvec_deg": pose_forms(est.T_x)["rotvec_deg"],
                    "board_consistency_mm": dt,
                    "board_consistency_deg": dr,
                }
            )
            if run.T_x is not None:
                r, t = pose_error(est.T_x, run.T_x)
                e["diff_to_result_deg"], e["diff_to_result_mm"] = r, t
                if cov is not None:
                    e["diff_to_result_sigma"] = _sigma_distance(run.T_x, est.T_x, cov)
        else:
            e["failure_reason"] = est.failure_reason
        cf[m] = e
    return cf


def verdict_cov_x(run) -> Optional[np.ndarray]:
    """The verdict covariance (6,6) of the run's T_x.

    The validated verdict when the run was validated, else the refinement's model covariance; None
    without a refinement.
    """
    ref = run.refined
    if ref is None or getattr(ref, "status", "") != "ok":
        return None
    val = getattr(run, "validation", None)
    # without the arm's stated accuracy: it is common to the result and what it meets here (the closed forms of the
    # same views)
    return val.x.cov_verdict if val is not None and val.status == "ok" else np.asarray(ref.cov_x_6x6, float)


def _sigma_distance(T_ref: np.ndarray, T: np.ndarray, cov: np.ndarray) -> Optional[float]:
    """sqrt(xi^T cov^-1 xi) of T against T_ref (xi = Log(T_ref^-1 T), the tangent of ``cov``)."""
    from .refine.validation import mahalanobis2

    m2 = mahalanobis2(tangent_difference(T_ref, T), cov)
    return float(np.sqrt(m2)) if np.isfinite(m2) else None


def validation_fields(ref, val, arm=None) -> dict:
    """The validated and verdict uncertainty for result.json's ``refinement`` block.

    ``cov_x_6x6`` and ``intrinsics_sigma`` stay the model's. Added: ``cov_x_6x6_validated`` and
    ``cov_x_6x6_verdict`` (same parametrisation; the model's when not validated), ``sigma_source`` (model |
    validated | model+validated: which covariance the verdict takes; ``model`` also when validation did not
    run) and ``sigma_rule``;
    ``sigma_rot_deg``, ``sigma_trans_mm``, ``correlation_6x6``, ``predicted_error_mm`` and
    ``predicted_error_axes_mm`` become the verdict's, the model's kept as ``*_model``; for the free
    intrinsics ``intrinsics_sigma_validated``, ``intrinsics_sigma_verdict`` and ``cov_intrinsics_verdict``
    (rows in ``intrinsics_cov_names``); ``validation``: the fold scheme, the spread over the model's
    sigma with its p-value if the model is right (``spread_p_value``; ``spread_beyond_chance``: below
    validation.alpha, the verdict then takes the validated covariance where it is larger), the same for the
    intrinsics and the model covariance they were measured against (``intrinsics_model``: full | sigmas), and
    the odd and even halves refitted (their T_x, intrinsics, and offset from the result). ``arm``: the arm's
    stated accuracy (:class:`handeye.refine.arm_accuracy.ArmAccuracy`): its covariance is added to the verdict
    covariance (written then also without validation) and described as ``robot_accuracy``.
    """
    from .refine.covariance import hand_eye_uncertainty
    from .refine.validation import SIGMA_RULE, mahalanobis2

    out: dict[str, Any] = {"sigma_rule": SIGMA_RULE}
    model = hand_eye_uncertainty(np.asarray(ref.cov_x_6x6, float), ref.T_x, ref.working_distance_m)
    for k in ("sigma_rot_deg", "sigma_trans_mm", "correlation_6x6", "predicted_error_mm", "predicted_error_axes_mm"):
        out[f"{k}_model"] = getattr(model, k)
    if arm is not None:
        out["robot_accuracy"] = arm.describe()
    if val is None or val.status != "ok":
        out.update(
            sigma_source="model",
            intrinsics_sigma_verdict=dict(ref.intrinsics_sigma),
            validation={"status": "not_run", "summary": "not run" if val is None else val.summary()},
        )
        out["cov_x_6x6_verdict"] = np.asarray(ref.cov_x_6x6, float)  # the model's: every result carries one
        if arm is not None:
            out["cov_x_6x6_verdict"] = out["cov_x_6x6_verdict"] + arm.cov_x_6x6
            verdict = hand_eye_uncertainty(out["cov_x_6x6_verdict"], ref.T_x, ref.working_distance_m)
            for k in ("sigma_rot_deg", "sigma_trans_mm", "correlation_6x6", "predicted_error_mm"):
                out[k] = getattr(verdict, k)
            out["predicted_error_axes_mm"] = verdict.predicted_error_axes_mm
        return plain(out)
    cov_verdict = val.x.cov_verdict if arm is None else val.x.cov_verdict + arm.cov_x_6x6
    verdict = hand_eye_uncertainty(cov_verdict, ref.T_x, ref.working_distance_m)
    validated = hand_eye_uncertainty(val.x.cov_validated, ref.T_x, ref.working_distance_m)
    out.update(
        cov_x_6x6_validated=val.x.cov_validated,
        cov_x_6x6_verdict=cov_verdict,
        sigma_source=val.x.source,
        sigma_rot_deg_validated=validated.sigma_rot_deg,
        sigma_trans_mm_validated=validated.sigma_trans_mm,
    )
    for k in ("sigma_rot_deg", "sigma_trans_mm", "correlation_6x6", "predicted_error_mm", "predicted_error_axes_mm"):
        out[k] = getattr(verdict, k)
    kb = val.intrinsics
    if kb is not None:
        out["intrinsics_cov_names"] = list(kb.names)
        out["cov_intrinsics_verdict"] = kb.cov_verdict
        out["intrinsics_sigma_validated"] = dict(zip(kb.names, np.sqrt(np.diag(kb.cov_validated)), strict=False))
        out["intrinsics_sigma_verdict"] = dict(zip(kb.names, np.sqrt(np.diag(kb.cov_verdict)), strict=False))
        out["intrinsics_sigma_source"] = kb.source
    else:
        out["intrinsics_sigma_verdict"] = dict(ref.intrinsics_sigma)
    K = len(val.folds)
    block = {
        "status": "ok",
        "summary": val.summary(),
        "scheme": val.scheme,
        "n_views": len(val.view_ids),
        "n_folds": K,
        "folds_solved": val.n_solved,
        "spread_over_model_sigma_max": float(np.sqrt(max(val.x.eig_spread.max(), 0.0))),  # the raw spread's
        "spread_over_model_sigma_rms": float(np.sqrt(max(val.x.scale, 0.0))),
        "generalised_eigenvalues": val.x.eig,
        "shrinkage": val.x.shrinkage,
        "spread_p_value": val.x.p_value,
        "spread_beyond_chance": val.x.finding,
        "spread_test": val.x.test,
    }
    if kb is not None:
        block.update(
            intrinsics_spread_over_model_sigma_max=float(np.sqrt(max(kb.eig_spread.max(), 0.0))),
            intrinsics_spread_over_model_sigma_rms=float(np.sqrt(max(kb.scale, 0.0))),
            intrinsics_spread_p_value=kb.p_value if np.isfinite(kb.p_value) else None,
            intrinsics_spread_beyond_chance=kb.finding,
            intrinsics_spread_test=kb.test,
            intrinsics_model=kb.model_form,
        )
    halves = {}
    for name, fit in val.halves.items():
        # view_ids: every view refitted (robot-excluded ones serve the intrinsics); used_view_ids: X's views
        h = {
            "view_ids": list(fit.view_ids),
            "status": fit.status,
            "used_view_ids": [v for v in fit.view_ids if (ref.per_view.get(v) or {}).get("status") == "used"],
        }
        if fit.status == "ok":
            r, t = pose_error(fit.T_x, ref.T_x)
            h.update(
                {
                    ref.x_name: fit.T_x,
                    "intrinsics": None if fit.intrinsics is None else fit.intrinsics.to_dict(),
                    "diff_to_result_deg": r,
                    "diff_to_result_mm": t,
                    # result vs a half of its views: cov(half - full) = cov(half) - cov(full) ~ cov(full)
                    "diff_to_result_sigma": _sigma_distance(ref.T_x, fit.T_x, val.x.cov_verdict),
                }
            )
        halves[name] = h
    if all(h.get("status") == "ok" for h in halves.values()) and len(halves) == 2:
        a, b = val.halves["odd"], val.halves["even"]
        # independent halves, each with about twice the full covariance: the difference has ~4x
        m2 = mahalanobis2(tangent_difference(a.T_x, b.T_x), 4.0 * val.x.cov_verdict)
        r, t = pose_error(a.T_x, b.T_x)
        halves["odd_vs_even"] = {
            "diff_deg": r,
            "diff_mm": t,
            "mahalanobis2": m2,
            "covariance": "4x the verdict covariance (each half has about twice it)",
        }
    block["halves"] = halves
    out["validation"] = block
    return plain(out)


def failed_load_result(session_path, err: HandeyeError, mode: Optional[str]) -> dict:
    """result.json for a session that could not be read at all."""
    return {
        "handeye_result": RESULT_VERSION,
        "status": "failed",
        "failure_reason": str(err),
        "error": err.to_dict(),
        "mode": mode or "unknown",
        "mode_source": "flag" if mode else None,
        "method": None,
        "refined": False,
        "views": [],
        "n_views": {"total": 0, "used": 0},
        "session": {"path": recorded_path(Path(session_path).resolve()), "format": "unreadable"},
        "provenance": provenance(),
    }


#: the keys of a finding in result.json's ``findings``
FINDING_KEYS = ("code", "severity", "title", "evidence", "action", "view_ids")
_SEVERITY_RANK = {"fail": 0, "warn": 1, "info": 2}


def verdict_fields(verdict, res: dict, error: Optional[HandeyeError], *, qa_cfg: Optional[dict] = None) -> dict:
    """``verdict``, ``verdict_headline``, ``qa`` and ``findings`` for result.json.

    ``verdict``: the report's :class:`handeye.report.qa.Verdict` of this result folder, or None when it
    could not be evaluated (the verdict then rests on the findings: FAIL on a fail finding, else WARN,
    since the QA checks did not run). A run with an error is FAIL (REFUSED for a
    :class:`~handeye.errors.SessionRefused`) whatever the checks say: there is no matrix to use.
    ``qa_cfg``: the QA thresholds the verdict used (for each check's ``limits``).
    """
    raw = ((res.get("diagnostics") or {}).get("findings")) or []
    findings = [
        {k: (list(f.get(k) or []) if k == "view_ids" else f.get(k)) for k in FINDING_KEYS}
        for f in raw
        if isinstance(f, dict)
    ]
    findings.sort(key=lambda f: _SEVERITY_RANK.get(str(f["severity"]).lower(), 3))
    if verdict is not None:
        label, headline = verdict.label, verdict.headline
        qa = {
            "source": verdict.thresholds_source,
            "status": verdict.status,
            "counts": dict(verdict.counts),
            "checks": [_check_dict(c, (qa_cfg or {}).get("checks") or {}) for c in verdict.checks],
        }
    else:
        worst = min((_SEVERITY_RANK.get(str(f["severity"]).lower(), 3) for f in findings), default=3)
        label = "FAIL" if worst == 0 else "WARN"
        headline = "The QA checks could not be evaluated; the verdict rests on the diagnostics' findings."
        qa = {"source": None, "status": None, "counts": {}, "checks": [], "error": "the QA checks crashed"}
    if error is not None:
        label = "REFUSED" if isinstance(error, SessionRefused) else "FAIL"
        if label == "REFUSED" and verdict is not None and verdict.cause:  # the report's banner's words
            headline = f"{verdict.cause}; no result is given."
        elif label == "REFUSED":  # led by the root cause's name, as the report's banner is
            code = str(getattr(error, "code", "") or "")
            cause = ROOT_CAUSE_LABELS.get(code)
            if code == "pairs_shuffled" and any(is_out_of_step(f) for f in raw if isinstance(f, dict)):
                cause = PAIRS_OUT_OF_STEP
            what = f"{error.what[:1].lower()}{error.what[1:]}" if cause else f"{error.what[:1].upper()}{error.what[1:]}"
            headline = f"{cause}: {what}; no result is given." if cause else f"{what}; no result is given."
    return {"verdict": label, "verdict_headline": headline, "qa": qa, "findings": findings}


def _check_dict(c, limits_cfg: dict) -> dict:
    """A QA check (:class:`handeye.report.qa.Check`) for result.json, with its limits as numbers.

    A QA check (:class:`handeye.report.qa.Check`) for result.json, with its limits as numbers
    (``limits``: check key -> {warn_above, fail_above, warn_below, fail_below}, from the QA file).
    """
    limits = {
        k: {n: v for n, v in limits_cfg[k].items() if v is not None}
        for k in c.key.split("+")
        if isinstance(limits_cfg.get(k), dict)
    }
    return {
        "key": c.key,
        "title": c.title,
        "status": c.status,
        "value": c.value,
        "value_text": c.value_text,
        "limit_text": c.limit_text,
        "limits": limits,
        "why": c.why,
        "action": c.action,
        "source": c.source,
        "short": c.short,
    }


def cov_source_words(source: str) -> str:
    """Which covariance of X an earlier result gave (result.json's key, as verify and --prior record it), in words."""
    key, _, less = source.partition(" less ")
    words = {
        "cov_x_6x6_verdict": "its verdict covariance",
        "cov_x_6x6": "its model covariance (the result has no verdict covariance)",
        "none": "none",
    }.get(key, key)
    return words + (", less the arm's stated accuracy (an error every session of the arm shares)" if less else "")
