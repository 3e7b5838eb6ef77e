"""Robust fits of ``C_i = A · M_i · B`` from the view pairs, one board per group of views.

What the pose checks compare: a reading of the robot poses, a pairing of images and poses, or a
split of the sequence into two boards is judged by how much the board implied by each view
(``B_i = inv(A M_i) C_i``) scatters around the fitted one (:attr:`BoardFit.cost`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .geometry import A_from_sums, PairMotions, implied_boards, pair_motions, pose_differences, robust_mean_T
from .thresholds import thresholds


@dataclass(frozen=True)
class BoardFit:
    A: np.ndarray  # (4,4)
    B: np.ndarray  # (G,4,4) one board per group
    labels: np.ndarray  # (N,) group of each view
    board_rot_deg: np.ndarray  # (N,) implied board vs its group's board
    board_trans_mm: np.ndarray  # (N,)
    median_rot_deg: float
    median_trans_mm: float

    @property
    def cost(self) -> float:
        """hypot(median scatter / cost_deg, / cost_mm) (configs/diagnostics.yaml readings)."""
        return float(thresholds().cost(self.median_rot_deg, self.median_trans_mm))

    def view_costs(self) -> np.ndarray:
        """(N,) each view's implied-board deviation on the cost scale."""
        return thresholds().cost(self.board_rot_deg, self.board_trans_mm)

    def inliers(self) -> np.ndarray:
        """(N,) views whose implied board is within ``inlier_factor`` x the median deviation (at least 3)."""
        d = self.view_costs()
        keep = d <= max(thresholds().robot_pose.inlier_factor * float(np.median(d)), 0.05)
        return keep if keep.sum() >= 3 else np.ones(len(d), bool)

    def group_index(self) -> np.ndarray:
        """(N,) index into ``B`` of each view's board."""
        return np.searchsorted(np.unique(self.labels), self.labels)


def fit_boards(
    C: np.ndarray,
    M: np.ndarray,
    *,
    labels: Optional[np.ndarray] = None,
    use: Optional[np.ndarray] = None,
    robust: bool = True,
    motions: Optional[PairMotions] = None,
) -> BoardFit:
    """Park & Martin on all pairs within a group (among views in ``use``), one board per group.

    ``C`` (N,4,4) board poses ``T_cam_board``, ``M`` (N,4,4) robot motions. ``robust``: refit twice
    without the views whose implied board is more than 3x the median deviation away, so a minority of
    wrong views does not tilt the fit of the others. ``motions``: the pairs' relative motions of these
    ``C`` and ``M`` when the caller fits them several times (default: computed here). Raises LinAlgError for
    a degenerate set.
    """
    th = thresholds()
    n = len(C)
    labels = np.zeros(n, int) if labels is None else np.asarray(labels)
    use0 = np.ones(n, bool) if use is None else np.asarray(use, bool)
    use = use0.copy()
    motions = pair_motions(C, M) if motions is None else motions
    i, j = motions.i, motions.j
    groups = np.unique(labels)
    gi = np.searchsorted(groups, labels)
    same_group = labels[i] == labels[j]
    for rnd in range(3 if robust else 1):
        n_sel = int(np.count_nonzero(same_group & use[i] & use[j]))
        if n_sel < 3:
            if rnd == 0:
                raise np.linalg.LinAlgError(f"only {n_sel} view pairs to fit (needs 3)")
            break
        A = A_from_sums(motions.group_sums(labels, use))
        Bs = implied_boards(A, C, M)
        B = np.stack(
            [robust_mean_T(Bs[(labels == g) & use] if ((labels == g) & use).sum() else Bs[labels == g]) for g in groups]
        )
        rot, trans = pose_differences(B[gi], Bs)
        d = th.cost(rot, trans)
        if float(np.median(d[use0])) > 10.0 * th.readings.bad_cost:
            break  # hopeless: refitting without wild views cannot rescue this model
        new_use = use0 & (d <= max(3.0 * float(np.median(d[use0])), 0.05))
        if rnd == 2 or np.array_equal(new_use, use) or new_use.sum() < max(3, 0.5 * use0.sum()):
            break
        use = new_use
    return BoardFit(A, B, labels, rot, trans, float(np.median(rot[use0])), float(np.median(trans[use0])))
