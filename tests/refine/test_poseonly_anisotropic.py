"""A tracker noisier along its optical axis: its three sigmas are estimated and weight the views."""

from __future__ import annotations

import numpy as np
import pytest

from handeye.frames import pose_error
from handeye.initial import all_methods
from handeye.mounting import mounting
from handeye.refine.poseonly import PoseView, refine_poses
from handeye.sim.arm_tracker import make_arm_tracker_session


def _refine(ts, **kw):
    mount = mounting(ts.mode)
    Ms = np.stack([mount.M_from_T_base_end(T) for T in ts.T_base_end])
    closed = all_methods(mount, ts.T_cam_board, Ms)
    views = [PoseView(v, ts.T_cam_board[k], ts.T_base_end[k]) for k, v in enumerate(ts.view_ids)]
    res = refine_poses(
        mode=ts.mode, views=views, T_x0=closed["tsai"].T_x, T_board0=closed["tsai"].T_board, starts=closed, **kw
    )
    assert res.status == "ok"
    return res


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_the_three_tracker_sigmas_are_estimated(mode):
    ts = make_arm_tracker_session(mode=mode, n_views=40, seed=3, sigma_mm=0.3, sigma_deg=0.1, axial_factor=5.0)
    res = _refine(ts)
    assert res.tracker_sigma_mm == pytest.approx(0.3, rel=0.3)
    assert res.tracker_sigma_along_mm == pytest.approx(1.5, rel=0.3)
    assert res.tracker_sigma_deg == pytest.approx(0.1, rel=0.3)
    assert res.to_dict()["tracker_noise"]["sigma_mm_along"] == res.tracker_sigma_along_mm


def test_an_isotropic_tracker_gets_equal_sigmas_across_and_along():
    ts = make_arm_tracker_session(n_views=40, seed=5, sigma_mm=0.5, sigma_deg=0.1)
    res = _refine(ts)
    assert res.tracker_sigma_along_mm == pytest.approx(res.tracker_sigma_mm, rel=0.35)


def test_weighting_the_optical_axis_apart_beats_one_translation_sigma():
    """The stated anisotropic model (the truth) against the same sigma on every axis, over a few sessions."""
    err_aniso, err_iso = [], []
    for seed in range(6):
        ts = make_arm_tracker_session(n_views=20, seed=seed, sigma_mm=0.3, sigma_deg=0.05, axial_factor=6.0)
        sig = (np.radians(0.05), 0.3e-3, 1.8e-3)
        rms = float(np.sqrt((2 * 0.3**2 + 1.8**2) / 3)) * 1e-3
        for out, stated in ((err_aniso, sig), (err_iso, (sig[0], rms))):
            out.append(pose_error(_refine(ts, tracker_sigma=stated).T_x, ts.truth.T_x_true)[1])
    assert np.sqrt(np.mean(np.square(err_aniso))) < 0.8 * np.sqrt(np.mean(np.square(err_iso)))
