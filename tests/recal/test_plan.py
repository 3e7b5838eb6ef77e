"""verify --plan's greedy choice: the same poses whatever the installed result's last bits."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from handeye.frames import se3_exp
from handeye.recal.loaded import load_result, result_from_refinement
from handeye.recal.plan import _first_best, plan_verification, x_information
from handeye.sim.corners import make_corner_session

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from bench_refine import refine_from_tsai  # noqa: E402  (the pipeline's seeding)


def test_scores_that_agree_to_their_last_bits_are_a_tie_broken_by_order():
    assert _first_best([1.0, 1.0 + 1e-14, 0.5]) == 0
    assert _first_best([0.5, 1.0 - 1e-14, 1.0]) == 1
    assert _first_best([1.0, 1.0 + 1e-4, 0.5]) == 1  # a real difference wins
    assert _first_best([3.0]) == 0


def _view_info(inst, T_base_end):
    from handeye.collect.plan import view_information
    from handeye.session.target_spec import parse_target

    return view_information(
        mode=inst.mode,
        T_x=inst.T_x,
        T_board=inst.T_board,
        T_base_end=T_base_end,
        object_points=parse_target(inst.target, path=inst.source).object_points(),
        intrinsics=inst.intrinsics,
        pixel_noise_px=inst.sigma_px,
        robot_noise_mm=inst.robot_sigma_mm,
        robot_noise_deg=inst.robot_sigma_deg,
    )


def test_the_plan_does_not_follow_the_installed_results_last_bits():
    s = make_corner_session(mode="eye_in_hand", n_views=10, seed=4, noise_px=0.3, robot_noise=(0.2, 0.05))
    r = refine_from_tsai(s)
    inst = load_result(result_from_refinement(r, target=s.target))
    plan = plan_verification(inst, max_views=6, power=1 - 1e-12)
    assert len(plan.poses) == 6 and plan.candidate_index[0] == 0  # one view tells nothing of X: a tie, the first
    # one view's information on X, the board marginalised, is none at all (not rounding noise of either sign)
    assert np.all(x_information(_view_info(inst, plan.poses[1])) == 0.0)
    rng = np.random.default_rng(0)
    for _ in range(3):  # X and its covariance off by a few units in the last place, as another platform gives them
        other = replace(
            inst,
            T_x=inst.T_x @ se3_exp(1e-15 * rng.normal(size=6)),
            cov_x=inst.cov_x * (1.0 + 1e-15 * rng.normal()),
        )
        again = plan_verification(other, max_views=6, power=1 - 1e-12)
        assert again.candidate_index == plan.candidate_index
