"""The per-view table: status, residuals, robot disagreement, flags and corners of every view."""

from __future__ import annotations

import re

from ...records import IMAGE_MISSING_REASON, SHIFT_UNPAIRED_REASON
from ..observations import board_disagreement
from .values import _num

#: what a refinement outlier of each kind means for its view (the reason text itself is shown as is)
OUTLIER_KIND_TEXT = {
    "robot_pose": "robot pose disagrees with the camera",
    "reprojection": "corners do not fit",
    "too_few_corners": "too few usable corners",
    "corners": "outlier corners",
}


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
            # one word for one state, as the command prints it: a view that did not serve X is dropped (the flag
            # says why: an outlier of the refinement keeps serving the intrinsics)
            status = "dropped"
            kind = next((OUTLIER_KIND_TEXT.get(k, k) for k in kinds if k), "")
            reason_kind = kind or (
                "image missing"
                if str(v.get("reason") or "").startswith(IMAGE_MISSING_REASON)
                else "no pose (shifted)"
                if str(v.get("reason") or "").startswith(SHIFT_UNPAIRED_REASON)
                else "target not found"
                if fit is None
                else "not used"
            )
            flags.append({"severity": "fail", "text": _strip_view_prefix(v.get("reason") or "not used")})
        elif pv.get("status") == "robot_excluded":
            status, reason_kind = "dropped", OUTLIER_KIND_TEXT["robot_pose"]
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
        # flagged: in the dropped share once, dropped or its robot pose excluded (it did not serve X);
        # a used view with a few outlier corners is listed (corner_flags), not counted: its pose served X
        # (a pose line whose image was deleted, or an image that --shift-poses leaves without a pose, is listed as
        # dropped, not counted: nothing was captured badly)
        flagged = status != "used" and reason_kind not in ("image missing", "no pose (shifted)")
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
