"""verify.html and verify.md from verify.json alone, in the calibration report's style.

They use the calibration report's stylesheet and number filters (:mod:`handeye.report.render`).
"""

from __future__ import annotations

from pathlib import Path

from ..output import atomic_write_text, read_json


def verify_context(v: dict) -> dict:
    drifted = bool(v.get("drifted"))
    mode = v.get("mode", "")
    return {
        "v": v,
        "label": "DRIFTED" if drifted else "STILL VALID",
        "status": "fail" if drifted else "pass",
        "session_name": Path(str((v.get("session") or {}).get("path", "session"))).name,
        "mode_text": {
            "eye_in_hand": "Eye-in-hand (camera on the robot)",
            "eye_to_hand": "Eye-to-hand (camera fixed, board on the robot)",
        }.get(mode, mode),
        "checked_utc": str((v.get("provenance") or {}).get("time_utc", "")).replace("T", " ").replace("+00:00", " UTC"),
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
    ctx = verify_context(read_json(out_dir / "verify.json"))
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
