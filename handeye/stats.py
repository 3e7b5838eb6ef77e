"""Small robust statistics shared by the refinement and the diagnostics (pure numpy/scipy.special)."""
from __future__ import annotations

import numpy as np
from scipy.special import chdtri

RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))  # median of |e| / sigma for a 2-D Gaussian


def robust_noise_sigma(d: np.ndarray, C: np.ndarray, *, floor: float, shape: np.ndarray | None = None) -> float:
    """Sigma s with median_i d_i^T (C_i + s^2 B_i)^-1 d_i = chi2(dim) median: the extra noise that makes
    typical views' disagreements ``d`` (N,k) consistent with their covariances ``C`` (N,k,k); ``shape``
    B (N,k,k) is its covariance at s = 1 (None: isotropic, I)."""
    k = d.shape[1]
    target = float(chdtri(k, 0.5))  # the chi-square(k) median
    B = np.eye(k) if shape is None else np.asarray(shape, float)

    def med(s):
        Cs = C + s * s * B
        return np.median(np.einsum("ni,ni->n", d, np.linalg.solve(Cs, d[..., None])[..., 0]))

    if med(floor) <= target:
        return floor
    lo, hi = np.log(floor), np.log(10.0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if med(np.exp(mid)) > target:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))


# ------------------------------------------------------------------------------ heavy-tailed residuals
# Degrees of freedom tried for the scale-mixture (multivariate t) model of a residual's spread; inf is
# the Gaussian. The test is matched to an estimated variance, and a variance estimate is only stable when
# the fourth moment exists (dof > 4): heavier tails than that are not a model the covariance could carry.
TAIL_DOF_GRID = (5.0, 6.0, 8.0, 10.0, 13.0, 17.0, 22.0, 30.0, 45.0, 70.0, 120.0, np.inf)
# fewer statistics than this say nothing about the shape of a tail (the likelihood-ratio test of a t against
# the Gaussian has next to no power on fewer, and its 5 % false calls would be extreme dofs): Gaussian
MIN_TAIL_BODY = 12
TAIL_LR_CRITICAL = float(chdtri(1, 0.10))  # 2.71: 5 % test of the Gaussian, a boundary point of the dof


def _variance_match(nu: float) -> float:
    """``a`` with ``statistic * a / dim ~ F(dim, nu)`` when the statistic is taken under the covariance of
    the t distribution (``nu / (nu - 2)`` times its scale matrix), as an estimated covariance is."""
    return 1.0 if not np.isfinite(nu) else nu / (nu - 2.0)


def mixture_tail_pvalue(statistic: np.ndarray, dim: int, dof: np.ndarray) -> np.ndarray:
    """P(statistic' > statistic) for squared Mahalanobis distances ``statistic`` (n,) of ``dim``-vectors
    under their covariance, when the vector is multivariate t with ``dof`` (n,; inf: Gaussian, chi-square)."""
    from scipy.special import chdtrc, fdtrc

    s = np.asarray(statistic, float)
    nu = np.broadcast_to(np.asarray(dof, float), s.shape)
    out = chdtrc(dim, np.where(np.isfinite(s), s, 0.0))
    fin = np.isfinite(nu)
    if fin.any():
        a = nu[fin] / (nu[fin] - 2.0)
        out[fin] = fdtrc(dim, nu[fin], np.where(np.isfinite(s[fin]), s[fin], 0.0) * a / dim)
    return np.where(np.isfinite(s), out, np.nan)


def mixture_tail_quantile(p: float, dim: int, dof: np.ndarray) -> np.ndarray:
    """The statistic exceeded with probability ``p`` under :func:`mixture_tail_pvalue`'s model (per dof)."""
    from scipy.special import fdtri

    nu = np.asarray(dof, float)
    out = np.full(nu.shape, float(chdtri(dim, p)))
    fin = np.isfinite(nu)
    out[fin] = dim * fdtri(dim, nu[fin], 1.0 - p) / (nu[fin] / (nu[fin] - 2.0))
    return out


def leave_one_out_tail_dof(statistic: np.ndarray, body: np.ndarray, *, dim: int, cut: float) -> np.ndarray:
    """Each row's degrees of freedom of the scale-mixture (multivariate t) model, estimated from the OTHER
    rows' statistics (squared Mahalanobis distances of ``dim``-vectors under their estimated covariance).

    Only rows in ``body`` with a statistic below ``cut`` inform it: a gross error beyond ``cut`` can
    neither make the tail look heavier nor mask another. The shape of their distribution decides, not its
    scale: the t (dof over :data:`TAIL_DOF_GRID`) and the Gaussian (chi-square) are each fitted with a free
    scale by maximum likelihood of the truncated distribution, and the t's dof is taken only when the
    likelihood-ratio test rejects the Gaussian at 5 % (otherwise inf; ties go to the larger dof). A
    covariance that is merely too large or too small (a noise estimate not yet converged) is thus not read
    as a heavy tail; the test itself keeps the covariance's scale (:func:`mixture_tail_pvalue`). Fewer than
    :data:`MIN_TAIL_BODY` other rows: inf (Gaussian)."""
    from scipy.special import chdtr, fdtr
    from scipy.stats import chi2, f

    s = np.asarray(statistic, float)
    n = s.shape[0]
    inb = np.asarray(body, bool) & np.isfinite(s) & (s < cut)
    x = s[inb]
    if inb.sum() - 1 < MIN_TAIL_BODY:
        return np.full(n, np.inf)
    c = np.exp(np.linspace(np.log(0.05), np.log(20.0), 121))[:, None]  # scale of the statistic, relative
    L = np.empty((len(TAIL_DOF_GRID), len(c), len(x)))  # log-likelihood of each body value per dof and scale
    for g, nu in enumerate(TAIL_DOF_GRID):
        if np.isfinite(nu):
            a = _variance_match(nu) / (dim * c)
            L[g] = f.logpdf(x[None, :] * a, dim, nu) + np.log(a) - np.log(fdtr(dim, nu, cut * a))
        else:
            L[g] = chi2.logpdf(x[None, :] / c, dim) - np.log(c) - np.log(chdtr(dim, cut / c))
    total = L.sum(axis=2)
    grid = np.asarray(TAIL_DOF_GRID)
    out = np.full(n, np.inf)
    pos = np.cumsum(inb) - 1  # a body row's column in L
    for i in range(n):
        if inb[i] and inb.sum() - 1 < MIN_TAIL_BODY:
            continue
        prof = (total - L[:, :, pos[i]] if inb[i] else total).max(axis=1)  # each dof at its best scale
        # Gaussian unless the body rejects it: likelihood-ratio test at 5 % (dof = inf lies on the boundary
        # of the parameter space, so the statistic is a 50:50 mixture of 0 and chi-square(1): 2.71)
        if 2.0 * (prof.max() - prof[-1]) < TAIL_LR_CRITICAL:
            continue
        best = np.flatnonzero(prof >= prof.max() - 1e-9)
        out[i] = grid[best[-1]]
    return out
