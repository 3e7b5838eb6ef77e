"""The validated covariance (handeye.refine.validation): the jackknife and its scaling, the verdict rule,
the refits on simulated sessions (clean: the model holds and the verdict stays near it; a robot error the
model does not have: the verdict widens to cover the truth), and the fields result.json carries."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from handeye.diagnose.crossval import ratio_limits
from handeye.frames import tangent_difference
from handeye.refine import RefineOptions, refine
from handeye.refine.validation import (
    Validation,
    _block,
    fold_indices,
    fold_information_statistic,
    generalised_max,
    jackknife_covariance,
    mahalanobis2,
    settings,
    shrunk_jackknife,
    trace_p_value,
    validate,
)
from handeye.results import validation_fields
from handeye.sim.corners import make_corner_session

CHI2_6_999 = chi2.ppf(0.999, 6)


def _spd(rng, d, scale=1.0):
    A = rng.normal(size=(d, d))
    return scale * (A @ A.T + d * np.eye(d))


def _min_eig(A):
    return float(np.linalg.eigvalsh(0.5 * (A + A.T)).min())


# ------------------------------------------------------------------------------ pure math
def test_leave_one_out_jackknife_of_a_mean_is_its_sample_covariance_over_n():
    x = np.random.default_rng(1).normal(size=(9, 3))
    loo = np.stack([np.delete(x, k, axis=0).mean(axis=0) for k in range(len(x))])
    assert np.allclose(jackknife_covariance(loo), np.cov(x.T) / len(x), atol=1e-12)


def test_folds_are_leave_one_out_up_to_the_limit_then_interleaved_groups():
    assert [f.tolist() for f in fold_indices(4, loo_max_views=5, folds=3)] == [[0], [1], [2], [3]]
    f = fold_indices(10, loo_max_views=5, folds=3)
    assert [g.tolist() for g in f] == [[0, 3, 6, 9], [1, 4, 7], [2, 5, 8]]
    assert sorted(np.concatenate(f).tolist()) == list(range(10))


def test_verdict_covariance_is_never_smaller_than_either_in_any_direction():
    rng = np.random.default_rng(2)
    for _ in range(20):
        M, V = _spd(rng, 6), _spd(rng, 6, scale=rng.uniform(0.2, 5.0))
        C, lam = generalised_max(M, V)
        scale = np.abs(C).max()
        assert _min_eig(C - M) > -1e-9 * scale and _min_eig(C - V) > -1e-9 * scale
        assert np.all(np.diff(lam) >= 0)
    M = _spd(rng, 6)
    assert np.allclose(generalised_max(M, 4.0 * M)[0], 4.0 * M)  # validated larger everywhere: it is the verdict
    assert np.allclose(generalised_max(M, 0.5 * M)[0], M)  # smaller everywhere: the model stands
    with pytest.raises(np.linalg.LinAlgError):
        generalised_max(np.zeros((6, 6)), M)  # a model covariance that is not positive definite


def test_the_trace_p_value_is_the_chi_square_tail_of_k_minus_1_dof_per_direction():
    # (K - 1) D · scale ~ chi2((K - 1) D): at the mean the tail is near one half, far out it vanishes
    assert trace_p_value(1.0, 12, 6) == pytest.approx(chi2.sf(66, 66))
    assert trace_p_value(2.0, 12, 6) == pytest.approx(chi2.sf(132, 66)) and trace_p_value(2.0, 12, 6) < 1e-5
    assert trace_p_value(0.5, 12, 6) > 0.99


def _weighted_mean_folds(rng, covs, inflate=1.0):
    """Leave-one-out of the information-weighted mean of n vector observations with unequal covariances (views
    that inform the result unequally): (all-views estimate, its covariance, fold estimates, fold covariances)."""
    W = [np.linalg.inv(c) for c in covs]
    y = [rng.multivariate_normal(np.zeros(len(c)), inflate * c) for c in covs]

    def fit(idx):
        C = np.linalg.inv(sum(W[i] for i in idx))
        return C @ sum(W[i] @ y[i] for i in idx), C

    n = len(covs)
    t_all, C_all = fit(range(n))
    folds = [fit([i for i in range(n) if i != k]) for k in range(n)]
    return t_all, C_all, np.stack([f[0] for f in folds]), [f[1] for f in folds]


def test_the_fold_information_test_holds_its_level_where_views_inform_unequally():
    # 12 views, information spread 100x between them: the jackknife exceeds the model's covariance, so the trace
    # test finds the model wrong far more often than alpha; measured fold by fold against the covariance the model
    # predicts for it, the statistic is chi-square and finds it at the nominal rate
    rng = np.random.default_rng(7)
    alpha, floor = float(settings()["alpha"]), float(settings()["information_floor"])
    found_info, found_trace, ratio = [], [], []
    for _ in range(300):
        covs = [_spd(rng, 3, scale=10 ** rng.uniform(-1, 1)) for _ in range(12)]
        t_all, C_all, th, Ck = _weighted_mean_folds(rng, covs)
        T, dof = fold_information_statistic(th - t_all, Ck, C_all, floor=floor)
        ratio.append(T / dof)
        found_info.append(chi2.sf(T, dof) < alpha)
        found_trace.append(_block(tuple("abc"), C_all, th - t_all).p_value < alpha)
    assert abs(np.mean(ratio) - 1.0) < 0.06 and np.mean(found_info) < alpha + 3 * np.sqrt(alpha / 300)
    assert np.mean(found_trace) > 5 * alpha
    # the views' noise 3x their stated variance: found
    hits = []
    for _ in range(20):
        covs = [_spd(rng, 3, scale=10 ** rng.uniform(-1, 1)) for _ in range(12)]
        t_all, C_all, th, Ck = _weighted_mean_folds(rng, covs, inflate=3.0)
        T, dof = fold_information_statistic(th - t_all, Ck, C_all, floor=floor)
        hits.append(chi2.sf(T, dof) < alpha)
        assert _block(tuple("abc"), C_all, th - t_all, test=(T, dof)).test == "fold information"
    assert np.mean(hits) > 0.9


def test_directions_a_fold_carries_no_information_in_are_left_out_of_the_test():
    # the fold's covariance equals the full one along z (the fold's views say nothing about z): its displacement
    # there (a solver tolerance of 1e-5) is not measured, and the degrees of freedom count x and y only
    floor = float(settings()["information_floor"])
    C_all, C_k = np.eye(3), np.diag([1.1, 1.1, 1.0 + 1e-9])
    T, dof = fold_information_statistic(np.array([[0.1, -0.1, 1e-5]] * 4), [C_k] * 4, C_all, floor=floor)
    assert dof == pytest.approx(3 / 4 * 4 * 2) and T == pytest.approx(3 / 4 * 4 * 0.2)


def test_the_verdict_is_the_model_unless_the_folds_reject_it_at_alpha():
    # fold estimates drawn from a jackknife whose covariance is the model's (delete-one means of n points):
    # the spread is a finding in about alpha of the sessions, and then only the verdict departs from the model
    rng = np.random.default_rng(5)
    alpha, K = float(settings()["alpha"]), 12
    M = _spd(rng, 6)
    L = np.linalg.cholesky(M)
    found = []
    for _ in range(400):
        x = rng.normal(size=(K, 6)) @ L.T * np.sqrt(K)  # per-unit influence: the mean of K has covariance M
        b = _block(
            tuple("abcdef"), M, np.stack([np.delete(x, k, axis=0).mean(axis=0) - x.mean(axis=0) for k in range(K)])
        )
        found.append(b.finding)
        if not b.finding:
            assert np.allclose(b.cov_verdict, M) and b.source == "model" and b.p_value >= alpha
        else:
            assert _min_eig(b.cov_verdict - b.cov_validated) > -1e-9 * np.abs(b.cov_verdict).max()
    assert np.mean(found) < alpha + 3 * np.sqrt(alpha / 400)
    # three times the model's variance in every direction: found, and the verdict takes the validated covariance
    x = rng.normal(size=(K, 6)) @ L.T * np.sqrt(3 * K)
    b = _block(tuple("abcdef"), M, np.stack([np.delete(x, k, axis=0).mean(axis=0) for k in range(K)]))
    assert b.finding and b.source != "model" and _min_eig(b.cov_verdict - M) > -1e-9 * np.abs(M).max()


def test_shrinkage_keeps_the_average_spread_over_the_model():
    rng = np.random.default_rng(3)
    M = _spd(rng, 6)
    thetas = rng.multivariate_normal(np.zeros(6), 3.0 * M, size=12)
    S = jackknife_covariance(thetas)
    V, rho, s = shrunk_jackknife(thetas, M)
    Mi = np.linalg.inv(M)
    assert 0.0 <= rho <= 1.0
    assert np.trace(Mi @ V) == pytest.approx(np.trace(Mi @ S), rel=1e-10) == pytest.approx(6 * s, rel=1e-10)
    assert np.isnan(mahalanobis2(np.ones(6), np.zeros((6, 6))))  # a singular covariance: no distance


def test_the_summary_states_the_worst_direction_of_the_folds_own_spread_not_of_the_shrunk_one():
    # 12 folds spread 1.6x the model's sigma along one axis: the shrinkage pulls that direction toward the average
    # (intensity near 1), so the shrunk covariance's worst direction is below the spread along that very axis
    from types import SimpleNamespace

    rng = np.random.default_rng(3)
    M = _spd(rng, 6)
    L = np.linalg.cholesky(M)
    thetas = (rng.normal(size=(12, 6)) * np.array([1.0, 1.6, 1.0, 1.0, 1.0, 1.0]) / np.sqrt(11)) @ L.T
    b = _block(tuple("abcdef"), M, thetas)
    J = jackknife_covariance(thetas)
    per_axis = np.sqrt(np.diag(J) / np.diag(M))  # the report's held-out table: jackknife sigma / predicted sigma
    worst = float(np.sqrt(np.linalg.eigvalsh(np.linalg.solve(L, np.linalg.solve(L, J).T)).max()))
    assert b.shrinkage > 0.5 and np.sqrt(b.eig.max()) < per_axis.max()  # the shrunk one's worst understates it
    v = Validation(
        "ok", scheme="leave-one-out", folds=tuple(range(12)), refits=(SimpleNamespace(status="ok"),) * 12, x=b
    )
    text = v.summary()
    assert f"{np.sqrt(b.scale):.2f}x the model's sigma on average" in text
    assert f"(up to {worst:.2f}x along the worst)" in text
    assert worst >= per_axis.max() > np.sqrt(b.scale)


# ------------------------------------------------------------------------------ refits on simulated sessions
def _refined(s, **opts):
    views = s.refine_views()
    r = refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=views,
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true,
        T_board0=s.T_board_true,
        options=RefineOptions(**opts),
    )
    assert r.status == "ok", r.failure_reason
    return r, views


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_on_clean_data_the_folds_agree_with_the_model_and_the_verdict_covers_the_truth(mode):
    s = make_corner_session(mode=mode, n_views=16, seed=31, noise_px=0.3, robot_noise=(0.3, 0.03))
    r, views = _refined(s)
    v = validate(r, object_points=s.target.object_points(), views=views)
    assert v.status == "ok" and v.n_solved == len(v.folds) == settings()["folds"]
    lo, hi = ratio_limits(len(v.folds))
    # the folds' spread over the model's, averaged over the 6 directions, is sampling noise (K - 1 dof each)
    assert lo**2 < v.x.scale < hi**2, v.x.scale
    M, C = r.cov_x_6x6, v.x.cov_verdict
    # no finding: the verdict is the model's, and the summary says the spread is within chance
    assert not v.x.finding and v.x.p_value >= settings()["alpha"] and np.allclose(C, M) and v.x.source == "model"
    assert v.x.test == v.intrinsics.test == "fold information"
    assert "within chance" in v.summary()
    # the intrinsics were measured against their joint model covariance, correlations included
    assert v.intrinsics.model_form == "full"
    assert np.allclose(v.intrinsics.cov_model, r.cov_x_intrinsics["intrinsics_kxk"])
    assert mahalanobis2(tangent_difference(r.T_x, s.T_x_true), C) < CHI2_6_999
    # the halves: each a refit of half the views
    assert set(v.halves) == {"odd", "even"} and all(h.status == "ok" for h in v.halves.values())
    assert v.halves["odd"].view_ids[:2] == (s.view_ids[0], s.view_ids[2])


def test_refits_without_their_covariance_fall_back_and_never_cancel_the_validation(monkeypatch):
    # one fold without its covariance: the test runs over the others; the all-views refit without one: T_x falls
    # back to the trace test and the intrinsics, whose jackknife would mislead it, keep the model's covariance; an
    # all-views covariance that is not positive definite does the same, the validation still runs
    from dataclasses import replace

    import handeye.refine.refitting as refitting

    s = make_corner_session(mode="eye_to_hand", n_views=14, seed=35, noise_px=0.3, robot_noise=(0.3, 0.03))
    r, views = _refined(s)
    real = refitting.Refitter.refit
    n_used = sum(pv["status"] == "used" for pv in r.per_view.values())

    def run(change):
        calls = []

        def fake(self, views, *, covariance=True):
            out = real(self, views, covariance=covariance)
            calls.append(out)
            return change(out, len(views), len(calls))

        monkeypatch.setattr(refitting.Refitter, "refit", fake)
        return validate(r, object_points=s.target.object_points(), views=views, halves=False)

    v = run(lambda out, n, k: replace(out, cov_x=None, cov_intrinsics=None) if k == 1 else out)
    assert v.status == "ok" and v.x.test == v.intrinsics.test == "fold information"
    v = run(lambda out, n, k: replace(out, cov_x=None, cov_intrinsics=None) if n == n_used else out)
    assert v.status == "ok" and v.x.test == "trace" and v.intrinsics.test == "none"
    assert not v.intrinsics.finding and np.allclose(v.intrinsics.cov_verdict, v.intrinsics.cov_model)
    assert validation_fields(r, v)["validation"]["intrinsics_spread_p_value"] is None
    v = run(lambda out, n, k: replace(out, cov_x=-np.eye(6)) if n == n_used else out)
    assert v.status == "ok" and v.x.test == "trace" and v.intrinsics.test == "fold information"


def test_an_unmodelled_robot_error_widens_the_verdict_until_it_covers_the_truth():
    # robot poses 1 mm / 0.1 deg off per view, refined as if they were exact to 0.02 mm / 0.002 deg: the model's
    # covariance is far too small; the views disagree, and the refits show it
    s = make_corner_session(mode="eye_to_hand", n_views=20, seed=32, noise_px=0.3, robot_noise=(1.0, 0.1))
    r, views = _refined(s, robot_noise="fixed", robot_sigma_mm=0.02, robot_sigma_deg=0.002, outlier_loop=False)
    v = validate(r, object_points=s.target.object_points(), views=views)
    assert v.status == "ok" and v.x.source == "validated"
    xi = tangent_difference(r.T_x, s.T_x_true)
    assert mahalanobis2(xi, r.cov_x_6x6) > chi2.ppf(0.999, 6)  # the model's ellipsoid misses the truth
    assert mahalanobis2(xi, v.x.cov_verdict) < CHI2_6_999  # the verdict's holds it
    assert np.sqrt(v.x.scale) > ratio_limits(len(v.folds))[1]


def test_too_few_views_are_not_validated_and_the_model_stands():
    s = make_corner_session(mode="eye_in_hand", n_views=5, seed=33, noise_px=0.3)
    r, views = _refined(s)
    v = validate(r, object_points=s.target.object_points(), views=views)
    assert v.status == "not_run" and "5 used views" in v.reason
    f = validation_fields(r, v)
    assert f["sigma_source"] == "model" and "cov_x_6x6_validated" not in f
    np.testing.assert_array_equal(np.asarray(f["cov_x_6x6_verdict"]), np.asarray(r.cov_x_6x6))  # every result has one
    assert f["validation"]["status"] == "not_run"


def test_result_json_carries_the_model_the_validated_and_the_verdict_uncertainty():
    s = make_corner_session(mode="eye_in_hand", n_views=14, seed=34, noise_px=0.3, robot_noise=(0.5, 0.05))
    r, views = _refined(s)
    v = validate(r, object_points=s.target.object_points(), views=views)
    f = validation_fields(r, v)
    C = np.asarray(f["cov_x_6x6_verdict"])
    assert np.allclose(C, v.x.cov_verdict) and np.allclose(f["cov_x_6x6_validated"], v.x.cov_validated)
    assert f["sigma_source"] == v.x.source and "generalised-eigenvalue maximum" in f["sigma_rule"]
    # the printed sigmas are the verdict's; the model's are kept beside them
    assert np.allclose(np.degrees(np.sqrt(np.diag(C)[:3])), f["sigma_rot_deg"])
    assert np.allclose(f["sigma_rot_deg_model"], r.sigma_rot_deg) and np.allclose(
        f["sigma_trans_mm_model"], r.sigma_trans_mm
    )
    assert all(f["sigma_trans_mm"][k] >= f["sigma_trans_mm_model"][k] - 1e-12 for k in range(3))
    names = f["intrinsics_cov_names"]
    assert names == list(r.intrinsics_sigma) and set(f["intrinsics_sigma_verdict"]) == set(names)
    assert all(f["intrinsics_sigma_verdict"][k] >= r.intrinsics_sigma[k] * (1 - 1e-9) for k in names)
    h = f["validation"]["halves"]
    assert h["odd"]["status"] == "ok" and h["odd_vs_even"]["mahalanobis2"] < CHI2_6_999
    assert isinstance(v, Validation) and f["validation"]["n_folds"] == len(v.folds)
