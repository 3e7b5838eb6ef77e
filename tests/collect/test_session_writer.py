"""Collected sessions: simulated collections against their ground truth, crash safety, the real-arm path."""

from __future__ import annotations

import argparse
import io
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from handeye.camera import pixels_from_board_points
from handeye.cli.collect import add_collect_arguments, parse_target_spec, run_collect
from handeye.collect import session_writer as sw
from handeye.collect.camera import Camera
from handeye.collect.collector import CaptureChecks, Collector
from handeye.collect.realman import RealmanArm
from handeye.detect import detect_gray
from handeye.errors import ConfigError, DetectionError, InputError
from handeye.frames import inv_T, rotvec_from_R
from handeye.mounting import mounting
from handeye.sim.devices import SimCamera, SimRig, SimRobot
from handeye.sim.realman_emulator import RealmanEmulator
from handeye.sim.render import render_view
from handeye.sim.scenarios import default_intrinsics
from handeye.targets import ChessboardSpec

REPO = Path(__file__).resolve().parents[2]
FAST = ["--resolution", "640x360", "--sim-supersample", "2"]
EMPTY_RUN_RECORD = "collect_run.yaml"  # a collection that kept no view: its settings, seed and why


def _args(argv):
    p = argparse.ArgumentParser()
    add_collect_arguments(p)
    return p.parse_args([str(a) for a in argv])


def _records(out: Path) -> dict:
    """Every view record parsed with PyYAML, checked to have its image."""
    recs = {}
    for f in sorted((out / "views").iterdir()):
        if f.name.startswith(".") or f.suffix != ".yaml":
            continue
        r = yaml.safe_load(f.read_text())
        for key in ("id", "image", "pose", "t_image", "t_pose", "robot_state"):
            assert key in r, f"{f}: missing {key}"
        img = cv2.imread(str(out / r["image"]), cv2.IMREAD_UNCHANGED)
        assert img is not None, f"{f}: image {r['image']} missing or unreadable"
        recs[str(r["id"])] = r
    return recs


def _load(out: Path):
    from handeye.session import load_session

    return load_session(out)


# ------------------------------------------------------------------------------ simulated collection
@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_simulated_auto_collection_agrees_with_ground_truth(tmp_path, mode):
    out = tmp_path / "s"
    rc = run_collect(
        _args(
            [out, "--mode", mode, "--camera", "sim", "--robot", "sim", "--auto", "--views", "6", "--seed", "11", *FAST]
        )
    )
    assert rc == 0
    truth = json.loads((out / "ground_truth.json").read_text())
    mount = mounting(mode)
    assert truth["mode"] == mode and mount.x_name in truth and mount.board_name in truth
    T_x, T_b = np.asarray(truth[mount.x_name]), np.asarray(truth[mount.board_name])
    header = yaml.safe_load((out / "session.yaml").read_text())
    assert header["pose_format"] == {"rotation": "matrix", "translation_unit": "m"}
    assert header["intrinsics"]["use"] == "initial" and header["view_records"] == "views"
    assert truth["intrinsics"]["fx"] == header["intrinsics"]["fx"]
    recs = _records(out)
    assert len(recs) == 10  # start + 3 probes + 6 planned
    target = ChessboardSpec(11, 8, 0.03)
    intr = default_intrinsics(640, 360)
    obj = target.object_points()
    for vid, r in recs.items():
        gt = truth["views"][vid]
        T_rep = np.asarray(r["pose"], float)
        np.testing.assert_allclose(T_rep, np.asarray(gt["T_base_end_reported"]), atol=1e-12)
        gray = cv2.imread(str(out / r["image"]), cv2.IMREAD_GRAYSCALE)
        ids, pts = detect_gray(gray, target)
        # the image shows the board where the truth (true robot pose) puts it ...
        C_true = mount.predict_T_cam_board(T_x, T_b, np.asarray(gt["T_base_end_true"]))
        uv = pixels_from_board_points(C_true, obj[ids], intr)
        rms_true = np.sqrt(np.mean(np.sum((uv - pts) ** 2, axis=1)))
        # detected corners of a 640x360 render (supersample 2, 2 grey levels of noise) against the truth:
        # measured 0.06-0.23 px rms per view with this seed (noise-free renders: 0.04-0.09 px, test_synth)
        assert rms_true < 0.3, f"view {vid}: corners {rms_true:.3f} px from the truth"
        # ... and the reported pose is off only by the simulated robot noise: per axis 0.1 mm and
        # 0.02 deg in the end frame (the --sim-pose-noise default); 4.9 sigma bounds 60 draws with a
        # false alarm of 6e-5 in all
        dT = inv_T(np.asarray(gt["T_base_end_true"])) @ T_rep
        assert np.all(np.abs(1e3 * dT[:3, 3]) < 4.9 * 0.1), f"view {vid}: {1e3 * dT[:3, 3]} mm"
        assert np.all(np.abs(np.degrees(rotvec_from_R(dT[:3, :3]))) < 4.9 * 0.02), f"view {vid}"
    session = _load(out)
    assert session.format == "native" and session.mode == mode
    assert sorted(v.view_id for v in session.views) == sorted(recs)
    assert session.intrinsics is not None and session.intrinsics.width == 640


def test_simulated_interactive_collection_from_a_terminal(tmp_path, monkeypatch):
    out = tmp_path / "i"
    monkeypatch.setattr(sys, "stdin", io.StringIO("s\n\nhelp\ns\nq\ns\n"))
    rc = run_collect(
        _args([out, "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", "--seed", "2", "--no-preview", *FAST])
    )
    assert rc == 0
    assert sorted(_records(out)) == ["1", "2", "3"]  # 'help' is not a key, input stops at 'q'


def test_blurred_frames_are_rejected_with_the_reason(tmp_path, caplog):
    rig = SimRig.sample(mode="eye_in_hand", rng=np.random.default_rng(0), intrinsics=default_intrinsics(640, 360))
    robot = SimRobot(rig, rng=np.random.default_rng(1))
    # a floor between a blurred and a sharp frame of the same view (640x360, 2 grey levels of noise:
    # ~100 at a blur sigma of 2.5 px, thousands when sharp; bench_render prints the scale)
    checks = CaptureChecks(min_sharpness=1000.0)
    camera = SimCamera(robot, blur_sigma_px=2.5, rng=np.random.default_rng(2))
    writer = sw.SessionWriter(tmp_path / "b", mode="eye_in_hand", target=rig.target, intrinsics=rig.intrinsics)
    col = Collector(robot=robot, camera=camera, writer=writer, target=rig.target, mode="eye_in_hand", checks=checks)
    cap = col.capture()
    assert not cap.kept and "not sharp" in cap.reason
    assert not (tmp_path / "b").exists()  # nothing is written before the first view kept
    sharp = Collector(
        robot=robot,
        camera=SimCamera(robot, rng=np.random.default_rng(3)),
        writer=sw.SessionWriter(tmp_path / "s", mode="eye_in_hand", target=rig.target),
        target=rig.target,
        mode="eye_in_hand",
        checks=checks,
    ).capture()
    assert sharp.kept and sharp.sharpness > checks.min_sharpness, sharp.reason


def test_collect_argument_errors(tmp_path):
    with pytest.raises(ConfigError, match="simulated arm"):
        run_collect(_args([tmp_path / "x", "--mode", "eye_in_hand", "--camera", "sim", "--robot", "realman:127.0.0.1"]))
    with pytest.raises(ConfigError, match="address"):
        run_collect(_args([tmp_path / "x", "--mode", "eye_in_hand", "--camera", "realsense", "--robot", "realman"]))
    with pytest.raises(ConfigError, match="--target"):
        parse_target_spec("chessboard:11x8:30")  # millimetres instead of metres
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x.txt").write_text("x")
    with pytest.raises(InputError, match="not empty"):
        run_collect(_args([tmp_path / "full", "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", *FAST]))


@pytest.mark.parametrize(
    "extra, stdin, why",
    [
        (["--auto", "--sim-blur", "30"], "", "automatic mode starts from a view of the board, and the first capture"),
        (["--no-preview"], "", "no capture was taken"),
        (["--no-preview", "--sim-blur", "30"], "s\ns\nq\n", "target not detected (2x)"),
    ],  # no board in sight; no key pressed; every capture blurred
    ids=["auto_blurred", "interactive_no_input", "interactive_all_rejected"],
)
def test_a_collection_that_keeps_no_view_leaves_its_record_only_and_runs_again(
    tmp_path, monkeypatch, capsys, extra, stdin, why
):
    """Before, OUT kept session.yaml without views, ground_truth.json and empty images/ and views/: calibrate said the
    session has no views and the same command was refused (output folder is not empty). Then OUT was removed and
    nothing on disk said which seed and settings had kept no view. Now OUT holds only collect_run.yaml (the settings,
    the seed, why, each rejection), no command takes it for a session, and the same command runs into it again."""
    from handeye.batch.discover import discover
    from handeye.cli import main
    from handeye.session import load_session

    out = tmp_path / "new" / "s"
    argv = ["-q", "collect", out, "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", "--seed", "1"]
    command = [str(a) for a in [*argv, *FAST, *extra]]
    monkeypatch.setattr(sys, "argv", ["/usr/local/bin/handeye", *command])  # as typed, for the record
    for _ in range(2):
        monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
        assert main(command) == 3
        assert [f.name for f in out.glob("*")] == [EMPTY_RUN_RECORD]
        err = capsys.readouterr().err
        err = err[err.index("handeye: error: ") :].splitlines()[0]  # the error's line, after the prompt if any
        assert err.startswith(f"handeye: error: no view kept: {why}"), err
        assert f"; this run's settings and seed: {out / EMPTY_RUN_RECORD} -> " in err, err
    record = yaml.safe_load((out / EMPTY_RUN_RECORD).read_text())
    assert record["outcome"] == "no view kept" and record["why"].startswith(why) and record["mode"] == "eye_in_hand"
    assert record["collected"]["seed"] == 1 and record["collected"]["command_line"] == "handeye " + " ".join(command)
    assert record["target"]["type"] == "chessboard" and record["collected"]["capture"] in ("auto", "interactive")
    assert len(record["rejected"]) == (2 if "(2x)" in why else 1 if "--auto" in extra else 0)
    assert "handeye_session" not in record and "view_records" not in record
    with pytest.raises(InputError, match=f"its {EMPTY_RUN_RECORD} records a collection that kept no view"):
        load_session(out)
    assert discover(tmp_path / "new") == []  # nor does a batch over its parent find a session
    (tmp_path / "mine").mkdir()  # a folder of the user's gets the record too
    monkeypatch.setattr(sys, "stdin", io.StringIO(stdin))
    assert main([str(a) for a in [*argv[:2], tmp_path / "mine", *argv[3:], *FAST, *extra]]) == 3
    assert [f.name for f in (tmp_path / "mine").iterdir()] == [EMPTY_RUN_RECORD]


def test_a_collection_that_keeps_a_view_replaces_an_earlier_empty_run_s_record(tmp_path, monkeypatch):
    """The seed an empty run recorded repeats it; with the board in sight the folder becomes a session, its
    session.yaml the run's record, and the empty run's record goes."""
    out = tmp_path / "s"
    argv = [out, "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", "--no-preview", *FAST]
    monkeypatch.setattr(sys, "stdin", io.StringIO("q\n"))
    with pytest.raises(DetectionError, match="no view kept: no capture was taken"):
        run_collect(_args(argv))
    seed = yaml.safe_load((out / EMPTY_RUN_RECORD).read_text())["collected"]["seed"]
    monkeypatch.setattr(sys, "stdin", io.StringIO("s\nq\n"))
    assert run_collect(_args([*argv, "--seed", seed])) == 0
    assert sorted(f.name for f in out.iterdir()) == ["ground_truth.json", "images", "session.yaml", "views"]
    assert yaml.safe_load((out / "session.yaml").read_text())["collected"]["seed"] == seed


def test_an_interrupted_collection_before_its_first_view_leaves_its_record(tmp_path, monkeypatch, caplog):
    """Ctrl-C at the prompt, before a view was kept: the record says so and the interrupt goes on to the CLI."""

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    out = tmp_path / "s"
    monkeypatch.setattr(sys, "stdin", io.StringIO("s\ns\n"))
    monkeypatch.setattr(sw.SessionWriter, "write_view", interrupted)  # the first capture is never written
    with pytest.raises(KeyboardInterrupt):
        run_collect(_args([out, "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", "--seed", "4", *FAST]))
    record = yaml.safe_load((out / EMPTY_RUN_RECORD).read_text())
    assert record["why"] == "interrupted" and record["collected"]["seed"] == 4 and "error" not in record
    assert f"no view kept: interrupted; this run's settings and seed: {out / EMPTY_RUN_RECORD}" in caplog.text
    assert [f.name for f in out.iterdir()] == [EMPTY_RUN_RECORD]


# ------------------------------------------------------------------------------ crash safety
def test_crash_between_image_and_record_leaves_a_readable_session(tmp_path, monkeypatch):
    out = tmp_path / "c"
    real_write = sw.atomic_write_bytes
    calls = {"records": 0}

    def flaky(path, data):
        if Path(path).parent.name == "views":
            calls["records"] += 1
            if calls["records"] == 3:
                raise KeyboardInterrupt  # the process dies after the image, before the record
        real_write(path, data)

    monkeypatch.setattr(sw, "atomic_write_bytes", flaky)
    with pytest.raises(KeyboardInterrupt):
        run_collect(
            _args(
                [
                    out,
                    "--mode",
                    "eye_to_hand",
                    "--camera",
                    "sim",
                    "--robot",
                    "sim",
                    "--auto",
                    "--views",
                    "4",
                    "--seed",
                    "5",
                    *FAST,
                ]
            )
        )
    recs = _records(out)
    assert sorted(recs) == ["1", "2"]
    assert (out / "images" / "3.png").exists()  # the orphan image of the capture in flight
    assert [v.view_id for v in _load(out).views] == ["1", "2"]


_KILL_IN_RENAME = textwrap.dedent("""
    import os, signal, sys
    real = os.replace
    n = {"records": 0}
    def replace(src, dst):
        if os.path.basename(os.path.dirname(str(dst))) == "views":
            n["records"] += 1
            if n["records"] == 3:
                os.kill(os.getpid(), signal.SIGKILL)  # record written to its temp file, not yet renamed
        return real(src, dst)
    os.replace = replace
    from handeye.cli import main
    sys.exit(main(["collect", *sys.argv[1:]]))
""")


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def test_sigkill_while_a_record_is_renamed(tmp_path):
    out = tmp_path / "k"
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            _KILL_IN_RENAME,
            str(out),
            "--mode",
            "eye_in_hand",
            "--camera",
            "sim",
            "--robot",
            "sim",
            "--auto",
            "--views",
            "4",
            "--seed",
            "3",
            *FAST,
        ],
        env=_env(),
        capture_output=True,
        timeout=300,
    )
    assert proc.returncode == -signal.SIGKILL
    assert len(list((out / "views").glob(".3.yaml.*.tmp"))) == 1  # the record in flight stayed a temp file
    recs = _records(out)
    assert sorted(recs) == ["1", "2"]
    assert len(_load(out).views) == 2


def test_sigkill_at_an_arbitrary_moment(tmp_path):
    out = tmp_path / "r"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "handeye.cli",
            "collect",
            str(out),
            "--mode",
            "eye_in_hand",
            "--camera",
            "sim",
            "--robot",
            "sim",
            "--auto",
            "--views",
            "30",
            "--seed",
            "4",
            "--sim-supersample",
            "4",
            "--resolution",
            "640x360",
        ],
        env=_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            views = out / "views"
            if views.is_dir() and sum(f.suffix == ".yaml" for f in views.iterdir()) >= 5:
                break
            time.sleep(0.02)
        assert proc.poll() is None, "the collection ended before it could be killed"
        time.sleep(0.137)  # somewhere inside the next capture
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    recs = _records(out)
    assert len(recs) >= 5
    session = _load(out)
    assert sorted(v.view_id for v in session.views) == sorted(recs)


# ------------------------------------------------------------------------------ real-arm path on the emulator
class _EmulatorCamera(Camera):
    """Renders the board from the emulated RealMan arm's pose (the emulator plays a perfect arm)."""

    def __init__(self, emu: RealmanEmulator, rig: SimRig):
        self.emu, self.rig, self.name = emu, rig, "emulator camera"

    def intrinsics(self):
        return self.rig.intrinsics

    def grab(self):
        C = mounting(self.rig.mode).predict_T_cam_board(self.rig.T_x, self.rig.T_board, self.emu.T_base_end)
        return render_view(self.rig.target, self.rig.intrinsics, C, supersample=2), time.time()


@pytest.mark.parametrize("confirmed", [True, False])
def test_auto_collection_drives_the_realman_client(tmp_path, confirmed):
    rig = SimRig.sample(mode="eye_in_hand", rng=np.random.default_rng(8), intrinsics=default_intrinsics(640, 360))
    asked = []
    with RealmanEmulator(T_base_end=rig.T_base_end_start, lifetime_s=120) as emu:
        arm = RealmanArm(*emu.address, timeout_s=1.0, max_speed_fraction=0.5)
        camera = _EmulatorCamera(emu, rig)
        writer = sw.SessionWriter(tmp_path / "e", mode=rig.mode, target=rig.target, intrinsics=rig.intrinsics)
        col = Collector(
            robot=arm,
            camera=camera,
            writer=writer,
            target=rig.target,
            mode=rig.mode,
            checks=CaptureChecks(settle_interval_s=0.01),
        )
        col.run_auto(n_views=3, speed_fraction=0.2, confirm=lambda text: asked.append(text) or confirmed)
        arm.close()
    moves = [c for c in emu.received if c["command"] == "movej_p"]
    if not confirmed:
        assert len(asked) == 1 and moves == [] and sorted(_records(tmp_path / "e")) == ["1"]
        return
    assert len(asked) == 2 and len(moves) >= 6 and all(c["v"] == 20 for c in moves)
    recs = _records(tmp_path / "e")
    assert len(recs) == 7
    assert all(r["robot_state"]["work_frame"] == "Base" and r["robot_state"]["errors"] == [] for r in recs.values())


def test_camera_unplugged_mid_session_keeps_what_was_saved(tmp_path):
    from handeye.errors import HardwareError

    rig = SimRig.sample(mode="eye_to_hand", rng=np.random.default_rng(6), intrinsics=default_intrinsics(640, 360))
    robot = SimRobot(rig, rng=np.random.default_rng(7))

    class Unplugged(SimCamera):
        def grab(self):
            if self.n_frames == 3:
                raise HardwareError("no frame from the RealSense camera within 5 s", hint="reconnect the camera")
            return super().grab()

    writer = sw.SessionWriter(tmp_path / "u", mode=rig.mode, target=rig.target, intrinsics=rig.intrinsics)
    col = Collector(
        robot=robot,
        camera=Unplugged(robot, rng=np.random.default_rng(8)),
        writer=writer,
        target=rig.target,
        mode=rig.mode,
    )
    with pytest.raises(HardwareError, match="reconnect the camera"):
        col.run_auto(n_views=4, speed_fraction=0.2)
    assert sorted(_records(tmp_path / "u")) == ["1", "2", "3"]
    assert len(_load(tmp_path / "u").views) == 3


def test_a_kinematic_simulated_arm_records_its_joint_angles(tmp_path):
    from handeye.sim.robot_error import make_kinematic_error

    kin = make_kinematic_error(rng=np.random.default_rng(4))
    rig = SimRig.sample(
        mode="eye_in_hand", rng=np.random.default_rng(0), intrinsics=default_intrinsics(640, 360), kinematic=kin
    )
    robot = SimRobot(rig, rng=np.random.default_rng(1), kinematic=kin)
    writer = sw.SessionWriter(tmp_path / "k", mode="eye_in_hand", target=rig.target, intrinsics=rig.intrinsics)
    cap = Collector(
        robot=robot,
        camera=SimCamera(robot, rng=np.random.default_rng(3)),
        writer=writer,
        target=rig.target,
        mode="eye_in_hand",
    ).capture()
    assert cap.kept, cap.reason
    rec = yaml.safe_load((tmp_path / "k" / "views" / f"{cap.view_id}.yaml").read_text())
    joints = np.array(rec["joints"])
    assert joints.shape == (6,)
    # the reported pose is the nominal model of the recorded encoder angles; the flange is off by the DH errors
    np.testing.assert_allclose(kin.nominal.T_base_end(joints), np.array(rec["pose"]), atol=1e-9)
    off_mm = 1e3 * np.linalg.norm(robot.T_true[:3, 3] - robot.T_reported[:3, 3])
    assert 0.05 < off_mm < 5.0
    from handeye.errors import HardwareError

    with pytest.raises(HardwareError, match="cannot reach"):
        far = np.eye(4)
        far[:3, 3] = [2.0, 0.0, 0.5]
        robot.move_to(far, speed_fraction=0.5)
