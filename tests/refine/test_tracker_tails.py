"""A heavy-tailed tracker in the pose-only refinement (handeye.refine.tracker_tails)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_t

from handeye.frames import inv_T, se3_log
from handeye.initial import all_methods
from handeye.mounting import mounting
from handeye.refine.poseonly import PoseView, refine_poses, refit_poses
from handeye.refine.tracker_tails import (
    TAIL_TEST_LL,
    choose_dof,
    information_factor,
    log_likelihood,
    t_weights,
)
from handeye.sim.arm_tracker import make_arm_tracker_session


def test_the_log_likelihood_is_the_multivariate_t_and_the_gaussian():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(5, 6))
    cov = np.diag([1.0, 2.0, 0.5, 1.5, 3.0, 0.7])
    m2 = np.einsum("ni,ij,nj->n", x, np.linalg.inv(cov), x)
    logdet = np.full(5, np.linalg.slogdet(cov)[1])
    for nu in (3.0, 10.0):
        want = multivariate_t(loc=np.zeros(6), shape=cov, df=nu).logpdf(x).sum()
        assert log_likelihood(m2, logdet, nu) == pytest.approx(want, rel=1e-12)
    gauss = -0.5 * (6 * np.log(2 * np.pi) + logdet + m2)
    assert log_likelihood(m2, logdet, np.inf) == pytest.approx(gauss.sum(), rel=1e-12)


def test_weights_and_information_factor():
    np.testing.assert_allclose(t_weights(np.array([0.0, 9.0]), 3.0), [3.0, 0.75])
    np.testing.assert_array_equal(t_weights(np.array([0.0, 1e6]), np.inf), [1.0, 1.0])
    assert information_factor(3.0) == pytest.approx(11.0 / 9.0)
    assert information_factor(np.inf) == 1.0


def test_the_tails_are_chosen_only_where_the_gaussian_is_rejected():
    """Squared Mahalanobis norms of 40 Gaussian views: Gaussian; of 40 multivariate-t(3) views: a t."""
    rng = np.random.default_rng(4)
    z = rng.normal(size=(40, 6))
    nu, w = choose_dof(np.sum(z**2, axis=1), np.zeros(40))
    assert np.isinf(nu) and np.all(w == 1.0)
    g = rng.chisquare(3.0, 40) / 3.0
    m2 = np.sum(z**2, axis=1) / g
    nu, w = choose_dof(m2, np.zeros(40))
    assert nu == 5.0
    assert w[np.argmax(m2)] < 0.3 and w[np.argmin(m2)] > 1.0  # the spoilt views count less
    assert TAIL_TEST_LL == pytest.approx(1.3528, abs=1e-4)  # chi-square(1) 90 % point / 2: 5 % on the boundary


def _refine(ts):
    m = mounting(ts.mode)
    cf = all_methods(m, ts.T_cam_board, np.stack([m.M_from_T_base_end(T) for T in ts.T_base_end]))
    views = [PoseView(v, ts.T_cam_board[k], ts.T_base_end[k]) for k, v in enumerate(ts.view_ids)]
    res = refine_poses(mode=ts.mode, views=views, T_x0=cf["tsai"].T_x, T_board0=cf["tsai"].T_board, starts=cf)
    assert res.status == "ok", res.failure_reason
    return res, views


def test_a_heavy_tailed_tracker_is_modelled_not_trimmed():
    """Student-t(3) tracker noise: a t is chosen (the grid's heaviest), every view kept with its EM weight
    (none called a wrong robot pose), X's covariance the t model's; a Gaussian tracker stays Gaussian."""
    ts = make_arm_tracker_session(arm="ur5e", mode="eye_in_hand", seed=0, tracker_dof=3.0)
    res, views = _refine(ts)
    assert res.tracker_tail_dof == 5.0
    assert not res.outliers and all(v["status"] == "used" for v in res.per_view.values())
    w = np.array(list(res.view_weights.values()))
    assert w.min() < 0.3 and w.max() > 1.5
    d = res.to_dict()["tracker_noise"]
    assert d["tail_dof"] == 5.0 and "Student-t" in d["model"]
    # a refit on every view holds the weights: the full solution again (a Gaussian refit would move it)
    refit = refit_poses(res, views, covariance=False)
    assert np.abs(se3_log(inv_T(refit.T_x) @ res.T_x)).max() < 1e-7
    clean, _ = _refine(make_arm_tracker_session(arm="ur5e", mode="eye_in_hand", seed=0))
    assert np.isinf(clean.tracker_tail_dof) and clean.view_weights is None
    assert clean.to_dict()["tracker_noise"]["tail_dof"] is None
