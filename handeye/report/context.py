"""Everything the templates show, computed from a result folder (plain values, no HTML here).

Every key of result.json is optional except ``status`` and ``mode``: partial results (failed runs,
``--no-refine``, results written before the refinement or diagnostics existed) still build.
"""

from __future__ import annotations

import datetime as _dt
import re
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from .. import __version__
from ..conventions import pose_forms, vendor_euler_from_R
from ..frames import quat_wxyz_from_R
from ..mounting import EYE_IN_HAND, MODES, mounting
from ..output import plain
from ..records import IMAGE_MISSING_REASON
from ..stats import chi2_ppf
from .advice import STAGE_CHECKS, failure_advice, finding_advice, root_cause, untrusted_metrics
from .folder import ResultFolder
from .metrics import qa_metrics
from .observations import as_cov6, as_T, board_disagreement, finite, median_board_distance_m, view_fits
from .qa import STATUS_ORDER, Verdict, evaluate
from .uncertainty import Z95, form_sigmas, predicted_point_error

SEVERITY_ORDER = {"fail": 0, "warn": 1, "info": 2}
#: what a refinement outlier of each kind means for its view (the reason text itself is shown as is)
OUTLIER_KIND_TEXT = {
    "robot_pose": "robot pose disagrees with the camera",
    "reprojection": "corners do not fit",
    "too_few_corners": "too few usable corners",
    "corners": "outlier corners",
}


def build_context(folder: ResultFolder, *, qa_cfg: dict, qa_source: str, make_plots: bool = True) -> dict[str, Any]:
    res, obs = folder.result or {}, folder.observations or {}
    mode_known = res.get("mode") in MODES
    mount = mounting(res["mode"]) if mode_known else EYE_IN_HAND  # an unknown mode is shown as such
    x_name, b_name = mount.x_name, mount.board_name
    parent, board_parent = mount.fixed_frame, mount.board_frame
    ok = res.get("status") == "ok"
    ref = res.get("refinement") if isinstance(res.get("refinement"), dict) else {}
    if ref and ref.get("status") not in (None, "ok"):
        ref = {}
    diag = res.get("diagnostics") if isinstance(res.get("diagnostics"), dict) else {}
    T_x = as_T(res.get(x_name)) if ok else None
    T_board = as_T(res.get(b_name)) if ok else None
    # the verdict covariance when the result has one (the model's or the validated, as the validation found), else
    # the model's
    cov = (
        (
            as_cov6(ref.get("cov_x_6x6_verdict"))
            if ref.get("cov_x_6x6_verdict") is not None
            else as_cov6(ref.get("cov_x_6x6"))
        )
        if ref
        else None
    )
    intr = res.get("intrinsics") or ref.get("intrinsics")
    obj = np.asarray(obs.get("object_points_m") or [], float).reshape(-1, 3)
    board_centre = obj.mean(axis=0) if len(obj) else np.zeros(3)
    fits = view_fits(obs)
    image_size = (intr or {}).get("image_size") or obs.get("image_size")

    wd_cfg = qa_cfg.get("working_distance_m")
    wd = float(wd_cfg) if wd_cfg is not None else _num(ref.get("working_distance_m"))
    if not finite(wd):
        wd = median_board_distance_m(fits, board_centre)

    ctx: dict[str, Any] = {
        "x_name": x_name,
        "board_name": b_name,
        "parent": parent,
        "mode": mount.name,
        "mode_text": _mode_text(mount) if mode_known else "Mounting mode unknown",
        "ok": ok,
        "refined": bool(ref),
    }
    ctx["meta"] = _meta(res, obs)
    findings = _findings(diag)
    stages = _stages(diag)
    views = _view_rows(res, ref, fits, board_centre, findings, image_size)
    ctx["views"] = views
    ctx["n_used"] = sum(v["status"] == "used" for v in views)
    ctx["n_total"] = len(views)

    # --- result forms and uncertainty
    unc = form_sigmas(T_x, cov) if T_x is not None and cov is not None else None
    pred = (
        predicted_point_error(T_x, cov, working_distance_m=wd)
        if T_x is not None and cov is not None and finite(wd)
        else None
    )
    ctx["result"] = (
        _result_block(res, T_x, T_board, unc, pred, wd, x_name, b_name, parent, board_parent)
        if T_x is not None
        else None
    )
    ctx["uncertainty"] = _uncertainty_block(ref, unc, parent) if unc is not None else None
    ctx["methods"] = _methods(res, T_x, x_name)
    ctx["prior"] = _prior_block(res, x_name)
    ctx["offsets"] = _offsets(res, ref, T_x, cov, x_name)
    ctx["intrinsics"] = _intrinsics_rows(
        intr,
        (ref.get("intrinsics_sigma_verdict") or ref.get("intrinsics_sigma")) if ref else None,
        res,
        model_sigma=ref.get("intrinsics_sigma") if ref else None,
    )
    ctx["noise"] = _noise(ref)
    ctx["robot_model"] = _robot_model(ref)

    # --- metrics and verdict
    metrics, notes = qa_metrics(
        res,
        ref,
        fits,
        views,
        unc,
        pred,
        wd,
        image_size,
        mount,
        coverage_cells_x=int(qa_cfg.get("coverage_grid_cells_x", 16)),
    )
    failure = failure_advice(res, findings, has_views=bool(views)) if not ok else None
    notes["x_name"] = x_name
    cause = root_cause(res, findings)
    if cause:
        notes["root_cause"] = cause
    untrusted = untrusted_metrics(findings)
    if any(f["severity"] == "fail" for f in findings):  # those checks are shown untrusted: the headline skips them
        notes["headline_skips"] = tuple(untrusted)
    if pred is not None and "predicted_error_mm" not in untrusted:  # the headline repeats it
        notes["predicted_text"] = f"{pred['rms_mm']:.2f} mm (1 σ) at {wd:.2f} m"
    verdict = evaluate(
        metrics,
        qa_cfg,
        context=notes,
        failure=failure,
        findings=findings,
        crashed_stages=stages["crashed"],
        thresholds_source=qa_source,
    )
    verdict = _distrust(verdict, untrusted, fail_finding=any(f["severity"] == "fail" for f in findings))
    ctx["verdict"] = verdict
    ctx["untrusted"] = untrusted
    ctx["failure"] = failure
    ctx["root_cause"] = cause
    ctx["verdict_label"] = "REFUSED" if cause and cause["refused"] else verdict.label
    ctx["findings"] = findings
    ctx["stages"] = stages
    ctx["cross_validation"] = _cross_validation(diag.get("cross_validation"))
    ctx["kpis"] = _kpis(metrics, pred, wd, views, verdict, ok, untrusted)
    ctx["motion"] = res.get("motion")
    ctx["provenance"] = _provenance(res, qa_cfg, qa_source)
    ctx["plots"] = []
    ctx["figure_inputs"] = dict(
        res=res,
        obs=obs,
        ref=ref,
        fits=fits,
        views=views,
        T_x=T_x,
        T_board=T_board,
        unc=unc,
        metrics=metrics,
        notes=notes,
        qa_cfg=qa_cfg,
        mounting=mount,
        image_size=image_size,
    )
    if make_plots:
        add_figures(ctx)
    ctx["thumbs"] = {v["id"]: folder.thumbnails[v["id"]] for v in views if v["id"] in folder.thumbnails}
    for v in views:
        v["has_thumb"] = v["id"] in ctx["thumbs"]
    return ctx


def add_figures(ctx: dict) -> dict:
    """The report's figures (``ctx["plots"]``) for a context built without them: the context is built
    once, judged, and drawn only when a report is written.
    """
    from .figures import report_figures

    ctx["plots"] = report_figures(**ctx["figure_inputs"])
    return ctx


def _mode_text(mount) -> str:
    """``Eye-in-hand (camera on the robot's flange, board on the table)``."""
    return f"{mount.name.replace('_', '-').capitalize()} (camera {mount.camera_location}, board {mount.board_location})"


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


# ------------------------------------------------------------------------------ meta
def _target_text(t: dict | None) -> str:
    if not t:
        return ""
    kind = t.get("type") or t.get("kind")
    sq = t.get("square_m")
    if kind == "chessboard":
        ic = t.get("inner_corners") or [t.get("cols"), t.get("rows")]
        return f"chessboard, {ic[0]}×{ic[1]} inner corners, {sq * 1e3:g} mm squares" if sq else "chessboard"
    if kind == "charuco":
        s = t.get("squares") or ["?", "?"]
        m = t.get("marker_m")
        extra = f", markers {m * 1e3:g} mm" if m else ""
        return f"ChArUco {s[0]}×{s[1]} squares of {sq * 1e3:g} mm{extra}, {t.get('dictionary', '')}".rstrip(", ")
    return str(kind or "")


def _meta(res: dict, obs: dict) -> dict:
    prov = res.get("provenance") or {}
    sess = res.get("session") or {}
    path = sess.get("path") or ""
    nv = res.get("n_views") or {}
    size = (res.get("intrinsics") or {}).get("image_size") or obs.get("image_size")
    return {
        "session_name": Path(path).name if path else "session",
        "session_path": path,
        "session_format": sess.get("format", ""),
        "pose_format": sess.get("pose_format", ""),
        "target": _target_text(res.get("target") or obs.get("target")),
        "calibrated_utc": prov.get("time_utc", ""),
        "generated_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "method": res.get("method", ""),
        "refined": bool(res.get("refined")),
        "n_total": nv.get("total", len(res.get("views") or [])),
        "n_used": nv.get("used"),
        "image_size": f"{size[0]}×{size[1]} px" if size else "",
        "handeye_version": prov.get("handeye_version", ""),
        "report_version": __version__,
        "status": res.get("status", "unknown"),
    }


# ------------------------------------------------------------------------------ views
def _strip_view_prefix(text: str) -> str:
    """``view 7: reported robot pose ...`` -> ``reported robot pose ...`` (the row already names the view)."""
    return re.sub(r"^(outlier: )?view \S+: ", r"\1", str(text or ""))


def _view_rows(res, ref, fits, centre, findings, image_size) -> list[dict]:
    per_view = (ref or {}).get("per_view") or {}
    outl: dict[str, list] = {}
    for o in (ref or {}).get("outliers") or []:
        outl.setdefault(str(o.get("view_id")), []).append(o)
    finding_by_view: dict[str, list] = {}
    for f in findings:
        for vid in f["view_ids"]:
            finding_by_view.setdefault(vid, []).append(f)
    flagged_corners: dict[str, set] = {}
    for o in (ref or {}).get("outliers") or []:
        if o.get("corner_ids"):
            flagged_corners.setdefault(str(o.get("view_id")), set()).update(int(c) for c in o["corner_ids"])
    rows = []
    for v in res.get("views") or []:
        vid = str(v.get("id"))
        fit = fits.get(vid)
        pv = per_view.get(vid, {})
        kinds = [str(o.get("kind", "")) for o in outl.get(vid, [])]
        flags: list[dict] = []
        if not v.get("used", False):
            status = "flagged" if kinds or vid in per_view else "dropped"
            kind = next((OUTLIER_KIND_TEXT.get(k, k) for k in kinds if k), "")
            reason_kind = kind or (
                "image missing"
                if str(v.get("reason") or "").startswith(IMAGE_MISSING_REASON)
                else "target not found"
                if fit is None
                else "not used"
            )
            flags.append({"severity": "fail", "text": _strip_view_prefix(v.get("reason") or "not used")})
        elif pv.get("status") == "robot_excluded":
            status, reason_kind = "flagged", OUTLIER_KIND_TEXT["robot_pose"]
        elif v.get("flags") or outl.get(vid):  # used, with flagged corners
            status, reason_kind = "used", OUTLIER_KIND_TEXT["corners"]
        else:
            status, reason_kind = "used", ""
        for o in outl.get(vid, []):
            text = _strip_view_prefix(o.get("reason", ""))
            if any(text in f["text"] for f in flags):
                continue
            kind = o.get("kind")
            sev = "info" if kind == "corners" else ("warn" if kind == "robot_pose" else "fail")
            flags.append({"severity": sev, "text": text})
        by_reason: dict[str, list] = {}
        for c in v.get("corners_dropped") or []:  # found by the detector, not used (result.json)
            by_reason.setdefault(str(c.get("reason", "")), []).append(str(c.get("corner_id")))
        for why, ids in by_reason.items():
            flags.append(
                {"severity": "info", "text": f"detector left out corner{'s' * (len(ids) > 1)} {', '.join(ids)}: {why}"}
            )
        for f in finding_by_view.get(vid, []):
            flags.append({"severity": f["severity"], "text": f["title"] + (f" ({f['code']})" if f["code"] else "")})
        rms = fit.rms_px if fit else _num(pv.get("rms_px", v.get("pnp_rms_px")))
        mx = fit.max_px if fit else _num(pv.get("max_px"))
        chain = fit.chain_rms_px if fit else float("nan")
        if "robot_vs_camera_trans_mm" in pv:
            rc_mm, rc_deg = _num(pv.get("robot_vs_camera_trans_mm")), _num(pv.get("robot_vs_camera_rot_deg"))
            maha = _num(pv.get("robot_vs_camera_mahalanobis"))
        elif fit is not None:
            rc_deg, rc_mm = board_disagreement(fit, centre)
            maha = float("nan")
        else:
            rc_deg = rc_mm = maha = float("nan")
        corners = []
        if fit is not None and image_size:
            bad = flagged_corners.get(vid, set())
            corners = [
                (round(float(u), 1), round(float(w), 1), int(c) in bad)
                for c, (u, w) in zip(fit.corner_ids, fit.image_points_px, strict=False)
            ]
        # flagged: in the dropped/flagged share once, dropped or its robot pose excluded (it did not serve X);
        # a used view with a few outlier corners is listed (corner_flags), not counted: its pose served X
        # (a pose line whose image was deleted is listed as dropped, not counted: nothing was captured badly)
        flagged = status != "used" and reason_kind != "image missing"
        corner_flags = status == "used" and (bool(v.get("flags")) or vid in outl)
        rows.append(
            {
                "id": vid,
                "image": v.get("image") or "",
                "status": status,
                "reason_kind": reason_kind,
                "flagged": flagged,
                "corner_flags": corner_flags,
                "n_corners": v.get("n_corners") or (len(fit.corner_ids) if fit else 0),
                "rms_px": rms,
                "max_px": mx,
                "chain_rms_px": chain,
                "robot_mm": rc_mm,
                "robot_deg": rc_deg,
                "robot_maha": maha,
                "flags": flags,
                "corners": corners,
                "image_size": list(image_size) if image_size else None,
            }
        )
    return rows


# ------------------------------------------------------------------------------ result
def matrix_text(T: np.ndarray) -> str:
    """A 4x4 as aligned plain text (ASCII minus, so that it can be copied)."""
    return "\n".join("   ".join(f"{x:+.6f}" for x in row) for row in np.asarray(T, float))


def _result_block(res, T_x, T_board, unc, pred, wd, x_name, b_name, parent, board_parent) -> dict:
    f = pose_forms(T_x)
    q = quat_wxyz_from_R(T_x[:3, :3])
    rows = []

    def add(group, comp, unit, val, sig, digits):
        lo = hi = None
        if sig is not None and np.isfinite(sig):
            lo, hi = val - Z95 * sig, val + Z95 * sig
        rows.append(
            {
                "group": group,
                "comp": comp,
                "unit": unit,
                "value": val,
                "sigma": sig,
                "lo": lo,
                "hi": hi,
                "digits": digits,
            }
        )

    t = T_x[:3, 3] * 1e3
    for k, c in enumerate("xyz"):
        add(f"Translation ({parent} frame)", c, "mm", t[k], unc["translation_mm"][k] if unc else None, 2)
    for k, c in enumerate("wxyz"):
        add("Quaternion (w, x, y, z)", c, "", q[k], unc["quaternion_wxyz"][k] if unc else None, 6)
    rv = np.asarray(f["rotvec_deg"], float)
    for k, c in enumerate("xyz"):
        add("Rotation vector (axis × angle)", c, "deg", rv[k], unc["rotvec_deg"][k] if unc else None, 3)
    eu = np.asarray(f["euler_vendor_deg"], float)
    for k, c in enumerate(("rx", "ry", "rz")):
        add("Euler, R = Rz·Ry·Rx (extrinsic x-y-z)", c, "deg", eu[k], unc["euler_vendor_deg"][k] if unc else None, 3)
    out = {
        "name": x_name,
        # the frame's words without result.json's equation: the line below the name states it once
        "meaning": re.sub(r";\s*p_\w+ = \w+ @ p_\w+\.?$", "", str((res.get("frames") or {}).get(x_name, ""))),
        "equation": f"p_{parent} = {x_name} · p_cam",
        "child": "cam",
        "parent": parent,
        "matrix_text": matrix_text(T_x),
        "translation_mm": t.tolist(),
        "quaternion_wxyz": q.tolist(),
        "euler_deg": eu.tolist(),
        "rows": rows,
        "rotvec_rad": list(map(float, f["rotvec_rad"])),
        "vendor_line": f["vendor_pose_line"],
        "quaternion_xyzw": [q[1], q[2], q[3], q[0]],
        "pred": pred,
        "working_distance_m": wd,
        "has_sigma": unc is not None,
    }
    if T_board is not None:
        bf = pose_forms(T_board)
        out["board"] = {
            "name": b_name,
            "meaning": (res.get("frames") or {}).get(b_name, ""),
            "equation": f"p_{board_parent} = {b_name} · p_board",
            "matrix_text": matrix_text(T_board),
            "translation_mm": bf["translation_mm"],
            "euler_deg": bf["euler_vendor_deg"],
            "vendor_line": bf["vendor_pose_line"],
        }
    return out


def _change_rows(d: dict) -> list[dict]:
    """Per axis a change of X with its 1-sigma (a ``prior`` block's update or change)."""
    keys = ("d_trans_mm", "sigma_trans_mm", "d_rot_deg", "sigma_rot_deg")
    vals = [np.asarray(d.get(k) if d.get(k) is not None else [np.nan] * 3, float).reshape(-1)[:3] for k in keys]
    return [{"axis": ax, **{k: float(v[i]) for k, v in zip(keys, vals, strict=False)}} for i, ax in enumerate("xyz")]


def _prior_block(res, x_name) -> Optional[dict]:
    """A ``calibrate --prior`` run (result.json's ``prior``): the earlier result used as the prior (source, X,
    sigmas), the update the new views made to it, whether they contradict it and which the result is.
    """
    p = res.get("prior")
    if not isinstance(p, dict):
        return None
    T0 = as_T(p.get(p.get("frame") or x_name))
    f = pose_forms(T0) if T0 is not None else None
    test, upd, change = p.get("test") or {}, p.get("update") or {}, p.get("change") or {}
    return {
        "source": p.get("source", ""),
        "frame": p.get("frame") or x_name,
        "covariance_used": p.get("covariance_used", ""),
        "intrinsics": p.get("intrinsics", ""),
        "translation_mm": f["translation_mm"] if f else None,
        "euler_deg": f["euler_vendor_deg"] if f else None,
        "sigma_trans_mm": p.get("sigma_trans_mm"),
        "sigma_rot_deg": p.get("sigma_rot_deg"),
        "update_rows": _change_rows(upd) if upd else None,
        "test": test or None,
        "alpha": p.get("alpha"),
        "contradicted": bool(p.get("contradicted")),
        "tested": p.get("tested", True) is not False,
        "used": p.get("used", ""),
        "summary": p.get("summary", ""),
        "change_rows": _change_rows(change) if change else None,
    }


SIGMA_SOURCE_TEXT = {
    "validated": "the validated covariance (the spread of the result over refits without some views), which "
    "exceeds the model's in every direction",
    "model+validated": "the larger of the model's and the validated covariance (the spread over refits without "
    "some views) in each direction",
    "model": "the refinement's model covariance (the refits without some views spread no more than it predicts, "
    "or by no more than chance)",
}


def _uncertainty_block(ref, unc, parent) -> dict:
    corr = ref.get("correlation_6x6")
    src = ref.get("sigma_source")
    val = ref.get("validation") if isinstance(ref.get("validation"), dict) else {}
    rows = []
    for label, r, t in (
        ("model (refinement)", ref.get("sigma_rot_deg_model"), ref.get("sigma_trans_mm_model")),
        (
            "validated (the folds' spread, shrunk toward the model scaled to it)",
            ref.get("sigma_rot_deg_validated"),
            ref.get("sigma_trans_mm_validated"),
        ),
    ):
        if r is not None and t is not None:
            rows.append({"name": label, "rot": list(r), "trans": list(t)})
    text = (
        SIGMA_SOURCE_TEXT.get(src, SIGMA_SOURCE_TEXT["model"])
        if val.get("status") == "ok"
        else "the refinement's model covariance (not validated"
        + (f": {val['summary']})" if val.get("summary") else ")")
    )
    return {
        "source": src,
        "source_text": text,
        "rule": ref.get("sigma_rule", ""),
        "other_rows": rows,
        "validation_summary": val.get("summary"),
        "sigma_trans_mm": list(unc["translation_mm"]),
        "sigma_rot_deg": list(unc["rot_cam_deg"]),
        "trans_axes": ref.get("sigma_trans_axes", f"{parent} frame"),
        "rot_axes": ref.get("sigma_rot_axes", "camera frame"),
        "parametrisation": ref.get("cov_parametrisation", ""),
        "corr": np.asarray(corr, float).tolist() if corr is not None else None,
        "corr_names": ["ωx", "ωy", "ωz", "vx", "vy", "vz"],
    }


def _methods(res, T_x, x_name) -> list[dict]:
    rows = []
    ref = res.get("refinement") if isinstance(res.get("refinement"), dict) else {}
    start = ref.get("start_method")  # the closed form the refinement started from, when not the seed
    for m, e in (res.get("closed_form") or {}).items():
        T = as_T(e.get(x_name))
        row = {
            "name": m,
            "status": e.get("status", "?"),
            "reason": e.get("failure_reason", ""),
            "is_seed": m == res.get("method"),
            "is_start": m == start and m != res.get("method"),
            "is_result": False,
            "cons_mm": None,
            "cons_deg": None,
        }
        if T is not None:
            row["t_mm"] = (T[:3, 3] * 1e3).tolist()
            row["euler_deg"] = np.degrees(vendor_euler_from_R(T[:3, :3])).tolist()
            if T_x is not None:
                row["d_deg"], row["d_mm"], _ = _stored_difference(e)
                row["offset_mm"] = ((T[:3, 3] - T_x[:3, 3]) * 1e3).tolist()
            row["cons_mm"], row["cons_deg"] = e.get("board_consistency_mm"), e.get("board_consistency_deg")
        rows.append(row)
    if T_x is not None and res.get("refined"):
        rows.append(
            {
                "name": "joint refinement (result)",
                "status": "ok",
                "reason": "",
                "is_result": True,
                "is_seed": False,
                "is_start": False,
                "cons_mm": None,
                "cons_deg": None,
                "t_mm": (T_x[:3, 3] * 1e3).tolist(),
                "euler_deg": np.degrees(vendor_euler_from_R(T_x[:3, :3])).tolist(),
                "d_deg": 0.0,
                "d_mm": 0.0,
                "offset_mm": [0.0, 0.0, 0.0],
            }
        )
    elif T_x is not None:
        for r in rows:
            if r.get("is_seed"):
                r["is_result"] = True
    return rows


def _intrinsics_rows(intr, sig, res, *, model_sigma=None) -> Optional[dict]:
    """The intrinsics with their (verdict) sigma ``sig`` and the model's ``model_sigma`` beside it."""
    if not intr:
        return None
    sig = sig or {}
    model_sigma = model_sigma or {}
    rows = []
    for k, unit in (("fx", "px"), ("fy", "px"), ("cx", "px"), ("cy", "px")):
        if k in intr:
            rows.append(
                {"name": k, "unit": unit, "value": intr[k], "sigma": sig.get(k), "sigma_model": model_sigma.get(k)}
            )
    d = intr.get("dist") or {}
    if isinstance(d, dict):
        for k in ("k1", "k2", "p1", "p2", "k3"):
            if k in d:
                rows.append(
                    {"name": k, "unit": "", "value": d[k], "sigma": sig.get(k), "sigma_model": model_sigma.get(k)}
                )
    given = res.get("intrinsics") or {}
    ref = res.get("refinement") if isinstance(res.get("refinement"), dict) else {}
    return {
        "rows": rows,
        "source": given.get("source", ""),
        "rms": given.get("calibrate_camera_rms_px"),
        "size": intr.get("image_size"),
        "refined": bool(sig),
        "sigma_source": ref.get("intrinsics_sigma_source") if ref.get("intrinsics_sigma_verdict") else None,
        "sigma_source_text": SIGMA_SOURCE_TEXT.get(ref.get("intrinsics_sigma_source"), ""),
    }


def _stored_difference(e: dict) -> tuple[float, float, float]:
    """(deg, mm, verdict sigmas) of a closed form or a refitted half against the result, as result.json
    stores them (``diff_to_result_deg``, ``_mm``, ``_sigma``; NaN where it does not).
    """
    return _num(e.get("diff_to_result_deg")), _num(e.get("diff_to_result_mm")), _num(e.get("diff_to_result_sigma"))


def _offsets(res, ref, T_x, cov, x_name) -> Optional[dict]:
    """Where the result lies against each closed form and each half of the views (refitted alone), in mm,
    degrees and verdict sigmas, with the sentences that explain a departure.
    """
    from ..config import load_preset
    from .uncertainty import offset_explanation

    if T_x is None or cov is None or not ref:
        return None
    alpha = float(load_preset("diagnostics")["validation"]["offset_alpha"])
    limit = float(np.sqrt(chi2_ppf(1.0 - alpha, 6)))
    rows = []
    for m, e in (res.get("closed_form") or {}).items():
        T = as_T(e.get(x_name))
        if T is not None:
            rows.append({"name": m, "kind": "closed_form", "T": T, "stored": e})
    val = ref.get("validation") if isinstance(ref.get("validation"), dict) else {}
    halves = val.get("halves") or {}
    n_used = sum(len((halves.get(h) or {}).get("used_view_ids") or []) for h in ("odd", "even"))
    for h, which in (("odd", "1st"), ("even", "2nd")):
        T = as_T((halves.get(h) or {}).get(x_name))
        if T is not None:
            ids = [str(v) for v in halves[h].get("used_view_ids") or halves[h].get("view_ids") or []]
            shown = ", ".join(ids[:4]) + (f", …, {ids[-1]}" if len(ids) > 5 else "".join(f", {v}" for v in ids[4:]))
            rows.append(
                {
                    "name": f"every other used view from the {which} ({len(ids)}"
                    + (f" of {n_used}" if n_used else "")
                    + f": views {shown}), refitted alone",
                    "kind": "half",
                    "T": T,
                    "stored": halves[h],
                }
            )
    if not rows:
        return None
    for r in rows:
        T = r.pop("T")
        r["d_deg"], r["d_mm"], r["sigma"] = _stored_difference(r.pop("stored"))
        r["offset_mm"] = ((T[:3, 3] - T_x[:3, 3]) * 1e3).tolist()
        r["far"] = bool(r["sigma"] > limit)
    split = (halves.get("odd_vs_even") or {}).get("mahalanobis2")
    model = ref.get("robot_model") if isinstance(ref.get("robot_model"), dict) else {}
    text = offset_explanation(
        rows,
        limit_sigma=limit,
        halves_m2=None if split is None else float(split),
        halves_m2_limit=chi2_ppf(1.0 - alpha, 6),
        robot_mm=_num(ref.get("robot_sigma_mm")),
        robot_deg=_num(ref.get("robot_sigma_deg")),
        robot_model=str(model.get("kind") or ref.get("robot_noise_model") or ""),
    )
    return {
        "rows": rows,
        "limit_sigma": limit,
        "explanation": text,
        "halves_split_m2": split,
        "sigma_source": ref.get("sigma_source") or "model",
    }


def _plain_text(v) -> str:
    """A parameter of the robot model as one short line (numbers to 4 significant digits)."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, (int, float)):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        if len(v) > 8 and all(isinstance(x, (int, float)) for x in v):
            return f"{len(v)} values, largest magnitude {max(abs(float(x)) for x in v):.4g}"
        return ", ".join(_plain_text(x) for x in v)
    if isinstance(v, dict):
        return "; ".join(f"{a}: {_plain_text(b)}" for a, b in v.items())
    return str(v)


def _robot_model(ref) -> Optional[dict]:
    """The refinement's robot error model (``refinement.robot_model``: kind and its parameters), else the
    robot noise model's name with its estimated sigmas.
    """
    if not ref:
        return None
    rm = ref.get("robot_model")
    if isinstance(rm, dict) and rm.get("kind") in ("kinematic", "joint_space"):
        return {"kind": str(rm["kind"]), "items": _kinematic_items(rm)}
    if isinstance(rm, dict) and rm:
        items = []
        for k, v in rm.items():
            if k == "kind":
                continue
            items.append({"name": str(k).replace("_", " "), "value": _plain_text(v)})
        return {"kind": str(rm.get("kind", "?")), "items": items}
    return {
        "kind": str(ref.get("robot_noise_model") or "iid"),
        "items": [
            {
                "name": "robot sigma",
                "value": f"{_num(ref.get('robot_sigma_mm')):.3f} mm / "
                f"{_num(ref.get('robot_sigma_deg')):.4f} deg per view",
            }
        ],
    }


def _kinematic_items(rm: dict) -> list:
    """The kinematic robot models' parameters as short lines: the arm, where the joint angles came from, the
    encoder noise, the DH prior (stated, as used, its test) and the largest DH offsets, the tool offset. The DH
    table and the joint angles of every view stay in result.json.
    """
    items = [{"name": "model", "value": str(rm.get("description", ""))}]
    items.append({"name": "arm", "value": f"{rm.get('arm', '?')} ({rm.get('dh_convention', '?')} DH)"})
    items.append({"name": "joint angles", "value": str(rm.get("joint_angles", "?"))})
    enc = _num(rm.get("encoder_sigma_deg"))
    items.append(
        {
            "name": "encoder noise",
            "value": f"{enc:.4f} deg per joint and view, "
            + ("estimated" if "encoder_sigma_deg" in (rm.get("estimated") or []) else "stated")
            + ("" if rm.get("encoder_sigma_resolved") is not False else " (not resolved by the views)"),
        }
    )
    stated, used = rm.get("dh_prior_sigma_stated") or {}, rm.get("dh_prior_sigma") or {}
    if used:
        test = rm.get("dh_prior_test") or {}
        line = f"{_num(used.get('length_mm')):.3g} mm / {_num(used.get('angle_deg')):.3g} deg per DH parameter"
        if rm.get("dh_prior") and rm["dh_prior"] != "the arm's error prior":
            line = f"{rm['dh_prior']} (the arm's own: {line})"
        elif test.get("contradicted"):
            line += (
                f": the views contradict the arm's stated {_num(stated.get('length_mm')):.3g} mm / "
                f"{_num(stated.get('angle_deg')):.3g} deg (chi-square {_num(test.get('statistic')):.1f} with "
                f"{_num(test.get('redundancy')):.1f} offsets resolved, p = {_num(test.get('p_value')):.2g}), so "
                f"its scale was estimated: x{_num(rm.get('dh_prior_scale')):.2f}"
            )
        elif test.get("resolved"):
            line += (
                f", the arm's stated prior (not rejected at {100 * _num(test.get('alpha')):g} %: "
                f"p = {_num(test.get('p_value')):.2g})"
            )
        else:
            line += ", the arm's stated prior"
        items.append({"name": "DH prior", "value": line})
    off, sd = rm.get("dh_offset"), rm.get("dh_offset_sigma")
    if isinstance(off, list) and isinstance(sd, list) and off:
        o, e = np.asarray(off, float), np.asarray(sd, float)
        names = ["a", "alpha", "d", "theta_offset"]
        parts = []
        for cols, unit in (((0, 2), "mm"), ((1, 3), "deg")):
            sub = np.abs(o[:, cols])
            j, c = np.unravel_index(int(np.argmax(sub)), sub.shape)
            parts.append(f"{o[j, cols[c]]:+.3g} ± {e[j, cols[c]]:.2g} {unit} ({names[cols[c]]} of joint {j + 1})")
        share = np.asarray(rm.get("dh_resolved_share") or [], float)
        resolved = (
            f" ({int(np.sum(share > 0.5))} of {share.size} known more from the views than from the prior)"
            if share.size
            else ""
        )
        items.append({"name": "DH offsets", "value": "largest " + ", ".join(parts) + resolved})
    spread = rm.get("tool_offset_spread_deg_mm")
    T = rm.get("tool_offset_T_flange_reported")
    if isinstance(T, list) and isinstance(spread, list) and len(spread) == 2:
        t = np.asarray(T, float)[:3, 3] * 1000.0
        items.append(
            {
                "name": "tool offset",
                "value": f"{np.linalg.norm(t):.1f} mm from the flange (spread over the "
                f"views {_num(spread[1]):.2g} mm / {_num(spread[0]):.2g} deg)",
            }
        )
    bad = rm.get("joints_disagree_view_ids") or []
    if bad:
        items.append({"name": "joints disagree with the pose", "value": ", ".join(str(v) for v in bad)})
    return items


def _noise(ref) -> Optional[dict]:
    if not ref:
        return None
    resolved = ref.get("robot_sigma_resolved") or {}
    return {
        "sigma_px": ref.get("sigma_px"),
        "robot_mm": ref.get("robot_sigma_mm"),
        "robot_deg": ref.get("robot_sigma_deg"),
        "resolved_rot": resolved.get("rot"),
        "resolved_trans": resolved.get("trans"),
        "model": ref.get("robot_noise_model", ""),
        "rms_before": ref.get("rms_px_before"),
        "rms_after": ref.get("rms_px_after"),
        "iterations": ref.get("iterations"),
    }


# ------------------------------------------------------------------------------ diagnostics
def _cap1(s) -> str:
    s = str(s or "")
    return s[:1].upper() + s[1:]


def _findings(diag: dict) -> list[dict]:
    out = []
    for f in (diag or {}).get("findings") or []:
        if not isinstance(f, dict):
            continue
        sev = str(f.get("severity", "info")).lower()
        sev = sev if sev in SEVERITY_ORDER else "info"
        out.append(
            {
                "code": str(f.get("code") or ""),
                "severity": sev,
                "title": str(f.get("title") or f.get("code") or "finding"),
                "evidence": _cap1(f.get("evidence", "")),
                "action": _cap1(f.get("action", "")),
                "view_ids": [str(v) for v in (f.get("view_ids") or [])],
                "details": f.get("details") if isinstance(f.get("details"), dict) else {},
                "advice": _unless_said(finding_advice(f), f.get("action", "")),
            }
        )
    out.sort(key=lambda f: SEVERITY_ORDER[f["severity"]])
    return out


def _stages(diag: dict) -> dict:
    """How each diagnostics stage ended (``diagnostics["stages"]``, ``["stage_errors"]``,
    ``["stages_skipped"]``, ``["crashed_stages"]``; see handeye/diagnose/findings.py):

    ``{"crashed": [{name, checks, error}], "skipped": [{name, checks, why}], "n_ok": int, "known": bool,
    "clean": bool}``. ``clean`` only when the stage record exists and every stage ran; a result
    written before stages were recorded is not ``known``, and its report does not claim that
    everything ran.
    """
    diag = diag or {}
    status = diag.get("stages") if isinstance(diag.get("stages"), dict) else {}
    errors = diag.get("stage_errors") if isinstance(diag.get("stage_errors"), dict) else {}
    skipped = diag.get("stages_skipped") if isinstance(diag.get("stages_skipped"), dict) else {}
    crashed_names = [n for n, st in status.items() if st == "crashed"]
    crashed_names += [n for n in errors if n not in crashed_names]  # an error always means a crash
    try:
        n_crashed = max(int(diag.get("crashed_stages") or 0), len(crashed_names))
    except (TypeError, ValueError):
        n_crashed = len(crashed_names)
    crashed = [
        {
            "name": str(n),
            "checks": STAGE_CHECKS.get(str(n), ""),
            "error": str(errors.get(n) or "no error message recorded"),
        }
        for n in crashed_names
    ]
    crashed += [
        {"name": "(unnamed)", "checks": "", "error": "counted as crashed without a name"}
        for _ in range(n_crashed - len(crashed))
    ]
    skipped_names = [n for n, st in status.items() if st == "skipped"]
    skipped_names += [n for n in skipped if n not in skipped_names and n not in crashed_names]
    skipped_rows = [
        {"name": str(n), "checks": STAGE_CHECKS.get(str(n), ""), "why": str(skipped.get(n) or "no reason recorded")}
        for n in skipped_names
    ]
    known = bool(status) or "crashed_stages" in diag
    return {
        "crashed": crashed,
        "skipped": skipped_rows,
        "n_ok": sum(st == "ok" for st in status.values()),
        "known": known,
        "clean": known and not crashed and not skipped_rows,
    }


def _col_title(key: str) -> str:
    """``held_out_rms_px`` -> ``Held out RMS [px]``."""
    k, unit = str(key), ""
    for suf in ("px", "mm", "deg", "m", "rad"):
        if k.endswith("_" + suf):
            k, unit = k[: -len(suf) - 1], f" [{suf}]"
            break
    k = k.replace("_", " ").replace("rms", "RMS")
    return k[:1].upper() + k[1:] + unit


def _unless_said(advice: str, action: str) -> str:
    """The advice of a finding's code, or "" when its own action says the same."""

    def norm(s):
        return re.sub(r"[^a-z0-9]+", " ", str(s).lower()).strip()

    return "" if norm(advice) == norm(action) else advice


def _cross_validation(cv) -> Optional[dict]:
    """The diagnostics' held-out validation: summary, spread against prediction, per-view table.

    Known keys (jackknife_sigma_*, predicted_sigma_*, per_view) get a dedicated layout; anything
    else is shown generically (scalars as items, lists of dicts as tables).
    """
    if not isinstance(cv, dict) or not cv:
        return None
    summary = str(cv.get("summary") or cv.get("conclusion") or "")
    ran = bool(cv.get("verdict")) or "jackknife_sigma_rot_deg" in cv
    out = {
        "summary": summary,
        "items": [],
        "tables": [],
        "not_run": not ran,
        "spread": None,
        "verdict": cv.get("verdict", ""),
    }
    used = {"summary", "conclusion", "verdict", "status"}
    if "jackknife_sigma_rot_deg" in cv or "jackknife_sigma_trans_mm" in cv:
        rows = [
            ("Held-out spread (jackknife, 1 σ)", cv.get("jackknife_sigma_rot_deg"), cv.get("jackknife_sigma_trans_mm"))
        ]
        if cv.get("predicted_sigma_rot_deg") is not None:
            rows.append(
                (
                    "Predicted by the covariance (1 σ)",
                    cv.get("predicted_sigma_rot_deg"),
                    cv.get("predicted_sigma_trans_mm"),
                )
            )
        out["spread"] = {
            "rows": [{"name": n, "rot": list(r or [None] * 3), "trans": list(t or [None] * 3)} for n, r, t in rows],
            "ratio_rot": cv.get("ratio_rot"),
            "ratio_trans": cv.get("ratio_trans"),
            "axes": cv.get("axes", ""),
        }
        used |= {
            "jackknife_sigma_rot_deg",
            "jackknife_sigma_trans_mm",
            "predicted_sigma_rot_deg",
            "predicted_sigma_trans_mm",
            "ratio_rot",
            "ratio_trans",
            "axes",
        }
    labels = {
        "method": "Refit",
        "scheme": "Scheme",
        "n_views": "Views",
        "n_folds": "Folds",
        "folds_solved": "Folds solved",
        "held_out_rms_px_median": "Held-out RMS, median [px]",
        "held_out_trans_mm_median": "Held-out pose residual, median [mm]",
        "held_out_rot_deg_median": "Held-out pose residual, median [deg]",
        "per_view": "Per view (the views held out together share their fold's shift of X)",
    }

    def num_text(x, d):
        return f"{x:.{d}f}" if isinstance(x, (int, float)) else "—"  # a NaN is stored as null

    def triple(v, d):
        return ", ".join(num_text(x, d) for x in v) if isinstance(v, list) else num_text(v, d)

    lim = cv.get("ratio_limits")
    if isinstance(lim, list) and len(lim) == 2:
        out["items"].append(
            {
                "name": "Range of the ratio by chance when the model holds",
                "value": f"{num_text(lim[0], 2)}-{num_text(lim[1], 2)}×",
            }
        )
    if cv.get("spread_p_value") is not None:
        out["items"].append(
            {"name": "p-value of the spread under the model covariance", "value": f"{float(cv['spread_p_value']):.2g}"}
        )
    if cv.get("verdict_sigma_rot_deg") is not None:
        out["items"].append(
            {
                "name": "Verdict covariance (1 σ): rotation [°] / translation [mm]",
                "value": f"{triple(cv['verdict_sigma_rot_deg'], 4)} / {triple(cv.get('verdict_sigma_trans_mm'), 3)}",
            }
        )
    if cv.get("ratio_rot_verdict") is not None:
        out["items"].append(
            {
                "name": "Held-out spread / verdict σ",
                "value": f"rotation {num_text(cv['ratio_rot_verdict'], 2)}×, translation "
                f"{num_text(cv.get('ratio_trans_verdict'), 2)}×"
                + (
                    ""
                    if cv.get("covered_by_verdict") is None
                    else "; the verdict covariance covers the spread"
                    if cv["covered_by_verdict"]
                    else "; the verdict covariance does not cover the spread"
                ),
            }
        )
    used |= {
        "ratio_limits",
        "ratio_limits_meaning",
        "spread_p_value",
        "verdict_sigma_rot_deg",
        "verdict_sigma_trans_mm",
        "ratio_rot_verdict",
        "ratio_trans_verdict",
        "covered_by_verdict",
    }
    for k, v in cv.items():
        if k in used:
            continue
        name = labels.get(k, k.replace("_", " "))
        if isinstance(v, (int, float, str, bool)) or v is None:
            out["items"].append({"name": name, "value": v})
        elif isinstance(v, list) and v and all(isinstance(r, dict) for r in v):
            cols = list(dict.fromkeys(c for r in v for c in r if not isinstance(r[c], (list, dict))))
            out["tables"].append(
                {"name": name, "cols": [_col_title(c) for c in cols], "rows": [[r.get(c) for c in cols] for r in v]}
            )
        elif isinstance(v, list) and v and all(isinstance(x, (int, float)) for x in v) and len(v) <= 6:
            out["items"].append({"name": name, "value": ", ".join(f"{x:.4g}" for x in v)})
        elif isinstance(v, dict):
            for kk, vv in v.items():
                if isinstance(vv, (int, float, str, bool)):
                    out["items"].append({"name": f"{name} {kk}".replace("_", " "), "value": vv})
    return out


# ------------------------------------------------------------------------------ KPIs
def _distrust(verdict: Verdict, untrusted: dict[str, str], *, fail_finding: bool = False) -> Verdict:
    """Checks on a number a finding says is wrong are shown as untrusted, not as passed or failed: the
    finding is the cause and counts towards the verdict itself (the label stays as judged), e.g. a board
    that moved inflates the validated sigmas past their limit, and the report leads with the move. A warn or
    fail check is marked so only when a fail finding already makes the verdict FAIL (``fail_finding``).
    """
    if not untrusted:
        return verdict
    checks = tuple(
        replace(
            c,
            status="untrusted",
            why=f"Not to be trusted: {untrusted[c.key]}",
            action="Fix what that finding names and re-run handeye calibrate",
        )
        if c.key in untrusted and (c.status == "pass" or (fail_finding and c.status in ("info", "warn", "fail")))
        else c
        for c in verdict.checks
    )
    counts = dict(
        verdict.counts, **{s: sum(c.status == s for c in checks) for s in ("pass", "info", "warn", "fail", "untrusted")}
    )
    return replace(verdict, checks=checks, counts=counts)


def _kpis(metrics, pred, wd, views, verdict: Verdict, ok: bool, untrusted: dict[str, str]) -> list[dict]:
    """The headline cards. A card whose number a finding says is not to be trusted is shown as such,
    never green.
    """
    status = {k: c.status for c in verdict.checks for k in c.key.split("+")}

    def card(label, value, sub, keys):
        st = max((status.get(k, "pass") for k in keys), key=lambda s: STATUS_ORDER.get(s, 0)) if keys else ""
        if not ok and st == "pass":  # no result: a number of the data is not a passed calibration
            st = "info"
        doubt = next((untrusted[k] for k in keys if k in untrusted), None)
        if doubt and value != "n/a":
            return {"label": label, "value": value, "sub": f"not to be trusted: {doubt}", "status": "untrusted"}
        return {"label": label, "value": value, "sub": sub, "status": st}

    out = []
    if pred is not None:
        out.append(
            card(
                f"Predicted error at {wd:.2f} m",
                f"{pred['rms_mm']:.2f} mm",
                f"1 σ RMS 3-D · 95 %: {pred['r95_mm']:.2f} mm",
                ["predicted_error_mm"],
            )
        )
    elif ok:
        out.append(card("Predicted error", "n/a", "no covariance (--no-refine)", ["predicted_error_mm"]))
    v = metrics.get("reprojection_rms_px")
    if v is not None:
        out.append(card("Reprojection RMS", f"{v:.2f} px", "detected vs predicted corners", ["reprojection_rms_px"]))
    n_used = sum(x["status"] == "used" for x in views)
    if views:
        n_flagged = sum(bool(x.get("flagged")) for x in views)
        n_corners = sum(bool(x.get("corner_flags")) for x in views)
        out.append(
            card(
                "Views used" if ok else "Views detected and paired",
                f"{n_used} / {len(views)}",
                f"{n_flagged} dropped or flagged" + (f"; {n_corners} used with outlier corners" if n_corners else ""),
                ["used_views"],
            )
        )
    mr, sp = metrics.get("max_rotation_deg"), metrics.get("axis_spread_deg")
    if mr is not None:
        out.append(
            card(
                "Rotation coverage",
                f"{mr:.0f}°",
                f"largest rotation; axis spread {sp:.0f}°" if sp is not None else "largest rotation",
                ["max_rotation_deg", "axis_spread_deg"],
            )
        )
    return out


# ------------------------------------------------------------------------------ provenance
def _provenance(res, qa_cfg, qa_source) -> dict:
    import yaml

    prov = dict(res.get("provenance") or {})
    options = prov.pop("options", None)
    rows = []
    labels = {
        "handeye_version": "handeye version",
        "command_line": "Command line",
        "time_utc": "Calibrated (UTC)",
        "inputs_sha256": "Input hash (SHA-256 of images and pose files)",
        "python": "Python",
        "opencv": "OpenCV",
    }
    for k in labels:
        if k in prov:
            rows.append({"name": labels[k], "value": prov.pop(k), "mono": k in ("command_line", "inputs_sha256")})
    for k, v in prov.items():
        if isinstance(v, (str, int, float)):
            rows.append({"name": k.replace("_", " "), "value": v, "mono": False})
    sess = res.get("session") or {}
    if sess.get("path"):
        rows.append({"name": "Session", "value": f"{sess.get('path')} ({sess.get('format', '')})", "mono": True})
    if sess.get("pose_format"):
        rows.append({"name": "Pose format", "value": sess["pose_format"], "mono": False})
    secs = res.get("seconds") or {}
    if secs.get("total"):
        rows.append(
            {
                "name": "Run time",
                "value": ", ".join(f"{k} {v:.2f} s" for k, v in secs.items() if isinstance(v, (int, float))),
                "mono": False,
            }
        )
    report_cmd = " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv and sys.argv[0] else ""
    if report_cmd and report_cmd != (res.get("provenance") or {}).get("command_line") and "pytest" not in report_cmd:
        rows.append({"name": "Report command line", "value": report_cmd, "mono": True})
    rows.append(
        {
            "name": "Report generated (UTC)",
            "value": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "mono": False,
        }
    )
    rows.append({"name": "QA thresholds", "value": qa_source, "mono": True})
    config = {}
    if options:
        config["calibration options"] = options
    ref_opts = (res.get("refinement") or {}).get("options") if isinstance(res.get("refinement"), dict) else None
    if ref_opts:
        config["refinement options"] = ref_opts
    config["QA thresholds"] = qa_cfg
    return {
        "rows": rows,
        "config_yaml": yaml.safe_dump(plain(config), sort_keys=False, default_flow_style=None, width=100).strip(),
    }
