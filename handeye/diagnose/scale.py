"""The board's scale against the robot's: is the stated square size right?

The square size sets the scale of every camera translation (PnP with squares stated ``L`` when they
are really ``k·L`` gives translations ``1/k`` of the truth; the intrinsics do not change); the robot
sets the scale of the world. With one extra unknown ``k`` the translation part of the pair equations
of ``C_i = A · M_i · B`` stays linear::

    (R_Cij - I) t_A + k · t_Cij = R_A t_Mij        (all view pairs i < j, R_A from the rotations)

so ``k`` comes in closed form with ``t_A``; its sigma is the jackknife over views (pairs share views:
the residual-based sigma of all pairs together would be far too small). ``k`` is named when it differs
from 1 both statistically (a two-sided t test at ``scale.p_value``) and practically (by more than
``scale.min_rel``), and when rescaling the squares by ``k`` shrinks the board scatter by
``scale.min_scatter_gain`` (the scale explains the data), see configs/diagnostics.yaml.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .findings import Finding
from .fits import fit_boards
from .geometry import pair_motions, rotation_from_sums, solve_from_sums
from .thresholds import thresholds

__all__ = ["ScaleEstimate", "estimate_scale", "scale_findings", "stated_length_m"]


@dataclass(frozen=True)
class ScaleEstimate:
    k: float  # true board length / stated board length (camera translations x k match the robot's)
    sigma: float  # jackknife standard error of k
    n_views: int

    @property
    def z(self) -> float:
        return abs(self.k - 1.0) / self.sigma if self.sigma > 0 else float("inf")

    def p_value(self) -> float:
        """Two-sided p-value of k = 1.

        Two-sided p-value of k = 1 (Student t with n - 1 degrees of freedom; scipy.special's distribution
        function, what scipy.stats.t.sf evaluates, without importing scipy.stats: seconds of start-up).
        """
        from scipy.special import stdtr

        return float(2.0 * stdtr(max(self.n_views - 1, 1), -self.z))


def _k_from_sums(sums: np.ndarray) -> float:
    """K from summed pair terms (:meth:`PairMotions.sums`): R_A by Kabsch, then (t_A, k) in least squares."""
    return float(solve_from_sums(sums, rotation_from_sums(sums), scale=True)[3])


def estimate_scale(C: np.ndarray, M: np.ndarray, *, use: Optional[np.ndarray] = None) -> Optional[ScaleEstimate]:
    """The scale ratio ``k`` of ``C`` (N,4,4) ``T_cam_board`` against robot motions ``M``.

    The scale ratio ``k`` of ``C`` (N,4,4) ``T_cam_board`` against robot motions ``M`` (N,4,4), with its
    jackknife sigma over the views in ``use`` (bool (N,), default all); None with fewer than 4 views.

    The pairs' terms are computed once and summed per view, so each leave-one-out solve subtracts the
    sums of the pairs of the view it leaves out: O(pairs) in all, not O(views x pairs).
    """
    idx = np.flatnonzero(np.ones(len(C), bool) if use is None else np.asarray(use, bool))
    n = len(idx)
    if n < 4:
        return None
    C, M = C[idx], M[idx]
    motions = pair_motions(C, M)
    total = motions.sums()
    k = _k_from_sums(total)
    per_view = np.zeros((n, total.size))  # the terms of the pairs each view is in (as i or as j)
    np.add.at(per_view, motions.i, motions.terms)
    np.add.at(per_view, motions.j, motions.terms)
    loo = np.array([_k_from_sums(total - per_view[v]) for v in range(n)])
    sigma = float(np.sqrt((n - 1) / n * np.sum((loo - loo.mean()) ** 2)))
    return ScaleEstimate(k, sigma, n)


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


def is_scale_wrong(est: Optional[ScaleEstimate]) -> bool:
    """Both tests: statistically different from 1 and by more than the practical minimum."""
    if est is None or not np.isfinite(est.k):
        return False
    t = thresholds().scale
    return est.p_value() < t.p_value and abs(est.k - 1.0) > t.min_rel


def scale_findings(obs, fit, M: np.ndarray) -> tuple[list, Optional[ScaleEstimate]]:
    """(findings, the estimate) of the board scale against the robot's, on the fit's inlier views."""
    est = estimate_scale(obs.C, M, use=fit.inliers() if fit is not None else None)
    if not is_scale_wrong(est) or getattr(obs.target, "kind", "") == "tracked":  # pose-only: no printed length
        return [], est
    assert est is not None, "is_scale_wrong(None) is False"
    # the scale must explain the data: with the squares rescaled the board scatter must shrink
    as_stated = fit if fit is not None else fit_boards(obs.C, M)
    rescaled_fit = fit_boards(rescaled(obs.C, est.k), M)
    gain = as_stated.median_trans_mm / max(rescaled_fit.median_trans_mm, 1e-9)
    if gain < thresholds().scale.min_scatter_gain:
        return [], est
    what, L = stated_length_m(obs.target)
    true_mm, sig_mm = 1e3 * L * est.k, 1e3 * L * est.sigma
    noun = "dot spacing" if what == "dot spacing" else "squares"
    title = (
        f"The board's {noun} look like {true_mm:.1f} mm, not {1e3 * L:g} mm"
        if noun == "squares"
        else f"The board's dot spacing looks like {true_mm:.1f} mm, not {1e3 * L:g} mm"
    )
    field = "spacing_m" if noun == "dot spacing" else "square_m"
    ev = (
        f"the camera's motions are {est.k:.4f} ± {est.sigma:.4f} x the robot's once both are compared in one "
        f"frame (closed form over all view pairs of {est.n_views} views, jackknife sigma; 1 is "
        f"{est.z:.0f} sigma away, p = {est.p_value():.1e}): {noun} of {true_mm:.2f} ± {sig_mm:.2f} mm; with "
        f"that size the board implied by each view scatters by {rescaled_fit.median_trans_mm:.2f} mm instead of "
        f"{as_stated.median_trans_mm:.2f} mm (median)"
    )
    action = (
        f"measure the printed {noun} with a caliper and state that size (vendor config.yaml: L: "
        f"{L * est.k:.4f}; session.yaml: target.{field}: {L * est.k:.4f}); a printer's 'fit to page' "
        f"shrinks boards by a few per cent"
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
            },
        )
    ], est
