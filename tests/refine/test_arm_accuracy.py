"""The arm's stated accuracy: the error it models is the one the data cannot show, mapped into X exactly."""

from __future__ import annotations

import json

import numpy as np
import pytest

from handeye.frames import inv_T, se3_exp, tangent_difference
from handeye.mounting import mounting
from handeye.refine.arm_accuracy import arm_accuracy, arm_accuracy_covariance
from handeye.refine.problem import solve_pose_graph
from handeye.sim.arm_tracker import make_arm_tracker_session


def _solve(mode, T_base_end, C, T_x0, T_board0):
    m = mounting(mode)
    M = np.stack([m.M_from_T_base_end(T) for T in T_base_end])
    cov = np.tile(np.diag([1e-6] * 3 + [1e-8] * 3), (len(C), 1, 1))
    T_x, _, _ = solve_pose_graph(M=M, T_cam_board=C, covariances=cov, T_x0=T_x0, T_board0=T_board0)
    return T_x


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_a_constant_arm_error_moves_x_as_the_covariance_maps_it(mode):
    """Noise-free views of an arm whose flange (eye-in-hand) or base (eye-to-hand) is off by one constant error.

    The solve fits them exactly with another X, displaced by the error mapped as arm_accuracy_covariance's
    Jacobian says: xi = +-A e, so xi's squared Mahalanobis distance under A S A^T is e's under S.
    """
    ts = make_arm_tracker_session(mode=mode, n_views=15, seed=3, sigma_mm=1e-9, sigma_deg=1e-10)
    t = ts.truth
    T_rep = ts.T_base_end
    rng = np.random.default_rng(0)
    e = np.r_[np.radians(rng.normal(0, 0.1, 3)), rng.normal(0, 0.001, 3)]
    if mode == "eye_in_hand":
        T_true = T_rep @ se3_exp(e)[None]
        C = inv_T(t.T_x_true)[None] @ inv_T(T_true) @ t.T_board_true[None]
    else:
        T_c = np.eye(4)
        T_c[:3, 3] = T_rep[:, :3, 3].mean(axis=0)
        T_true = (T_c @ se3_exp(e) @ inv_T(T_c))[None] @ T_rep
        C = inv_T(t.T_x_true)[None] @ T_true @ t.T_board_true[None]
    T_x = _solve(mode, T_rep, C, t.T_x_true, t.T_board_true)
    xi = tangent_difference(T_x, t.T_x_true)  # the right-tangent error of the estimate, as the covariance's
    assert np.linalg.norm(xi[3:]) > 2e-4  # the error moved X: it is not absorbed by the board's pose
    # the mapping: xi = +-A e with A S A^T the covariance
    S = np.diag([np.radians(1.0) ** 2] * 3 + [1e-6] * 3)
    cov = arm_accuracy_covariance(mode, T_x, T_rep, sigma_mm=1.0, sigma_deg=1.0)
    # xi must lie where cov says: its squared Mahalanobis distance equals e's under S
    m2_xi = float(xi @ np.linalg.solve(cov, xi))
    m2_e = float(e @ np.linalg.solve(S, e))
    assert m2_xi == pytest.approx(m2_e, rel=2e-3)


def test_a_session_with_a_stated_accuracy_carries_it_in_the_verdict(tmp_path):
    """calibrate with --robot-accuracy: result.json's verdict covariance is the validated one plus the term."""
    from handeye.cli import main

    ts = make_arm_tracker_session(mode="eye_to_hand", n_views=16, seed=5)
    ts.write(tmp_path / "s", state_sigma=False)
    assert main(["calibrate", str(tmp_path / "s"), "--no-report", "--out", str(tmp_path / "a")]) == 0
    code = main(
        [
            "calibrate",
            str(tmp_path / "s"),
            "--no-report",
            "--out",
            str(tmp_path / "b"),
            "--robot-accuracy",
            "0.5",
            "0.05",
        ]
    )
    assert code == 0
    a = json.loads((tmp_path / "a" / "result.json").read_text())["refinement"]
    b = json.loads((tmp_path / "b" / "result.json").read_text())["refinement"]
    assert "robot_accuracy" not in a
    acc = b["robot_accuracy"]
    assert (acc["sigma_mm"], acc["sigma_deg"]) == (0.5, 0.05)
    base = np.asarray(a.get("cov_x_6x6_verdict", a["cov_x_6x6"]))
    np.testing.assert_allclose(np.asarray(b["cov_x_6x6_verdict"]), base + np.asarray(acc["cov_x_6x6"]), atol=1e-15)
    assert all(sb > sa for sa, sb in zip(a["sigma_trans_mm"], b["sigma_trans_mm"], strict=True))
    # the stated 0.5 mm per axis at the least, and the 0.05 deg lever over the camera's distance on top
    added_mm2 = np.trace(np.asarray(acc["cov_x_6x6"])[3:, 3:]) * 1e6
    assert 3 * 0.5**2 < added_mm2 < 3 * (0.5 + 2.0 * np.radians(0.05) * 1e3) ** 2
    T_x = np.asarray(b["T_base_cam"])
    expect = arm_accuracy("eye_to_hand", T_x, ts.T_base_end, (0.5, 0.05)).cov_x_6x6
    np.testing.assert_allclose(np.asarray(acc["cov_x_6x6"]), expect, rtol=1e-9, atol=1e-18)


def test_a_stated_accuracy_with_the_arm_model_is_refused(tmp_path, capsys):
    from handeye.cli import main

    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=12, seed=2)
    ts.write(tmp_path / "s", state_sigma=False)
    args = ["calibrate", str(tmp_path / "s"), "--no-report", "--out", str(tmp_path / "o")]
    assert main([*args, "--robot", "ur5e", "--robot-accuracy", "0.5", "0.05"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--robot-accuracy" in err[0] and "kinematic model" in err[0]
    res = json.loads((tmp_path / "o" / "result.json").read_text())  # a failed run still says why
    assert res["status"] == "failed" and res["error"]["code"] == "config_error" and "refinement" not in res


def test_a_malformed_robot_accuracy_names_the_file(tmp_path, capsys):
    import yaml

    from handeye.cli import main

    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=12, seed=2)
    path = ts.write(tmp_path / "s", state_sigma=False)
    d = yaml.safe_load(path.read_text())
    d["robot_accuracy"] = {"mm": 0.5}
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    assert main(["calibrate", str(tmp_path / "s"), "--no-report", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "session.yaml" in err and "robot_accuracy" in err


def test_an_image_session_takes_the_stated_accuracy_too(tmp_path):
    """The common error is geometry, not the sensor: an image session adds the same term to its verdict."""
    from handeye.cli import main

    assert main(["simulate", str(tmp_path / "s"), "--views", "8", "--seed", "3"]) == 0
    args = ["calibrate", str(tmp_path / "s"), "--no-report", "--robot-accuracy", "0.3", "0.03"]
    assert main([*args, "--out", str(tmp_path / "o")]) == 0  # PASS or WARN: a result either way
    ref = json.loads((tmp_path / "o" / "result.json").read_text())["refinement"]
    acc = np.asarray(ref["robot_accuracy"]["cov_x_6x6"])
    T_x = np.asarray(ref["T_end_cam"])
    np.testing.assert_allclose(acc, arm_accuracy("eye_in_hand", T_x, np.eye(4)[None], (0.3, 0.03)).cov_x_6x6)
    # eye-in-hand: the flange error maps to the camera with the lever of T_end_cam only, so every translation
    # sigma is at least the stated 0.3 mm and at most that plus the 0.03 deg over the camera's offset
    lever_mm = np.linalg.norm(T_x[:3, 3]) * 1e3 * np.radians(0.03)
    assert all(0.3 <= s <= np.hypot(0.3 + lever_mm, 0.05) for s in ref["sigma_trans_mm"])


def test_a_cell_refuses_the_stated_accuracy_in_one_line(tmp_path, capsys):
    from handeye.cli import main

    for name, seed in (("a", 1), ("b", 2)):
        make_arm_tracker_session(mode="eye_to_hand", n_views=10, seed=seed).write(tmp_path / name, state_sigma=False)
    args = ["calibrate", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(tmp_path / "o")]
    assert main([*args, "--robot-accuracy", "0.5", "0.05"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--robot-accuracy is for one session" in err[0]
    assert not (tmp_path / "o").exists()


def test_the_arms_common_error_cancels_where_a_result_meets_its_own_arm(tmp_path):
    """verify, compare and a prior read X's covariance less the stated accuracy; export states the whole."""
    from handeye.cli import main
    from handeye.recal.loaded import load_result

    ts = make_arm_tracker_session(mode="eye_in_hand", n_views=14, seed=4)
    ts.write(tmp_path / "s", state_sigma=False)
    out = tmp_path / "o"
    assert (
        main(["calibrate", str(tmp_path / "s"), "--no-report", "--out", str(out), "--robot-accuracy", "0.5", "0.05"])
        == 0
    )
    ref = json.loads((out / "result.json").read_text())["refinement"]
    verdict, arm = np.asarray(ref["cov_x_6x6_verdict"]), np.asarray(ref["robot_accuracy"]["cov_x_6x6"])
    same_arm = load_result(out)
    np.testing.assert_allclose(same_arm.cov_x, verdict - arm, atol=1e-18)
    assert "less robot_accuracy" in same_arm.cov_source
    np.testing.assert_allclose(load_result(out, absolute=True).cov_x, verdict, atol=1e-18)
    assert main(["export", str(out), "--to", "json", "--out", str(tmp_path / "x")]) == 0
    exported = json.loads((tmp_path / "x.json").read_text())
    text = json.dumps(exported)
    assert "cov_x_6x6_verdict" in text and "less robot_accuracy" not in text


def test_the_qa_advice_names_the_arm_when_its_accuracy_dominates(tmp_path, capsys):
    """A stated accuracy far above what the views resolve: the advice is not "add views"."""
    from handeye.cli import main

    make_arm_tracker_session(mode="eye_to_hand", n_views=16, seed=5).write(tmp_path / "s", state_sigma=False)
    args = ["calibrate", str(tmp_path / "s"), "--no-report", "--out", str(tmp_path / "o")]
    assert main([*args, "--robot-accuracy", "3", "0.5"]) in (0, 7)  # WARN (0) or FAIL (7): the arm's 3 mm / 0.5 deg
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if "uncertainty" in ln and "->" in ln]
    assert lines and all("of this uncertainty is the arm's stated accuracy" in ln for ln in lines)
    assert "add views" not in " ".join(lines)
