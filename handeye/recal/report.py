"""verify.html and verify.md from verify.json alone, in the calibration report's style.

They use the calibration report's stylesheet and number filters (:mod:`handeye.report.render`).
"""

from __future__ import annotations

from pathlib import Path

from ..output import atomic_write_text, read_json


def installed_report_link(v: dict, out_dir) -> str:
    """The installed result's report.html relative to the verification's folder ``out_dir``, or "" without one."""
    import os

    against = Path(str(v.get("against") or ""))
    report = (against.parent if against.suffix == ".json" else against) / "report.html"
    try:
        return Path(os.path.relpath(report, Path(out_dir))).as_posix() if report.is_file() else ""
    except (OSError, ValueError):  # another drive: no relative path
        return ""


def verify_context(v: dict, out_dir=None) -> dict:
    """What verify.html and verify.md show of verify.json ``v``: result.json's keys and statuses in words.

    ``out_dir``: the reports' folder, for the link to the installed result's report.
    """
    from ..report.sections.views import OUTLIER_KIND_TEXT
    from ..results import cov_source_words
    from .loaded import axes_words
    from .verification import disagreeing_poses

    drifted = bool(v.get("drifted"))
    mode = v.get("mode", "")
    status_text = {
        "used": "used",
        "robot_excluded": f"not used: its {OUTLIER_KIND_TEXT['robot_pose']}",
        "removed": "not used: its corners do not fit or are too few",
    }
    robot = [str(r) for r in (v.get("robot") or {}).get("views") or []]
    return {
        "v": v,
        "covariance_text": cov_source_words(str((v.get("test") or {}).get("covariance_used") or "none")),
        "change_text": "new minus installed, as the test estimates it, with its 1-sigma (the installed and the new "
        f"views' uncertainty together); {axes_words(str(v.get('frame') or ''))}",
        "status_text": {
            vid: status_text.get(str(d.get("status")), d.get("status")) for vid, d in (v.get("views") or {}).items()
        },
        "robot_text": disagreeing_poses(robot) if robot else "every robot pose agrees with the camera",
        "label": "DRIFTED" if drifted else "STILL VALID",
        "status": "fail" if drifted else "pass",
        "session_name": Path(str((v.get("session") or {}).get("path", "session"))).name,
        "mode_text": {
            "eye_in_hand": "Eye-in-hand (camera on the robot)",
            "eye_to_hand": "Eye-to-hand (camera fixed, board on the robot)",
        }.get(mode, mode),
        "checked_utc": str((v.get("provenance") or {}).get("time_utc", "")).replace("T", " ").replace("+00:00", " UTC"),
        "installed_report": installed_report_link(v, out_dir) if out_dir is not None else "",
    }


def write_verification(sv, out_dir, *, reports: bool = True) -> tuple[dict, list[Path]]:
    """verify.json of a verification in ``out_dir`` and, with ``reports``, verify.html and verify.md.

    verify.json of a :class:`~handeye.recal.verify.SessionVerification` in ``out_dir`` and, with
    ``reports``, verify.html and verify.md from it: (verify.json's content, the files written).
    """
    from ..contract import Verify, write_validated
    from .verify import verify_dict

    d = verify_dict(sv)
    files = [write_validated(Path(out_dir) / "verify.json", d, Verify)]
    if reports:
        files += write_verify_reports(out_dir)
    return d, files


def write_verify_reports(out_dir, *, formats=("html", "md")) -> list[Path]:
    """Render verify.html / verify.md in ``out_dir`` from its verify.json."""
    from ..report.render import _env, _tidy_markdown

    out_dir = Path(out_dir)
    ctx = verify_context(read_json(out_dir / "verify.json"), out_dir)
    written = []
    if "html" in formats:
        written.append(
            atomic_write_text(out_dir / "verify.html", _env(html=True).get_template("verify.html.j2").render(**ctx))
        )
    if "md" in formats:
        written.append(
            atomic_write_text(
                out_dir / "verify.md", _tidy_markdown(_env(html=False).get_template("verify.md.j2").render(**ctx))
            )
        )
    return written
