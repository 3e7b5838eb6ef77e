"""The drift test's covariance of the change, split into the install's part and the new views' own."""

from __future__ import annotations

import numpy as np

from handeye.frames import se3_exp
from handeye.recal.drift import drift_test, joint_drift_test


def _model(seed: int = 3, nk: int = 4):
    """verify as a linear-Gaussian model (as in tests/recal/test_recal.py's joint test).

    An install solves (x, k) from 60 measurements G0 with unit noise; new views measure 24 of the same kind, G,
    solved with x vague and k under the installed intrinsics' prior.
    """
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(60, 6))
    K = X[:, :nk] + 0.3 * rng.normal(size=(60, nk))
    G0 = np.hstack([3e3 * X, K])
    S_inst = np.linalg.inv(G0.T @ G0)
    G = G0[:24] + 0.05 * rng.normal(size=(24, 6 + nk)) * np.r_[np.full(6, 3e3), np.full(nk, 1.0)]
    info_prior = np.zeros((6 + nk, 6 + nk))
    info_prior[:6, :6], info_prior[6:, 6:] = np.eye(6), np.linalg.inv(S_inst[6:, 6:])
    return rng, G0, S_inst, G, np.linalg.inv(G.T @ G + info_prior)


def _test(S_inst, P_v, m):
    return joint_drift_test(
        T_x_installed=np.eye(4),
        cov_installed=S_inst[:6, :6],
        cov_xk_installed=S_inst[:6, 6:],
        cov_kk_installed=S_inst[6:, 6:],
        T_x_new=se3_exp(m[:6]),
        dk_new=m[6:],
        cov_new=P_v,
        cov_k_prior=S_inst[6:, 6:],
        cov_x_prior=np.eye(6),
    )


def test_the_new_views_part_of_the_change_covariance_is_what_their_noise_alone_makes():
    rng, G0, S_inst, G, P_v = _model()
    n = 3000
    own, inst = [], []
    for _ in range(n):
        e = np.linalg.solve(G0.T @ G0, G0.T @ rng.normal(size=60))  # the install's error
        own.append(_test(S_inst, P_v, P_v @ (G.T @ rng.normal(size=24))).change_xi)  # the rig as installed
        inst.append(_test(S_inst, P_v, P_v @ (G.T @ (G @ -e))).change_xi)  # noiseless new views
    t = _test(S_inst, P_v, np.zeros(len(P_v)))
    V, V_new = t.change_cov, t.change_cov_new
    # whitened by V, each empirical covariance against its part (sampling sd of an entry ~ sqrt(2 / n) = 0.026)
    Li = np.linalg.inv(np.linalg.cholesky(V))
    for xs, part in ((own, V_new), (inst, V - V_new)):
        emp = np.cov(np.array(xs).T, bias=True)
        assert np.abs(Li @ (emp - part) @ Li.T).max() < 0.1
    assert 0.2 < np.trace(Li @ V_new @ Li.T) < 5.8  # both parts count here


def test_the_plain_test_splits_the_change_covariance_into_the_installed_one_and_the_new_views():
    S0, S_new = np.diag([1e-6] * 3 + [1e-8] * 3), np.diag([4e-6] * 3 + [9e-8] * 3)
    t = drift_test(cov_installed=S0, T_x_installed=np.eye(4), T_x_new=np.eye(4), cov_new=S_new)
    assert np.allclose(t.change_cov_new, S_new) and np.allclose(t.change_cov, S0 + S_new)
