"""Gather everything the report shows into one plain context (no HTML/Markdown here).

Input: result.json and observations.json as dicts, the QA thresholds, and where the session images
are. Every key of result.json is optional except ``status`` and ``mode``: partial results (failed
runs, ``--no-refine``, results written before the refinement or diagnostics existed) still build.
"""
from __future__ import annotations

import datetime as _dt
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from .. import __version__
from ..conventions import pose_forms, vendor_euler_from_R
from ..frames import pose_error
from ..output import plain
from ..records import view_id_key
from . import analysis as A
from . import plots
from .qa import Verdict, evaluate

log = logging.getLogger(__name__)

MODE_TEXT = {"eye_in_hand": "Eye-in-hand (camera on the robot flange)",
             "eye_to_hand": "Eye-to-hand (camera fixed, board in the gripper)"}
X_NAMES = {"eye_in_hand": ("T_end_cam", "T_base_board", "end", "base"),
           "eye_to_hand": ("T_base_cam", "T_end_board", "base", "end")}
SEVERITY_ORDER = {"fail": 0, "warn": 1, "info": 2}


@dataclass(frozen=True)
class Plot:
    key: str
    title: str
    caption: str
    png: bytes


@dataclass(frozen=True)
class Thumb:
    view_id: str
    png: bytes


# ------------------------------------------------------------------------------ entry
def build_context(res: dict, obs: Optional[dict], *, qa_cfg: dict, qa_source: str,
                  image_paths: dict[str, Path], make_plots: bool = True) -> dict[str, Any]:
    res = res or {}
    obs = _matching_observations(res, obs or {})
    mode_known = res.get("mode") in X_NAMES
    mode = res.get("mode") if mode_known else "eye_in_hand"
    x_name, b_name, parent, board_parent = X_NAMES[mode]
    ok = res.get("status") == "ok"
    ref = res.get("refinement") if isinstance(res.get("refinement"), dict) else {}
    if ref and ref.get("status") not in (None, "ok"):
        ref = {}
    diag = res.get("diagnostics") if isinstance(res.get("diagnostics"), dict) else {}
    T_x = A.as_T(res.get(x_name)) if ok else None
    T_board = A.as_T(res.get(b_name)) if ok else None
    cov = A.as_cov6(ref.get("cov_x_6x6")) if ref else None
    intr = res.get("intrinsics") or ref.get("intrinsics")
    obj = np.asarray(obs.get("object_points_m") or [], float).reshape(-1, 3)
    board_centre = obj.mean(axis=0) if len(obj) else np.zeros(3)
    fits = A.camera_only_fits(obs, intr) if obs.get("views") else {}

    wd_cfg = qa_cfg.get("working_distance_m")
    wd = float(wd_cfg) if wd_cfg is not None else _num(ref.get("working_distance_m"))
    if not A.finite(wd):
        wd = _median_board_distance(fits, board_centre)

    ctx: dict[str, Any] = {"x_name": x_name, "board_name": b_name, "parent": parent, "mode": mode,
                           "mode_text": MODE_TEXT[mode] if mode_known else "Mounting mode unknown",
                           "ok": ok, "refined": bool(ref)}
    ctx["meta"] = _meta(res, obs, mode)
    views = _view_rows(res, ref, fits, board_centre, diag, image_paths)
    ctx["views"] = views
    used_for_he = [v for v in views if v["status"] == "used"]
    ctx["n_used"] = len(used_for_he)
    ctx["n_total"] = len(views)

    # --- result forms and uncertainty
    unc = None
    if T_x is not None and cov is not None:
        unc = A.form_sigmas(T_x, cov)
    pred = None
    if T_x is not None and cov is not None and A.finite(wd):
        pred = A.predicted_point_error(T_x, cov, working_distance_m=wd)
    ctx["result"] = _result_block(res, T_x, T_board, unc, pred, wd, x_name, b_name, parent, board_parent,
                                  ref) if T_x is not None else None
    ctx["uncertainty"] = _uncertainty_block(ref, unc, cov, x_name, parent) if unc is not None else None
    ctx["methods"] = _methods(res, T_x, x_name, pred, unc)
    ctx["intrinsics"] = _intrinsics_rows(intr, ref.get("intrinsics_sigma") if ref else None, res)
    ctx["noise"] = _noise(ref)

    # --- metrics and verdict
    metrics, mctx = _metrics(res, ref, fits, views, unc, pred, wd, obs, mode, parent)
    findings = _findings(diag)
    failure = _failure(res, findings, has_views=bool(views)) if not ok else None
    mctx.update(x_name=x_name)
    if pred is not None:
        mctx["predicted_text"] = f"{pred['rms_mm']:.2f} mm (1 σ) at {wd:.2f} m"
    verdict = evaluate(metrics, qa_cfg, context=mctx, failure=failure, findings=findings,
                       thresholds_source=qa_source)
    ctx["verdict"] = verdict
    ctx["failure"] = failure
    ctx["findings"] = findings
    ctx["cross_validation"] = _cross_validation(diag.get("cross_validation"))
    ctx["kpis"] = _kpis(metrics, pred, wd, views, verdict, ok)
    ctx["motion"] = res.get("motion")
    ctx["provenance"] = _provenance(res, qa_cfg, qa_source)
    ctx["plots"] = _plots(res, obs, ref, fits, views, T_x, T_board, unc, metrics, mctx, qa_cfg, mode, x_name,
                          parent, board_centre) if make_plots else []
    ctx["thumbs"] = _thumbs(views, fits, ref, image_paths)
    for v in views:
        v["has_thumb"] = v["id"] in ctx["thumbs"]
    return ctx


def _matching_observations(res: dict, obs: dict) -> dict:
    """observations.json restricted to the views of this result (a stale file from an earlier run of
    another session in the same folder must not leak into the report)."""
    if not obs:
        return {}
    ids = {str(v.get("id")) for v in res.get("views") or []}
    if not ids or (obs.get("mode") and res.get("mode") and obs.get("mode") != res.get("mode")):
        return {}
    out = dict(obs)
    out["views"] = {k: v for k, v in (obs.get("views") or {}).items() if str(k) in ids}
    return out


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


def _median_board_distance(fits, centre) -> float:
    d = [float((f.T_cam_board[:3, :3] @ centre + f.T_cam_board[:3, 3])[2]) for f in fits.values()
         if f.T_cam_board is not None]
    return float(np.median(d)) if d else float("nan")


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
    return str(kind)


def _meta(res: dict, obs: dict, mode: str) -> dict:
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
def _view_rows(res, ref, fits, centre, diag, image_paths) -> list[dict]:
    per_view = (ref or {}).get("per_view") or {}
    outl: dict[str, list] = {}
    for o in (ref or {}).get("outliers") or []:
        outl.setdefault(str(o.get("view_id")), []).append(o)
    finding_by_view: dict[str, list] = {}
    for f in (diag or {}).get("findings") or []:
        for vid in f.get("view_ids") or []:
            finding_by_view.setdefault(str(vid), []).append(f)
    rows = []
    for v in res.get("views") or []:
        vid = str(v.get("id"))
        fit = fits.get(vid)
        pv = per_view.get(vid, {})
        flags: list[dict] = []
        if not v.get("used", False):
            reason = re.sub(r"^(outlier: )?view \S+: ", r"\1", v.get("reason") or "not used")
            status = "flagged" if reason.startswith("outlier") or vid in per_view else "dropped"
            flags.append({"severity": "fail", "text": reason})
        elif pv.get("status") == "robot_excluded":
            status = "flagged"
        else:
            status = "used"
        for o in outl.get(vid, []):
            text = re.sub(r"^view \S+: ", "", o.get("reason", ""))
            if any(text in f["text"] for f in flags):
                continue
            sev = "info" if o.get("kind") == "corners" else ("warn" if o.get("kind") == "robot_pose" else "fail")
            flags.append({"severity": sev, "text": text})
        for f in finding_by_view.get(vid, []):
            text, part = _finding_for_view(f, vid)
            if part and any(part in g["text"] or g["text"] in part for g in flags):
                continue  # the same fact already stated (e.g. the reason the view was dropped)
            flags.append({"severity": str(f.get("severity", "info")).lower(), "text": text})
        rms = fit.rms_px if fit else _num(pv.get("rms_px", v.get("pnp_rms_px")))
        mx = fit.max_px if fit else _num(pv.get("max_px"))
        chain = fit.chain_rms_px if fit else float("nan")
        if "robot_vs_camera_trans_mm" in pv:
            rc_mm, rc_deg = _num(pv.get("robot_vs_camera_trans_mm")), _num(pv.get("robot_vs_camera_rot_deg"))
            maha = _num(pv.get("robot_vs_camera_mahalanobis"))
            rc_src = "refinement"
        elif fit is not None:
            rc_deg, rc_mm = A.board_disagreement(fit, centre)
            maha, rc_src = float("nan"), "board centre"
        else:
            rc_deg = rc_mm = maha = float("nan")
            rc_src = ""
        path = image_paths.get(vid)
        rows.append({"id": vid, "image": v.get("image") or (path.name if path else ""),
                     "image_path": str(path) if path else "", "status": status,
                     "n_corners": v.get("n_corners") if v.get("n_corners") else (len(fit.corner_ids) if fit else 0),
                     "rms_px": rms, "max_px": mx, "chain_rms_px": chain, "robot_mm": rc_mm, "robot_deg": rc_deg,
                     "robot_maha": maha, "robot_src": rc_src, "flags": flags,
                     "sharpness": None})
    return rows


def _finding_for_view(f: dict, vid: str) -> tuple[str, str]:
    """(flag text, the evidence about this view or "") from a finding ("view 3: ..." parts), else its title."""
    title = str(f.get("title", f.get("code", "")))
    for part in re.split(r";\s+", str(f.get("evidence", ""))):
        m = re.match(rf"^views?\s+{re.escape(vid)}\s*:\s*(.+)$", part.strip())
        if m:
            code = str(f.get("code", "")).replace("_", " ")
            return (f"{code}: {m.group(1)}" if code else m.group(1)), m.group(1)
    return title, ""


# ------------------------------------------------------------------------------ result
def _result_block(res, T_x, T_board, unc, pred, wd, x_name, b_name, parent, board_parent, ref) -> dict:
    he = res.get("hand_eye") or {}
    f = pose_forms(T_x) if not he.get("matrix") else {**pose_forms(T_x), **he}
    q = A.quat_wxyz(T_x)
    rows = []

    def add(group, comp, unit, val, sig, digits):
        lo = hi = None
        if sig is not None and np.isfinite(sig):
            lo, hi = val - A.Z95 * sig, val + A.Z95 * sig
        rows.append({"group": group, "comp": comp, "unit": unit, "value": val, "sigma": sig, "lo": lo, "hi": hi,
                     "digits": digits})

    t = T_x[:3, 3] * 1e3
    for k, c in enumerate("xyz"):
        add(f"Translation ({parent} frame)", c, "mm", t[k], unc["translation_mm"][k] if unc else None, 2)
    for k, c in enumerate("wxyz"):
        add("Quaternion (w, x, y, z)", c, "", q[k], unc["quaternion_wxyz"][k] if unc else None, 6)
    rv = np.degrees(np.asarray(f["rotvec_rad"], float))
    for k, c in enumerate("xyz"):
        add("Rotation vector (axis × angle)", c, "deg", rv[k], unc["rotvec_deg"][k] if unc else None, 3)
    eu = np.asarray(f["euler_vendor_deg"], float)
    for k, c in enumerate(("rx", "ry", "rz")):
        add("Euler, R = Rz·Ry·Rx (extrinsic x-y-z)", c, "deg", eu[k], unc["euler_vendor_deg"][k] if unc else None, 3)
    out = {
        "name": x_name,
        "meaning": (res.get("frames") or {}).get(x_name, ""),
        "equation": f"p_{parent} = {x_name} · p_cam",
        "child": "cam", "parent": parent,
        "matrix": T_x.tolist(),
        "matrix_text": matrix_text(T_x),
        "translation_mm": (T_x[:3, 3] * 1e3).tolist(),
        "quaternion_wxyz": q.tolist(),
        "euler_deg": eu.tolist(),
        "rows": rows,
        "rotvec_rad": list(map(float, f["rotvec_rad"])),
        "euler_rad": list(map(float, f["euler_vendor_rad"])),
        "vendor_line": f.get("vendor_pose_line") or "",
        "quaternion_xyzw": [q[1], q[2], q[3], q[0]],
        "pred": pred,
        "working_distance_m": wd,
        "has_sigma": unc is not None,
    }
    if T_board is not None:
        bf = pose_forms(T_board)
        out["board"] = {"name": b_name, "meaning": (res.get("frames") or {}).get(b_name, ""),
                        "equation": f"p_{board_parent} = {b_name} · p_board",
                        "matrix": T_board.tolist(), "matrix_text": matrix_text(T_board), "translation_mm": bf["translation_mm"],
                        "euler_deg": bf["euler_vendor_deg"], "quaternion_wxyz": bf["quaternion_wxyz"],
                        "vendor_line": bf["vendor_pose_line"]}
    return out


def matrix_text(T: np.ndarray) -> str:
    """A 4x4 as aligned plain text (ASCII minus, so that it can be copied)."""
    return "\n".join("   ".join(f"{x:+.6f}" for x in row) for row in np.asarray(T, float))


def _uncertainty_block(ref, unc, cov, x_name, parent) -> dict:
    corr = ref.get("correlation_6x6")
    names = ["ωx", "ωy", "ωz", "vx", "vy", "vz"]
    return {"sigma_trans_mm": list(unc["translation_mm"]), "sigma_rot_deg": list(unc["rot_cam_deg"]),
            "trans_axes": ref.get("sigma_trans_axes", f"{parent} frame"),
            "rot_axes": ref.get("sigma_rot_axes", "camera frame"),
            "parametrisation": ref.get("cov_parametrisation", ""),
            "corr": np.asarray(corr, float).tolist() if corr is not None else None, "corr_names": names,
            "definition": ref.get("predicted_error_definition", "")}


def _methods(res, T_x, x_name, pred, unc) -> list[dict]:
    rows = []
    cf = res.get("closed_form") or {}
    for m, e in cf.items():
        T = A.as_T(e.get(x_name))
        row = {"name": m, "status": e.get("status", "?"), "reason": e.get("failure_reason", ""),
               "is_seed": m == res.get("method"), "is_result": False, "cons_mm": None, "cons_deg": None}
        if T is not None:
            row["t_mm"] = (T[:3, 3] * 1e3).tolist()
            row["euler_deg"] = np.degrees(vendor_euler_from_R(T[:3, :3])).tolist()
            if T_x is not None:
                dr, dt = pose_error(T, T_x)
                row["d_deg"], row["d_mm"] = dr, dt
                row["offset_mm"] = ((T[:3, 3] - T_x[:3, 3]) * 1e3).tolist()
            row["cons_mm"], row["cons_deg"] = e.get("board_consistency_mm"), e.get("board_consistency_deg")
        rows.append(row)
    if T_x is not None and res.get("refined"):
        rows.append({"name": "joint refinement (result)", "status": "ok", "reason": "", "is_result": True,
                     "is_seed": False, "cons_mm": None, "cons_deg": None,
                     "t_mm": (T_x[:3, 3] * 1e3).tolist(), "euler_deg": np.degrees(vendor_euler_from_R(T_x[:3, :3])).tolist(),
                     "d_deg": 0.0, "d_mm": 0.0, "offset_mm": [0.0, 0.0, 0.0]})
    elif T_x is not None:
        for r in rows:
            if r.get("is_seed"):
                r["is_result"] = True
    return rows


def _intrinsics_rows(intr, sig, res) -> Optional[dict]:
    if not intr:
        return None
    sig = sig or {}
    rows = []
    for k, unit in (("fx", "px"), ("fy", "px"), ("cx", "px"), ("cy", "px")):
        if k in intr:
            rows.append({"name": k, "unit": unit, "value": intr[k], "sigma": sig.get(k)})
    d = intr.get("dist") or {}
    if isinstance(d, dict):
        for k in ("k1", "k2", "p1", "p2", "k3"):
            if k in d:
                rows.append({"name": k, "unit": "", "value": d[k], "sigma": sig.get(k)})
    src = (res.get("intrinsics") or {}).get("source", "")
    rms = (res.get("intrinsics") or {}).get("calibrate_camera_rms_px")
    return {"rows": rows, "source": src, "rms": rms, "size": intr.get("image_size"),
            "refined": bool(sig)}


def _noise(ref) -> Optional[dict]:
    if not ref:
        return None
    res = ref.get("robot_sigma_resolved") or {}
    return {"sigma_px": ref.get("sigma_px"), "robot_mm": ref.get("robot_sigma_mm"),
            "robot_deg": ref.get("robot_sigma_deg"), "resolved_rot": res.get("rot"),
            "resolved_trans": res.get("trans"), "model": ref.get("robot_noise_model", ""),
            "rms_before": ref.get("rms_px_before"), "rms_after": ref.get("rms_px_after"),
            "iterations": ref.get("iterations")}


# ------------------------------------------------------------------------------ metrics
def _metrics(res, ref, fits, views, unc, pred, wd, obs, mode, parent):
    m: dict[str, Optional[float]] = {}
    c: dict[str, Any] = {}
    used_ids = {v["id"] for v in views if v["status"] == "used"}
    # reprojection
    if ref and A.finite(ref.get("rms_px_after")):
        m["reprojection_rms_px"] = float(ref["rms_px_after"])
        c["rms_source"] = "joint fit"
        c["reprojection_rms_px_source"] = "joint refinement, corners used"
    else:
        r = [fits[v].residual_px for v in used_ids if v in fits]
        if r:
            m["reprojection_rms_px"] = A.rms_norm(np.concatenate(r))
            c["rms_source"] = "each view's own board pose"
            c["reprojection_rms_px_source"] = "camera fit per view (no joint refinement)"
        else:
            m["reprojection_rms_px"] = None
    # uncertainty
    if pred is not None:
        m["predicted_error_mm"] = pred["rms_mm"]
        c["wd_m"] = wd
        c["predicted_error_mm_source"] = f"covariance, point on the optical axis at {wd:.2f} m"
    else:
        m["predicted_error_mm"] = None
    if unc is not None:
        st = np.asarray(unc["translation_mm"])
        sr = np.asarray(unc["rot_cam_deg"])
        m["sigma_trans_mm"] = float(st.max())
        m["sigma_rot_deg"] = float(sr.max())
        c["sigma_t_axis"] = f"along {parent} {'xyz'[int(st.argmax())]}"
        c["sigma_r_axis"] = "xyz"[int(sr.argmax())]
    else:
        m["sigma_trans_mm"] = m["sigma_rot_deg"] = None
    for k in ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"):
        c[f"{k}_missing"] = ("no covariance: the joint refinement did not run" if res.get("status") == "ok"
                             else "no result")
        c[f"{k}_missing_action"] = "run handeye calibrate without --no-refine to get the uncertainty"
    # motion
    Ts = []
    for vid in sorted(used_ids, key=view_id_key):
        T = A.as_T(((obs.get("views") or {}).get(vid) or {}).get("T_base_end_reported"))
        if T is not None:
            Ts.append(T)
    rv = A.relative_rotvecs(np.array(Ts), mode=mode) if len(Ts) >= 2 else np.zeros((0, 3))
    c["rotvecs"] = rv
    c["axis_frame"] = "end" if mode == "eye_in_hand" else "base"
    mo = res.get("motion") or {}
    if len(rv):
        mx, spread, weak = A.axis_spread(rv)
        ang = np.linalg.norm(rv, axis=1)
        main = rv[int(ang.argmax())]
        # the dominant axis from the same eigen-decomposition
        W = rv * np.minimum(ang, np.pi / 2)[:, None] / np.maximum(ang, 1e-12)[:, None]
        main = np.linalg.eigh(W.T @ W)[1][:, 2]
        c["main_axis"] = A.fmt_axis(main)
        c["weak_axes"] = f"{A.fmt_axis(weak[1])} and {A.fmt_axis(weak[0])}"
        m["max_rotation_deg"], m["axis_spread_deg"] = mx, spread
    elif mo:
        m["max_rotation_deg"], m["axis_spread_deg"] = mo.get("max_rotation_deg"), mo.get("axis_spread_deg")
    else:
        m["max_rotation_deg"] = m["axis_spread_deg"] = None
    # views
    n_total = len(views)
    bad = [v for v in views if v["status"] != "used"]
    if n_total:
        m["dropped_share"] = len(bad) / n_total
    c["n_bad"], c["n_total"] = len(bad), n_total
    reasons: dict[str, list] = {}
    for v in bad:
        reasons.setdefault(_brief(v["flags"][0]["text"]) if v["flags"] else v["status"], []).append(v["id"])
    if len(reasons) > 3:  # many distinct texts: group them by their wording without the numbers
        grouped: dict[str, list] = {}
        for r, ids in reasons.items():
            grouped.setdefault(_short_reason(r), []).extend(ids)
        reasons = grouped
    items = [f"{r} (view{'s' if len(ids) > 1 else ''} {', '.join(ids)})" for r, ids in reasons.items()]
    c["bad_reasons"] = "; ".join(items[:3]) + (f"; and {len(items) - 3} more" if len(items) > 3 else "")
    m["used_views"] = float(len(used_ids)) if n_total else None
    # coverage
    size = (res.get("intrinsics") or {}).get("image_size") or obs.get("image_size")
    pts = [fits[v].image_points_px for v in fits if v in used_ids or not used_ids]
    if size and pts:
        counts = A.coverage_counts(np.concatenate(pts), width=size[0], height=size[1])
        m["image_coverage"] = float((counts > 0).mean())
        c["coverage_counts"] = counts
    else:
        m["image_coverage"] = None
        c["image_coverage_missing"] = "no detected corners"
    return m, c


def _brief(r: str) -> str:
    """The first clause of a reason: no parenthesised numbers, nothing after a semicolon."""
    return re.split(r"\s\(|;\s", r, maxsplit=1)[0]


def _short_reason(r: str) -> str:
    r = re.sub(r"^view \S+: ", "", r)
    r = re.sub(r"^outlier: view \S+: ", "outlier: ", r)
    r = re.sub(r"\d+(\.\d+)?", "#", r)
    return r.split(";")[0].split(" (")[0]


# ------------------------------------------------------------------------------ failure
_FAILURE_TIPS = [  # (text in the reason, a tip that complements the error's own hint)
    ("target was found in only", "Count the inner corners (where four squares meet), not the squares, give the "
                                 "square size in metres, and check in the thumbnails below that the board is whole, "
                                 "sharp and evenly lit."),
    ("rotates at most", "Collect views tilted 20-45 deg against each other about two different axes."),
    ("all rotations are about one axis", "Tilt the tool about the other axes as well, not only about one."),
    ("usable views", "Collect 15-25 views with the board fully visible."),
    ("refinement failed", "Re-run with --no-refine to get the closed-form result, and check the per-view table for "
                          "views whose robot pose disagrees with the image."),
    ("intrinsics are for", "Fix the intrinsics' image size in the session or remove the given intrinsics."),
    ("solver failed", "Try another --method (e.g. park) and check the robot poses' units and rotation convention."),
]


def _similar(a: str, b: str) -> bool:
    """Two pieces of advice that share most of their words."""
    wa, wb = (set(re.findall(r"[a-z]{4,}", x.lower())) for x in (a, b))
    return bool(wa and wb) and len(wa & wb) / min(len(wa), len(wb)) > 0.5


def _sentence(s: str) -> str:
    s = s.strip()
    return (s[:1].upper() + s[1:]).rstrip(".") + "." if s else s


def _failure(res: dict, findings: list, *, has_views: bool) -> dict:
    reason = res.get("failure_reason") or "the calibration failed (no reason recorded)"
    problem, _, hint = reason.partition(" -> ")
    path_free = problem
    if ": " in problem and (problem.startswith("/") or problem[1:3] == ":\\"):
        path_free = problem.split(": ", 1)[1]
    actions = [_sentence(hint)] if hint else []

    def add(text: str) -> None:
        if text and not any(_similar(text, a) for a in actions):
            actions.append(text)

    for f in findings:  # the diagnostics name the mistake more precisely than the error can
        if f["severity"] == "fail" and f["action"]:
            add(_sentence(f["action"]))
    if len(actions) < 2:
        for key, text in _FAILURE_TIPS:
            if key in reason:
                add(text)
    if not actions:
        actions.append("Read the per-view table for what was found in each image, fix the cause and re-run "
                       "handeye calibrate." if has_views else
                       "Fix what the message names (docs/session_format.md describes the session files) and re-run "
                       "handeye calibrate.")
    return {"reason": reason, "problem": _sentence(path_free), "short": _sentence(path_free),
            "action": "", "actions": actions}


# ------------------------------------------------------------------------------ diagnostics
def _findings(diag: dict) -> list[dict]:
    out = []
    for f in (diag or {}).get("findings") or []:
        if not isinstance(f, dict):
            continue
        sev = str(f.get("severity", "info")).lower()
        sev = sev if sev in SEVERITY_ORDER else "info"
        out.append({"code": f.get("code", ""), "severity": sev, "title": f.get("title", f.get("code", "finding")),
                    "evidence": _cap1(f.get("evidence", "")), "action": _cap1(f.get("action", "")),
                    "view_ids": [str(v) for v in (f.get("view_ids") or [])]})
    out.sort(key=lambda f: SEVERITY_ORDER[f["severity"]])
    return out


def _col_title(key: str) -> str:
    """``held_out_rms_px`` -> ``Held out rms [px]``."""
    k = str(key)
    unit = ""
    for suf in ("px", "mm", "deg", "m", "rad"):
        if k.endswith("_" + suf):
            k, unit = k[: -len(suf) - 1], f" [{suf}]"
            break
    k = k.replace("_", " ").replace("rms", "RMS")
    return k[:1].upper() + k[1:] + unit


def _cap1(s) -> str:
    s = str(s or "")
    return s[:1].upper() + s[1:]


def _cross_validation(cv) -> Optional[dict]:
    """The diagnostics' held-out validation: summary, spread against prediction, per-view table.

    Known keys (jackknife_sigma_*, predicted_sigma_*, per_view) get a dedicated layout; anything
    else is shown generically (scalars as items, lists of dicts as tables)."""
    if not isinstance(cv, dict) or not cv:
        return None
    summary = str(cv.get("summary") or cv.get("conclusion") or "")
    out = {"summary": summary, "items": [], "tables": [], "not_run": summary.startswith("not run"),
           "spread": None, "verdict": cv.get("verdict", "")}
    used = {"summary", "conclusion", "verdict"}
    if "jackknife_sigma_rot_deg" in cv or "jackknife_sigma_trans_mm" in cv:
        rows = [("Held-out spread (jackknife, 1 σ)", cv.get("jackknife_sigma_rot_deg"), cv.get("jackknife_sigma_trans_mm"))]
        if cv.get("predicted_sigma_rot_deg") is not None:
            rows.append(("Predicted by the covariance (1 σ)", cv.get("predicted_sigma_rot_deg"),
                         cv.get("predicted_sigma_trans_mm")))
        out["spread"] = {"rows": [{"name": n, "rot": list(r or [None] * 3), "trans": list(t or [None] * 3)}
                                  for n, r, t in rows],
                         "ratio_rot": cv.get("ratio_rot"), "ratio_trans": cv.get("ratio_trans"),
                         "axes": cv.get("axes", "")}
        used |= {"jackknife_sigma_rot_deg", "jackknife_sigma_trans_mm", "predicted_sigma_rot_deg",
                 "predicted_sigma_trans_mm", "ratio_rot", "ratio_trans", "axes"}
    labels = {"method": "Refit", "scheme": "Scheme", "n_views": "Views", "n_folds": "Folds",
              "folds_solved": "Folds solved", "held_out_rms_px_median": "Held-out RMS, median [px]"}
    for k, v in cv.items():
        if k in used:
            continue
        name = labels.get(k, k.replace("_", " "))
        if isinstance(v, (int, float, str, bool)) or v is None:
            out["items"].append({"name": name, "value": v})
        elif isinstance(v, list) and v and all(isinstance(r, dict) for r in v):
            cols = list(dict.fromkeys(c for r in v for c in r if not isinstance(r[c], (list, dict))))
            out["tables"].append({"name": name, "cols": [_col_title(c) for c in cols],
                                  "rows": [[r.get(c) for c in cols] for r in v]})
        elif isinstance(v, list) and v and all(isinstance(x, (int, float)) for x in v) and len(v) <= 6:
            out["items"].append({"name": name, "value": ", ".join(f"{x:.4g}" for x in v)})
        elif isinstance(v, dict):
            for kk, vv in v.items():
                if isinstance(vv, (int, float, str, bool)):
                    out["items"].append({"name": f"{name} {kk}".replace("_", " "), "value": vv})
    return out


# ------------------------------------------------------------------------------ KPIs
def _kpis(metrics, pred, wd, views, verdict: Verdict, ok: bool) -> list[dict]:
    status = {k: c.status for c in verdict.checks for k in c.key.split("+")}
    out = []
    if pred is not None:
        out.append({"label": f"Predicted error at {wd:.2f} m", "value": f"{pred['rms_mm']:.2f} mm",
                    "sub": f"1 σ RMS 3-D · 95 %: {pred['r95_mm']:.2f} mm", "status": status.get("predicted_error_mm", "")})
    elif ok:
        out.append({"label": "Predicted error", "value": "n/a", "sub": "no covariance (--no-refine)",
                    "status": status.get("predicted_error_mm", "")})
    v = metrics.get("reprojection_rms_px")
    if v is not None:
        out.append({"label": "Reprojection RMS", "value": f"{v:.2f} px", "sub": "detected vs predicted corners",
                    "status": status.get("reprojection_rms_px", "")})
    n_used = sum(x["status"] == "used" for x in views)
    if views:
        out.append({"label": "Views used", "value": f"{n_used} / {len(views)}",
                    "sub": f"{len(views) - n_used} dropped or flagged", "status": status.get("used_views", "")})
    mr, sp = metrics.get("max_rotation_deg"), metrics.get("axis_spread_deg")
    if mr is not None:
        out.append({"label": "Rotation coverage", "value": f"{mr:.0f}°",
                    "sub": f"largest rotation; axis spread {sp:.0f}°" if sp is not None else "largest rotation",
                    "status": max((status.get("max_rotation_deg", "pass"), status.get("axis_spread_deg", "pass")),
                                  key=lambda s: {"pass": 0, "info": 1, "warn": 2, "fail": 3}.get(s, 0))})
    return out


# ------------------------------------------------------------------------------ provenance
def _provenance(res, qa_cfg, qa_source) -> dict:
    import yaml

    prov = dict(res.get("provenance") or {})
    options = prov.pop("options", None)
    rows = []
    labels = {"handeye_version": "handeye version", "command_line": "Command line", "time_utc": "Calibrated (UTC)",
              "inputs_sha256": "Input hash (SHA-256 of images and pose files)", "python": "Python",
              "opencv": "OpenCV"}
    for k in ("handeye_version", "command_line", "time_utc", "inputs_sha256", "python", "opencv"):
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
        rows.append({"name": "Run time", "value": ", ".join(f"{k} {v:.1f} s" for k, v in secs.items()), "mono": False})
    import sys

    report_cmd = " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv and sys.argv[0] else ""
    if report_cmd and report_cmd != (res.get("provenance") or {}).get("command_line") and "pytest" not in report_cmd:
        rows.append({"name": "Report command line", "value": report_cmd, "mono": True})
    rows.append({"name": "Report generated (UTC)", "value": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                 "mono": False})
    rows.append({"name": "QA thresholds", "value": qa_source, "mono": True})
    config = {}
    if options:
        config["calibration options"] = options
    ref_opts = (res.get("refinement") or {}).get("options") if isinstance(res.get("refinement"), dict) else None
    if ref_opts:
        config["refinement options"] = ref_opts
    config["QA thresholds"] = qa_cfg
    return {"rows": rows, "config_yaml": yaml.safe_dump(plain(config), sort_keys=False, default_flow_style=None,
                                                        width=100).strip()}


# ------------------------------------------------------------------------------ plots
def _plots(res, obs, ref, fits, views, T_x, T_board, unc, metrics, mctx, qa_cfg, mode, x_name, parent,
           board_centre) -> list[Plot]:
    out: list[Plot] = []
    used = {v["id"] for v in views if v["status"] == "used"}
    flagged = {v["id"] for v in views if v["status"] != "used"}
    lim = (qa_cfg.get("checks") or {})

    jobs: list = []

    def attempt(key, title, caption, fn):
        jobs.append((key, title, caption, fn))

    # residual histogram
    cam = [fits[v].residual_px for v in fits if v in used]
    chain = [fits[v].residual_chain_px for v in fits if v in used and fits[v].residual_chain_px is not None]
    if cam:
        cam_all = np.concatenate(cam)
        if ref and A.finite(ref.get("sigma_px")):
            sigma, src = float(ref["sigma_px"]), "estimated by the refinement"
        else:
            n_obs = 2 * len(cam_all)
            dof = max(n_obs - 6 * len(cam), 1)
            sigma, src = float(np.sqrt(np.sum(cam_all ** 2) / dof)), "from the camera-fit residuals"
        attempt("residuals", "Residuals against the noise model",
                "Lengths of the corner residuals. Left: each view fitted on its own (camera, intrinsics, corner "
                "detection). Right: the board predicted through the reported robot pose and the result — the "
                "difference between the two is what the robot's pose error adds. The curve is the distribution "
                "the residual lengths follow when the pixel noise is Gaussian with the stated σ.",
                lambda: plots.residual_histogram(cam_all, np.concatenate(chain) if chain else None, sigma_px=sigma,
                                                 sigma_source=src))
    # per-view bars
    if views and any(A.finite(v["rms_px"]) for v in views):
        rl = lim.get("reprojection_rms_px") or {}
        attempt("per_view", "Residual per view",
                "RMS residual of each view, fitted on its own (dark) and through the robot chain (light). "
                "Red outlines: views dropped or flagged; dashed lines: QA limits of the reprojection RMS.",
                lambda: plots.per_view_bars([v["id"] for v in views], [v["rms_px"] for v in views],
                                            [v["chain_rms_px"] for v in views], [v["status"] for v in views],
                                            warn_px=rl.get("warn_above"), fail_px=rl.get("fail_above")))
    # coverage
    size = (res.get("intrinsics") or {}).get("image_size") or obs.get("image_size")
    if size and fits and "coverage_counts" in mctx:
        vv = [(vid, f.image_points_px, f.residual_px, vid in flagged) for vid, f in fits.items()]
        attempt("coverage", "Image coverage and residual vectors",
                "Left: where the detected corners fall (cell shading = number of corners; outlines = each view's "
                "board). Lens distortion is only known where corners were seen. Right: the camera-fit residual "
                "of every corner, magnified; a systematic pattern (swirl, radial) points at a lens model that "
                "does not fit.",
                lambda: plots.image_coverage(int(size[0]), int(size[1]), vv, mctx["coverage_counts"],
                                             coverage_share=float(metrics.get("image_coverage") or 0.0)))
    # 3-D poses
    if T_x is not None and T_board is not None:
        ids = [v["id"] for v in views if v["id"] in (obs.get("views") or {})]
        Ts = [A.as_T(obs["views"][v].get("T_base_end_reported")) for v in ids]
        keep = [i for i, T in enumerate(Ts) if T is not None]
        if keep:
            T_be = np.stack([Ts[i] for i in keep])
            if mode == "eye_in_hand":
                cams = T_be @ T_x
                boards = np.repeat(T_board[None], len(T_be), axis=0)
            else:
                cams = np.repeat(T_x[None], len(T_be), axis=0)
                boards = T_be @ T_board
            outline = _board_outline(obs)
            fl = [ids[i] in flagged for i in keep]
            attempt("poses", "Robot, camera and board",
                    "Robot poses (small axes: x red, y green, z blue) as reported, the camera"
                    + (" at each pose" if mode == "eye_in_hand" else "") + " and the board"
                    + (" at each pose" if mode == "eye_to_hand" else "")
                    + " under the result, in the robot base frame. Red: views dropped or flagged.",
                    lambda: plots.poses_3d(T_base_cams=cams, T_base_ends=T_be, T_base_boards=boards,
                                           board_outline=outline, flagged=fl, mode=mode))
    # rotation coverage
    rv = mctx.get("rotvecs")
    if rv is not None and len(rv):
        rl = lim.get("max_rotation_deg") or {}
        attempt("rotations", "Rotation coverage",
                "Every pair of used views defines a robot rotation. Left: its axis (a point per pair, folded into "
                "one hemisphere, equal-area; colour = angle). Axes spread over the disk constrain the hand-eye "
                "rotation in all directions; a line or a cluster means one axis is missing. Right: the rotation "
                "angles between view pairs.",
                lambda: plots.rotation_coverage(rv, frame=mctx.get("axis_frame", ""), warn_deg=rl.get("warn_below"),
                                                fail_deg=rl.get("fail_below")))
    # uncertainty
    if T_x is not None:
        meth = []
        for m, e in (res.get("closed_form") or {}).items():
            T = A.as_T(e.get(x_name))
            if T is not None:
                meth.append((m, (T[:3, 3] - T_x[:3, 3]) * 1e3))
        cov_t = unc["cov_translation_mm2"] if unc is not None else None
        if cov_t is not None or meth:
            attempt("uncertainty", "Uncertainty of the translation",
                    ("1-σ (solid) and 2-σ (dashed) ellipses of the hand-eye translation from the refinement's "
                     "covariance" if cov_t is not None else "No covariance (closed form only)")
                    + "; markers: the closed-form methods, relative to the result. The closed-form methods treat "
                    "the robot poses as exact and weigh views unevenly, so they scatter more than the refined "
                    "result; one method far from all others points at weak motion or a bad pose.",
                    lambda: plots.translation_uncertainty(cov_t, meth, frame=parent, x_name=x_name))
    for (key, title, caption, _), (png, err) in zip(jobs, _draw_all([j[3] for j in jobs])):
        if err:  # a plot that cannot be drawn must not cost the whole report
            log.warning("report: plot %s skipped: %s", key, err)
        elif png:
            out.append(Plot(key, title, caption, png))
    return out


_PLOT_JOBS: list = []  # read by forked workers (closures need no pickling)


def _draw_one(k: int):
    try:
        return _PLOT_JOBS[k](), ""
    except Exception as e:  # noqa: BLE001 - reported per plot by the caller
        return None, f"{type(e).__name__}: {e}"


def _draw_all(fns: list) -> list:
    """Draw the plots, on all cores where the platform can fork (matplotlib is single-threaded)."""
    import multiprocessing as mp
    import os
    from concurrent.futures import ProcessPoolExecutor

    _PLOT_JOBS[:] = fns
    try:
        workers = min(len(fns), os.cpu_count() or 1)
        if workers > 1 and "fork" in mp.get_all_start_methods():
            try:
                with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as ex:
                    return list(ex.map(_draw_one, range(len(fns))))
            except (OSError, RuntimeError) as e:  # e.g. no fork allowed: draw here instead
                log.debug("report: parallel plotting unavailable (%s)", e)
        return [_draw_one(k) for k in range(len(fns))]
    finally:
        _PLOT_JOBS.clear()


def _board_outline(obs) -> np.ndarray:
    obj = np.asarray(obs.get("object_points_m") or [], float).reshape(-1, 3)
    if not len(obj):
        return np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0.15, 0], [0, 0.15, 0]], float)
    lo, hi = obj.min(axis=0), obj.max(axis=0)
    sq = (obs.get("target") or {}).get("square_m") or 0.0
    lo, hi = lo - sq, hi + sq
    return np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]], float)


# ------------------------------------------------------------------------------ thumbnails
def _thumbs(views, fits, ref, image_paths, *, width_px: int = 240) -> dict[str, bytes]:
    import cv2

    flagged_corners: dict[str, set] = {}
    for o in (ref or {}).get("outliers") or []:
        if o.get("corner_ids"):
            flagged_corners.setdefault(str(o.get("view_id")), set()).update(int(c) for c in o["corner_ids"])
    out = {}
    for v in views:
        p = image_paths.get(v["id"])
        if p is None or not Path(p).exists():
            continue
        img, factor = None, 1
        for flag, factor in ((cv2.IMREAD_REDUCED_COLOR_4, 4), (cv2.IMREAD_REDUCED_COLOR_2, 2), (cv2.IMREAD_COLOR, 1)):
            img = cv2.imread(str(p), flag)  # JPEG decodes at 1/4 or 1/2 size several times faster
            if img is None or img.shape[1] >= width_px:
                break
        if img is None:
            continue
        h, w = img.shape[:2]
        s = width_px / (w * factor)  # full-resolution pixels -> thumbnail pixels
        small = cv2.resize(img, (width_px, max(1, int(round(h * factor * s)))), interpolation=cv2.INTER_AREA)
        fit = fits.get(v["id"])
        if fit is not None:
            bad = flagged_corners.get(v["id"], set())
            for cid, (u, vv) in zip(fit.corner_ids, fit.image_points_px):
                color = (40, 40, 220) if int(cid) in bad else (60, 190, 60)
                cv2.circle(small, (int(round(u * s)), int(round(vv * s))), 2, color, -1, lineType=cv2.LINE_AA)
        ok, buf = cv2.imencode(".png", small, [cv2.IMWRITE_PNG_COMPRESSION, 3])
        if ok:
            out[v["id"]] = buf.tobytes()
    return out
