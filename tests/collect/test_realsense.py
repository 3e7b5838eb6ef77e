"""RealSense backends: distortion mapping, and playback of a recording made from synthetic frames.

The recording is written with the SDK's own software device and recorder (no camera needed), then
played back as ``--camera bag:FILE`` does. Every test that loads pyrealsense2's native code runs in
a fresh interpreter of its own (:func:`in_subprocess`): a crash inside the library fails that test
with the signal that ended it instead of taking down the pytest (or xdist worker) process.
"""

from __future__ import annotations

import argparse
import builtins
import functools
import io
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from handeye.collect.realsense import intrinsics_from_realsense, opencv5_from_realsense
from handeye.errors import HardwareError

W, H = 640, 360


# ------------------------------------------------------------------------------ distortion mapping
def _rs_project(xy: np.ndarray, model: str, c) -> np.ndarray:
    """librealsense's rs2_project_point_to_pixel distortion step (rsutil.h), on normalized points."""
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    f = 1 + c[0] * r2 + c[1] * r2**2 + c[4] * r2**3
    if model == "brown_conrady":
        xf, yf = x * f, y * f
        return np.stack(
            [xf + 2 * c[2] * x * y + c[3] * (r2 + 2 * x * x), yf + 2 * c[3] * x * y + c[2] * (r2 + 2 * y * y)], 1
        )
    x, y = x * f, y * f  # modified / inverse Brown-Conrady: tangential terms after the radial scaling
    return np.stack([x + 2 * c[2] * x * y + c[3] * (r2 + 2 * x * x), y + 2 * c[3] * x * y + c[2] * (r2 + 2 * y * y)], 1)


def _cv_project(xy: np.ndarray, dist) -> np.ndarray:
    pts = np.concatenate([xy, np.ones((len(xy), 1))], 1)
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.eye(3), np.asarray(dist, float))
    return uv.reshape(-1, 2)


@pytest.mark.parametrize(
    "model, coeffs, exactness",
    [
        ("brown_conrady", [0.1, -0.2, 0.003, -0.002, 0.05], "exact"),
        ("inverse_brown_conrady", [0.1, -0.2, 0.0, 0.0, 0.05], "exact"),
        ("distortion.modified_brown_conrady", [0.1, -0.2, 0.003, -0.002, 0.05], "approximate"),
        ("inverse_brown_conrady", [0, 0, 0, 0, 0], "exact"),
        ("kannala_brandt4", [0.1, 0.01, 0, 0, 0], "not representable"),
    ],
)
def test_realsense_distortion_maps_to_opencv(model, coeffs, exactness):
    dist, how = opencv5_from_realsense(model, coeffs)
    assert how == exactness
    if how == "not representable":
        assert dist == (0.0,) * 5
        return
    xy = np.random.default_rng(0).uniform(-0.6, 0.6, (200, 2))
    gap = np.abs(_rs_project(xy, model.replace("distortion.", ""), coeffs) - _cv_project(xy, dist)).max()
    if how == "exact":
        assert gap < 1e-9
    else:
        assert 0 < gap < 1e-3  # close, but not OpenCV's model: recorded as approximate


def test_factory_intrinsics_record_the_original_model():
    intr, source = intrinsics_from_realsense(
        fx=615.0,
        fy=614.5,
        ppx=322.1,
        ppy=241.7,
        width=640,
        height=480,
        model="distortion.inverse_brown_conrady",
        coeffs=[0, 0, 0, 0, 0],
    )
    assert (intr.fx, intr.cy, intr.width, intr.dist) == (615.0, 241.7, 640, (0.0,) * 5)
    assert source["original_model"] == "inverse_brown_conrady" and source["mapping_to_opencv5"] == "exact"


def test_missing_libusb_is_one_clear_line(monkeypatch):
    real_import = builtins.__import__

    def fake(name, *a, **k):
        if name == "pyrealsense2":
            raise ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")
        return real_import(name, *a, **k)

    monkeypatch.delitem(sys.modules, "pyrealsense2", raising=False)
    monkeypatch.setattr(builtins, "__import__", fake)
    from handeye.collect.realsense import import_pyrealsense2

    with pytest.raises(HardwareError, match="apt-get install libusb-1.0-0"):
        import_pyrealsense2()


# ------------------------------------------------------------------------------ isolation
_CHILD = "HANDEYE_TEST_IN_SUBPROCESS"  # names the one test a child interpreter runs itself


def in_subprocess(test):
    """Run ``test`` in a child ``python -m pytest`` of its own; its outcome (pass, skip, fail, or the signal
    that killed it) is this test's outcome.

    The child runs this one test with the same interpreter and environment (so the same handeye), without
    xdist; the parent's fixtures are not used (the child makes its own).
    """

    @functools.wraps(test)
    def run(*args, **kwargs):
        if os.environ.get(_CHILD) == test.__name__:
            return test(*args, **kwargs)
        root = Path(__file__).resolve().parents[2]
        env = {k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS" and not k.startswith("PYTEST_XDIST")}
        env[_CHILD] = test.__name__
        cmd = [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", "-p", "no:xdist"]
        cmd.append(f"{Path(__file__).resolve()}::{test.__name__}")
        cap = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=600)
        text = cap.stdout + cap.stderr
        if cap.returncode < 0:
            name = signal.Signals(-cap.returncode).name
            pytest.fail(f"{test.__name__} crashed its interpreter ({name}):\n{text[-4000:]}", pytrace=False)
        if cap.returncode != 0:
            pytest.fail(f"{test.__name__} failed in its own interpreter:\n{text[-6000:]}", pytrace=False)
        if " passed" not in text:
            reason = [ln for ln in text.splitlines() if ln.startswith("SKIPPED")]
            pytest.skip(reason[0].split(": ", 1)[-1] if reason else "skipped in its own interpreter")

    return run


_CRASH = "HANDEYE_TEST_CRASH_PROBE"


@in_subprocess
def test_isolation_probe():
    """Passes; kills its own interpreter when the test below asks it to."""
    if os.environ.get(_CRASH) == "1":
        os.kill(os.getpid(), signal.SIGSEGV)


def test_a_native_crash_fails_one_test_and_not_the_process(monkeypatch):
    monkeypatch.setenv(_CRASH, "1")
    with pytest.raises(pytest.fail.Exception, match=r"crashed its interpreter \(SIGSEGV\)"):
        test_isolation_probe()


# ------------------------------------------------------------------------------ SDK playback
def _rs():
    try:
        import pyrealsense2 as rs
    except ImportError as e:
        pytest.skip(f"pyrealsense2 cannot be imported here ({e}); the playback path is untested")
    return rs


def _record(rs, folder, frames, *, fx=455.0, fy=454.5, ppx=321.1, ppy=180.4, model=None, coeffs=(0, 0, 0, 0, 0)):
    """Write ``frames`` (BGR) through a software device into a recording; returns its path."""
    model = rs.distortion.inverse_brown_conrady if model is None else model
    last_error = None
    for ext in (".db3", ".bag"):  # librealsense >= 2.56 records rosbag2 (.db3), older versions ROS1 .bag
        path = folder / f"synthetic{ext}"
        sd = rs.software_device()
        sd.register_info(rs.camera_info.name, "Intel RealSense D435 (software device)")
        sd.register_info(rs.camera_info.serial_number, "000000000000")
        sensor = sd.add_sensor("RGB Camera")
        intr = rs.intrinsics()
        intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = W, H, fx, fy, ppx, ppy
        intr.model, intr.coeffs = model, list(coeffs)
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp = rs.stream.color, 0, 0, W, H, 30, 3
        vs.fmt, vs.intrinsics = rs.format.bgr8, intr
        profile = sensor.add_video_stream(vs).as_video_stream_profile()
        try:
            recorder = rs.recorder(str(path), sd)
        except RuntimeError as e:
            last_error = e
            continue
        queue = rs.frame_queue(len(frames) + 2)
        sensor.open(profile)
        sensor.start(queue)
        for i, img in enumerate(frames):
            f = rs.software_video_frame()
            f.pixels, f.bpp, f.stride = np.ascontiguousarray(img), 3, W * 3
            f.timestamp, f.domain, f.frame_number, f.profile = (
                1000.0 + 33.3 * i,
                rs.timestamp_domain.system_time,
                i,
                profile,
            )
            sensor.on_video_frame(f)
            queue.wait_for_frame(10_000)  # through the sensor (and the recorder) before the next one and the stop
        sensor.stop()
        sensor.close()
        recorder.pause()
        del recorder, sd
        return path
    pytest.skip(f"this pyrealsense2 cannot record a software device ({last_error}); the playback path is untested")


def _board_frames(n):
    from handeye.mounting import mounting
    from handeye.sim.devices import SimRig
    from handeye.sim.render import render_view
    from handeye.sim.scenarios import default_intrinsics, sample_view_poses

    rig = SimRig.sample(mode="eye_in_hand", rng=np.random.default_rng(1), intrinsics=default_intrinsics(W, H))
    rng = np.random.default_rng(2)
    Ts = sample_view_poses(
        mode="eye_in_hand",
        n_views=n,
        rng=rng,
        T_x=rig.T_x,
        T_board=rig.T_board,
        target=rig.target,
        intrinsics=rig.intrinsics,
    )
    C = mounting("eye_in_hand").predict_T_cam_board(rig.T_x, rig.T_board, Ts)
    return [render_view(rig.target, rig.intrinsics, c, supersample=2, channels=3) for c in C]


@in_subprocess
def test_recording_plays_back_frame_by_frame(tmp_path):
    rs = _rs()
    frames = [np.full((H, W, 3), v, np.uint8) for v in (10, 60, 110)]
    frames[1][100:120, 200:260] = (0, 0, 255)  # colour order must survive: red in BGR
    path = _record(rs, tmp_path, frames, coeffs=(0.1, -0.2, 0.001, 0.002, 0.05))
    from handeye.collect.realsense import BagCamera

    cam = BagCamera(path)
    try:
        intr = cam.intrinsics()
        assert (intr.width, intr.height) == (W, H)
        assert intr.fx == pytest.approx(455.0) and intr.cy == pytest.approx(180.4, abs=1e-4)
        src = cam.intrinsics_source()
        assert src["original_model"] == "inverse_brown_conrady" and src["mapping_to_opencv5"] == "approximate"
        got = [cam.grab()[0] for _ in frames]
        for a, b in zip(got, frames, strict=False):
            np.testing.assert_array_equal(a, b)
        assert cam.last_frame_info["frame_number"] == 2
        with pytest.raises(HardwareError, match="no more colour frames"):
            cam.grab()
    finally:
        cam.close()


@in_subprocess
def test_a_late_reader_gets_every_frame_in_order(tmp_path):
    """The player waits for the reader: a reader that starts late (a loaded machine) loses nothing.

    With a pipeline started in real time, a reader late by one frame interval (33 ms here) lost the
    first frames ("no more colour frames (after 2)", 4 of 40 runs under load)."""
    import time

    rs = _rs()
    frames = [np.full((H, W, 3), 20 * k, np.uint8) for k in range(6)]
    path = _record(rs, tmp_path, frames)
    from handeye.collect.realsense import BagCamera

    cam = BagCamera(path, timeout_s=30.0)
    try:
        time.sleep(0.5)  # 15 frame intervals of the recording
        got = [int(cam.grab()[0][0, 0, 0]) for _ in frames]
        assert got == [20 * k for k in range(6)]
        # the end is the player's word, not the 30 s timeout waited out (that would say "stalled")
        with pytest.raises(HardwareError, match=r"no more colour frames \(after 6\)"):
            cam.grab()
        assert cam._ended()
    finally:
        cam.close()
    with pytest.raises(HardwareError, match="closed"):
        cam.grab()


@in_subprocess
def test_a_slow_player_is_never_read_as_the_end(tmp_path, monkeypatch):
    """The end of a recording is the player's word, not a timeout: a player slower than the wait (a loaded
    machine) delivers every frame, and a stall says so instead of "no more colour frames (after 2)"."""
    rs = _rs()
    frames = [np.full((H, W, 3), v, np.uint8) for v in (10, 60, 110)]
    path = _record(rs, tmp_path, frames)
    import time

    import handeye.collect.realsense as realsense

    convert = realsense._bgr_from_frame

    def slow(rs_, frame):  # each frame takes 0.3 s to hand over
        time.sleep(0.3)
        return convert(rs_, frame)

    monkeypatch.setattr(realsense, "_bgr_from_frame", slow)
    cam = realsense.BagCamera(path, timeout_s=5.0)
    try:
        got = [int(cam.grab()[0][0, 0, 0]) for _ in frames]
        assert got == [10, 60, 110]
        with pytest.raises(HardwareError, match=r"no more colour frames \(after 3\)"):
            cam.grab()
    finally:
        cam.close()
    cam = realsense.BagCamera(path, timeout_s=0.05)  # shorter than one frame's hand-over
    try:
        with pytest.raises(HardwareError, match=r"stalled.*after 0 frames"):
            cam.grab()
    finally:
        cam.close()


@in_subprocess
def test_a_recording_closed_at_any_moment_shuts_down_in_order(tmp_path, monkeypatch):
    """Readers that give up at random moments (during a stall, mid-recording, after the end) and close: the
    shutdown is ordered (callback out, sensor stopped and released, player stopped, device released).

    Releasing the device while its player was still stopping crashed librealsense in about one close in 25.
    """
    import random
    import time

    import handeye.collect.realsense as realsense

    rs = _rs()
    path = _record(rs, tmp_path, [np.full((H, W, 3), v, np.uint8) for v in (10, 60, 110)])
    rnd = random.Random(3)
    convert = realsense._bgr_from_frame

    def slow(rs_, frame):  # a player as slow as a loaded machine makes it
        time.sleep(rnd.uniform(0.0, 0.1))
        return convert(rs_, frame)

    monkeypatch.setattr(realsense, "_bgr_from_frame", slow)
    for _ in range(30):
        cam = realsense.BagCamera(path, timeout_s=rnd.uniform(0.001, 0.15))
        try:
            for _ in range(rnd.randint(0, 4)):
                try:
                    cam.grab()
                except HardwareError as e:
                    assert "stalled" in str(e) or "no more colour frames" in str(e)
                    break
            time.sleep(rnd.uniform(0.0, 0.05))
        finally:
            cam.close()
        assert cam._player == []  # sensor and device released
        with pytest.raises(HardwareError, match="closed"):
            cam.grab()


@in_subprocess
def test_collect_from_a_recording(tmp_path, monkeypatch):
    rs = _rs()
    path = _record(rs, tmp_path, _board_frames(3))
    from handeye.cli.collect import add_collect_arguments, run_collect

    p = argparse.ArgumentParser()
    add_collect_arguments(p)
    out = tmp_path / "session"
    args = p.parse_args(
        [str(out), "--mode", "eye_in_hand", "--camera", f"bag:{path}", "--robot", "sim", "--no-preview", "--seed", "0"]
    )
    monkeypatch.setattr(sys, "stdin", io.StringIO("s\ns\ns\nq\n"))
    assert run_collect(args) == 0
    header = yaml.safe_load((out / "session.yaml").read_text())
    assert header["intrinsics"]["fx"] == pytest.approx(455.0) and header["intrinsics"]["use"] == "initial"
    assert header["intrinsics"]["source"]["original_model"] == "inverse_brown_conrady"
    assert header["collected"]["camera"]["name"] == "Intel RealSense D435 (software device)"
    recs = sorted((out / "views").glob("*.yaml"))
    assert [r.stem for r in recs] == ["1", "2", "3"]
    for r in recs:
        rec = yaml.safe_load(r.read_text())
        assert rec["camera_frame"]["frame_number"] == int(rec["id"]) - 1
        assert cv2.imread(str(out / rec["image"])).shape == (H, W, 3)


@in_subprocess
def test_live_camera_absent_is_a_hardware_error():
    rs = _rs()
    if len(rs.context().query_devices()) > 0:
        pytest.skip("a RealSense camera is connected; this test checks the message without one")
    from handeye.collect.realsense import RealSenseCamera

    with pytest.raises(HardwareError, match="no RealSense camera found"):
        RealSenseCamera()
