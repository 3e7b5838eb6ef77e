"""The board's scale against the robot's: a check of the stated square size.

A wrong square size scales every camera translation by ``1/k``; with ``k`` as one more unknown the
pair equations of ``C_i = A · M_i · B`` stay linear, so ``k`` comes in closed form with ``t_A`` and
its sigma from the jackknife over views (thresholds in configs/diagnostics.yaml ``scale:``).
``k`` is named when it differs from 1 statistically and X's translation with the squares as stated
lies farther than its own sigma from where the measured ``k`` puts it, and rescaling does not make
the board scatter worse; a ``k`` below 0 is a mirrored image. See docs/diagnostics.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional

import numpy as np

from .findings import Finding
from .fits import fit_boards
from .geometry import pair_motions, pairs_text, rotation_from_sums, solve_from_sums
from .thresholds import thresholds

__all__ = ["ScaleEstimate", "estimate_scale", "scale_findings", "stated_length_m", "x_shift_sigmas"]


@dataclass(frozen=True)
class ScaleEstimate:
    k: float  # true board length / stated board length (camera translations x k match the robot's)
    sigma: float  # jackknife standard error of k
    n_views: int
    # how far X's translation moves (m, X's parent frame) from the squares as stated (k = 1) to the measured
    # k: the closed-form solve with k fixed at 1 against the one with k free; shape (3,)
    x_shift_m: Optional[np.ndarray] = None
    # jackknife covariance (m^2, (3,3)) of X's translation as stated: its sigma when no refinement gave one
    cov_x_trans_m2: Optional[np.ndarray] = None

    @property
    def z(self) -> float:
        return abs(self.k - 1.0) / self.sigma if self.sigma > 0 else float("inf")

    def p_value(self, *, against: float = 1.0) -> float:
        """Two-sided p-value of k = ``against`` (Student t with n - 1 degrees of freedom).

        The distribution function scipy.stats.t.sf evaluates (:func:`handeye.special.stdtr`), without
        importing scipy (a fifth of a second of start-up or more).
        """
        from ..special import stdtr

        z = abs(self.k - against) / self.sigma if self.sigma > 0 else float("inf")
        return float(2.0 * stdtr(max(self.n_views - 1, 1), -z))

    @property
    def mirrored(self) -> bool:
        """K below 0 at the significance of ``scale.p_value``: camera motions opposite to the robot's.

        No square size does that; a mirrored image does (PnP then fits the board seen from behind).
        """
        return bool(np.isfinite(self.k) and self.k < 0 and self.p_value(against=0.0) < thresholds().scale.p_value)


def _solve_from_sums(sums: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(k, X's translation as stated, X's translation at k) from summed pair terms (:meth:`PairMotions.sums`).

    R_A by Kabsch, then ``t_A`` in least squares with k = 1 and (t_A, k) with k free; X = inv(A), so X's
    translation is ``-R_A^T t_A`` (m, X's parent frame).
    """
    R_A = rotation_from_sums(sums)
    t_stated = solve_from_sums(sums, R_A, scale=False)
    sol = solve_from_sums(sums, R_A, scale=True)
    return float(sol[3]), -R_A.T @ t_stated, -R_A.T @ sol[:3]


def _k_from_sums(sums: np.ndarray) -> float:
    """K from summed pair terms (:meth:`PairMotions.sums`): R_A by Kabsch, then (t_A, k) in least squares."""
    return _solve_from_sums(sums)[0]


def estimate_scale(C: np.ndarray, M: np.ndarray, *, use: Optional[np.ndarray] = None) -> Optional[ScaleEstimate]:
    """The scale ratio ``k`` of board poses against robot motions, with its jackknife sigma.

    ``C`` (N,4,4) ``T_cam_board``, ``M`` (N,4,4) robot motions, over the views in ``use`` (bool (N,),
    default all); None with fewer than 4 views. Also how far X's translation moves between the squares
    as stated and the measured ``k``, and the jackknife covariance of X's translation as stated. The
    pairs' terms are computed once and summed per view, so each leave-one-out solve subtracts the sums
    of the pairs of the view it leaves out: O(pairs) in all, not O(views x pairs).
    """
    idx = np.flatnonzero(np.ones(len(C), bool) if use is None else np.asarray(use, bool))
    n = len(idx)
    if n < 4:
        return None
    C, M = C[idx], M[idx]
    motions = pair_motions(C, M)
    total = motions.sums()
    k, t_stated, t_at_k = _solve_from_sums(total)
    per_view = np.zeros((n, total.size))  # the terms of the pairs each view is in (as i or as j)
    np.add.at(per_view, motions.i, motions.terms)
    np.add.at(per_view, motions.j, motions.terms)
    loo = [_solve_from_sums(total - per_view[v]) for v in range(n)]
    loo_k = np.array([x[0] for x in loo])
    loo_t = np.array([x[1] for x in loo])  # shape (n, 3)
    sigma = float(np.sqrt((n - 1) / n * np.sum((loo_k - loo_k.mean()) ** 2)))
    dev = loo_t - loo_t.mean(axis=0)
    cov_t = (n - 1) / n * dev.T @ dev
    return ScaleEstimate(k, sigma, n, x_shift_m=t_at_k - t_stated, cov_x_trans_m2=cov_t)


def intrinsics_sigma(obs, M: np.ndarray, use: Optional[np.ndarray] = None) -> Optional[float]:
    """The sigma of ``k`` that the uncertainty of the intrinsics the board poses were solved with gives.

    An error of those intrinsics is common to every view's board pose (a focal length scales every distance),
    so the jackknife over views cannot see the scale it adds. ``sqrt(g^T S g)`` of :func:`intrinsics_gradient`.
    None when the intrinsics were given (held fixed) or there are no corners.
    """
    gs = intrinsics_gradient(obs, M, use)
    return None if gs is None else float(np.sqrt(max(gs[0] @ gs[1] @ gs[0], 0.0)))


def intrinsics_gradient(obs, M: np.ndarray, use: Optional[np.ndarray] = None) -> Optional[tuple]:
    """(g = dk/d(intrinsics) (9,), S the intrinsics' covariance (9,9)), or None (see :func:`intrinsics_sigma`).

    ``S`` from the views' corners (:func:`.geometry.intrinsics_covariance`, the pixel noise of
    :meth:`PoseObservations.pixel_sigma`); ``g`` by central differences of one sigma, each view's pose solved
    again from its own.
    """
    if not getattr(obs, "corners", None) or obs.intrinsics is None or not obs.intrinsics_estimated:
        return None
    from ..camera import Intrinsics
    from ..initial.board_poses import refit_pose
    from .geometry import intrinsics_covariance

    idx = np.flatnonzero(np.ones(len(obs.C), bool) if use is None else np.asarray(use, bool))
    if len(idx) < 4:
        return None
    theta = obs.intrinsics.as_vector()
    S = intrinsics_covariance(obs.corners, obs.C, theta, obs.pixel_sigma())
    if not np.all(np.isfinite(S)):
        return None
    g = np.zeros(9)
    for j in range(9):
        h = max(float(np.sqrt(max(S[j, j], 0.0))), 1e-9 * max(abs(theta[j]), 1.0))
        k_pm = []
        for sign in (1.0, -1.0):
            intr = Intrinsics.from_vector(theta + sign * h * np.eye(9)[j], obs.intrinsics.width, obs.intrinsics.height)
            C = np.stack([refit_pose(obs.C[i], obs.corners[i][0], obs.corners[i][1], intr) for i in idx])
            k_pm.append(_k_from_sums(pair_motions(C, M[idx]).sums()))
        g[j] = (k_pm[0] - k_pm[1]) / (2.0 * h)
    return g, S


def arm_model_sigma(obs, refined, use: Optional[np.ndarray] = None) -> Optional[float]:
    """The sigma of ``k`` that the arm's DH table, off by its stated tolerance, gives; None without the arm's model.

    With the arm's kinematic model (``refined.robot_model`` of kind kinematic), a DH offset moves the robot's
    translations as a board scale does, in part (a length error, most of all on a short arm). The sigma is
    ``sqrt(g^T S g)``: ``S`` the arm's stated DH prior (``dh_prior_sigma_stated``, not a prior the session's own
    views widened, nor their estimate of the offsets, which a wrong board size pulls as well), ``g`` =
    dk/d(offset) by central differences at the reported poses (``reported · (FK(q) T_tool)^-1 FK_dh(q)
    T_tool``) over the views in ``use``. None without the arm's model or its joint angles for every view.
    """
    rm = getattr(refined, "robot_model", None) or {}
    q_by_id = rm.get("joint_angles_rad") or {}
    stated = rm.get("dh_prior_sigma_stated")
    if rm.get("kind") != "kinematic" or not stated or not all(v in q_by_id for v in obs.ids):
        return None
    from ..frames import inv_T
    from ..kinematics import chain_from_dict

    chain = chain_from_dict(rm["dh_table"])
    n_j = chain.n_joints
    prior = np.tile(
        [
            stated["length_mm"] * 1e-3,
            np.radians(stated["angle_deg"]),
            stated["length_mm"] * 1e-3,
            np.radians(stated["angle_deg"]),
        ],
        n_j,
    )
    q = np.array([q_by_id[v] for v in obs.ids], float)
    T_tool = np.asarray(rm["tool_offset_T_flange_reported"], float)
    idx = np.flatnonzero(np.ones(obs.n, bool) if use is None else np.asarray(use, bool))
    C, q, T_rep = obs.C[idx], q[idx], obs.T[idx]
    to_reported = T_rep @ inv_T(chain.T_base_end(q) @ T_tool)
    mount = obs.mounting

    def k_at(delta: np.ndarray) -> float:
        T = to_reported @ chain.with_dh(chain.dh + delta.reshape(n_j, 4)).T_base_end(q) @ T_tool
        return _k_from_sums(pair_motions(C, mount.M_from_T_base_end(T)).sums())

    h = 1e-6  # m and rad: far inside the linear range, far above round-off
    g = np.array([(k_at(h * e) - k_at(-h * e)) / (2 * h) for e in np.eye(4 * n_j)])
    return float(np.sqrt(np.sum((g * prior) ** 2)))


def x_shift_sigmas(est: Optional[ScaleEstimate], cov_x_trans_m2: Optional[np.ndarray] = None) -> float:
    """How many of its own sigmas X's translation moves from the squares as stated to the measured ``k``.

    The Mahalanobis length of :attr:`ScaleEstimate.x_shift_m` under ``cov_x_trans_m2`` ((3,3) m^2 in X's
    parent frame: the refinement's, :func:`x_translation_cov`), or under the closed form's jackknife
    covariance when None. NaN when there is neither.
    """
    if est is None or est.x_shift_m is None:
        return float("nan")
    cov = est.cov_x_trans_m2 if cov_x_trans_m2 is None else np.asarray(cov_x_trans_m2, float)
    if cov is None or not np.all(np.isfinite(cov)):
        return float("nan")
    d = np.asarray(est.x_shift_m, float)
    return float(np.sqrt(max(float(d @ np.linalg.pinv(cov, hermitian=True) @ d), 0.0)))


def x_translation_cov(refined) -> Optional[np.ndarray]:
    """(3,3) covariance (m^2) of X's translation in its parent frame from a refinement's ``cov_x_6x6``.

    GTSAM's right tangent: ``R cov_v R^T``. None without a refinement.
    """
    cov = getattr(refined, "cov_x_6x6", None)
    T_x = getattr(refined, "T_x", None)
    if cov is None or T_x is None:
        return None
    cov, R = np.asarray(cov, float), np.asarray(T_x, float)[:3, :3]
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        return None
    return R @ cov[3:, 3:] @ R.T


def rescaled(C: np.ndarray, k: float) -> np.ndarray:
    """``C`` with its translations multiplied by ``k`` (the board poses had the squares been stated right)."""
    out = np.array(C, float, copy=True)
    out[..., :3, 3] *= k
    return out


def stated_length_m(target) -> tuple[str, float]:
    """(what sets the board's scale, its stated length in metres)."""
    if getattr(target, "kind", "") == "circlegrid":
        return "dot spacing", float(target.spacing_m)
    return "squares", float(target.square_m)


def is_scale_wrong(est: Optional[ScaleEstimate], cov_x_trans_m2: Optional[np.ndarray] = None) -> bool:
    """K differs from 1 statistically (``scale.p_value``) and by enough to matter.

    Enough: X's translation with the squares as stated lies more than one of its sigmas from where the
    measured k puts it (:func:`x_shift_sigmas`; ``cov_x_trans_m2``: the refinement's covariance, default
    the jackknife's).
    """
    if est is None or not np.isfinite(est.k) or est.k <= 0:
        return False
    return est.p_value() < thresholds().scale.p_value and x_shift_sigmas(est, cov_x_trans_m2) > 1.0


def _pairs(est: ScaleEstimate) -> str:
    """The view pairs of the estimate's closed form, in words."""
    return pairs_text(est.n_views, all_text="all view pairs")


def _mirrored_finding(est: ScaleEstimate) -> Finding:
    return Finding(
        "images_mirrored",
        "fail",
        "The images are mirrored (the camera moves opposite to the robot)",
        f"the camera's motions are {est.k:.4f} ± {est.sigma:.4f} x the robot's once both are compared in one frame "
        f"(closed form over {_pairs(est)} of {est.n_views} views, jackknife sigma; p = "
        f"{est.p_value(against=0.0):.1e} against 0): a negative scale, which no square size gives; a mirrored "
        "image (left-right or up-down) does, the board then fits seen from behind",
        "turn off the mirror / flip setting of the camera or its driver and capture again, or flip every image "
        "back before calibrating; the stated square size is not the cause",
        details={"scale": est.k, "scale_sigma": est.sigma, "n_views": est.n_views},
    )


def _length_accepted(length_m_value: float, field: str) -> bool:
    """Whether the session loader accepts this board length (m) for ``field``."""
    from ..errors import HandeyeError
    from ..session.fields import length_m

    try:
        length_m(length_m_value, path=Path("session.yaml"), field=field)
    except HandeyeError:
        return False
    return True


def _unexplained_scale_finding(est: ScaleEstimate, noun: str, L: float) -> Finding:
    return Finding(
        "scale_unexplained",
        "fail",
        f"The camera's motions are {est.k:.4g} x the robot's: no printable board size explains that",
        f"closed form over {_pairs(est)} of {est.n_views} views: k = {est.k:.4g} ± {est.sigma:.2g} (jackknife), p = "
        f"{est.p_value():.1e} against 1; the stated {noun} ({1e3 * L:g} mm) would have to be {1e3 * L * est.k:.4g} "
        "mm, which is no board",
        "check the unit of the robot translations (pose_format translation_unit: m | cm | mm) and that each pose "
        "is the flange's (or tool's) pose in the robot's base frame",
        details={"scale": est.k, "scale_sigma": est.sigma, "n_views": est.n_views, "stated_mm": 1e3 * L},
    )


def _tracker_scale_finding(est: ScaleEstimate) -> Finding:
    """A tracker whose translations are a factor off the robot's (a wrong marker size, monocular SLAM)."""
    return Finding(
        "tracker_scale",
        "fail",
        f"The tracker's translations are {1.0 / est.k:.4f} x the robot's",
        f"the robot's motions are {est.k:.4f} ± {est.sigma:.4f} x the tracker's once both are compared in one "
        f"frame (closed form over {_pairs(est)} of {est.n_views} views, jackknife sigma; 1 is {est.z:.0f} sigma "
        f"away, p = {est.p_value():.1e}): every target translation the tracker reports is scaled",
        f"a marker tracker scales its translations with the marker size it is given: multiply that size by "
        f"{est.k:.4f} and track again; or calibrate with --estimate-scale (estimate_scale: true in session.yaml), "
        "which estimates the factor jointly with X and carries its sigma into X's (a monocular SLAM or odometry "
        "tracker has no metric scale: this or a stereo or depth camera)",
        details={"scale": est.k, "scale_sigma": est.sigma, "n_views": est.n_views, "p_value": est.p_value()},
    )


def _decimals(value: float, stated: float, least: int) -> int:
    """Decimals (``least`` or more, at most 7) with which ``value`` no longer prints as ``stated`` does."""
    d = least
    while d < 7 and f"{value:.{d}f}" == f"{stated:.{d}f}":
        d += 1
    return d


def scale_findings(obs, fit, M: np.ndarray, *, refined=None) -> tuple[list, Optional[ScaleEstimate]]:
    """(findings, the estimate) of the board scale against the robot's, on the fit's inlier views.

    ``refined``: the run's refinement, whose covariance of X is the sigma a scale's effect on X is
    compared with (default: the closed form's jackknife).
    """
    use = fit.inliers() if fit is not None else None
    est = estimate_scale(obs.C, M, use=use)
    if est is None:
        return [], est
    arm_sigma = arm_model_sigma(obs, refined, use)
    if arm_sigma is not None:  # the arm's DH tolerance in k, beside the views' scatter
        est = replace(est, sigma=float(np.hypot(est.sigma, arm_sigma)))
    tracked = getattr(obs.target, "kind", "") == "tracked"  # pose-only: no printed length, no image
    if est.mirrored and not tracked:
        return [_mirrored_finding(est)], est
    cov_t = x_translation_cov(refined)
    if not is_scale_wrong(est, cov_t):
        return [], est
    intr_sigma = intrinsics_sigma(obs, M, use)  # only for a k that would be named: it solves the poses 18 times
    if intr_sigma is not None:
        est = replace(est, sigma=float(np.hypot(est.sigma, intr_sigma)))
        if not is_scale_wrong(est, cov_t):
            return [], est
    if tracked:
        return [_tracker_scale_finding(est)], est
    # the scale must explain the data: with the squares rescaled the board scatter must not grow (measured
    # on the ical Kinect set: a k that passes the t test and raises the scatter is not the squares' size)
    as_stated = fit if fit is not None else fit_boards(obs.C, M)
    rescaled_fit = fit_boards(rescaled(obs.C, est.k), M)
    gain = as_stated.median_trans_mm / max(rescaled_fit.median_trans_mm, 1e-9)
    if gain < thresholds().scale.min_scatter_gain:
        return [], est
    shift_mm = 1e3 * float(np.linalg.norm(est.x_shift_m)) if est.x_shift_m is not None else float("nan")
    n_sig = x_shift_sigmas(est, cov_t)
    what, L = stated_length_m(obs.target)
    true_mm, sig_mm = 1e3 * L * est.k, 1e3 * L * est.sigma
    noun = "dot spacing" if what == "dot spacing" else "squares"
    shown = f"{true_mm:.{_decimals(true_mm, 1e3 * L, 1)}f}"
    sigma_words = ", ".join(
        ["jackknife over views"]
        + (["the intrinsics' uncertainty"] if intr_sigma is not None else [])
        + (["the arm's DH tolerance"] if arm_sigma is not None else [])
    )
    title = (
        f"The board's {noun} look like {shown} mm, not {1e3 * L:g} mm"
        if noun == "squares"
        else f"The board's dot spacing looks like {shown} mm, not {1e3 * L:g} mm"
    )
    field = "spacing_m" if noun == "dot spacing" else "square_m"
    new_L = f"{L * est.k:.{_decimals(L * est.k, L, 4)}f}"
    if not _length_accepted(float(new_L), field):  # a fix the loader would refuse is never offered
        return [_unexplained_scale_finding(est, noun, L)], est
    ev = (
        f"the camera's motions are {est.k:.{_decimals(est.k, 1.0, 4)}f} ± {est.sigma:.2g} x the robot's once both "
        "are compared in one "
        f"frame (closed form over {_pairs(est)} of {est.n_views} views, sigma: {sigma_words}; 1 is "
        f"{est.z:.0f} sigma away, p = {est.p_value():.1e}): {noun} of {true_mm:.{_decimals(true_mm, 1e3 * L, 2)}f} ± "
        f"{sig_mm:.2g} mm; with "
        f"that size the board implied by each view scatters by {rescaled_fit.median_trans_mm:.2f} mm instead of "
        f"{as_stated.median_trans_mm:.2f} mm (median); between the two sizes the closed-form hand-eye translation "
        f"moves by {shift_mm:.2f} mm, {n_sig:.1f} x its sigma "
        f"({'the refinement' if cov_t is not None else 'jackknife over views'})"
    )
    action = (
        f"measure the printed {noun} with a caliper and state that size (vendor config.yaml: L: "
        f"{new_L}; session.yaml: target.{field}: {new_L}); a printer's 'fit to page' "
        f"shrinks boards by a few per cent. If they measure as stated, the robot's own lengths are off by that "
        f"ratio (its kinematic model)"
    )
    return [
        Finding(
            "square_size",
            "fail",
            title,
            ev,
            action,
            details={
                "scale": est.k,
                "scale_sigma": est.sigma,
                "n_views": est.n_views,
                "stated_mm": 1e3 * L,
                "measured_mm": true_mm,
                "measured_sigma_mm": sig_mm,
                "p_value": est.p_value(),
                "scatter_gain": gain,
                "x_shift_mm": shift_mm,
                "x_shift_sigmas": n_sig,
            },
        )
    ], est
