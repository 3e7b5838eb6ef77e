"""The report's header (session, target, versions, times) and its provenance table."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

from ... import __version__
from ...output import command_line, plain
from ...session.target_spec import is_tracked, target_words

#: settings that act on images only (corners, intrinsics, image coverage): a pose-only report leaves them out
IMAGE_ONLY = {
    "calibration options": ("fix_k3",),
    "refinement options": (
        "intrinsics",
        "intrinsics_prior_sigma",
        "fix",
        "corner_outlier_sigmas",
        "min_corner_outlier_px",
        "min_corners",
    ),
    "QA thresholds": ("coverage_grid_cells_x",),
    "QA checks": ("reprojection_rms_px", "image_coverage"),
}


def _meta(res: dict, obs: dict) -> dict:
    prov = res.get("provenance") or {}
    sess = res.get("session") or {}
    path = sess.get("path") or ""
    nv = res.get("n_views") or {}
    size = (res.get("intrinsics") or {}).get("image_size") or obs.get("image_size")
    target = res.get("target") or obs.get("target")
    return {
        "session_name": Path(path).name if path else "session",
        "session_path": path,
        "session_format": sess.get("format", ""),
        "pose_format": sess.get("pose_format", ""),
        "target": target_words(target) if target else "",
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


def _provenance(res, qa_cfg, qa_source) -> dict:
    import yaml

    prov = dict(res.get("provenance") or {})
    options = prov.pop("options", None)
    tracked = is_tracked(res.get("target"))  # a pose-only session: no images, no corners, no intrinsics
    rows = []
    labels = {
        "handeye_version": "handeye version",
        "command_line": "Command line",
        "time_utc": "Calibrated (UTC)",
        "inputs_sha256": "Input hash (SHA-256 of the pose and session files)"
        if tracked
        else "Input hash (SHA-256 of images and pose files)",
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
                "value": ", ".join(
                    f"{k.replace('_', ' ')} {v:.2f} s" for k, v in secs.items() if isinstance(v, (int, float))
                ),
                "mono": False,
            }
        )
    report_cmd = command_line()
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
    if tracked:
        config = _without_image_settings(config)
    return {
        "rows": rows,
        "config_yaml": yaml.safe_dump(plain(config), sort_keys=False, default_flow_style=None, width=100).strip(),
    }


def _without_image_settings(config: dict) -> dict:
    """``config`` (the Configuration block) without the settings that act on images only (:data:`IMAGE_ONLY`)."""
    out = {}
    for section, values in config.items():
        if isinstance(values, dict):
            values = {k: v for k, v in values.items() if k not in IMAGE_ONLY.get(section, ())}
            if section == "QA thresholds" and isinstance(values.get("checks"), dict):
                checks = values["checks"]
                values["checks"] = {k: v for k, v in checks.items() if k not in IMAGE_ONLY["QA checks"]}
        out[section] = values
    return out
