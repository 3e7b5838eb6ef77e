"""Small robust statistics shared by the refinement and the diagnostics (pure numpy/scipy)."""
from __future__ import annotations

import numpy as np


def robust_noise_sigma(d: np.ndarray, C: np.ndarray, *, floor: float) -> float:
    """Sigma s with median_i d_i^T (C_i + s^2 I)^-1 d_i = chi2(dim) median: the extra isotropic noise that
    makes typical views' disagreements ``d`` (N,k) consistent with their covariances ``C`` (N,k,k)."""
    from scipy.stats import chi2 as _chi2  # scipy.stats is slow to import; only here

    k = d.shape[1]
    target = _chi2.ppf(0.5, k)

    def med(s):
        Cs = C + s * s * np.eye(k)
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
