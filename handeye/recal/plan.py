"""How many views, and which robot poses, a verification needs to detect a drift.

From the installed calibration alone, each candidate view's information about X is predicted with
the collector's planner (:func:`handeye.collect.plan.view_information`); verify's statistic is then
non-central chi-square (or F), and its power for a drift of ``drift_mm`` / ``drift_deg`` in the worst
direction follows (:func:`test_power`). Views are added greedily until the power reaches the goal or
``max_views``; the installed covariance sets a ceiling, and the plan says when it is below the goal.

See docs/recalibrate.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np
from scipy import stats

from ..config import load_preset
from ..conventions import VENDOR_POSE_FORMAT, pose_values_from_T
from ..errors import ConfigError, InputError
from ..mounting import mounting
from ..output import plain
from ..session.target_spec import is_tracked, parse_target
from .loaded import LoadedResult, ResultLike, load_result
from .verify import installed_robot_model, shares_dh

log = logging.getLogger(__name__)

_FLOOR_INFO = 1e-6  # information (1/rad^2, 1/m^2) added so that an empty set of views inverts
_SCHUR_RTOL = 1e-9  # relative to the largest information: below it, the Schur complement holds rounding, not data


@dataclass(frozen=True)
class VerifyPlan:
    """The plan: the chosen poses in order, the worst-case power after each, the ceiling."""

    frame: str
    drift_mm: float
    drift_deg: float
    power_goal: float
    alpha: float
    poses: tuple  # (n,4,4) T_base_end to visit, in order
    labels: tuple  # where each pose comes from
    power_by_views: tuple  # worst-case power with the first k poses, k = 1..n
    n_views: Optional[int]  # views that reach the goal (None: not within max_views)
    ceiling_power: float  # with perfect verification views: only the installed uncertainty left
    min_drift_scale: float  # the drift, scaled by this, is detected at the goal power with the planned views
    sigma_px: float
    robot_sigma_mm: float
    robot_sigma_deg: float
    candidate_index: tuple = ()  # index of each chosen pose among the candidates

    def to_dict(self) -> dict:
        return plain(
            {
                "frame": self.frame,
                "drift_mm": self.drift_mm,
                "drift_deg": self.drift_deg,
                "power_goal": self.power_goal,
                "alpha": self.alpha,
                "n_views": self.n_views,
                "power_by_views": self.power_by_views,
                "ceiling_power": self.ceiling_power,
                "detectable_drift_mm": self.drift_mm * self.min_drift_scale,
                "detectable_drift_deg": self.drift_deg * self.min_drift_scale,
                "poses_T_base_end": self.poses,
                "labels": self.labels,
                "poses_vendor": [pose_values_from_T(T, VENDOR_POSE_FORMAT) for T in self.poses],
                "poses_vendor_format": "x,y,z [m], rx,ry,rz [rad], R = Rz·Ry·Rx",
                "noise": {
                    "sigma_px": self.sigma_px,
                    "robot_sigma_mm": self.robot_sigma_mm,
                    "robot_sigma_deg": self.robot_sigma_deg,
                },
            },
            nan_to_none=True,
        )


def drift_directions(*, drift_mm: float, drift_deg: float, n_random: int, seed: int = 0) -> np.ndarray:
    """(K, 6) drifts in the tangent (rad, m) of the given rotation and translation sizes.

    (K, 6) drifts in the tangent (rad, m): a rotation of ``drift_deg`` and a translation of ``drift_mm``,
    along the axis pairs and ``n_random`` seeded random direction pairs (both signs count the same).
    """
    rng = np.random.default_rng(seed)
    eye = np.eye(3)
    w = [eye[i] for i in range(3) for _ in range(3)] + list(_unit(rng.normal(size=(n_random, 3))))
    u = [eye[j] for _ in range(3) for j in range(3)] + list(_unit(rng.normal(size=(n_random, 3))))
    return np.hstack([np.radians(drift_deg) * np.array(w), 1e-3 * drift_mm * np.array(u)])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def worst_noncentrality(cov_change: np.ndarray, drifts: np.ndarray) -> float:
    """Min over the drifts (K,6) of ``delta^T cov_change^-1 delta``."""
    P = np.linalg.inv(0.5 * (cov_change + cov_change.T))
    return float(np.min(np.einsum("ki,ij,kj->k", drifts, P, drifts)))


def worst_noncentrality_with_views(S0: np.ndarray, info_x: np.ndarray, drifts: np.ndarray) -> float:
    """:func:`worst_noncentrality` of the change covariance ``S0 + info_x^-1``.

    :func:`worst_noncentrality` of the change covariance ``S0 + info_x^-1`` (the installed X's plus the new
    views', given as their information on X, :func:`x_information`), computed as
    ``(I + info_x S0)^-1 info_x`` so that it stays exact when the views leave some direction of X
    unknown (information ~0, variance ~1e6) while the install knows another to 1e-13: inverting the sum
    of the two covariances loses the small one to rounding.
    """
    P = np.linalg.solve(np.eye(6) + info_x @ S0, info_x)
    P = 0.5 * (P + P.T)
    return float(np.min(np.einsum("ki,ij,kj->k", drifts, P, drifts)))


def x_information(info: np.ndarray) -> np.ndarray:
    """Information (6,6) on X from the summed information (12,12) of (X, board), the board marginalised.

    Information (6,6) on X from the summed information (12,12) of (X, board), the board marginalised
    (its Schur complement, the board's block floored so that an empty set of views inverts; its eigenvalues
    below :data:`_SCHUR_RTOL` of X's own block's largest are rounding and set to zero).
    """
    A, B, D = info[:6, :6], info[:6, 6:], info[6:, 6:] + _FLOOR_INFO * np.eye(6)
    Ix = A - B @ np.linalg.solve(D, B.T)
    # the directions the views leave X unknown in (one view: all six) come out of the subtraction as rounding
    # noise of either sign, of the size of A's last bits: zero them, or the plan's choice follows those bits
    w, U = np.linalg.eigh(0.5 * (Ix + Ix.T))
    tol = _SCHUR_RTOL * float(np.max(np.abs(np.linalg.eigvalsh(0.5 * (A + A.T)))))
    return (U * np.where(w > tol, w, 0.0)) @ U.T


def test_power(nc: float, *, alpha: float, dof: int = 6, noise_dof: Optional[float] = None) -> float:
    """Probability that verify's test at ``alpha`` rejects under non-centrality ``nc``.

    Chi-square, or F(dof, noise_dof) on ``T / dof`` when the installed robot noise level was estimated
    (:func:`handeye.stats.wald_p_value`; the non-central F then).
    """
    nc = max(nc, 1e-12)
    if noise_dof is None or not np.isfinite(noise_dof) or noise_dof <= 0:
        return float(stats.ncx2.sf(stats.chi2.isf(alpha, dof), dof, nc))
    return float(stats.ncf.sf(stats.f.isf(alpha, dof, noise_dof), dof, noise_dof, nc))


def installed_poses(installed: LoadedResult) -> list[np.ndarray]:
    """The robot poses of the installed calibration's views (refined), in view order."""
    poses = (installed.raw.get("refinement") or {}).get("robot_poses_refined_T_base_end") or {}
    return [np.asarray(T, float) for T in poses.values()]


def plan_verification(
    against: Union[ResultLike, LoadedResult],
    *,
    drift_mm: Optional[float] = None,
    drift_deg: Optional[float] = None,
    power: Optional[float] = None,
    alpha: Optional[float] = None,
    max_views: Optional[int] = None,
    candidates: Optional[Sequence[np.ndarray]] = None,
    cfg: Optional[dict] = None,
) -> VerifyPlan:
    """The verification plan for the installed result ``against`` (see the module docstring).

    ``candidates``: robot poses to choose from (default: the installed views' poses and orbits around them).
    """
    from ..collect.plan import PlanConfig, candidate_views, view_information

    cfg = load_preset("recal") if cfg is None else cfg
    pc = cfg["plan"]
    drift_mm = float(pc["drift_mm"] if drift_mm is None else drift_mm)
    drift_deg = float(pc["drift_deg"] if drift_deg is None else drift_deg)
    goal = float(pc["power"] if power is None else power)
    alpha = float(cfg["test"]["alpha"] if alpha is None else alpha)
    max_views = int(pc["max_views"] if max_views is None else max_views)
    if not alpha < goal < 1.0:  # a test at alpha rejects with probability alpha when nothing moved
        raise InputError(
            "the power wanted must exceed the test's level",
            expected=f"{alpha:g} < --power < 1",
            received=f"{goal:g}",
            hint="ask for the probability of detecting the drift, e.g. 0.95",
        )
    if not (drift_mm >= 0 and drift_deg >= 0 and drift_mm + drift_deg > 0):
        raise InputError(
            "the drift to detect must be positive",
            expected="--drift-mm >= 0, --drift-deg >= 0, not both 0",
            received=f"{drift_mm} mm, {drift_deg} deg",
        )
    installed = against if isinstance(against, LoadedResult) else load_result(against)
    tracked = is_tracked(installed.target)
    lacks = (
        ["its hand-eye matrix (the calibration failed)"]
        if not installed.ok or installed.T_x is None
        else [
            what
            for what, gone in (
                ("the covariance of X (calibrated with --no-refine)", installed.cov_x is None),
                ("the board pose", installed.T_board is None),
                (
                    "camera intrinsics" + (" (calibrated from a tracker's poses)" if tracked else ""),
                    installed.intrinsics is None,
                ),
            )
            if gone
        ]
    )
    if lacks:
        raise InputError(
            f"the installed result lacks {' and '.join(lacks)}",
            path=installed.source,
            hint="plan against a calibration refined from images of the board (handeye calibrate without --no-refine)",
        )
    assert installed.T_x is not None and installed.cov_x is not None, "an ok result lacking none has X and its cov"
    assert installed.T_board is not None and installed.intrinsics is not None, "an ok result lacking none has both"
    target = parse_target(installed.target, path=installed.source)  # type: ignore[arg-type]  # str names it alike
    obj = target.object_points()
    mode, T_x, T_board = installed.mode, installed.T_x, installed.T_board
    sigma_px = installed.sigma_px or 0.3
    rs_mm, rs_deg = installed.robot_sigma_mm or 0.0, installed.robot_sigma_deg or 0.0
    drifts = drift_directions(drift_mm=drift_mm, drift_deg=drift_deg, n_random=int(pc["n_directions"]))

    def info_of(T):
        return view_information(
            mode=mode,
            T_x=T_x,
            T_board=T_board,
            T_base_end=T,
            object_points=obj,
            intrinsics=installed.intrinsics,
            pixel_noise_px=sigma_px,
            robot_noise_mm=rs_mm,
            robot_noise_deg=rs_deg,
        )

    if candidates is not None:
        cands = [(np.asarray(T, float), f"given pose {k + 1}") for k, T in enumerate(candidates)]
    else:
        base = installed_poses(installed)
        cands = [(T, f"installed view pose {k + 1}") for k, T in enumerate(base)]  # reached once: kept
        arm = installed_robot_model(installed).get("arm")
        m = mounting(mode)
        config = PlanConfig(pixel_noise_px=sigma_px, robot_noise_mm=rs_mm, robot_noise_deg=rs_deg)
        for k, T0 in enumerate(base[: int(pc["orbit_views"])]):  # orbits around a few installed views
            C0 = m.predict_T_cam_board(T_x, T_board, T0)
            orbit = None
            for intr in (installed.intrinsics, _without_k3(installed.intrinsics)):
                try:
                    orbit = candidate_views(
                        mode=mode,
                        T_x=T_x,
                        T_board=T_board,
                        T_base_end_start=T0,
                        T_cam_board_start=C0,
                        target=target,
                        intrinsics=intr,
                        config=config,
                    )
                    break
                except ConfigError as e:  # a distortion the visibility test cannot invert
                    log.debug("orbit candidates with dist=%s: %s", np.round(intr.dist, 4).tolist(), e.args[0])
            if orbit is None:
                log.warning(
                    "no orbit candidates (the lens distortion folds back in the image); planning from the "
                    "installed poses"
                )
                break
            cands += _reachable([(c.T_base_end, f"orbit of installed view {k + 1}: {c.label}") for c in orbit], arm, T0)
    if not cands:
        raise InputError(
            "no candidate robot poses to plan from",
            path=installed.source,
            hint="the result holds no refined robot poses; give candidate poses",
        )
    infos = [info_of(T) for T, _ in cands]
    # verify shares the installed intrinsics (and the DH offsets when it can): their error cancels in its test
    S0 = installed.cov_x_given_shared if shares_dh(installed) else installed.cov_x_given_intrinsics
    assert S0 is not None, "an ok result with its covariance and intrinsics has it"
    nu = installed.robot_noise_dof
    ceiling = test_power(worst_noncentrality(S0, drifts), alpha=alpha, noise_dof=nu)
    info = np.zeros((12, 12))
    chosen, powers, n_goal = [], [], None
    pool = list(range(len(cands)))
    nc = 0.0
    for step in range(max_views):
        scores = [worst_noncentrality_with_views(S0, x_information(info + infos[i]), drifts) for i in pool]
        k = _first_best(scores)
        best, nc = pool[k], scores[k]
        info = info + infos[best]
        chosen.append(best)
        pool.remove(best)
        powers.append(test_power(nc, alpha=alpha, noise_dof=nu))
        if n_goal is None and step >= 2 and powers[-1] >= goal:
            n_goal = step + 1
            break
        if not pool:
            break
    nc_goal = _noncentrality_for_power(goal, alpha=alpha, noise_dof=nu)
    scale = float(np.sqrt(nc_goal / nc)) if nc > 0 else float("inf")
    return VerifyPlan(
        frame=installed.x_name,
        drift_mm=drift_mm,
        drift_deg=drift_deg,
        power_goal=goal,
        alpha=alpha,
        poses=tuple(cands[i][0] for i in chosen),
        labels=tuple(cands[i][1] for i in chosen),
        power_by_views=tuple(powers),
        n_views=n_goal,
        ceiling_power=ceiling,
        min_drift_scale=scale,
        sigma_px=sigma_px,
        robot_sigma_mm=rs_mm,
        robot_sigma_deg=rs_deg,
        candidate_index=tuple(chosen),
    )


def _reachable(cands: list, arm, T_from: np.ndarray) -> list:
    """The candidate (pose, label) pairs around ``T_from`` that the installed arm reaches.

    The candidate (pose, label) pairs around the installed pose ``T_from`` that the installed arm reaches (inverse
    kinematics within its joint limits, from the configuration that reaches ``T_from`` and the default seeds);
    all of them when the result names no arm.
    """
    if arm is None:
        return cands
    from ..kinematics import default_ik_seeds, solve_ik

    q0 = solve_ik(arm, T_from, seeds=default_ik_seeds(arm, T_from))
    near = [] if q0 is None else [q0]
    kept = [(T, label) for T, label in cands if solve_ik(arm, T, seeds=near + default_ik_seeds(arm, T)) is not None]
    if len(kept) < len(cands):
        log.info(
            "plan: %d of %d candidate poses are beyond the reach of %s and left out",
            len(cands) - len(kept),
            len(cands),
            arm.name,
        )
    return kept


def _without_k3(intrinsics):
    """The intrinsics with k3 = 0, for the collector's visibility test only.

    A 20-view calibration's k3 is fitted where corners were, and often folds the lens model back
    near the image corners, where no corner lies; the views' information is still computed with the
    full model.
    """
    from dataclasses import replace

    return replace(intrinsics, dist=tuple(intrinsics.dist[:4]) + (0.0,))


# scores this close (relative) are a tie, broken by the candidates' order: orbit candidates placed
# symmetrically score alike to the last bits, and the last bits of a sum differ with the platform's libraries
SCORE_TIE_RTOL = 1e-6


def _first_best(scores) -> int:
    """The index of the first score within :data:`SCORE_TIE_RTOL` of the largest."""
    top = max(scores)
    return next(i for i, s in enumerate(scores) if s >= top - SCORE_TIE_RTOL * abs(top))


def _noncentrality_for_power(goal: float, *, alpha: float, dof: int = 6, noise_dof: Optional[float] = None) -> float:
    """The non-centrality at which the test at ``alpha`` has power ``goal`` (bisection)."""
    lo, hi = 0.0, 1.0
    while test_power(hi, alpha=alpha, dof=dof, noise_dof=noise_dof) < goal:
        hi *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if test_power(mid, alpha=alpha, dof=dof, noise_dof=noise_dof) < goal else (lo, mid)
    return hi


def plan_lines(p: VerifyPlan) -> list[str]:
    """The plan for a person: the answer, the poses, the power after each view, the ceiling."""
    goal = f"{100 * p.power_goal:.0f} %"
    drift = f"{p.drift_mm:g} mm / {p.drift_deg:g} deg"
    if p.n_views is not None:
        head = f"{p.n_views} views detect a drift of {drift} of {p.frame} with {goal} power (worst direction)"
    else:
        head = (
            f"no plan of up to {len(p.poses)} views reaches {goal} power for a drift of {drift} of {p.frame} "
            f"(best {100 * p.power_by_views[-1]:.0f} %)"
        )
    lines = [head]
    if p.ceiling_power < p.power_goal:
        lines.append(
            f"the installed calibration's own uncertainty limits the power to {100 * p.ceiling_power:.0f} % "
            f"for this drift even with perfect views: recalibrate with more views to verify at {drift}"
        )
    lines.append(
        f"with these views the drift detected with {goal} power is {p.drift_mm * p.min_drift_scale:.2f} mm / "
        f"{p.drift_deg * p.min_drift_scale:.3f} deg"
    )
    lines.append(
        f"assumed noise (installed): {p.sigma_px:.2f} px corners, robot {p.robot_sigma_mm:.3f} mm / "
        f"{p.robot_sigma_deg:.4f} deg"
    )
    lines.append("poses T_base_end to visit (x, y, z [mm]; rx, ry, rz [deg], R = Rz·Ry·Rx), power after the view:")
    for k, (T, label, pw) in enumerate(zip(p.poses, p.labels, p.power_by_views, strict=False)):
        v = pose_values_from_T(T, VENDOR_POSE_FORMAT)
        lines.append(
            f"  {k + 1:2d}: {1000 * v[0]:8.1f} {1000 * v[1]:8.1f} {1000 * v[2]:8.1f}  "
            f"{np.degrees(v[3]):7.2f} {np.degrees(v[4]):7.2f} {np.degrees(v[5]):7.2f}   "
            f"{100 * pw:5.1f} %  ({label})"
        )
    return lines
