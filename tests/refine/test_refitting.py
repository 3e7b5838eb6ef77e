"""Refits (handeye.refine.refitting): Gauss-Newton from the full solution against Levenberg-Marquardt from cold."""

from __future__ import annotations

import numpy as np
import pytest

from handeye.errors import InputError
from handeye.frames import se3_exp, tangent_difference
from handeye.refine import RefineOptions, refine
from handeye.refine.problem import Problem
from handeye.refine.refitting import Refitter, refit
from handeye.sim.corners import make_corner_session

# the warm refit and the cold one agree to this share of the fold's own sigma along every direction (squared
# Mahalanobis distance below TOL**2): the Gauss-Newton steps end below 1e-3 sigma, Levenberg-Marquardt's cost
# tolerance (relative 1e-6) leaves a few 1e-3 sigma
TOL = 0.02


def _refined(s, views, **opts):
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
    return r


def _assert_same_covariance(A, B, tol=1e-3):
    """Every direction's variance of A within ``tol`` (relative) of B's: the generalised eigenvalues near 1."""
    L = np.linalg.cholesky(B)
    W = np.linalg.solve(L, np.linalg.solve(L, A).T)
    lam = np.linalg.eigvalsh(0.5 * (W + W.T))
    assert np.all(np.abs(lam - 1.0) < tol), lam


def _cold(rf: Refitter, sub: list, rng) -> Problem:
    """The fold solved by GTSAM's Levenberg-Marquardt from a start 0.5 deg / 5 mm off the full solution."""
    pb = rf._problem([rf.views[v.view_id] for v in sub])
    pb.T_x = pb.T_x @ se3_exp(np.r_[np.radians(0.5) * rng.normal(size=3), 5e-3 * rng.normal(size=3)])
    pb.T_board = pb.T_board @ se3_exp(np.r_[np.radians(0.5) * rng.normal(size=3), 5e-3 * rng.normal(size=3)])
    pb.P = pb.reported.copy()
    pb.solve(robust=False)
    return pb


def _check_against_cold(s, views, r, rng, monkeypatch):
    used = [v for v in views if r.per_view[v.view_id]["status"] != "removed"]
    rf = Refitter(r, object_points=s.target.object_points(), views=used)
    folds = [used[1:], used[::2], used]
    real_solve = Problem.solve
    monkeypatch.setattr(Problem, "solve", lambda *a, **k: pytest.fail("a warm refit fell back to the LM solve"))
    warm = [rf.refit(f) for f in folds]
    monkeypatch.setattr(Problem, "solve", real_solve)
    for f, w in zip(folds, warm, strict=True):
        assert w.status == "ok" and w.view_ids == tuple(v.view_id for v in f)
        cold = _cold(rf, f, rng)
        xi = tangent_difference(cold.T_x, w.T_x)
        assert xi @ np.linalg.solve(w.cov_x, xi) < TOL**2
        dk = (cold.k - w.intrinsics.as_vector())[cold.free]
        assert dk @ np.linalg.solve(w.cov_intrinsics, dk) < TOL**2
        # the fold's covariance is its own (less information than the full run), the one at the cold solution
        g, values, keys = cold.build(robust=False)
        S_cc, _ = cold.covariances(g, values, keys)
        _assert_same_covariance(w.cov_x, S_cc[:6, :6])
    # leaving views out moves the estimate (the test above is not comparing the start with itself)
    xi = tangent_difference(r.T_x, warm[1].T_x)
    assert xi @ np.linalg.solve(r.cov_x_6x6, xi) > 1e-4


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_warm_refit_is_the_cold_refits_answer(mode, monkeypatch):
    s = make_corner_session(mode=mode, n_views=14, seed=21, noise_px=0.3, robot_noise=(0.2, 0.02), outlier_views=1)
    views = s.refine_views()
    r = _refined(s, views)
    assert any(o.kind for o in r.outliers), "the session has an outlier the refits must hold"
    _check_against_cold(s, views, r, np.random.default_rng(1), monkeypatch)


def test_a_warm_refit_is_the_cold_refits_answer_with_a_kinematic_robot_model(monkeypatch):
    # the DH offsets in the core and the kinematic robot priors (a CustomFactor) linearised by GTSAM per factor
    s = make_corner_session(
        mode="eye_in_hand",
        n_views=16,
        seed=4,
        noise_px=0.3,
        robot_error="kinematic",
        dh_length_error_mm=(0.1, 0.5),
        dh_angle_error_deg=(0.01, 0.05),
    )
    views = s.refine_views(s.joints_encoder)
    r = _refined(s, views, arm="rm65")
    assert r.robot_model["kind"] == "kinematic"
    _check_against_cold(s, views, r, np.random.default_rng(2), monkeypatch)


def test_refits_that_do_not_settle_are_solved_by_levenberg_marquardt(monkeypatch):
    import handeye.refine.gauss_newton as gauss_newton

    s = make_corner_session(mode="eye_to_hand", n_views=10, seed=8, noise_px=0.3)
    views = s.refine_views()
    r = _refined(s, views)
    gn = refit(r, object_points=s.target.object_points(), views=views[1:])
    preset = gauss_newton.refine_preset()
    monkeypatch.setattr(
        gauss_newton, "refine_preset", lambda: {**preset, "solver": {**preset["solver"], "gauss_newton_max_steps": 1}}
    )
    lm = refit(r, object_points=s.target.object_points(), views=views[1:])
    assert lm.status == "ok"
    xi = tangent_difference(lm.T_x, gn.T_x)
    assert xi @ np.linalg.solve(gn.cov_x, xi) < TOL**2
    _assert_same_covariance(lm.cov_x, gn.cov_x)


def test_a_refitter_refuses_views_it_was_not_made_with():
    s = make_corner_session(mode="eye_to_hand", n_views=8, seed=8, noise_px=0.3)
    views = s.refine_views()
    r = _refined(s, views)
    rf = Refitter(r, object_points=s.target.object_points(), views=views[:6])
    with pytest.raises(InputError, match="cannot be refitted"):
        rf.refit(views[4:])
    with pytest.raises(InputError, match="duplicate view id"):
        rf.refit(views[:3] + views[:1])
    with pytest.raises(InputError, match="at least 3 views"):
        rf.refit(views[:2])
