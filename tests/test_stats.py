"""handeye.stats: the chi-square and F tails (through handeye.special) are scipy.stats' values to 1e-10."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from handeye.stats import chi2_ppf, chi2_sf, estimated_noise_region_factor, f_sf, wald_p_value, weighted_chi2_sf

XS = [-1.0, 0.0, 1e-300, 1e-8, 0.3, 1.0, 2.5, 6.0, 17.3, 120.0, 1e4, math.inf, math.nan]
DFS = [-1.0, 0.0, 0.4, 1.0, 2.0, 3.0, 5.5, 6.0, 30.0, 1e3, math.nan]
QS = [-0.1, 0.0, 1e-12, 0.001, 0.025, 0.5, 0.95, 0.999, 1 - 1e-12, 1.0, 1.1, math.nan]


def _same(a: float, b, rel: float = 1e-10) -> bool:
    """The same value: both NaN, equal (infinities, zeros), or within ``rel`` relative (below 1e-300: both tiny)."""
    b = float(b)
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if a == b:
        return True
    if math.isinf(a) or math.isinf(b):
        return False
    return abs(a - b) <= rel * abs(b) or max(abs(a), abs(b)) < 1e-300


def test_chi2_sf_and_ppf_are_scipy_stats_values():
    bad = [(x, df) for x, df in itertools.product(XS, DFS) if not _same(chi2_sf(x, df), stats.chi2.sf(x, df))]
    assert bad == []
    bad = [(q, df) for q, df in itertools.product(QS, DFS) if not _same(chi2_ppf(q, df), stats.chi2.ppf(q, df))]
    assert bad == []
    assert abs(chi2_ppf(0.95, 1) - 1.959963984540054**2) < 1e-12  # the familiar 1.96 sigma
    assert chi2_sf(chi2_ppf(0.95, 6), 6) == pytest.approx(0.05, rel=1e-12)


def test_f_sf_is_scipy_stats_value():
    bad = [
        (x, a, b)
        for x, a, b in itertools.product(XS, DFS[::2], DFS[1::2])
        if not _same(f_sf(x, a, b), stats.f.sf(x, a, b))
    ]
    assert bad == []


def test_wald_and_weighted_tails_keep_their_values():
    assert _same(wald_p_value(7.0, 3), stats.chi2.sf(7.0, 3))
    assert _same(wald_p_value(7.0, 3, noise_dof=12.0), stats.f.sf(7.0 / 3, 3, 12.0))
    w = np.array([1.0, 0.5, 0.25])
    c, nu = float(np.sum(w**2) / w.sum()), float(w.sum() ** 2 / np.sum(w**2))
    p, got_nu = weighted_chi2_sf(2.0, w)
    assert _same(p, stats.chi2.sf(2.0 / c, nu)) and got_nu == nu


def test_the_region_factor_of_estimated_noise_is_f_over_chi_square():
    # one part estimated with nu degrees of freedom: the Wald statistic is dim F(dim, nu) exactly
    for dim, nu in ((6, 17.0), (1, 10.0), (3, 60.0)):
        got_nu, k = estimated_noise_region_factor([1.0], [nu], dim=dim)
        assert got_nu == nu
        assert k == pytest.approx(dim * stats.f.ppf(0.95, dim, nu) / stats.chi2.ppf(0.95, dim), rel=1e-12)
    # one dimension: the Student t interval over the normal one
    assert estimated_noise_region_factor([1.0], [10.0], dim=1)[1] == pytest.approx(
        (stats.t.ppf(0.975, 10) / stats.norm.ppf(0.975)) ** 2, rel=1e-12
    )
    # fewer degrees of freedom, a larger region; known parts carry none
    ks = [estimated_noise_region_factor([0.7, 0.3], [n, None], dim=6)[1] for n in (5.0, 20.0, 100.0, 1e6)]
    assert ks[0] > ks[1] > ks[2] > ks[3] > 1.0 and ks[3] == pytest.approx(1.0, abs=1e-4)
    assert estimated_noise_region_factor([0.5, 0.5], [None, math.inf], dim=6) == (None, 1.0)
