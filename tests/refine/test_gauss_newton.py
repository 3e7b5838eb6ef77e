"""Gauss-Newton solves of the refinement (handeye.refine.gauss_newton) against GTSAM's Levenberg-Marquardt."""

from __future__ import annotations

import numpy as np
import pytest

import handeye.refine.gauss_newton as gauss_newton
from handeye.frames import se3_exp, tangent_difference
from handeye.refine import RefineOptions
from handeye.refine.options import check_inputs
from handeye.refine.problem import Problem
from handeye.sim.corners import make_corner_session

TOL = 0.02  # share of the solve's own sigma along every direction (tests/refine/test_refitting.py: the same)


def _problem(s) -> Problem:
    views = s.refine_views()
    obj, reported = check_inputs(s.target.object_points(), views)
    pb = Problem(
        mode=s.mode,
        object_points=obj,
        views=views,
        reported=reported,
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true @ se3_exp(np.r_[0.002, -0.001, 0.001, 0.001, 0.002, -0.001]),  # a start near the optimum
        T_board0=s.T_board_true,
        options=RefineOptions(robot_noise="fixed", robot_sigma_mm=0.2, robot_sigma_deg=0.02),
    )
    pb.sigma_px = 0.3
    return pb


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_solve_gaussian_is_the_levenberg_marquardt_solve(mode, monkeypatch):
    s = make_corner_session(mode=mode, n_views=10, seed=13, noise_px=0.3, robot_noise=(0.2, 0.02))
    lm, gn = _problem(s), _problem(s)
    g, values, keys = lm.solve(robust=False)
    S_cc, _ = lm.covariances(g, values, keys)
    monkeypatch.setattr(Problem, "solve", lambda *a, **k: pytest.fail("Gauss-Newton fell back to the LM solve"))
    gauss_newton.solve_gaussian(gn)
    monkeypatch.undo()
    assert gn.iterations > 1  # the start was off: more than one step
    xi = tangent_difference(lm.T_x, gn.T_x)
    assert xi @ np.linalg.solve(S_cc[:6, :6], xi) < TOL**2
    k = slice(12, 12 + gn.free.size)
    dk = (gn.k - lm.k)[gn.free]
    assert dk @ np.linalg.solve(S_cc[k, k], dk) < TOL**2


def test_solve_gaussian_falls_back_to_levenberg_marquardt_from_the_same_start(monkeypatch):
    s = make_corner_session(mode="eye_to_hand", n_views=8, seed=14, noise_px=0.3, robot_noise=(0.2, 0.02))
    lm, gn = _problem(s), _problem(s)
    lm.solve(robust=False)
    preset = gauss_newton.refine_preset()
    monkeypatch.setattr(
        gauss_newton, "refine_preset", lambda: {**preset, "solver": {**preset["solver"], "gauss_newton_max_steps": 1}}
    )
    with pytest.raises(gauss_newton.NoGaussNewton, match="did not settle"):
        gauss_newton.gauss_newton(_problem(s))
    gauss_newton.solve_gaussian(gn)  # one step does not settle: the same LM solve, from the same start
    np.testing.assert_allclose(gn.T_x, lm.T_x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(gn.k, lm.k, rtol=1e-12)
    assert gn.iterations == lm.iterations
