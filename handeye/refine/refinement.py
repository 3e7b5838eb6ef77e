"""refine(): joint maximum-likelihood refinement of the hand-eye transform, board, intrinsics and robot poses.

Both mounting modes are ``T_cam_board_i = inv(T_x) · M_i · T_board`` (:mod:`handeye.mounting`); the
unknowns are ``T_x``, ``T_board``, the free intrinsics and each view's true robot pose, tied to the
reported one by the robot model (:mod:`.robot_model`), with optional priors from an earlier
calibration. Stages: the best closed-form start, guard solves with robust losses, the outlier loop
with variance-component estimation (:mod:`.outliers`, :mod:`.noise`), then the covariance
(:mod:`.covariance`). The graph is built and solved in :mod:`.problem`.

See docs/refinement.md.
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
        log.debug("refinement failed: %s", reason)  # the result carries it; its caller says it where it matters
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
