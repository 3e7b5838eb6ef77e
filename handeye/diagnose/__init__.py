"""Dataset diagnostics that name the mistake, and validation by held-out views.

:func:`diagnose_run` looks at a :class:`handeye.pipeline.CalibrationRun` (successful or failed) and
returns the ``diagnostics`` block of result.json (findings, stage statuses, cross-validation);
:func:`diagnose_session_error` re-reads the raw poses of a session that does not load in every
plausible way and says which reading fits the images. Every check runs as a named stage: one that
raises is reported as ``crashed``, never as a finding. All functions are pure; images are only read.

See docs/diagnostics.md for the modules and every finding.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from ..frames import inv_T
from ..mounting import mounting
from ..output import plain
from ..records import view_id_key
from .arm import arm_table_findings, unreachable_pose_findings
from .consistency import (
    board_moved_findings,
    corner_flip_findings,
    flagged_views,
    motion_findings,
    robot_pose_check,
    robot_pose_findings,
    view_count_findings,
    view_disagreements,
)
from .crossval import cross_validate
from .detection import another_board_size, detection_findings
from .findings import SEVERITIES, Finding, Stages, worst_first
from .imaging import coverage_findings, image_findings, image_metrics
from .intrinsics import distortion_findings
from .observations import PoseObservations, candidates_of, observations_from_run
from .pairing import pairing_findings, partial_shift_findings, swapped_pose_findings
from .readings import (
    READING_CODES,
    alternative_formats,
    evaluate_readings,
    given_reading,
    read_poses,
    reading_findings,
    reading_in_use,
)
from .scale import scale_findings
from .thresholds import thresholds

log = logging.getLogger(__name__)

__all__ = ["diagnose_run", "diagnose_session_error", "Finding", "SEVERITIES", "alternative_formats"]

#: findings that say the robot poses as a whole do not match the images as read or paired
GLOBAL_FAULT_CODES = READING_CODES + (
    "pairs_shifted",
    "pairs_shuffled",
    "square_size",
    "images_mirrored",
    "scale_unexplained",
)


def _pose_checks(
    stages: Stages, obs: PoseObservations, *, refined=None, session_kind: str = "native", pairing=None
) -> dict:
    """Readings, pairing, board move, per-view disagreement and motion on one set of observations.

    Readings, pairing, board move, per-view disagreement and motion on one set of observations
    (``pairing``: the pairing search the calibration already made, :class:`.pairing.PairingSearch`).

    Returns ``{"findings", "readings", "global_fault", "global_reason", "per_view", "fit", "M"}`` (fit/M None when
    the readings crashed; ``global_reason``: the global fault in words).
    """
    out: dict = {
        "findings": [],
        "readings": [],
        "global_fault": False,
        "global_reason": "",
        "per_view": {},
        "fit": None,
        "M": None,
        "scale": None,
    }
    readings = stages.run("readings", evaluate_readings, obs)
    if readings is None:
        for name in ("pairing", "scale", "board_moved", "robot_poses"):
            stages.skip(name, "the readings stage crashed")
        out["findings"] += stages.run("motion", motion_findings, obs.mode, obs.M(), default=[])
        return out
    out["readings"] = [r.row() for r in readings[:8]]
    given = given_reading(readings)
    if given is None and readings and readings[0].fit.cost < thresholds().readings.good_cost:
        given_cost = float("inf")  # the stated reading does not even parse
        rf = stages.run(
            "readings",
            reading_findings,
            obs,
            [replace(readings[0], changes=(), invert=False)] + list(readings),
            session_kind=session_kind,
            default=[],
        )
    else:
        given_cost = given.fit.cost if given is not None else float("inf")
        rf = stages.run("readings", reading_findings, obs, readings, session_kind=session_kind, default=[])
    out["findings"] += rf
    M, fit = stages.run("readings", reading_in_use, obs, readings, rf, default=(obs.M(), None))
    out["global_fault"] = bool(rf)
    out["global_reason"] = "the robot poses do not match the images as read" if rf else ""
    motion_ok = _motion_ok(obs, M)
    not_run = (
        "no fit of the poses as read"
        if fit is None
        else "the robot poses do not match the images as read"
        if rf
        # a motion that leaves X undetermined fits alternative pairings or a moved board as well as the truth
        else "the robot motion does not determine the hand-eye transform (see the motion findings)"
        if not motion_ok
        else None
    )
    if not_run is not None:
        for name in ("pairing", "scale", "board_moved", "robot_poses"):
            stages.skip(name, not_run)
    else:
        pf = stages.run(
            "pairing", pairing_findings, obs, obs.raw.fmt, given_cost=given_cost, search=pairing, default=[]
        )
        out["findings"] += pf
        out["global_fault"] = bool(pf)
        if pf:
            out["global_reason"] = "images and robot poses are paired wrongly"
            for name in ("scale", "board_moved", "robot_poses"):
                stages.skip(name, out["global_reason"])
        else:
            sf, est = stages.run("scale", scale_findings, obs, fit, M, refined=refined, default=([], None))
            out["findings"] += sf
            out["scale"] = (
                None
                if est is None
                else {"scale": est.k, "sigma": est.sigma, "n_views": est.n_views, "p_value": est.p_value()}
            )
            if sf:
                out["global_fault"] = True
                out["global_reason"] = f"the board's scale does not match the robot's ({sf[0].code})"
                for name in ("board_moved", "robot_poses"):
                    stages.skip(name, out["global_reason"])
            else:
                bm, segfit = stages.run("board_moved", board_moved_findings, obs, M, default=([], None))
                out["findings"] += bm
                fit = segfit or fit
                found = stages.run(
                    "robot_poses",
                    _robot_pose_stage,
                    obs,
                    fit,
                    refined=refined,
                    exclude=bm[0].view_ids if bm else (),
                    default=None,
                )
                if found is not None:
                    out["findings"] += found[0]
                    out["per_view"] = found[1]
    if (
        given_cost > thresholds().readings.bad_cost
        and not any(f.severity in ("fail", "warn") for f in out["findings"])
        and motion_ok
    ):  # (a degenerate motion does not determine the fit: the motion finding says so)
        out["findings"].append(_unexplained(obs, given))
        out["global_fault"] = True
        out["global_reason"] = "the robot poses do not fit the images as read, for no cause found"
    out["findings"] += stages.run("motion", motion_findings, obs.mode, M, A=None if fit is None else fit.A, default=[])
    out["fit"], out["M"] = fit, M
    return out


def _unexplained(obs: PoseObservations, given) -> Finding:
    """The poses as read do not fit the images and no check found why: never a quiet pass."""
    target = "tracked target" if obs.tracker else "board"
    sc = (
        ""
        if given is None
        else (
            f": the {target} implied by each view scatters by {given.fit.median_rot_deg:.2f} deg / "
            f"{given.fit.median_trans_mm:.1f} mm (median over {obs.n} views)"
        )
    )
    if obs.tracker:  # a pose-only session: the tracker's poses, whose format no reading above tried
        seen, read, action = (
            "the tracker's poses",
            "robot pose numbers, pairing, scale, target move",
            "check the tracker's pose format (target_pose_format: rotation, quaternion_order, translation_unit; "
            "camera -> target, not its inverse), that each tracker pose is paired with the robot pose of that "
            "moment, and the mounting mode",
        )
    else:
        seen, read, action = (
            "the images",
            "pose numbers, pairing, scale, board move",
            "check that every image is paired with the pose recorded at that moment, the pose format, the "
            "mounting mode and the board; re-capture if unsure",
        )
    return Finding(
        "poses_do_not_fit",
        "fail",
        f"The robot poses do not fit {seen} as read, and no single cause was found",
        f"no reading of the {read} or single view explains it{sc}",
        action,
    )


def _motion_ok(obs: PoseObservations, M: np.ndarray) -> bool:
    """The motion passes the degeneracy gates (a scale needs rotations about two axes)."""
    from ..initial import motion_quality

    return motion_quality(M, frame=obs.mounting.fixed_frame).status == "ok"


def _robot_pose_stage(obs: PoseObservations, fit, *, refined=None, exclude=()) -> tuple[list, dict]:
    """(findings, per-view numbers) of the robot poses that disagree.

    (findings, per-view numbers): robot poses that disagree, explained by a corner flip or a swap where
    one fits.
    """
    covs = obs.pnp_covariances(with_intrinsics=False)
    check = robot_pose_check(obs, fit, covs=covs)
    check_k = (
        robot_pose_check(obs, fit, covs=obs.pnp_covariances())
        if obs.intrinsics_estimated and covs is not None
        else None
    )
    flagged, ref_flags, source = flagged_views(obs, check, refined=refined, check_with_intrinsics=check_k)
    flagged = [v for v in flagged if v not in set(exclude)]
    out, flipped = corner_flip_findings(obs, check, flagged, covs)
    flagged = [v for v in flagged if v not in flipped]
    stepped, out_of_step = partial_shift_findings(obs, fit, flagged)
    out += stepped
    flagged = [v for v in flagged if v not in out_of_step]
    swaps, swapped = swapped_pose_findings(obs, check, flagged, obs.raw.fmt)
    out += swaps
    out += robot_pose_findings(obs, check, [v for v in flagged if v not in swapped], ref_flags=ref_flags, source=source)
    rot, trans = view_disagreements(obs.mode, fit, obs.C, obs.T)
    per_view = {
        v: {
            "robot_vs_camera_rot_deg": float(rot[k]),
            "robot_vs_camera_trans_mm": float(trans[k]),
            "robot_vs_camera_sigmas": float(check.test.distance[k]),
            "implied_board_rot_deg": float(fit.board_rot_deg[k]),
            "implied_board_trans_mm": float(fit.board_trans_mm[k]),
        }
        for k, v in enumerate(obs.ids)
    }
    return out, per_view


def _prediction(run, pose_checks: Optional[dict]):
    """(A, B, inverted) to predict where the board should have been in views without it, or None."""
    if pose_checks is None or pose_checks["fit"] is None:
        return None
    if not pose_checks["global_fault"] and run.T_x is not None and run.T_board is not None and run.status == "ok":
        return inv_T(run.T_x), run.T_board, False
    fit = pose_checks["fit"]
    inverted = pose_checks["global_fault"] and any(
        f.code in ("poses_inverted", "mode_swapped") for f in pose_checks["findings"]
    )
    return fit.A, fit.B[0], inverted


def diagnose_run(run, *, images: bool = True, cross_validation: bool = True) -> dict:
    """Diagnostics of a calibration run (successful or failed) for ``result.json["diagnostics"]``.

    Returns ``{"version", "findings": [Finding as dict, worst first], "stages": {name: ok|crashed|skipped},
    "stage_errors": {name: "Type: message"}, "crashed_stages": int, "cross_validation": {...},
    "readings": [...], "per_view": {view_id: {...}}, "images": {view_id: {...}}}``. ``images=False``
    skips the image measures (blur, exposure); ``cross_validation=False`` skips the refits.
    """
    s = run.session
    stages = Stages()
    findings: list = []
    result: dict = {"version": 2}
    obs = stages.run("observations", observations_from_run, run)
    pose = None
    if obs is not None:
        pose = _pose_checks(
            stages, obs, refined=run.refined, session_kind=s.format, pairing=getattr(run, "pairing", None)
        )
        findings += pose["findings"]
        result["readings"] = pose["readings"]
        result["scale"] = pose["scale"]
    else:
        for name in ("readings", "pairing", "board_moved", "robot_poses"):
            stages.skip(name, f"fewer than {thresholds().views.min_fail} views with a board pose")
        if stages.status.get("observations") == "ok" and (run.detections or run.outcomes):
            if another_board_size(run) is None:  # else the count is the wrong board size's effect (its finding)
                findings += stages.run("motion", view_count_findings, len(run.board_poses or {}), default=[])
            else:
                stages.skip("motion", "the images show another board size than the stated one")
        else:
            stages.skip("motion", "no views to count")
    global_fault = bool(pose and pose["global_fault"])
    predict = _prediction(run, pose)
    if predict is None or run.intrinsics is None:
        findings += stages.run("detection", detection_findings, run, default=[])
    else:
        A, B, inverted = predict
        findings += stages.run("detection", detection_findings, run, A=A, B=B, invert_poses=inverted, default=[])
    findings += stages.run("intrinsics", distortion_findings, run, default=[])
    metrics = {}
    if images:
        metrics = stages.run("images", image_metrics, run, default={})
        findings += stages.run("images", image_findings, metrics, default=[])
        result["images"] = {
            v: {k: (round(float(x), 4) if isinstance(x, (float, np.floating)) else x) for k, x in m.items()}
            for v, m in metrics.items()
        }
    else:
        stages.skip("images", "not asked for")
    findings += stages.run("coverage", coverage_findings, run, default=[])
    # pose-only views have no corners: their folds are the validation's refits on the tracker's poses
    val = getattr(run, "validation", None)
    refitted = val is not None and bool(val.refits)
    no_folds = bool(s.meta.get("pose_only")) and not refitted
    # the validation's refits ran and its covariance may be the verdict's: their check is shown whatever the fault
    if cross_validation and (refitted or not global_fault) and run.status == "ok" and not no_folds:
        cv = stages.run("cross_validation", cross_validate, run, default=None) or {"summary": "not run: it crashed"}
    else:
        why = (
            str((pose or {}).get("global_reason"))  # every global fault has its words
            if global_fault
            else "no hand-eye result"
            if run.status != "ok"
            else "a pose-only session without the validation's refits (no corners to refit)"
            if no_folds
            else "not asked for"
        )
        stages.skip("cross_validation", why)
        cv = {"summary": "not run: " + why}
    result["cross_validation"] = cv
    if cv.get("verdict") == "spread_exceeds_prediction":
        # info when the verdict covariance (the printed sigmas) already covers the spread: a finding with its size
        covered = bool(cv.get("covered_by_verdict"))
        model = getattr(getattr(run, "refined", None), "robot_model", None) or {}
        beyond = (
            "arm errors beyond its DH offsets and encoder noise (joint elasticity, backlash)"
            if model.get("kind") == "kinematic"
            else "robot pose errors the model does not have (a kinematic robot model when joint angles exist)"
        )
        findings.append(
            Finding(
                "uncertainty_underestimated",
                "info" if covered or cv.get("n_views", 0) < thresholds().views.recommended else "warn",
                "The model covariance is too small: the result varies more between held-out folds "
                "than it predicts" + ("; the verdict uses the validated covariance" if covered else ""),
                cv["summary"] + f" (jackknife over {cv.get('n_folds')} folds: rotation "
                f"{cv.get('ratio_rot')}x, translation {cv.get('ratio_trans')}x the model's sigma)",
                f"look for {beyond}, a moving board or timing problems"
                if covered
                else "use the cross-validation spread as the uncertainty; look for robot pose errors "
                "(estimate robot noise: --robot-noise estimate), a moving board or timing problems",
            )
        )
    result["per_view"] = pose["per_view"] if pose else {}
    decision = getattr(run, "mode_decision", None)
    if decision:
        result["mode"] = decision
        if decision.get("mode_source") == "default":
            findings.append(_mode_undecided(decision))
    refined = getattr(run, "refined", None)
    findings += arm_table_findings(getattr(refined, "robot_model", None))
    findings += unreachable_pose_findings(getattr(refined, "robot_model", None), getattr(refined, "per_view", None))
    result["findings"] = [f.to_dict() for f in worst_first(findings)]
    result.update(stages.to_dict())
    return plain(result, nan_to_none=True)


def _mode_undecided(decision: dict) -> Finding:
    """The finding of a session that states no mode, whose data do not decide it.

    A warning; a failure when the mode calibrated in puts the camera where a camera of that mode cannot be (the
    other mode's rig with inverted poses fits the same motions: the two are one model, told apart only by where
    they put the camera).
    """
    ev = decision.get("evidence", {})
    used = mounting(decision["mode"])
    title = (
        f"The session states no mounting mode and the data do not decide it: calibrated as {used.name} (the default)"
    )
    fix = "state the mode (--mode, or mode: in config.yaml or session.yaml)"
    if ev.get("plausible", {}).get(used.name) is not False:
        return Finding("mode_undecided", "warn", title, ev.get("summary", ""), fix)
    other = used.other
    where = (
        "farther from the flange than the board is from the robot base"
        if used.camera_moves
        else "nearer the robot base than the board is to the flange"
    )
    return Finding(
        "mode_undecided",
        "fail",
        f"{title}, which puts the camera {where}",
        ev.get("summary", "") + f"; an {other.name.replace('_', '-')} rig whose robot poses are inverted (T_end_base) "
        "fits these motions as well",
        f"{fix}; if the camera is {other.camera_location}, write each robot pose as the flange in the base frame "
        "(T_base_end), i.e. invert them",
    )


# ------------------------------------------------------------------------------ failed loads
def _of_one_size(items: list) -> list:
    """The (view id, image path) items whose image has the most common size.

    The (view id, image path) items whose image (read from the file header) has the most common size;
    those whose header cannot be read stay (detection drops them with the reason).
    """
    from collections import Counter

    from ..session import image_sizes

    sizes = image_sizes(items)
    if len(set(sizes.values())) <= 1:
        return items
    common = Counter(sizes.values()).most_common(1)[0][0]
    return [(v, p) for v, p in items if sizes.get(v, common) == common]


def _observe_lenient(sess, observe: Callable[..., Any]) -> tuple[Optional[PoseObservations], Optional[int], int]:
    """Detections, intrinsics and board poses of a leniently read session.

    Detections, intrinsics and board poses of a leniently read session through the pipeline's
    observation stage: (observations | None, n_found, n_images); n_found is None when no reading of the
    pose numbers parses (nothing was detected then).
    """
    from ..initial import board_poses

    target, raw = sess.target, sess.raw
    mode = mounting(sess.mode)
    items = [(v, sess.images_by_id[v]) for v in sorted(sess.images_by_id, key=view_id_key) if v in raw.values]
    items = _of_one_size(items)  # an image of another camera or resolution: the load error names it
    item_ids = [v for v, _ in items]
    # a reading that parses, to order symmetric boards' corners (re-done below with the best reading)
    T_items = None
    for fmt, _ in alternative_formats(raw.fmt):
        T_items = read_poses(raw, fmt, item_ids)
        if T_items is not None:
            break
    if T_items is None:
        return None, None, len(items)
    M_by_id = dict(zip(item_ids, mode.M_from_T_base_end(T_items), strict=False))
    seen = observe(target=target, items=items, intrinsics=sess.intrinsics, M_by_id=M_by_id)
    n_det = len(seen.detections)
    if seen.error is not None or len(seen.board_poses) < thresholds().views.min_fail:
        return None, n_det, len(items)
    ids = sorted(seen.board_poses, key=view_id_key)
    T = np.stack([T_items[item_ids.index(v)] for v in ids])
    obj = target.object_points()

    def observations(poses) -> PoseObservations:
        C = np.stack([poses[v].T_cam_board for v in ids])
        corners = tuple((obj[poses[v].corner_ids], seen.detections[v].image_points) for v in ids)
        return PoseObservations(
            sess.mode,
            tuple(ids),
            C,
            T,
            raw,
            {},
            corners,
            seen.intrinsics,
            target,
            sess.intrinsics is None,
            candidates_of(poses, ids),
        )

    obs = observations(seen.board_poses)
    if len(target.symmetries()) > 1:
        readings = evaluate_readings(obs)
        if readings:
            best = readings[0]
            T_best = read_poses(raw, best.fmt, ids)
            if T_best is not None:
                assert seen.intrinsics is not None, "board poses were solved with them"
                M_best = mode.M_from_T_base_end(inv_T(T_best) if best.invert else T_best)
                poses = board_poses(
                    [seen.detections[v] for v in ids], target, seen.intrinsics, dict(zip(ids, M_best, strict=False))
                )
                obs = observations(poses)
    return obs, n_det, len(items)


def diagnose_session_error(
    path, error, *, observe: Callable[..., Any], mode: Optional[str] = None, images: bool = True
) -> dict:
    """What can be said about a session that failed to load (e.g. poses that look like mm or degrees).

    Reads the session leniently (raw pose values, target, images), observes it through ``observe`` (the
    pipeline's observation stage, :func:`handeye.pipeline.observe`, passed in by the caller above the
    diagnostics), and tests every plausible reading of the raw poses against the images. Returns
    ``{"findings": [...], "readings": [...], "load_error": str, "stages": {...}, ...}``. Never raises for
    bad input; a crashed stage is in ``stages``.
    """
    from ..session.raw import read_session_lenient

    err = str(error)
    stages = Stages()
    base = {
        "version": 2,
        "load_error": err,
        "findings": [],
        "cross_validation": {"summary": "not run: the session did not load"},
    }
    sess = stages.run("lenient_read", read_session_lenient, path, mode=mode)
    if sess is None:
        base["findings"] = [
            Finding(
                "session_unreadable",
                "fail",
                "The session could not be read",
                err,
                "fix what the message names (see docs/session_format.md)",
            ).to_dict()
        ]
        base.update(stages.to_dict())
        return plain(base, nan_to_none=True)
    observed = stages.run("observations", _observe_lenient, sess, observe, default=(None, 0, len(sess.images_by_id)))
    obs, n_det, n_img = observed
    if obs is None and n_det is None:  # the pose numbers parse in no reading: not a detection problem
        base["findings"] = [
            Finding(
                "session_unreadable",
                "fail",
                "The session could not be read: its pose numbers fit no pose format",
                err,
                "write the poses as the format says, or state the format they are in (pose_format: in "
                "session.yaml or a vendor config.yaml, see docs/session_format.md)",
            ).to_dict()
        ]
        base.update(stages.to_dict())
        return plain(base, nan_to_none=True)
    if obs is None and stages.status.get("observations") == "crashed":  # the images were not looked at
        base["findings"] = [
            Finding(
                "session_unreadable",
                "fail",
                "The session could not be read",
                err,
                "fix what the message names (see docs/session_format.md)",
            ).to_dict()
        ]
        base.update(stages.to_dict())
        return plain(base, nan_to_none=True)
    if obs is None:
        few = n_det < thresholds().views.min_fail
        base["findings"] = [
            Finding(
                "target_not_found" if few else "session_unreadable",
                "fail",
                f"The session could not be read, and the board was found in only {n_det} of {n_img} images"
                if few
                else "The session could not be read, and its robot poses could not be compared with the images",
                err,
                "fix what the message names; check the board size (inner corners) in the session",
            ).to_dict()
        ]
        base.update(stages.to_dict())
        return plain(base, nan_to_none=True)
    kind = "vendor" if Path(sess.raw.source).name == "poses.txt" else "native"
    pose = _pose_checks(stages, obs, session_kind=kind)
    findings = [f for f in pose["findings"] if f.code != "too_few_views" or f.severity != "info"]
    if not any(f.code in GLOBAL_FAULT_CODES for f in findings):
        given = next((r for r in pose["readings"] if r["changes"] == "as given"), None)
        if given is not None and given["cost"] < thresholds().readings.good_cost:
            findings.insert(
                0,
                Finding(
                    "poses_fit_as_stated",
                    "info",
                    "The robot poses fit the images as stated",
                    f"read as stated the board scatters by {given['board_scatter_deg']:.3f} deg / "
                    f"{given['board_scatter_mm']:.2f} mm; the load error is about something else",
                    "fix what the load error names",
                ),
            )
    base["findings"] = [f.to_dict() for f in worst_first(findings)]
    base["readings"] = pose["readings"]
    base["n_views"] = {"images": n_img, "board_found": n_det}
    base.update(stages.to_dict())
    return plain(base, nan_to_none=True)
