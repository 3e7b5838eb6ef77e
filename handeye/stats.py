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
