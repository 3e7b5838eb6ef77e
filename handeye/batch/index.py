"""The fleet index of a batch output folder, from its result folders alone.

Writes ``fleet.csv`` (and ``fleet.parquet`` with pyarrow), one row per session (:data:`COLUMNS`), and
``index.html`` / ``index.md``: the fleet's verdicts, the installs whose latest session fails, the most
common findings, and per install the drift of X between consecutive sessions
(:func:`handeye.recal.compare.compare_results`) and the trend of X with 2-sigma bands. A session whose
last batch run ended without a result is listed as ERROR with the reason.

See docs/fleet.md and, for faults in one session, docs/batch.md.
"""

from __future__ import annotations

import csv
import io
import logging
from collections import Counter
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..output import atomic_write_bytes, atomic_write_text
from .rows import (  # noqa: F401 (re-exported: the index's rows live in rows.py)
    COLUMNS,
    DAMAGED,
    FILES_DIR,
    ROW_ERRORS,
    SKIPPED_NAME,
    TOP_FINDINGS,
    DamagedResult,
    _comparable,
    _damaged,
    _mapping,
    _number,
    _read_json_file,
    _rec_text,
    _text,
    _vector3,
    _verify_row,
    fleet_rows,
    result_fields,
    session_folders,
    session_row,
)
from .run import FAILED_VERDICTS, LOG_NAME, read_json

log = logging.getLogger(__name__)


# ------------------------------------------------------------------------------------------ installs
def _drift(out: Path, a: dict, b: dict) -> dict:
    """compare_results between two sessions of an install, as a table row.

    Their results as :func:`session_row` loaded them. Every row has ``comparable``, ``reason`` and
    ``drifted`` (False when not comparable); a comparable one the numbers of the comparison.
    """
    from ..recal.compare import compare_loaded

    d = {"from": a["session"], "to": b["session"], "time_utc": b["time_utc"], "drifted": False}
    try:
        pair = [r.get("compared") or _comparable(None, out / r["result_dir"] / "result.json") for r in (a, b)]
        for loaded in pair:
            if isinstance(loaded, Exception):
                raise loaded
        c = compare_loaded(*pair)
    except ROW_ERRORS as e:  # one pair that cannot be compared must not lose the index
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


def series_key(row: dict) -> Optional[tuple]:
    """What a session's result describes: (mode, frame of X, board, image size).

    None when its result does not load for a comparison. Two sessions are compared only within one key
    (module docstring).
    """
    import json

    loaded = row.get("compared")
    if loaded is None or isinstance(loaded, Exception):
        return None
    size = tuple(loaded.image_size) if loaded.image_size else None
    return (loaded.mode, loaded.x_name, json.dumps(loaded.target, sort_keys=True, default=str), size, row.get("camera"))


def _series_label(key: tuple) -> str:
    """One line naming a series: its mode, X, board and image size."""
    import json

    mode, x_name, target, size, camera = key
    t = json.loads(target)
    board = "an unknown board"
    if isinstance(t, dict):
        dims = t.get("inner_corners") or t.get("squares") or t.get("grid")
        board = str(t.get("type") or "board") + (
            f" {dims[0]}x{dims[1]}" if isinstance(dims, list) and len(dims) == 2 else ""
        )
        if isinstance(t.get("square_m"), (int, float)):
            board += f" of {1e3 * t['square_m']:g} mm"
    return ("" if camera is None else f"camera {camera}: ") + (
        f"{mode}, {x_name}, {board}" + (f", {size[0]}x{size[1]} px" if size else "")
    )


def _not_comparable(a: dict, b: dict) -> dict:
    """The drift row of two consecutive sessions of two series: not comparable, with the difference."""
    from ..recal.compare import why_not_comparable

    reason = why_not_comparable(a["compared"], b["compared"]) or "the results describe different quantities"
    return {
        "from": a["session"],
        "to": b["session"],
        "time_utc": b["time_utc"],
        "comparable": False,
        "reason": reason,
        "drifted": False,
    }


def install_drifts(out: Path, usable: list[dict]) -> list[dict]:
    """The drift rows of an install's sessions with a result (by time).

    Each session against the previous one of its series (:func:`series_key`); two consecutive sessions of
    two series also get a row, not comparable, naming the difference. A session whose result does not load
    for a comparison is paired with the previous session, and its row says why.
    """
    drifts: list[dict[str, Any]] = []
    last_of: dict[Any, Any] = {}
    for k, row in enumerate(usable):
        key, prev = series_key(row), (usable[k - 1] if k else None)
        if prev is not None:
            prev_key = series_key(prev)
            if key is None or prev_key is None:  # the pair's row says why a result does not load
                drifts.append(_drift(out, prev, row))
            elif key != prev_key:
                drifts.append(_not_comparable(prev, row))
            else:
                drifts.append(_drift(out, prev, row))
        if key is not None and key in last_of and last_of[key] is not prev:  # across sessions of other series
            drifts.append(_drift(out, last_of[key], row))
        if key is not None:
            last_of[key] = row
    return drifts


def install_summaries(out, rows: list[dict], *, plots: bool = True) -> list[dict]:
    """Per install: its rows (by time), latest verdict, drifts and trends.

    ``drifts``: :func:`install_drifts`; ``trends``: per series with a result (:func:`series_key`) its
    ``label``, ``rows`` and trend plot ``png`` (bytes; None without ``plots`` or for one session alone).
    """
    out = Path(out)
    by_install: dict[str, list] = {}
    for r in rows:
        by_install.setdefault(r["install"], []).append(r)
    summaries = []
    for name in sorted(by_install):
        rs = by_install[name]
        usable = [r for r in rs if r["tx_mm"] is not None]
        by_camera: dict = {}  # a cell's camera is compared with the same camera of the install's other cells only
        for r in usable:
            by_camera.setdefault(r.get("camera"), []).append(r)
        drifts = [d for rows_ in by_camera.values() for d in install_drifts(out, rows_)]
        if len(by_camera) > 1:
            drifts.sort(key=lambda d: d["time_utc"] or "")
        series: dict = {}
        for r in usable:
            key = series_key(r)
            if key is not None:
                series.setdefault(key, []).append(r)
        trends = [
            {
                "label": _series_label(key),
                "rows": srows,
                "png": trend_png(name, srows) if plots and len(srows) > 1 else None,
            }
            for key, srows in series.items()
        ]
        summaries.append(
            {
                "install": name,
                "rows": rs,
                "latest": rs[-1],
                "latest_verdict": rs[-1]["verdict"],
                "drifts": drifts,
                "n_drifted": sum(bool(d["drifted"]) for d in drifts),
                "trends": trends,
            }
        )
    return summaries


def _rotvec_change_deg(first: dict, row: dict) -> np.ndarray:
    from ..frames import R_from_rotvec, rotvec_from_R

    R0 = R_from_rotvec(np.radians([first["rx_deg"], first["ry_deg"], first["rz_deg"]]))
    R = R_from_rotvec(np.radians([row["rx_deg"], row["ry_deg"], row["rz_deg"]]))
    return np.degrees(rotvec_from_R(R0.T @ R))


def trend_series(rows: list[dict]) -> dict:
    """Change of X since the first row, with its 1-sigma and the times.

    Change of X since the first row (see the module docstring): ``dt_mm`` (N, 3), ``dr_deg`` (N, 3),
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
    from datetime import timedelta

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
            times = list(s["times"])
            if times and min(times) == max(times):  # one instant: an hour each side (the locator has no span)
                ax.set_xlim(times[0] - timedelta(hours=1), times[0] + timedelta(hours=1))
            locator = AutoDateLocator(maxticks=5)
            ax.xaxis.set_major_locator(locator)
            ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))
            ax.tick_params(axis="x", labelsize=7.5)
            ax.legend(loc="upper left", ncols=3)
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
    return buf.getvalue()


def fleet_summary(rows: list[dict], installs: list[dict]) -> dict:
    """Fleet-wide summary: verdict counts, failing and drifting installs, findings, failed exports.

    Fleet-wide: verdict counts, failing installs (latest session FAIL, REFUSED or ERROR), installs
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
        "damaged": [r for r in rows if r["outcome"] == DAMAGED],
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


def write_skipped(out, skipped: list) -> Path:
    """Keep the folders discovery skipped (:class:`handeye.batch.discover.SkippedFolder`) in OUT for the index."""
    import json

    data = [{"path": str(s.path), "reason": s.reason} for s in skipped]
    return atomic_write_text(Path(out) / SKIPPED_NAME, json.dumps({"skipped": data}, indent=1) + "\n")


def read_skipped(out) -> list[dict]:
    """The skipped folders of the last batch into ``out`` (``path``, ``reason``); [] when none are recorded."""
    d = read_json(Path(out) / SKIPPED_NAME) or {}
    items = d.get("skipped")
    return [
        {"path": str(x.get("path")), "reason": str(x.get("reason"))}
        for x in (items if isinstance(items, list) else [])
        if isinstance(x, dict)
    ]


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
        "skipped": read_skipped(out),
        "version": __version__,
        "generated_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "anchor": lambda name: "install-" + safe_name(name),
        "log_name": LOG_NAME,
    }
    written = [atomic_write_text(out / "fleet.csv", csv_text(rows))]
    pq_path = _write_parquet(out / "fleet.parquet", rows)
    if pq_path is not None:
        written.append(pq_path)
    images = {i["install"]: [(t["label"], data_uri(t["png"])) for t in i["trends"] if t["png"]] for i in installs}
    written.append(
        atomic_write_text(
            out / "index.html", _env(html=True).get_template("fleet.html.j2").render(**ctx, images=images)
        )
    )
    files: dict[str, Any] = {}
    for i in installs:
        for k, t in enumerate(t for t in i["trends"] if t["png"]):  # one install's first series keeps its old name
            name = f"{FILES_DIR}/trend_{safe_name(i['install'])}{f'_{k + 1}' if k else ''}.png"
            atomic_write_bytes(out / name, t["png"])
            files.setdefault(i["install"], []).append((t["label"], name))
    written.append(
        atomic_write_text(out / "index.md", _env(html=False).get_template("fleet.md.j2").render(**ctx, images=files))
    )
    return written
