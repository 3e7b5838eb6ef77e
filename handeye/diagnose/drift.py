"""A drifting target: the implied board moving steadily from one view on, told apart from a single move.

When the step test of :mod:`.consistency` finds the board moved, :func:`drift_or_step` fits a step and a
drift (a line from one view on) to the implied boards with the same number of parameters; the better
fit names the finding (:func:`drift_finding` for a drift). See docs/diagnostics.md.
"""

from __future__ import annotations

import numpy as np

from ..stats import chi2_ppf, f_sf
from .findings import Finding
from .observations import PoseObservations


def _break_design(n: int, k: int, *, ramp: bool) -> np.ndarray:
    """(N,2) the columns of a level and of a step (1 from view ``k`` on) or a drift (1, 2, ... from view ``k``)."""
    i = np.arange(n)
    x = np.where(i >= k, (i - k + 1.0) if ramp else 1.0, 0.0)
    return np.stack([np.ones(n), x], axis=1)


def drift_or_step(v: np.ndarray, use: np.ndarray, *, min_segment: int) -> tuple[str, int, float]:
    """Whether the implied board deviations ``v`` (N,6) change in one step or drift.

    Returns ("step" | "drift", the first view that moved, the drift's residual share of the step's). The models
    are fitted to the size of each view's deviation (rotation and translation, each in units of its robust
    spread over the views ``use``): a level plus a step from a view on, or a level plus a steady growth from a
    view on, the same number of parameters, so the one with the smaller residual explains the sequence. Sizes,
    not coordinates: a tracker's drift is steady in the tracker's frame, and its direction in the board's frame
    turns with every view. Each model leaves out its own outliers (a view costs at most the chi-square(2)
    99.9 % quantile, and the model is fitted again on the views below it).
    """
    n = len(v)
    m = np.stack([np.linalg.norm(v[:, :3], axis=1), np.linalg.norm(v[:, 3:], axis=1)], axis=1)  # shape (N, 2)
    mad = np.median(np.abs(m[use] - np.median(m[use], axis=0)), axis=0)
    m = m / np.maximum(1.4826 * mad, 1e-9)  # in units of the robust spread
    cap = chi2_ppf(0.999, 2)

    def cost(k: int, ramp: bool) -> float:
        X = _break_design(n, k, ramp=ramp)
        rows = np.ones(n, bool)
        for _ in range(2):  # the fit on every view, then on the views the model does not leave out
            coef, *_ = np.linalg.lstsq(X[rows], m[rows], rcond=None)
            r2 = np.sum((m - X @ coef) ** 2, axis=1)
            inl = r2 <= cap
            if inl.all() or np.count_nonzero(inl) < 3 or (inl == rows).all():
                break
            rows = inl
        return float(np.sum(np.minimum(r2, cap)))

    def best(ramp: bool) -> tuple[float, int]:
        ks = range(1, n - 1) if ramp else range(min_segment, n - min_segment + 1)
        return min((cost(k, ramp), k) for k in ks)

    (r_step, k_step), (r_drift, k_drift) = best(False), best(True)
    if r_drift < r_step:
        return "drift", k_drift, r_drift / max(r_step, 1e-12)
    return "step", k_step, r_drift / max(r_step, 1e-12)


def ramp_test(v: np.ndarray, use: np.ndarray) -> tuple[int, float, np.ndarray]:
    """The best drift of the implied board deviations ``v`` (N,6) against none: (first view, p-value, last shift).

    For each break ``k`` every coordinate is fitted on the views ``use`` by a constant (no drift) and by a
    constant plus a line from view ``k`` on; the F test of the six slopes (each coordinate against its own
    residual variance) at the best break, its p-value multiplied by the number of breaks tried (Bonferroni).
    ``last shift`` (6,): the drift's displacement at the last view (deg, mm), as ``v``'s coordinates.
    """
    n = len(v)
    idx = np.flatnonzero(use)
    vu = v[idx]
    m = len(idx)
    rss0 = np.sum((vu - vu.mean(axis=0)) ** 2, axis=0)  # shape (6,)
    best = (0, 1.0, np.zeros(6))
    breaks = range(1, n - 1)
    for k in breaks:
        r = np.maximum(np.arange(n) - k + 1.0, 0.0)
        ru = r[idx]
        if np.count_nonzero(ru) < 2:
            continue
        X = np.stack([np.ones(m), ru], axis=1)  # shape (m, 2)
        coef, *_ = np.linalg.lstsq(X, vu, rcond=None)  # shape (2, 6)
        rss1 = np.sum((vu - X @ coef) ** 2, axis=0)
        dof = m - 2
        if dof < 3:
            continue
        F = float(np.sum((rss0 - rss1) / np.maximum(rss1 / dof, 1e-18))) / 6.0
        p = f_sf(F, 6, 6 * dof)
        if p < best[1]:
            best = (k, p, coef[1] * r[-1])
    k, p, shift = best
    return k, min(1.0, p * len(breaks)), shift


def drift_finding(obs: PoseObservations, k: int, share: float, v: np.ndarray) -> Finding:
    """The target pose drifts over the views from view ``k`` on (a tracker's odometry, a creeping board).

    ``v`` (N,6): each view's implied board against the first segment's (deg, mm), as the step test has them.
    """
    last = v[-1]
    tracked = getattr(obs.target, "kind", "") == "tracked"
    what = "The tracker's target pose drifts" if tracked else "The board drifts"
    title = f"{what} from view {obs.ids[k]} on"
    ev = (
        f"the board implied by each view moves steadily from view {obs.ids[k]} on, by "
        f"{float(np.linalg.norm(last[3:])):.1f} mm / {float(np.linalg.norm(last[:3])):.2f} deg at the last view; "
        + (
            f"a gradual drift fits the sequence better than a single move (residual {share:.2f}x a step's)"
            if np.isfinite(share)
            else "no single move explains it; a steady drift does (F test of its slopes)"
        )
    )
    action = (
        "a tracker that accumulates error (visual odometry, SLAM) cannot give the target's pose: locate the "
        "target in every view directly (a marker tracker), or calibrate the views before the drift alone"
        if tracked
        else "the board crept during the collection: fix it rigidly (clamp or tape) and re-capture; if it was "
        "fixed, the robot's reported poses drift instead (the arm warming up, or an arm model whose error grows "
        "along the path): let the arm warm up first, or give its calibrated kinematics"
    )
    return Finding(
        "target_drift",
        "fail",
        title,
        ev,
        action,
        view_ids=tuple(obs.ids[k:]),
        details={
            "drift_from_view": obs.ids[k],
            "residual_vs_step": share if np.isfinite(share) else None,
            "last_mm": float(np.linalg.norm(last[3:])),
        },
    )
