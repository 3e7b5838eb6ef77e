"""The product workflow, once: load -> calibrate -> diagnose -> write -> verdict -> report.

:func:`calibrate_session` is what ``handeye calibrate`` does and what the tests and benchmarks call.
It writes result.json (with the verdict and the time of every stage), observations.json, thumbnails
and the reports into ``out_dir``, one locked run at a time, atomically, with one ``run_id``; a failed
run still gets a result.json and a report saying why, and ``result.last-good.json`` keeps the last
usable one. The verdict (PASS / WARN / FAIL / REFUSED) is the report's own, stored in result.json;
:attr:`WorkflowResult.exit_code` follows :mod:`handeye.errors`.

See docs/calibrate.md.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional

from .contract import Observations, check_written, write_result
from .errors import HandeyeError, SessionRefused, verdict_exit_code
from .output import (
    FolderLock,
    OutputWriteError,
    atomic_write_bytes,
    atomic_write_text,
    check_out_dir,
    inputs_record,
    remove_stray_temps,
    to_json,
    writing,
)
from .pipeline import CalibrateOptions, CalibrationRun, run_calibration

log = logging.getLogger(__name__)

THUMBNAIL_DIR = "thumbnails"
LAST_GOOD_NAME = "result.last-good.json"
#: the files of a result folder's reports (removed before a new result is written)
REPORT_NAMES = ("report.html", "report.md")


@dataclass(frozen=True)
class WorkflowResult:
    """What :func:`calibrate_session` did: the result as written, where, and the run behind it."""

    status: str  # ok | failed
    out_dir: Path
    result_path: Path
    result: dict  # result.json's content
    run: Optional[CalibrationRun] = None  # None when the session could not be read
    error: Optional[HandeyeError] = None
    report_paths: tuple = ()
    seconds: dict = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """PASS | WARN | FAIL | REFUSED (result.json's ``verdict``)."""
        return self.result.get("verdict", "FAIL")

    @property
    def exit_code(self) -> int:
        return self.error.exit_code if self.error is not None else verdict_exit_code(self.verdict)


def calibrate_session(
    session_path,
    *,
    options: Optional[CalibrateOptions] = None,
    out_dir,
    report: bool = True,
    qa=None,
    mode: Optional[str] = None,
    progress: Callable[[str], None] | None = None,
    diagnostics: bool = True,
    allow_outside: bool = False,
    site_files=(),
    prior=None,
    board_unmoved: bool = False,
    detected=None,
    figure_process=None,
) -> WorkflowResult:
    """Calibrate the session folder ``session_path`` and write its results into ``out_dir``.

    ``mode`` overrides the session's mounting mode; ``qa`` is a site QA file for the verdict and the
    report (read first: a bad QA file raises before any work); ``progress`` receives one line per
    stage; ``diagnostics=False`` skips the diagnostics (faster, for benchmarks of the solver path only;
    the verdict then rests on the QA checks alone and the report has no findings); ``allow_outside`` lets
    a native session's image and pose-file paths leave its folder; ``site_files`` (the site config and QA
    files) are recorded with the session's files in ``provenance.inputs``. ``prior``: an earlier result of
    the rig (folder, result.json or dict) whose X and intrinsics enter the refinement as priors
    (:func:`handeye.recal.prior.calibrate_with_prior`); result.json's ``prior`` block says what it did.
    ``board_unmoved``: with ``prior``, the board was not touched since (its earlier pose may enter too).
    ``detected``: the session's images' detections made ahead (:func:`handeye.pipeline.detect_ahead`), used
    when they are of the same images and options. ``figure_process``: the command's
    :class:`~handeye.report.figure_process.FigureProcess`, started here once the images are detected (a
    session without images: after the run); it draws the report's figures (drawn here without it, or when
    it cannot).
    """
    from .report.qa import load_qa
    from .session import load_session

    options = CalibrateOptions() if options is None else options
    progress = progress or (lambda s: None)
    t0 = time.perf_counter()
    qa_cfg = load_qa(qa)  # a bad site QA file is unusable input: say so before the calibration, not after it
    if not Path(session_path).exists():
        load_session(session_path, mode=mode, allow_outside=allow_outside)  # raises: nothing to report on
    out_dir = check_out_dir(out_dir)
    with FolderLock(out_dir):
        remove_stray_temps(out_dir)
        return _calibrate_locked(
            session_path,
            options=options,
            out_dir=out_dir,
            report=report,
            qa=(qa, qa_cfg),
            mode=mode,
            progress=progress,
            diagnostics=diagnostics,
            allow_outside=allow_outside,
            t0=t0,
            site_files=site_files,
            prior=prior,
            board_unmoved=board_unmoved,
            detected=detected,
            figure_process=figure_process,
        )


def _calibrate_locked(
    session_path,
    *,
    options,
    out_dir: Path,
    report: bool,
    qa: tuple,
    mode,
    progress,
    diagnostics: bool,
    allow_outside: bool,
    t0: float,
    site_files,
    prior=None,
    board_unmoved: bool = False,
    detected=None,
    figure_process=None,
) -> WorkflowResult:
    """``qa``: (the site QA file or None, its thresholds as loaded)."""
    from .session import load_session

    run_id = uuid.uuid4().hex
    try:
        session = load_session(session_path, mode=mode, allow_outside=allow_outside, check_sizes=False)
    except HandeyeError as e:
        # the session exists but cannot be read: still leave a result and a report that say why
        return _failed_load(
            session_path,
            e,
            mode=mode,
            out_dir=out_dir,
            report=report,
            qa=qa,
            t0=t0,
            diagnostics=diagnostics,
            run_id=run_id,
            figure_process=figure_process,
        )
    t_load = time.perf_counter() - t0
    log.info("session %s: %d views, %s, %s", session.path, len(session.views), session.mode, session.format)
    prior_record = None
    if prior is not None:  # an earlier result as the prior of X and the intrinsics (handeye.recal.prior)
        from .recal.prior import calibrate_with_prior

        run, prior_record = calibrate_with_prior(
            session, options, prior, progress=progress, board_unmoved=board_unmoved
        )
    else:  # the report's figure process starts once the images are detected: a core is free from then on
        start = figure_process.start if (figure_process is not None and report) else None
        run = run_calibration(session, options, progress=progress, detected=detected, on_detected=start)
    if figure_process is not None and report:
        figure_process.start()  # a session without images, or with --prior: now (nothing if it runs already)
    from .results import observations_dict, result_dict

    seconds = {"load": t_load, **run.seconds}
    diag = None
    stage_errors: dict[str, str] = {}
    if diagnostics:
        progress("diagnostics")
        t1 = time.perf_counter()
        from .diagnose import diagnose_run

        diag = optional_stage("diagnostics", diagnose_run, run, errors=stage_errors)
        seconds["diagnose"] = time.perf_counter() - t1
    refusal = refusing_finding(diag)
    if refusal is not None and run.error is None:
        run = _refused(run, refusal)
    elif run.error is None and (misread := global_fault(diag, misread_only=True)) is not None:
        # a matrix from robot poses read wrongly (units, convention, inversion, mode) is no calibration
        run = _refused(run, misread, evidence=False)
    elif run.error is not None and not isinstance(run.error, SessionRefused):
        cause = global_fault(diag)
        if cause is not None:  # the failure is the effect of a fault the diagnostics name: that is the reason
            what = getattr(run.error, "what", run.error)  # not its hint: the cause's fix replaces it
            log.info("the calibration failed (%s); the diagnostics name the cause", what)
            run = _refused(run, cause, evidence=False)
    res = result_dict(run, mode_flag=mode)
    if prior_record is not None:
        res["prior"] = prior_record
    res["run_id"] = run_id
    res.setdefault("provenance", {})["run_id"] = run_id  # the reports show it: one run id in the folder
    if diag is not None:
        res["diagnostics"] = diag
    if stage_errors:
        res["stage_errors"] = stage_errors
    files = [*(session.meta.get("files_read") or [v.image_path for v in session.views]), *site_files]
    seen = {**run.failures, **run.detections}  # the images were hashed as they were decoded: each read once
    digests = {
        os.path.abspath(v.image_path): d.sha256
        for v in session.views
        if v.image_path is not None and (d := seen.get(v.view_id)) is not None and getattr(d, "sha256", None)
    }
    res.setdefault("provenance", {})["inputs"] = inputs_record(
        [f for f in files if f], base=session.path, digests=digests
    )
    t2 = time.perf_counter()
    _keep_previous(out_dir, failed=run.status != "ok")
    write_thumbnails(out_dir, {**run.failures, **run.detections})
    obs_text = to_json({**observations_dict(run), "run_id": run_id}, indent=None)
    observations = json.loads(obs_text)  # parsed once: checked, then judged as a reader sees it
    check_written(observations, Observations, str(out_dir / "observations.json"))
    atomic_write_text(out_dir / "observations.json", obs_text + "\n")
    return _finish(
        out_dir,
        res,
        observations,
        seconds,
        report=report,
        qa=qa,
        t0=t0,
        t_write=t2,
        run=run,
        error=run.error,
        progress=progress,
        figure_process=figure_process,
    )


def optional_stage(name: str, fn, *args, errors: dict, **kwargs):
    """``fn(*args, **kwargs)``, or None when it crashes: an optional stage.

    ``fn(*args, **kwargs)``, or None when it crashes: an optional stage (diagnostics, report) never
    takes the result down. The crash is one error line naming the stage (its traceback at debug level,
    i.e. with ``--debug``) and ``errors[name]`` says what it was, for result.json's ``stage_errors``.
    """
    try:
        return fn(*args, **kwargs)
    except HandeyeError:
        raise
    except Exception as e:  # noqa: BLE001 - an optional stage must not lose the result
        log.error(
            "handeye: the %s stage crashed (%s: %s); the result is written without it. "
            "Rerun with --debug for the traceback and report it",
            name,
            type(e).__name__,
            e,
        )
        log.debug("%s stage traceback", name, exc_info=True)
        errors[name] = f"{type(e).__name__}: {e}"
        return None


def refusing_finding(diagnostics: Optional[dict]) -> Optional[dict]:
    """The first diagnostics finding that refuses the run.

    The first diagnostics finding that refuses the run (``refuses: true`` in the finding or its
    ``details``), or None.
    """
    for f in (diagnostics or {}).get("findings") or []:
        if isinstance(f, dict) and (f.get("refuses") is True or (f.get("details") or {}).get("refuses") is True):
            return f
    return None


def global_fault(diagnostics: Optional[dict], *, misread_only: bool = False) -> Optional[dict]:
    """The first failing diagnostics finding of a fault of the whole session.

    The first failing diagnostics finding of a fault of the whole session
    (:data:`handeye.diagnose.GLOBAL_FAULT_CODES`; ``misread_only``: of the robot poses read wrongly,
    :data:`handeye.diagnose.readings.READING_CODES`), or None.
    """
    from .diagnose import GLOBAL_FAULT_CODES
    from .diagnose.readings import READING_CODES

    codes = READING_CODES if misread_only else GLOBAL_FAULT_CODES
    for f in (diagnostics or {}).get("findings") or []:
        if isinstance(f, dict) and f.get("severity") == "fail" and f.get("code") in codes:
            return f
    return None


def _refused(run: CalibrationRun, finding: dict, *, evidence: bool = True) -> CalibrationRun:
    """The run without any matrix, its error the refusing finding.

    The run without any matrix, its error the refusing finding (with its evidence unless ``evidence`` is
    False: the finding is in the diagnostics with it).
    """
    what = f"the session was refused: {str(finding.get('title') or finding.get('code')).rstrip('.')}"
    if evidence and finding.get("evidence"):
        what += f" ({str(finding['evidence']).rstrip('.')})"
    err = SessionRefused(what, hint=finding.get("action") or None, code=str(finding.get("code") or "session_refused"))
    log.debug("refused: %s", err)  # the command's own last line says it
    return replace(run, status="failed", error=err, T_x=None, T_board=None, start=None, closed_forms={}, refined=None)


def _finish(
    out_dir: Path,
    res: dict,
    observations: Optional[dict],
    seconds: dict,
    *,
    report: bool,
    qa: tuple,
    t0: float,
    t_write: float,
    run,
    error,
    progress,
    figure_process=None,
) -> WorkflowResult:
    """Judge the result (verdict, QA checks, findings) as the report does, from the folder's contents.

    Judge the result (verdict, QA checks, findings) as the report does, from the folder's contents
    (``res`` and ``observations`` as written or about to be, the thumbnails on disk), render the
    reports from that one context, then write result.json once, atomically, ending with every stage's
    time, and the reports beside it.
    """
    from .output import to_json
    from .report.folder import result_folder
    from .results import verdict_fields

    qa_path, qa_cfg = qa
    result_path = out_dir / "result.json"
    paths: tuple[Path, ...] = ()
    seconds["write"] = time.perf_counter() - t_write
    res["seconds"] = dict(seconds)
    with writing(out_dir):
        remove_previous_outputs(out_dir)  # the previous result's reports and exports must not sit beside this one
    t_v = time.perf_counter()
    # the folder as a reader sees it: result.json's content through the JSON it is written as
    folder = result_folder(out_dir, json.loads(to_json(res, indent=None)), observations)
    ctx = _judge(folder, qa_path, qa_cfg)
    res.update(verdict_fields(None if ctx is None else ctx["verdict"], res, error, qa_cfg=qa_cfg))
    seconds["verdict"] = time.perf_counter() - t_v
    rendered = None
    try:
        if report and ctx is not None:
            progress("reports")
            t3 = time.perf_counter()
            rendered = _render_reports(ctx, folder, figure_process)
            seconds["report"] = time.perf_counter() - t3
    finally:  # a rendering that raises (or an interrupt) must not lose the result
        seconds["total"] = time.perf_counter() - t0
        res["seconds"] = seconds
        # once, validated, and before the reports: a report never describes another result
        write_result(result_path, res)
    if rendered is not None:
        paths = tuple(_write_reports(out_dir, rendered))
    if error is None and res.get("verdict") in ("PASS", "WARN"):
        try:
            atomic_write_bytes(out_dir / LAST_GOOD_NAME, result_path.read_bytes())  # result.json as written
        except OutputWriteError as e:  # result.json and the reports are complete: say so, and what failed
            log.warning("%s is written; %s was not: %s", result_path, LAST_GOOD_NAME, e)
    status = "ok" if error is None else "failed"
    return WorkflowResult(status, out_dir, result_path, res, run, error, paths, seconds)


def _failed_load(
    session_path,
    err: HandeyeError,
    *,
    mode,
    out_dir: Path,
    report: bool,
    qa: tuple,
    t0: float,
    diagnostics: bool,
    run_id: str,
    figure_process=None,
) -> WorkflowResult:
    from .results import failed_load_result

    res = failed_load_result(session_path, err, mode)
    res["run_id"] = run_id
    res.setdefault("provenance", {})["run_id"] = run_id
    seconds = {"load": time.perf_counter() - t0}
    if diagnostics:
        t1 = time.perf_counter()
        from .diagnose import diagnose_session_error
        from .pipeline import observe

        stage_errors: dict[str, str] = {}
        diag = optional_stage(
            "diagnostics",
            diagnose_session_error,
            Path(session_path),
            res["failure_reason"],
            observe=observe,
            mode=mode,
            errors=stage_errors,
        )
        if diag is not None:
            res["diagnostics"] = diag
        if stage_errors:
            res["stage_errors"] = stage_errors
        seconds["diagnose"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    _keep_previous(out_dir, failed=True)
    for stale in (out_dir / "observations.json", out_dir / THUMBNAIL_DIR):  # an earlier run's, not this one's
        with writing(stale):
            if stale.is_dir():
                shutil.rmtree(stale)
            elif stale.exists():
                stale.unlink()
    return _finish(
        out_dir,
        res,
        None,
        seconds,
        report=report,
        qa=qa,
        t0=t0,
        t_write=t2,
        run=None,
        error=err,
        progress=lambda s: None,
        figure_process=figure_process,
    )


def _judge(folder, qa, qa_cfg: dict) -> Optional[dict]:
    """The report's context of the result folder.

    The report's context of the result folder (its ``verdict``: :class:`handeye.report.qa.Verdict`),
    without figures, or None when building it crashed (a report bug: logged;
    :func:`handeye.results.verdict_fields` then judges from the findings alone, and no report is written).
    """
    from .report import build_report_context

    try:
        return build_report_context(folder, qa=qa, qa_cfg=qa_cfg, make_plots=False)
    except HandeyeError:
        raise
    except Exception as e:  # noqa: BLE001 - the result must survive a bug in the judging
        log.error(
            "handeye: the QA checks could not be evaluated (%s: %s); the verdict rests on the findings. "
            "Rebuild the report with: handeye --debug report %s",
            type(e).__name__,
            e,
            folder.path,
        )
        return None


def remove_previous_outputs(out_dir: Path) -> list[str]:
    """Remove the reports and the exports of the folder's result.json that a new result replaces.

    The reports (:data:`REPORT_NAMES` and the Markdown report's ``report_files/``) and the files ``handeye export``
    and ``calibrate --export`` wrote into the folder from that result.json (:func:`handeye.export.exports_of`):
    beside a new result they would describe the old one, and hand robots its transform under the new result's
    name. Others (another source, a file of the user's with such a name) stay. Returns the exports' names.
    """
    from .export import exports_of

    for name in REPORT_NAMES:
        (out_dir / name).unlink(missing_ok=True)
    shutil.rmtree(out_dir / "report_files", ignore_errors=True)  # the Markdown report's figures
    removed = []
    for p in exports_of(out_dir / "result.json"):
        p.unlink()
        removed.append(p.name)
    if removed:
        log.info(
            "removed the exports of the result this run replaces (%s): export this one again if it is usable "
            "(handeye export %s --to FORMAT)",
            ", ".join(removed),
            out_dir,
        )
    return removed


def _keep_previous(out_dir: Path, *, failed: bool) -> None:
    """Before a failed run's result.json replaces a successful one, keep a copy as result.previous.json.

    Before a failed run's result.json replaces a successful one, keep a copy as result.previous.json
    (a copy, written atomically: result.json stays in place until the new one replaces it).
    """
    current = out_dir / "result.json"
    out_dir.mkdir(parents=True, exist_ok=True)
    if not failed or not current.exists():
        return
    try:
        data = current.read_bytes()
        previous = json.loads(data.decode("utf-8"))
        was_ok = isinstance(previous, dict) and previous.get("status") == "ok"  # a damaged one is not kept
    except (OSError, ValueError):
        was_ok = False
    if was_ok:
        atomic_write_bytes(out_dir / "result.previous.json", data)


def write_thumbnails(out_dir: Path, per_view: dict) -> list[Path]:
    """``thumbnails/<view_id>.jpg`` from the JPEG bytes detection made.

    ``thumbnails/<view_id>.jpg`` from the JPEG bytes detection made (``thumbnail_jpeg`` on a
    detection or a detection failure); thumbnails of views not in this run are removed.
    """
    folder = Path(out_dir) / THUMBNAIL_DIR
    written = []
    for vid, rec in per_view.items():
        data = getattr(rec, "thumbnail_jpeg", None)
        if data and (folder / f"{vid}.jpg").parent != folder:  # an id that is not one file name stays inside
            log.warning("view %r: no thumbnail (the id is not a file name)", vid)
            continue
        if data:
            written.append(atomic_write_bytes(folder / f"{vid}.jpg", bytes(data), durable=False))
    if folder.is_dir():
        keep = {p.name for p in written}
        with writing(folder):
            for p in folder.glob("*.jpg"):
                if p.name not in keep:
                    p.unlink()
    return written


def _render_reports(ctx: dict, folder, figure_process=None) -> Optional[tuple]:
    """report.html and report.md of the judged context, with its figures, in memory.

    The figures are drawn by ``figure_process`` when it can. None when that crashed (a report bug is
    logged, never fatal: result.json is complete without it).
    """
    from .report import render_reports, report_crashed
    from .report.context import add_figures

    try:
        return render_reports(add_figures(ctx, figure_process), folder, out_dir=folder.path)
    except HandeyeError:
        raise
    except Exception as e:  # noqa: BLE001 - the calibration result must survive a report bug
        report_crashed(e, folder.path)
        return None


def _write_reports(out_dir: Path, rendered: tuple) -> list[Path]:
    """The rendered reports into ``out_dir`` (a failed write is logged: result.json is complete)."""
    from .report import report_crashed
    from .report.render import write_files

    try:
        return write_files(out_dir, *rendered)
    except OutputWriteError as e:  # the file system refused: a write fix, not bug advice
        log.error(
            "handeye: the report could not be written: cannot write %s (%s); result.json is complete. "
            "Free space or make the folder writable, then rebuild it with: handeye report %s",
            e.filename or out_dir,
            e.strerror or e,
            out_dir,
        )
        return []
    except Exception as e:  # noqa: BLE001 - the calibration result must survive a report that cannot be written
        report_crashed(e, out_dir)
        return []
