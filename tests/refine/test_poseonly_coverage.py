"""X's covariance of a pose-only refinement with the tracker's sigmas estimated (handeye.refine.tracker_dof),
and the tracker's translation scale estimated with X (--estimate-scale)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handeye.frames import pose_error, se3_log
from handeye.initial import all_methods
from handeye.mounting import mounting
from handeye.pipeline.poseonly import tracker_scale_start
from handeye.refine.poseonly import PoseView, _State, refine_poses
from handeye.refine.tracker_dof import (
    covariance_parts,
    equivalent_dof,
    noise_dof,
    resampled_factors,
)
from handeye.sim.arm_tracker import make_arm_tracker_session
from handeye.special import fdtri
from handeye.stats import chi2_ppf, estimated_parts_region_factor

#: chi-square(6)'s 99.9 % point: a truth farther than this in X's covariance is a failure of the covariance
M2_999 = 22.46


def _refine(ts, *, estimate_scale: bool = False, tracker_sigma=None):
    mount = mounting(ts.mode)
    Ms = np.stack([mount.M_from_T_base_end(T) for T in ts.T_base_end])
    log_scale0 = tracker_scale_start(ts.T_cam_board, Ms) if estimate_scale else None
    C = ts.T_cam_board.copy()
    if log_scale0 is not None:
        C[:, :3, 3] *= np.exp(-log_scale0)
    closed = all_methods(mount, C, Ms)
    views = [PoseView(v, ts.T_cam_board[k], ts.T_base_end[k]) for k, v in enumerate(ts.view_ids)]
    start = closed["tsai"]
    res = refine_poses(
        mode=ts.mode,
        views=views,
        T_x0=start.T_x,
        T_board0=start.T_board,
        starts=closed,
        tracker_sigma=tracker_sigma,
        log_scale0=log_scale0,
    )
    assert res.status == "ok", res.failure_reason
    return res


def test_the_region_factor_grows_as_the_views_decrease():
    """Fewer views: fewer degrees of freedom for the three sigmas, a larger factor on X's plug-in covariance."""
    dofs, factors = [], []
    for n in (40, 20, 10):
        ts = make_arm_tracker_session(mode="eye_in_hand", n_views=n, seed=4, axial_factor=4.0)
        res = _refine(ts)
        assert set(res.tracker_noise_dof) == {"rot", "trans", "trans_along"}
        # each group's redundancy: below its observation count (3n, 2n, n), the 12 parameters take their share
        assert res.tracker_noise_dof["rot"] < 3 * n and res.tracker_noise_dof["trans_along"] < n
        dofs.append(res.cov_x_noise_dof)
        factors.append(res.cov_x_dof_factor)
    assert dofs[0] > dofs[1] > dofs[2] > 0
    assert 1.0 < factors[0] < factors[1] < factors[2]
    # 10 views: the along-axis sigma from a handful of residuals; the region is far beyond chi-square(6)'s
    assert factors[2] > 1.15 and factors[0] < 1.06


def test_stated_sigmas_have_no_degrees_of_freedom_to_carry():
    ts = make_arm_tracker_session(mode="eye_to_hand", n_views=12, seed=2)
    res = _refine(ts, tracker_sigma=(np.radians(0.1), 0.0005, 0.0005))
    assert res.tracker_noise_dof == {} and res.cov_x_noise_dof is None and res.cov_x_dof_factor == 1.0
    d = res.to_dict()
    assert d["tracker_noise_dof"] == {} and d["cov_x_dof_factor"] == 1.0 and "tracker_scale" not in d


def test_the_noise_groups_parts_sum_to_the_plug_in_covariance():
    """``Sigma`` is homogeneous of degree 1 in the variances: its parts per noise group add up to it."""
    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=15, seed=9, axial_factor=3.0)
    mount = mounting(ts.mode)
    Ms = np.stack([mount.M_from_T_base_end(T) for T in ts.T_base_end])
    sigma = np.array([np.radians(0.1), 0.0005, 0.0015])
    st = _State(Ms, ts.T_cam_board, ts.truth.T_x_true, ts.truth.T_board_true, sigma, np.ones(15, bool))
    _, J = st.residuals(jacobians=True)
    W = st.W()
    S = np.linalg.inv(np.einsum("nki,nkl,nlj->ij", J, W, J))
    parts = covariance_parts(sigma, st.groups(), W, J, S)
    assert np.allclose(parts.sum(axis=0), S, rtol=1e-9, atol=1e-18)
    assert all(np.all(np.linalg.eigvalsh(0.5 * (p + p.T)) > -1e-15) for p in parts)


def _rotation_only_problem(n: int, p: int, seed: int):
    """Q (3,n,6,6) of unit weights and a J (n,6,p) that only the rotation group's rows inform."""
    rng = np.random.default_rng(seed)
    Q = np.zeros((3, n, 6, 6))
    Q[0, :, :3, :3] = np.eye(3)
    Q[1, :, 3:5, 3:5] = np.eye(2)
    Q[2, :, 5, 5] = 1.0
    J = np.zeros((n, 6, p))
    J[:, :3, :] = rng.normal(size=(n, 3, p))
    return Q, J


@pytest.mark.parametrize("p", [12, 13])
def test_one_estimated_sigma_gives_the_f_distributions_factor(p):
    """One variance estimated from r = 3n - p residuals, independent of the estimate: the plug-in Wald statistic
    of k parameters is exactly k F(k, r), so the resampled factor is that 95 % point over chi-square's."""
    n = 20
    Q, J = _rotation_only_problem(n, p, seed=3)
    sigma = np.array([0.002, 0.5e-3, 1.5e-3])
    S = np.linalg.inv(np.einsum("nki,nkl,nlj->ij", J, np.linalg.inv(np.einsum("g,gnij->nij", sigma**2, Q)), J))
    held = np.array([False, True, True])
    x, board, scale = resampled_factors(sigma, Q, J, S, held, np.zeros(3))
    r = 3 * n - p
    for got, k in ((x, 6), (board, 6)):
        assert got == pytest.approx(k * fdtri(k, r, 0.95) / chi2_ppf(0.95, k), rel=0.03)
    if p == 13:
        assert scale == pytest.approx(fdtri(1, r, 0.95) / chi2_ppf(0.95, 1), rel=0.04)
    else:
        assert scale == 1.0
    # every sigma held: nothing estimated, the plug-in is the covariance
    assert resampled_factors(sigma, Q, J, S, np.ones(3, bool), np.zeros(3))[:2] == (1.0, 1.0)


def test_a_prior_on_the_parameters_is_drawn_with_its_own_covariance():
    """A strong prior on every parameter (known) leaves nothing to the estimated sigma: factors of 1."""
    Q, J = _rotation_only_problem(20, 12, seed=4)
    sigma = np.array([0.002, 0.5e-3, 1.5e-3])
    W = np.linalg.inv(np.einsum("g,gnij->nij", sigma**2, Q))
    N = np.einsum("nki,nkl,nlj->ij", J, W, J)
    S = np.linalg.inv(N + 1e4 * np.trace(N) * np.eye(12))
    x, board, _ = resampled_factors(sigma, Q, J, S, np.array([False, True, True]), np.zeros(3))
    assert x == pytest.approx(1.0, abs=0.02) and board == pytest.approx(1.0, abs=0.02)


def test_the_resampled_factor_exceeds_satterthwaites_where_the_weights_were_estimated():
    """Three sigmas estimated from 20 eye-in-hand views: the weights the estimate used widen X's error beyond
    the sigmas' own spread (Satterthwaite's F), and the reported degrees of freedom are the factor's F."""
    st, J = _at_the_truth(seed=2)
    sigma = st.sigma
    W = st.W()
    S = np.linalg.inv(np.einsum("nki,nkl,nlj->ij", J, W, J))
    estimated = {"rot": True, "trans": True, "trans_along": True}
    dof = noise_dof(sigma, st.groups(), W, J, S, estimated)
    parts = covariance_parts(sigma, st.groups(), W, J, S)
    _, satterthwaite = estimated_parts_region_factor(S[:6, :6], [q[:6, :6] for q in parts], list(dof.dof.values()))
    assert dof.method == "resampled"
    assert dof.x_factor > satterthwaite * 1.05 > 1.0
    assert 6 * fdtri(6, dof.x_dof, 0.95) / chi2_ppf(0.95, 6) == pytest.approx(dof.x_factor, rel=1e-6)
    assert equivalent_dof(1.0, 6) is None
    # the arm path (each draw inverts the views' weights) with a vanishing extra covariance: the same factors
    sig = np.array([np.radians(0.1), 0.5e-3, 1.5e-3])
    st.sigma = sig
    S2 = _plug_in(J, st.W())
    fast = resampled_factors(sig, st.groups(), J, S2, np.zeros(3, bool), np.zeros(3))
    tiny = np.tile(np.eye(6) * 1e-16, (20, 1, 1))
    arm = resampled_factors(sig, st.groups(), J, S2, np.zeros(3, bool), np.zeros(3), extra=tiny, draws=4000)
    assert arm[0] == pytest.approx(fast[0], rel=0.04) and arm[1] == pytest.approx(fast[1], rel=0.04)


def test_an_arm_models_encoder_noise_is_resampled_with_the_tracker_sigmas():
    """Each view's covariance holds a known share too (an arm model's encoder noise): the more of it, the less the
    estimated sigmas move the weights, and the smaller the factor; once it dominates, the plug-in stands."""
    st, J = _at_the_truth(seed=2)
    sigma = st.sigma
    tracker = np.einsum("g,gnij->nij", sigma**2, st.groups())
    factors = []
    for k in (1e-12, 1.0, 10.0):
        W = np.linalg.inv(tracker * (1.0 + k))
        f = resampled_factors(sigma, st.groups(), J, _plug_in(J, W), np.zeros(3, bool), np.zeros(3), extra=k * tracker)
        factors.append(f[0])
    assert factors[0] > factors[1] > 1.05 and factors[2] < 1.02
    estimated = {"rot": True, "trans": True, "trans_along": True}
    W = np.linalg.inv(tracker * 2.0)
    dof = noise_dof(sigma, st.groups(), W, J, _plug_in(J, W), estimated, extra=tracker)
    assert dof.x_factor == pytest.approx(factors[1])


def _at_the_truth(seed: int):
    """(the pose-only state of a 20-view eye-in-hand session at its truth, 0.1 deg / 0.5 mm sigmas; its J)."""
    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=20, seed=seed)
    mount = mounting(ts.mode)
    Ms = np.stack([mount.M_from_T_base_end(T) for T in ts.T_base_end])
    sigma = np.array([np.radians(0.1), 0.5e-3, 0.5e-3])
    st = _State(Ms, ts.T_cam_board, ts.truth.T_x_true, ts.truth.T_board_true, sigma, np.ones(20, bool))
    return st, st.residuals(jacobians=True)[1]


def _plug_in(J: np.ndarray, W: np.ndarray) -> np.ndarray:
    return np.linalg.inv(np.einsum("nki,nkl,nlj->ij", J, W, J))


@pytest.mark.parametrize(("mode", "scale"), [("eye_in_hand", 1.6), ("eye_to_hand", 0.55)])
def test_a_scaled_tracker_session_recovers_its_scale_and_x(mode, scale):
    ts = make_arm_tracker_session(mode=mode, n_views=20, seed=5, scale=scale, sigma_mm=0.5, sigma_deg=0.1)
    res = _refine(ts, estimate_scale=True)
    s, sd = res.tracker_scale, res.tracker_scale_sigma
    assert s is not None and sd is not None and 0 < sd < 0.01 * scale
    assert abs(s - scale) < 3.0 * sd
    xi = se3_log(np.linalg.inv(res.T_x) @ ts.truth.T_x_true)
    assert xi @ np.linalg.solve(res.cov_x_6x6, xi) < M2_999
    rot_deg, trans_mm = pose_error(res.T_x, ts.truth.T_x_true)
    # 0.5 mm / 0.1 deg of tracker noise over 20 views: X to a few tenths of a degree and a few mm
    assert rot_deg < 0.3 and trans_mm < 5.0
    d = res.to_dict()["tracker_scale"]
    assert d["value"] == pytest.approx(s) and d["sigma"] == pytest.approx(sd)


def test_without_the_scale_a_scaled_session_is_far_off():
    """The same data with the scale taken as 1: X's translation absorbs the scale (what the finding names)."""
    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=20, seed=5, scale=1.6)
    res = _refine(ts)
    assert res.tracker_scale is None
    _, trans_mm = pose_error(res.T_x, ts.truth.T_x_true)
    assert trans_mm > 20.0


def test_a_metric_tracker_estimates_a_scale_of_one():
    ts = make_arm_tracker_session(mode="eye_to_hand", n_views=20, seed=8)
    res = _refine(ts, estimate_scale=True)
    assert abs(res.tracker_scale - 1.0) < 3.0 * res.tracker_scale_sigma


def test_calibrate_estimate_scale_writes_the_scale_and_no_scale_finding(tmp_path):
    from handeye.cli import main
    from handeye.contract import read_result

    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=20, seed=5, scale=2.0)
    ts.write(tmp_path / "s", state_sigma=False)
    rc = main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--no-report", "--estimate-scale"])
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    ref = r["refinement"]
    sc = ref["tracker_scale"]
    assert abs(sc["value"] - 2.0) < 3.0 * sc["sigma"]
    assert ref["cov_x_dof_factor"] > 1.0 and set(ref["tracker_noise_dof"]) == {"rot", "trans", "trans_along"}
    assert "tracker_scale" not in {f["code"] for f in r["findings"]}
    assert rc == 0 and r["verdict"] in ("PASS", "WARN")
    read_result(tmp_path / "o" / "result.json")  # the contract reads it back


def test_without_estimate_scale_the_finding_names_the_flag(tmp_path):
    from handeye.cli import main

    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=20, seed=5, scale=2.0)
    ts.write(tmp_path / "s", state_sigma=False)
    main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--no-report"])
    r = json.loads((tmp_path / "o" / "result.json").read_text())
    f = next(f for f in r["findings"] if f["code"] == "tracker_scale")
    assert "--estimate-scale" in f["action"] and "marker size" in f["action"]
    assert "tracker_scale" not in r["refinement"]


def test_estimate_scale_in_session_yaml_is_read(tmp_path):
    import yaml

    from handeye.workflow import calibrate_session

    ts = make_arm_tracker_session(mode="eye_to_hand", n_views=12, seed=6, scale=0.5)
    ts.write(tmp_path / "s", state_sigma=False)
    doc = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())
    doc["estimate_scale"] = True
    (tmp_path / "s" / "session.yaml").write_text(yaml.safe_dump(doc))
    calibrate_session(tmp_path / "s", out_dir=tmp_path / "o", report=False)
    sc = json.loads((tmp_path / "o" / "result.json").read_text())["refinement"]["tracker_scale"]
    assert abs(sc["value"] - 0.5) < 3.0 * sc["sigma"]


def test_estimate_scale_with_an_arm_model_is_refused_in_one_line(tmp_path, capsys):
    """The scale and the arm's DH offsets are not estimated in one graph: refused before any work, or failed
    with the reason when session.yaml asks for both."""
    import yaml

    from handeye.cli import main

    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=12, seed=6)
    ts.write(tmp_path / "s", state_sigma=False)
    rc = main(
        ["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--estimate-scale", "--robot", "ur5e"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--estimate-scale and --robot" in err[0]
    assert not (tmp_path / "o").exists()
    doc = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())
    doc |= {"estimate_scale": True, "robot": "ur5e"}
    (tmp_path / "s" / "session.yaml").write_text(yaml.safe_dump(doc))
    rc = main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o2"), "--no-report"])
    res = json.loads((tmp_path / "o2" / "result.json").read_text())
    assert rc != 0 and res["status"] == "failed" and "not estimated together" in res["failure_reason"]


def _image_session(tmp_path, extra: str = ""):
    d = tmp_path / "img"
    d.mkdir()
    flat = str([0.0, -1.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.2, 0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 1.0])
    (d / "a.png").write_bytes(b"x")
    (d / "session.yaml").write_text(
        "handeye_session: 1\nmode: eye_in_hand\ntarget: {type: chessboard, inner_corners: [11, 8], square_m: 0.03}\n"
        f"pose_format: {{rotation: matrix}}\n{extra}views:\n  - {{id: '1', image: a.png, pose: {flat}}}\n"
    )
    return d


def test_estimate_scale_on_an_image_session_is_refused_in_one_line(tmp_path, capsys):
    from handeye.cli import main

    d = _image_session(tmp_path)
    rc = main(["-q", "calibrate", str(d), "--out", str(tmp_path / "o"), "--no-report", "--estimate-scale"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "--estimate-scale" in err[0] and "square size" in err[0]
    assert not (tmp_path / "o" / "result.json").exists()


@pytest.mark.parametrize(("value", "message"), [("true", "pose-only sessions"), ("'yes'", "true or false")])
def test_estimate_scale_in_an_image_session_yaml_is_refused(tmp_path, value, message):
    from handeye.errors import ConfigError
    from handeye.session.native import read_native_document

    d = _image_session(tmp_path, extra=f"estimate_scale: {value}\n")
    with pytest.raises(ConfigError, match=message):
        read_native_document(d / "session.yaml")


def test_too_few_views_for_three_sigmas_fall_back_to_satterthwaite():
    """Five views leave the sigma along the optical axis about two degrees of freedom: many draws take it to its
    floor, where a view's weight has no bound and the resampled 95 % point would be the floor's. The factor is
    then Satterthwaite's; eight views are resampled."""
    few = _refine(make_arm_tracker_session(mode="eye_in_hand", n_views=5, seed=5, arm="ur5e"))
    assert few.cov_x_dof_method == "satterthwaite" and 1.2 < few.cov_x_dof_factor < 3.0
    assert few.to_dict()["cov_x_dof_method"] == "satterthwaite"
    enough = _refine(make_arm_tracker_session(mode="eye_in_hand", n_views=8, seed=8, arm="ur5e"))
    assert enough.cov_x_dof_method == "resampled" and 1.2 < enough.cov_x_dof_factor < 3.0
