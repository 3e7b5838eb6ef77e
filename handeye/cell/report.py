"""A cell's report (report.md and report.html) from its result.json content alone.

A short cell section (verdict, the arm's error model, the shared board, the camera pairs with their sigmas,
the cross-camera findings) and each camera's key numbers (X with its sigmas, the pixel noise, the solo
agreement, views used); each camera's full report is its solo folder's.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

import numpy as np

from ..output import atomic_write_text


def _fmt(v, spec: str = ".3f") -> str:
    try:
        return format(float(v), spec)
    except (TypeError, ValueError):
        return "-"


def _rotvec_deg(T) -> list:
    """The rotation vector (deg) of a 4x4 transform, or [] when it is not one."""
    from ..frames import rotvec_from_R

    try:
        M = np.asarray(T, float)
        return np.degrees(rotvec_from_R(M[:3, :3])).tolist() if M.shape == (4, 4) else []
    except (TypeError, ValueError):
        return []


def cell_markdown(res: dict) -> str:
    """The cell's report as Markdown."""
    lines = [f"# Cell of {len(res.get('cameras') or {})} cameras: {res.get('verdict', '?')}", ""]
    prov = res.get("provenance") or {}
    when = str(prov.get("time_utc") or "").replace("T", " ").replace("+00:00", " UTC")
    lines += [f"Calibrated {when or '-'} · handeye {prov.get('handeye_version') or '-'}", ""]
    if prov.get("command_line"):
        lines += [f"Command: `{prov['command_line']}`", ""]
    lines += [res.get("verdict_headline", ""), ""]
    ref = res.get("refinement") or {}
    rm = ref.get("robot_model") or {}
    lines.append(f"Arm error model: {rm.get('kind', '?')}" + (f" ({rm['arm']})" if rm.get("arm") else "") + ".")
    if res.get("board"):
        b = res["board"]
        cov = np.asarray(ref.get("cov_board_6x6") or np.full((6, 6), np.nan))
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        lines.append(
            f"Shared board {b['name']}: translation [mm] {' '.join(_fmt(x, '.2f') for x in b['translation_mm'])}, "
            f"1-sigma {_fmt(1e3 * np.linalg.norm(sd[3:]), '.3f')} mm / "
            f"{_fmt(np.degrees(np.linalg.norm(sd[:3])), '.4f')} deg."
        )
    lines += [
        "",
        "## Camera pairs",
        "",
        "| pair | translation [mm] | rotation vector [deg] | 1-sigma trans [mm] | 1-sigma rot [deg] |",
        "|---|---|---|---|---|",
    ]
    for p in (res.get("camera_pairs") or {}).values():
        lines.append(
            f"| {p['name']} | {' '.join(_fmt(x, '.2f') for x in p.get('translation_mm', []))} | "
            f"{' '.join(_fmt(x, '.3f') for x in _rotvec_deg(p.get('matrix')))} | "
            f"{' '.join(_fmt(x, '.3f') for x in p.get('sigma_trans_mm', []))} | "
            f"{' '.join(_fmt(x, '.4f') for x in p.get('sigma_rot_deg', []))} |"
        )
    lines += [
        "",
        "## Cameras",
        "",
        "| camera | mode | verdict | X | X translation [mm] | X rotation vector [deg] | 1-sigma [mm] | "
        "1-sigma [deg] | sigma px | solo vs joint (Mahalanobis) | views used |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, c in (res.get("cameras") or {}).items():
        he, r = c.get("hand_eye") or {}, c.get("refinement") or {}
        agree = (r.get("solo") or {}).get("agreement") or {}
        n = c.get("n_views") or {}
        mode = str(c.get("mode") or "-")
        lines.append(
            f"| {name} | {mode.replace('_', '-')} | {c.get('verdict', '?')} | {he.get('name', '-')} | "
            f"{' '.join(_fmt(x, '.2f') for x in he.get('translation_mm', []))} | "
            f"{' '.join(_fmt(x, '.3f') for x in he.get('rotvec_deg', []))} | "
            f"{' '.join(_fmt(x, '.3f') for x in r.get('sigma_trans_mm', []))} | "
            f"{' '.join(_fmt(x, '.4f') for x in r.get('sigma_rot_deg', []))} | {_fmt(r.get('sigma_px'))} | "
            f"{_fmt(agree.get('mahalanobis'), '.2f')} | {n.get('used', '-')}/{n.get('total', '-')} |"
        )
    lines += ["", "## Cross-camera findings", ""]
    found = res.get("findings") or []
    for f in found:
        who = f" (camera {f['camera']})" if f.get("camera") else ""
        lines.append(f"- **{f['severity'].upper()}** {f['title']}{who}: {f['evidence']}. {f['action']}")
    if not found:
        lines.append("None: the cameras agree about the arm's poses, and each camera's own result with the cell's.")
    lines += ["", "## Each camera's own calibration", ""]
    for name, c in (res.get("cameras") or {}).items():
        why = str(c.get("verdict_headline") or c.get("failure_reason") or "").strip()
        lines.append(f"- **{name}** ({c.get('verdict', '?')}): {why} [its report](solo/{name}/report.md)")
    lines.append("")
    return "\n".join(lines)


_STYLE = (
    "body{font-family:'DejaVu Sans',Arial,sans-serif;color:#1d2733;max-width:1100px;margin:24px auto;padding:0 16px}"
    "table{border-collapse:collapse;margin:8px 0 16px}th,td{border:1px solid #d5dbe3;padding:4px 8px;text-align:left}"
    "th{background:#f1f4f8}h1{font-size:22px}h2{font-size:17px;margin-top:24px}"
)
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")


def _html_link(m: re.Match) -> str:
    """A Markdown link as an HTML one; a solo camera's report.md becomes its report.html."""
    return f'<a href="{m.group(2).replace("report.md", "report.html")}">{m.group(1)}</a>'


def cell_html(res: dict) -> str:
    """The cell's report as a self-contained HTML page (the Markdown's content, tables as tables, links as links)."""
    out = [
        "<!doctype html><html lang='en'><head><meta charset='utf-8'><title>handeye cell</title>"
        f"<style>{_STYLE}</style></head><body>"
    ]
    in_table = False
    for line in cell_markdown(res).splitlines():
        if line.startswith("|"):
            cells = [html.escape(x.strip()) for x in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            tag = "td" if in_table else "th"  # a table's first row is its header
            if not in_table:
                out.append("<table>")
                in_table = True
            out.append("<tr>" + "".join(f"<{tag}>{c}</{tag}>" for c in cells) + "</tr>")
            continue
        if in_table:
            out.append("</table>")
            in_table = False
        if line.startswith("## "):
            out.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.startswith("# "):
            out.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("- "):
            text = re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", html.escape(line[2:]))
            text = _LINK.sub(_html_link, text)
            out.append(f"<p>{text}</p>")
        elif line:
            out.append(f"<p>{html.escape(line)}</p>")
    if in_table:
        out.append("</table>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def write_cell_report(out_dir, res: dict) -> list[Path]:
    """Write report.md and report.html of a cell into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    return [
        atomic_write_text(out / "report.md", cell_markdown(res)),
        atomic_write_text(out / "report.html", cell_html(res)),
    ]
