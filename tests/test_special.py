"""handeye.special: the incomplete gamma and beta functions and their inverses are scipy.special's, to 3e-10.

scipy stays a dependency: the reference values are its own, on grids that reach the far tails, large degrees of
freedom and probabilities near 0 and 1.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.special as sc

from handeye import special as hs

KS = [0.4, 1, 2, 3, 5.5, 6, 7, 12, 40, 100, 500, 3000, 20000]
QS = [1e-100, 1e-12, 1e-6, 1e-3, 0.01, 0.05, 0.1, 0.5, 0.9, 0.95, 0.99, 1 - 1e-6, 1 - 1e-12]
DFN = [0.4, 1, 2, 3, 6, 10, 30]
DFD = [0.5, 1, 2, 4, 8, 14, 30, 100, 1000, 10000]
XS = [1e-8, 1e-3, 0.1, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0, 10.0, 30.0, 100.0, 1e3, 1e5]


def _rel(a: float, b: float) -> float:
    """Relative difference; 0 for equal values (infinities, zeros) and for two values below 1e-300."""
    if a == b or (max(abs(a), abs(b)) < 1e-300):
        return 0.0
    return abs(a - b) / abs(b) if b != 0 else math.inf


def _worst(cases, ours, theirs) -> tuple[float, tuple]:
    return max((_rel(ours(*c), float(theirs(*c))), c) for c in cases)


def test_chi_square_tail_and_quantile():
    xs = XS + [k * f for k in KS for f in (0.5, 0.9, 1.0, 1.1, 2.0)]
    assert _worst(list(itertools.product(KS, xs)), hs.chdtrc, sc.chdtrc)[0] < 1e-10
    assert _worst(list(itertools.product(KS, QS)), hs.chdtri, sc.chdtri)[0] < 1e-10
    cases = [(k / 2, q) for k, q in itertools.product(KS, QS)]
    assert _worst(cases, hs.gammaincinv, sc.gammaincinv)[0] < 1e-10


def test_f_tail_and_quantile():
    assert _worst(list(itertools.product(DFN, DFD, XS)), hs.fdtrc, sc.fdtrc)[0] < 1e-10
    # the quantile inherits the tail's digits times its condition: 2e-10 at 10000 and 0.4 degrees of freedom
    assert _worst(list(itertools.product(DFN, DFD, QS[1:])), hs.fdtri, sc.fdtri)[0] < 3e-10


def test_f_with_huge_denominator_dof_is_chi_square_over_its_dof():
    """Past 1e8 denominator degrees of freedom (a share of a variance near 0 gives Satterthwaite's 1e17) the
    F functions are chi-square's limit; scipy's own values there agree to 1e-6 (its far tail at 1e9 carries
    the last 1e-7 of the finite degrees of freedom; its own quantile fails at 1e17)."""
    for dfd in (1e9, 1e12):
        for x in (0.5, 2.1, 5.0):
            assert hs.fdtrc(6, dfd, x) == pytest.approx(float(sc.fdtrc(6, dfd, x)), rel=1e-6)
        for p in (0.05, 0.5, 0.95):
            assert hs.fdtri(6, dfd, p) == pytest.approx(float(sc.fdtri(6, dfd, p)), rel=1e-6)
    for dfd in (1e17, 1e300):  # scipy's quantile is NaN at 1e300
        assert hs.fdtri(6, dfd, 0.95) == pytest.approx(hs.chdtri(6, 0.05) / 6, rel=1e-12)
        assert hs.fdtrc(6, dfd, 2.1) == pytest.approx(hs.chdtrc(6, 12.6), rel=1e-12)


def test_student_t_distribution_function():
    ts = [-1e3, -50, -10, -5, -3, -2, -1, -0.5, -1e-6, 0.0, 0.1, 1, 2, 5, 50]
    assert _worst(list(itertools.product([0.5, 1, 2, 3, 5, 10, 19, 30, 100, 1000], ts)), hs.stdtr, sc.stdtr)[0] < 1e-10


def test_the_inverses_invert():
    for k, q in itertools.product([1, 6, 50], [1e-9, 0.05, 0.5, 0.99]):
        assert hs.chdtrc(k, hs.chdtri(k, q)) == pytest.approx(q, rel=1e-12)
    for d1, d2, p in itertools.product([1, 6], [3, 200], [1e-9, 0.05, 0.5, 0.95, 1 - 1e-9]):
        assert 1.0 - hs.fdtrc(d1, d2, hs.fdtri(d1, d2, p)) == pytest.approx(p, rel=1e-9)


def test_edges_are_scipys():
    nan, inf = math.nan, math.inf
    for args in [(6, 0.0), (6, -1.0), (6, inf), (0.0, 1.0), (-1, 1.0), (6, nan)]:
        a, b = hs.chdtrc(*args), float(sc.chdtrc(*args))
        assert (math.isnan(a) and math.isnan(b)) or a == b, args
    for args in [(6, 0.0), (6, 1.0), (6, -0.1), (6, 1.1), (6, nan)]:
        a, b = hs.chdtri(*args), float(sc.chdtri(*args))
        assert (math.isnan(a) and math.isnan(b)) or a == b, args
    for args in [(6, 8, 0.0), (6, 8, inf), (6, 8, -2.0), (0, 8, 1.0), (6, 8, nan)]:
        a, b = hs.fdtrc(*args), float(sc.fdtrc(*args))
        assert (math.isnan(a) and math.isnan(b)) or a == b, args
    assert hs.fdtri(6, 8, 0.0) == 0.0 and hs.fdtri(6, 8, 1.0) == math.inf and math.isnan(hs.fdtri(6, 8, 1.5))
    assert hs.stdtr(5, -inf) == 0.0 and hs.stdtr(5, inf) == 1.0 and hs.stdtr(5, 0.0) == 0.5


def test_vectorised_broadcasts_and_keeps_scalars():
    f = hs.vectorised(hs.fdtrc)
    got = f(6, np.array([[3.0], [30.0]]), np.array([0.5, 2.0, 8.0]))
    assert isinstance(got, np.ndarray) and got.shape == (2, 3) and got.dtype == float
    assert np.allclose(got, sc.fdtrc(6, np.array([[3.0], [30.0]]), np.array([0.5, 2.0, 8.0])), rtol=1e-10, atol=0)
    assert isinstance(f(6, 3.0, 2.0), float)
