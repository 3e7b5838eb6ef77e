"""Accuracy reports: ``report.html`` (one self-contained file) and ``report.md`` (+ ``report_files/``).

Built from a result folder alone (result.json, observations.json, thumbnails/), so
``write_reports("reports/cell3")`` or ``handeye report DIR`` rebuilds them without the session.
:mod:`.folder` reads the folder, :mod:`.context` computes what the templates show (with the section
builders of :mod:`.sections`, :mod:`.observations`, :mod:`.uncertainty`, :mod:`.metrics`, :mod:`.qa`,
:mod:`.advice`, :mod:`.figures`, :mod:`.plots`) and :mod:`.render` writes HTML and Markdown.
matplotlib and jinja2 load only when a report is written.

See docs/report.md.
"""

from __future__ import annotations

import logging
from pathlib import Path

from ..errors import HandeyeError

log = logging.getLogger(__name__)

__all__ = ["write_reports", "build_report_context", "load_qa", "evaluate", "Verdict"]


def __getattr__(name):  # the QA module loads the config machinery only when asked for
    if name in ("load_qa", "evaluate", "Verdict"):
        from . import qa

        return getattr(qa, name)
    raise AttributeError(name)


def write_reports(
    result_dir: str | Path,
    *,
    qa: str | Path | None = None,
    out_dir: str | Path | None = None,
    formats=("html", "md"),
    strict: bool = False,
    plots: bool = True,
    figure_process=None,
) -> list[Path]:
    """Write ``report.html`` and ``report.md`` (figures in ``report_files/``) for a result folder.

    ``result_dir``: the folder written by ``handeye calibrate`` (result.json, observations.json,
    thumbnails/); ``qa``: a site QA file overriding ``configs/qa.yaml``; ``out_dir``: where to write
    (default ``result_dir``); ``plots=False`` leaves the figures out; ``figure_process``: the command's
    :class:`~handeye.report.figure_process.FigureProcess`, which draws them when it can. Returns the paths
    written.
    With ``strict=False`` (the calibrate command) an unexpected error is logged and no report is
    written, since result.json is complete without it; user errors (a bad QA file, no result.json)
    always raise.
    """
    from .folder import read_result_folder

    folder = read_result_folder(result_dir)
    out = Path(out_dir) if out_dir is not None else folder.path
    if folder.result.get("kind") == "cell":  # several cameras: handeye.cell.report (handeye report routes there)
        from ..errors import InputError

        raise InputError(
            "the result is a cell of several cameras; this report is of one camera",
            path=folder.path / "result.json",
            hint="handeye report CELL_DIR writes the cell's report (handeye.cell.report.write_cell_report)",
        )
    try:
        from .render import write_files

        ctx = _context(folder, qa=qa, make_plots=plots, figure_process=figure_process)
        return write_files(out, *render_reports(ctx, folder, out_dir=out, formats=formats))
    except HandeyeError:
        raise
    except Exception as e:  # noqa: BLE001 - the calibration result must survive a report bug
        if strict:
            raise
        report_crashed(e, folder.path)
        return []


def render_reports(ctx: dict, folder, *, out_dir: str | Path, formats=("html", "md")) -> tuple:
    """The HTML and Markdown reports of the context ``ctx`` of ``folder``.

    (html text or None, (Markdown text, its files) or None): the reports of the context ``ctx`` of
    ``folder`` (a :class:`~handeye.report.folder.ResultFolder`) rendered in memory, for
    :func:`handeye.report.render.write_files` into ``out_dir``. A context built without figures is
    rendered without them (:func:`handeye.report.context.add_figures` adds them).
    """
    from .render import render_html, render_markdown

    html = render_html(ctx) if "html" in formats else None
    beside = Path(out_dir).resolve() == folder.path.resolve()
    md = render_markdown(ctx, thumbnails_beside=beside) if "md" in formats else None
    return html, md


def report_crashed(e: Exception, result_dir: Path) -> None:
    """The one error line of a report that could not be built (a bug: result.json is complete without it)."""
    log.error(
        "handeye: the report could not be written (%s: %s); result.json is complete. "
        "Rebuild it with: handeye --debug report %s",
        type(e).__name__,
        e,
        result_dir,
    )


def build_report_context(
    result_dir, *, qa: str | Path | None = None, qa_cfg: dict | None = None, make_plots: bool = True
) -> dict:
    """The template context of a result folder (what the report shows, as plain values).

    ``result_dir``: a folder (read here) or a :class:`~handeye.report.folder.ResultFolder` already read;
    ``qa_cfg``: the QA thresholds of ``qa`` when already loaded (:func:`handeye.report.qa.load_qa`).
    """
    from .folder import ResultFolder, read_result_folder

    folder = result_dir if isinstance(result_dir, ResultFolder) else read_result_folder(result_dir)
    return _context(folder, qa=qa, qa_cfg=qa_cfg, make_plots=make_plots)


def _context(folder, *, qa, make_plots: bool, qa_cfg: dict | None = None, figure_process=None) -> dict:
    from .context import add_figures, build_context
    from .qa import load_qa

    cfg = load_qa(qa) if qa_cfg is None else qa_cfg
    source = f"{qa} (site override of configs/qa.yaml)" if qa is not None else "configs/qa.yaml (shipped)"
    ctx = build_context(folder, qa_cfg=cfg, qa_source=source, make_plots=False)
    return add_figures(ctx, figure_process) if make_plots else ctx
