"""A drifting target: the implied board moving steadily from one view on, told apart from a single move.

When the step test of :mod:`.consistency` finds the board moved, :func:`drift_or_step` fits a step and a
drift (a line from one view on) to the implied boards with the same number of parameters; the better
fit names the finding (:func:`drift_finding` for a drift). See docs/diagnostics.md.
"""

from __future__ import annotations

import numpy as np

from .findings import Finding
from .observations import PoseObservations


def _break_fit(v: np.ndarray, k: int, *, ramp: bool) -> np.ndarray:
    """(N,6) the best fit to ``v`` (N,6) of zero before view ``k`` and a step or a drift from ``k`` on.

    The step is a constant from view ``k`` on; the drift a line through zero at view ``k - 1``.
    """
    n = len(v)
    x = np.where(np.arange(n) >= k, (np.arange(n) - k + 1.0) if ramp else 1.0, 0.0)  # shape (N,)
    slope = (x @ v) / max(float(x @ x), 1e-12)  # shape (6,)
    return x[:, None] * slope[None, :]


def drift_or_step(v: np.ndarray, use: np.ndarray, *, min_segment: int) -> tuple[str, int, float]:
    """Whether the implied board deviations ``v`` (N,6) change in one step or drift.

    Returns ("step" | "drift", the first view that moved, the drift's residual share of the step's). Both
    models have the same parameters (a break and six numbers), so the one with the smaller weighted
    residual over the views ``use`` (each coordinate scaled by its robust spread) explains the sequence.
    """
    n = len(v)
    w = 1.0 / np.maximum(np.median(np.abs(v[use] - np.median(v[use], axis=0)), axis=0), 1e-9)

    def best(ramp: bool) -> tuple[float, int]:
        ks = range(1, n - 1) if ramp else range(min_segment, n - min_segment + 1)
        rss = [(float(np.sum((((v - _break_fit(v, k, ramp=ramp)) * w)[use]) ** 2)), k) for k in ks]
        return min(rss)

    (r_step, k_step), (r_drift, k_drift) = best(False), best(True)
    if r_drift < r_step:
        return "drift", k_drift, r_drift / max(r_step, 1e-12)
    return "step", k_step, r_drift / max(r_step, 1e-12)


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
        f"a gradual drift fits the sequence better than a single move (residual {share:.2f}x a step's)"
    )
    action = (
        "a tracker that accumulates error (visual odometry, SLAM) cannot give the target's pose: locate the "
        "target in every view directly (a marker tracker), or calibrate the views before the drift alone"
        if tracked
        else "the board crept during the collection: fix it rigidly (clamp or tape) and re-capture"
    )
    return Finding(
        "target_drift",
        "fail",
        title,
        ev,
        action,
        view_ids=tuple(obs.ids[k:]),
        details={"drift_from_view": obs.ids[k], "residual_vs_step": share, "last_mm": float(np.linalg.norm(last[3:]))},
    )
