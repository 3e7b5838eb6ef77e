"""X's covariance when the tracker's sigmas are estimated from the views: their degrees of freedom.

The plug-in covariance ``Sigma = inv(J^T W J)`` of a pose-only refinement is the sum of one part per noise
group (rotation; translation across and along the optical axis), ``Sigma_g = s_g^2 Sigma J^T W Q_g W J Sigma``
(``Sigma`` is homogeneous of degree 1 in the variances). Each ``s_g^2`` estimated by variance components
has about as many degrees of freedom as its redundancy ``r_g = s_g^2 tr(Q_g P)``; with the plug-in the Wald
statistic of X is heavier-tailed than chi-square(6): about ``6 F(6, nu)`` with Satterthwaite's ``nu`` over
the parts' shares in X's covariance (:func:`handeye.stats.estimated_noise_region_factor`). The covariance
is returned times the ratio of the 95 % points, so its chi-square(6) ellipsoid and every sigma drawn from
it hold the truth as often as stated. See docs/uncertainty.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from ..stats import estimated_parts_region_factor

#: the tracker's noise groups, in the order of the sigmas
GROUPS = ("rot", "trans", "trans_along")
REGION_P = 0.95


@dataclass(frozen=True)
class NoiseDof:
    """The estimated sigmas' degrees of freedom and the factor each block's plug-in covariance takes."""

    dof: dict[str, float]  # per estimated noise group: its redundancy
    x_dof: Optional[float] = None  # Satterthwaite's for X's covariance; None: every sigma stated
    x_factor: float = 1.0
    board_dof: Optional[float] = None
    board_factor: float = 1.0
    scale_dof: Optional[float] = None  # the tracker's translation scale (13th parameter), when estimated
    scale_factor: float = 1.0


def redundancies(sigma: np.ndarray, Q: np.ndarray, W: np.ndarray, J: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(3,) each group's redundancy ``s_g^2 tr(Q_g P)``, ``P = W - W J S J^T W`` (its diagonal blocks).

    ``sigma`` (3,), ``Q`` (3, n, 6, 6) the groups' unit covariances, ``W`` (n, 6, 6) the views' weights,
    ``J`` (n, 6, p) their Jacobians, ``S`` (p, p) the covariance of the parameters.
    """
    WJ = W @ J
    P = W - WJ @ S @ np.swapaxes(WJ, 1, 2)  # shape (n, 6, 6)
    return sigma**2 * np.einsum("gnij,nji->g", Q, P)


def covariance_parts(sigma: np.ndarray, Q: np.ndarray, W: np.ndarray, J: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(3, p, p) each noise group's part ``Sigma_g`` of the parameters' covariance ``S`` (arguments as above)."""
    WJ = W @ J  # shape (n, 6, p)
    inner = np.einsum("nki,gnkl,nlj->gij", WJ, Q, WJ)  # sum over the views of J^T W Q_g W J
    return sigma[:, None, None] ** 2 * (S[None] @ inner @ S[None])


def _block(S: np.ndarray, parts: np.ndarray, dofs: list[Optional[float]], idx: slice) -> tuple[Optional[float], float]:
    """(nu, factor) of one block of the parameters (``idx``); the rest (a prior) known."""
    return estimated_parts_region_factor(S[idx, idx], [part[idx, idx] for part in parts], dofs, p=REGION_P)


def noise_dof(
    sigma: np.ndarray,
    Q: np.ndarray,
    W: np.ndarray,
    J: np.ndarray,
    S: np.ndarray,
    estimated: Mapping[str, bool],
) -> NoiseDof:
    """The degrees of freedom of the estimated sigmas and the factors of X's, the board's and the scale's blocks.

    X is parameters 0:6, the board 6:12, the tracker's log scale 12 when estimated.

    ``estimated``: group name -> whether its sigma was estimated from the views (an unresolved group's is held,
    as a stated one: known). Arguments as :func:`redundancies`, over the views in the solve.
    """
    red = redundancies(sigma, Q, W, J, S)
    dofs = [float(red[g]) if estimated.get(name, False) else None for g, name in enumerate(GROUPS)]
    if not any(d is not None for d in dofs):
        return NoiseDof({})
    parts = covariance_parts(sigma, Q, W, J, S)
    x_dof, x_factor = _block(S, parts, dofs, slice(0, 6))
    b_dof, b_factor = _block(S, parts, dofs, slice(6, 12))
    s_dof, s_factor = _block(S, parts, dofs, slice(12, 13)) if S.shape[0] > 12 else (None, 1.0)
    dof = {name: d for name, d in zip(GROUPS, dofs, strict=True) if d is not None}
    return NoiseDof(dof, x_dof, x_factor, b_dof, b_factor, s_dof, s_factor)
