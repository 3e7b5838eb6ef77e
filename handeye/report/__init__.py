"""Accuracy reports: ``report.html`` (one self-contained file) and ``report.md`` (+ ``report_files/``).

The report is built from what the result folder holds (result.json, observations.json) and the
session images, so ``handeye report RESULT_DIR`` rebuilds it without re-running the calibration;
a run object, when given, only helps to find the images.

    from handeye.report import write_reports
    paths = write_reports(None, result_dict, "reports/cell3")
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Optional

from ..errors import HandeyeError, InputError

log = logging.getLogger(__name__)

__all__ = ["write_reports", "build_report_context", "load_qa", "evaluate", "Verdict"]


def __getattr__(name):  # matplotlib and jinja2 load only when a report is built, not with the CLI
    if name in ("load_qa", "evaluate", "Verdict"):
        from . import qa

        return getattr(qa, name)
    raise AttributeError(name)


def write_reports(run, res: dict, out_dir, *, qa: str | Path | None = None, formats=("html", "md"),
                  strict: bool = False, source_dir=None, plots: bool = True) -> list[Path]:
    """Write ``out_dir/report.html`` and ``out_dir/report.md`` (figures in ``out_dir/report_files``).

    ``run``: the :class:`handeye.calibrate.CalibrationRun` or None; ``res``: result.json's content;
    ``qa``: a site QA file overriding ``configs/qa.yaml``; ``source_dir``: where observations.json is
    (default ``out_dir``); ``plots=False`` leaves the figures out (faster). Returns the paths written. With
    ``strict=False`` (the calibrate command) an unexpected error is logged and no report is written,
    since result.json is complete without it; user errors (a bad QA file) always raise.
    """
    from .render import render_html, render_markdown, write_files

    out_dir = Path(out_dir)
    try:
        ctx = build_report_context(run, res, Path(source_dir) if source_dir else out_dir, qa=qa, make_plots=plots)
        html = render_html(ctx) if "html" in formats else None
        md = render_markdown(ctx) if "md" in formats else None
        return write_files(out_dir, html, md)
    except HandeyeError:
        raise
    except Exception as e:  # noqa: BLE001 - the calibration result must survive a report bug
        if strict:
            raise
        log.error("handeye: the report could not be written (%s: %s); result.json is complete. "
                  "Rebuild it with: handeye --debug report %s", type(e).__name__, e, out_dir)
        return []


def build_report_context(run, res: dict, result_dir: Path, *, qa: str | Path | None = None,
                         make_plots: bool = True) -> dict:
    from .build import build_context
    from .qa import load_qa

    cfg = load_qa(qa)
    source = f"{qa} (site override of configs/qa.yaml)" if qa is not None else "configs/qa.yaml (shipped)"
    obs = _observations(run, result_dir)
    images = _image_paths(run, res, obs)
    return build_context(res, obs, qa_cfg=cfg, qa_source=source, image_paths=images, make_plots=make_plots)


def _observations(run, out_dir: Path) -> Optional[dict]:
    p = Path(out_dir) / "observations.json"
    if p.exists():
        try:
            return json.loads(p.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"not valid JSON ({e})", path=p, hint="re-run handeye calibrate") from None
    if run is not None:
        from ..results import observations_dict

        from ..output import plain

        return plain(observations_dict(run))
    return None


def _image_paths(run, res: dict, obs: Optional[dict]) -> dict[str, Path]:
    """view id -> image file, from the run, observations.json, or by reloading the session."""
    paths: dict[str, Path] = {}
    if run is not None:
        for v in run.session.views:
            paths[str(v.view_id)] = Path(v.image_path)
    for vid, v in ((obs or {}).get("views") or {}).items():
        if v.get("image"):
            paths.setdefault(str(vid), Path(v["image"]))
    want = [str(v.get("id")) for v in res.get("views") or [] if str(v.get("id")) not in paths]
    sess = (res.get("session") or {}).get("path")
    if want and sess:
        try:
            from ..session import load_session

            s = load_session(sess)
            for v in s.views:
                paths.setdefault(str(v.view_id), Path(v.image_path))
        except (HandeyeError, OSError, ValueError) as e:
            log.debug("report: session %s not reloadable for thumbnails: %s", sess, e)
        for v in res.get("views") or []:
            vid = str(v.get("id"))
            if vid not in paths and v.get("image") and (Path(sess) / v["image"]).exists():
                paths[vid] = Path(sess) / v["image"]
    return paths
