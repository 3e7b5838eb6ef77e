"""An earlier result as the prior of a new calibration (``handeye calibrate SESSION --prior RESULT``).

The earlier X and intrinsics enter the refinement as one joint Gaussian prior
(:class:`handeye.refine.options.Prior`), so a few new views update the calibration. Whether the data
contradict it is ``handeye verify``'s test on the same views; when they do, the session is calibrated
again without the prior on X (the intrinsics prior kept, and the board pose too with
``--board-unmoved``), and the result says which priors it used and the drift.

See docs/recalibrate.md.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any, Optional

import numpy as np

from ..errors import HandeyeError, InputError
from ..frames import tangent_difference
from ..output import plain
from .loaded import VAGUE_COV_X, LoadedResult, ResultLike, installed_prior, load_result, session_camera
from .verify import VerifyOptions, change_in_result_frame, check_resolution, verify_views

log = logging.getLogger(__name__)


def check_prior_fits(installed: LoadedResult, session) -> None:
    """The earlier result must describe this rig: same mode, board and image resolution.

    The earlier result must describe this rig: same mode, board and (unless the session brings its own
    intrinsics) image resolution; else a one-line InputError.
    """
    if not installed.ok or installed.cov_x is None:
        raise InputError(
            "the prior result has no hand-eye matrix with a covariance",
            path=installed.source,
            hint="use a result calibrated with the refinement (status ok)",
        )
    if session.mode != installed.mode:
        raise InputError(
            f"the prior is {installed.mode} but the session is {session.mode}",
            path=installed.source,
            code="not_comparable",
            hint="use a result of this rig's mounting mode as --prior",
        )
    if installed.target is not None and session.target.to_dict() != installed.target:
        raise InputError(
            f"the prior used another board than the session ({session.target.describe()})",
            path=installed.source,
            code="not_comparable",
            hint="use a result of this board as --prior",
        )
    if session.intrinsics is None:  # the prior's intrinsics would describe these images
        check_resolution(installed, session)


#: result.json's field behind each part of the prior (:class:`handeye.refine.options.Prior`)
_PRIOR_FIELDS = {
    "prior.cov_intrinsics": "refinement.intrinsics_sigma / refinement.cov_x_intrinsics.intrinsics_kxk",
    "prior.cov_x_intrinsics": "refinement.cov_x_intrinsics.cross_6xk",
    "prior.cov_board": "refinement.cov_board_6x6",
    "prior.cov_board_intrinsics": "refinement.cov_x_intrinsics.cross_board_6xk",
    "prior.cov_dh": "refinement.cov_x_intrinsics (its DH offsets)",
}


def check_prior_file(prior, installed: LoadedResult) -> None:
    """The prior built from ``installed``, checked as the refinement will check it.

    A broken covariance is one InputError naming the prior's file and its result.json field (not a refine
    option: the user gave a file).
    """
    from ..refine.options import check_prior

    def bad(field_name, expected, got):
        fields = dict(
            _PRIOR_FIELDS, **{"prior.cov_x": f"refinement.{installed.cov_source}", "prior.T_x": installed.x_name}
        )
        where = fields.get(field_name, field_name)
        raise InputError(
            f"the prior's {where} is not usable ({field_name})",
            path=installed.source,
            expected=expected,
            received=got,
            hint="use another result as --prior, or recalibrate the rig without --prior",
            code="prior_invalid",
        )

    check_prior(prior, bad)


def _with_prior(session, options, installed: LoadedResult, *, cov_x=None, board: bool = False):
    """(session, options) with the earlier X and intrinsics as priors.

    (session, options) with the earlier X (covariance ``cov_x``, default its own) and, unless the session
    has its own intrinsics, the earlier intrinsics as priors (:func:`handeye.recal.loaded.installed_prior`:
    the session starts from them, the refinement estimates them under their prior); ``board``: the earlier
    board pose too (jointly with the intrinsics), for a board that has not moved.
    """
    own = session.intrinsics is not None and session.intrinsics_prior in ("fixed", "prior")
    prior, held = installed_prior(installed, session_intrinsics=own, cov_x=cov_x, board=board)
    check_prior_file(prior, installed)
    ro = dict(options.refine_options, prior=prior)
    if prior.intrinsics is not None:
        ro["intrinsics"] = "estimate"  # the prior's intrinsics term, and no factory prior on top of it
        ro["fix"] = tuple(sorted(set(ro.get("fix", ())) | set(held)))
        session = replace(session, intrinsics=installed.intrinsics, intrinsics_prior="prior")
    return session, replace(options, refine_options=ro)


def calibrate_with_prior(
    session,
    options,
    prior: ResultLike,
    *,
    progress=None,
    verify_options: Optional[VerifyOptions] = None,
    board_unmoved: bool = False,
) -> tuple:
    """Calibrate ``session`` (loaded) with the result ``prior`` as the prior of X and the intrinsics.

    When the data contradict it, calibrate again without the prior on X and say so. ``board_unmoved``: the
    user states that the board was not touched since; then, in that second calibration, the earlier board
    pose enters too unless verify's test finds the board moved.

    Returns (the CalibrationRun kept, result.json's ``prior`` block: the prior, the update, the test and the
    ``change`` of X it estimates, ``contradicted``, ``used``).
    """
    from ..diagnose.consistency import board_turns
    from ..pipeline import run_calibration

    progress = progress or (lambda s: None)
    if not options.refine:
        raise InputError(
            "--prior enters the joint refinement",
            expected="a calibration with the refinement",
            received="--no-refine",
            hint="drop --no-refine or --prior",
        )
    o = verify_options or VerifyOptions.from_config()
    installed: LoadedResult
    if isinstance(prior, LoadedResult):
        installed = prior
    else:  # a cell: the camera the session folder is named after
        hint = "name the session folder after its camera, or give --prior that camera's own result"
        installed = load_result(prior, camera=session_camera(prior, session.path, what="--prior", hint=hint))
    check_prior_fits(installed, session)
    assert installed.T_x is not None and installed.cov_x is not None, "check_prior_fits: an ok result"
    s_p, opts_p = _with_prior(session, options, installed)
    prior_used = opts_p.refine_options["prior"]
    progress(f"calibrating with the prior {installed.label}")
    run = run_calibration(s_p, opts_p, progress=progress)
    rec: dict[str, Any] = {
        "source": installed.label,
        "covariance_used": installed.cov_source,
        "frame": installed.x_name,
        installed.x_name: installed.T_x,
        "cov_x_6x6": installed.cov_x,
        "sigma_trans_mm": 1000.0
        * np.sqrt(np.diag(installed.T_x[:3, :3] @ installed.cov_x[3:, 3:] @ installed.T_x[:3, :3].T)),
        "sigma_rot_deg": np.degrees(np.sqrt(np.diag(installed.cov_x[:3, :3]))),
        "intrinsics": "the session's own" if prior_used.intrinsics is None else "the prior's, with its sigmas",
        "alpha": o.alpha,
    }
    if run.status == "ok" and run.refined is not None and run.T_x is not None:  # an ok run has X
        xi = tangent_difference(installed.T_x, run.T_x)
        spread = installed.cov_x - run.refined.cov_x_6x6  # the update's covariance when the prior is right
        rec["update"] = dict(
            change_in_result_frame(installed.T_x, xi, 0.5 * (spread + spread.T)),
            sigma_meaning="1-sigma of the update when the prior is right (prior minus posterior covariance)",
        )
    contradicted, why, v = True, f"the calibration with the prior failed ({run.error})", None
    if len(run.board_poses) >= 3:
        try:
            v = verify_views(
                installed,
                views=_refine_views(run),
                object_points=session.target.object_points(),
                intrinsics=None if prior_used.intrinsics is not None else session.intrinsics,
                options=o,
                board_turns=[F for _, F in board_turns(session.target)],
            )
        except HandeyeError as e:
            why = f"the test of the prior failed ({e})"
    if v is not None:
        t = v.test
        rec["test"] = {
            "kind": "handeye verify's test on these views: " + t.kind,
            "statistic": t.statistic,
            "dof": t.dof,
            "p_value": t.p_value,
            "reference": t.reference,
            "robot_noise_dof": t.noise_dof,
        }
        rec["change"] = dict(v.change, p_value=t.p_value)
        contradicted = v.drifted or run.status != "ok"
        why = f"the views are beyond the prior's uncertainty (p = {t.p_value:.3g} < {o.alpha:g})" if v.drifted else why
    rec["contradicted"] = contradicted
    rec["board_prior"] = False
    rec["prior_views"] = prior_views(installed)
    if not contradicted:
        rec["used"] = "prior"
        rec["views_with_prior"] = _n_used(run) + rec["prior_views"]
        rec["summary"] = (
            f"the prior {installed.x_name} was updated by {rec['update']['trans_mm']:.2f} mm, "
            f"{rec['update']['rot_deg']:.3f} deg; the data agree with it "
            f"(p = {rec['test']['p_value']:.3g})"
        )
        log.debug("prior: %s", rec["summary"])  # the command prints it after the result
        return _described(run), plain(rec, nan_to_none=True)
    tested = v is not None and run.status == "ok"
    rec["tested"] = tested
    progress(
        "the data contradict the prior: calibrating without it"
        if tested
        else "the prior could not be tested: calibrating without it"
    )
    # the intrinsics prior stays; so does the board's pose when the user says the board was not touched and verify
    # does not find it moved (a bumped camera does not move the board, and each new view then measures X through it;
    # a few views cannot tell a board moved by a millimetre from a bumped camera, so it is the user's statement)
    board_kept = bool(
        board_unmoved
        and v is not None
        and v.board.get("known")
        and not v.board.get("moved")
        and installed.board_joint is not None
    )
    # a symmetric board numbered from another corner than in the earlier session: its board pose in this turn
    board_from = (
        installed.with_board_turned(np.asarray(v.board["T_turn"]))
        if board_kept and v is not None and "T_turn" in v.board
        else installed
    )
    s_n, opts_n = _with_prior(session, options, board_from, cov_x=VAGUE_COV_X, board=board_kept)
    run_n = run_calibration(s_n, opts_n, progress=progress)
    if board_kept and any(
        getattr(bp, "orientation", 0) != getattr(run.board_poses.get(vid), "orientation", 0)
        for vid, bp in run_n.board_poses.items()
    ):
        # the run numbered the board otherwise than the views verify turned the earlier board pose for: that pose
        # does not apply (the runs number the same detections alike; this guards the assumption)
        log.warning("prior: the board was numbered otherwise in the calibration run; calibrating without its pose")
        board_kept = False
        s_n, opts_n = _with_prior(session, options, installed, cov_x=VAGUE_COV_X, board=False)
        run_n = run_calibration(s_n, opts_n, progress=progress)
    if board_kept:
        assert v is not None, "board_kept needs the verification"
        rec["board_turn_deg"] = float(v.board.get("turn_deg", 0.0))
    rec["used"] = (
        "no prior on X (the new views with the prior's intrinsics and board pose: the board did not move)"
        if board_kept
        else "no prior on X (the new views alone; the prior's intrinsics kept)"
    )
    overruled = ""
    if board_unmoved and not board_kept and v is not None and v.board.get("moved"):
        b = v.board  # the user's word against the data: say which one the run followed
        overruled = (
            f"; --board-unmoved was overruled: the board moved by {b['trans_mm']:.1f} mm / "
            f"{b['rot_deg']:.2f} deg (sigma {b['sigma_trans_mm']:.1f} mm / {b['sigma_rot_deg']:.2f} deg), "
            "so its earlier pose was not used"
        )
        rec["board_unmoved_overruled"] = True
    rec["board_prior"] = board_kept
    rec["views_with_prior"] = _n_used(run_n)  # X from the new views alone: the prior's views do not count
    lead = "the data contradict the prior" if tested else "the prior could not be tested"
    if run_n.status == "ok" and run_n.refined is not None:
        size = (
            f"; {installed.x_name} drifted by {rec['change']['trans_mm']:.2f} mm, {rec['change']['rot_deg']:.3f} deg"
            if "change" in rec and tested
            else ""
        )
        rec["summary"] = (
            f"{lead}: {why}{size} (the result is the new views' calibration without the prior on X){overruled}"
        )
    else:
        rec["summary"] = f"{lead}: {why}; the calibration without it failed too"
    log.debug("prior: %s", rec["summary"])  # the command prints it after the result
    return _described(run_n), plain(rec, nan_to_none=True)


def prior_views(installed: LoadedResult) -> int:
    """The views behind the prior's X: those its result used, plus its own prior's when that one held."""
    raw = installed.raw or {}
    own: dict = raw["prior"] if isinstance(raw.get("prior"), dict) else {}
    if own.get("used") == "prior":
        n = own.get("views_with_prior")
    elif isinstance(raw.get("n_views"), dict):
        n = raw["n_views"].get("used")
    else:  # a result written without the view table: the views its refinement used
        per_view = (raw.get("refinement") or {}).get("per_view")
        n = sum(isinstance(v, dict) and v.get("status") == "used" for v in per_view.values()) if per_view else 0
    return int(n) if isinstance(n, (int, float)) and not isinstance(n, bool) and n >= 0 else 0


def _n_used(run) -> int:
    return sum(bool(o.used) for o in run.outcomes)


def _refine_views(run) -> list:
    """The detected views of a calibration run as the refinement takes them (corners in the board's order)."""
    from ..refine import RefineView

    return [
        RefineView(
            vid,
            bp.corner_ids,
            run.detections[vid].image_points,
            run.session.view(vid).T_base_end,
            run.session.view(vid).joint_angles,
        )
        for vid, bp in run.board_poses.items()
    ]


def _described(run):
    """The run with the prior in its options described in words.

    The run with the prior in its options described in words (result.json's provenance records the
    options; the prior's numbers are in the ``prior`` block).
    """
    ro = dict(run.options.refine_options)
    if "prior" in ro:
        ro["prior"] = "the earlier result in the prior block"
    return replace(run, options=replace(run.options, refine_options=ro))
