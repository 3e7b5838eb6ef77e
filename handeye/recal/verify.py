"""Verify an installed calibration with a short session, without re-solving it (``handeye verify``).

:func:`verify_session` reads the session in the installed result's mode and board, detects the target
and tests the installed calibration on the new views (:func:`handeye.recal.verification.verify_views`);
:func:`verify_dict` is verify.json. The test itself is in :mod:`handeye.recal.drift` and
:mod:`handeye.recal.joint`; their names are importable from here too.

See docs/recalibrate.md.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from ..errors import InputError
from ..mounting import mounting
from ..output import plain
from ..session.target_spec import is_tracked, target_words
from .drift import JOINT_DH_KIND, JOINT_KIND, DriftTest, change_in_result_frame, drift_test, joint_drift_test
from .joint import installed_robot_model, shares_dh, test_refined, with_installed_dh
from .loaded import LoadedResult, require_matrix
from .verification import (
    Verification,
    VerifyOptions,
    board_from_views,
    nearest_board_turn,
    verify_views,
    what_moved,
)

__all__ = [
    "JOINT_DH_KIND",
    "JOINT_KIND",
    "DriftTest",
    "SessionVerification",
    "Verification",
    "VerifyOptions",
    "board_from_views",
    "change_in_result_frame",
    "check_resolution",
    "drift_test",
    "installed_images_among",
    "installed_robot_model",
    "joint_drift_test",
    "nearest_board_turn",
    "session_for_installed",
    "shares_dh",
    "test_refined",
    "verify_dict",
    "verify_session",
    "verify_views",
    "what_moved",
    "with_installed_dh",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SessionVerification:
    """:func:`verify_session`'s outcome: the verification and what the session gave it."""

    verification: Verification
    session_path: str
    installed_source: str
    outcomes: tuple  # ViewOutcome per view of the session (detected or why not)
    target_text: str
    image_size: tuple
    intrinsics_source: str
    seconds: dict


def session_for_installed(session_path, installed: LoadedResult, *, mode: Optional[str] = None):
    """The session, read in the installed result's mounting mode.

    Refuses a session of another mode or board (one line naming the difference), and a pose-only session whatever
    its target (it has no images to refine X on).
    """
    from ..session import load_session

    s = load_session(session_path, mode=mode)
    if s.mode_source == "default" and mode is None:  # the session does not say: the installed mode
        from dataclasses import replace

        s = replace(s, mode=installed.mode, mode_source="flag")
    if s.mode != installed.mode:
        said = f"--mode {mode} was given" if mode is not None else f"the session is {s.mode}"
        raise InputError(
            f"{said} but the installed calibration is {installed.mode}",
            path=s.path,
            code="not_comparable",
            hint="verify against a result of this rig's mounting mode"
            + ("" if mode is None else f", or drop --mode (the installed {installed.mode} is used)"),
        )
    if s.meta.get("pose_only"):  # the test refines X on the detected corners of new images
        raise InputError(
            "a pose-only session (views with target_pose) cannot be verified: the check refines X on new images",
            path=s.path,
            hint="calibrate the new session and compare: handeye calibrate SESSION --out NEW, then handeye compare "
            "INSTALLED NEW",
        )
    if installed.target is not None and s.target.to_dict() != installed.target:
        tracked = is_tracked(installed.target)
        raise InputError(
            f"the session's board ({s.target.describe()}) is not the installed calibration's",
            path=s.path,
            expected=f"the installed calibration's: {target_words(installed.target)}",
            code="not_comparable",
            hint="the installed calibration came from a tracker's poses; verify needs one calibrated from images "
            "of this board (calibrate this session for one)"
            if tracked
            else "verify with the board the rig was calibrated with",
        )
    return s


def installed_images_among(installed: LoadedResult, session) -> int:
    """How many of the session's images are files the installed calibration read.

    How many of the session's images are files the installed calibration read, when its robot poses are too (by
    their SHA-256 in the installed result's provenance): the installed session itself, not a new one. (Rendered
    sessions of one scene can share images while their poses differ.)
    """
    from ..output import file_sha256

    known = {
        str(i.get("sha256")) for i in (installed.raw.get("provenance") or {}).get("inputs") or [] if isinstance(i, dict)
    }
    if not known:
        return 0
    images = {Path(v.image_path) for v in session.views if v.image_path is not None}
    folder = Path(session.path)
    others = [
        Path(f)
        for f in session.meta.get("files_read") or [folder / "poses.txt", folder / "session.yaml"]
        if Path(f).name != "config.yaml"
    ]  # the board's description is the same for every session of a rig
    if not any(f.is_file() and f not in images and file_sha256(f) in known for f in others):
        return 0
    return sum(1 for p in images if p.is_file() and file_sha256(p) in known)


def check_resolution(installed: LoadedResult, session) -> None:
    """The session's images (read from their headers) must have the installed calibration's resolution.

    Its intrinsics describe that image; else a one-line InputError (``not_comparable``).
    """
    from ..session import image_sizes

    size = next(iter(image_sizes(session).values()), None)
    if size and installed.image_size and tuple(size) != tuple(installed.image_size):
        raise InputError(
            f"the session's images are {size[0]}x{size[1]} but the installed calibration's are "
            f"{installed.image_size[0]}x{installed.image_size[1]}",
            path=session.path,
            code="not_comparable",
            hint="capture at the calibrated resolution (the installed intrinsics describe that image)",
        )


def verify_session(
    session_path,
    against,
    *,
    options: VerifyOptions = VerifyOptions(),  # noqa: B008 - a frozen dataclass, imported
    mode: Optional[str] = None,
    progress=None,
) -> SessionVerification:
    """Detect the target in a short session and test the installed calibration ``against``.

    Detect the target in a short session (:func:`handeye.pipeline.observe`) and test the installed
    calibration ``against`` (a result folder, result.json or loaded dict) on it (:func:`verify_views`).
    """
    from ..diagnose.consistency import board_turns
    from ..pipeline import CalibrateOptions, missing_image_outcomes, observe, target_text
    from ..pipeline.records import ordered_outcomes
    from ..refine import RefineView
    from .loaded import load_result

    t0 = time.perf_counter()
    installed = against if isinstance(against, LoadedResult) else load_result(against)
    require_matrix(installed)
    s = session_for_installed(session_path, installed, mode=mode)
    check_resolution(installed, s)
    reused = installed_images_among(installed, s)
    if reused:
        log.warning(
            "%s: %d of %d images are the installed calibration's own (the same files): verify tests new views "
            "against the installed calibration, and its own views cannot show a drift",
            s.path,
            reused,
            len(s.views),
        )
    m = mounting(s.mode)
    own = s.intrinsics if (s.intrinsics is not None and s.intrinsics_prior in ("fixed", "prior")) else None
    intr = own if own is not None else installed.intrinsics
    M_all = {v.view_id: m.M_from_T_base_end(v.T_base_end) for v in s.views}
    obs = observe(
        target=s.target,
        items=[(v.view_id, v.image_path) for v in s.views],
        intrinsics=intr,
        intrinsics_prior="fixed",
        M_by_id=M_all,
        options=CalibrateOptions(),
        intrinsics_source="session" if own is not None else "installed",
        progress=progress,
    )
    if obs.error is not None:
        raise obs.error if obs.error.path is not None else obs.error.at(s.path)
    size = next(iter(obs.detections.values())).image_size
    t1 = time.perf_counter()
    views = [
        RefineView(
            vid, bp.corner_ids, obs.detections[vid].image_points, s.view(vid).T_base_end, s.view(vid).joint_angles
        )
        for vid, bp in obs.board_poses.items()
    ]
    v = verify_views(
        installed,
        views=views,
        object_points=s.target.object_points(),
        intrinsics=own,
        options=options,
        board_turns=[F for _, F in board_turns(s.target)],
    )
    seconds = dict(obs.seconds, verify=time.perf_counter() - t1, total=time.perf_counter() - t0)
    return SessionVerification(
        verification=v,
        session_path=str(s.path),
        installed_source=installed.label,
        outcomes=ordered_outcomes({**obs.outcomes, **missing_image_outcomes(s)}),
        target_text=target_text(s.target),
        image_size=tuple(size),
        intrinsics_source=obs.intrinsics_source,
        seconds=seconds,
    )


def verify_dict(sv: SessionVerification) -> dict:
    """verify.json: the verification with its inputs and provenance."""
    from ..output import provenance, recorded_path

    d = sv.verification.to_dict()
    d = {
        "handeye_verify": 1,
        **d,
        "session": {
            "path": recorded_path(sv.session_path),
            "target": sv.target_text,
            "image_size": list(sv.image_size),
            "intrinsics": sv.intrinsics_source,
        },
        "against": sv.installed_source,
        "view_outcomes": [
            {"id": o.view_id, "image": o.image, "detected": o.used, "reason": o.reason, "n_corners": o.n_corners}
            for o in sv.outcomes
        ],
        "seconds_by_stage": sv.seconds,
        "provenance": provenance(),
    }
    return plain(d, nan_to_none=True)
