"""The pose forensics gates: the mounting mode and the image/pose pairing, decided before any solve.

:func:`_mode_gate` decides the mode from the data when the session states none and refuses a stated
mode the data contradict; :func:`_pairing_gate` refuses images and robot poses that are shifted or
shuffled; :func:`shift_poses` applies a known constant shift (``--shift-poses``).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import SessionRefused
from ..records import Session, view_id_key
from .records import Observation

log = logging.getLogger(__name__)


def _stated_source(s: Session) -> str:
    """Stated | flag | default: where the session's mode came from (the loader records it)."""
    return getattr(s, "mode_source", "stated") or "stated"


def _mode_gate(s: Session, obs: Observation, state: dict, progress) -> Session:
    """Decide the mode from the data when the session states none; refuse a stated mode the data contradict.

    Records ``state["mode_decision"]`` = {"mode", "mode_source", "evidence"} and, when the mode was
    detected, a session in that mode (``state["session"]``).
    """
    from ..diagnose.mode import mode_evidence
    from ..diagnose.observations import candidates_of

    source = _stated_source(s)
    ids = [v for v in sorted(obs.board_poses, key=view_id_key)]
    decision: dict[str, Any] = {"mode": s.mode, "mode_source": source}
    state["mode_decision"] = decision
    if len(ids) < 4:
        return s
    C = np.stack([obs.board_poses[v].T_cam_board for v in ids])
    T = np.stack([s.view(v).T_base_end for v in ids])
    ambiguous = bool(getattr(s.target, "pose_ambiguous", False))
    ev = mode_evidence(C, T, C_candidates=candidates_of(obs.board_poses, ids) if ambiguous else None)
    decision["evidence"] = ev.to_dict()
    if source == "default":
        # the diagnostics' mode-swap test on the mode about to be used: a mode they would refuse is never chosen
        chosen, summary = ev.decided or s.mode, ev.summary()
        swap = _swap_test(s, obs, ids, C, T, chosen)
        if swap is not None:
            chosen, why = swap
            summary = f"the mode-swap test: {why}" + (
                f" (the quick test said {ev.decided}: {summary})"
                if ev.decided is not None
                else f" (the quick test: {summary})"
            )
            decision["evidence"].update(decided=chosen, swap_test=why, summary=summary)
        if ev.decided is not None or swap is not None:
            progress(f"mode: {chosen}, detected from the data (the session states none): {summary}")
            decision.update(mode=chosen, mode_source="detected")
            if chosen != s.mode:
                s = replace(s, mode=chosen)
                state["session"] = s
        else:
            log.warning(
                "the session states no mounting mode and the data do not decide it; calibrating as %s "
                "(the default): %s",
                s.mode,
                ev.summary(),
            )
            progress(f"mode: {s.mode} (the default; the data do not decide it: {ev.summary()})")
        return s
    if ev.decided is not None and ev.decided != s.mode:
        stated = "--mode" if source == "flag" else "the session"
        raise SessionRefused(
            f"the data are {ev.decided} but {stated} says {s.mode}: {ev.summary()}",
            expected=f"robot and camera motions that fit {s.mode}",
            received=f"they fit {ev.decided}",
            hint=f"calibrate with --mode {ev.decided} (or set mode: {ev.decided} in config.yaml or session.yaml); "
            f"if the camera really is {s.mode.replace('_', '-')}, the robot poses may be inverted (T_end_base)",
            code="mode_swapped",
        )
    return s


def _swap_test(s: Session, obs: Observation, ids: list, C: np.ndarray, T: np.ndarray, mode: str):
    """(the other mode, why) when the diagnostics' mode-swap finding would fire on a run in ``mode``, else None."""
    from ..diagnose.mode import swapped_mode
    from ..diagnose.observations import PoseObservations, candidates_of
    from ..session.raw import raw_poses_of

    po = PoseObservations(
        mode,
        tuple(ids),
        C,
        T,
        raw_poses_of(s),
        {},
        target=s.target,
        C_candidates=candidates_of(obs.board_poses, ids),
        tracker=bool(s.meta.get("pose_only")),
    )
    return swapped_mode(po)


def _pairing_gate(s: Session, obs: Observation, M_all: dict, state: dict) -> None:
    """Refuse a session whose images and robot poses are shifted or shuffled (no result from wrong pairs).

    The search it made is the run's ``pairing`` (the diagnostics decide on it without searching again).
    """
    from ..diagnose.fits import fit_boards
    from ..diagnose.observations import PoseObservations, candidates_of
    from ..diagnose.pairing import PairingSearch, pairing_findings
    from ..diagnose.thresholds import thresholds
    from ..session.raw import raw_poses_of

    ids = [v.view_id for v in s.views if v.view_id in obs.board_poses]
    if len(ids) < 5:
        return
    C = np.stack([obs.board_poses[v].T_cam_board for v in ids])
    try:
        fit = fit_boards(C, np.stack([M_all[v] for v in ids]))
    except np.linalg.LinAlgError:
        return
    if fit.cost <= thresholds().readings.bad_cost:
        return
    T = np.stack([s.view(v).T_base_end for v in ids])
    po = PoseObservations(
        s.mode, tuple(ids), C, T, raw_poses_of(s), {}, C_candidates=candidates_of(obs.board_poses, ids)
    )
    search = state["pairing"] = PairingSearch(po, po.raw.fmt)
    found = pairing_findings(po, po.raw.fmt, given_cost=fit.cost, search=search)
    if not found:
        return
    f = found[0]
    shift = f.details.get("shift")
    if shift is not None:
        raise SessionRefused(
            f"{f.title}: {f.evidence}",
            expected="each image paired with its own pose line",
            received=f"image k fits the pose written for image k{shift:+d}",
            hint=f"fix the pairing, or apply the shift with --shift-poses {shift} (image k takes the pose written "
            f"for image k{shift:+d})",
            code="pairs_shifted",
        )
    raise SessionRefused(
        f"{f.title}: {f.evidence}",
        expected="each image paired with its own robot pose",
        received="poses that belong to other images",
        hint=f.action,
        code="pairs_shuffled",
    )


def shift_poses(s: Session, shift: int) -> tuple[Session, list]:
    """The session with image k paired with the pose written for image k + ``shift``.

    The session with image k paired with the pose written for image k + ``shift`` (in the order the poses
    are written): (session, views left without a pose).
    """
    from ..conventions import T_from_pose_values
    from ..session.raw import raw_poses_of

    raw = raw_poses_of(s)
    pos = {v: k for k, v in enumerate(raw.order)}
    views, unpaired = [], []
    for v in s.views:
        p = pos.get(v.view_id, -1) + shift
        if v.view_id not in pos or not 0 <= p < len(raw.order):
            unpaired.append(v)
            continue
        T = T_from_pose_values(np.asarray(raw.values[raw.order[p]], float), raw.fmt)
        views.append(replace(v, T_base_end=T, source_line=None))
    meta = dict(s.meta, shift_poses=shift)
    return replace(s, views=tuple(views), meta=meta), unpaired
