"""Pose-only results are validated as image results are: refits without some views, the verdict covariance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handeye.frames import pose_error, tangent_difference
from handeye.initial import all_methods
from handeye.mounting import mounting
from handeye.refine.poseonly import PoseView, refine_poses, refit_poses
from handeye.refine.validation import validate
from handeye.sim.poses import make_tracker_session


def _refined(mode="eye_in_hand", seed=4, **kw):
    ts = make_tracker_session(mode=mode, n_views=16, seed=seed, **kw)
    mount = mounting(mode)
    Ms = np.stack([mount.M_from_T_base_end(T) for T in ts.T_base_end])
    closed = all_methods(mount, ts.T_cam_board, Ms)
    views = [PoseView(v, ts.T_cam_board[k], ts.T_base_end[k]) for k, v in enumerate(ts.view_ids)]
    start = closed["tsai"]
    res = refine_poses(mode=mode, views=views, T_x0=start.T_x, T_board0=start.T_board, starts=closed)
    assert res.status == "ok"
    return ts, views, res


def test_a_refit_on_every_view_is_the_full_solution_and_a_fold_knows_less():
    _, views, res = _refined()
    every = refit_poses(res, views)
    assert every.status == "ok" and every.intrinsics is None
    rot, trans = pose_error(every.T_x, res.T_x)
    assert rot < 1e-6 and trans < 1e-6
    # a refit's covariance is the plug-in at the held sigmas; the result's carries their degrees of freedom
    assert res.cov_x_dof_factor > 1.0
    plug_in = res.cov_x_6x6 / res.cov_x_dof_factor
    assert np.allclose(every.cov_x, plug_in, rtol=1e-6, atol=1e-14)
    fold = refit_poses(res, views[1:])
    assert fold.status == "ok" and fold.view_ids == tuple(v.view_id for v in views[1:])
    # leaving a view out never adds information: the fold's covariance exceeds the full one's
    assert np.all(np.linalg.eigvalsh(fold.cov_x - plug_in) > -1e-15)
    assert refit_poses(res, views[:2]).status == "failed"


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_validation_of_a_clean_tracker_session_keeps_the_model_covariance(mode):
    _, views, res = _refined(mode=mode)
    val = validate(res, views=views, refit_views=lambda sub, cov: refit_poses(res, sub, cov))
    assert val.status == "ok" and val.n_solved == len(val.folds) >= 8
    assert val.intrinsics is None and set(val.halves) == {"odd", "even"}
    assert not val.x.finding and np.allclose(val.x.cov_verdict, res.cov_x_6x6)
    # the folds move X by about the model's sigma, not by nothing and not by much more
    shifts = np.stack([tangent_difference(res.T_x, r.T_x) for r in val.refits])
    assert 0.2 < np.sqrt(val.x.scale) < 3.0 and np.abs(shifts).max() > 0


def test_validation_sees_a_tracker_noisier_than_its_stated_sigma():
    """A stated tracker sigma 1.6 times too small: the folds scatter far beyond the model, and the verdict
    covariance takes the validated one."""
    ts, views, _ = _refined()
    mount = mounting(ts.mode)
    Ms = np.stack([mount.M_from_T_base_end(T) for T in ts.T_base_end])
    closed = all_methods(mount, ts.T_cam_board, Ms)
    stated = (np.radians(ts.sigma_deg) / 1.6, ts.sigma_mm / 1600.0)
    res = refine_poses(
        mode=ts.mode, views=views, T_x0=closed["tsai"].T_x, T_board0=closed["tsai"].T_board, tracker_sigma=stated
    )
    val = validate(res, views=views, refit_views=lambda sub, cov: refit_poses(res, sub, cov))
    assert val.status == "ok" and val.x.finding and val.x.p_value < 1e-3
    assert np.all(np.linalg.eigvalsh(val.x.cov_verdict - res.cov_x_6x6) > -1e-15)
    assert np.trace(val.x.cov_verdict) > 1.5 * np.trace(res.cov_x_6x6)


def test_a_pose_only_result_carries_the_verdict_covariance_and_its_folds(tmp_path):
    from handeye.workflow import calibrate_session

    ts = make_tracker_session(mode="eye_to_hand", n_views=14, seed=2, outlier_views=1)
    ts.write(tmp_path / "s", state_sigma=False)
    calibrate_session(tmp_path / "s", out_dir=tmp_path / "out")
    d = json.loads((tmp_path / "out" / "result.json").read_text())
    ref = d["refinement"]
    assert ref["validation"]["status"] == "ok" and ref["sigma_source"] in ("model", "validated", "model+validated")
    cov = np.array(ref["cov_x_6x6_verdict"])
    assert cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert ref["validation"]["halves"]["odd"]["status"] == "ok"
    cv = d["diagnostics"]["cross_validation"]
    assert d["diagnostics"]["stages"]["cross_validation"] == "ok"
    assert cv["held_out_trans_mm_median"] > 0 and all("held_out_rot_deg" in r for r in cv["per_view"])
    # the outlier view is not among the folds' views
    assert not set(o["view_id"] for o in ref["outliers"]) & {r["view"] for r in cv["per_view"]}
    assert "Held-out pose residual" in (tmp_path / "out" / "report.md").read_text()
