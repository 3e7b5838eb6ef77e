"""Applying a result: camera points and poses into the robot base, checked against ground truth."""

import json

import numpy as np
import pytest

from handeye.apply import points_cam_to_base, pose_cam_to_base, result_transform
from handeye.cli import main
from handeye.conventions import VENDOR_POSE_FORMAT, pose_values_from_T
from handeye.errors import ConfigError, InputError, clip
from handeye.frames import transform_points
from handeye.sim.corners import make_corner_session


def truth_points(cs, k):
    p_board = cs.target.object_points()[[0, 17, 50]]
    p_cam = transform_points(cs.T_cam_board_true[k], p_board)
    if cs.mode == "eye_in_hand":
        p_base = transform_points(cs.T_board_true, p_board)  # board fixed in base
    else:
        p_base = transform_points(cs.T_base_end_true[k] @ cs.T_board_true, p_board)
    return p_cam, p_base


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_points_and_poses_reach_the_base_frame(mode):
    cs = make_corner_session(mode=mode, n_views=5, seed=4, noise_px=0.0)
    for k in range(cs.n_views):
        p_cam, p_base = truth_points(cs, k)
        got = points_cam_to_base(p_cam, mode=mode, T_x=cs.T_x_true, T_base_end=cs.T_base_end_true[k])
        np.testing.assert_allclose(got, p_base, atol=1e-12)
        T_base_board = pose_cam_to_base(
            cs.T_cam_board_true[k], mode=mode, T_x=cs.T_x_true, T_base_end=cs.T_base_end_true[k]
        )
        expect = cs.T_board_true if mode == "eye_in_hand" else cs.T_base_end_true[k] @ cs.T_board_true
        np.testing.assert_allclose(T_base_board, expect, atol=1e-12)


def test_eye_in_hand_needs_the_end_pose():
    cs = make_corner_session(mode="eye_in_hand", n_views=4, seed=0, noise_px=0.0)
    with pytest.raises(ConfigError, match="--end-pose"):
        points_cam_to_base([0, 0, 0.5], mode="eye_in_hand", T_x=cs.T_x_true)


def _write_result(tmp_path, cs):
    res = {"status": "ok", "mode": cs.mode, cs.x_name: cs.T_x_true.tolist()}
    p = tmp_path / "result.json"
    p.write_text(json.dumps(res))
    return p


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_cli_apply_point(tmp_path, capsys, mode):
    cs = make_corner_session(mode=mode, n_views=3, seed=2, noise_px=0.0)
    res = _write_result(tmp_path, cs)
    p_cam, p_base = truth_points(cs, 1)
    end = pose_values_from_T(cs.T_base_end_true[1], VENDOR_POSE_FORMAT)
    args = ["apply", str(res), "--point", *map(str, p_cam[0])]
    if mode == "eye_in_hand":
        args += ["--end-pose", *(f"{v:.12f}" for v in end)]
    assert main(args) == 0
    out = capsys.readouterr().out
    got = [float(x) for x in out.splitlines()[0].split(":")[1].split()]
    np.testing.assert_allclose(got, p_base[0], atol=2e-6)


def test_cli_apply_pose_in_millimetres(tmp_path, capsys):
    cs = make_corner_session(mode="eye_to_hand", n_views=3, seed=2, noise_px=0.0)
    _write_result(tmp_path, cs)
    v = pose_values_from_T(cs.T_cam_board_true[0], VENDOR_POSE_FORMAT)
    v[:3] *= 1000
    assert main(["apply", str(tmp_path), "--pose", *(f"{x:.12f}" for x in v), "--mm"]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if ln.startswith("x,y,z")][0]
    got = np.array([float(x) for x in line.split(":")[1].split(",")])
    expect = pose_values_from_T(cs.T_base_end_true[0] @ cs.T_board_true, VENDOR_POSE_FORMAT)
    np.testing.assert_allclose(got, expect, atol=2e-6)  # printed with 6 decimals (m, rad)


@pytest.mark.parametrize(
    "end_pose,flags,says",
    [
        (
            ["500", "0", "500", "3.1", "0", "0"],
            [],
            "beyond an arm's reach; expected x, y, z in metres (or millimetres "
            "with --mm) -> the position looks like millimetres: add --mm",
        ),
        (["0.5", "0", "0.5", "180", "0", "0"], [], "rotation angle 180 is larger than 2*pi"),
        (["500", "0", "500", "180", "0", "0"], ["--mm"], "the angles look like degrees"),
    ],
)
def test_an_end_pose_in_other_units_is_refused(tmp_path, capsys, end_pose, flags, says):
    cs = make_corner_session(mode="eye_in_hand", n_views=3, seed=2, noise_px=0.0)
    _write_result(tmp_path, cs)
    rc = main(["apply", str(tmp_path), "--point", "0", "0", "0.5", "--end-pose", *end_pose, *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and says in err[0], err


def test_an_end_pose_is_refused_for_an_eye_to_hand_result(tmp_path, capsys):
    cs = make_corner_session(mode="eye_to_hand", n_views=3, seed=2, noise_px=0.0)
    _write_result(tmp_path, cs)
    end = ["0.69", "-0.22", "0.71", "3.1", "-0.2", "2.2"]
    rc = main(["apply", str(tmp_path), "--point", "0", "0", "0.5", "--end-pose", *end])
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert rc == 2 and captured.out == "" and len(err) == 1, err
    assert "--end-pose does not apply to an eye_to_hand result: the camera is fixed to the robot base" in err[0]
    assert err[0].endswith("-> drop --end-pose")


def test_apply_refuses_failed_results(tmp_path, capsys):
    p = tmp_path / "result.json"
    p.write_text(json.dumps({"status": "failed", "failure_reason": "degenerate", "mode": "eye_in_hand"}))
    with pytest.raises(InputError, match="failed calibration"):
        result_transform(json.loads(p.read_text()))
    assert main(["apply", str(p), "--point", "0", "0", "1"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "failed calibration" in err


def test_a_failed_results_reason_is_quoted_whole(tmp_path, capsys):
    # the reason of a calibrate of poses.txt with 'nan' on line 6; it was cut at 120 characters, mid-word
    # inside the parentheses ('(|x| )', '(e.)')
    reason = (
        "/very/long/path/to/a/vendor/session/folder/poses.txt:6: pose line holds a value that is not a usable "
        "number; expected finite numbers (|x| < 1e6); got nan -> fix line 6"
    )
    p = tmp_path / "result.json"
    p.write_text(json.dumps({"status": "failed", "failure_reason": reason, "mode": "eye_in_hand"}))
    with pytest.raises(InputError) as e:
        result_transform(json.loads(p.read_text()))
    assert f"({reason})" in str(e.value)
    assert main(["apply", str(p), "--point", "0", "0", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"failed calibration ({reason}) -> calibrate again" in err[0], err


def test_clip_cuts_between_words_and_says_so():
    text = "expected finite numbers (|x| < 1e6); got nan"
    assert clip(text, 80) == text
    assert clip(text, 30) == "expected finite numbers..."
    assert clip("  two\n lines ", 80) == "two lines"
    assert clip("x" * 50, 20) == "x" * 17 + "..."


def test_apply_takes_a_cells_camera_by_name(cell, capsys):
    from handeye.contract import read_result

    T_base_cam = read_result(cell["cell"]).camera_result("fixed1").T_x
    p_cam = np.array([0.01, -0.02, 0.5])
    assert main(["apply", str(cell["cell"]), "--point", *map(str, p_cam), "--camera", "fixed1"]) == 0
    out = capsys.readouterr().out
    want = transform_points(T_base_cam, p_cam[None])[0]
    got = [float(x) for x in out.splitlines()[0].split(":")[1].split()]
    np.testing.assert_allclose(got, want, atol=2e-6)
    assert main(["apply", str(cell["cell"]), "--point", "0", "0", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cell of 3 cameras (wrist, fixed1, fixed2)" in err[0] and "--camera" in err[0]
