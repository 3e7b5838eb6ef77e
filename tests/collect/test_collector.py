"""The automatic collection: corner orderings resolved before the first estimate, re-planning after misses,
the simulator's seed recorded, and collect's exit codes."""

from __future__ import annotations

import argparse
import io
import sys
from dataclasses import replace

import numpy as np
import pytest
import yaml

from handeye.cli.collect import add_collect_arguments, run_collect
from handeye.collect import session_writer as sw
from handeye.collect.collector import Collector, detector_orderings
from handeye.errors import DetectionError
from handeye.frames import se3_exp
from handeye.sim.devices import SimCamera, SimRig, SimRobot
from handeye.sim.scenarios import default_intrinsics
from handeye.targets import ChessboardSpec


def _args(out, *extra):
    p = argparse.ArgumentParser()
    add_collect_arguments(p)
    return p.parse_args([str(out), "--camera", "sim", "--robot", "sim", *extra])


def _collected(out) -> dict:
    return yaml.safe_load((out / "session.yaml").read_text())["collected"]


def test_an_asymmetric_chessboard_may_be_numbered_from_either_end():
    orderings = detector_orderings(ChessboardSpec(11, 8, 0.03))
    assert len(orderings) == 2
    np.testing.assert_array_equal(orderings[0], np.arange(88))
    np.testing.assert_array_equal(orderings[1], np.arange(88)[::-1])
    assert len(detector_orderings(ChessboardSpec(9, 9, 0.03))) == 4


# seeds whose start or probe views OpenCV numbered from the other end of the board: the first estimate was
# wrong, all 8 planned poses missed the board and the session kept 4 views (96, 119), or the first estimate
# failed (63: "solver returned a matrix that is not a rotation", exit 3)
@pytest.mark.parametrize("seed", [63, 96, 119])
def test_a_probe_view_numbered_from_the_other_end_does_not_spoil_the_plan(tmp_path, seed, caplog):
    out = tmp_path / "s"
    assert run_collect(_args(out, "--mode", "eye_in_hand", "--auto", "--seed", str(seed))) == 0
    recs = sorted((out / "views").glob("*.yaml"))
    assert len(recs) == 12
    assert _collected(out)["seed"] == seed


class _SpoiledFirstEstimate(Collector):
    """A collector whose first hand-eye estimate is 30 deg and 200 mm off (as a wrong view would make it)."""

    spoiled = 0
    every_time = False  # spoil every estimate alike (the same views giving the same wrong answer)

    def _estimate(self, mount):
        views, rough = super()._estimate(mount)
        if (self.every_time or not self.spoiled) and rough is not None:
            self.spoiled += 1
            T_x = rough.T_x @ se3_exp(np.r_[np.radians(30.0) * np.array([0.6, 0.8, 0.0]), 0.0, 0.2, 0.0])
            rough = replace(rough, T_x=T_x)
        return views, rough


def _spoiled_collector(tmp_path, *, every_time: bool) -> _SpoiledFirstEstimate:
    rig = SimRig.sample(mode="eye_in_hand", rng=np.random.default_rng(3), intrinsics=default_intrinsics(640, 360))
    robot = SimRobot(rig, rng=np.random.default_rng(4))
    writer = sw.SessionWriter(tmp_path / "r", mode=rig.mode, target=rig.target, intrinsics=rig.intrinsics)
    col = _SpoiledFirstEstimate(
        robot=robot,
        camera=SimCamera(robot, rng=np.random.default_rng(5)),
        writer=writer,
        target=rig.target,
        mode=rig.mode,
    )
    col.every_time = every_time
    return col


def test_two_planned_poses_missing_the_board_re_estimate_and_re_plan(tmp_path, caplog):
    col = _spoiled_collector(tmp_path, every_time=False)
    with caplog.at_level("INFO", logger="handeye.collect.collector"):
        col.run_auto(n_views=8, speed_fraction=0.2)
    misses = [c for c in col.rejected if c.reason.startswith("target not detected")]
    assert len(misses) == 2, [c.reason for c in col.rejected]  # the two misses that started the re-plan
    assert "2 planned poses in a row missed the board: re-estimated from 4 views" in caplog.text
    assert "half as far" not in caplog.text  # the new estimate differs: the plan keeps its reach
    assert len(col.kept) == 4 + 8  # start, 3 probes, and every planned view after all


def test_an_estimate_that_stays_wrong_re_plans_nearer_once_then_stops(tmp_path, caplog):
    col = _spoiled_collector(tmp_path, every_time=True)
    with caplog.at_level("INFO", logger="handeye.collect.collector"):
        col.run_auto(n_views=8, speed_fraction=0.2)
    assert caplog.text.count("the estimate did not change: the new plan turns half as far") == 1
    assert "the estimate does not change; stopping with" in caplog.text
    misses = [c for c in col.history[4:] if not c.kept]
    assert len(misses) <= 4  # two blind moves per plan, two plans


def test_the_simulator_records_the_seed_it_drew_and_the_seed_repeats_the_run(tmp_path, monkeypatch):
    runs = []
    for k, seed in enumerate([None, "drawn"]):
        out = tmp_path / f"s{k}"
        extra = [] if seed is None else ["--seed", str(runs[0]["seed"])]
        monkeypatch.setattr(sys, "stdin", io.StringIO("s\ns\nq\n"))
        assert run_collect(_args(out, "--mode", "eye_to_hand", "--no-preview", *extra)) == 0
        runs.append(_collected(out))
        truth = yaml.safe_load((out / "ground_truth.json").read_text())
        assert truth["seed"] == runs[-1]["seed"]
        runs[-1]["truth"] = truth
    assert isinstance(runs[0]["seed"], int) and runs[1]["seed"] == runs[0]["seed"]
    assert runs[1]["truth"]["T_base_cam"] == runs[0]["truth"]["T_base_cam"]
    assert runs[1]["truth"]["views"] == runs[0]["truth"]["views"]  # the same poses, true and reported


def test_a_session_where_every_capture_is_rejected_exits_with_the_detection_code(tmp_path, monkeypatch):
    from handeye.cli import main

    monkeypatch.setattr(sys, "stdin", io.StringIO("s\ns\nq\n"))
    out = tmp_path / "blind"
    # a blur no chessboard detector finds: every capture is rejected as "target not detected"
    with pytest.raises(DetectionError, match=r"no view kept: target not detected \(2x\)"):
        run_collect(_args(out, "--mode", "eye_in_hand", "--no-preview", "--sim-blur", "40", "--seed", "1"))
    monkeypatch.setattr(sys, "stdin", io.StringIO("q\n"))  # no capture at all: the same code, through the CLI
    argv = ["collect", str(tmp_path / "none"), "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim"]
    assert main([*argv, "--no-preview"]) == DetectionError.exit_code == 3


def test_a_symmetric_board_view_numbered_from_the_other_end_is_turned_back_by_the_robot_motion(tmp_path):
    from handeye.camera import pixels_from_board_points
    from handeye.collect.collector import Capture, pose_orderings
    from handeye.collect.plan import probe_poses
    from handeye.collect.robot import PoseReading
    from handeye.mounting import mounting

    target = ChessboardSpec(9, 7, 0.03)  # cols + rows even: a half turn looks the same, colours or not
    rig = SimRig.sample(
        mode="eye_to_hand", rng=np.random.default_rng(2), target=target, intrinsics=default_intrinsics(1280, 720)
    )
    robot = SimRobot(rig, pose_noise_mm=0.0, pose_noise_deg=0.0)
    writer = sw.SessionWriter(tmp_path / "y", mode=rig.mode, target=target, intrinsics=rig.intrinsics)
    col = Collector(robot=robot, camera=SimCamera(robot), writer=writer, target=target, mode=rig.mode)
    T0 = rig.T_base_end_start
    poses = [T0] + [tries[0] for tries in probe_poses(T0, probe_deg=10.0)] + [T0 @ se3_exp(np.r_[0.1, 0.1, 0, 0, 0, 0])]
    C_true = mounting(rig.mode).predict_T_cam_board(rig.T_x, rig.T_board, np.stack(poses))
    obj = target.object_points()
    caps = []
    for k, (T, C) in enumerate(zip(poses, C_true, strict=True)):
        ids = np.arange(target.n_corners)
        pts = pixels_from_board_points(C, obj, rig.intrinsics)
        if k == 2:  # this view's detector numbered the corners from the other end
            pts = pts[::-1].copy()
        Ts = pose_orderings(target, rig.intrinsics, ids, pts)
        caps.append(Capture(True, "", str(k + 1), PoseReading(T, 0.0, {}), ids, pts, 100.0, Ts[0], float("nan"), Ts, 0))
    assert rotation_angle_deg(caps[2].T_cam_board, C_true[2]) > 170  # as detected: turned by half a turn
    out = col._reoriented(caps)
    assert [c.orientation for c in out] == [0, 0, 1, 0, 0]
    for c, C in zip(out, C_true, strict=True):
        assert rotation_angle_deg(c.T_cam_board, C) < 1e-6
        np.testing.assert_allclose(c.T_cam_board[:3, 3], C[:3, 3], atol=1e-9)


def rotation_angle_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    from handeye.frames import rotation_angle_rad

    return float(np.degrees(rotation_angle_rad(T_a[:3, :3].T @ T_b[:3, :3])))


def test_an_arm_in_error_for_every_capture_exits_with_the_hardware_code(tmp_path, monkeypatch):
    from handeye.cli import main
    from handeye.collect.robot import PoseReading
    from handeye.errors import HardwareError

    real_read = SimRobot.read_pose

    def in_error(self):
        r = real_read(self)
        return PoseReading(r.T_base_end, r.t_pose, {**r.state, "errors": [0x1001]}, r.joints)

    monkeypatch.setattr(SimRobot, "read_pose", in_error)
    monkeypatch.setattr(sys, "stdin", io.StringIO("s\ns\nq\n"))
    argv = ["collect", str(tmp_path / "e"), "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim"]
    assert main([*argv, "--no-preview", "--seed", "2"]) == HardwareError.exit_code == 6
