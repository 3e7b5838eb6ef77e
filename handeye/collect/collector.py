"""The capture loop: check each capture, keep the good ones, say why the others were rejected.

A capture reads the robot pose, grabs a fresh frame, reads the pose again, and is kept only when
the two reads agree (the arm was still while the frame was taken), the arm reports no error, the
target is detected and the image is sharp around it (thresholds and record: :mod:`.capture`). Kept
captures are written at once by the :class:`~handeye.collect.session_writer.SessionWriter`; a device
fault stops the loop with a one-line HardwareError and leaves everything already saved intact.

Modes: interactive (key ``s`` captures, ``q`` quits; :mod:`.interactive`) and automatic
(:meth:`Collector.run_auto`: probe moves, a first rough hand-eye, then the planned views of
:mod:`handeye.collect.plan`; two planned views in a row that miss the board re-estimate from every
view kept and re-plan the rest).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Any, Callable, Optional

import numpy as np

from ..detect import detect_gray, sharpness
from ..detect.chessboard import order_cue
from ..detect.options import default_options
from ..errors import DetectionError, HardwareError
from ..initial import solve_closed_form
from ..initial.board_poses import candidate_invariants, orientation_labels
from ..mounting import MountingMode, mounting
from ..records import HandEyeEstimate
from ..targets import ChessboardSpec, TargetSpec
from . import plan as planning
from .camera import Camera
from .capture import Capture, CaptureChecks, _gray, detector_orderings, nearest_ordering, pose_orderings
from .interactive import InteractiveMode
from .robot import Robot, poses_agree
from .session_writer import SessionWriter

log = logging.getLogger(__name__)

_DEFAULT_CHECKS = CaptureChecks()  # configs/collect.yaml ``capture:``


def _narrower(config: planning.PlanConfig) -> planning.PlanConfig:
    """``config`` with half its tilts and rolls and distances halfway to the start's."""
    return replace(
        config,
        tilt_deg=tuple(sorted({0.5 * float(t) for t in config.tilt_deg})),
        roll_deg=tuple(sorted({0.5 * float(r) for r in config.roll_deg})),
        distance_scales=tuple(sorted({1.0 + 0.5 * (float(d) - 1.0) for d in config.distance_scales})),
    )


def _T_base_end(c: Capture) -> np.ndarray:
    """The robot pose of a kept capture."""
    assert c.pose is not None, "a kept capture has its robot pose"
    return c.pose.T_base_end


def _T_cam_board(c: Capture) -> np.ndarray:
    """The board pose of a capture that has one (a kept capture, with the camera's intrinsics)."""
    assert c.T_cam_board is not None, "only captures with a board pose get here"
    return c.T_cam_board


def _orderings(c: Capture) -> np.ndarray:
    """The board poses (k, 4, 4) of a capture with a board pose, under each detector ordering."""
    assert c.T_cam_board_orderings is not None, "a capture with a board pose has its orderings"
    return c.T_cam_board_orderings


class Collector(InteractiveMode):
    """Captures views from ``robot`` and ``camera`` into ``writer``."""

    def __init__(
        self,
        *,
        robot: Robot,
        camera: Camera,
        writer: SessionWriter,
        target: TargetSpec,
        mode: str,
        checks: CaptureChecks = _DEFAULT_CHECKS,
        truth: Optional[Callable[[str], None]] = None,
    ):
        self.robot = robot
        self.camera = camera
        self.writer = writer
        self.target = target
        self.mode = mode
        self.checks = checks
        self.intrinsics = camera.intrinsics()
        self._on_kept_truth = truth  # simulated backends: record the true pose of a kept view
        self.kept: list[Capture] = []
        self.rejected: list[Capture] = []
        self.history: list[Capture] = []  # every capture in the order taken, kept or not
        self._next_id = 1
        self._cue_min_grey = default_options().order_cue_min_grey

    # -- one capture ---------------------------------------------------------------------------
    def capture(self, *, reference_T_cam_board: Optional[np.ndarray] = None) -> Capture:
        """Take one capture; keep and write it if every check passes."""
        c = self.checks
        first = self.robot.read_pose()
        image, t_image = self.camera.grab()
        second = self.robot.read_pose()
        still, rot_deg, trans_mm = poses_agree(
            first.T_base_end, second.T_base_end, tol_mm=c.still_tol_mm, tol_deg=c.still_tol_deg
        )
        if not still:
            return self._reject(
                f"the arm moved while the frame was taken ({trans_mm:.2f} mm, {rot_deg:.3f} deg "
                f"between the pose reads; tolerance {c.still_tol_mm} mm, {c.still_tol_deg} deg)"
            )
        errors = first.errors or second.errors
        if errors:
            from .realman import describe_error_codes

            return self._reject(f"the arm reports {describe_error_codes(errors)}")
        gray = _gray(image)
        found = detect_gray(gray, self.target)
        if isinstance(found, str):
            return self._reject(f"target not detected: {found}")
        ids, pts = found
        sharp = sharpness(gray, pts)
        if not sharp >= c.min_sharpness:
            return self._reject(
                f"image not sharp (variance of the Laplacian {sharp:.1f} < {c.min_sharpness:g}); "
                "check focus, lighting and that nothing moves"
            )
        cue = float("nan")
        if isinstance(self.target, ChessboardSpec):
            cue = order_cue(gray, pts, self.target.cols, self.target.rows, ids)
        T_cb = orderings = None
        orientation = 0
        if self.intrinsics is not None:
            orderings = pose_orderings(self.target, self.intrinsics, ids, pts)
            by_colour = self._ordering_by_colour(cue, self._colour_sign(self.kept))
            if by_colour is None:
                by_colour = 0 if reference_T_cam_board is None else nearest_ordering(orderings, reference_T_cam_board)
            orientation = by_colour
            T_cb = orderings[orientation]
        vid = str(self._next_id)
        state = dict(first.state)
        extra: dict[str, Any] = {
            "checks": {
                "pose_reads_dt_s": round(second.t_pose - first.t_pose, 4),
                "pose_reads_diff_mm": round(trans_mm, 4),
                "pose_reads_diff_deg": round(rot_deg, 5),
                "sharpness": round(float(sharp), 2),
                "n_corners": int(len(ids)),
            }
        }
        if self.camera.last_frame_info:
            extra["camera_frame"] = dict(self.camera.last_frame_info)
        if first.joints is not None:
            extra["joints"] = [float(v) for v in first.joints]  # radians, the encoder readings with this pose
        self.writer.write_view(
            vid, image, first.T_base_end, t_image=t_image, t_pose=first.t_pose, robot_state=state, extra=extra
        )
        self._next_id += 1
        cap = Capture(True, "", vid, first, ids, pts, float(sharp), T_cb, cue, orderings, orientation)
        self.kept.append(cap)
        self.history.append(cap)
        if self._on_kept_truth is not None:
            self._on_kept_truth(vid)
        log.info("view %s kept: %d corners, sharpness %.0f", vid, len(ids), sharp)
        return cap

    # -- corner orderings -----------------------------------------------------------------------
    def _colour_sign(self, caps: list[Capture]) -> Optional[float]:
        """The sign of the colour cue most of ``caps`` show (an asymmetric chessboard), None when none shows one.

        A tie keeps the first view's sign. The numbering most views have is the one kept, as
        :func:`handeye.detect.chessboard.normalize_chessboard_order` does for a whole session.
        """
        t = self.target
        if not (isinstance(t, ChessboardSpec) and (t.cols + t.rows) % 2 == 1):
            return None
        signs = [float(np.sign(c.order_cue)) for c in caps if abs(c.order_cue) > self._cue_min_grey]
        if not signs:
            return None
        total = sum(signs)
        return signs[0] if total == 0 else float(np.sign(total))

    def _ordering_by_colour(self, cue: float, sign: Optional[float]) -> Optional[int]:
        """0 (as detected) or 1 (numbered from the other end) when the colours tell, else None."""
        if sign is None or not abs(cue) > self._cue_min_grey:
            return None
        return 0 if np.sign(cue) == sign else 1

    def _reoriented(self, caps: list[Capture]) -> list[Capture]:
        """``caps`` (with board poses) under one consistent corner ordering.

        The colours decide where they tell, then the robot's motion (camera motions whose rotation
        angle and screw pitch match the robot's).
        """
        k = len(detector_orderings(self.target))
        sign = self._colour_sign(caps)
        fixed = [self._ordering_by_colour(c.order_cue, sign) for c in caps]
        labels = [c.orientation if f is None else f for c, f in zip(caps, fixed, strict=True)]
        free = [i for i, f in enumerate(fixed) if f is None]
        if k > 1 and free and len(caps) >= 3:
            Cs = np.stack(
                [
                    _orderings(c) if f is None else np.repeat(_orderings(c)[f][None], k, axis=0)
                    for c, f in zip(caps, fixed, strict=True)
                ]
            )  # shape (n, k, 4, 4): a view the colours decided has its one pose k times
            Ms = mounting(self.mode).M_from_T_base_end(np.stack([_T_base_end(c) for c in caps]))
            # all free: the detector's own order for the majority; else the frame of the decided views
            lab = orientation_labels(candidate_invariants(Cs), Ms, turns=len(free) == len(caps))
            labels = [int(lab[i]) if fixed[i] is None else labels[i] for i in range(len(caps))]
        out = []
        for c, a in zip(caps, labels, strict=True):
            if a != c.orientation:
                log.info("view %s: corner order taken from the other end of the board (ordering %d)", c.view_id, a)
            out.append(replace(c, orientation=a, T_cam_board=_orderings(c)[a]))
        return out

    def _estimate(self, mount: MountingMode) -> tuple[list[Capture], Optional[HandEyeEstimate]]:
        """Every kept view with a board pose and the closed-form hand-eye from them (None: fewer than 3).

        The views are re-oriented consistently first (and so replaced in ``kept``).
        """
        idx = [i for i, c in enumerate(self.kept) if c.T_cam_board is not None]
        views = self._reoriented([self.kept[i] for i in idx])
        for i, c in zip(idx, views, strict=True):
            self.kept[i] = c
        if len(views) < 3:
            return views, None
        M = mount.M_from_T_base_end(np.stack([_T_base_end(c) for c in views]))
        C = np.stack([_T_cam_board(c) for c in views])
        return views, solve_closed_form(mount, C, M, method="park")

    def _reject(self, reason: str) -> Capture:
        cap = Capture(False, reason)
        self.rejected.append(cap)
        self.history.append(cap)
        log.warning("capture rejected: %s", reason)
        return cap

    def wait_still(self) -> bool:
        """After a motion: wait until two pose reads agree (or the settle timeout passes)."""
        c = self.checks
        t_end = time.monotonic() + c.settle_timeout_s
        while True:
            if self.robot.is_still(
                interval_s=c.settle_interval_s if self.robot.is_real else 0.0,
                tol_mm=c.still_tol_mm,
                tol_deg=c.still_tol_deg,
            ):
                return True
            if time.monotonic() > t_end:
                return False

    # -- automatic -----------------------------------------------------------------------------
    def run_auto(
        self,
        *,
        n_views: int,
        speed_fraction: float,
        plan_config: Optional[planning.PlanConfig] = None,
        confirm: Callable[[str], bool] = lambda text: True,
        probe_deg: float = 6.0,
    ) -> Optional[planning.Plan]:
        """Probe, plan and capture ``n_views`` planned views (plus the start and probe views).

        Returns the last plan (None when ``n_views`` asks for none).
        """
        plan_config = planning.PlanConfig() if plan_config is None else plan_config
        if self.intrinsics is None:
            raise HardwareError(
                "automatic mode needs the camera's intrinsics to plan, and this camera has none",
                hint="use interactive mode, or a camera that reports factory intrinsics",
            )
        mount = mounting(self.mode)
        start = self.capture()
        if not start.kept:
            raise DetectionError(
                f"automatic mode starts from a view of the board, and the first capture failed: {start.reason}",
                hint="move the arm so the camera sees the whole board, roughly face on, then start again",
            )
        assert start.pose is not None and start.T_cam_board is not None, "a kept capture has both"
        T0, C0 = start.pose.T_base_end, start.T_cam_board
        probes = planning.probe_poses(T0, probe_deg=probe_deg)
        if self.robot.is_real and not confirm(
            f"The arm will make {len(probes)} small probe moves ({probe_deg:g} deg about the end's own x, y and "
            "z axes; other directions or half the angle where the board leaves the image) at "
            f"{100 * speed_fraction:.0f}% speed. Continue?"
        ):
            log.warning("stopped before moving the arm")
            return planning.Plan((), float("nan"), float("nan"), np.zeros(3), "cancelled", "not confirmed")
        for axis, tries in zip("xyz", probes, strict=False):
            for T in tries:
                self.robot.move_to(T, speed_fraction=speed_fraction)
                cap = self._capture_after_move(reference=C0)
                if cap.kept or not cap.reason.startswith("target not detected"):
                    break
                log.info("the probe about the end's %s axis lost the board; trying another direction or angle", axis)
        views, rough = self._estimate(mount)
        if rough is None:
            raise DetectionError(
                f"only {len(views)} of the start and probe views show the board; a first hand-eye estimate needs 3",
                hint="start from a pose where the board is in the middle of the image, or lower --probe-deg",
            )
        if rough.status != "ok":
            raise DetectionError(
                f"the first hand-eye estimate failed ({rough.failure_reason})",
                hint="check the board size given with --target",
            )
        C0 = _T_cam_board(views[0])  # the start view, in the ordering consistent with the others
        log.info(
            "first estimate from %d views; planning %d views (predicted 1-sigma of %s, total over 3 axes):",
            len(views),
            n_views,
            mount.x_name,
        )

        def on_step(pv: planning.PlannedView) -> None:
            log.info(
                "  plan %2d: sigma %.3f deg, %.2f mm  (%s)",
                pv.index,
                pv.sigma_rot_deg,
                pv.sigma_trans_mm,
                pv.candidate.label,
            )

        captured, replans, plan, narrowed = 0, 0, None, False
        while captured < n_views:
            plan = planning.make_plan(
                mode=self.mode,
                T_x=rough.T_x,
                T_board=rough.T_board,
                T_base_end_start=T0,
                T_cam_board_start=C0,
                T_base_end_done=[_T_base_end(c) for c in views],
                target=self.target,
                intrinsics=self.intrinsics,
                n_views=n_views - captured,
                config=plan_config,
                pose_ok=getattr(self.robot, "pose_ok", None),
                on_step=on_step,
            )
            if plan.status != "ok":
                log.warning("plan: %s", plan.failure_reason)
            if not plan.views:
                return plan
            travel = max(np.linalg.norm(pv.candidate.T_base_end[:3, 3] - T0[:3, 3]) for pv in plan.views)
            turn = max(np.linalg.norm(pv.candidate.end_rotvec_deg) for pv in plan.views)
            if self.robot.is_real and not confirm(
                f"The plan moves the arm to {len(plan.views)} poses up to {1000 * travel:.0f} mm and {turn:.0f} deg "
                f"from the start pose, at {100 * speed_fraction:.0f}% speed. Continue?"
            ):
                log.warning("stopped before the planned moves")
                return plan
            n_kept, missed = self._run_plan(plan, rough=rough, speed_fraction=speed_fraction, plan_config=plan_config)
            captured += n_kept
            if captured >= n_views:
                break
            if replans == self.MAX_REPLANS:
                log.warning("%d of the %d planned views kept after %d re-plans; stopping", captured, n_views, replans)
                break
            replans += 1
            views, new = self._estimate(mount)
            if new is None or new.status != "ok":
                log.warning(
                    "the new estimate failed (%s); stopping with %d planned views",
                    "too few views" if new is None else new.failure_reason,
                    captured,
                )
                break
            same = np.allclose(new.T_x, rough.T_x, rtol=0.0, atol=1e-9)  # the same views gave the same estimate
            if same and narrowed:
                log.warning(
                    "planned poses miss the board and the estimate does not change; stopping with %d of %d "
                    "planned views (start again from a view nearer the board's centre)",
                    captured,
                    n_views,
                )
                break
            if same:  # stay nearer the views that worked, once
                plan_config, narrowed = _narrower(plan_config), True
                log.info("the estimate did not change: the new plan turns half as far")
            rough, C0 = new, _T_cam_board(views[0])
            cause = (
                f"{missed} planned poses in a row missed the board"
                if missed >= self.MISSES_BEFORE_REPLAN
                else "the plan ended with views rejected"
            )
            log.warning("%s: re-estimated from %d views, planning the %d left", cause, len(views), n_views - captured)
        return plan

    #: planned poses in a row that miss the board before the estimate is redone and the rest re-planned
    MISSES_BEFORE_REPLAN = 2
    #: re-plans after which a plan that keeps missing stops the automatic collection
    MAX_REPLANS = 3

    def _run_plan(
        self, plan: planning.Plan, *, rough: HandEyeEstimate, speed_fraction: float, plan_config: planning.PlanConfig
    ) -> tuple[int, int]:
        """Move to and capture the planned views until ``MISSES_BEFORE_REPLAN`` in a row miss the board.

        Returns (views kept, misses in a row at the end).
        """
        done = [_T_base_end(c) for c in self.kept if c.T_cam_board is not None]
        assert self.intrinsics is not None, "run_auto plans only with the camera's intrinsics"
        n_kept = missed = 0
        for pv in plan.views:
            self.robot.move_to(pv.candidate.T_base_end, speed_fraction=speed_fraction)
            cap = self._capture_after_move(reference=pv.candidate.T_cam_board)
            if not cap.kept:
                log.warning("planned view %d/%d skipped: %s", pv.index, len(plan.views), cap.reason)
                missed = missed + 1 if cap.reason.startswith("target not detected") else 0
                if missed >= self.MISSES_BEFORE_REPLAN:
                    return n_kept, missed
                continue
            n_kept, missed = n_kept + 1, 0
            done.append(_T_base_end(cap))
            info = planning.information_of_views(
                mode=self.mode,
                T_x=rough.T_x,
                T_board=rough.T_board,
                T_base_end=done,
                target=self.target,
                intrinsics=self.intrinsics,
                config=plan_config,
            )
            sr, st = planning.predicted_sigma(info)
            log.info(
                "planned view %d/%d captured as view %s: predicted sigma %.3f deg, %.2f mm",
                pv.index,
                len(plan.views),
                cap.view_id,
                sr,
                st,
            )
        return n_kept, missed

    def capture_at(
        self, T_base_end: np.ndarray, *, speed_fraction: float, reference: Optional[np.ndarray] = None
    ) -> Capture:
        """Move to ``T_base_end``, wait until the arm is still and capture (a planned view)."""
        self.robot.move_to(T_base_end, speed_fraction=speed_fraction)
        return self._capture_after_move(reference=reference)

    def _capture_after_move(self, *, reference: Optional[np.ndarray]) -> Capture:
        cap = None
        for _attempt in range(2):
            if not self.wait_still():
                cap = self._reject("the arm did not settle after the motion")
                continue
            cap = self.capture(reference_T_cam_board=reference)
            if cap.kept or "moved while" not in cap.reason:
                return cap
        assert cap is not None, "two attempts made"
        return cap
