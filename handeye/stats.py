"""Small statistics shared by the refinement, the diagnostics and the recalibration tests (pure numpy)."""

from __future__ import annotations

import math

import numpy as np

from .special import chdtrc, chdtri, fdtrc, fdtri, gammaincinv, vectorised

RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))  # median of |e| / sigma for a 2-D Gaussian
_chdtrc, _fdtrc, _fdtri = vectorised(chdtrc), vectorised(fdtrc), vectorised(fdtri)  # over arrays


# ------------------------------------------------------------------------------ chi-square and F
# What scipy.stats.chi2 and scipy.stats.f evaluate, with rv_continuous's rules at the edges, from
# handeye.special (scipy.special's functions, to about 1e-11 relative): neither scipy.stats nor scipy.special
# is imported, which would cost 0.2-0.5 s of every calibration's start-up.
def chi2_sf(x: float, df: float) -> float:
    """``scipy.stats.chi2.sf(x, df)``: P(chi-square(df) > x)."""
    x, df = float(x), float(df)
    if not df > 0 or math.isnan(x):
        return math.nan
    if x <= 0:
        return 1.0
    return 0.0 if x == math.inf else float(chdtrc(df, x))


def chi2_ppf(q: float, df: float) -> float:
    """``scipy.stats.chi2.ppf(q, df)``: the chi-square(df) quantile of probability ``q``."""
    q, df = float(q), float(df)
    if not df > 0 or not 0 <= q <= 1:
        return math.nan
    if q == 0:
        return 0.0
    return math.inf if q == 1 else float(2 * gammaincinv(df / 2, q))


def f_sf(x: float, dfn: float, dfd: float) -> float:
    """``scipy.stats.f.sf(x, dfn, dfd)``: P(F(dfn, dfd) > x)."""
    x, dfn, dfd = float(x), float(dfn), float(dfd)
    if not (dfn > 0 and dfd > 0) or math.isnan(x):
        return math.nan
    if x <= 0:
        return 1.0
    return 0.0 if x == math.inf else float(fdtrc(dfn, dfd, x))


def robust_noise_sigma(d: np.ndarray, C: np.ndarray, *, floor: float, shape: np.ndarray | None = None) -> float:
    """Extra noise sigma that makes typical views' disagreements consistent with their covariances.

    Sigma s with median_i d_i^T (C_i + s^2 B_i)^-1 d_i = chi2(dim) median: the extra noise that makes
    typical views' disagreements ``d`` (N,k) consistent with their covariances ``C`` (N,k,k); ``shape``
    B (N,k,k) is its covariance at s = 1 (None: isotropic, I).
    """
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
# A multivariate t with nu dof whose covariance (nu / (nu - 2) times its scale matrix) is the one the
# statistic was taken under: statistic * (nu / (nu - 2)) / dim ~ F(dim, nu).
def mixture_tail_pvalue(statistic: np.ndarray, dim: int, dof: np.ndarray) -> np.ndarray:
    """P(statistic' > statistic) for squared Mahalanobis distances ``statistic``.

    P(statistic' > statistic) for squared Mahalanobis distances ``statistic`` (n,) of ``dim``-vectors
    under their covariance, when the vector is multivariate t with ``dof`` (n,; inf: Gaussian, chi-square).
    """
    s = np.asarray(statistic, float)
    nu = np.broadcast_to(np.asarray(dof, float), s.shape)
    out = np.asarray(_chdtrc(dim, np.where(np.isfinite(s), s, 0.0)), float).copy()
    fin = np.isfinite(nu)
    if fin.any():
        a = nu[fin] / (nu[fin] - 2.0)
        out[fin] = _fdtrc(dim, nu[fin], np.where(np.isfinite(s[fin]), s[fin], 0.0) * a / dim)
    return np.where(np.isfinite(s), out, np.nan)


def mixture_tail_quantile(p: float, dim: int, dof: np.ndarray) -> np.ndarray:
    """The statistic exceeded with probability ``p`` under :func:`mixture_tail_pvalue`'s model (per dof)."""
    nu = np.asarray(dof, float)
    out = np.full(nu.shape, float(chdtri(dim, p)))
    fin = np.isfinite(nu)
    out[fin] = dim * _fdtri(dim, nu[fin], 1.0 - p) / (nu[fin] / (nu[fin] - 2.0))
    return out


def wald_p_value(T: float, dof: int, noise_dof: float | None = None) -> float:
    """P-value of the Wald statistic ``T`` with ``dof`` directions.

    Chi-square(dof) when the covariances are known; when they rest on a robot noise level estimated with
    ``noise_dof`` degrees of freedom (the plug-in variance makes the statistic heavier-tailed, as Hotelling's
    T^2), ``T / dof`` is taken as F(dof, noise_dof).
    """
    if not dof:
        return 1.0
    if noise_dof is None or not np.isfinite(noise_dof) or noise_dof <= 0:
        return chi2_sf(T, dof)
    return f_sf(T / dof, dof, noise_dof)


def satterthwaite_dof(shares, dofs) -> float | None:
    """Degrees of freedom of a variance that is the sum of parts with ``shares``.

    Degrees of freedom of a variance that is the sum of parts with ``shares`` (summing to 1) each estimated
    with ``dofs`` (None or inf: known): ``1 / sum(share^2 / dof)`` (Satterthwaite 1946); None when every part
    is known.
    """
    s = sum(
        float(a) ** 2 / float(n)
        for a, n in zip(shares, dofs, strict=False)
        if n is not None and np.isfinite(n) and n > 0
    )
    return 1.0 / s if s > 0 else None


def estimated_noise_region_factor(shares, dofs, *, dim: int, p: float = 0.95) -> tuple[float | None, float]:
    """(nu, factor) of a ``dim``-vector's ``p`` region when its covariance rests on estimated noise levels.

    The covariance is the sum of parts with ``shares`` (summing to 1), each from a noise level estimated with
    ``dofs`` (None or inf: known). With the plug-in covariance the Wald statistic is about ``dim F(dim, nu)``
    with Satterthwaite's ``nu`` (:func:`satterthwaite_dof`) rather than chi-square(dim); ``factor`` is its
    ``p`` point over chi-square's: the plug-in covariance times ``factor`` has chi-square's ``p`` region
    right. (None, 1.0) when every part is known.
    """
    nu = satterthwaite_dof(shares, dofs)
    if nu is None:
        return None, 1.0
    return nu, float(dim * fdtri(dim, nu, p)) / chi2_ppf(p, dim)


def estimated_parts_region_factor(cov, parts, dofs, *, p: float = 0.95) -> tuple[float | None, float]:
    """(nu, factor) of :func:`estimated_noise_region_factor` for a covariance ``cov`` (k,k) split into parts.

    Each of ``parts`` ((k,k) each, from a noise level estimated with the matching ``dofs`` entry; None: known)
    has the share ``tr(cov^-1 part) / k``; what the parts leave of ``cov`` (priors, well-known noise) is known.
    """
    cov = np.asarray(cov, float)
    k = cov.shape[0]
    shares = [float(np.trace(np.linalg.solve(cov, part))) / k for part in parts]
    shares.append(max(1.0 - sum(shares), 0.0))
    return estimated_noise_region_factor(shares, list(dofs) + [None], dim=k, p=p)


def weighted_chi2_sf(x: float, weights) -> tuple[float, float]:
    """Tail probability at ``x`` of ``sum w_i z_i^2``.

    Tail probability at ``x`` of ``sum w_i z_i^2`` (z_i iid N(0, 1), weights w_i >= 0) by Satterthwaite's
    scaled chi-square ``c * chi2(nu)`` with the same mean and variance: ``c = sum w^2 / sum w``,
    ``nu = (sum w)^2 / sum w^2``. Returns (p, nu). Plain chi2(sum w) would overstate the spread when weights are
    below 1 (its variance is 2 sum w, the form's 2 sum w^2), and so the p-values.
    """
    w = np.clip(np.asarray(weights, float).reshape(-1), 0.0, None)
    s1, s2 = float(w.sum()), float(np.sum(w**2))
    if s1 <= 0.0 or s2 <= 0.0:
        return (1.0 if x <= 0 else 0.0), 0.0
    c, nu = s2 / s1, s1**2 / s2
    return chi2_sf(x / c, nu), nu
