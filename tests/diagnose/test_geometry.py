"""The view pairs of the diagnostics' pair checks (handeye.diagnose.geometry): every pair up to
ALL_PAIRS_MAX_VIEWS views, above that a set linear in the views that still tests every view against many
others; the fits' summed pair terms are the same on either set."""

import numpy as np
import pytest

from handeye.diagnose.geometry import (
    ALL_PAIRS_MAX_VIEWS,
    all_pairs,
    pair_motions,
    pair_strides,
    pairs_text,
    view_pairs,
)
from handeye.mounting import mounting
from handeye.sim.corners import make_corner_session


@pytest.mark.parametrize("n", [2, 3, 20, ALL_PAIRS_MAX_VIEWS])
def test_small_sessions_keep_every_pair(n):
    i, j = view_pairs(n)
    a, b = all_pairs(n)
    assert np.array_equal(i, a) and np.array_equal(j, b)
    assert pairs_text(n) == f"{n * (n - 1) // 2} view pairs" and pairs_text(n, all_text="all") == "all"


@pytest.mark.parametrize("n", [ALL_PAIRS_MAX_VIEWS + 2, 100, 301, 500, 1000])
def test_large_sessions_get_pairs_linear_in_the_views_that_test_every_view(n):
    i, j = view_pairs(n)
    per_view = ALL_PAIRS_MAX_VIEWS // 2
    assert len(i) == n * per_view  # linear in n: 30 per view, not n (n - 1) / 2
    assert np.all(i < j) and len(set(zip(i.tolist(), j.tolist(), strict=True))) == len(i)  # distinct pairs
    assert np.array_equal(np.bincount(np.concatenate([i, j]), minlength=n), np.full(n, 2 * per_view))
    assert np.all(np.diff(i) >= 0)  # sorted by i like all_pairs
    strides = pair_strides(n)
    assert strides[0] == 1 and strides[-1] >= 0.4 * n  # neighbours and views far apart in the sequence
    assert np.array_equal(view_pairs(n)[1], j)  # from the view count alone
    assert pairs_text(n) == f"{n * per_view} view pairs ({2 * per_view} per view)"


def test_one_view_more_than_the_limit_still_gets_every_pair():
    """The set is continuous at the limit: 61 views with 30 strides are all 1830 pairs."""
    n = ALL_PAIRS_MAX_VIEWS + 1
    assert len(view_pairs(n)[0]) == n * (n - 1) // 2


@pytest.mark.parametrize("n", [40, 150])
def test_group_sums_from_running_sums_equal_the_direct_sums(n):
    """The fits' fast path (a split with a few views left out) on all pairs and on the linear set."""
    cs = make_corner_session(mode="eye_in_hand", n_views=n, seed=3, robot_noise=(0.3, 0.05), noise_px=0.3)
    M = mounting("eye_in_hand").M_from_T_base_end(np.asarray(cs.T_base_end_reported))
    motions = pair_motions(np.asarray(cs.T_cam_board_true), M)
    rng = np.random.default_rng(0)
    for k in (0, 5, n // 2 + 1):
        labels = (np.arange(n) >= k).astype(int)
        use = np.ones(n, bool)
        use[rng.choice(n, 6, replace=False)] = False
        same = labels[motions.i] == labels[motions.j]
        direct = motions.sums(same & use[motions.i] & use[motions.j])
        assert np.allclose(motions.group_sums(labels, use), direct, rtol=1e-10, atol=1e-9)
