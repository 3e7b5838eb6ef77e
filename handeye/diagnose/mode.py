"""The mounting mode from the data: both models ``C_i = A · M_i · B`` fitted, each with its own board scale.

Eye-in-hand uses ``M_i = inv(T_base_end_i)``, eye-to-hand ``M_i = T_base_end_i``. Pair invariants (rotation
angle, screw pitch) are the same for both, so only the full fit tells them apart: the rotation axes of
the camera's pair motions must map onto the robot's by one rotation. Each model is fitted after
rescaling the camera translations by that model's scale estimate (:mod:`.scale`), so a wrong square
size does not make the mode undecided. A mode is decided only when its model fits (cost below
``mode.good_cost``), the other fits ``mode.ratio`` times worse, and the solution is physically plausible
(a camera on the flange is closer to the flange than the board is to the base; a camera beside the
robot farther from the base than the board from the flange). Otherwise the mode is undecided.
:func:`swapped_mode` is the diagnostics' own mode-swap test (:mod:`.readings`), which a calibration without a
stated mode also asks, so the mode it calibrates in is never one the diagnostics then refuse.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..frames import inv_T
from ..mounting import MODES, mounting
from .fits import fit_boards
from .scale import estimate_scale, rescaled
from .thresholds import thresholds

__all__ = ["ModeEvidence", "mode_evidence", "swapped_mode"]


@dataclass(frozen=True)
class ModeEvidence:
    costs: dict  # mode -> cost of its fit (inf when it could not be fitted)
    scatter: dict  # mode -> (median board scatter deg, mm)
    plausible: dict  # mode -> the solution puts the camera where the mode says
    best: str
    decided: Optional[str]  # the mode the data show, or None (undecided)

    @property
    def ratio(self) -> float:
        other = mounting(self.best).other.name
        c_best, c_other = self.costs[self.best], self.costs[other]
        return float(c_other / c_best) if c_best > 0 else float("inf")

    def summary(self) -> str:
        parts = []
        for m in MODES:
            d, mm = self.scatter.get(m, (float("nan"), float("nan")))
            parts.append(f"{m}: board scatter {d:.2f} deg / {mm:.1f} mm (cost {self.costs[m]:.2f})")
        txt = "; ".join(parts)
        if self.decided is None:
            return (
                txt
                + f"; undecided (ratio {self.ratio:.1f}, needs {thresholds().mode.ratio:g}"
                + (", and a plausible camera position" if not self.plausible.get(self.best, False) else "")
                + ")"
            )
        return txt + f"; {self.decided} fits {self.ratio:.1f} x better"

    def to_dict(self) -> dict:
        return {
            "costs": {m: _finite(c) for m, c in self.costs.items()},
            "board_scatter": {m: [_finite(a), _finite(b)] for m, (a, b) in self.scatter.items()},
            "plausible": dict(self.plausible),
            "best": self.best,
            "decided": self.decided,
            "ratio": _finite(self.ratio),
            "summary": self.summary(),
        }


def _finite(x):
    x = float(x)
    return round(x, 4) if np.isfinite(x) else None


def _camera_on_robot(fit) -> bool:
    t_x = float(np.linalg.norm(inv_T(fit.A)[:3, 3]))
    t_b = float(np.linalg.norm(fit.B[0][:3, 3]))
    return t_x < t_b


def mode_evidence(C: np.ndarray, T_base_end: np.ndarray, *, C_candidates: Optional[np.ndarray] = None) -> ModeEvidence:
    """Both mounting models fitted to board poses ``C`` (N,4,4) and robot poses ``T_base_end`` (N,4,4).

    ``C_candidates`` (N,2,4,4): a single marker's two planar poses per view. Which of them the robot motion
    picks depends on the model (:func:`handeye.initial.board_poses.rotation_consistent_labels`), so each
    model is fitted with its own picks, as the readings are (``C`` was picked under one mode only).
    """
    t = thresholds().mode
    costs, scatter, plausible = {}, {}, {}
    for m in MODES:
        mount = mounting(m)
        M = mount.M_from_T_base_end(T_base_end)
        try:
            if C_candidates is not None:
                C = _picked(C_candidates, M)
            fit0 = fit_boards(C, M)
            est = estimate_scale(C, M, use=fit0.inliers())
            fit = fit_boards(rescaled(C, est.k), M) if est is not None and np.isfinite(est.k) and est.k > 0 else fit0
        except np.linalg.LinAlgError:
            costs[m], scatter[m], plausible[m] = float("inf"), (float("nan"), float("nan")), False
            continue
        costs[m] = fit.cost
        scatter[m] = (fit.median_rot_deg, fit.median_trans_mm)
        plausible[m] = _camera_on_robot(fit) == mount.camera_moves
    best = min(MODES, key=lambda m: costs[m])
    other = mounting(best).other.name
    clear = costs[best] < t.good_cost and costs[other] > t.ratio * costs[best] and plausible[best]
    return ModeEvidence(costs, scatter, plausible, best, best if clear else None)


def _picked(C_candidates: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(N,4,4) each view's planar pose that the robot motions ``M`` pick under their model."""
    from ..initial.board_poses import candidate_invariants, orientation_labels, rotation_consistent_labels

    lab = orientation_labels(candidate_invariants(C_candidates), M, turns=False)
    lab = rotation_consistent_labels(C_candidates, M, lab)
    return C_candidates[np.arange(len(C_candidates)), lab]


def swapped_mode(obs) -> Optional[tuple[str, str]]:
    """(the other mode, the finding's evidence) when the diagnostics' mode-swap finding fires, else None.

    ``obs``: :class:`.observations.PoseObservations` read in ``obs.mode``. The test is the diagnostics' own
    (:func:`.readings.evaluate_readings`, :func:`.readings.reading_findings`): the poses as read fit badly,
    the inverted motions fit clearly better, and the solution puts the camera where the other mode says.
    """
    from .readings import evaluate_readings, given_reading, reading_findings

    readings = evaluate_readings(obs)
    if given_reading(readings) is None:
        return None
    for f in reading_findings(obs, readings):
        if f.code == "mode_swapped":
            return mounting(obs.mode).other.name, f.evidence
    return None
