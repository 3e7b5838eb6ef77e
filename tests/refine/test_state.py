"""The refinement's numpy state (handeye.refine.state): its linearisation is GTSAM's of the same factors."""

from __future__ import annotations

import numpy as np
import pytest

from handeye.refine import RefineOptions
from handeye.refine.covariance import arrow_blocks
from handeye.refine.options import check_inputs
from handeye.refine.problem import Problem
from handeye.sim.corners import make_corner_session


def _problem(s, **opts) -> Problem:
    views = s.refine_views()
    obj, reported = check_inputs(s.target.object_points(), views)
    return Problem(
        mode=s.mode,
        object_points=obj,
        views=views,
        reported=reported,
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true,
        T_board0=s.T_board_true,
        options=RefineOptions(**opts),
    )


@pytest.mark.parametrize(
    ("mode", "opts"),
    [("eye_in_hand", {}), ("eye_to_hand", {"fix": ("k3", "p1")}), ("eye_in_hand", {"robot_noise": "none"})],
)
def test_pixel_linearisation_is_gtsams_linearisation_of_the_reprojection_factors(mode, opts):
    s = make_corner_session(mode=mode, n_views=7, seed=11, noise_px=0.3, robot_noise=(0.3, 0.03))
    pb = _problem(s, **opts)
    rng = np.random.default_rng(0)
    pb.P = pb.P @ np.stack([np.eye(4)] * pb.n)  # a copy
    pb.P[:, :3, 3] += 1e-3 * rng.normal(size=(pb.n, 3))  # off the reported poses, so the robot blocks matter
    pb.status[2] = "robot_excluded"  # a robot-pose variable without its prior
    pb.status[4] = "removed"
    pb.mask[1][::3] = False  # flagged corners are left out
    lin = pb.pixel_linearisation()
    g, v, keys = pb.build(robust=False, pixel_only=True)
    H, eta = g.linearize(v).hessian(pb._ordering(keys))
    idx_p = sorted(keys)
    assert lin.robot_views == tuple(idx_p) and 4 not in idx_p
    assert (2 in idx_p) and (len(idx_p) == (6 if pb.robot_var else 1))
    Hcc, Hcp, Hpp = arrow_blocks(H, pb.n_core, len(idx_p))
    scale = np.abs(H).max()
    np.testing.assert_allclose(lin.Hcc, Hcc, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(lin.Hcp, Hcp, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(lin.Hpp, Hpp, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(lin.g, -np.asarray(eta).reshape(-1), rtol=0, atol=1e-10 * np.abs(eta).max())
    assert lin.rr == pytest.approx(2.0 * g.error(v), rel=1e-12)
    assert list(lin.prior) == [pb.robot_var and pb.status[i] == "used" for i in idx_p]
