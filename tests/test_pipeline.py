"""End to end on rendered sessions in the vendor layout: `handeye simulate` then `handeye calibrate`."""
import json

import numpy as np
import pytest
import yaml

from handeye.cli import main
from handeye.frames import pose_error
from handeye.sim.synth import default_intrinsics, write_vendor_session

SMALL = dict(intrinsics=default_intrinsics(640, 480), supersample=3)


@pytest.fixture(scope="module", params=["eye_in_hand", "eye_to_hand"])
def rendered(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param) / "session"
    write_vendor_session(out, mode=request.param, n_views=12, seed=11, hidden_views=("6",), image_noise=1.0, **SMALL)
    return request.param, out


def _calibrate(session, out, *extra):
    rc = main(["-q", "calibrate", str(session), "--out", str(out), "--no-report", *extra])
    res = json.loads((out / "result.json").read_text())
    return rc, res


def test_rendered_session_calibrates_and_drops_the_hidden_view_with_its_pose(rendered, tmp_path):
    mode, session = rendered
    truth = json.loads((session / "ground_truth.json").read_text())
    rc, res = _calibrate(session, tmp_path / "out", "--no-refine")
    assert rc == 0 and res["status"] == "ok" and res["mode"] == mode
    name = {"eye_in_hand": "T_end_cam", "eye_to_hand": "T_base_cam"}[mode]
    board = {"eye_in_hand": "T_base_board", "eye_to_hand": "T_end_board"}[mode]
    views = {v["id"]: v for v in res["views"]}
    assert not views["6"]["used"] and "not found" in views["6"]["reason"]
    assert all(v["used"] for k, v in views.items() if k != "6")
    # every later pair is still right: each view's corners are explained through its own robot pose
    assert max(v["chain_max_px"] for v in views.values() if v["used"]) < 3.0
    r, t = pose_error(np.asarray(res[name]), np.asarray(truth[name]))
    assert r < 0.2 and t < 2.0, (r, t)  # rendered, anti-aliased images: corners good to ~0.05 px
    rb, tb = pose_error(np.asarray(res[board]), np.asarray(truth[board]))
    assert rb < 0.2 and tb < 3.0
    intr = res["intrinsics"]
    assert abs(intr["fx"] - truth["intrinsics"]["fx"]) / truth["intrinsics"]["fx"] < 0.01
    for key in ("hand_eye", "closed_form", "provenance", "intrinsics"):
        assert key in res
    assert len(res["provenance"]["inputs_sha256"]) == 64
    assert set(res["closed_form"]) == {"tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li"}
    obs = json.loads((tmp_path / "out" / "observations.json").read_text())
    assert "6" not in obs["views"] and len(obs["views"]) == 11


def test_wrong_mode_is_visible_in_the_residuals(rendered, tmp_path):
    mode, session = rendered
    other = "eye_to_hand" if mode == "eye_in_hand" else "eye_in_hand"
    rc, res = _calibrate(session, tmp_path / "out", "--no-refine", "--mode", other)
    # either the wrong model cannot be solved at all, or its residuals show it
    if rc == 0:
        assert max(v["chain_max_px"] for v in res["views"] if v["used"]) > 20
    else:
        assert res["status"] == "failed" and res["failure_reason"]


def test_board_size_mismatch_fails_with_reason_and_no_matrix(rendered, tmp_path, capsys):
    _, session = rendered
    bad = tmp_path / "bad"
    bad.mkdir()
    for f in session.iterdir():
        (bad / f.name).symlink_to(f)
    (bad / "config.yaml").unlink()
    (bad / "config.yaml").write_text(yaml.safe_dump({"checkerboard_args": {"XX": 9, "YY": 6, "L": 0.03}}))
    rc, res = _calibrate(bad, tmp_path / "out", "--no-refine")
    assert rc == 3
    assert res["status"] == "failed" and "T_end_cam" not in res and "T_base_cam" not in res
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "found in only 0 of 12 images" in err[0] and "9x6" in err[0]


def test_degenerate_motion_is_an_error_naming_the_axis(tmp_path, capsys):
    # one rotation axis: only roll about the optical axis, no tilts
    session = write_vendor_session(tmp_path / "s", mode="eye_in_hand", n_views=6, seed=2, tilt_deg=(0.0, 0.0), min_spread_deg=0.0,
                                   **SMALL)
    rc, res = _calibrate(session, tmp_path / "out", "--no-refine")
    assert rc == 4 and res["status"] == "failed"
    assert "one axis" in res["failure_reason"] and "add views rotated" in res["failure_reason"]


def test_failed_run_keeps_the_previous_result(rendered, tmp_path):
    _, session = rendered
    out = tmp_path / "out"
    assert _calibrate(session, out, "--no-refine")[0] == 0
    good = (out / "result.json").read_text()
    rc = main(["-q", "calibrate", str(session), "--out", str(out), "--no-report", "--no-refine",
               "--config", str(_strict_config(tmp_path))])
    assert rc != 0
    assert (out / "result.previous.json").read_text() == good


def _strict_config(tmp_path):
    p = tmp_path / "strict.yaml"
    p.write_text(yaml.safe_dump({"motion": {"min_rotation_deg": 400.0}}))
    return p


def test_unknown_config_key_is_named(rendered, tmp_path, capsys):
    _, session = rendered
    p = tmp_path / "site.yaml"
    p.write_text(yaml.safe_dump({"methd": "park"}))
    assert main(["calibrate", str(session), "--config", str(p)]) == 2
    assert "unknown setting 'methd'" in capsys.readouterr().err


def test_demo_command_reports_its_error_against_the_truth(tmp_path, capsys):
    assert main(["-q", "demo", "--out", str(tmp_path / "demo"), "--views", "8", "--mode", "eye_to_hand"]) == 0
    out = capsys.readouterr().out
    line = [l for l in out.splitlines() if l.startswith("error against the ground truth")][0]
    t_mm, r_deg = float(line.split(":")[1].split("mm")[0]), float(line.split(",")[1].split("deg")[0])
    assert t_mm < 1.0 and r_deg < 0.1
    assert (tmp_path / "demo" / "result" / "report.html").exists()
    assert "T_base_cam" in out


def test_fixed_intrinsics_stay_fixed(rendered, tmp_path):
    _, session = rendered
    rc, res = _calibrate(session, tmp_path / "out", "--fix", "p1", "p2", "k3")
    assert rc == 0
    ref = res["refinement"]
    assert set(ref["intrinsics_sigma"]) == {"fx", "fy", "cx", "cy", "k1", "k2"}
    seed_d = ref["seed"]["intrinsics"]["dist"]
    assert all(ref["intrinsics"]["dist"][k] == seed_d[k] for k in ("p1", "p2", "k3"))
