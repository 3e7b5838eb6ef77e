"""``handeye report RESULT_DIR [--qa FILE]``: (re)build report.html and report.md from a result folder."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..errors import HandeyeError, InputError, clip

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    add_report_arguments(parser)
    parser.set_defaults(func=run_report)


def add_report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Rebuild report.html (self-contained) and report.md (+ report_files/) from a folder "
        "written by handeye calibrate (result.json, observations.json, thumbnails/); the "
        "session itself is not read."
    )
    parser.add_argument(
        "result_dir",
        type=Path,
        help="folder holding result.json, or a result file in it (result.json, result.last-good.json: with --out)",
    )
    parser.add_argument(
        "--qa", type=Path, metavar="FILE", help="site QA thresholds (YAML) overriding the shipped configs/qa.yaml"
    )
    parser.add_argument("--out", type=Path, metavar="DIR", help="write the reports here (default: RESULT_DIR)")
    parser.add_argument("--format", choices=["all", "html", "md"], default="all", help="which report(s) to write")


def run_report(args) -> int:
    from ..report.figure_process import figure_process

    with figure_process(start_now=True) as figures:  # it imports matplotlib while the result is read
        return _run_report(args, figures)


def _run_report(args, figures) -> int:
    from ..output import FolderLock, check_out_dir, remove_stray_temps
    from ..report import write_reports

    src = Path(args.result_dir)
    result_file = src if src.is_file() else src / "result.json"
    result_dir = result_file.parent
    if not result_file.exists():
        raise InputError(
            "no result.json in this folder", path=result_dir, hint="pass the folder written by handeye calibrate --out"
        )
    if result_file.name != "result.json" and not getattr(args, "out", None):
        raise InputError(
            f"a report of {result_file.name} would replace the reports of this folder's result.json",
            path=result_file,
            hint="write it into another folder with --out DIR",
        )
    out = Path(args.out) if getattr(args, "out", None) else result_dir
    fmt = getattr(args, "format", "all")
    formats = ("html", "md") if fmt == "all" else (fmt,)
    out = check_out_dir(out, option="--out" if getattr(args, "out", None) else "RESULT_DIR")
    with FolderLock(out, option="the result folder"):
        remove_stray_temps(out)
        cell = cell_result(result_file)
        try:
            if cell is not None:  # several cameras of one arm: the cell's own report
                from ..cell.report import cell_html, cell_markdown
                from ..output import atomic_write_text

                texts = {"html": cell_html, "md": cell_markdown}
                paths = [atomic_write_text(out / f"report.{f}", texts[f](cell)) for f in formats]
            else:
                paths = write_reports(
                    result_file,
                    qa=getattr(args, "qa", None),
                    out_dir=out,
                    formats=formats,
                    strict=True,
                    figure_process=figures,
                )
        except HandeyeError:
            raise
        except Exception as e:  # noqa: BLE001 - result.json passed its checks; the rest of it may still be damaged
            if getattr(args, "debug", False):
                raise
            raise InputError(
                f"the report could not be built from this result.json ({type(e).__name__}: {clip(e, 80)})",
                path=result_file,
                hint="re-run handeye calibrate into this folder; if the file is intact, rerun with "
                "--debug and report the traceback",
            ) from None
    for p in paths:
        print(f"report: {p}")
    return 0


def cell_result(result_file: Path):
    """The result file's content when it is a cell (checked by the contract), else None (the one-camera report's)."""
    import json

    from ..contract import read_result

    try:
        d = json.loads(result_file.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):  # the one-camera report's reader names what is wrong
        return None
    if not isinstance(d, dict) or d.get("kind") != "cell":
        return None
    return read_result(result_file).raw
