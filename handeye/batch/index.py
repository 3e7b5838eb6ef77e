"""The fleet index of a batch output folder, from its result folders alone.

Writes into OUT:

- ``fleet.csv`` (and ``fleet.parquet`` when pyarrow is installed): one row per session (:data:`COLUMNS`);
- ``index.html`` (self-contained: styles and trend plots inlined) and ``index.md`` (its plots in
  ``index_files/``): the fleet's verdicts, the installs whose latest session fails, the most common
  findings, and per install the latest verdict, the drift of X between consecutive sessions with its
  significance (:func:`handeye.recal.compare.compare_results`) and the trend of X over time with its
  2-sigma bands; every session links to its report.

A session folder is any folder under OUT holding ``result.json`` or ``batch.json`` (the batch's record,
:mod:`handeye.batch.run`); its install and name come from the record, else from its path
(``OUT/<install>/<session>``). A session whose last batch run ended without a result (timeout, crash,
lost worker) is listed with verdict ERROR and the reason, whatever an older result.json says.

The trend plot shows each session's X against the install's first usable session: the translation
change (mm, in the frame of X's translation, e.g. the end frame for ``T_end_cam``) and the rotation
change ``rotvec(R_first^T R)`` (deg, about the camera axes), with 2-sigma bands from each session's
printed sigmas (``sigma_trans_mm``, ``sigma_rot_deg``: the same axes).
"""

from __future__ import annotations

import csv
import io
import logging
import os
from collections import Counter
from pathlib import Path
from typing import Optional

import numpy as np

from ..contract import validate_result
from ..errors import InputError
from ..output import atomic_write_bytes, atomic_write_text
from .run import FAILED_VERDICTS, LOG_NAME, RECORD_NAME, read_json

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
)
#: how many findings codes the fleet summary lists
TOP_FINDINGS = 10
FILES_DIR = "index_files"


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
    """The fleet row of one session folder (see :data:`COLUMNS`; vectors as 3-lists, findings a list)."""
    rel = folder.relative_to(out).parts
    rec = read_json(folder / RECORD_NAME) or {}
    res, damaged = read_json(folder / "result.json"), None
    if res is not None:  # checked by the one reader: a damaged result is a row with the reason, never a crash
        try:
            validate_result(res, source=str(folder / "result.json"), partial=True)
        except InputError as e:
            res, damaged = None, str(e)
    row = {c: None for c in COLUMNS}
    row.update(
        install=rec.get("install") or (rel[0] if len(rel) > 1 else "default"),
        session=rec.get("name") or ("/".join(rel[1:]) if len(rel) > 1 else folder.name),
        time_utc=rec.get("time_utc"),
        time_source=rec.get("time_source"),
        result_dir="/".join(rel),
        outcome=rec.get("outcome"),
        reason=rec.get("reason") or "",
        findings=[],
        export_error=rec.get("export_error"),
    )  # calibrate --export failed on a usable result
    ver = read_json(folder / "verify.json") if res is None else None
    if ver is not None and (not rec or rec.get("outcome") == "done"):  # a verification session (handeye verify)
        from .run import VERIFY_VERDICTS

        row.update(
            mode=ver.get("mode"),
            x_name=ver.get("frame"),
            outcome=row["outcome"] or "done",
            verdict=VERIFY_VERDICTS.get(str(ver.get("verdict")), "ERROR"),
            time_utc=row["time_utc"] or (ver.get("provenance") or {}).get("time_utc"),
            reason=row["reason"] or ("" if ver.get("verdict") == "still valid" else str(ver.get("headline"))),
        )
        if (folder / "verify.html").exists():
            row["report"] = "/".join(rel) + "/verify.html"
        return row
    if rec and rec.get("outcome") != "done" or res is None:
        row.update(verdict="ERROR", reason=row["reason"] or damaged or "no result.json")
        return row
    row.update(
        mode=res.get("mode"),
        verdict=res.get("verdict") or "FAIL",
        outcome=row["outcome"] or "done",
        findings=[str(f.get("code")) for f in res.get("findings") or [] if isinstance(f, dict)],
    )
    if not row["time_utc"]:
        row.update(time_utc=(res.get("provenance") or {}).get("time_utc"), time_source="calibrated")
    if not row["reason"] and row["verdict"] not in ("PASS", "WARN"):
        row["reason"] = res.get("failure_reason") or res.get("verdict_headline") or ""
    he = res.get("hand_eye") if res.get("status") == "ok" else None
    if isinstance(he, dict):
        ref = res.get("refinement") or {}
        row.update(x_name=he.get("name"), sigma_source=ref.get("sigma_source") or ("model" if ref else None))
        for names, key, src in (
            (("tx_mm", "ty_mm", "tz_mm"), "translation_mm", he),
            (("rx_deg", "ry_deg", "rz_deg"), "rotvec_deg", he),
            (("sigma_tx_mm", "sigma_ty_mm", "sigma_tz_mm"), "sigma_trans_mm", ref),
            (("sigma_rx_deg", "sigma_ry_deg", "sigma_rz_deg"), "sigma_rot_deg", ref),
        ):
            vals = src.get(key) or [None] * 3
            row.update(dict(zip(names, (None if v is None else float(v) for v in vals), strict=False)))
        rms = ref.get("rms_px_after")
        if rms is None:
            rms = next(
                (
                    c.get("value")
                    for c in (res.get("qa") or {}).get("checks") or []
                    if c.get("key") == "reprojection_rms_px"
                ),
                None,
            )
        row["reprojection_rms_px"] = None if rms is None else float(rms)
        row["compared"] = _comparable(res, folder / "result.json")  # for the drift: result.json is read once
    if (folder / "report.html").exists():
        row["report"] = "/".join(rel) + "/report.html"
    return row


def _comparable(res: Optional[dict], path: Path):
    """The result as the drift compares it (:class:`handeye.recal.loaded.LoadedResult`, its source the
    file), from result.json's content ``res`` as read (None: read ``path``); or the error loading it
    raised (the drift reports it). Only a file that does not load is read again, for load_result's own
    message naming it.
    """
    from dataclasses import replace

    from ..recal.loaded import load_result

    try:
        if res is not None and "handeye_result" in res:
            try:
                return replace(load_result(res), source=str(path))
            except Exception:  # noqa: BLE001 - said as load_result says it of the file, below
                pass
        return load_result(path)
    except Exception as e:  # noqa: BLE001 - one result that cannot be compared must not lose the index
        return e


def fleet_rows(out) -> list[dict]:
    """The rows of every session under ``out``, sorted by install, time and session."""
    out = Path(out)
    rows = [session_row(out, f) for f in session_folders(out)]
    rows.sort(key=lambda r: (r["install"], r["time_utc"] or "", r["session"]))
    return rows


# ------------------------------------------------------------------------------------------ installs
def _drift(out: Path, a: dict, b: dict) -> dict:
    """compare_results between two consecutive sessions of an install, as a table row (their results as
    :func:`session_row` loaded them).
    """
    from ..recal.compare import compare_loaded

    d = {"from": a["session"], "to": b["session"], "time_utc": b["time_utc"]}
    try:
        pair = [r.get("compared") or _comparable(None, out / r["result_dir"] / "result.json") for r in (a, b)]
        for loaded in pair:
            if isinstance(loaded, Exception):
                raise loaded
        c = compare_loaded(*pair)
    except Exception as e:  # noqa: BLE001 - one pair that cannot be compared must not lose the index
        log.warning("drift %s -> %s not computed: %s", a["session"], b["session"], e)
        return {**d, "comparable": False, "reason": f"{type(e).__name__}: {e}"}
    if not c.comparable:
        return {**d, "comparable": False, "reason": c.reason}
    return {
        **d,
        "comparable": True,
        "reason": "",
        "trans_mm": float(c.trans_mm),
        "rot_deg": float(c.rot_deg),
        "d_trans_mm": [float(x) for x in c.d_trans_mm],
        "d_rot_deg": [float(x) for x in c.d_rot_deg],
        "p_value": float(c.p_value),
        "drifted": bool(c.drifted),
    }


def install_summaries(out, rows: list[dict], *, plots: bool = True) -> list[dict]:
    """Per install: its rows (by time), latest verdict, drifts between consecutive sessions with a
    result, and the trend plot (PNG bytes or None).
    """
    out = Path(out)
    by_install: dict[str, list] = {}
    for r in rows:
        by_install.setdefault(r["install"], []).append(r)
    summaries = []
    for name in sorted(by_install):
        rs = by_install[name]
        usable = [r for r in rs if r["tx_mm"] is not None]
        drifts = [_drift(out, a, b) for a, b in zip(usable, usable[1:], strict=False)]
        summaries.append(
            {
                "install": name,
                "rows": rs,
                "latest": rs[-1],
                "latest_verdict": rs[-1]["verdict"],
                "drifts": drifts,
                "n_drifted": sum(bool(d.get("drifted")) for d in drifts),
                "trend_png": trend_png(name, usable) if plots and usable else None,
            }
        )
    return summaries


def _rotvec_change_deg(first: dict, row: dict) -> np.ndarray:
    from ..frames import R_from_rotvec, rotvec_from_R

    R0 = R_from_rotvec(np.radians([first["rx_deg"], first["ry_deg"], first["rz_deg"]]))
    R = R_from_rotvec(np.radians([row["rx_deg"], row["ry_deg"], row["rz_deg"]]))
    return np.degrees(rotvec_from_R(R0.T @ R))


def trend_series(rows: list[dict]) -> dict:
    """Change of X since the first row (see the module docstring): ``dt_mm`` (N, 3), ``dr_deg`` (N, 3),
    their 1-sigma ``st_mm`` / ``sr_deg`` (N, 3; NaN when not reported), ``times`` (N,) datetimes.
    """
    import datetime as _dt

    def vec(r, names):
        return np.array([np.nan if r[n] is None else r[n] for n in names], dtype=float)

    t = np.array([vec(r, ("tx_mm", "ty_mm", "tz_mm")) for r in rows])  # shape (N, 3)
    times = []
    for k, r in enumerate(rows):
        try:
            times.append(_dt.datetime.fromisoformat(r["time_utc"]))
        except (TypeError, ValueError):
            times.append(_dt.datetime(1970, 1, 1) + _dt.timedelta(days=k))
    return {
        "times": times,
        "dt_mm": t - t[0],
        "dr_deg": np.array([_rotvec_change_deg(rows[0], r) for r in rows]),
        "st_mm": np.array([vec(r, ("sigma_tx_mm", "sigma_ty_mm", "sigma_tz_mm")) for r in rows]),
        "sr_deg": np.array([vec(r, ("sigma_rx_deg", "sigma_ry_deg", "sigma_rz_deg")) for r in rows]),
    }


def trend_png(install: str, rows: list[dict]) -> bytes:
    """The install's trend plot: translation and rotation change of X over time, 2-sigma bands."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter
    from matplotlib.figure import Figure

    from ..report.plots import style

    s = trend_series(rows)
    with style():
        fig = Figure(figsize=(9.0, 2.8), dpi=110)
        FigureCanvasAgg(fig)
        fig.subplots_adjust(left=0.08, right=0.98, bottom=0.16, top=0.86, wspace=0.28)
        for k, (key, skey, unit, title) in enumerate(
            (
                ("dt_mm", "st_mm", "mm", "translation change"),
                ("dr_deg", "sr_deg", "deg", "rotation change (camera axes)"),
            )
        ):
            ax = fig.add_subplot(1, 2, k + 1)
            for j, (axis, color) in enumerate(zip("xyz", ("#c0392b", "#27865a", "#2c5d95"), strict=False)):
                y, sig = s[key][:, j], s[skey][:, j]
                ax.plot(s["times"], y, "o-", color=color, ms=3.5, lw=1.2, label=axis)
                ok = np.isfinite(sig)
                if ok.any():
                    ax.fill_between(
                        np.array(s["times"], dtype=object)[ok],
                        (y - 2 * sig)[ok],
                        (y + 2 * sig)[ok],
                        color=color,
                        alpha=0.15,
                        lw=0,
                    )
            ax.set_title(f"{title} [{unit}]", fontsize=9.5, loc="left")
            locator = AutoDateLocator(maxticks=5)
            ax.xaxis.set_major_locator(locator)
            ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))
            ax.tick_params(axis="x", labelsize=7.5)
            ax.legend(loc="upper left", ncols=3)
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    return buf.getvalue()


def fleet_summary(rows: list[dict], installs: list[dict]) -> dict:
    """Fleet-wide: verdict counts, failing installs (latest session FAIL, REFUSED or ERROR), installs
    with a significant drift, the most common findings codes (sessions that have each), the sessions
    whose export (``calibrate --export``) failed.
    """
    codes = Counter(c for r in rows for c in set(r["findings"]))
    return {
        "n_sessions": len(rows),
        "n_installs": len(installs),
        "verdicts": Counter(r["verdict"] for r in rows),
        "failing": [i for i in installs if i["latest_verdict"] in FAILED_VERDICTS],
        "drifting": [i for i in installs if i["n_drifted"]],
        "top_findings": codes.most_common(TOP_FINDINGS),
        "export_errors": [r for r in rows if r["export_error"]],
    }


# ------------------------------------------------------------------------------------------ files
def csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (";".join(r[k]) if k == "findings" else ("" if r[k] is None else r[k])) for k in COLUMNS})
    return buf.getvalue()


def read_fleet_csv(path) -> list[dict]:
    """fleet.csv as rows: numbers as floats (None when empty), findings as a list."""
    numeric = {c for c in COLUMNS if c.endswith(("_mm", "_deg", "_px"))}
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for k in COLUMNS:
            v = r.get(k, "")
            if k == "findings":
                r[k] = [c for c in v.split(";") if c]
            elif k in numeric:
                r[k] = float(v) if v != "" else None
            elif v == "":
                r[k] = None
    return rows


def _write_parquet(path: Path, rows: list[dict]) -> Optional[Path]:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    table = pa.table({c: [r[c] for r in rows] for c in COLUMNS})
    buf = pa.BufferOutputStream()
    pq.write_table(table, buf)
    return atomic_write_bytes(path, buf.getvalue().to_pybytes())


def _env(*, html: bool):
    import jinja2

    from ..report.render import mdcell, num

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("handeye", "templates"),
        autoescape=html,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters["num"] = num
    env.filters["mdcell"] = lambda x: mdcell(x).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    env.filters["pill"] = lambda v: {"PASS": "pass", "WARN": "warn"}.get(str(v), "fail")
    return env


def write_index(out, *, plots: bool = True) -> list[Path]:
    """Write fleet.csv (fleet.parquet), index.html, index.md and index_files/ into ``out``; return the paths."""
    import datetime as _dt

    from .. import __version__
    from ..report.render import data_uri, safe_name

    out = Path(out)
    rows = fleet_rows(out)
    installs = install_summaries(out, rows, plots=plots)
    ctx = {
        "rows": rows,
        "installs": installs,
        "fleet": fleet_summary(rows, installs),
        "version": __version__,
        "generated_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "anchor": lambda name: "install-" + safe_name(name),
        "log_name": LOG_NAME,
    }
    written = [atomic_write_text(out / "fleet.csv", csv_text(rows))]
    pq_path = _write_parquet(out / "fleet.parquet", rows)
    if pq_path is not None:
        written.append(pq_path)
    images = {i["install"]: data_uri(i["trend_png"]) for i in installs if i["trend_png"]}
    written.append(
        atomic_write_text(
            out / "index.html", _env(html=True).get_template("fleet.html.j2").render(**ctx, images=images)
        )
    )
    files = {i["install"]: f"{FILES_DIR}/trend_{safe_name(i['install'])}.png" for i in installs if i["trend_png"]}
    for i in installs:
        if i["trend_png"]:
            atomic_write_bytes(out / files[i["install"]], i["trend_png"])
    written.append(
        atomic_write_text(out / "index.md", _env(html=False).get_template("fleet.md.j2").render(**ctx, images=files))
    )
    return written
