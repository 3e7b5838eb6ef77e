"""verify's test on short checks of an unchanged rig: false alarms at its level, the statistic at its reference."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from handeye.camera import INTRINSIC_NAMES, Intrinsics, pixels_from_board_points
from handeye.frames import se3_exp
from handeye.recal.loaded import load_result, result_from_refinement
from handeye.recal.verify import JOINT_KIND, verify_views
from handeye.refine import RefineOptions, RefineView
from handeye.sim.corners import make_corner_session
from handeye.sim.scenarios import default_intrinsics

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from bench_refine import refine_from_tsai  # noqa: E402  (the pipeline's seeding)

ROBOT = (0.2, 0.05)  # mm, deg per axis: the simulated arm's noise, stated to the install (chi-square reference)
N_CHECKS = 20  # per mounting mode
ALPHA = 0.05


def _install(mode: str, seed: int):
    """A 12-view corner-level install whose robot noise is stated (known), as its loaded result."""
    s = make_corner_session(
        mode=mode,
        n_views=12,
        seed=seed,
        noise_px=0.3,
        robot_noise=ROBOT,
        intrinsics=default_intrinsics(640, 360),
    )
    ro = RefineOptions(robot_noise="fixed", robot_sigma_mm=ROBOT[0], robot_sigma_deg=ROBOT[1])
    r = refine_from_tsai(s, ro)
    assert r.status == "ok", r.failure_reason
    inst = load_result(result_from_refinement(r, target=s.target))
    assert inst.robot_noise_dof is None and inst.cov_x_intrinsics is not None
    return s, inst


def _rig_behind(inst, rng: np.random.Generator):
    """A rig the install could have come from: X and the intrinsics off the installed ones by a draw of its joint error.

    The installed (X0, K0) is the rig's truth plus an error with the installed joint covariance (H0 of the test:
    the rig did not change since); X0 = X Exp(e_x) in X's right tangent.
    """
    names, C, K = inst.cov_x_intrinsics
    S = np.block([[inst.cov_x, C], [C.T, K]])
    e = rng.multivariate_normal(np.zeros(len(S)), S)
    T_x = inst.T_x @ se3_exp(-e[:6])
    k = inst.intrinsics.as_vector().copy()
    k[[INTRINSIC_NAMES.index(n) for n in names]] -= e[6:]
    return T_x, Intrinsics.from_vector(k, inst.intrinsics.width, inst.intrinsics.height)


def _checks(mode: str, seed: int) -> list:
    s, inst = _install(mode, seed)
    rng = np.random.default_rng(seed + 1)
    obj = s.target.object_points()
    out = []
    for k in range(N_CHECKS):
        T_x, intr = _rig_behind(inst, rng)
        # poses and robot errors from the simulator (its visibility test with the simulated lens: an estimated k3
        # may fold back beyond the image), the corners projected through the drawn lens
        c = make_corner_session(
            mode=mode,
            n_views=4,
            seed=1000 * seed + k,
            noise_px=0.3,
            robot_noise=ROBOT,
            intrinsics=s.intrinsics,
            rig=(T_x, inst.T_board),
        )
        C = c.T_cam_board_true
        views = [
            RefineView(
                v,
                i,
                pixels_from_board_points(C[j], obj[i], intr) + rng.normal(0.0, 0.3, (len(i), 2)),
                c.T_base_end_reported[j],
            )
            for j, (v, i) in enumerate(zip(c.view_ids, c.corner_ids, strict=True))
        ]
        out.append(verify_views(inst, views=views, object_points=obj).test)
    return out


@pytest.fixture(scope="module")
def unchanged():
    return _checks("eye_in_hand", 21) + _checks("eye_to_hand", 22)


def _band(dist, level: float = 0.999) -> tuple[float, float]:
    return float(dist.ppf((1.0 - level) / 2.0)), float(dist.isf((1.0 - level) / 2.0))


def test_short_checks_of_an_unchanged_rig_raise_false_alarms_at_the_tests_level(unchanged):
    tests = unchanged
    assert all(t.kind == JOINT_KIND and t.noise_dof is None and t.dof == 6 for t in tests)
    n_alarms = sum(t.p_value < ALPHA for t in tests)
    lo, hi = _band(stats.binom(len(tests), ALPHA))  # 99.9 % of the count of false alarms under H0
    assert lo <= n_alarms <= hi, (n_alarms, len(tests), (lo, hi))
    # sharper: the statistics of independent checks sum to chi-square with the sum of their dof under H0
    total = sum(t.statistic for t in tests)
    lo, hi = _band(stats.chi2(sum(t.dof for t in tests)))
    assert lo <= total <= hi, (total / len(tests), (lo / len(tests), hi / len(tests)))
    # and the p-values spread over (0, 1) as they should (KS at 0.1 %)
    assert stats.kstest([t.p_value for t in tests], "uniform").pvalue > 1e-3


def test_a_pose_only_session_is_refused_in_one_line_naming_compare(tmp_path, capsys):
    """verify refines X on new images' corners: a tracker session is refused (exit 2), never a crash."""
    from handeye.cli import main
    from handeye.sim.arm_tracker import make_arm_tracker_session

    make_arm_tracker_session(arm="ur5e", seed=3, n_views=12).write(tmp_path / "s", state_sigma=False)
    main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "r"), "--no-report"])
    assert load_result(tmp_path / "r").status == "ok"
    capsys.readouterr()
    rc = main(["verify", str(tmp_path / "s"), "--against", str(tmp_path / "r"), "--out", str(tmp_path / "v")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "pose-only session" in err[0] and "handeye compare" in err[0]
    assert not (tmp_path / "v" / "verify.json").exists()


def test_images_against_a_tracker_s_calibration_name_both_targets_in_words(tmp_path, capsys):
    """Images of a chessboard verified against a pose-only result: refused in one line that names the installed
    target in words (it printed result.json's raw dict) and says what verify needs."""
    from handeye.cli import main
    from handeye.sim.arm_tracker import make_arm_tracker_session
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session

    make_arm_tracker_session(arm="ur5e", seed=3, n_views=12).write(tmp_path / "s", state_sigma=False)
    main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "r"), "--no-report"])
    images = write_vendor_session(tmp_path / "img", n_views=4, seed=5, intrinsics=default_intrinsics(400, 300))
    capsys.readouterr()
    rc = main(["verify", str(images), "--against", str(tmp_path / "r"), "--out", str(tmp_path / "v")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "expected the installed calibration's: tracked target (poses from an external tracker)" in err[0]
    assert "{" not in err[0] and "calibrated from images" in err[0]
