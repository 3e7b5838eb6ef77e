"""Recalibration: compare two results, verify a short session against an installed calibration,
calibrate with an earlier result as the prior, and plan a verification."""
from __future__ import annotations

import json

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
    cov = np.diag([SIGMA_ROT ** 2] * 3 + [SIGMA_TRANS ** 2] * 3) if cov is None else cov
    return {"handeye_result": 1, "status": "ok", "mode": mode, "hand_eye": {"name": x_name},
            "board": {"name": board_name}, x_name: T_x.tolist(), board_name: np.eye(4).tolist(),
            "intrinsics": {"fx": fx, "fy": 909.0, "cx": 640.0, "cy": 360.0, "image_size": list(size),
                           "dist": {"k1": 0.1, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0}},
            "target": {"type": "chessboard", "inner_corners": [11, 8], "square_m": square_m},
            "refinement": {"cov_x_6x6": cov.tolist(), "intrinsics_sigma": {"fx": 0.5, "fy": 0.5, "cx": 0.4, "cy": 0.4},
                           "cov_parametrisation": "GTSAM Pose3 tangent, right perturbation: ..., rotation first",
                           "sigma_px": 0.3, "robot_sigma_mm": 0.2, "robot_sigma_deg": 0.05}}


# ------------------------------------------------------------------------------ compare
def test_compare_identical_results_is_zero_and_not_drifted():
    T = se3_exp(np.array([0.1, -0.2, 0.3, 0.05, 0.02, 0.1]))
    c = compare_results(fake_result(T), fake_result(T))
    assert c.comparable and c.frame == "T_end_cam"
    assert c.mahalanobis2 == pytest.approx(0.0, abs=1e-12) and c.p_value == pytest.approx(1.0)
    assert not c.drifted and c.trans_mm == pytest.approx(0.0, abs=1e-9)


def test_compare_known_difference_gives_the_chi2_statistic():
    T_a = se3_exp(np.array([0.1, -0.2, 0.3, 0.05, 0.02, 0.1]))
    xi = np.array([np.radians(0.1), 0.0, 0.0, 2e-3, 0.0, 0.0])  # 0.1 deg about camera x, 2 mm along camera x
    T_b = T_a @ se3_exp(xi)
    cov = np.diag([SIGMA_ROT ** 2] * 3 + [SIGMA_TRANS ** 2] * 3)
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


def test_compare_prefers_the_verdict_covariance():
    a, b = fake_result(), fake_result(se3_exp(np.array([0, 0, 0, 1e-3, 0, 0])))
    wide = np.diag([SIGMA_ROT ** 2] * 3 + [(2e-3) ** 2] * 3)
    for r in (a, b):
        r["refinement"]["cov_x_6x6_verdict"] = wide.tolist()
    c = compare_results(a, b)
    assert c.cov_sources == ("cov_x_6x6_verdict", "cov_x_6x6_verdict")
    assert c.mahalanobis2 == pytest.approx(1.0 / 8.0, rel=1e-6) and not c.drifted


@pytest.mark.parametrize("change, words", [
    (dict(mode="eye_to_hand"), "mounting modes differ"),
    (dict(size=(640, 480)), "camera resolutions differ"),
    (dict(square_m=0.025), "boards differ"),
])
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
    for name, r in {"a": fake_result(), "b": fake_result(se3_exp(np.array([0, 0, 0, 2e-3, 0, 0]))),
                    "c": fake_result(mode="eye_to_hand")}.items():
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
