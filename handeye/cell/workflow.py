"""``handeye calibrate SESSION_1 SESSION_2 ...`` or ``handeye calibrate CELL_DIR``: a cell of cameras, once.

:func:`calibrate_cell` calibrates each camera's session on its own (:func:`handeye.workflow.calibrate_session`
into ``OUT/solo/<camera>/``: detection, intrinsics, closed forms, its refinement, diagnostics and report; the
next camera's images are detected while one is calibrated), then refines every camera in one factor graph
(:func:`handeye.refine.cell.refine_cell`) and writes one result.json (``kind: cell``, :mod:`handeye.contract`)
with each camera's joint result, the camera pairs, the joint covariance and the cross-camera checks, and the
cell's report. A camera is named by its session folder's name. A cell folder holds ``cell.yaml``
(``cell: {sessions: [...]}``, optional ``robot:``).

See docs/session_format.md and docs/refinement.md.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from ..contract import RESULT_VERSION, write_result
from ..errors import CalibrationError, HandeyeError, InputError, verdict_exit_code
from ..output import FolderLock, check_out_dir, provenance, read_text, recorded_path, remove_stray_temps
from ..pipeline import CalibrateOptions
from ..session.fields import CELL_FILE, is_cell_folder
from ..workflow import calibrate_session, remove_previous_outputs

log = logging.getLogger(__name__)

SOLO_DIR = "solo"
CAMERA_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class CellWorkflowResult:
    """What :func:`calibrate_cell` did: the cell's result as written and each camera's solo run."""

    status: str
    out_dir: Path
    result_path: Path
    result: dict
    solos: dict  # camera name -> handeye.workflow.WorkflowResult
    report_paths: tuple = ()

    @property
    def verdict(self) -> str:
        return self.result.get("verdict", "FAIL")

    @property
    def exit_code(self) -> int:
        return verdict_exit_code(self.verdict)


def read_cell_file(folder) -> tuple[list[Path], Optional[str]]:
    """(session folders, the arm named by ``robot:`` or None) of a cell folder's ``cell.yaml``."""
    from ..config import parse_yaml
    from ..session.keys import CELL_KEYS, CELL_SECTION_KEYS, unknown_keys

    path = Path(folder) / CELL_FILE
    doc = parse_yaml(read_text(path), path=path)
    cell = doc.get("cell") if isinstance(doc, dict) else None
    sessions = cell.get("sessions") if isinstance(cell, dict) else None
    if not isinstance(sessions, list) or not sessions or not all(isinstance(s, str) and s for s in sessions):
        raise InputError(
            "cell.sessions must list the cell's session folders",
            path=path,
            expected="cell: {sessions: [cam1, cam2, ...]} (folders relative to the cell folder)",
            received=repr(sessions),
        )
    for line in unknown_keys(doc, CELL_KEYS) + unknown_keys(cell, CELL_SECTION_KEYS, prefix="cell."):
        log.warning("%s: %s", path, line)
    robot = doc.get("robot")
    if robot is not None and not isinstance(robot, str):
        raise InputError(
            "robot must name the arm",
            path=path,
            expected="a preset (e.g. ur5e) or a DH table file",
            received=repr(robot),
        )
    if robot is not None and (Path(folder) / robot).is_file():
        robot = str((Path(folder) / robot).resolve())
    return [Path(folder) / s for s in sessions], robot


def camera_names(session_paths: Sequence) -> list[str]:
    """Each session folder's name, checked: usable in a frame name, one per camera."""
    names = []
    for p in session_paths:
        q = Path(p)
        name = (q.parent if q.is_file() else q).resolve().name
        if not CAMERA_NAME.match(name) or len(name) > 64:
            raise InputError(
                f"session folder name {name!r} cannot name a camera of the cell",
                path=q,
                expected="letters, digits, '_', '.', '-' (starting with a letter or digit), at most 64",
                hint="rename the folder (it becomes the camera's name, e.g. T_cam1_cam2)",
            )
        if name in names:
            raise InputError(
                f"two sessions of the cell are named {name!r}",
                path=q,
                hint="each camera's session folder needs its own name",
            )
        names.append(name)
    return names


def check_cell_sessions(paths: Sequence[Path], names: Sequence[str], *, mode=None, allow_outside=False) -> list:
    """Every camera's session, read and the robot poses of the view ids they share compared, before any work.

    A missing or unreadable session, or one view id at two robot poses, is an InputError naming the file;
    nothing has been calibrated or written then. Returns the sessions in ``paths``' order.
    """
    from ..refine.cell import robot_pose_conflict
    from ..session import load_session

    seen: dict[str, np.ndarray] = {}  # view id -> the robot pose the first camera with it gives
    sessions = []
    for name, p in zip(names, paths, strict=True):
        if not Path(p).exists():
            raise InputError(
                f"camera {name}: its session folder is not there",
                path=p,
                hint="the cell's list (cell.yaml or the command line) names a folder that does not exist: "
                "fix the name or add the folder",
            )
        s = load_session(p, mode=mode, allow_outside=allow_outside, check_sizes=False)
        sessions.append(s)
        folder = Path(s.path)
        pose_file = next((f for f in (folder / "session.yaml", folder / "poses.txt") if f.is_file()), folder)
        for v in s.views:
            if v.view_id in seen:
                conflict = robot_pose_conflict(v.view_id, name, seen[v.view_id], v.T_base_end, path=pose_file)
                if conflict is not None:
                    raise conflict
            else:
                seen[v.view_id] = np.asarray(v.T_base_end, float)
    return sessions


def _remove_other_cameras(solo_dir: Path, names: Sequence[str]) -> None:
    """Remove an earlier run's results of cameras this cell does not have (their folders hold a result.json)."""
    if not solo_dir.is_dir():
        return
    for d in solo_dir.iterdir():
        if d.is_dir() and d.name not in names and (d / "result.json").is_file():
            log.info("removing %s: a camera of an earlier cell in this folder, not of this one", d)
            shutil.rmtree(d)


def _detect_ahead(session, options: CalibrateOptions):
    """A camera's images (its session as :func:`check_cell_sessions` read it) detected ahead of its calibration.

    (:class:`handeye.pipeline.Detected`), or None when that fails: the camera's own calibration then says why,
    in its result and report.
    """
    from ..pipeline import detect_ahead

    try:
        return detect_ahead(session, options)
    except HandeyeError as e:
        log.debug("%s: not detected ahead (%s)", session.path, e)
        return None


def calibrate_cell(
    session_paths: Sequence,
    out_dir,
    *,
    options: Optional[CalibrateOptions] = None,
    report: bool = True,
    qa=None,
    mode: Optional[str] = None,
    progress: Callable[[str], None] | None = None,
    diagnostics: bool = True,
    allow_outside: bool = False,
    site_files=(),
) -> CellWorkflowResult:
    """Calibrate the sessions of one arm (or a cell folder with cell.yaml) as one cell into ``out_dir``.

    The options are those of :func:`handeye.workflow.calibrate_session`, applied to every camera; ``mode``
    overrides every session's mounting mode (rarely right for a mixed cell). See the module docstring.
    """
    from ..refine.cell import refine_cell
    from ..report.qa import load_qa
    from .build import camera_input, cell_result, dh_prior_scale, excluded_by_most, start_options

    t0 = time.perf_counter()
    progress = progress or (lambda s: None)
    options = CalibrateOptions() if options is None else options
    paths = [Path(p) for p in session_paths]
    if options.robot_accuracy is not None:
        raise InputError(
            "--robot-accuracy is for one session, not a cell",
            received=" ".join(str(p) for p in paths),
            hint="a cell's joint covariance models the arm with its DH table: name the arm (--robot ARM or robot: "
            "in cell.yaml), or calibrate a camera alone with --robot-accuracy",
        )
    if len(paths) == 1 and is_cell_folder(paths[0]):
        paths, robot = read_cell_file(paths[0])
        if robot is not None and options.refine_options.get("arm") is None:
            options = replace(options, refine_options={**options.refine_options, "arm": robot})
    if len(paths) < 2:
        raise InputError(
            "a cell needs two cameras or more",
            path=paths[0],
            received=f"{len(paths)} session",
            hint=f"calibrate it as one session (handeye calibrate {paths[0]}), or list the other cameras",
        )
    names = camera_names(paths)
    sessions = check_cell_sessions(paths, names, mode=mode, allow_outside=allow_outside)
    load_qa(qa)  # a bad site QA file is unusable input: say so before any work
    out = check_out_dir(out_dir)
    with FolderLock(out):
        remove_stray_temps(out)
        _remove_other_cameras(out / SOLO_DIR, names)
        solos = {}
        # one thread detects the cameras' images in turn, ahead of their calibrations (detection releases the
        # GIL): the next camera's images are detected while one camera is calibrated
        ahead = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cell-detect")
        try:
            detecting = [ahead.submit(_detect_ahead, s, options) for s in sessions]
            for name, p, detected in zip(names, paths, detecting, strict=True):
                progress(f"camera {name}: its own calibration")
                solos[name] = calibrate_session(
                    p,
                    options=options,
                    out_dir=out / SOLO_DIR / name,
                    report=report,
                    qa=qa,
                    mode=mode,
                    progress=progress,
                    diagnostics=diagnostics,
                    allow_outside=allow_outside,
                    site_files=site_files,
                    detected=detected.result(),
                )
        finally:
            ahead.shutdown(wait=True, cancel_futures=True)
        ok = {
            n: w.run for n, w in solos.items() if w.status == "ok" and w.run is not None and w.run.refined is not None
        }
        ok = {n: r for n, r in ok.items() if r.refined.status == "ok"}
        if not ok:
            raise CalibrationError(
                "no camera of the cell could be calibrated",
                hint=f"see each camera's result in {out / SOLO_DIR}",
                code="cell_failed",
            )
        progress("the cell's joint refinement")
        ref_opts = start_options(ok)
        t1 = time.perf_counter()
        cr = refine_cell(
            [camera_input(n, r) for n, r in ok.items()],
            options=ref_opts,
            robot_excluded0=excluded_by_most(ok),
            dh_scale0=dh_prior_scale(ok),
        )
        t_joint = time.perf_counter() - t1
        res = cell_result(cr, {n: w.result for n, w in solos.items()}, ok, version=RESULT_VERSION)
        run_id = uuid.uuid4().hex
        res["run_id"] = run_id
        res["provenance"] = provenance(
            extra={"sessions": {n: recorded_path(p.resolve()) for n, p in zip(names, paths, strict=True)}}
        )
        res["provenance"]["run_id"] = run_id
        res["seconds"] = {
            "cameras": {n: w.result.get("seconds", {}).get("total") for n, w in solos.items()},
            "joint": t_joint,
            "total": time.perf_counter() - t0,
        }
        remove_previous_outputs(out)  # the previous result's reports and exports must not sit beside this one
        result_path = write_result(out / "result.json", res)
        reports: tuple = ()
        if report:
            from .report import write_cell_report

            try:
                reports = tuple(write_cell_report(out, res))
            except HandeyeError as e:  # the result stands without its report
                log.warning("the cell's report was not written: %s", e)
        return CellWorkflowResult(
            status="ok",
            out_dir=out,
            result_path=result_path,
            result=json.loads(result_path.read_text(encoding="utf-8")),
            solos=solos,
            report_paths=reports,
        )
