"""Capture a verification session with the collector (``handeye collect --verify-against RESULT --auto``).

From a first view of the board, the installed X places the board (``B = M^-1 X C``, so a board that
moved since the calibration is no obstacle), the collector's planner proposes orbit views around that
view (:func:`handeye.collect.plan.candidate_views`), and :func:`handeye.recal.plan.plan_verification`
picks the ones that detect the configured drift with the most power, stopping at the goal.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Callable

from ..errors import DetectionError
from .loaded import LoadedResult
from .plan import VerifyPlan, plan_lines, plan_verification
from .verify import board_from_views

log = logging.getLogger(__name__)


def capture_verification(
    collector,
    installed: LoadedResult,
    *,
    n_views: int,
    speed_fraction: float,
    confirm: Callable[[str], bool] = lambda text: True,
    plan_config=None,
) -> VerifyPlan:
    """Capture a start view, plan up to ``n_views`` more for the verification and capture them."""
    from ..collect.plan import PlanConfig, candidate_views

    start = collector.capture()
    if not start.kept or start.T_cam_board is None:
        raise DetectionError(
            f"a verification starts from a view of the board, and the first capture failed: "
            f"{start.reason or 'no board pose'}",
            hint="move the arm so the camera sees the whole board, then start again",
        )
    T0, C0 = start.pose.T_base_end, start.T_cam_board
    assert installed.T_x is not None, "the caller verifies against an ok result"
    board_now = board_from_views(installed.mode, installed.T_x, T0[None], C0[None])[0]
    config = plan_config or PlanConfig()
    cands = candidate_views(
        mode=installed.mode,
        T_x=installed.T_x,
        T_board=board_now,
        T_base_end_start=T0,
        T_cam_board_start=C0,
        target=collector.target,
        intrinsics=collector.intrinsics,
        config=config,
        pose_ok=getattr(collector.robot, "pose_ok", None),
    )
    if not cands:
        raise DetectionError(
            "no feasible verification views around the start pose",
            hint="start from a pose with the board in the middle of the image",
        )
    plan = plan_verification(
        replace(installed, T_board=board_now), candidates=[c.T_base_end for c in cands], max_views=max(int(n_views), 3)
    )
    for line in plan_lines(plan):
        log.info("%s", line)
    if collector.robot.is_real and not confirm(
        f"The verification moves the arm to {len(plan.poses)} poses around the start pose at "
        f"{100 * speed_fraction:.0f}% speed. Continue?"
    ):
        log.warning("stopped before the planned moves")
        return plan
    for k, (T, i) in enumerate(zip(plan.poses, plan.candidate_index, strict=False)):
        cap = collector.capture_at(T, speed_fraction=speed_fraction, reference=cands[i].T_cam_board)
        log.info(
            "verification view %d/%d: %s",
            k + 1,
            len(plan.poses),
            f"captured as view {cap.view_id}" if cap.kept else f"skipped ({cap.reason})",
        )
    return plan
