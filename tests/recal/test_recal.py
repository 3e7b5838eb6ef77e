"""Recalibration: compare two results, verify a short session against an installed calibration,
calibrate with an earlier result as the prior, and plan a verification."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from handeye.cli import main
from handeye.errors import DRIFTED_EXIT_CODE, EXIT_CODES, InputError
from handeye.frames import se3_adjoint, se3_exp
from handeye.recal.compare import compare_results
from handeye.recal.loaded import load_result

SIGMA_ROT = np.radians(0.05)  # rad
SIGMA_TRANS = 0.3e-3  # m


def fake_result(T_x=None, *, mode="eye_in_hand", size=(1280, 720), square_m=0.03, cov=None, fx=910.0) -> dict:
    """The parts of a result.json that compare reads, with a known covariance."""
    x_name = "T_end_cam" if mode == "eye_in_hand" else "T_base_cam"
    board_name = "T_base_board" if mode == "eye_in_hand" else "T_end_board"
    T_x = np.eye(4) if T_x is None else T_x
    cov = np.diag([SIGMA_ROT**2] * 3 + [SIGMA_TRANS**2] * 3) if cov is None else cov
    return {
        "handeye_result": 1,
        "status": "ok",
        "mode": mode,
        "hand_eye": {"name": x_name},
        "board": {"name": board_name},
        x_name: T_x.tolist(),
        board_name: np.eye(4).tolist(),
        "intrinsics": {
            "fx": fx,
            "fy": 909.0,
            "cx": 640.0,
            "cy": 360.0,
            "image_size": list(size),
            "dist": {"k1": 0.1, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0},
        },
        "target": {"type": "chessboard", "inner_corners": [11, 8], "square_m": square_m},
        "refinement": {
            "cov_x_6x6": cov.tolist(),
            "intrinsics_sigma": {"fx": 0.5, "fy": 0.5, "cx": 0.4, "cy": 0.4},
            "cov_parametrisation": "GTSAM Pose3 tangent, right perturbation: ..., rotation first",
            "sigma_px": 0.3,
            "robot_sigma_mm": 0.2,
            "robot_sigma_deg": 0.05,
        },
    }


# ------------------------------------------------------------------------------ compare
def test_compare_identical_results_is_zero_and_not_drifted():
    T = se3_exp(np.array([0.1, -0.2, 0.3, 0.05, 0.02, 0.1]))
    c = compare_results(fake_result(T), fake_result(T))
    assert c.comparable and c.frame == "T_end_cam"
    assert c.mahalanobis2 == pytest.approx(0.0, abs=1e-12) and c.p_value == pytest.approx(1.0)
    assert not c.drifted and c.trans_mm == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(
    "damage,what",
    [
        (lambda d: d["T_end_cam"][0].__setitem__(3, float("nan")), "T_end_cam is not a finite 4x4 rigid transform"),
        (lambda d: d["T_end_cam"][0].__setitem__(0, 2.0), "T_end_cam is not a finite 4x4 rigid transform"),
        (
            lambda d: d["refinement"]["cov_x_6x6"][0].__setitem__(0, -1.0),
            "refinement.cov_x_6x6 is not a finite symmetric",
        ),
        (lambda d: d["intrinsics"].__setitem__("fx", float("nan")), "intrinsics.fx is nan"),
    ],
)
def test_a_damaged_result_is_refused_by_every_command_that_reads_it(tmp_path, capsys, damage, what):
    """A NaN or an edited matrix in result.json would flow into compare as "no change" (p = nan), into export
    and apply as numbers: each command refuses it in one line naming the entry."""
    good, bad = tmp_path / "good", tmp_path / "bad"
    for folder in (good, bad):
        folder.mkdir()
        d = fake_result()
        if folder is bad:
            damage(d)
        (folder / "result.json").write_text(json.dumps(d))
    argvs = [["compare", str(good), str(bad)], ["export", str(bad), "--to", "json", "--out", str(tmp_path / "x.json")]]
    if "T_end_cam" in what:
        argvs.append(["apply", str(bad), "--point", "0", "0", "0.5", "--end-pose", "0.5", "0", "0.5", "3.1", "0", "0"])
    for argv in argvs:
        rc = main(["-q", *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and f"damaged: {what}" in err[0], (argv, err)
    assert not (tmp_path / "x.json").exists()


def test_a_result_that_failed_qa_is_used_with_a_warning(tmp_path, caplog):
    """compare and apply use a result whose verdict is FAIL as it is, and say so (export refuses it)."""
    good, failed = tmp_path / "good", tmp_path / "failed"
    for folder, extra in ((good, {}), (failed, {"verdict": "FAIL", "verdict_headline": "T_end_cam fails QA: x."})):
        folder.mkdir()
        (folder / "result.json").write_text(json.dumps(dict(fake_result(), **extra)))
    for argv in (
        ["compare", str(good), str(failed)],
        ["apply", str(failed), "--point", "0", "0", "0.5", "--end-pose", "0.5", "0", "0.5", "3.1", "0", "0"],
    ):
        caplog.clear()
        with caplog.at_level("WARNING"):
            assert main(argv) == 0
        assert "this calibration's verdict is FAIL (T_end_cam fails QA: x); it is used as it is" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        main(["compare", str(good), str(good)])
    assert "verdict is FAIL" not in caplog.text


def test_compare_known_difference_gives_the_chi2_statistic():
    T_a = se3_exp(np.array([0.1, -0.2, 0.3, 0.05, 0.02, 0.1]))
    xi = np.array([np.radians(0.1), 0.0, 0.0, 2e-3, 0.0, 0.0])  # 0.1 deg about camera x, 2 mm along camera x
    T_b = T_a @ se3_exp(xi)
    cov = np.diag([SIGMA_ROT**2] * 3 + [SIGMA_TRANS**2] * 3)
    Ad = se3_adjoint(se3_exp(xi))
    expected = xi @ np.linalg.solve(cov + Ad @ cov @ Ad.T, xi)
    c = compare_results(fake_result(T_a), fake_result(T_b))
    assert c.mahalanobis2 == pytest.approx(expected, rel=1e-9)
    assert c.p_value == pytest.approx(stats.chi2.sf(expected, 6), rel=1e-9)
    assert c.drifted  # 2 mm against a 0.42 mm sigma of the difference: d2 ~ 24
    assert c.d_rot_deg == pytest.approx([0.1, 0.0, 0.0], abs=1e-9)
    assert c.trans_mm == pytest.approx(2.0, rel=1e-6)  # |t_b - t_a| = |R_a J v| = |v|
    d = c.to_dict()
    assert d["dof"] == 6 and d["frame"] == "T_end_cam" and d["drifted"] is True
    assert c.intrinsics["fx"]["diff"] == 0.0 and c.intrinsics["p_value"] == pytest.approx(1.0)
    assert c.robot_noise_dof is None and d["reference"] == "chi-square(6)"
    # both results estimated their robot noise (A: rotation 10 and translation 30 dof, Satterthwaite's 30 for equal
    # parts; B: 60): their covariances rest on the estimates, and the difference's (half of it from each, the same
    # covariances here) has 1 / (0.25/30 + 0.25/60) = 80 dof
    a, b = fake_result(T_a), fake_result(T_b)
    a["refinement"]["robot_noise_dof"], b["refinement"]["robot_noise_dof"] = {"rot": 10.0, "trans": 30.0}, {"rot": 60.0}
    assert load_result(a).robot_noise_dof == pytest.approx(30.0)
    cf = compare_results(a, b)
    assert cf.robot_noise_dof == pytest.approx(1.0 / (0.25 / 30 + 0.25 / 60), rel=1e-3)
    assert cf.p_value == pytest.approx(stats.f.sf(expected / 6, 6, cf.robot_noise_dof), rel=1e-9)
    assert cf.p_value > c.p_value  # the heavier tail
    assert cf.to_dict()["reference"].startswith("6 × F(6, 80)")
    # results whose X covariance was multiplied for those degrees of freedom already are compared as known
    a["refinement"]["cov_x_dof_factor"] = b["refinement"]["cov_x_dof_factor"] = 1.05
    ck = compare_results(a, b)
    assert ck.robot_noise_dof is None and ck.to_dict()["reference"] == "chi-square(6)"
    assert ck.p_value == pytest.approx(c.p_value, rel=1e-9)


def test_compare_prefers_the_verdict_covariance():
    a, b = fake_result(), fake_result(se3_exp(np.array([0, 0, 0, 1e-3, 0, 0])))
    wide = np.diag([SIGMA_ROT**2] * 3 + [(2e-3) ** 2] * 3)
    for r in (a, b):
        r["refinement"]["cov_x_6x6_verdict"] = wide.tolist()
    c = compare_results(a, b)
    assert c.cov_sources == ("cov_x_6x6_verdict", "cov_x_6x6_verdict")
    assert c.mahalanobis2 == pytest.approx(1.0 / 8.0, rel=1e-6) and not c.drifted and c.note == ""
    b["prior"] = {"used": "prior", "source": "a/result.json"}  # B updated from A: not independent
    assert "not independent" in compare_results(a, b).note
    b["prior"] = {
        "used": "no prior on X (...)",
        "source": "a/result.json",
        "board_prior": True,
        "intrinsics": "the prior's, with its sigmas",
    }  # a contradicted prior: its intrinsics and board stay
    assert "intrinsics and board pose of a/result.json as priors" in compare_results(a, b).note
    b["prior"].update(intrinsics="the session's own", board_prior=False)  # nothing of A stayed a prior
    assert compare_results(a, b).note == ""


def _joint_result(T_x, k, D, H, K) -> dict:
    """A result whose X error is ``D`` plus what its intrinsics error (fx, fy, cx, cy; covariance ``K``) causes
    through ``H`` (6,4): the joint covariance result.json's cov_x_intrinsics carries."""
    r = fake_result(T_x)
    S = D + H @ K @ H.T
    r["intrinsics"].update(fx=k[0], fy=k[1], cx=k[2], cy=k[3])
    r["refinement"].update(
        cov_x_6x6=S.tolist(),
        intrinsics_sigma=dict(zip(("fx", "fy", "cx", "cy"), np.sqrt(np.diag(K)), strict=False)),
        cov_x_intrinsics={
            "intrinsics": ["fx", "fy", "cx", "cy"],
            "cross_6xk": (H @ K).tolist(),
            "intrinsics_kxk": K.tolist(),
        },
    )
    return r


def test_compare_takes_out_the_part_of_the_difference_the_intrinsics_explain():
    # X's error tied to its principal point (cx tilts X about the camera y axis and shifts it along x) and fx to
    # fy: compare tests X given the intrinsics difference. A difference of X that the cx difference explains is
    # no drift; a camera moved by the same amount with the lens unchanged is one, and more clearly than X alone says
    D = np.diag([SIGMA_ROT**2] * 3 + [SIGMA_TRANS**2] * 3) / 4.0
    H = np.zeros((6, 4))
    H[1, 2], H[3, 2] = 4e-4, 3e-4  # rad and m per px of cx
    K = np.array([[0.25, 0.24, 0, 0], [0.24, 0.25, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
    k_a = np.array([910.0, 909.0, 640.0, 360.0])
    dk = np.array([0.0, 0.0, 3.0, 0.0])
    T_a = se3_exp(np.array([0.1, -0.2, 0.3, 0.05, 0.02, 0.1]))
    xi = H @ dk  # 0.069 deg about y, 0.9 mm along x
    a = _joint_result(T_a, k_a, D, H, K)
    lens = compare_results(a, _joint_result(T_a @ se3_exp(xi), k_a + dk, D, H, K))
    assert lens.test == "X given the intrinsics difference"
    assert lens.mahalanobis2 < 0.01 and not lens.drifted
    assert lens.explained_trans_mm == pytest.approx(0.9, rel=0.02) and lens.explained_rot_deg == pytest.approx(
        np.degrees(1.2e-3), rel=0.02
    )
    moved = compare_results(a, _joint_result(T_a @ se3_exp(xi), k_a, D, H, K))
    # the same difference without the lens change: X given dk = 0, the explicit conditional Gaussian
    Ad = se3_adjoint(se3_exp(xi))
    S = (D + H @ K @ H.T) + Ad @ (D + H @ K @ H.T) @ Ad.T
    C = H @ K + Ad @ H @ K
    V = S - C @ np.linalg.solve(2 * K, C.T)
    assert moved.mahalanobis2 == pytest.approx(xi @ np.linalg.solve(V, xi), rel=1e-6)
    assert moved.drifted and moved.mahalanobis2 > 3 * moved.mahalanobis2_x_alone
    # a verdict twice the model's covariance of X (A = sqrt(2) I): the regression stays the model's geometry, the
    # part the intrinsics do not explain doubles with X's covariance
    a2, b2 = a, _joint_result(T_a @ se3_exp(xi), k_a, D, H, K)
    for r in (a2, b2):
        r["refinement"]["cov_x_6x6_verdict"] = (2 * np.asarray(r["refinement"]["cov_x_6x6"])).tolist()
    assert compare_results(a2, b2).mahalanobis2 == pytest.approx(moved.mahalanobis2 / 2, rel=1e-6)
    assert compare_results(a2, _joint_result(T_a @ se3_exp(xi), k_a + dk, D, H, K)).mahalanobis2 < 0.01
    # the intrinsics under their full covariance: fx and fy moving together by 0.5 px is within it
    both = compare_results(a, _joint_result(T_a, k_a + np.array([0.5, 0.5, 0, 0]), D, H, K))
    assert both.intrinsics["dof"] == 4 and "full covariance" in both.intrinsics["test"]
    assert both.intrinsics["mahalanobis2"] == pytest.approx(
        np.array([0.5, 0.5]) @ np.linalg.solve(2 * K[:2, :2], np.array([0.5, 0.5])), rel=1e-9
    )


@pytest.mark.parametrize(
    "change, words",
    [
        (dict(mode="eye_to_hand"), "mounting modes differ"),
        (dict(size=(640, 480)), "camera resolutions differ"),
        (dict(square_m=0.025), "boards differ"),
    ],
)
def test_compare_refuses_results_of_different_rigs(change, words):
    c = compare_results(fake_result(), fake_result(**change))
    assert not c.comparable and words in c.reason and not c.drifted and np.isnan(c.p_value)


def test_compare_reads_result_folders_and_refuses_a_bad_parametrisation(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "result.json").write_text(json.dumps(fake_result()))
    assert load_result(tmp_path / "a").cov_source == "cov_x_6x6"
    bad = fake_result()
    bad["refinement"]["cov_parametrisation"] = "left perturbation, translation first"
    with pytest.raises(InputError, match="unknown parametrisation"):
        load_result(bad)
    with pytest.raises(InputError):
        load_result(tmp_path / "missing")


def test_compare_cli_exit_codes_and_json(tmp_path, capsys):
    paths = {}
    for name, r in {
        "a": fake_result(),
        "b": fake_result(se3_exp(np.array([0, 0, 0, 2e-3, 0, 0]))),
        "c": fake_result(mode="eye_to_hand"),
    }.items():
        paths[name] = tmp_path / f"{name}.json"
        paths[name].write_text(json.dumps(r))
    assert main(["compare", str(paths["a"]), str(paths["a"])]) == 0
    assert "Mahalanobis" in capsys.readouterr().out
    assert main(["compare", "--json", str(paths["a"]), str(paths["b"])]) == DRIFTED_EXIT_CODE
    assert json.loads(capsys.readouterr().out)["trans_mm"] == pytest.approx(2.0, rel=1e-6)
    assert main(["compare", str(paths["a"]), str(paths["c"])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mounting modes differ" in err[0]
    assert DRIFTED_EXIT_CODE in dict(EXIT_CODES)


# ------------------------------------------------------------------------------ the tests' math
def _spd(rng, scale):
    A = rng.normal(size=(6, 6))
    return scale * (A @ A.T + 6 * np.eye(6))


def test_the_installed_joint_covariance_is_carried_to_the_verdict_covariances():
    """result.json's X-intrinsics joint covariance is the model's; the verdict's X and intrinsics covariances are
    larger (validated on real data). Loaded, the joint has the verdict's X block and intrinsics sigmas (the model's
    correlations among the intrinsics), the model's canonical correlations between X and the intrinsics, and stays
    positive definite, so that verify's joint test never measures a change against the model's smaller intrinsics
    uncertainty."""
    from handeye.recal.loaded import stretch

    rng = np.random.default_rng(0)
    names = ["fx", "fy", "cx", "cy"]
    A = rng.normal(size=(10, 10)) * np.r_[[SIGMA_ROT] * 3, [SIGMA_TRANS] * 3, [0.5, 0.5, 0.4, 0.4]][:, None]
    S = A @ A.T  # the model's joint covariance of (X tangent, fx fy cx cy)
    d = fake_result(cov=S[:6, :6])
    ref = d["refinement"]
    ref["cov_x_intrinsics"] = {
        "intrinsics": names,
        "cross_6xk": S[:6, 6:].tolist(),
        "intrinsics_kxk": S[6:, 6:].tolist(),
    }
    # verdicts larger along some directions only (the generalised-eigenvalue maximum of the validation)
    Vx = S[:6, :6] + 3.0 * np.outer(S[:6, 0], S[:6, 0]) / S[0, 0]
    Vk = 2.0**2 * S[6:, 6:]
    ref["cov_x_6x6_verdict"] = Vx.tolist()
    ref["intrinsics_cov_names"] = ["cx", "cy", "fx", "fy", "k1"]  # another order, one more parameter
    P = np.zeros((5, 5))
    P[:4, :4] = Vk[np.ix_([2, 3, 0, 1], [2, 3, 0, 1])]
    P[4, 4] = 1e-4
    ref["cov_intrinsics_verdict"] = P.tolist()
    n, C, K = load_result(d).cov_x_intrinsics
    assert list(n) == names
    np.testing.assert_allclose(K, Vk, rtol=1e-9, atol=1e-12)
    J = np.block([[Vx, C], [C.T, K]])
    assert np.linalg.eigvalsh(J).min() > 0

    # canonical correlations (singular values of Lx^-1 C Lk^-T) are the model's
    def canon(Sxx, Sxk, Skk):
        return np.linalg.svd(
            np.linalg.solve(np.linalg.cholesky(Sxx), Sxk) @ np.linalg.inv(np.linalg.cholesky(Skk)).T, compute_uv=False
        )

    np.testing.assert_allclose(canon(Vx, C, K), canon(S[:6, :6], S[:6, 6:], S[6:, 6:]), rtol=1e-7)
    # a verdict measured against the intrinsics' joint model covariance (validation.intrinsics_model: full), larger
    # along one direction only: carried as it is, its correlations included (not the diagonal map's)
    Kv = S[6:, 6:] + 3.0 * np.outer(S[6:, 6], S[6:, 6]) / S[6, 6]
    saved = (ref["intrinsics_cov_names"], ref["cov_intrinsics_verdict"])
    ref.update(intrinsics_cov_names=names, cov_intrinsics_verdict=Kv.tolist(), validation={"intrinsics_model": "full"})
    n, C2, K2 = load_result(d).cov_x_intrinsics
    np.testing.assert_allclose(K2, Kv, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(canon(Vx, C2, K2), canon(S[:6, :6], S[:6, 6:], S[6:, 6:]), rtol=1e-7)
    ref["validation"] = {"intrinsics_model": "sigmas"}  # measured one by one: the diagonal map, not Kv
    assert not np.allclose(load_result(d).cov_x_intrinsics[2], Kv, rtol=1e-3)
    ref["intrinsics_cov_names"], ref["cov_intrinsics_verdict"] = saved
    del ref["validation"]
    # a verdict without the intrinsics' correlations (measured one by one): the verdict's sigmas, the model's
    # correlations among them (fx - fy stays as well determined, relative to fx, as the model says)
    P[:4, :4] = np.diag(np.diag(P[:4, :4]))
    ref["cov_intrinsics_verdict"] = P.tolist()
    _, _, K1 = load_result(d).cov_x_intrinsics
    np.testing.assert_allclose(np.sqrt(np.diag(K1)), np.sqrt(np.diag(Vk)), rtol=1e-9)

    def corr(M):
        return M / np.sqrt(np.outer(np.diag(M), np.diag(M)))

    np.testing.assert_allclose(corr(K1), corr(S[6:, 6:]), atol=1e-9)
    # the stretch moves nothing where the verdict is the model's
    np.testing.assert_allclose(stretch(S[:6, :6], S[:6, :6]), np.eye(6), atol=1e-9)
    # no verdict in the result: the model's joint as stored
    for k in ("cov_x_6x6_verdict", "intrinsics_cov_names", "cov_intrinsics_verdict"):
        del ref[k]
    n, C, K = load_result(d).cov_x_intrinsics
    np.testing.assert_allclose(C, S[:6, 6:], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(K, S[6:, 6:])


def test_drift_test_is_the_wald_statistic_and_drops_unconstrained_directions():
    from handeye.recal.verify import drift_test

    rng = np.random.default_rng(1)
    S0, S_new = _spd(rng, 1e-7), _spd(rng, 3e-7)
    xi = 1e-3 * rng.normal(size=6)
    T0 = se3_exp(np.array([0.3, -0.1, 0.2, 0.05, 0.0, 0.1]))
    t = drift_test(cov_installed=S0, T_x_installed=T0, T_x_new=T0 @ se3_exp(xi), cov_new=S_new)
    Ad = se3_adjoint(se3_exp(xi))
    assert t.dof == 6
    assert t.statistic == pytest.approx(xi @ np.linalg.solve(S0 + Ad @ S_new @ Ad.T, xi), rel=1e-9)
    assert t.p_value == pytest.approx(stats.chi2.sf(t.statistic, 6), rel=1e-9)
    # the posterior combines both: its covariance is (S0^-1 + S_new'^-1)^-1 (S_new' = Ad S_new Ad^T)
    S_new_t = Ad @ S_new @ Ad.T
    assert t.posterior_cov == pytest.approx(np.linalg.inv(np.linalg.inv(S0) + np.linalg.inv(S_new_t)), rel=1e-6)
    # a direction the new views do not see (huge variance) leaves the test
    S_blind = S_new + 1e6 * np.outer(np.eye(6)[2], np.eye(6)[2])
    t5 = drift_test(cov_installed=S0, T_x_installed=T0, T_x_new=T0 @ se3_exp(xi), cov_new=S_blind)
    assert t5.dof == 5 and t5.statistic < t.statistic + 1e-9


def test_joint_drift_test_is_chi_square_when_the_intrinsics_are_shared():
    """A linear-Gaussian model of verify: an install solves (x, k) from 60 measurements G0 (x: rad and m, k: px),
    new views measure some of the same kind, G, and are solved with x vague and k under the installed
    intrinsics' prior, as verify does. Under X = X_installed the joint test is chi-square with 6 dof;
    drift_test, which adds the installed covariance whole, counts the intrinsics' error they share twice."""
    from handeye.recal.verify import drift_test, joint_drift_test

    rng = np.random.default_rng(3)
    nk, n = 4, 800
    X = rng.normal(size=(60, 6))
    K = X[:, :nk] + 0.3 * rng.normal(size=(60, nk))  # the intrinsics confounded with x (cx with a rotation, ...)
    G0 = np.hstack([3e3 * X, K])  # pixels per unit
    S_inst = np.linalg.inv(G0.T @ G0)  # unit pixel noise
    G = G0[:24] + 0.05 * rng.normal(size=(24, 6 + nk)) * np.r_[np.full(6, 3e3), np.full(nk, 1.0)]
    S_kp, vague = S_inst[6:, 6:], np.eye(6)  # verify's priors: the installed intrinsics' covariance, x vague
    info_prior = np.zeros((6 + nk, 6 + nk))
    info_prior[:6, :6], info_prior[6:, 6:] = np.linalg.inv(vague), np.linalg.inv(S_kp)
    P_v = np.linalg.inv(G.T @ G + info_prior)
    T0 = np.eye(4)
    Tj, Tw = [], []
    for _ in range(n):
        e = np.linalg.solve(G0.T @ G0, G0.T @ rng.normal(size=60))  # the install's error (x0, k0) - truth
        # the new views' solve relative to the installed (x0, k0), priors centred there (truth at -e)
        m = P_v @ (G.T @ (G @ -e + rng.normal(size=24)))
        T_new = se3_exp(m[:6])
        t = joint_drift_test(
            T_x_installed=T0,
            cov_installed=S_inst[:6, :6],
            cov_xk_installed=S_inst[:6, 6:],
            cov_kk_installed=S_kp,
            T_x_new=T_new,
            dk_new=m[6:],
            cov_new=P_v,
            cov_k_prior=S_kp,
            cov_x_prior=vague,
        )
        Tj.append(t.statistic)
        Tw.append(
            drift_test(cov_installed=S_inst[:6, :6], T_x_installed=T0, T_x_new=T_new, cov_new=P_v[:6, :6]).statistic
        )
        assert t.dof == 6
    assert stats.kstest(Tj, stats.chi2(6).cdf).pvalue > 0.01
    assert np.mean(Tj) == pytest.approx(6.0, abs=0.6)  # sd of the mean of 800 chi2_6: 0.12
    assert np.mean(Tw) < 0.7 * np.mean(Tj)  # the shared error counted twice: a conservative test (2.9)


def test_the_p_value_allows_for_a_robot_noise_level_that_was_estimated():
    # a Wald statistic whose covariance rests on a noise level estimated with nu degrees of freedom is
    # T = chi2_6 / (chi2_nu / nu): the chi-square reference calls it significant too often, the F reference not
    from handeye.stats import wald_p_value

    rng = np.random.default_rng(3)
    nu = 30
    T = rng.chisquare(6, 4000) / (rng.chisquare(nu, 4000) / nu)
    p_chi = np.array([wald_p_value(t, 6) for t in T])
    p_f = np.array([wald_p_value(t, 6, nu) for t in T])
    assert np.mean(p_chi < 0.05) > 0.07 and abs(np.mean(p_f < 0.05) - 0.05) < 0.01
    assert wald_p_value(12.59, 6) == pytest.approx(0.05, abs=1e-3) and wald_p_value(3.0, 0, nu) == 1.0
    assert wald_p_value(12.59, 6, None) == wald_p_value(12.59, 6, float("nan"))


# ------------------------------------------------------------------------------ verify on simulated rigs
SMALL = dict(width=640, height=360)


@pytest.fixture(scope="module")
def install():
    """A 15-view corner-level install (640x360, 0.3 px, robot 0.2 mm / 0.05 deg) and its result dict."""
    return _installed(n_views=15, noise_px=0.3, robot_noise=(0.2, 0.05))


def _installed(*, n_views, noise_px, robot_noise, seed=5):
    """(corner-level session at 640x360, result dict of its refinement from the Tsai seed, as calibrate runs it)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from bench_refine import refine_from_tsai

    from handeye.recal.loaded import result_from_refinement
    from handeye.sim.corners import make_corner_session
    from handeye.sim.scenarios import default_intrinsics

    s = make_corner_session(
        n_views=n_views, seed=seed, noise_px=noise_px, robot_noise=robot_noise, intrinsics=default_intrinsics(**SMALL)
    )
    r = refine_from_tsai(s)
    assert r.status == "ok"
    return s, result_from_refinement(r, target=s.target)


def _verification(s, xi, *, seed, n_views=6, board=None, **kw):
    """Views of the install's rig with X moved by ``xi`` (and the board at ``board``, default the install's);
    ``kw`` goes to make_corner_session (its robot noise, outlier views...)."""
    from handeye.sim.corners import make_corner_session

    kw = {"noise_px": 0.3, "robot_noise": (0.2, 0.05), **kw}
    board = s.T_board_true if board is None else board
    return make_corner_session(
        n_views=n_views, seed=seed, intrinsics=s.intrinsics, rig=(s.T_x_true @ se3_exp(xi), board), **kw
    )


def _views(s):
    from handeye.refine import RefineView

    return [
        RefineView(v, i, p, s.T_base_end_reported[k])
        for k, (v, i, p) in enumerate(zip(s.view_ids, s.corner_ids, s.image_points, strict=False))
    ]


def test_verify_still_valid_on_the_same_rig_and_drifted_after_a_bump(install):
    from handeye.recal.verify import verify_views

    s, res = install
    inst = load_result(res)
    same = verify_views(
        inst, views=_views(_verification(s, np.zeros(6), seed=101)), object_points=s.target.object_points()
    )
    assert same.verdict == "still valid" and same.test.dof == 6 and same.test.p_value > 0.05
    # the install estimated its robot noise (15 views: at most 45 equations per group; a group the camera cannot
    # resolve is frozen and has none): the test takes the p-value from F with Satterthwaite's degrees of freedom
    # of the estimated sigmas taken as equal parts
    dof, resolved = res["refinement"]["robot_noise_dof"], res["refinement"]["robot_sigma_resolved"]
    assert dof and set(dof) == {g for g, ok in resolved.items() if ok} and all(5 < v < 45 for v in dof.values())
    n = len(dof)
    assert same.test.noise_dof == pytest.approx(1.0 / sum((1.0 / n) ** 2 / v for v in dof.values()))
    assert same.to_dict()["test"]["reference"].startswith("6 × F(6, ")
    assert same.what_moved == ("nothing moved beyond the uncertainty",)
    bump = np.array([np.radians(0.5), 0.0, 0.0, 0.0, 5e-3, 0.0])  # 0.5 deg, 5 mm along the camera's y
    moved = verify_views(inst, views=_views(_verification(s, bump, seed=102)), object_points=s.target.object_points())
    assert moved.drifted and moved.test.p_value < 1e-6
    e = moved.test.change_xi - bump  # the estimated change within its 3-D 3-sigma region of the truth
    assert e[3:] @ np.linalg.solve(moved.test.change_cov[3:, 3:], e[3:]) < stats.chi2.ppf(0.997, 3)
    assert moved.change["trans_mm"] == pytest.approx(5.0, abs=4 * np.linalg.norm(moved.change["sigma_trans_mm"]))
    assert "camera moved on the flange" in moved.what_moved[0]
    d = moved.to_dict()
    assert d["verdict"] == "drifted" and d["test"]["dof"] == 6 and d["frame"] == "T_end_cam"
    # the install's joint covariance of X and the intrinsics is used: the intrinsics' shared error cancels, so
    # the change is tighter than the installed covariance plus the new views' alone
    from handeye.recal.verify import JOINT_KIND

    assert same.test.kind == JOINT_KIND and np.trace(same.test.change_cov) < np.trace(inst.cov_x)
    older = json.loads(json.dumps(res))
    del older["refinement"]["cov_x_intrinsics"]  # a result written before the joint covariance was kept
    old = verify_views(
        load_result(older),
        views=_views(_verification(s, np.zeros(6), seed=101)),
        object_points=s.target.object_points(),
    )
    assert old.test.kind != JOINT_KIND and np.trace(old.test.change_cov) > np.trace(inst.cov_x)


def test_verify_uses_the_installed_arm_when_the_result_names_a_preset():
    from handeye.recal.verify import installed_robot_model

    def named(arm_option, kind="kinematic"):
        return load_result(
            {
                "handeye_result": 1,
                "status": "ok",
                "mode": "eye_in_hand",
                "refinement": {
                    "options": {"arm": arm_option},
                    "robot_model": {
                        "kind": kind,
                        "arm": "RealMan RM65-B",
                        "encoder_sigma_deg": 0.01,
                        "dh_prior_sigma": {"length_mm": 0.5, "angle_deg": 0.05},
                    },
                },
            }
        )

    o = installed_robot_model(named("rm65"))
    assert o["robot_model"] == "kinematic" and o["arm"].name == "RealMan RM65-B"
    assert (o["encoder_sigma_deg"], o["dh_sigma_mm"], o["dh_sigma_deg"]) == (0.01, 0.5, 0.05)
    assert installed_robot_model(named("my_arm.yaml")) == {}  # its table is not in result.json
    table = Path(__file__).resolve().parents[2] / "configs" / "robots" / "ur5e.yaml"  # a DH file that exists
    assert installed_robot_model(named(str(table)))["arm"].n_joints == 6
    assert installed_robot_model(named(None, kind="iid")) == {}
    # the table result.json records (an arm named by session.yaml's robot:, whose options hold only its name)
    from handeye.kinematics import chain_to_dict, load_arm

    rm65 = load_arm("rm65")
    d = named("RealMan RM65-B")
    d.raw["refinement"]["robot_model"]["dh_table"] = chain_to_dict(rm65)
    o = installed_robot_model(d)
    assert o["robot_model"] == "kinematic" and o["arm"].name == rm65.name
    np.testing.assert_allclose(o["arm"].dh, rm65.dh, atol=1e-12)
    np.testing.assert_allclose(o["arm"].joint_limits_rad, rm65.joint_limits_rad, atol=1e-12)


def test_verify_refuses_too_few_views_and_a_result_without_covariance(install):
    from handeye.recal.verify import verify_views

    s, res = install
    v = _verification(s, np.zeros(6), seed=103, n_views=3)
    with pytest.raises(InputError, match="at least 3 views"):
        verify_views(load_result(res), views=_views(v)[:2], object_points=s.target.object_points())
    bare = json.loads(json.dumps(res))
    del bare["refinement"]["cov_x_6x6"]
    with pytest.raises(InputError, match="no covariance"):
        verify_views(load_result(bare), views=_views(v), object_points=s.target.object_points())


def test_verify_with_robot_poses_far_noisier_than_installed_says_so(install):
    """New views whose robot poses scatter 10x beyond the installed robot noise: the verification cannot be
    solved (too few robot poses agree with the camera); the error measures the scatter and says what to check,
    not 'turn the robot between views'."""
    from handeye.errors import CalibrationError
    from handeye.recal.verify import verify_views

    s, res = install
    v = _verification(s, np.zeros(6), seed=104, robot_noise=(2.0, 0.5))
    with pytest.raises(CalibrationError) as e:
        verify_views(load_result(res), views=_views(v), object_points=s.target.object_points())
    hint = e.value.hint
    assert "scatters by" in hint and "installed robot noise of" in hint and "at rest" in hint
    assert "turned between them" not in hint


def test_four_views_with_one_wrong_robot_pose_are_verified_on_the_other_three(install):
    """With 4 views and X free, one robot pose 5-10 mm off drags the solve until the others look wrong too (the
    outlier loop keeps too few). The board each view puts through the installed X names the odd one: the
    verification is solved without it and says so."""
    from handeye.recal.verification import odd_view
    from handeye.recal.verify import verify_views

    s, res = install
    v = _verification(s, np.zeros(6), seed=121, n_views=4, outlier_views=["2"], outlier_trans_mm=(5.0, 10.0))
    out = verify_views(load_result(res), views=_views(v), object_points=s.target.object_points())
    assert out.verdict == "still valid" and out.n_views == 3 and out.robot["views"] == ["2"]
    assert "solved without it" in out.robot["reasons"][0] and out.views["2"]["status"] == "robot_excluded"
    # two of six 20-30 mm / 5-10 deg off: each is left out in turn (the reference is the view the others agree
    # with best, so one far-off view does not hide the other)
    wrong = {"outlier_views": ["2", "3"], "outlier_trans_mm": (20.0, 30.0), "outlier_rot_deg": (5.0, 10.0)}
    two = verify_views(
        load_result(res),
        views=_views(_verification(s, np.zeros(6), seed=137, **wrong)),
        object_points=s.target.object_points(),
    )
    assert two.verdict == "still valid" and two.n_views == 4 and sorted(two.robot["views"]) == ["2", "3"]
    assert sum("solved without it" in r for r in two.robot["reasons"]) == 2
    assert all(two.views[v]["robot_vs_camera_trans_mm"] > 20 for v in ("2", "3"))
    # named only when the others agree and it lies apart: a clean session has no odd view
    from handeye.recal.verification import board_from_views, robot_board_sigma_mm

    for seed in range(121, 131):
        clean = _verification(s, np.zeros(6), seed=seed, n_views=4)
        C = clean.T_cam_board_true
        B = board_from_views("eye_in_hand", s.T_x_true, clean.T_base_end_reported, C)
        assert odd_view(B, sigma_mm=robot_board_sigma_mm("eye_in_hand", s.T_x_true, C, B, 0.2, 0.05)) is None
    C = v.T_cam_board_true
    B_bad = board_from_views("eye_in_hand", s.T_x_true, v.T_base_end_reported, C)
    assert odd_view(B_bad, sigma_mm=robot_board_sigma_mm("eye_in_hand", s.T_x_true, C, B_bad, 0.2, 0.05))[0] == 1


def test_a_view_left_out_for_its_robot_pose_does_not_hide_a_board_that_moved(install):
    """The board moved 10 mm on the table, and one of 6 new views has a wrong robot pose: the view is left out, and
    the board's change is judged on the views the solve used (with the wrong one its scatter was 5.8 mm)."""
    from handeye.recal.verify import verify_views

    s, res = install
    shift = np.eye(4)
    shift[0, 3] = 10e-3  # T_base_board: 10 mm along the base's x
    out = {}
    for bad in ([], ["3"]):
        v = _verification(
            s, np.zeros(6), seed=106, board=shift @ s.T_board_true, outlier_views=bad, outlier_trans_mm=(15.0, 20.0)
        )
        out[len(bad)] = verify_views(load_result(res), views=_views(v), object_points=s.target.object_points())
    assert out[1].robot["views"] == ["3"] and out[1].verdict == out[0].verdict == "still valid"
    for b in (out[0].board, out[1].board):
        assert b["moved"] and b["trans_mm"] == pytest.approx(10.0, abs=3 * b["sigma_trans_mm"])
    assert out[1].board["sigma_trans_mm"] < 1.5 * out[0].board["sigma_trans_mm"]


def test_plan_power_grows_with_views_and_is_bounded_by_the_installed_uncertainty(install):
    from handeye.recal.plan import installed_poses, plan_lines, plan_verification

    s, res = install
    inst = load_result(res)
    p = plan_verification(inst, candidates=installed_poses(inst), max_views=8)
    assert p.power_by_views[0] == pytest.approx(0.05, abs=1e-3)  # one view says nothing about X: the test's level
    assert all(b >= a - 1e-9 for a, b in zip(p.power_by_views, p.power_by_views[1:], strict=False))
    assert p.power_by_views[-1] <= p.ceiling_power + 1e-9
    big = plan_verification(inst, candidates=installed_poses(inst), drift_mm=10.0, drift_deg=1.0, max_views=8)
    assert big.n_views is not None and 3 <= big.n_views <= 8 and big.power_by_views[-1] >= 0.95
    assert "views detect a drift of 10 mm / 1 deg" in plan_lines(big)[0]
    with pytest.raises(InputError, match="positive"):
        plan_verification(inst, drift_mm=0.0, drift_deg=0.0)


# ------------------------------------------------------------------------------ the commands on rendered images
@pytest.fixture(scope="module")
def rendered(install, tmp_path_factory):
    """The install's result.json and three rendered 4-view sessions of its rig: unchanged, camera bumped
    by 5 mm / 0.5 deg, and the unchanged rig stated as eye-to-hand."""
    from handeye.sim.vendor import write_vendor_session

    s, res = install
    root = tmp_path_factory.mktemp("recal")
    (root / "installed").mkdir()
    (root / "installed" / "result.json").write_text(json.dumps(res))
    out = {"installed": root / "installed"}
    bump = np.array([np.radians(0.5), 0.0, 0.0, 0.0, 5e-3, 0.0])
    moved = s.T_board_true @ se3_exp(np.array([0.0, 0.0, np.radians(2.0), 0.02, 0.0, 0.0]))  # 20 mm, 2 deg on the table
    for name, xi, board in (
        ("same", np.zeros(6), s.T_board_true),
        ("bumped", bump, s.T_board_true),
        ("bumped_board_moved", bump, moved),
    ):
        out[name] = write_vendor_session(
            root / name,
            n_views=4,
            seed=200,
            robot_noise=(0.2, 0.05),
            image_noise=2.0,
            intrinsics=s.intrinsics,
            supersample=2,
            rig=(s.T_x_true @ se3_exp(xi), board),
        )
    return out


def test_verify_cli_writes_reports_and_exits_9_when_drifted(rendered, tmp_path, capsys):
    rc = main(["verify", str(rendered["same"]), "--against", str(rendered["installed"]), "--out", str(tmp_path / "a")])
    out = capsys.readouterr().out
    assert rc == 0 and "still valid" in out
    d = json.loads((tmp_path / "a" / "verify.json").read_text())
    assert d["verdict"] == "still valid" and d["n_views"] == 4 and d["session"]["intrinsics"] == "installed"
    html = (tmp_path / "a" / "verify.html").read_text()
    md = (tmp_path / "a" / "verify.md").read_text()
    assert "STILL VALID" in html and "## What moved" in md and d["headline"] in md
    # the test's reference distribution is named wherever the p-value is: the CLI, verify.json and both reports
    ref = d["test"]["reference"]
    assert ref.startswith(("chi-square(", "6 × F(6, ")) and f"reference {ref}" in out and ref in html and ref in md
    rc = main(
        ["verify", str(rendered["bumped"]), "--against", str(rendered["installed"]), "--out", str(tmp_path / "b")]
    )
    assert rc == DRIFTED_EXIT_CODE and "DRIFTED" in capsys.readouterr().out
    assert json.loads((tmp_path / "b" / "verify.json").read_text())["drifted"] is True
    rc = main(["verify", str(rendered["same"]), "--against", str(rendered["installed"]), "--mode", "eye_to_hand"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "eye_to_hand" in err[0]
    assert (
        main(["verify", "--plan", "--against", str(rendered["installed"]), "--drift-mm", "0", "--drift-deg", "0"]) == 2
    )


def test_calibrate_with_prior_reports_the_update_or_the_contradiction(rendered, tmp_path, capsys):
    installed = json.loads((rendered["installed"] / "result.json").read_text())
    runs = (("same", False, False), ("bumped", True, False), ("bumped", True, True), ("bumped_board_moved", True, True))
    for name, contradicted, unmoved in runs:
        out = tmp_path / f"{name}{'_unmoved' if unmoved else ''}"
        main(
            ["-q", "calibrate", str(rendered[name]), "--prior", str(rendered["installed"]), "--out", str(out)]
            + (["--board-unmoved"] if unmoved else [])
        )
        res = json.loads((out / "result.json").read_text())
        p = res["prior"]
        assert p["contradicted"] is contradicted and p["frame"] == "T_end_cam"
        assert "prior:" in capsys.readouterr().out
        # a bump moves the camera, not its lens: the prior's intrinsics stay either way
        assert p["intrinsics"] == "the prior's, with its sigmas"
        assert (
            abs(res["intrinsics"]["fx"] - installed["intrinsics"]["fx"])
            < 5 * installed["refinement"]["intrinsics_sigma"]["fx"]
        )
        if contradicted:
            assert p["used"].startswith("no prior on X") and p["change"]["trans_mm"] > 2.0
            # the board's earlier pose is kept only when the user says the board stayed and verify does not find it
            # moved: the bumped camera's views then measure X through it
            kept = unmoved and name == "bumped"
            assert p["board_prior"] is kept and ("board pose" in p["used"]) is kept
            # the user's word overruled by the data is said, with the move
            assert ("--board-unmoved was overruled: the board moved by" in p["summary"]) is (unmoved and not kept)
            if kept:
                from handeye.frames import pose_error

                rot, trans = pose_error(np.array(res["T_base_board"]), np.array(installed["T_base_board"]))
                sd = 1000 * np.sqrt(np.trace(np.array(installed["refinement"]["cov_board_6x6"])[3:, 3:]))
                assert trans < 3 * sd, (trans, sd)
        else:
            assert p["used"] == "prior" and p["test"]["dof"] == 6 and p["test"]["p_value"] > 0.05
            assert len(p["update"]["sigma_trans_mm"]) == 3 and all(s >= 0 for s in p["update"]["sigma_trans_mm"])
        md = (out / "report.md").read_text()
        html = (out / "report.html").read_text()
        label = "CONTRADICTED" if contradicted else "PRIOR HOLDS"
        assert "## Prior: an earlier calibration" in md and label in md and p["summary"] in md
        assert 'id="prior"' in html and label in html
        assert "Change of X the new views show" in md and "Update of the prior" in md


def test_collect_verify_against_refuses_another_mode_in_one_line(rendered, tmp_path, capsys):
    rc = main(
        [
            "collect",
            str(tmp_path / "c"),
            "--mode",
            "eye_to_hand",
            "--camera",
            "sim",
            "--robot",
            "sim",
            "--verify-against",
            str(rendered["installed"]),
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "installed calibration is eye_in_hand" in err[0]
    rc = main(
        [
            "collect",
            str(tmp_path / "d"),
            "--mode",
            "eye_in_hand",
            "--camera",
            "sim",
            "--robot",
            "sim",
            "--sim-bump",
            "1",
            "0.1",
        ]
    )
    assert rc == 2 and "--verify-against" in capsys.readouterr().err


def test_the_plan_scores_views_that_leave_x_unknown_against_a_precise_install():
    """One view's information about (X, board) has rank 6 and entries up to ~1e12: X given the board marginalised
    is unknown. Against an install known to 1e-13 (a clean simulated session), the change's non-centrality
    must still be computed (adding the two covariances and inverting lost the small one to rounding: a singular
    matrix), and equal the direct formula where that is well conditioned."""
    from handeye.recal.plan import worst_noncentrality, worst_noncentrality_with_views, x_information

    rng = np.random.default_rng(3)
    J = rng.normal(size=(6, 12)) * np.r_[[1e3] * 6, [1e6] * 6]  # rad and m columns, like pixels per unit
    J[:, 6:] = J[:, :6] @ rng.normal(size=(6, 6))  # the board's effect a mix of X's: rank 6
    one = J.T @ J
    assert np.abs(x_information(one)).max() < 1e-3 * np.abs(one).max() ** 0.5  # X not determined by one view
    drifts = rng.normal(size=(20, 6)) * np.r_[[1e-3] * 3, [1e-3] * 3]
    S0 = np.diag(np.r_[[2e-13] * 3, [1e-11] * 3])
    nc = worst_noncentrality_with_views(S0, x_information(one), drifts)
    assert np.isfinite(nc) and 0 <= nc < 1e-3  # an unknown X detects nothing
    many = sum(J2.T @ J2 for J2 in (rng.normal(size=(12, 12)) * np.r_[[1e3] * 6, [1e6] * 6] for _ in range(4)))
    Ix = x_information(many)
    S0w = np.diag(np.r_[[1e-6] * 3, [1e-6] * 3])
    np.testing.assert_allclose(
        worst_noncentrality_with_views(S0w, Ix, drifts), worst_noncentrality(S0w + np.linalg.inv(Ix), drifts), rtol=1e-6
    )


def test_verify_plan_against_a_clean_simulated_install():
    """An install without robot noise and with 0.01 px corners (as the demo's rendered session): X known to
    ~1e-6 m, and the plan still scores the first views, which leave X unknown."""
    from handeye.recal.plan import plan_verification

    _, res = _installed(n_views=12, noise_px=0.01, robot_noise=(0.0, 0.0))
    p = plan_verification(res)
    assert p.n_views is not None and 3 <= p.n_views <= 8 and p.power_by_views[-1] >= 0.95


def test_verify_shares_the_installed_arms_dh_offsets():
    """A kinematic install records its DH offsets with their covariance with X and the intrinsics; verify gives
    them to the new views as their prior and takes them apart in the test like the shared intrinsics. The
    arm's systematic error is then known, not a fresh unknown: the change of X is far more precise than with
    the arm's own prior, an undisturbed rig is not called drifted and a 2 mm / 0.2 deg bump is (6 random
    views; the planned ones of benchmarks/bench_recal.py detect half of it)."""
    from dataclasses import replace

    from handeye.frames import se3_exp
    from handeye.recal.loaded import result_from_refinement
    from handeye.recal.verify import verify_views
    from handeye.refine import RefineOptions, RefineView, refine
    from handeye.sim.corners import make_corner_session

    def views(s):
        return [
            RefineView(v, ids, pts, s.T_base_end_reported[k], s.joints_encoder[k])
            for k, (v, ids, pts) in enumerate(zip(s.view_ids, s.corner_ids, s.image_points, strict=False))
        ]

    s = make_corner_session(mode="eye_in_hand", n_views=20, seed=3, noise_px=0.3, robot_error="kinematic")
    r = refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=views(s),
        intrinsics=s.intrinsics,
        T_x0=s.T_x_true,
        T_board0=s.T_board_true,
        options=RefineOptions(arm="rm65"),
    )
    assert r.status == "ok", r.failure_reason
    inst = load_result(result_from_refinement(r, target=s.target))
    dh, C, K = inst.dh_joint[0], inst.cov_x_intrinsics[1], inst.cov_x_intrinsics[2]
    m, k = len(dh), len(inst.cov_x_intrinsics[0])
    assert m == 24 and inst.dh_joint[1].shape == (6, m) and inst.dh_joint[2].shape == (k, m)
    J = np.block(
        [
            [inst.cov_x, C, inst.dh_joint[1]],
            [C.T, K, inst.dh_joint[2]],
            [inst.dh_joint[1].T, inst.dh_joint[2].T, inst.dh_joint[3]],
        ]
    )
    assert np.linalg.eigvalsh(J).min() > 0
    # what a verification faces of the install (verify --plan): X given the intrinsics and the DH offsets
    S_k, S_kd = inst.cov_x_given_intrinsics, inst.cov_x_given_shared
    assert np.trace(S_kd[3:, 3:]) < np.trace(S_k[3:, 3:]) and np.linalg.eigvalsh(S_kd).min() > 0
    results = {}
    for name, xi in (
        ("still", np.zeros(6)),
        ("bumped", np.r_[np.radians(0.2) * np.array([0.6, 0.0, 0.8]), 2e-3 * np.array([0.0, 0.8, -0.6])]),
    ):
        new = make_corner_session(
            mode="eye_in_hand",
            n_views=6,
            seed=40,
            noise_px=0.3,
            robot_error="kinematic",
            rig=(s.T_x_true @ se3_exp(xi), s.T_board_true),
            robot_model_seed=3,
        )
        obj = s.target.object_points()
        results[name] = verify_views(inst, views=views(new), object_points=obj)
        if name == "still":
            alone = verify_views(replace(inst, dh_joint=None), views=views(new), object_points=obj)
    shared, own = results["still"].test.change_cov, alone.test.change_cov
    assert np.trace(shared[3:, 3:]) < 0.8 * np.trace(own[3:, 3:])  # the arm's error no longer blurs the new X (0.66)
    assert results["still"].test.p_value > 0.01 and not results["still"].drifted
    assert "DH offsets" in results["still"].test.kind and "DH offsets" not in alone.test.kind
    assert results["bumped"].drifted
    # views without recorded joints (inverse kinematics may pick another arm configuration): the arm's own prior
    from handeye.recal.loaded import VAGUE_COV_X, installed_prior
    from handeye.recal.verify import installed_robot_model, with_installed_dh

    robot = installed_robot_model(inst)
    prior, _ = installed_prior(inst, session_intrinsics=False, cov_x=VAGUE_COV_X)
    assert prior.dh_offsets is None
    assert with_installed_dh(prior, inst, robot, views(new)).dh_offsets is not None
    assert with_installed_dh(prior, inst, robot, [replace(v, joint_angles=None) for v in views(new)]) is prior
    # the share of the DH prior the new views resolve is measured against the prior they had: the install's
    rm_shared, rm_own = results["still"].refined.robot_model, alone.refined.robot_model
    assert (
        rm_shared["dh_prior"] == "an earlier calibration's estimate" and rm_own["dh_prior"] == "the arm's error prior"
    )
    sd_installed = np.sqrt(np.diag(inst.dh_joint[3]))
    sd_new = np.asarray(rm_shared["dh_offset_sigma"], float).ravel() / np.tile(
        [1e3, np.degrees(1), 1e3, np.degrees(1)], 6
    )
    np.testing.assert_allclose(
        np.asarray(rm_shared["dh_resolved_share"], float).ravel(),
        1.0 - np.clip((sd_new / sd_installed) ** 2, 0.0, 1.0),
        atol=1e-9,
    )
    # verify --plan faces what verify will share: without an arm verify can rebuild, X given the intrinsics only
    from handeye.recal.verify import shares_dh

    assert shares_dh(inst)
    no_arm = replace(
        inst,
        raw=dict(
            inst.raw,
            refinement=dict(
                inst.raw["refinement"],
                robot_model={
                    k: v for k, v in inst.raw["refinement"]["robot_model"].items() if k not in ("dh_table", "arm")
                },
            ),
        ),
    )
    assert not shares_dh(no_arm)
    from handeye.recal.plan import plan_verification

    small = dict(drift_mm=0.3, drift_deg=0.03, max_views=3)  # a drift whose ceiling power is below 1
    assert plan_verification(inst, **small).ceiling_power > plan_verification(no_arm, **small).ceiling_power + 0.05
    # the plan proposes only poses the installed arm reaches (its orbits around the installed poses go far)
    from handeye.kinematics import default_ik_seeds, solve_ik

    plan = plan_verification(inst, max_views=6, power=1.0 - 1e-9)
    arm = robot["arm"]
    lo, hi = arm.joint_limits_rad.T
    seeds = list(np.random.default_rng(0).uniform(lo, hi, size=(300, arm.n_joints)))
    assert len(plan.poses) == 6
    for T, label in zip(plan.poses, plan.labels, strict=False):
        assert label.startswith("installed") or solve_ik(arm, T, seeds=default_ik_seeds(arm, T) + seeds) is not None


def test_the_plan_counts_on_the_test_verify_runs():
    # with the installed robot noise level estimated, verify's reference is F: at the non-centrality that gives the
    # chi-square test 95 % power, the F test has less, and the plan asks for the larger non-centrality
    from handeye.recal.plan import _noncentrality_for_power, test_power

    nc = _noncentrality_for_power(0.95, alpha=0.05)
    assert test_power(nc, alpha=0.05) == pytest.approx(0.95, abs=1e-6)
    assert test_power(nc, alpha=0.05, noise_dof=30.0) < 0.92
    nc_f = _noncentrality_for_power(0.95, alpha=0.05, noise_dof=30.0)
    assert nc_f > nc and test_power(nc_f, alpha=0.05, noise_dof=30.0) == pytest.approx(0.95, abs=1e-6)
    assert test_power(1e-9, alpha=0.05, noise_dof=30.0) == pytest.approx(0.05, abs=1e-3)  # no drift: the level


def test_verify_turns_the_installed_board_into_the_sessions_numbering(install):
    """A later session may number a symmetric board from the other corner: its board frame is the installed
    one turned by 180 degrees. Verify turns the installed board pose into the new numbering (the turn nearest
    the new one) before comparing (the board did not move), not 180 degrees and the board's size apart; X's
    test does not depend on the board's frame."""
    from handeye.diagnose.consistency import _rigid_motion
    from handeye.recal.verify import nearest_board_turn, verify_views
    from handeye.refine import RefineView
    from handeye.targets import grid_turns

    s, res = install
    inst = load_result(res)
    obj = s.target.object_points()
    perm = grid_turns(s.target.cols, s.target.rows)[1]  # the half turn's corner order
    F = np.linalg.inv(_rigid_motion(obj, obj[perm]))
    views = _views(_verification(s, np.zeros(6), seed=101))
    turned = [RefineView(v.view_id, perm[np.asarray(v.corner_ids)], v.image_points, v.T_base_end) for v in views]
    plain_v = verify_views(inst, views=turned, object_points=obj)
    assert plain_v.board["moved"] and plain_v.board["rot_deg"] > 170  # without the turns: a false "moved"
    v = verify_views(inst, views=turned, object_points=obj, board_turns=[F])
    assert v.board["turn_deg"] == pytest.approx(180.0) and not v.board["moved"]
    np.testing.assert_allclose(v.board["installed"], inst.T_board)  # result.json's, and the same board turned
    np.testing.assert_allclose(v.board["installed_in_session_numbering"], inst.T_board @ F)
    assert v.board["trans_mm"] < 3 * v.board["sigma_trans_mm"] + 1.0
    assert v.verdict == "still valid" and v.test.statistic == pytest.approx(plain_v.test.statistic, rel=1e-6)
    same = verify_views(inst, views=views, object_points=obj, board_turns=[F])  # numbered as installed: no turn
    assert same.board["turn_deg"] == pytest.approx(0.0) and not same.board["moved"]
    assert np.array_equal(nearest_board_turn(None, inst.T_board, [F]), np.eye(4))  # no installed board: no turn


def test_a_turned_board_pose_carries_its_covariance_along(install):
    """``with_board_turned(H)``: the board pose T H and the covariance of its right tangent as seen from the
    turned frame, checked by sampling T Exp(xi) H for a quarter turn of a square grid (a half turn is its own
    inverse and cannot tell H from H^-1); the cross-covariance with the intrinsics follows the board."""
    from handeye.diagnose.consistency import board_turns
    from handeye.frames import se3_exp, tangent_difference
    from handeye.targets import ChessboardSpec

    _, res = install
    inst = load_result(res)
    turns = board_turns(ChessboardSpec(cols=7, rows=7, square_m=0.03))
    name, F = next((n, F) for n, F in turns if n in ("90 deg", "-90 deg", "270 deg"))
    t = inst.with_board_turned(F)
    np.testing.assert_allclose(t.T_board, inst.T_board @ F)
    C, K = inst.board_joint
    rng = np.random.default_rng(4)
    L = np.linalg.cholesky(C)
    xi = rng.standard_normal((20000, 6)) @ L.T
    seen = tangent_difference(inst.T_board @ F, inst.T_board @ se3_exp(xi) @ F)  # (n, 6)
    S = np.cov(seen.T)
    rel = np.abs(S - t.board_joint[0]) / np.sqrt(np.outer(np.diag(S), np.diag(S)))
    assert rel.max() < 0.05, (name, rel.max())
    # the intrinsics' cross-covariance: the board's tangent is a linear map of xi, so is its covariance with k
    A = np.linalg.lstsq(xi, seen, rcond=None)[0].T  # (6, 6) from sampling
    np.testing.assert_allclose(t.board_joint[1], A @ K, atol=0.05 * np.abs(A @ K).max())


def test_a_kept_board_prior_is_taken_in_the_new_sessions_numbering(rendered, tmp_path, monkeypatch, capsys):
    """calibrate --prior --board-unmoved after a bump, with an install whose board frame is the new session's
    turned by a half turn (a symmetric board numbered from the other corner; the symmetry is granted to this
    board here): the earlier board pose is kept in the new session's numbering, and the result's board is the
    installed one turned back."""
    import handeye.diagnose.consistency as consistency
    from handeye.frames import inv_T, pose_error, se3_adjoint
    from handeye.sim.corners import make_corner_session
    from handeye.targets import grid_turns

    installed = json.loads((rendered["installed"] / "result.json").read_text())
    target = make_corner_session(n_views=3, seed=0).target  # the install's board
    obj = target.object_points()
    perm = grid_turns(target.cols, target.rows)[1]
    F = np.linalg.inv(consistency._rigid_motion(obj, obj[perm]))
    monkeypatch.setattr(consistency, "board_turns", lambda t: [("180 deg", F)])
    turned = json.loads(json.dumps(installed))
    Finv = inv_T(F)
    A = se3_adjoint(F)  # the board's right tangent seen from the turned frame: Ad(Finv^-1)
    turned["T_base_board"] = (np.array(installed["T_base_board"]) @ Finv).tolist()
    ref = turned["refinement"]
    ref["cov_board_6x6"] = (A @ np.array(ref["cov_board_6x6"]) @ A.T).tolist()
    ref["cov_x_intrinsics"]["cross_board_6xk"] = (A @ np.array(ref["cov_x_intrinsics"]["cross_board_6xk"])).tolist()
    (tmp_path / "inst").mkdir()
    (tmp_path / "inst" / "result.json").write_text(json.dumps(turned))
    out = tmp_path / "out"
    main(
        [
            "-q",
            "calibrate",
            str(rendered["bumped"]),
            "--prior",
            str(tmp_path / "inst"),
            "--out",
            str(out),
            "--board-unmoved",
            "--no-report",
        ]
    )
    capsys.readouterr()
    res = json.loads((out / "result.json").read_text())
    p = res["prior"]
    assert p["contradicted"] and p["board_prior"] is True and p["board_turn_deg"] == pytest.approx(180.0), p["used"]
    rot, trans = pose_error(np.array(res["T_base_board"]), np.array(installed["T_base_board"]))
    sd = 1000 * np.sqrt(np.trace(np.array(installed["refinement"]["cov_board_6x6"])[3:, 3:]))
    assert trans < 3 * sd and rot < 1.0, (trans, rot, sd)
    # the same as with the install in the session's own numbering: the board's pose and covariance came across
    main(
        [
            "-q",
            "calibrate",
            str(rendered["bumped"]),
            "--prior",
            str(rendered["installed"]),
            "--out",
            str(tmp_path / "plain"),
            "--board-unmoved",
            "--no-report",
        ]
    )
    capsys.readouterr()
    ref = json.loads((tmp_path / "plain" / "result.json").read_text())
    assert ref["prior"]["board_prior"] is True and ref["prior"]["board_turn_deg"] == pytest.approx(0.0)
    rot, trans = pose_error(np.array(res["T_end_cam"]), np.array(ref["T_end_cam"]))
    assert trans < 1e-4 and rot < 1e-5, (trans, rot)


def test_verify_and_prior_refuse_images_of_another_resolution_in_one_line(rendered, tmp_path, capsys):
    import shutil

    import cv2

    d = tmp_path / "half"
    shutil.copytree(rendered["same"], d)
    for p in d.glob("*.jpg"):
        img = cv2.imread(str(p))
        cv2.imwrite(str(p), cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2)))
    for argv in (
        ["verify", str(d), "--against", str(rendered["installed"])],
        ["calibrate", str(d), "--prior", str(rendered["installed"]), "--out", str(tmp_path / "out")],
    ):
        rc = main(["-q", *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1, err
        assert "images are 320x180 but the installed calibration's are 640x360" in err[0], err


def test_board_unmoved_without_a_prior_is_refused(rendered, tmp_path, capsys):
    rc = main(["-q", "calibrate", str(rendered["same"]), "--board-unmoved", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "add --prior RESULT, or drop --board-unmoved" in err[0]
    assert not (tmp_path / "o").exists()


def test_verify_and_plan_say_what_is_wrong_with_their_arguments(rendered, tmp_path, capsys):
    """Each refused in one line that names the real problem: a power at or below the test's level, a --mode
    that contradicts the installed result, a session of two views whose board was found in both."""
    import shutil

    inst = str(rendered["installed"])
    two = tmp_path / "two"
    shutil.copytree(rendered["same"], two)
    for k in (3, 4):
        (two / f"{k}.jpg").unlink()
    (two / "poses.txt").write_text("\n".join((two / "poses.txt").read_text().split()[:2]) + "\n")
    cases = (
        (["verify", "--plan", "--against", inst, "--power", "0.01"], "must exceed the test's level"),
        (
            ["verify", str(rendered["same"]), "--against", inst, "--mode", "eye_to_hand"],
            "--mode eye_to_hand was given but the installed calibration is eye_in_hand",
        ),
        (["verify", str(two), "--against", inst], "the session has 2 images (the board found in each); at least 3"),
    )
    for argv, says in cases:
        rc = main(["-q", *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc in (2, 3) and len(err) == 1 and says in err[0], (argv, err)
    assert main(["-q", "verify", "--plan", "--against", inst, "--out", str(tmp_path / "plan")]) == 0
    plan = json.loads((tmp_path / "plan" / "plan.json").read_text())
    assert plan["power_goal"] == 0.95 and len(plan["poses_T_base_end"]) >= 3


def test_verify_on_the_installed_calibrations_own_images_says_so(rendered, tmp_path, caplog):
    main(["-q", "calibrate", str(rendered["same"]), "--out", str(tmp_path / "own"), "--no-report"])
    with caplog.at_level("WARNING"):
        main(
            [
                "-q",
                "verify",
                str(rendered["same"]),
                "--against",
                str(tmp_path / "own"),
                "--out",
                str(tmp_path / "v"),
                "--no-report",
            ]
        )
    assert "4 of 4 images are the installed calibration's own" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        main(
            [
                "-q",
                "verify",
                str(rendered["bumped"]),
                "--against",
                str(tmp_path / "own"),
                "--out",
                str(tmp_path / "v2"),
                "--no-report",
            ]
        )
    assert "installed calibration's own" not in caplog.text


def test_verify_reports_list_an_image_without_the_board_with_its_reason(rendered, tmp_path, capsys):
    import shutil

    import cv2

    session = tmp_path / "with_blank"
    shutil.copytree(rendered["same"], session)
    size = cv2.imread(str(session / "1.jpg"), cv2.IMREAD_GRAYSCALE).shape
    cv2.imwrite(str(session / "5.jpg"), np.full(size, 128, np.uint8))  # the same camera, no board in view
    poses = (session / "poses.txt").read_text().strip().splitlines()
    (session / "poses.txt").write_text("\n".join([*poses, poses[-1]]) + "\n")
    (session / "2.jpg").unlink()  # and one image missing: its pose line is dropped by the loader
    rc = main(["verify", str(session), "--against", str(rendered["installed"]), "--out", str(tmp_path / "v")])
    assert rc == 0 and "still valid" in capsys.readouterr().out
    d = json.loads((tmp_path / "v" / "verify.json").read_text())
    out = {o["id"]: o for o in d["view_outcomes"]}
    assert d["n_views"] == 3 and list(out) == ["1", "2", "3", "4", "5"]
    assert not out["5"]["detected"] and not out["2"]["detected"] and "image file missing" in out["2"]["reason"]
    for name in ("verify.html", "verify.md"):
        text = (tmp_path / "v" / name).read_text()
        assert f"not detected: {out['5']['reason']}" in text and f"not detected: {out['2']['reason']}" in text


def test_a_prior_whose_test_fails_is_not_used_and_not_called_contradicted(rendered, monkeypatch):
    """When verify's test of the prior cannot be solved, the prior on X is not used, and the record says that it
    could not be tested (not that the data contradict it); the report shows NOT TESTED."""
    import handeye.recal.prior as prior_mod
    from handeye.errors import CalibrationError
    from handeye.pipeline import CalibrateOptions
    from handeye.report.context import _prior_block
    from handeye.session import load_session

    def unsolvable(*a, **k):
        raise CalibrationError("the verification solve failed: only 1 views left", code="refinement_failed")

    monkeypatch.setattr(prior_mod, "verify_views", unsolvable)
    run, rec = prior_mod.calibrate_with_prior(load_session(rendered["same"]), CalibrateOptions(), rendered["installed"])
    assert run.status == "ok" and rec["tested"] is False and rec["used"].startswith("no prior on X")
    assert rec["summary"].startswith("the prior could not be tested: the test of the prior failed")
    assert "contradict" not in rec["summary"] and "test" not in rec
    assert _prior_block({"prior": rec}, "T_end_cam")["tested"] is False


def test_a_board_numbered_otherwise_in_the_update_run_drops_the_board_prior(rendered, monkeypatch, caplog):
    """The guard of calibrate --prior --board-unmoved: when the calibration without the prior on X numbers the board
    otherwise than the run whose views verify turned the earlier board pose for, that pose does not apply: the
    session is calibrated again without it, and the prior block says so."""
    import dataclasses
    import logging

    import handeye.pipeline as pipeline
    from handeye.pipeline import CalibrateOptions
    from handeye.recal.prior import calibrate_with_prior
    from handeye.session import load_session

    real, priors = pipeline.run_calibration, []

    def numbered_otherwise(session, options, **kw):
        run = real(session, options, **kw)
        priors.append(options.refine_options["prior"])
        if len(priors) == 2:  # the run with the earlier board pose: its views numbered from another corner
            run = dataclasses.replace(
                run,
                board_poses={
                    vid: dataclasses.replace(bp, orientation=bp.orientation + 1) for vid, bp in run.board_poses.items()
                },
            )
        return run

    monkeypatch.setattr(pipeline, "run_calibration", numbered_otherwise)
    with caplog.at_level(logging.WARNING, logger="handeye.recal.prior"):
        run, rec = calibrate_with_prior(
            load_session(rendered["bumped"]), CalibrateOptions(), rendered["installed"], board_unmoved=True
        )
    assert len(priors) == 3 and priors[1].T_board is not None and priors[2].T_board is None
    assert rec["contradicted"] and rec["board_prior"] is False and "board_turn_deg" not in rec
    assert rec["used"].startswith("no prior on X (the new views alone")
    assert run.status == "ok" and "numbered otherwise" in caplog.text


def test_a_few_views_with_a_prior_are_judged_with_the_priors_views_and_exported(install, rendered, tmp_path, capsys):
    """The documented use of --prior (3-5 new views of an installed rig): the views check counts the prior's
    views when the data agree with it, so 5 new views are not failed for their count, and --export runs."""
    from handeye.sim.vendor import write_vendor_session

    s, _ = install
    five = write_vendor_session(
        tmp_path / "five",
        n_views=5,
        seed=201,
        robot_noise=(0.2, 0.05),
        image_noise=2.0,
        intrinsics=s.intrinsics,
        supersample=2,
        rig=(s.T_x_true, s.T_board_true),
    )
    installed = json.loads((rendered["installed"] / "result.json").read_text())
    out = tmp_path / "upd"
    rc = main(
        ["-q", "calibrate", str(five), "--prior", str(rendered["installed"]), "--out", str(out)]
        + ["--export", "json", "--no-report"]
    )
    printed = capsys.readouterr().out
    res = json.loads((out / "result.json").read_text())
    assert res["prior"]["used"] == "prior" and res["n_views"]["used"] == 5
    n_prior = sum(v["status"] == "used" for v in installed["refinement"]["per_view"].values())
    assert n_prior == 15 and res["prior"]["prior_views"] == n_prior
    assert res["prior"]["views_with_prior"] == 5 + n_prior
    check = next(c for c in res["qa"]["checks"] if c["key"] == "used_views")
    assert check["value"] == 5 + n_prior and check["status"] != "fail", check
    assert f"5 new views + {n_prior} of the prior" in check["source"]
    assert res["verdict"] in ("PASS", "WARN") and rc == 0, (rc, res["verdict_headline"])
    exported = [Path(line.split("json: ", 1)[1]) for line in printed.splitlines() if line.startswith("json: ")]
    assert exported and all(f.is_file() and f != out / "result.json" for f in exported), printed
    # a contradicted prior does not count: the result is the new views' own
    out = tmp_path / "bumped"
    main(["-q", "calibrate", str(rendered["bumped"]), "--prior", str(rendered["installed"]), "--out", str(out)])
    res = json.loads((out / "result.json").read_text())
    assert res["prior"]["contradicted"] and res["prior"]["views_with_prior"] == 4
    assert next(c for c in res["qa"]["checks"] if c["key"] == "used_views")["value"] == 4


def test_a_prior_with_a_broken_covariance_names_the_prior_file_and_its_field(rendered, tmp_path, capsys):
    """A prior result whose joint covariance of X and the intrinsics is not positive definite is the prior file's
    fault: one line naming that file and its result.json field, exit 2 (not a refine option of the config)."""
    d = json.loads((rendered["installed"] / "result.json").read_text())
    j = d["refinement"]["cov_x_intrinsics"]
    j["cross_6xk"] = (1e3 * np.asarray(j["cross_6xk"], float) + 1.0).tolist()  # |correlation| far above 1
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "result.json").write_text(json.dumps(d))
    rc = main(["-q", "calibrate", str(rendered["same"]), "--prior", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert str(bad / "result.json") in err[0] and "refinement.cov_x_intrinsics.cross_6xk" in err[0], err[0]
    assert "refine option" not in err[0] and "config" not in err[0]
