"""Pose-only sessions: the pose factor, the refinement on tracker poses, session.yaml's target_pose views
and the workflow on them."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from handeye.errors import HandeyeError
from handeye.factors.pose import pose_residual, se3_right_jacobian_inverse
from handeye.frames import pose_error, se3_exp, se3_log, tangent_jacobian
from handeye.initial import all_methods
from handeye.mounting import mounting
from handeye.refine.poseonly import PoseView, refine_poses
from handeye.session import load_session
from handeye.sim.poses import make_tracker_session


def _refine(ts, **kw):
    m = mounting(ts.mode)
    Ms = np.stack([m.M_from_T_base_end(T) for T in ts.T_base_end])
    cf = all_methods(m, ts.T_cam_board, Ms)
    views = [PoseView(v, ts.T_cam_board[k], ts.T_base_end[k]) for k, v in enumerate(ts.view_ids)]
    return refine_poses(mode=ts.mode, views=views, T_x0=cf["tsai"].T_x, T_board0=cf["tsai"].T_board, starts=cf, **kw)


# ------------------------------------------------------------------------------ the factor
def test_right_jacobian_inverse_matches_numeric():
    rng = np.random.default_rng(0)
    for scale in (1e-3, 0.05, 0.2):
        xi = rng.standard_normal(6) * scale
        J = tangent_jacobian(se3_log, se3_exp(xi))
        assert np.abs(J - se3_right_jacobian_inverse(xi)).max() < 1e-7, scale


def test_pose_residual_jacobians_match_numeric():
    rng = np.random.default_rng(1)
    T_x, M, T_b = (se3_exp(rng.standard_normal(6) * 0.5) for _ in range(3))
    C = np.linalg.inv(T_x) @ M @ T_b @ se3_exp(rng.standard_normal(6) * 0.02)
    r, J_x, J_b = pose_residual(T_x=T_x, M=M, T_board=T_b, T_cam_board_measured=C)
    num_x = tangent_jacobian(
        lambda T: pose_residual(T_x=T, M=M, T_board=T_b, T_cam_board_measured=C, jacobians=False)[0], T_x
    )
    num_b = tangent_jacobian(
        lambda T: pose_residual(T_x=T_x, M=M, T_board=T, T_cam_board_measured=C, jacobians=False)[0], T_b
    )
    assert np.abs(J_x - num_x).max() < 1e-6
    assert np.abs(J_b - num_b).max() < 1e-6
    assert np.linalg.norm(r) > 0.01  # the test is not at a zero residual


# ------------------------------------------------------------------------------ the refinement
@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noiseless_tracker_session_recovers_the_truth(mode):
    ts = make_tracker_session(mode=mode, n_views=10, seed=4, sigma_mm=0.0, sigma_deg=0.0)
    res = _refine(ts, tracker_sigma=(np.radians(0.2), 0.0005))
    rot_deg, trans_mm = pose_error(res.T_x, ts.truth.T_x_true)
    assert res.status == "ok" and not res.outliers
    assert rot_deg < 1e-6 and trans_mm < 1e-6


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noisy_tracker_session_flags_outliers_within_its_sigma(mode):
    ts = make_tracker_session(mode=mode, n_views=20, seed=11, sigma_mm=0.5, sigma_deg=0.2, outlier_views=2)
    res = _refine(ts)  # the tracker's noise estimated
    assert res.status == "ok"
    assert sorted(o.view_id for o in res.outliers) == sorted(ts.truth.outlier_view_ids)
    assert all(res.per_view[v]["status"] == "removed" for v in ts.truth.outlier_view_ids)
    assert res.tracker_sigma_source == "estimated"
    # 18 views, 54 equations per group: the estimated sigma is within ~4 standard errors (1/sqrt(2*42))
    assert abs(res.tracker_sigma_mm / 0.5 - 1) < 0.45 and abs(res.tracker_sigma_deg / 0.2 - 1) < 0.45
    # the error of T_x in its own covariance: chi-square(6), below its 99.9 % quantile (22.5)
    xi = se3_log(np.linalg.inv(res.T_x) @ ts.truth.T_x_true)
    assert xi @ np.linalg.solve(res.cov_x_6x6, xi) < 22.5


def test_stated_tracker_sigma_is_held():
    ts = make_tracker_session(n_views=12, seed=5, sigma_mm=0.5, sigma_deg=0.2)
    res = _refine(ts, tracker_sigma=(np.radians(0.3), 0.001))
    assert res.tracker_sigma_source == "stated"
    assert res.tracker_sigma_mm == pytest.approx(1.0) and res.tracker_sigma_deg == pytest.approx(0.3)
    d = res.to_dict()
    assert d["intrinsics"] is None and d["tracker_noise"]["source"] == "stated"


def test_too_few_views_fail_with_a_reason():
    ts = make_tracker_session(n_views=3, seed=5)
    views = [PoseView(v, ts.T_cam_board[k], ts.T_base_end[k]) for k, v in enumerate(ts.view_ids)][:2]
    res = refine_poses(mode=ts.mode, views=views, T_x0=ts.truth.T_x_true, T_board0=ts.truth.T_board_true)
    assert res.status == "failed" and "need 3" in res.failure_reason


# ------------------------------------------------------------------------------ session.yaml
def test_session_yaml_target_pose_views_load(tmp_path):
    ts = make_tracker_session(n_views=6, seed=1)
    ts.write(tmp_path)
    s = load_session(tmp_path)
    assert s.meta["pose_only"] and s.target.kind == "tracked"
    assert s.meta["tracker_sigma"] == pytest.approx((np.radians(0.2), 0.0005, 0.0005))
    for k, v in enumerate(s.views):
        assert v.image_path is None
        assert np.allclose(v.T_cam_board, ts.T_cam_board[k], atol=1e-12)


def test_target_pose_format_is_applied(tmp_path):
    T = se3_exp(np.array([0.1, -0.2, 0.3, 0.05, 0.02, 0.6]))
    from handeye.conventions import PoseFormat, pose_values_from_T

    fmt = PoseFormat(rotation="quaternion", quaternion_order="xyzw", translation_unit="mm")
    vals = pose_values_from_T(T, fmt).tolist()
    d = {
        "handeye_session": 1,
        "pose_format": {"rotation": "matrix"},
        "target_pose_format": {"rotation": "quaternion", "quaternion_order": "xyzw", "translation_unit": "mm"},
        "views": [{"id": "1", "pose": np.eye(4).tolist(), "target_pose": vals}],
    }
    (tmp_path / "session.yaml").write_text(yaml.safe_dump(d))
    s = load_session(tmp_path)
    assert np.allclose(s.views[0].T_cam_board, T, atol=1e-9)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d["views"].append({"id": "9", "image": "9.png", "pose": np.eye(4).tolist()}), "all images or all"),
        (lambda d: d.update(tracker_sigma={"mm": 0.5}), "tracker_sigma"),
        (lambda d: d.update(tracker_sigma={"mm": -1, "deg": 0.2}), "tracker_sigma.mm"),
        (lambda d: d["views"][0].update(target_pose=[1, 2, 3]), "view 1"),
        (lambda d: d["views"][1].update(image="2.png"), "view 2 has both an image and a target_pose"),
        (lambda d: d["views"][2]["target_pose"][2].__setitem__(3, 450.0), "view 3: target position 450.0 m from the"),
        (lambda d: d["views"][3].pop("target_pose"), "view 4 is missing 'image' (or a tracker's target_pose)"),
    ],
)
def test_bad_pose_only_sessions_are_one_line_errors(tmp_path, change, message):
    ts = make_tracker_session(n_views=4, seed=1)
    ts.write(tmp_path)
    d = yaml.safe_load((tmp_path / "session.yaml").read_text())
    change(d)
    (tmp_path / "session.yaml").write_text(yaml.safe_dump(d))
    with pytest.raises(HandeyeError) as e:
        load_session(tmp_path)
    assert message in str(e.value)


# ------------------------------------------------------------------------------ the workflow
def test_workflow_calibrates_a_pose_only_session(tmp_path):
    from handeye.workflow import calibrate_session

    ts = make_tracker_session(mode="eye_to_hand", n_views=16, seed=2, outlier_views=1)
    ts.write(tmp_path / "s", state_sigma=False)
    calibrate_session(tmp_path / "s", out_dir=tmp_path / "out")
    d = json.loads((tmp_path / "out" / "result.json").read_text())
    assert d["status"] == "ok" and d["refinement"]["observations"] == "poses"
    assert [o["view_id"] for o in d["refinement"]["outliers"]] == list(ts.truth.outlier_view_ids)
    rot_deg, trans_mm = pose_error(np.array(d["T_base_cam"]), ts.truth.T_x_true)
    assert trans_mm < 5 * max(d["refinement"]["sigma_trans_mm"]) and rot_deg < 5 * max(d["refinement"]["sigma_rot_deg"])
    assert d["diagnostics"]["stages"]["cross_validation"] == "ok"  # the validation's folds on the poses
    assert (tmp_path / "out" / "report.html").exists() and (tmp_path / "out" / "report.md").exists()


def test_a_pose_only_report_and_verdict_speak_of_poses_not_pixels(tmp_path):
    """A pose-only session's views table gives each view's robot-vs-tracker disagreement, without the image,
    corner and pixel columns of an image session; with --no-refine the verdict has no pixel checks (reprojection
    RMS, image coverage) 'not available', only the uncertainty the refinement would give."""
    from handeye.cli import main

    make_tracker_session(n_views=10, seed=2).write(tmp_path / "s")
    assert main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o")]) == 0
    md = (tmp_path / "o" / "report.md").read_text()
    views = md[md.index("## Views") :].split("\n## ")[0]
    assert "| View | Status | Robot vs tracker | Flags |" in views and "[px]" not in views and "image not" not in views
    html = (tmp_path / "o" / "report.html").read_text()
    assert "Robot vs tracker" in html
    ids = set(re.findall(r'\sid="([^"]+)"', html))
    assert not [t for t in re.findall(r'href="#([^"]+)"', html) if t not in ids]  # no "Data quality" link to nothing
    assert (
        main(["-q", "calibrate", str(tmp_path / "s"), "--no-refine", "--no-report", "--out", str(tmp_path / "n")]) == 0
    )
    checks = json.loads((tmp_path / "n" / "result.json").read_text())["qa"]["checks"]
    keys = {k for c in checks for k in str(c["key"]).split("+")}
    assert "predicted_error_mm" in keys and not keys & {"reprojection_rms_px", "image_coverage"}, keys


# ------------------------------------------------------------------------------ easy_handeye2 samples
def _samples_file(path, ts, calibration_type):
    """An easy_handeye2 .samples file of a tracker session (robot: T_base_end eye-in-hand, T_end_base eye-on-base)."""
    from handeye.frames import quat_wxyz_from_R

    def tf(T):
        q = quat_wxyz_from_R(T[:3, :3])
        return {
            "translation": dict(zip("xyz", map(float, T[:3, 3]), strict=False)),
            "rotation": {"x": float(q[1]), "y": float(q[2]), "z": float(q[3]), "w": float(q[0])},
        }

    robot = ts.T_base_end if calibration_type == "eye_in_hand" else np.linalg.inv(ts.T_base_end)
    d = {
        "parameters": {
            "name": "demo",
            "calibration_type": calibration_type,
            "robot_base_frame": "base_link",
            "robot_effector_frame": "tool0",
            "tracking_base_frame": "camera_color_optical_frame",
            "tracking_marker_frame": "marker",
        },
        "samples": [{"robot": tf(R), "tracking": tf(C)} for R, C in zip(robot, ts.T_cam_board, strict=False)],
    }
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


@pytest.mark.parametrize("ctype, mode", [("eye_in_hand", "eye_in_hand"), ("eye_on_base", "eye_to_hand")])
def test_easy_handeye2_samples_import_to_a_pose_only_session(tmp_path, ctype, mode):
    from handeye.cli import main

    ts = make_tracker_session(mode=mode, n_views=5, seed=3)
    src = _samples_file(tmp_path / "demo.samples", ts, ctype)
    assert (
        main(["-q", "import", "easy_handeye2", str(src), "--out", str(tmp_path / "s"), "--tracker-sigma", "0.5", "0.2"])
        == 0
    )
    s = load_session(tmp_path / "s")
    assert s.mode == mode and s.meta["pose_only"]
    assert s.meta["tracker_sigma"] == pytest.approx((np.radians(0.2), 0.0005, 0.0005))
    for k, v in enumerate(s.views):
        assert v.view_id == str(k + 1)
        assert np.allclose(v.T_base_end, ts.T_base_end[k], atol=1e-9)
        assert np.allclose(v.T_cam_board, ts.T_cam_board[k], atol=1e-9)


# ------------------------------------------------------------------------------ MoveIt Calibration samples
def _moveit_samples(path, ts):
    """MoveIt Calibration's saved samples of a tracker session: effector_wrt_world (T_base_end, in both modes) and
    object_wrt_sensor (T_cam_board), 16 numbers row by row each."""
    samples = [
        {"effector_wrt_world": E.reshape(-1).tolist(), "object_wrt_sensor": C.reshape(-1).tolist()}
        for E, C in zip(ts.T_base_end, ts.T_cam_board, strict=True)
    ]
    path.write_text(yaml.safe_dump(samples, sort_keys=False))
    return path


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_moveit_samples_import_to_a_pose_only_session_whose_mode_the_data_decide(tmp_path, mode, capsys):
    from handeye.cli import main

    ts = make_tracker_session(mode=mode, n_views=12, seed=4)
    src = _moveit_samples(tmp_path / "samples.yaml", ts)
    assert main(["-q", "import", "moveit", str(src), str(tmp_path / "s")]) == 0
    s = load_session(tmp_path / "s")
    assert "mode" not in yaml.safe_load((tmp_path / "s" / "session.yaml").read_text()) and s.mode_source == "default"
    assert s.meta["pose_only"] and [v.view_id for v in s.views] == [str(k) for k in range(1, 13)]
    for k, v in enumerate(s.views):
        np.testing.assert_allclose(v.T_base_end, ts.T_base_end[k], atol=1e-12)
        np.testing.assert_allclose(v.T_cam_board, ts.T_cam_board[k], atol=1e-12)
    assert main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "out"), "--no-report"]) == 0
    d = json.loads((tmp_path / "out" / "result.json").read_text())
    x_name = mounting(mode).x_name
    assert d["mode"] == mode and d["mode_source"] != "stated"
    rot_deg, trans_mm = pose_error(np.array(d[x_name]), ts.truth.T_x_true)
    assert trans_mm < 5 * max(d["refinement"]["sigma_trans_mm"]) and rot_deg < 5 * max(d["refinement"]["sigma_rot_deg"])
    # --mode is written into the session
    assert main(["-q", "import", "moveit", str(src), str(tmp_path / "s2"), "--mode", mode]) == 0
    assert load_session(tmp_path / "s2").mode == mode
    # a tracker sigma that is no sigma is refused when the option is read, not written for calibrate to refuse
    for bad in (["-1", "0.2"], ["nan", "0.2"], ["0.5", "inf"]):
        with pytest.raises(SystemExit) as e:
            main(["-q", "import", "moveit", str(src), str(tmp_path / "s3"), "--tracker-sigma", *bad])
        assert e.value.code == 2 and not (tmp_path / "s3").exists()
    assert "argument --tracker-sigma: expected a finite number > 0" in capsys.readouterr().err


def test_a_sample_saved_twice_is_left_out_with_a_warning(tmp_path, caplog):
    from handeye.session.moveit_samples import import_moveit_samples

    src = _moveit_samples(tmp_path / "samples.yaml", make_tracker_session(n_views=6, seed=3))
    d = yaml.safe_load(src.read_text())
    src.write_text(yaml.safe_dump([*d, d[1]]))  # sample 7 is sample 2 again
    with caplog.at_level("WARNING"):
        path = import_moveit_samples(src, tmp_path / "s")
    assert "sample(s) 7 repeat an earlier one exactly: left out" in caplog.text
    assert len(yaml.safe_load(path.read_text())["views"]) == 6


@pytest.mark.parametrize(
    "text, message",
    [
        ("effector_wrt_world: [1, 0]\n", "not a list of samples"),
        ("- {effector_wrt_world: [], object_wrt_sensor: []}\n" * 2, "2 samples; at least 3"),
        (None, "sample 2 object_wrt_sensor: expected 16 numbers"),
        ("TRANSPOSED", "sample 1 effector_wrt_world: last row of the 4x4 matrix must be 0 0 0 1"),
        ("MILLIMETRES", "not plausible"),
    ],
)
def test_bad_moveit_samples_are_one_line_errors_naming_the_sample(tmp_path, text, message):
    from handeye.session.moveit_samples import import_moveit_samples

    src = _moveit_samples(tmp_path / "samples.yaml", make_tracker_session(n_views=4, seed=3))
    d = yaml.safe_load(src.read_text())
    if text is None:
        d[1]["object_wrt_sensor"] = d[1]["object_wrt_sensor"][:15]
    elif text == "TRANSPOSED":
        d[0]["effector_wrt_world"] = np.array(d[0]["effector_wrt_world"]).reshape(4, 4).T.reshape(-1).tolist()
    elif text == "MILLIMETRES":  # the translations in mm, the rotations as they were
        for sample in d:
            E = np.array(sample["effector_wrt_world"]).reshape(4, 4)
            E[:3, 3] *= 1000.0
            sample["effector_wrt_world"] = E.reshape(-1).tolist()
    src.write_text(yaml.safe_dump(d) if text in (None, "TRANSPOSED", "MILLIMETRES") else text)
    with pytest.raises(HandeyeError) as e:
        import_moveit_samples(src, tmp_path / "s")
    assert message in str(e.value) and "samples.yaml" in str(e.value) and not (tmp_path / "s").exists()


@pytest.mark.parametrize(
    "edit, mode, message",
    [
        (lambda d: d["parameters"].update(calibration_type=""), None, "--mode"),
        (lambda d: None, "eye_to_hand", "--mode eye_to_hand but the samples are eye_in_hand"),
        # samples are numbered from 1, as the session's views and MoveIt's samples are
        (lambda d: d["samples"][1]["tracking"]["rotation"].update(w=3.0), None, "sample 2 tracking"),
        (lambda d: d["samples"][0].pop("robot"), None, "sample 1: needs robot"),
        (lambda d: d["samples"][2]["tracking"]["translation"].update(z=450.0), None, "sample 3: target position"),
        (lambda d: d.update(samples=[d["samples"][0]] * 4), None, "1 distinct sample(s); at least 3 are needed"),
        (lambda d: d.pop("samples"), None, "no samples list"),
    ],
)
def test_bad_easy_handeye2_samples_are_one_line_errors(tmp_path, edit, mode, message):
    from handeye.session.easy_handeye2 import import_easy_handeye2

    ts = make_tracker_session(n_views=4, seed=3)
    src = _samples_file(tmp_path / "x.samples", ts, "eye_in_hand")
    d = yaml.safe_load(src.read_text())
    edit(d)
    src.write_text(yaml.safe_dump(d))
    with pytest.raises(HandeyeError) as e:
        import_easy_handeye2(src, tmp_path / "s", mode=mode)
    assert message in str(e.value)


@pytest.mark.parametrize(
    "flags, named",
    [
        (["--robot-noise", "fixed"], "one noise of the tracker and the robot"),
        (["--robot-sigma", "0.2", "0.05"], "tracker_sigma in session.yaml"),
        (["--fix", "k3"], "no camera intrinsics"),
        (["--fix-k3"], "no camera intrinsics"),
        (["--shift-poses", "1"], "holds its tracker pose and its robot pose"),
        (["--prior", "earlier"], "works on detected corners"),
        (["--robot-noise", "fixed", "--fix-k3"], "--robot-noise: a pose-only session"),
    ],
)
def test_calibrate_flags_a_pose_only_session_would_ignore_are_refused(tmp_path, capsys, flags, named):
    """Flags that do not apply to a session kind are used or refused, never ignored: one line, exit 2."""
    from handeye.cli import main

    ts = make_tracker_session(n_views=8, seed=3)
    ts.write(tmp_path / "s")
    (tmp_path / "earlier").mkdir()
    args = [a if a != "earlier" else str(tmp_path / "earlier") for a in flags]
    rc = main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "o"), "--no-report", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "not apply to a pose-only session" in err[0] and named in err[0] and flags[0] in err[0]
    assert not (tmp_path / "o" / "result.json").exists()


def test_calibrate_flags_that_apply_to_a_pose_only_session_are_used(tmp_path):
    """--method and --no-refine choose the solve; --workers is a thread limit (a batch passes it to every session)."""
    from handeye.cli import main

    ts = make_tracker_session(n_views=8, seed=3)
    ts.write(tmp_path / "s")
    flags = ["--no-report", "--workers", "1", "--method", "park", "--no-refine"]
    assert main(["-q", "calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "ok"), *flags]) == 0
    d = json.loads((tmp_path / "ok" / "result.json").read_text())
    assert d["status"] == "ok" and d["method"] == "park" and not d.get("refined")


def test_reported_poses_the_named_arm_cannot_reach_are_a_failing_finding(tmp_path):
    """A pose-only session calibrated with --robot naming an arm that cannot reach some of its reported poses
    (5 of these 12 flange poses are beyond a UR5e's reach or joint limits): their joints are the
    view's before, and the result rests on them. It passed without a word; now a FAIL finding names them and the
    arm, and says what to check."""
    from handeye.cli import main
    from handeye.kinematics import default_ik_seeds, load_arm, solve_ik

    ts = make_tracker_session(n_views=12, seed=5)
    ts.write(tmp_path / "s")
    argv = ["-q", "calibrate", str(tmp_path / "s"), "--robot", "ur5e", "--no-report", "--out", str(tmp_path / "o")]
    assert main(argv) == 7
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    arm = load_arm("ur5e")
    out_of_reach = [
        str(k + 1) for k, T in enumerate(ts.T_base_end) if solve_ik(arm, T, seeds=default_ik_seeds(arm, T)) is None
    ]
    unreachable = res["refinement"]["robot_model"]["unreachable_view_ids"]
    assert unreachable == out_of_reach and len(unreachable) == 5, (out_of_reach, unreachable)
    f = [f for f in res["findings"] if f["code"] == "arm_cannot_reach"]
    assert len(f) == 1 and f[0]["severity"] == "fail" and f[0]["view_ids"] == unreachable
    assert "UR5e" in f[0]["title"] and "--robot" in f[0]["action"]


def test_three_tracked_views_are_too_few_not_two_wrong_robot_poses(tmp_path):
    """Three views solve X, but a view left out leaves two, one motion, which leaves X free: no view can be
    tested against the others. The session fails for its few views (exit 7), all three used, none named as a
    wrong robot pose, and no numpy warning. Before, the test flagged two and the refinement failed (exit 5)."""
    import warnings

    from handeye.cli import main
    from handeye.sim.corners import make_corner_session

    s = make_corner_session(mode="eye_in_hand", n_views=20, seed=3, noise_px=0.0)  # its first three poses
    rng = np.random.default_rng(0)  # a tracker of 0.1 deg / 0.5 mm per axis, its noise estimated
    views = [
        {
            "id": str(k + 1),
            "pose": s.T_base_end_true[k].tolist(),
            "target_pose": (
                s.T_cam_board_true[k] @ se3_exp(np.r_[rng.normal(0, np.radians(0.1), 3), rng.normal(0, 5e-4, 3)])
            ).tolist(),
        }
        for k in range(3)
    ]
    (tmp_path / "s").mkdir()
    doc = {"handeye_session": 1, "mode": "eye_in_hand", "pose_format": {"rotation": "matrix"}, "views": views}
    (tmp_path / "s" / "session.yaml").write_text(yaml.safe_dump(doc))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert main(["-q", "calibrate", str(tmp_path / "s"), "--no-report", "--out", str(tmp_path / "o")]) == 7
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    assert {v["status"] for v in res["refinement"]["per_view"].values()} == {"used"}
    assert "robot_pose_disagrees" not in {f["code"] for f in res["findings"]}
    assert any("views used 3" in str(c.get("short") or c.get("title")) for c in res["qa"]["checks"])


def test_an_importer_given_the_other_kind_of_samples_file_names_the_importer_that_reads_it(tmp_path):
    """A MoveIt samples file given to ``import easy_handeye2`` and the other way round: one line naming the file,
    with the import command that reads it (before: 'expected a mapping at the top level; got list')."""
    from handeye.session.easy_handeye2 import import_easy_handeye2
    from handeye.session.moveit_samples import import_moveit_samples

    ts = make_tracker_session(n_views=4, seed=3)
    eh = _samples_file(tmp_path / "x.samples", ts, "eye_in_hand")
    mv = tmp_path / "samples.yaml"
    mv.write_text(yaml.safe_dump([{"effector_wrt_world": [0.0] * 16, "object_wrt_sensor": [0.0] * 16}] * 3))
    with pytest.raises(HandeyeError, match="this looks like a MoveIt Calibration samples file: handeye import moveit"):
        import_easy_handeye2(mv, tmp_path / "a", mode="eye_in_hand")
    with pytest.raises(HandeyeError, match="this looks like an easy_handeye2 samples file: handeye import easy_han"):
        import_moveit_samples(eh, tmp_path / "b")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_tracker_poses_that_fit_no_robot_pose_reading_point_at_the_tracker_s_format(tmp_path):
    """Tracker quaternions written w-first under ``quaternion_order: xyzw``: no reading of the robot's numbers
    explains them. The finding speaks of the tracker's poses and their format, not of images (there are none)."""
    from handeye.cli import main
    from handeye.frames import quat_wxyz_from_R

    ts = make_tracker_session(n_views=12, seed=2)
    ts.write(tmp_path / "s")
    f = tmp_path / "s" / "session.yaml"
    d = yaml.safe_load(f.read_text())
    d["target_pose_format"] = {"rotation": "quaternion", "quaternion_order": "xyzw"}
    for v in d["views"]:
        T = np.asarray(v["target_pose"], float)
        v["target_pose"] = [*T[:3, 3].tolist(), *quat_wxyz_from_R(T[:3, :3]).tolist()]  # w first: the wrong order
    f.write_text(yaml.safe_dump(d))
    assert main(["-q", "calibrate", str(tmp_path / "s"), "--no-report", "--out", str(tmp_path / "o")]) == 5
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    unfit = [x for x in res["findings"] if x["code"] == "poses_do_not_fit"]
    assert len(unfit) == 1 and "tracker's poses" in unfit[0]["title"] and "quaternion_order" in unfit[0]["action"]
    assert "images" not in res["verdict_headline"], res["verdict_headline"]
    assert "the tracked target implied by each view scatters by" in unfit[0]["evidence"], unfit[0]  # not a board
