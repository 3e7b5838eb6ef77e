"""The fleet index's rows: one per session folder under OUT, from its files alone.

:func:`session_row` reads a session's batch record and its result.json (or verify.json); a file that
does not parse or holds a field of the wrong kind (:func:`result_fields`, then the result contract's
checks) makes the row ``damaged`` with the field named, never a crash of the index.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..contract import validate_result
from ..errors import VERDICTS, HandeyeError, InputError, clip
from .run import RECORD_NAME, read_json

log = logging.getLogger(__name__)

#: fleet.csv's columns, in order
COLUMNS = (
    "install",
    "session",
    "time_utc",
    "time_source",
    "mode",
    "verdict",
    "outcome",
    "x_name",
    "tx_mm",
    "ty_mm",
    "tz_mm",
    "rx_deg",
    "ry_deg",
    "rz_deg",
    "sigma_tx_mm",
    "sigma_ty_mm",
    "sigma_tz_mm",
    "sigma_rx_deg",
    "sigma_ry_deg",
    "sigma_rz_deg",
    "sigma_source",
    "reprojection_rms_px",
    "findings",
    "reason",
    "result_dir",
    "report",
    "export_error",
    "warnings",
    "camera",  # a cell's camera (its row's session is <cell>/<camera>); last, so the earlier columns keep their places
)
#: how many findings codes the fleet summary lists
TOP_FINDINGS = 10
FILES_DIR = "index_files"
#: a row's outcome when its result.json cannot be read
DAMAGED = "damaged"
#: what reading one result for one row may raise; one session's fault, never the index's
ROW_ERRORS = (HandeyeError, ValueError, TypeError, KeyError, AttributeError, IndexError)
#: the file discovery's skipped folders are kept in (written by the batch, read by the index)
SKIPPED_NAME = "skipped.json"


class DamagedResult(InputError):
    """A result.json (or verify.json) whose content the fleet index cannot use: the field and why."""

    code = "result_damaged"


def _damaged(field: str, value, expected: str) -> DamagedResult:
    kind = {dict: "a mapping", list: "a list", str: "a text", bool: "a boolean", type(None): "null"}.get(
        type(value), type(value).__name__
    )
    return DamagedResult(f"field {field} is {kind} ({clip(repr(value), 40)})", expected=expected)


def _text(d: dict, key: str, field: str, *, choices=None) -> Optional[str]:
    """``d[key]`` as a text, None when absent.

    DamagedResult naming ``field`` when it is another kind or not one of ``choices``.
    """
    v = d.get(key)
    if v is None:
        return None
    if not isinstance(v, str) or (choices is not None and v not in choices):
        raise _damaged(field, v, "one of " + ", ".join(choices) if choices else "a text")
    return v


def _mapping(d: dict, key: str, field: str) -> dict:
    """``d[key]`` as a mapping ({} when absent or null); DamagedResult when it is another kind."""
    v = d.get(key)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise _damaged(field, v, "a mapping")
    return v


def _number(v, field: str, *, nan_is_missing: bool = False) -> Optional[float]:
    """A finite number, or None when absent (``nan_is_missing``: also NaN, a figure the run could not have)."""
    if v is None:
        return None
    if nan_is_missing and isinstance(v, float) and np.isnan(v):
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise _damaged(field, v, "a finite number")
    return float(v)


def _vector3(d: dict, key: str, field: str) -> Optional[list]:
    v = d.get(key)
    if v is None:
        return None
    if not isinstance(v, list) or len(v) != 3:
        raise _damaged(field, v, "a list of 3 numbers")
    return [_number(x, f"{field}[{k}]") for k, x in enumerate(v)]


def result_fields(res) -> dict:
    """The fields of a result.json's content that the fleet row shows, each checked for its kind.

    Returns ``mode``, ``verdict`` (FAIL when absent, as in results older than the verdict), ``status``,
    ``findings`` (codes), ``time_utc``, ``why`` (failure reason or headline), and for a result with a
    matrix ``x_name``, ``translation_mm``, ``rotvec_deg``, ``sigma_trans_mm``, ``sigma_rot_deg``,
    ``sigma_source``, ``rms_px``. Raises :class:`DamagedResult` naming the first field of the wrong kind.
    """
    if not isinstance(res, dict):
        raise _damaged("(top level)", res, "a mapping")
    status = _text(res, "status", "status")
    f: dict[str, Any] = {
        "mode": _text(res, "mode", "mode"),
        "verdict": _text(res, "verdict", "verdict", choices=tuple(VERDICTS)) or "FAIL",
        "status": status,
        "time_utc": _text(_mapping(res, "provenance", "provenance"), "time_utc", "provenance.time_utc"),
        "why": _text(res, "failure_reason", "failure_reason") or _text(res, "verdict_headline", "verdict_headline"),
    }
    findings = res.get("findings") or []
    if not isinstance(findings, list):
        raise _damaged("findings", findings, "a list")
    f["findings"] = [str(x.get("code")) for x in findings if isinstance(x, dict)]
    he = res.get("hand_eye") if status == "ok" else None
    if he is None:
        return f
    if not isinstance(he, dict):
        raise _damaged("hand_eye", he, "a mapping")
    ref = _mapping(res, "refinement", "refinement")
    f.update(
        x_name=_text(he, "name", "hand_eye.name"),
        translation_mm=_vector3(he, "translation_mm", "hand_eye.translation_mm"),
        rotvec_deg=_vector3(he, "rotvec_deg", "hand_eye.rotvec_deg"),
        sigma_trans_mm=_vector3(ref, "sigma_trans_mm", "refinement.sigma_trans_mm"),
        sigma_rot_deg=_vector3(ref, "sigma_rot_deg", "refinement.sigma_rot_deg"),
        sigma_source=_text(ref, "sigma_source", "refinement.sigma_source") or ("model" if ref else None),
    )
    # NaN: no pixels to measure (a pose-only session's target poses come from a tracker)
    rms = _number(ref.get("rms_px_after"), "refinement.rms_px_after", nan_is_missing=True)
    if rms is None:
        checks = _mapping(res, "qa", "qa").get("checks") or []
        if not isinstance(checks, list):
            raise _damaged("qa.checks", checks, "a list")
        rms = next(
            (
                _number(c.get("value"), "qa.checks[reprojection_rms_px].value", nan_is_missing=True)
                for c in checks
                if isinstance(c, dict) and c.get("key") == "reprojection_rms_px"
            ),
            None,
        )
    f["rms_px"] = rms
    return f


def _read_json_file(path: Path) -> tuple[Optional[object], Optional[str]]:
    """(content, None) of a JSON file, (None, None) when there is none, (None, why) when it does not parse."""
    import json

    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        return None, None
    except (OSError, UnicodeDecodeError) as e:
        return None, f"cannot be read ({e})"
    try:
        return json.loads(text), None
    except ValueError as e:
        return None, f"is not valid JSON ({e})"


# ------------------------------------------------------------------------------------------ rows
def session_folders(out: Path) -> list[Path]:
    """Every folder under ``out`` with a result.json or a batch record, sorted."""
    found = []
    for folder, dirs, files in os.walk(out):
        if "result.json" in files or "verify.json" in files or RECORD_NAME in files:
            found.append(Path(folder))
            dirs[:] = []
        else:
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != FILES_DIR)
    return sorted(found)


def session_row(out: Path, folder: Path) -> dict:
    """The fleet row of one session folder (see :data:`COLUMNS`; vectors as 3-lists, findings a list).

    A result.json (or verify.json) that cannot be used makes the row ``damaged`` with the reason; the
    batch record's fields of the wrong kind are passed over.
    """
    rel = folder.relative_to(out).parts
    rec = read_json(folder / RECORD_NAME) or {}
    row: dict[str, Any] = {c: None for c in COLUMNS}
    warnings = rec.get("warnings")
    row.update(
        install=_rec_text(rec, "install") or (rel[0] if len(rel) > 1 else "default"),
        session=_rec_text(rec, "name") or ("/".join(rel[1:]) if len(rel) > 1 else folder.name),
        time_utc=_rec_text(rec, "time_utc"),
        time_source=_rec_text(rec, "time_source"),
        result_dir="/".join(rel),
        outcome=_rec_text(rec, "outcome"),
        reason=_rec_text(rec, "reason") or "",
        findings=[],
        export_error=_rec_text(rec, "export_error"),
        warnings="; ".join(str(w) for w in warnings) if isinstance(warnings, list) else None,
    )  # calibrate --export failed on a usable result
    which = "result.json"
    res, res_error = _read_json_file(folder / which)
    try:
        if res_error is not None:
            raise DamagedResult(f"it {res_error}")
        if res is None:
            which = "verify.json"
            ver, ver_error = _read_json_file(folder / which)
            if ver_error is not None:
                raise DamagedResult(f"it {ver_error}")
            if ver is not None and (not rec or rec.get("outcome") == "done"):  # a verification (handeye verify)
                return _verify_row(row, ver, folder, rel)
        if rec and rec.get("outcome") != "done" or res is None:
            row.update(verdict="ERROR", reason=row["reason"] or "no result.json")
            return row
        f = result_fields(res)  # the fields the index shows, each named when damaged
        assert isinstance(res, dict), "result_fields refuses anything but a mapping"
        validate_result(res, source=str(folder / which), partial=True)  # then the one reader's other checks
    except ROW_ERRORS as e:
        log.warning("%s: %s is damaged: %s", folder, which, e)
        row.update(outcome=DAMAGED, verdict="ERROR", reason=f"{which} is damaged: {e}")
        return row
    if res.get("kind") == "cell":  # several cameras of one arm: the cell's row, its cameras' rows beside it
        row["cell_result"] = res
    _fill(row, f, res, folder / "result.json")
    if (folder / "report.html").exists():
        row["report"] = "/".join(rel) + "/report.html"
    return row


def _fill(row: dict, f: dict, res: dict, path: Path, camera: Optional[str] = None) -> None:
    """A row's result columns from :func:`result_fields`' ``f`` of ``res`` (a cell's camera ``camera``)."""
    row.update(mode=f["mode"], verdict=f["verdict"], outcome=row["outcome"] or "done", findings=f["findings"])
    if not row["time_utc"]:
        row.update(time_utc=f["time_utc"], time_source="calibrated")
    if not row["reason"] and row["verdict"] != "PASS":  # a WARN says why too (a QA check is no finding)
        row["reason"] = f["why"] or ""
    if f.get("translation_mm") is not None and f.get("rotvec_deg") is not None:
        row.update(x_name=f["x_name"], sigma_source=f["sigma_source"], reprojection_rms_px=f["rms_px"])
        for names, key in (
            (("tx_mm", "ty_mm", "tz_mm"), "translation_mm"),
            (("rx_deg", "ry_deg", "rz_deg"), "rotvec_deg"),
            (("sigma_tx_mm", "sigma_ty_mm", "sigma_tz_mm"), "sigma_trans_mm"),
            (("sigma_rx_deg", "sigma_ry_deg", "sigma_rz_deg"), "sigma_rot_deg"),
        ):
            row.update(dict(zip(names, f[key] or [None] * 3, strict=True)))
        row["compared"] = _comparable(res, path, camera)  # for the drift: result.json is read once


def cell_rows(row: dict, folder: Path) -> list[dict]:
    """A cell's rows: one per camera (session ``<cell>/<camera>``), then the cell's own (mode ``cell``).

    Each camera's row holds its mode, verdict and X with sigmas as a one-camera result's row does; a camera
    whose entry cannot be used is a damaged row of its own. The cell's row: its verdict (result.json's, else
    the worst camera's) and, when not PASS or WARN, the cameras that are not.
    """
    res = row.pop("cell_result")
    cams = res.get("cameras") or {}
    name = row["session"]
    rows = []
    for camera, entry in cams.items():
        r = {**row, "camera": camera, "cell": name, "session": f"{name}/{camera}", "reason": ""}
        try:
            _fill(r, result_fields(entry), res, folder / "result.json", camera)
        except ROW_ERRORS as e:
            r.update(outcome=DAMAGED, verdict="ERROR", reason=f"result.json is damaged: cameras.{camera}: {e}")
        rows.append(r)
    worst = next(
        (v for v in ("ERROR", "REFUSED", "FAIL", "WARN", "PASS") if any(r["verdict"] == v for r in rows)), None
    )
    verdict = res.get("verdict") if isinstance(res.get("verdict"), str) else worst
    bad = [r["camera"] for r in rows if r["verdict"] not in ("PASS", "WARN")]
    row.update(mode="cell", cell=name, verdict=verdict or row["verdict"])
    if not row["reason"]:
        row["reason"] = f"a cell of {len(cams)} cameras ({', '.join(cams)})" + (
            f"; not PASS or WARN: {', '.join(bad)}" if bad else ""
        )
    return [*rows, row]


def _rec_text(rec: dict, key: str) -> Optional[str]:
    """A text field of a batch record (None when absent or of another kind)."""
    v = rec.get(key)
    return v if isinstance(v, str) else None


def _verify_row(row: dict, ver, folder: Path, rel: tuple) -> dict:
    """The row of a verification session (handeye verify) from its verify.json's content ``ver``."""
    from .run import VERIFY_VERDICTS

    if not isinstance(ver, dict):
        raise _damaged("(top level)", ver, "a mapping")
    verdict = _text(ver, "verdict", "verdict", choices=tuple(VERIFY_VERDICTS))
    prov = _mapping(ver, "provenance", "provenance")
    row.update(
        mode=_text(ver, "mode", "mode"),
        x_name=_text(ver, "frame", "frame"),
        outcome=row["outcome"] or "done",
        verdict=VERIFY_VERDICTS.get(verdict or "", "ERROR"),
        time_utc=row["time_utc"] or _text(prov, "time_utc", "provenance.time_utc"),
        reason=row["reason"] or ("" if verdict == "still valid" else str(ver.get("headline"))),
    )
    if (folder / "verify.html").exists():
        row["report"] = "/".join(rel) + "/verify.html"
    return row


def _comparable(res: Optional[dict], path: Path, camera: Optional[str] = None):
    """The result as the drift compares it.

    The result as the drift compares it (:class:`handeye.recal.loaded.LoadedResult`, its source the
    file), from result.json's content ``res`` as read (None: read ``path``); or the error loading it
    raised (the drift reports it). Only a file that does not load is read again, for load_result's own
    message naming it.
    """
    from dataclasses import replace

    from ..recal.loaded import load_result

    try:
        if res is not None and "handeye_result" in res:
            try:
                return replace(load_result(res, camera=camera), source=str(path))
            except ROW_ERRORS:  # said as load_result says it of the file, below
                pass
        return load_result(path, camera=camera)
    except ROW_ERRORS as e:  # one result that cannot be compared must not lose the index
        return e


def fleet_rows(out) -> list[dict]:
    """The rows of every session under ``out``, sorted by install, time and session."""
    out = Path(out)
    rows = []
    for f in session_folders(out):
        row = session_row(out, f)
        rows += cell_rows(row, f) if "cell_result" in row else [row]
    # a cell's cameras then the cell's own row (the install's latest session is the cell)
    rows.sort(
        key=lambda r: (
            r["install"],
            r["time_utc"] or "",
            r.get("cell") or r["session"],
            r.get("cell") == r["session"],
            r["session"],
        )
    )
    return rows
