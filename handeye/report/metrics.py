"""The numbers the QA checks judge (configs/qa.yaml ``checks:``), computed from the result folder.

:func:`qa_metrics` returns ``metrics`` (check key -> number or None) for :func:`handeye.report.qa.evaluate`
and ``notes`` (where each number comes from, the words its advice needs, and the arrays the figures
reuse). Motion coverage is :func:`handeye.initial.motion.motion_quality`, the pipeline's own measure.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from ..initial.motion import axis_text, motion_quality
from ..mounting import MountingMode
from ..records import view_id_key
from ..session.target_spec import is_tracked
from .observations import ViewFit, coverage_counts, finite, relative_rotvecs, rms_norm, robot_motions


def qa_metrics(
    res: dict,
    ref: dict,
    fits: dict[str, ViewFit],
    views: list[dict],
    unc: Optional[dict],
    pred: Optional[dict],
    wd: float,
    image_size,
    mounting: MountingMode,
    *,
    coverage_cells_x: int = 16,
) -> tuple[dict, dict]:
    m: dict[str, Optional[float]] = {}
    c: dict[str, Any] = {}
    used_ids = {v["id"] for v in views if v["status"] == "used"}
    # reprojection
    if ref and finite(ref.get("rms_px_after")):
        m["reprojection_rms_px"] = float(ref["rms_px_after"])
        c["rms_source"] = "joint fit"
        c["reprojection_rms_px_source"] = "joint refinement, corners used"
    else:
        r = [fits[v].residual_px for v in sorted(used_ids) if v in fits]
        rms = rms_norm(np.concatenate(r)) if r else float("nan")
        m["reprojection_rms_px"] = rms if np.isfinite(rms) else None
        c["rms_source"] = "each view's own board pose"
        c["reprojection_rms_px_source"] = "camera fit per view (no joint refinement)"
    # uncertainty
    m["predicted_error_mm"] = pred["rms_mm"] if pred is not None else None
    if pred is not None:
        c["wd_m"] = wd
        c["predicted_error_mm_source"] = f"covariance, point on the optical axis at {wd:.2f} m"
    if unc is not None:
        st, sr = np.asarray(unc["translation_mm"]), np.asarray(unc["rot_cam_deg"])
        m["sigma_trans_mm"], m["sigma_rot_deg"] = float(st.max()), float(sr.max())
        c["sigma_t_axis"] = f"along {mounting.fixed_frame} {'xyz'[int(st.argmax())]}"
        c["sigma_r_axis"] = "xyz"[int(sr.argmax())]
        acc, verdict = (ref or {}).get("robot_accuracy"), (ref or {}).get("cov_x_6x6_verdict")
        if isinstance(acc, dict) and verdict is not None:  # the share of X's variance the arm's stated accuracy makes
            arm, full = np.asarray(acc["cov_x_6x6"], float), np.asarray(verdict, float)
            for key, b in (("arm_share_rot", slice(0, 3)), ("arm_share", slice(3, 6))):
                c[key] = float(np.trace(arm[b, b]) / max(np.trace(full[b, b]), 1e-300))
    else:
        m["sigma_trans_mm"] = m["sigma_rot_deg"] = None
    for k in ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"):
        c[f"{k}_missing"] = (
            "no covariance: the joint refinement did not run" if res.get("status") == "ok" else "no result"
        )
        c[f"{k}_missing_action"] = "run handeye calibrate without --no-refine to get the uncertainty"
    # motion of the used views, judged as the pipeline judges it
    Ts = [T for v in sorted(used_ids, key=view_id_key) if v in fits and (T := fits[v].T_base_end) is not None]
    frame = mounting.fixed_frame  # the frame the motions' rotation axes are expressed in
    c["axis_frame"] = frame
    c["rotvecs"] = np.zeros((0, 3))
    mo = res.get("motion") or {}
    if len(Ts) >= 3:
        M = robot_motions(np.stack(Ts), mounting)
        mq = motion_quality(M, frame=frame)
        c["rotvecs"] = relative_rotvecs(M)
        c["main_axis"] = axis_text(mq.main_axis, frame)
        c["weak_axes"] = f"{axis_text(mq.weak_axes[1], frame)} and {axis_text(mq.weak_axes[0], frame)}"
        m["max_rotation_deg"], m["axis_spread_deg"] = mq.max_rotation_deg, mq.axis_spread_deg
    elif mo:
        m["max_rotation_deg"], m["axis_spread_deg"] = mo.get("max_rotation_deg"), mo.get("axis_spread_deg")
    else:
        m["max_rotation_deg"] = m["axis_spread_deg"] = None
    # views
    n_total = len(views)
    # each view once: dropped or its robot pose excluded (not a pose line whose image was deleted)
    bad = [v for v in views if v.get("flagged")]
    if n_total:
        m["dropped_share"] = len(bad) / n_total
    c["n_bad"], c["n_total"] = len(bad), n_total
    by_reason: dict[str, list] = {}
    for v in bad:
        by_reason.setdefault(v["reason_kind"], []).append(v["id"])
    items = [f"{k} (view{'s' if len(ids) > 1 else ''} {', '.join(ids)})" for k, ids in by_reason.items()]
    c["bad_reasons"] = "; ".join(items[:3]) + (f"; and {len(items) - 3} more" if len(items) > 3 else "")
    m["used_views"] = float(len(used_ids)) if n_total else None
    prior: dict = res["prior"] if isinstance(res.get("prior"), dict) else {}
    n_prior = prior.get("prior_views")
    if n_total and prior.get("used") == "prior" and isinstance(n_prior, (int, float)) and n_prior > 0:
        # --prior that the data agree with: X rests on the new views and the earlier ones behind the prior
        m["used_views"] = float(len(used_ids) + n_prior)
        c["used_views_source"] = (
            f"{len(used_ids)} new views + {n_prior:.0f} of the prior "
            f"({prior.get('source', 'the earlier result')}) the new views agree with"
        )
    # coverage
    pts = [fits[v].image_points_px for v in fits if v in used_ids or not used_ids]
    if image_size and pts:
        counts = coverage_counts(
            np.concatenate(pts), width=int(image_size[0]), height=int(image_size[1]), cells_x=coverage_cells_x
        )
        m["image_coverage"] = float((counts > 0).mean())
        c["coverage_counts"] = counts
    else:
        m["image_coverage"] = None
        c["image_coverage_missing"] = "no detected corners"
    if is_tracked(res.get("target")):  # a pose-only session: no corners, no pixel checks
        for k in ("reprojection_rms_px", "image_coverage"):
            m.pop(k, None)
    return m, c
