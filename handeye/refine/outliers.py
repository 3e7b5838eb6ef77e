"""Outlier decisions of the refinement: decide, exclude, re-solve and decide again (no GTSAM here).

Each round checks every view against the current solution (:mod:`.checks`), tests each reported
robot pose (:func:`.robot_pose.robot_pose_test`) and drops corners, views or robot priors that
disagree, each as an :class:`~.robot_pose.Outlier` with its reason. The robot-pose test and the
outlier record live in :mod:`.robot_pose`; their names are importable from here too.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np

from .checks import ViewCheck, _factor, _failed_check, camera_only_poses, joint_checks, view_variance_factor
from .noise import robust_robot_sigmas, solve_with_vce
from .options import refine_preset
from .robot_pose import (
    Outlier,
    RobotPoseGates,
    RobotPoseTest,
    leave_one_out,
    prior_share,
    robot_pose_outlier,
    robot_pose_test,
)

if TYPE_CHECKING:
    from .problem import Problem

__all__ = [
    "Decision",
    "Outlier",
    "RobotPoseGates",
    "RobotPoseTest",
    "TooFewRobotPoses",
    "ViewCheck",
    "apply_decision",
    "camera_only_poses",
    "decide",
    "leave_one_out",
    "outlier_loop",
    "prior_share",
    "robot_pose_outlier",
    "robot_pose_test",
    "robot_tests",
    "view_variance_factor",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Decision:
    status: tuple[str, ...]  # per view: used | robot_excluded | removed
    masks: tuple[Any, ...]  # per view: bool array of the corners kept
    outliers: tuple[Any, ...]  # Outlier, ...
    checks: tuple[Any, ...]  # per view ViewCheck
    robot_test: RobotPoseTest  # the robot-pose test of every view

    def key(self) -> tuple[tuple[str, ...], tuple[bytes, ...]]:
        return self.status, tuple(m.tobytes() for m in self.masks)


def _robot_test_cov(pb: "Problem") -> np.ndarray:
    """(n,6,6) each view's robot noise covariance for the test.

    The model's, or for robot_noise "none" the configured iid tolerance.
    """
    if pb.robot_var:
        return pb.robot_cov(range(pb.n))
    R = np.diag([np.radians(pb.o.robot_sigma_deg) ** 2] * 3 + [(pb.o.robot_sigma_mm / 1000.0) ** 2] * 3)
    return np.broadcast_to(R, (pb.n, 6, 6)).copy()


def robot_tests(pb: "Problem", checks: Sequence[ViewCheck], S_pp: Optional[dict[int, np.ndarray]]) -> RobotPoseTest:
    """:func:`robot_pose_test` of every view's reported robot pose against what the other data imply.

    Each view's robot noise covariance R_i is its model's (:meth:`.problem.Problem.robot_cov`). With
    the covariances of a Gaussian solve (``S_pp``: the covariance of each robot-pose variable's prior
    residual, which for the kinematic model includes the DH offsets' share): for a view whose prior is in
    the solve, the leave-one-out prediction from the prior
    residual (:func:`leave_one_out`, Baarda's data snooping); for a view whose prior was excluded,
    its free pose ``P`` with covariance ``S_P``. Otherwise (robust phase, views not in the solve, or a
    view whose prior carries almost all the information about its pose, :func:`prior_share` below
    ``outliers.robot_pose.loo_min_camera_share``) the camera-only pose with its own covariance, which
    ignores the uncertainty of ``T_x``, ``T_board`` and the intrinsics (a share of about 1 / n views).
    Each view's camera-side covariance is scaled by its own corner variance
    (:func:`view_variance_factor`). Under the kinematic model the camera-only comparison is made with
    the current DH offsets taken off the disagreement and their covariance added to the camera's.
    """
    R_all = _robot_test_cov(pb)
    loo_min = float(refine_preset()["outliers"]["robot_pose"]["loo_min_camera_share"])
    d = np.full((pb.n, 6), np.nan)
    C = np.full((pb.n, 6, 6), np.nan)
    e_all = pb.prior_residuals(range(pb.n))  # shape (n, 6): prior residuals
    J_all = pb.J_dh(range(pb.n))  # shape (n, 6, m)
    dh_cov = np.einsum("nim,mk,njk->nij", J_all, pb.S_dd, J_all)  # the DH offsets' share of each pose

    def camera_side(i: int, ch: ViewCheck) -> tuple[np.ndarray, np.ndarray]:
        return ch.delta - J_all[i] @ pb.dh, ch.cov_cam * ch.variance_factor + dh_cov[i]

    own: list[int] = []  # views compared with their own fit
    for i, ch in enumerate(checks):
        Sp = None if S_pp is None else S_pp.get(i)
        f = ch.variance_factor  # the view's own corner variance (camera side only; see view_variance_factor)
        R = R_all[i]
        if Sp is not None and pb.status[i] in ("used", "robot_excluded") and pb.has_robot_var(i):
            e = e_all[i]
            try:
                if pb.status[i] == "used" and prior_share(R, Sp) < loo_min:
                    raise np.linalg.LinAlgError("the prior dominates: no reliable leave-one-out prediction")
                if pb.status[i] == "used":
                    d[i], C[i] = leave_one_out(e, R, Sp)
                else:
                    d[i], C[i] = e, Sp
                C[i] *= f
                continue
            except np.linalg.LinAlgError:  # fall back to the camera-only comparison
                own.append(i)
                continue
        if ch.ok:
            d[i], C[i] = camera_side(i, ch)
    for i, ch in camera_only_poses(pb, own).items() if own else ():  # all fall-backs in one batch
        if ch.ok:
            d[i], C[i] = camera_side(i, ch)
    return robot_pose_test(
        d, C, robot_covariance=R_all, gates=RobotPoseGates.from_options(pb.o, unmodelled_arm=pb.kind != "kinematic")
    )


def decide(pb: "Problem", *, robust_robot_sigma: bool, S_pp: Optional[dict[int, np.ndarray]] = None) -> Decision:
    """Outlier decisions for every view against the current solution.

    Outlier decisions for every view against the current solution, each with a reason and the size
    of the disagreement:

    * corners further than ``corner_outlier_sigmas`` from their prediction are flagged
      (``corners``): against the last Gaussian solve for views in it, otherwise against the pose
      that the view's corners alone imply (robust Gauss-Newton with ``T_x``, ``T_board`` and the
      intrinsics held);
    * a view keeping fewer than ``min_corners`` corners is dropped (``too_few_corners``); a view
      with more than ``outliers.reprojection_share`` of its corners flagged is dropped
      (``reprojection``);
    * the reported robot pose is tested by :func:`robot_tests`; a disagreeing view loses its robot
      prior (``robot_pose``) but keeps its corners, which still inform the intrinsics.

    ``robust_robot_sigma``: first set the robot sigmas from the camera-only poses by the robust
    (median) estimator, for decisions made before the data are clean. ``S_pp``: robot-pose
    covariances of the last Gaussian solve, for the exact robot-pose tests.
    """
    o = pb.o
    t_corner = o.corner_outlier_sigmas
    share = float(refine_preset()["outliers"]["reprojection_share"])
    # views outside the last Gaussian solve: their own fit; views in it: the variance factor of their
    # camera side from their own fit (measured without the robot pose; its residual variance hardly
    # moves between rounds, so a view's first own fit serves, divided by the current sigma_px^2)
    by_view = joint_checks(pb, S_pp) if S_pp is not None else {}
    need = [i for i in range(pb.n) if len(pb.obj[i]) >= o.min_corners and (i not in by_view or i not in pb.own_fit_var)]
    own = camera_only_poses(pb, need)
    by_view = {
        i: replace(ch, variance_factor=_factor(pb.own_fit_var.get(i, np.nan), pb.sigma_px)) for i, ch in by_view.items()
    }
    by_view.update({i: ch for i, ch in own.items() if i not in by_view})
    checks = [by_view.get(i) or _failed_check(pb.P[i], len(pb.obj[i])) for i in range(pb.n)]
    if robust_robot_sigma:
        robust_robot_sigmas(pb, {i: checks[i] for i in pb.prior_views()})
        if o.robot_noise == "estimate":
            # never below the configured start: on few views the robust estimate can fall to its floor (the
            # camera-only covariances explain the median disagreement), and a robot sigma of ~0 would flag
            # nearly every view before the variance components have spoken (VCE approaches a small robot
            # sigma from above, so the start must not be at the floor either)
            if pb.kin is not None:
                pb.sigma_q = max(pb.sigma_q, pb.kin.encoder_sigma_rad)
            else:
                pb.sigma_rot = max(pb.sigma_rot, np.radians(o.robot_sigma_deg))
                pb.sigma_trans = max(pb.sigma_trans, o.robot_sigma_mm / 1000.0)
    test = robot_tests(pb, checks, S_pp)
    status, masks, outliers = [], [], []
    for i, vid in enumerate(pb.ids):
        ch = checks[i]
        n_all = len(ch.resid_px)
        bad = ~(ch.resid_px <= max(t_corner * pb.sigma_px, o.min_corner_outlier_px))
        n_good = int((~bad).sum())
        if not ch.ok and n_all >= o.min_corners:
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(
                Outlier(
                    vid,
                    "reprojection",
                    f"view {vid}: its corners alone do not determine a pose ({n_all} corners)",
                    size={"n_corners": n_all},
                )
            )
            continue
        if n_good < o.min_corners or not ch.ok:
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(
                Outlier(
                    vid,
                    "too_few_corners",
                    f"view {vid}: {n_good} usable corners of {n_all}, need {o.min_corners}",
                    size={"n_usable": n_good, "n_corners": n_all},
                )
            )
            continue
        if bad.mean() > share:
            rms = float(np.sqrt(np.mean(ch.resid_px**2)))
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(
                Outlier(
                    vid,
                    "reprojection",
                    f"view {vid}: {int(bad.sum())} of {n_all} corners beyond "
                    f"{t_corner:g} sigma even with the pose fitted to this view alone "
                    f"(rms {rms:.2f} px, sigma {pb.sigma_px:.3f} px)",
                    size={"rms_px": rms, "max_px": float(ch.resid_px.max()), "n_flagged": int(bad.sum())},
                )
            )
            continue
        masks.append(~bad)
        if bad.any():
            ids = tuple(int(c) for c in np.asarray(pb.views[i].corner_ids)[bad])
            outliers.append(
                Outlier(
                    vid,
                    "corners",
                    f"view {vid}: {len(ids)} corner(s) beyond {t_corner:g} sigma "
                    f"(max {ch.resid_px[bad].max():.2f} px, sigma {pb.sigma_px:.3f} px)",
                    corner_ids=ids,
                    size={"residual_px": ch.resid_px[bad]},
                )
            )
        if test.flagged[i]:
            status.append("robot_excluded")
            outliers.append(
                robot_pose_outlier(
                    vid,
                    test,
                    i,
                    "reported robot pose disagrees with the camera",
                    "its corners still serve the intrinsics",
                )
            )
        else:
            status.append("used")
    return Decision(tuple(status), tuple(masks), tuple(outliers), tuple(checks), test)


def apply_decision(pb: "Problem", dec: Decision) -> None:
    pb.status = list(dec.status)
    pb.mask = [m.copy() for m in dec.masks]
    for i, ch in enumerate(dec.checks):  # start excluded / re-admitted poses from the camera's pose
        if ch.ok and dec.status[i] != "used":
            pb.P[i] = ch.P_cam


class TooFewRobotPoses(Exception):
    """Fewer than 3 views keep a robot pose that agrees with the camera."""


def outlier_loop(pb: "Problem") -> tuple[Decision, Optional[np.ndarray], Optional[dict[int, np.ndarray]]]:
    """Decide, exclude, re-solve and decide again until the set of outliers is stable.

    Decide, exclude, re-solve (Gaussian, with variance-component estimation) and decide again from
    scratch against the clean solution, so that a flagged view or corner that fits it is re-admitted,
    until the set is stable (or ``max_outlier_rounds``). Returns (Decision, Sigma_core, {view:
    Sigma_robot}); raises TooFewRobotPoses.
    """
    o = pb.o
    seen_keys: list[tuple[tuple[str, ...], tuple[bytes, ...]]] = []
    S_cc: Optional[np.ndarray] = None
    S_pp: Optional[dict[int, np.ndarray]] = None
    for rnd in range(o.max_outlier_rounds):
        dec = decide(pb, robust_robot_sigma=rnd == 0, S_pp=S_pp)
        if seen_keys and dec.key() == seen_keys[-1]:
            return dec, S_cc, S_pp
        if dec.key() in seen_keys:
            # two sets alternate (a borderline view): settle on the latest decision, solved with it
            log.warning("outlier decisions oscillate; solving once more with the latest set")
            apply_decision(pb, dec)
            S_cc, S_pp = solve_with_vce(pb)
            return dec, S_cc, S_pp
        seen_keys.append(dec.key())
        apply_decision(pb, dec)
        n_robot = len(pb.prior_views()) + (
            0 if pb.robot_var else len([i for i in pb.active() if pb.status[i] == "used"])
        )
        if n_robot < 3:
            raise TooFewRobotPoses(
                f"only {len(pb.prior_views())} views left whose robot pose agrees with the camera; need 3"
            )
        S_cc, S_pp = solve_with_vce(pb)
    log.warning("outlier decisions did not settle in %d rounds", o.max_outlier_rounds)
    return decide(pb, robust_robot_sigma=False, S_pp=S_pp), S_cc, S_pp
