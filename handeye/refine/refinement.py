"""refine(): joint maximum-likelihood refinement of the hand-eye transform, the board, the intrinsics
and the true robot poses, with noise estimation, outlier decisions and the covariance.

Model
-----
Both mounting modes are ``T_cam_board_i = inv(T_x) · M_i · T_board`` (see :mod:`handeye.mounting`).
Unknowns: ``T_x`` (``T_end_cam`` eye-in-hand, ``T_base_cam`` eye-to-hand); ``T_board``
(``T_base_board`` / ``T_end_board``); the free subset of the intrinsics
``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` (``options.fix`` names the fixed ones;
``intrinsics="fixed"`` fixes all; ``"prior"`` adds a Gaussian prior around the given ones); per
view, the true robot pose ``T_base_end_i``, tied to the reported pose by a prior
``Log(inv(T_reported) · T_base_end_i) ~ N(0, diag(s_rot^2 I3, s_trans^2 I3))`` (end frame, rotation
first); ``robot_noise="none"`` holds the reported poses exact instead. With an arm named
(``options.arm``) the prior is the kinematic one of :mod:`.robot_model` instead: the DH offsets of the
arm, shared by all views, join the unknowns with their own prior, and each view's prior covariance is
its encoder noise through the joint Jacobian. ``options.prior`` adds Gaussian priors on ``T_x``, the
free intrinsics and optionally the board's pose (an earlier calibration; the intrinsics in one joint
Gaussian with ``T_x`` or with the board when their cross-covariance is given). Every corner gives
``project(K, T_cam_board_i · p) - uv ~ N(0, sigma_px^2 I2)``.

Stages
------
1. Start: the given ``T_x0`` / ``T_board0``, or, among ``starts`` (the pipeline's closed-form
   solutions), the one with the lowest median over the views of the view's median corner residual
   through its reported robot pose: one closed-form method can be tens of degrees off when a robot
   pose is wrong (Tsai 120 deg off with one wrong pose in 12 views, where Park was within 1 deg) and
   the local solves below cannot recover from such a start.
2. Guard: noise levels from each view's own fit, then two solves with robust losses (per corner,
   and Huber on each robot prior), the pixel sigma from the median residual in between (one
   Gaussian solve with ``loss="none"``).
3. Outlier loop (:mod:`.outliers`): decisions against the current solution, Gaussian re-solves
   with variance-component estimation (:mod:`.noise`), until the decisions are stable.
4. Covariance (:mod:`.covariance`) from the information of the final Gaussian linearisation, in
   which the estimated sigmas are the noise models.

The graph itself is built and solved in :mod:`.problem` (the only GTSAM user).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Mapping, Optional, Sequence

import numpy as np

from ..camera import Intrinsics
from ..mounting import mounting
from ..records import HandEyeEstimate
from .noise import robust_robot_sigmas, robust_sigma_px, sigma_px_from_residuals
from .options import RefineOptions, RefineView, check_inputs, check_options, check_T
from .outliers import Decision, Outlier, TooFewRobotPoses, camera_only_poses, outlier_loop
from .problem import Problem
from .result import RefineResult, build_result

log = logging.getLogger(__name__)


def seed_score(pb: Problem, T_x: np.ndarray, T_board: np.ndarray) -> float:
    """Median over the views of each view's median corner residual.

    Median over the views of each view's median corner residual (px) through the reported robot
    pose: a start that half the views agree with scores low, whatever the other views do.
    """
    e = np.linalg.norm(pb.corner_residuals(T_robots=pb.reported, T_x=T_x, T_board=T_board), axis=1)
    e = np.where(np.isfinite(e), e, np.inf)
    counts = np.diff(pb.offsets)
    keep = counts >= pb.o.min_corners
    if not keep.any():
        return np.inf
    # per-view medians at once: rows padded with inf, sorted, the middle one(s) of each row's own count
    padded = np.full((pb.n, counts.max()), np.inf)
    padded[pb.view_of, np.arange(e.size) - pb.offsets[pb.view_of]] = e
    padded.sort(axis=1)
    c = counts[keep]
    rows = padded[keep]
    med = 0.5 * (rows[np.arange(c.size), (c - 1) // 2] + rows[np.arange(c.size), c // 2])
    return float(np.median(med))


def best_start(pb: Problem, starts: Mapping[str, HandEyeEstimate]) -> tuple[np.ndarray, np.ndarray, str]:
    """The given start, or the candidate among ``starts`` with a lower :func:`seed_score`.

    The given start, or the candidate among ``starts`` with the lowest :func:`seed_score` when
    that is lower. Candidates that failed or are not finite are skipped.
    """
    best, best_score, best_name = (pb.T_x, pb.T_board), seed_score(pb, pb.T_x, pb.T_board), "given"
    given_score = best_score
    for name, est in starts.items():
        if est.status != "ok" or not (np.all(np.isfinite(est.T_x)) and np.all(np.isfinite(est.T_board))):
            continue
        score = seed_score(pb, est.T_x, est.T_board)
        if score < best_score:
            best = (check_T(est.T_x, f"{name} {pb.mounting.x_name}"), check_T(est.T_board, name))
            best_score, best_name = score, name
    if best_name != "given":
        log.info(
            "starting the refinement from the %s closed form (median view residual %.4f px; the given start's %.4f px)",
            best_name,
            best_score,
            given_score,
        )
    return best[0], best[1], best_name


def refine(
    *,
    mode: str,
    object_points: np.ndarray,
    views: Sequence[RefineView],
    intrinsics: Intrinsics,
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    options: Optional[RefineOptions] = None,
    starts: Optional[Mapping[str, HandEyeEstimate]] = None,
) -> RefineResult:
    """Refine hand-eye, board, intrinsics and robot poses jointly; see the module docstring.

    ``starts``: other candidate starts (method name -> closed-form estimate, e.g. the pipeline's
    ``run.seeds``); the refinement starts from the one its views agree with best. None: start from
    ``T_x0`` / ``T_board0``.

    Raises ConfigError / InputError for invalid options or inputs; a solve that fails returns a
    result with ``status="failed"`` and a ``failure_reason``.
    """
    options = RefineOptions() if options is None else options
    t0 = time.perf_counter()
    mount = mounting(mode)
    check_options(options)
    T_x0 = check_T(T_x0, f"seed {mount.x_name}")
    T_board0 = check_T(T_board0, f"seed {mount.board_name}")
    object_points, reported = check_inputs(object_points, views)
    if len(object_points) < options.min_corners:  # a target with fewer corners (one marker: 4) must show them all
        options = replace(options, min_corners=len(object_points))
    pb = Problem(
        mode=mode,
        object_points=object_points,
        views=views,
        reported=reported,
        intrinsics=intrinsics,
        T_x0=T_x0,
        T_board0=T_board0,
        options=options,
    )
    start_method = "given"
    if starts:
        pb.T_x, pb.T_board, start_method = best_start(pb, starts)
    e_before = pb.corner_residuals(T_robots=pb.reported)
    rms_before = float(np.sqrt(np.mean(np.sum(e_before**2, axis=1))))
    sparse = []  # views that cannot even start (the outlier loop re-examines them with reasons)
    for i, vid in enumerate(pb.ids):
        if len(pb.obj[i]) < options.min_corners:
            pb.status[i] = "removed"
            sparse.append(
                Outlier(
                    vid,
                    "too_few_corners",
                    f"view {vid}: {len(pb.obj[i])} corners, need {options.min_corners}",
                    size={"n_usable": len(pb.obj[i]), "n_corners": len(pb.obj[i])},
                )
            )

    def result(
        status: str,
        reason: str,
        S_cc: Optional[np.ndarray] = None,
        dec: Optional[Decision] = None,
        code: str = "",
    ) -> RefineResult:
        return build_result(
            pb,
            status=status,
            reason=reason,
            S_cc=S_cc,
            dec=dec,
            rms_before=rms_before,
            T_x0=T_x0,
            T_board0=T_board0,
            intrinsics0=intrinsics,
            t0=t0,
            outliers=dec.outliers if dec is not None else tuple(sparse),
            start_method=start_method,
            failure_code=code,
        )

    def failed(reason: str, code: str) -> RefineResult:
        log.warning("refinement failed: %s", reason)
        return result("failed", reason, code=code)

    try:
        # start: sigmas from each view's own fit at the start
        pb.sigma_px = 1.0
        checks0 = camera_only_poses(pb, pb.active())
        e0 = np.concatenate([c.resid_px for c in checks0.values() if c.ok]) if checks0 else np.zeros(0)
        if e0.size:
            pb.sigma_px = sigma_px_from_residuals(e0)
            checks0 = {i: replace(c, cov_cam=c.cov_cam * pb.sigma_px**2) for i, c in checks0.items()}  # were for 1 px
        robust_robot_sigmas(pb, checks0)
        # guard: robust solves, pixel sigma from the median residual in between (without a robust loss one
        # Gaussian solve gives the residuals the pixel sigma is estimated from)
        for _ in range(2 if options.loss != "none" else 1):
            pb.solve(robust=options.loss != "none")
            pb.sigma_px = robust_sigma_px(pb)
        if options.outlier_loop:
            dec, S_cc, _ = outlier_loop(pb)
            return result("ok", "", S_cc, dec)
        robust_robot_sigmas(pb, camera_only_poses(pb, pb.prior_views()))
        g, values, rk = pb.solve(robust=options.loss != "none")
        S_cc, _ = pb.covariances(g, values, rk)
        return result("ok", "", S_cc)
    except TooFewRobotPoses as err:
        return failed(str(err), "too_few_robot_poses")
    except np.linalg.LinAlgError as err:
        return failed(
            f"the information matrix is singular ({err}); the views do not constrain all unknowns", "singular"
        )
    except RuntimeError as err:  # GTSAM raises RuntimeError (e.g. indeterminant linear system)
        return failed(f"GTSAM: {err}", "solver")
