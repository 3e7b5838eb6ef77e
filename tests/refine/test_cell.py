"""A cell of cameras in one graph (handeye.refine.cell) on corner-level simulated cells with ground truth."""

import functools
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from handeye.errors import InputError
from handeye.frames import inv_T, se3_exp, tangent_difference, tangent_jacobian
from handeye.refine import RefineOptions, RefineView, refine
from handeye.refine.cell import CellCameraInput, CellState, refine_cell
from handeye.sim.cell import make_cell

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from bench_refine import closed_forms  # noqa: E402  (the pipeline's seeding, one copy)

CHI2_95 = chi2.ppf(0.95, 6)


def _views(s):
    return tuple(v for v in s.refine_views(s.joints_encoder) if len(v.corner_ids))  # hidden views: none


def _solo(s, options):
    """One camera as the pipeline calibrates it: calibrateCamera, solvePnP, the closed forms, refine()."""
    intr, closed = closed_forms(s)
    return refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=_views(s),
        intrinsics=intr,
        T_x0=closed["tsai"].T_x,
        T_board0=closed["tsai"].T_board,
        options=options,
        starts=closed,
    )


def _inputs(cell, solos):
    return [
        CellCameraInput(
            name=name,
            mode=s.mode,
            object_points=s.target.object_points(),
            views=_views(s),
            intrinsics=solos[name].intrinsics,
            T_x0=solos[name].T_x,
            T_board0=solos[name].T_board,
            sigma_px=solos[name].sigma_px,
        )
        for name, s in zip(cell.names, cell.sessions, strict=True)
    ]


@functools.lru_cache(maxsize=None)
def _run(n_cameras: int, seed: int, outliers: tuple = ()):
    cell = make_cell(n_cameras, n_views=20, seed=seed, arm="ur5e", outlier_views=outliers)
    o = RefineOptions(arm="ur5e")
    solos = {name: _solo(s, o) for name, s in zip(cell.names, cell.sessions, strict=True)}
    return cell, solos, refine_cell(_inputs(cell, solos), options=o)


def _m2(T_est, C, T_true):
    xi = tangent_difference(T_est, T_true)
    return float(xi @ np.linalg.solve(C, xi))


def test_noiseless_cell_recovers_every_camera_and_pair():
    """Exact corners and robot poses: every X, the shared boards and the pairs to ~1e-8."""
    cell = make_cell(3, n_views=12, seed=2, noise_px=0.0, robot_error="none")
    ins = []
    for name, s in zip(cell.names, cell.sessions, strict=True):
        T_start = s.T_x_true @ se3_exp(np.r_[0.01, -0.01, 0.005, 0.003, 0.002, -0.004])
        ins.append(
            CellCameraInput(
                name=name,
                mode=s.mode,
                object_points=s.target.object_points(),
                views=_views(s),
                intrinsics=s.intrinsics,
                T_x0=T_start,
                T_board0=s.T_board_true,
                sigma_px=0.1,
            )
        )
    cr = refine_cell(ins, options=RefineOptions(robot_noise="none", intrinsics="fixed"))
    for name, s in zip(cell.names, cell.sessions, strict=True):
        assert np.abs(tangent_difference(cr.T_x[name], s.T_x_true)).max() < 1e-8
    assert [b["name"] for b in cr.boards] == ["T_end_board", "T_base_board"]
    assert cr.boards[0]["cameras"] == ["cam1", "cam2"]
    T_12, _ = cr.pair("cam1", "cam2")
    T_true = inv_T(cell.sessions[0].T_x_true) @ cell.sessions[1].T_x_true
    assert np.abs(tangent_difference(T_12, T_true)).max() < 1e-8
    assert cr.pairs() == [("cam1", "cam2")]  # a wrist camera has no constant transform to a fixed one


def test_each_camera_is_inside_its_95_percent_region_and_no_worse_than_alone():
    """Three 3-camera cells (kinematic arm error): every X inside the 95 % ellipsoid of its joint covariance,
    and the joint X closer to the truth than the solo one on average over cameras and seeds."""
    err_joint, err_solo, m2 = [], [], []
    for seed in (0, 1, 3):
        cell, solos, cr = _run(3, seed)
        for name, s in zip(cell.names, cell.sessions, strict=True):
            m2.append(_m2(cr.T_x[name], cr.cov_x(name), s.T_x_true))
            err_joint.append(np.sum(tangent_difference(cr.T_x[name], s.T_x_true)[3:] ** 2))
            err_solo.append(np.sum(tangent_difference(solos[name].T_x, s.T_x_true)[3:] ** 2))
            assert cr.sigma_px[name] == pytest.approx(0.3, rel=0.15)  # the simulated corner noise
        assert not cr.robot_excluded and not any(cr.camera_removed.values())
    assert max(m2) < CHI2_95, m2
    assert np.mean(err_joint) <= np.mean(err_solo), (np.sqrt(np.mean(err_joint)), np.sqrt(np.mean(err_solo)))


def test_the_joint_covariance_is_tighter_than_each_solo_one():
    """The cameras share the arm's error and the board: each X's covariance is no larger than alone."""
    cell, solos, cr = _run(3, 0)
    for name in cell.names:
        diff = np.asarray(solos[name].cov_x_6x6) - cr.cov_x(name)
        assert np.linalg.eigvalsh(0.5 * (diff + diff.T)).min() > -1e-12 * np.trace(solos[name].cov_x_6x6)


def test_camera_pair_against_the_truth_and_its_linearisation():
    cell, _solos, cr = _run(3, 0)
    T_ab, C = cr.pair("cam1", "cam2")
    T_true = inv_T(cell.session("cam1").T_x_true) @ cell.session("cam2").T_x_true
    assert _m2(T_ab, C, T_true) < CHI2_95
    # the covariance's Jacobian: T_a_b moved by X_a Exp(e_a), X_b Exp(e_b), numerically on the manifold
    Xa, Xb = cr.T_x["cam1"], cr.T_x["cam2"]
    J_a = tangent_jacobian(lambda T: tangent_difference(T_ab, inv_T(T) @ Xb), Xa)
    J_b = tangent_jacobian(lambda T: tangent_difference(T_ab, inv_T(Xa) @ T), Xb)
    xa, xb = cr.x_block("cam1"), cr.x_block("cam2")
    S = np.block([[cr.cov_of(xa), cr.cov_of(xa, xb)], [cr.cov_of(xb, xa), cr.cov_of(xb)]])
    J = np.hstack([J_a, J_b])
    np.testing.assert_allclose(C, J @ S @ J.T, rtol=1e-4, atol=1e-14)


def test_a_bad_robot_pose_is_named_once_for_the_cell():
    """A gross error on one reported pose: every camera disagrees with it, the cell excludes it once."""
    cell, _solos, cr = _run(3, 1, ("7",))
    assert list(cr.robot_excluded) == ["7"]
    assert cr.robot_excluded["7"]["p_value"] < 1e-6
    assert not any(cr.camera_removed.values())
    for name, s in zip(cell.names, cell.sessions, strict=True):
        assert _m2(cr.T_x[name], cr.cov_x(name), s.T_x_true) < chi2.ppf(0.99, 6)


def test_a_bad_image_of_one_camera_leaves_that_camera_only():
    """One camera's corners of one view from another pose: that camera's view is removed, the pose stays."""
    cell, solos, _cr = _run(3, 0)
    ins = _inputs(cell, solos)
    views = list(ins[1].views)
    bad = 3
    vid = views[bad].view_id
    views[bad] = RefineView(
        vid,
        views[bad].corner_ids,
        views[bad].image_points + np.r_[6.0, -4.0],
        views[bad].T_base_end,
        views[bad].joint_angles,
    )
    ins[1] = CellCameraInput(**{**ins[1].__dict__, "views": tuple(views)})
    cr = refine_cell(ins, options=RefineOptions(arm="ur5e"))
    assert list(cr.camera_removed["cam2"]) == [vid]
    assert not cr.robot_excluded and not cr.camera_removed["cam1"] and not cr.camera_removed["wrist"]
    assert cr.per_view["cam2"][vid]["status"] == "removed" and cr.per_view["wrist"][vid]["status"] == "used"


def test_cameras_that_disagree_about_a_reported_pose_are_refused():
    cell, solos, _cr = _run(3, 0)
    ins = _inputs(cell, solos)
    v = ins[0].views[0]
    moved = RefineView(v.view_id, v.corner_ids, v.image_points, v.T_base_end @ se3_exp(np.r_[0, 0, 0, 0.001, 0, 0]))
    ins[0] = CellCameraInput(**{**ins[0].__dict__, "views": (moved,) + ins[0].views[1:]})
    with pytest.raises(InputError, match=f"view {v.view_id}: camera cam2 has another robot pose"):
        refine_cell(ins, options=RefineOptions(arm="ur5e"))


def test_a_cell_without_a_camera_and_view_effect_keeps_one_pose_per_view():
    """The simulated cameras see each view's one robot pose: the test of one pose per view stands."""
    for seed in (0, 1):
        _cell, _solos, cr = _run(3, seed)
        t = cr.view_poses["test"]
        assert not t["contradicted"] and t["p_value"] >= 0.01 and t["dof"][0] > 0, t
        assert cr.view_poses["estimated"] is False and "sigma_rot_deg" not in cr.view_poses


def test_cameras_that_see_the_arm_at_their_own_instants():
    """Each fixed camera sees every view's flange moved by its own 0.1 deg / 0.2 mm (per axis): the test rejects
    one pose per view, the cell estimates that deviation, and each X stays inside its 95 % region; one shared
    pose per view forces the cameras' disagreement into the X and claims too small a covariance."""
    from unittest import mock

    import handeye.refine.cell as cell_module

    cell = make_cell(2, n_views=20, seed=0, arm="ur5e", view_jitter=(0.1, 0.2))
    o = RefineOptions(arm="ur5e")
    solos = {name: _solo(s, o) for name, s in zip(cell.names, cell.sessions, strict=True)}
    ins = _inputs(cell, solos)
    cr = refine_cell(ins, options=o)
    vp = cr.view_poses
    assert vp["test"]["contradicted"] and vp["test"]["p_value"] < 1e-20 and vp["estimated"]
    assert 0.07 < vp["sigma_rot_deg"] < 0.13 and 0.14 < vp["sigma_trans_mm"] < 0.26, vp
    assert vp["camera_views"] == 2 * sum(1 for v in cell.sessions[0].view_ids if v not in _hidden(cell))
    m2 = [_m2(cr.T_x[n], cr.cov_x(n), s.T_x_true) for n, s in zip(cell.names, cell.sessions, strict=True)]
    preset = cell_module.refine_preset()
    never = {**preset, "noise": {**preset["noise"], "view_pose_alpha": 0.0}}  # one pose per view, always
    with mock.patch.object(cell_module, "refine_preset", lambda: never):
        shared = refine_cell(ins, options=o)
    assert not shared.view_poses["estimated"]
    m2_shared = [
        _m2(shared.T_x[n], shared.cov_x(n), s.T_x_true) for n, s in zip(cell.names, cell.sessions, strict=True)
    ]
    assert max(m2_shared) > CHI2_95 > max(m2), (m2_shared, m2)


def _hidden(cell) -> set:
    return {v for s in cell.sessions for v in s.hidden_view_ids}


def test_the_arm_model_offsets_mean_the_simulated_dh_errors():
    """The cell's kinematic prior, at the true robot poses, with the simulated arm's DH errors as its offsets:
    each view's whitened robot residual is the encoder noise alone (chi-square 6 dof), without them far larger.

    The benchmark's bounds (benchmarks/bench_cell.py) take the true offsets in this order and sign.
    """
    cell = make_cell(2, n_views=40, seed=3, arm="ur5e")
    first = cell.sessions[0]
    ins = [
        CellCameraInput(
            name=name,
            mode=s.mode,
            object_points=s.target.object_points(),
            views=_views(s),
            intrinsics=s.intrinsics,
            T_x0=s.T_x_true,
            T_board0=s.T_board_true,
            sigma_px=0.3,
        )
        for name, s in zip(cell.names, cell.sessions, strict=True)
    ]
    st = CellState(ins, RefineOptions(arm="ur5e"))
    st.P = np.array([first.T_base_end_true[first.index(v)] for v in st.ids])
    st.sigma_q = np.radians(first.robot_model["encoder_sigma_deg"])

    def whitened(dh):
        st.dh = dh
        return [float(st.prior_residual(u) @ np.linalg.solve(st.prior_cov(u), st.prior_residual(u))) for u in st.seen()]

    dh_true = (np.asarray(first.robot_model["dh_true"]) - np.asarray(first.robot_model["dh_nominal"])).ravel()
    m2 = whitened(dh_true)
    # mean of n chi-square(6) draws: 6 within 4 of its standard errors (sqrt(12 / n))
    assert abs(np.mean(m2) - 6) < 4 * np.sqrt(12 / len(m2)), np.mean(m2)
    assert np.mean(whitened(np.zeros_like(dh_true))) > 100


def test_bench_cell_bound_uses_the_simulated_dh_spread():
    """benchmarks/bench_cell.py's bound of the simulated problem: its DH prior is the second moment of the
    simulator's DH error draw (a magnitude uniform in a range, a random sign), checked on 400 drawn arms."""
    import importlib.util
    from pathlib import Path

    from handeye.kinematics import load_arm
    from handeye.sim.robot_error import sample_true_arm

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_cell.py"
    spec = importlib.util.spec_from_file_location("bench_cell_bound", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    nominal = load_arm("ur5e")
    rng = np.random.default_rng(7)
    err = np.stack([sample_true_arm(nominal, rng=rng).dh - nominal.dh for _ in range(400)])  # (400, 6, 4)
    length, angle = np.square(err[..., [0, 2]]).ravel(), np.square(err[..., [1, 3]]).ravel()
    expected = bench.sim_dh_second_moment()
    for sample, m in ((length, expected[0]), (angle, expected[1])):  # within 4 standard errors of the mean
        assert abs(sample.mean() - m) < 4 * sample.std() / np.sqrt(sample.size), (sample.mean(), m)
    # the arm's stated prior (0.3 mm / 0.03 deg) is narrower than the simulated spread (RMS 0.321 / 0.0321)
    assert np.sqrt(expected[0]) * 1e3 == pytest.approx(0.3215, abs=1e-4)
    assert np.degrees(np.sqrt(expected[1])) == pytest.approx(0.03215, abs=1e-5)
