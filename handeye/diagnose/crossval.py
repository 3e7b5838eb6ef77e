"""Cross-validation of the hand-eye result by held-out views.

Leave-one-out, or interleaved k-fold above a view count. With a refinement each fold is one Gaussian
solve (:func:`handeye.refine.refit`) with the full run's noise levels and outlier decisions held, and
a validated run's refits are reused; without one, each fold is the closed-form method. The folds'
jackknife spread is judged against the model sigmas and against the verdict sigmas, so the
diagnostics and the printed sigmas never disagree.

See docs/uncertainty.md.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..camera import pixels_from_board_points
from ..frames import pose_error, rotvec_from_R
from ..mounting import mounting
from ..stats import chi2_ppf
from .geometry import jackknife_sigmas
from .thresholds import thresholds

log = logging.getLogger(__name__)


def x_delta(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(rot about the camera axes [deg] (3), translation along the parent axes [mm] (3)) of T vs T_ref.

    (rot about the camera axes [deg] (3), translation along the parent axes [mm] (3)) of T vs T_ref,
    in the parametrisation of the refinement's sigmas (T = T_ref Exp(omega), t - t_ref).
    """
    om = rotvec_from_R(T_ref[:3, :3].T @ T[:3, :3])
    return np.concatenate([np.degrees(om), 1e3 * (T[:3, 3] - T_ref[:3, 3])])


def _refined(run):
    ref = run.refined
    return ref if (ref is not None and getattr(ref, "status", "") == "ok") else None


def cv_view_ids(run) -> list:
    """Views that take part: with a board pose, and used by the refinement when it ran."""
    ids = [v.view_id for v in run.session.views if v.view_id in (run.board_poses or {})]
    ref = _refined(run)
    if ref is not None:
        pv = getattr(ref, "per_view", {}) or {}
        ids = [v for v in ids if pv.get(v, {}).get("status", "used") == "used"]
    return ids


def folds(n: int, *, refined: bool) -> list:
    t = thresholds().cross_validation
    loo_max, k = (t.loo_max_views_refined, t.folds_refined) if refined else (t.loo_max_views, t.folds)
    if n <= loo_max:
        return [np.array([i]) for i in range(n)]
    return [np.arange(f, n, k) for f in range(k)]


def _refined_folds(run, ref, ids, fold_list, T_rep):
    """(estimates per fold: (T_x, T_board, intrinsics) or None, method text): one solve per fold.

    (estimates per fold: (T_x, T_board, intrinsics) or None, method text): one solve per fold
    (:func:`handeye.refine.refit`: the full run's noise levels and outlier decisions held).
    """
    from ..refine import RefineView, refit

    obj = run.session.target.object_points()
    views = [RefineView(v, run.board_poses[v].corner_ids, run.detections[v].image_points, T_rep[v]) for v in ids]
    estimates = []
    for f in fold_list:
        out = set(f.tolist())
        fit = refit(ref, object_points=obj, views=[views[k] for k in range(len(views)) if k not in out])
        estimates.append((fit.T_x, fit.T_board, fit.intrinsics) if fit.status == "ok" else None)
    method = (
        f"refinement refitted per fold (one solve from the full solution, noise held at the full run's "
        f"{ref.robot_sigma_mm:.3f} mm / {ref.robot_sigma_deg:.4f} deg robot, {ref.sigma_px:.3f} px)"
    )
    return estimates, method


def _closed_form_folds(run, ids, fold_list, T_rep):
    from ..errors import HandeyeError
    from ..initial import solve_closed_form

    mount = mounting(run.session.mode)
    C = np.stack([run.board_poses[v].T_cam_board for v in ids])
    M = mount.M_from_T_base_end(np.stack([T_rep[v] for v in ids]))
    meth = run.options.method
    estimates = []
    for f in fold_list:
        keep = np.ones(len(ids), bool)
        keep[f] = False
        try:
            e = solve_closed_form(mount, C[keep], M[keep], method=meth)
        except (HandeyeError, np.linalg.LinAlgError) as ex:  # a degenerate fold is reported, not fatal
            log.info("cross-validation fold not solved: %s", ex)
            e = None
        estimates.append(None if e is None or e.status != "ok" else (e.T_x, e.T_board, run.intrinsics))
    return estimates, f"closed-form {meth} refitted per fold"


def cross_validate(run) -> dict:
    """Leave-one-out / k-fold cross-validation of the hand-eye result (see the module docstring)."""
    if run.T_x is None or not run.board_poses:
        return {"summary": "not run: no hand-eye result"}
    t = thresholds().cross_validation
    s = run.session
    mount = mounting(s.mode)
    ids = cv_view_ids(run)
    n = len(ids)
    if n < t.min_views:
        return {"summary": f"not run: {n} usable views (needs {t.min_views})", "n_views": n}
    ref = _refined(run)
    val = getattr(run, "validation", None) if ref is not None else None
    if val is not None and val.refits:  # the validation's folds: the views are solved once
        ids = list(val.view_ids)
        n = len(ids)
        fold_list = [np.array([ids.index(v) for v in f]) for f in val.folds]
    else:
        val = None
        fold_list = folds(n, refined=ref is not None)
    T_rep = {v: s.view(v).T_base_end for v in ids}
    if val is not None:
        estimates = [(r.T_x, r.T_board, r.intrinsics) if r.status == "ok" else None for r in val.refits]
        held = (
            f"the tracker's {ref.tracker_sigma_mm:.3f} mm / {ref.tracker_sigma_deg:.4f} deg"
            if s.meta.get("pose_only")
            else f"the full run's {ref.robot_sigma_mm:.3f} mm / {ref.robot_sigma_deg:.4f} deg robot, "
            f"{ref.sigma_px:.3f} px"
        )
        method = (
            "refinement refitted per fold (the validation's folds: one solve from the full solution, "
            f"noise held at {held})"
        )
        T_full, B_full, intr_full = ref.T_x, ref.T_board, ref.intrinsics
    elif ref is not None:
        estimates, method = _refined_folds(run, ref, ids, fold_list, T_rep)
        T_full, B_full, intr_full = ref.T_x, ref.T_board, ref.intrinsics
    else:
        estimates, method = _closed_form_folds(run, ids, fold_list, T_rep)
        T_full, B_full, intr_full = run.T_x, run.T_board, run.intrinsics
    ok = [k for k, e in enumerate(estimates) if e is not None]
    if len(ok) < max(3, len(fold_list) // 2):
        return {"summary": f"not run: only {len(ok)} of {len(fold_list)} folds could be solved", "method": method}
    deltas = np.stack([x_delta(T_full, estimates[k][0]) for k in ok])  # type: ignore[index]  # ok: solved folds
    jk = jackknife_sigmas(deltas)
    pose_only = bool(s.meta.get("pose_only"))
    rows = [
        _held_out_row(run, mount, estimates[k], (T_full, B_full, intr_full), ids[i], T_rep[ids[i]], deltas[row])  # type: ignore[arg-type]  # ok: solved folds
        for row, k in enumerate(ok)
        for i in fold_list[k]
    ]
    loo = all(len(f) == 1 for f in fold_list)
    out: dict[str, Any] = {
        "method": method,
        "scheme": "leave-one-out" if loo else f"{len(fold_list)}-fold (interleaved)",
        "n_views": n,
        "n_folds": len(fold_list),
        "folds_solved": len(ok),
        "jackknife_sigma_rot_deg": [round(float(x), 5) for x in jk[:3]],
        "jackknife_sigma_trans_mm": [round(float(x), 4) for x in jk[3:]],
        "axes": f"rotation about the camera axes, translation of {mount.x_name} along the {mount.fixed_frame} axes",
        "per_view": rows,
    }
    if pose_only:
        out["held_out_trans_mm_median"] = round(float(np.median([r["held_out_trans_mm"] for r in rows])), 3)
        out["held_out_rot_deg_median"] = round(float(np.median([r["held_out_rot_deg"] for r in rows])), 4)
    else:
        out["held_out_rms_px_median"] = round(float(np.median([r["held_out_rms_px"] for r in rows])), 3)
    if ref is None:
        out["verdict"] = "no_prediction"
        out["summary"] = (
            f"the closed-form result moves by {float(np.sqrt(np.sum(jk[3:] ** 2))):.2f} mm / "
            f"{float(np.sqrt(np.sum(jk[:3] ** 2))):.3f} deg (jackknife 1 sigma); no covariance to "
            "compare with (refinement not run)"
        )
        return out
    pr, pt = np.asarray(ref.sigma_rot_deg, float), np.asarray(ref.sigma_trans_mm, float)
    out["predicted_sigma_rot_deg"] = [round(float(x), 5) for x in pr]
    out["predicted_sigma_trans_mm"] = [round(float(x), 4) for x in pt]
    rr, rt = _ratio(jk[:3], pr), _ratio(jk[3:], pt)
    out["ratio_rot"], out["ratio_trans"] = round(rr, 3), round(rt, 3)
    lo, hi = ratio_limits(len(ok))
    out["ratio_limits"] = [round(lo, 3), round(hi, 3)]
    out["ratio_limits_meaning"] = (
        f"the {1 - 2 * validation_alpha():.0%} range of this ratio when the model "
        f"covariance is right: sqrt(chi2({len(ok) - 1}) / {len(ok) - 1}) at alpha {validation_alpha():g} "
        "each side"
    )
    covered = None
    exceeds = max(rr, rt) > hi
    if val is not None and val.status == "ok":
        from ..refine.covariance import hand_eye_uncertainty

        vu = hand_eye_uncertainty(val.x.cov_verdict, ref.T_x, ref.working_distance_m)
        out["verdict_sigma_rot_deg"] = [round(float(x), 5) for x in vu.sigma_rot_deg]
        out["verdict_sigma_trans_mm"] = [round(float(x), 4) for x in vu.sigma_trans_mm]
        vr, vt = _ratio(jk[:3], vu.sigma_rot_deg), _ratio(jk[3:], vu.sigma_trans_mm)
        out["ratio_rot_verdict"], out["ratio_trans_verdict"] = round(vr, 3), round(vt, 3)
        covered = max(vr, vt) <= hi
        # one test decides, the validation's on all six directions at once (it also decides the verdict covariance)
        exceeds = bool(val.x.finding)
        out["spread_p_value"] = float(val.x.p_value)
    out["covered_by_verdict"] = covered
    size = (
        f"rotation {rr:.2f}x, translation {rt:.2f}x the model's sigma; {lo:.2f}-{hi:.2f}x is sampling noise "
        f"with {len(ok)} folds that inform the result equally"
    )
    if exceeds:
        out["verdict"] = "spread_exceeds_prediction"
        test = f"; p = {out['spread_p_value']:.2g} over the six directions" if "spread_p_value" in out else ""
        out["summary"] = (
            f"the result moves {max(rr, rt):.1f}x more between folds than the model covariance predicts "
            f"({size}{test}): the model misses an error source (robot pose errors that are not "
            "independent per view, correlated detector errors, a moved board, timing)"
        )
        out["summary"] += (
            "; the printed sigmas and the verdict use the validated covariance, which covers it"
            if covered
            else "; trust the spread, not the covariance"
        )
    elif min(rr, rt) < lo:
        out["verdict"] = "spread_below_prediction"
        out["summary"] = f"the result moves less between folds than the model predicts ({size}): it is conservative"
    elif max(rr, rt) > hi:  # above the equal-information range, yet each fold moves as the model predicts for it
        out["verdict"] = "consistent"
        out["summary"] = (
            f"the result moves {max(rr, rt):.1f}x the model's sigma between folds ({size}), but each "
            f"fold moves as the model predicts for that fold (p = {out['spread_p_value']:.2g} over the six "
            "directions, within chance): the views inform the result unequally, which widens the plain "
            "spread; the model's covariance stands"
        )
    else:
        out["verdict"] = "consistent"
        test = (
            f"; p = {out['spread_p_value']:.2g} over the six directions, within chance"
            if "spread_p_value" in out
            else ""
        )
        out["summary"] = f"the spread between folds matches the model's uncertainty ({size}{test})"
    return out


def _held_out_row(run, mount, fold_fit: tuple, full_fit: tuple, v: str, T_base_end: np.ndarray, dx: np.ndarray) -> dict:
    """One held-out view: its residual under the fold's fit and under the full one, and the fold's shift of X.

    Image views: RMS reprojection error in pixels; pose-only views: the tracker's pose against the
    chain's prediction (rotation in deg, translation in mm).
    """
    bp = run.board_poses[v]
    row: dict = {"view": v}
    if run.session.meta.get("pose_only"):
        for key, (T_x, T_b, _) in (("held_out", fold_fit), ("in_sample", full_fit)):
            rot, trans = pose_error(mount.predict_T_cam_board(T_x, T_b, T_base_end), bp.T_cam_board)
            row[f"{key}_rot_deg"], row[f"{key}_trans_mm"] = round(float(rot), 4), round(float(trans), 3)
    else:
        obj = run.session.target.object_points()[bp.corner_ids]
        img = run.detections[v].image_points
        for key, (T_x, T_b, intr) in (("held_out", fold_fit), ("in_sample", full_fit)):
            px = pixels_from_board_points(mount.predict_T_cam_board(T_x, T_b, T_base_end), obj, intr) - img
            row[f"{key}_rms_px"] = round(float(np.sqrt(np.mean(np.sum(px**2, axis=1)))), 3)
    row["x_shift_deg"] = round(float(np.linalg.norm(dx[:3])), 4)
    row["x_shift_mm"] = round(float(np.linalg.norm(dx[3:])), 3)
    return row


def _ratio(spread: np.ndarray, sigma: np.ndarray) -> float:
    """RMS of the spread over RMS of the sigma (3 axes)."""
    return float(np.sqrt(np.mean(np.square(spread))) / max(np.sqrt(np.mean(np.square(sigma))), 1e-12))


def validation_alpha() -> float:
    from ..refine.validation import settings

    return float(settings()["alpha"])


def ratio_limits(k_folds: int) -> tuple[float, float]:
    """(low, high): the two-sided range, at ``validation.alpha`` each side.

    (low, high): the two-sided range, at ``validation.alpha`` each side, of a jackknife sigma over the
    true sigma from ``k_folds`` folds, ``sqrt(chi2(K - 1) / (K - 1))`` (K - 1 degrees of freedom: the
    three axes of a block are not independent, so no more are counted).
    """
    a, dof = validation_alpha(), max(int(k_folds) - 1, 1)
    return float(np.sqrt(chi2_ppf(a, dof) / dof)), float(np.sqrt(chi2_ppf(1.0 - a, dof) / dof))
