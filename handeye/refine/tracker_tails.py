"""A tracker's heavy tails in a pose-only refinement: a multivariate Student-t per view.

A tracker that now and then spoils a whole pose (a poor detection) has noise ``n_i = z_i / sqrt(g_i)``,
``z_i ~ N(0, Sigma_i)``, ``g_i ~ chi2(nu) / nu``: per view a scale mixture of Gaussians. Its likelihood
is maximised by EM: each view's covariance divided by the weight ``w_i = (nu + 6) / (nu + m2_i)`` (``m2_i``
its squared Mahalanobis residual at the tracker's sigmas), the sigmas re-estimated on the weighted views.
``nu`` is chosen by the profile likelihood over :data:`DOF_GRID` (infinity: Gaussian, every weight 1). The
parameters' covariance is the t model's inverse Fisher information, ``(nu + 8) / (nu + 6)`` times the
inverse of the weighted normal matrix (``E[w_i] = 1``). Also the start sigmas from the median residuals,
which a few spoilt views do not move. See docs/uncertainty.md.
"""

from __future__ import annotations

import math

import numpy as np

from ..special import chdtri

#: the tracker's tail degrees of freedom tried (inf: Gaussian). Not below 5: the robot-pose test's null is
#: this t, and at its alpha (1e-4) a t(3) accepts a view 35 sigma off (m2 1240; t(5): 16 sigma, 268), so
#: two gross errors in 20 views would pass as tails, never named
DOF_GRID = (5.0, 10.0, 20.0, float("inf"))
DIM = 6  # a pose residual's dimension
#: a t replaces the Gaussian when its log-likelihood is higher by more than this: the likelihood-ratio test of
#: the Gaussian (nu infinite, on the boundary: the statistic is 0 or chi-square(1) with even odds) at 5 %
TAIL_TEST_ALPHA = 0.05
TAIL_TEST_LL = 0.5 * float(chdtri(1, 2.0 * TAIL_TEST_ALPHA))
#: median of |x| for x ~ N(0, s^2 I3), N(0, s^2 I2) and N(0, s^2), in units of s
NORM3_MEDIAN = float(np.sqrt(chdtri(3, 0.5)))
NORM2_MEDIAN = float(np.sqrt(chdtri(2, 0.5)))
NORM1_MEDIAN = float(np.sqrt(chdtri(1, 0.5)))


def t_weights(m2: np.ndarray, nu: float) -> np.ndarray:
    """(n,) each view's EM weight ``(nu + 6) / (nu + m2_i)`` (1 for the Gaussian, ``nu`` infinite)."""
    m2 = np.asarray(m2, float)
    return np.ones_like(m2) if not np.isfinite(nu) else (nu + DIM) / (nu + m2)


def log_likelihood(m2: np.ndarray, logdet: np.ndarray, nu: float) -> float:
    """The views' log-likelihood under a multivariate t with ``nu`` degrees of freedom (inf: Gaussian).

    ``m2`` (n,) the squared Mahalanobis residuals and ``logdet`` (n,) the log-determinants of the views'
    (unweighted) covariances.
    """
    m2, logdet = np.asarray(m2, float), np.asarray(logdet, float)
    if not np.isfinite(nu):
        return float(np.sum(-0.5 * DIM * np.log(2.0 * np.pi) - 0.5 * logdet - 0.5 * m2))
    c = math.lgamma(0.5 * (nu + DIM)) - math.lgamma(0.5 * nu) - 0.5 * DIM * np.log(nu * np.pi)
    return float(np.sum(c - 0.5 * logdet - 0.5 * (nu + DIM) * np.log1p(m2 / nu)))


def choose_dof(m2: np.ndarray, logdet: np.ndarray) -> tuple[float, np.ndarray]:
    """(nu, weights (n,)): the tail degrees of freedom the views' Gaussian residuals call for.

    ``m2`` (n,) the squared Mahalanobis residuals of a Gaussian solve and ``logdet`` (n,) the log-determinants
    of its views' covariances. Per ``nu`` of :data:`DOF_GRID` the profile likelihood over a common scale ``c``
    of the covariances (EM: ``w_i = t_weights(m2_i / c)``, ``c = sum w_i m2_i / (6 n)``; the Gaussian's
    ``c = mean(m2) / 6``) at these residuals; a t is chosen when its log-likelihood exceeds the Gaussian's by
    more than :data:`TAIL_TEST_LL`, the largest such. ``weights``: the chosen t's EM weights (ones for the
    Gaussian).
    """
    m2, logdet = np.asarray(m2, float), np.asarray(logdet, float)
    n = len(m2)
    c = max(float(np.mean(m2)) / DIM, 1e-300)
    best = (log_likelihood(m2 / c, logdet + DIM * np.log(c), float("inf")) + TAIL_TEST_LL, float("inf"), np.ones(n))
    for nu in DOF_GRID:
        if not np.isfinite(nu):
            continue
        c_t = c
        for _ in range(200):  # EM on the scale: monotone, a few tens of steps
            w = t_weights(m2 / c_t, nu)
            c_new = float(np.sum(w * m2)) / (DIM * n)
            done = abs(c_new / c_t - 1.0) < 1e-8
            c_t = c_new
            if done:
                break
        ll = log_likelihood(m2 / c_t, logdet + DIM * np.log(c_t), nu)
        if ll > best[0]:
            best = (ll, nu, t_weights(m2 / c_t, nu))
    return best[1], best[2]


def information_factor(nu: float) -> float:
    """``(nu + 8) / (nu + 6)``: the t model's covariance over the weighted normal matrix's inverse (1: Gaussian)."""
    return 1.0 if not np.isfinite(nu) else (nu + DIM + 2.0) / (nu + DIM)


def camera_translations(C: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(n, 3) the residuals' translations in the camera frame (``r`` (n,6) in the target's)."""
    return -np.einsum("nij,nj->ni", C[:, :3, :3], r[:, 3:])


def robust_sigmas(C: np.ndarray, r: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """(rotation, across, along the optical axis) sigmas from the median residuals (Gaussian in each)."""
    t = camera_translations(C, r)
    med = np.array(
        [
            np.median(np.linalg.norm(r[:, :3], axis=1)) / NORM3_MEDIAN,
            np.median(np.linalg.norm(t[:, :2], axis=1)) / NORM2_MEDIAN,
            np.median(np.abs(t[:, 2])) / NORM1_MEDIAN,
        ]
    )
    return np.maximum(med, floors)
