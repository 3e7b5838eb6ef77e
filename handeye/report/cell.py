"""A cell's report (``handeye report CELL_DIR``): one table of its cameras, one of its camera pairs.

Per camera its mounting mode, X (translation in mm, rotation vector in deg), their 1-sigma (from the
covariance its verdict uses), the views used, the residual and its verdict; per camera pair ``T_a_b`` with
its 1-sigma; the cell's verdict. Built from result.json alone, written as report.html and report.md
(:func:`handeye.report.write_reports` sends a cell here). See docs/report.md.
"""

from __future__ import annotations

import html
from typing import Optional

import numpy as np

from ..frames import rotvec_from_R
from .uncertainty import form_sigmas

VERDICT_ORDER = ("REFUSED", "FAIL", "WARN", "PASS")


def _sigmas(T: np.ndarray, cov) -> tuple[Optional[list], Optional[list]]:
    if cov is None:
        return None, None
    s = form_sigmas(T, np.asarray(cov, float))
    return [float(v) for v in s["translation_mm"]], [float(v) for v in s["rot_cam_deg"]]


def cell_context(res: dict) -> dict:
    """What the cell's report shows, as plain values, from a cell's result.json dict."""
    cams = []
    for name, e in (res.get("cameras") or {}).items():
        x_name = (e.get("hand_eye") or {}).get("name") or (
            "T_end_cam" if e.get("mode") == "eye_in_hand" else "T_base_cam"
        )
        ref = e.get("refinement") or {}
        row = {"name": name, "mode": e.get("mode"), "x_name": x_name, "verdict": e.get("verdict") or "none"}
        row["status"] = e.get("status")
        row["views"] = e.get("n_views") or {}
        row["rms_px"] = ref.get("rms_px_after")
        if e.get(x_name) is not None:
            T = np.asarray(e[x_name], float)
            cov = ref.get("cov_x_6x6_verdict") or ref.get("cov_x_6x6")
            row["t_mm"] = [float(v) for v in 1000.0 * T[:3, 3]]
            row["rotvec_deg"] = [float(v) for v in np.degrees(rotvec_from_R(T[:3, :3]))]
            row["sigma_t_mm"], row["sigma_rot_deg"] = _sigmas(T, cov)
            row["cov_source"] = "cov_x_6x6_verdict" if ref.get("cov_x_6x6_verdict") else "cov_x_6x6" if cov else "none"
        cams.append(row)
    pairs = []
    for key, p in (res.get("camera_pairs") or {}).items():
        T = np.asarray(p["matrix"], float)
        st, sr = _sigmas(T, p.get("cov_6x6_verdict") or p.get("cov_6x6"))
        pairs.append(
            {
                "key": key,
                "name": p.get("name"),
                "t_mm": [float(v) for v in 1000.0 * T[:3, 3]],
                "distance_mm": float(1000.0 * np.linalg.norm(T[:3, 3])),
                "angle_deg": float(np.degrees(np.linalg.norm(rotvec_from_R(T[:3, :3])))),
                "sigma_t_mm": st,
                "sigma_rot_deg": sr,
            }
        )
    verdicts = [c["verdict"] for c in cams]
    worst = next((v for v in VERDICT_ORDER if v in verdicts), "none")
    return {
        "status": res.get("status"),
        "verdict": res.get("verdict") or worst,
        "headline": res.get("verdict_headline") or "",
        "cameras": cams,
        "pairs": pairs,
        "failure_reason": res.get("failure_reason"),
        "provenance": res.get("provenance") or {},
    }


def _v3(v, fmt: str) -> str:
    return "n/a" if v is None else " ".join(format(float(x), fmt) for x in v)


def _rows(ctx: dict) -> tuple[list[str], list[list[str]], list[str], list[list[str]]]:
    """The two tables' headers and cells as text (unescaped)."""
    head = ["camera", "mode", "X", "translation [mm]", "1-sigma [mm]", "rotation vector [deg]", "1-sigma [deg]"]
    head += ["views used", "rms [px]", "verdict"]
    rows = []
    for c in ctx["cameras"]:
        v = c["views"]
        rows.append(
            [
                c["name"],
                str(c["mode"]),
                c["x_name"],
                _v3(c.get("t_mm"), ".2f"),
                _v3(c.get("sigma_t_mm"), ".3f"),
                _v3(c.get("rotvec_deg"), ".3f"),
                _v3(c.get("sigma_rot_deg"), ".4f"),
                f"{v.get('used', '?')} of {v.get('total', '?')}" if v else "n/a",
                f"{c['rms_px']:.3f}"
                if isinstance(c.get("rms_px"), (int, float)) and np.isfinite(c["rms_px"])
                else "n/a",
                str(c["verdict"]),
            ]
        )
    phead = ["pair", "transform", "translation [mm]", "1-sigma [mm]", "distance [mm]", "angle [deg]", "1-sigma [deg]"]
    prows = [
        [
            p["key"],
            str(p["name"]),
            _v3(p["t_mm"], ".2f"),
            _v3(p["sigma_t_mm"], ".3f"),
            f"{p['distance_mm']:.2f}",
            f"{p['angle_deg']:.3f}",
            _v3(p["sigma_rot_deg"], ".4f"),
        ]
        for p in ctx["pairs"]
    ]
    return head, rows, phead, prows


NOTES = (
    "X: the camera's pose in the flange (T_end_cam, eye_in_hand) or in the robot base (T_base_cam, eye_to_hand); "
    "1-sigma of the translation along the parent's axes and of the rotation about the camera's axes, from the "
    "covariance each camera's verdict uses. A pair a/b is T_a_b, camera b's pose in camera a's frame.",
    "Each camera's full result (intrinsics, views, covariances, findings) is its entry in result.json's cameras.",
)


def render_markdown(ctx: dict) -> str:
    """report.md of a cell."""

    def cell(s: str) -> str:
        return str(s).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")

    def table(head, rows) -> list[str]:
        return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + [
            "| " + " | ".join(cell(x) for x in r) + " |" for r in rows
        ]

    head, rows, phead, prows = _rows(ctx)
    n = len(ctx["cameras"])
    lines = [f"# Hand-eye calibration of a cell: {n} cameras", "", f"**Verdict: {cell(ctx['verdict'])}**"]
    if ctx["headline"]:
        lines += ["", cell(ctx["headline"])]
    if ctx["failure_reason"]:
        lines += ["", f"Failed: {cell(ctx['failure_reason'])}"]
    lines += ["", "## Cameras", ""] + table(head, rows)
    lines += ["", "## Camera pairs", ""] + (table(phead, prows) if prows else ["No camera pairs in this result."])
    lines += ["", *(f"- {cell(s)}" for s in NOTES), ""]
    return "\n".join(lines)


def render_html(ctx: dict) -> str:
    """report.html of a cell (one self-contained file)."""
    e = html.escape

    def table(head, rows) -> str:
        th = "".join(f"<th>{e(h)}</th>" for h in head)
        trs = "".join("<tr>" + "".join(f"<td>{e(str(x))}</td>" for x in r) + "</tr>" for r in rows)
        return f"<table><thead><tr>{th}</tr></thead><tbody>{trs}</tbody></table>"

    head, rows, phead, prows = _rows(ctx)
    n = len(ctx["cameras"])
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>Hand-eye calibration of a cell: {n} cameras</title>",
        "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:first-child{text-align:left}</style>",
        "</head><body>",
        f"<h1>Hand-eye calibration of a cell: {n} cameras</h1>",
        f'<p class="verdict"><strong>Verdict: {e(str(ctx["verdict"]))}</strong></p>',
    ]
    if ctx["headline"]:
        parts.append(f"<p>{e(ctx['headline'])}</p>")
    if ctx["failure_reason"]:
        parts.append(f"<p>Failed: {e(str(ctx['failure_reason']))}</p>")
    parts += ["<h2>Cameras</h2>", table(head, rows), "<h2>Camera pairs</h2>"]
    parts.append(table(phead, prows) if prows else "<p>No camera pairs in this result.</p>")
    parts += ["<ul>", *(f"<li>{e(s)}</li>" for s in NOTES), "</ul>", "</body></html>", ""]
    return "\n".join(parts)


def render_reports(res: dict, formats=("html", "md")) -> tuple:
    """(html or None, (Markdown, {}) or None) of a cell's result.json dict, for :func:`.render.write_files`."""
    ctx = cell_context(res)
    return (
        render_html(ctx) if "html" in formats else None,
        (render_markdown(ctx), {}) if "md" in formats else None,
    )
