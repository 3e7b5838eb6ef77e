"""handeye import rosbag: a ROS 2 bag (MCAP, raw mono8 images) and a ROS 1 bag (JPEG CompressedImage),
written here with rosbags from a rendered session (TF at 100 Hz through a moving and a static edge,
the robot stopping at each view, images also while it moves, CameraInfo), import to sessions that
calibrate to the rendered vendor folder's result within 0.1 mm / 0.01 deg; a bag in which the robot
never stops is one clear error line."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from handeye.cli import main
from handeye.conventions import VENDOR_POSE_FORMAT, T_from_pose_values
from handeye.errors import InputError
from handeye.frames import inv_T, make_T, pose_error, quat_wxyz_from_R, se3_exp, se3_log
from handeye.output import read_json

rosbags = pytest.importorskip("rosbags")
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

N_VIEWS = 10
TF_HZ = 100.0
STILL_S, MOVE_S = 1.0, 0.8
IMAGE_SKEW_S = 0.003  # image stamps fall between TF samples: the pose is interpolated there
#: flange -> tool offset published on /tf_static; the TF stream moves base_link -> link_6
T_LINK6_TOOL0 = make_T(np.eye(3), np.array([0.0, 0.0, 0.1]))

TF_MSG_ROS1 = """geometry_msgs/TransformStamped[] transforms
================================================================================
MSG: geometry_msgs/TransformStamped
std_msgs/Header header
string child_frame_id
geometry_msgs/Transform transform
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: geometry_msgs/Transform
geometry_msgs/Vector3 translation
geometry_msgs/Quaternion rotation
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
"""


def _vendor_poses(folder: Path) -> list[np.ndarray]:
    lines = [ln for ln in (folder / "poses.txt").read_text().splitlines() if ln.strip()]
    return [T_from_pose_values([float(v) for v in ln.split(",")], VENDOR_POSE_FORMAT) for ln in lines]


def _timeline(poses, *, stops=True):
    """TF times (s) and T_base_tool0 along a path that stops STILL_S at each pose (or never stops)."""
    times, Ts, still = [], [], []
    t = 100.0
    for k, T in enumerate(poses):
        if stops:
            for _ in range(int(STILL_S * TF_HZ)):
                times.append(t)
                Ts.append(T)
                t += 1.0 / TF_HZ
            still.append((times[-int(STILL_S * TF_HZ)], times[-1]))
        if k + 1 < len(poses):
            xi = se3_log(inv_T(T) @ poses[k + 1])
            m = int(MOVE_S * TF_HZ)
            for i in range(m):
                a = 0.5 - 0.5 * np.cos(np.pi * i / m)  # smooth start and stop
                times.append(t)
                Ts.append(T @ se3_exp(a * xi))
                t += 1.0 / TF_HZ
    return np.array(times), Ts, still


def _stamp(ts, t: float, ros1: bool):
    Time = ts.types["builtin_interfaces/msg/Time"]
    sec = int(np.floor(t))
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))


def _header(ts, t, frame, ros1):
    H = ts.types["std_msgs/msg/Header"]
    return H(seq=0, stamp=_stamp(ts, t, ros1), frame_id=frame) if ros1 else H(stamp=_stamp(ts, t, ros1), frame_id=frame)


def _tf_msg(ts, t, parent, child, T, ros1):
    g = ts.types
    q = quat_wxyz_from_R(T[:3, :3])
    tr = g["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, t, parent, ros1),
        child_frame_id=child,
        transform=g["geometry_msgs/msg/Transform"](
            translation=g["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=g["geometry_msgs/msg/Quaternion"](x=q[1], y=q[2], z=q[3], w=q[0]),
        ),
    )
    return g["tf2_msgs/msg/TFMessage"](transforms=[tr])


def write_bag(vendor: Path, path: Path, *, ros1: bool, stops: bool = True, storage: str = "mcap") -> None:
    """A bag of the rendered vendor session: /tf (base_link -> link_6 at 100 Hz), /tf_static
    (link_6 -> tool0), /camera/color/image_raw (+ /compressed for ROS 1), /camera/color/camera_info;
    a ROS 2 bag in ``storage`` (mcap | sqlite3)."""
    gt = read_json(vendor / "ground_truth.json")
    poses = _vendor_poses(vendor)
    times, Ts, still = _timeline(poses, stops=stops)
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:
        ts.register(get_types_from_msg(TF_MSG_ROS1, "tf2_msgs/msg/TFMessage"))
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    g = ts.types
    images = []  # (stamp, file of the image shown)
    files = [vendor / f"{k + 1}.jpg" for k in range(len(poses))]
    if stops:
        for k, (a, b) in enumerate(still):
            images += [(a + 0.3 + IMAGE_SKEW_S, files[k]), (a + 0.5 + IMAGE_SKEW_S, files[k])]
            if k + 1 < len(poses):  # while moving on, the camera still shows the old view: never a view
                images.append((b + 0.4 + IMAGE_SKEW_S, files[k]))
    else:
        images = [(t + IMAGE_SKEW_S, files[min(int((t - times[0]) / (MOVE_S)), len(files) - 1)]) for t in times[::20]]
    intr = gt["intrinsics"]
    d = intr["dist"]
    w, h = intr["image_size"]
    K = np.array([intr["fx"], 0, intr["cx"], 0, intr["fy"], intr["cy"], 0, 0, 1], float)
    kw = (
        dict(D=np.array([d["k1"], d["k2"], d["p1"], d["p2"], d["k3"]]), K=K, R=np.eye(3).ravel(), P=np.zeros(12))
        if ros1
        else dict(d=np.array([d["k1"], d["k2"], d["p1"], d["p2"], d["k3"]]), k=K, r=np.eye(3).ravel(), p=np.zeros(12))
    )
    info = g["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, times[0], "camera_color_optical_frame", ros1),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        binning_x=0,
        binning_y=0,
        roi=g["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        **kw,
    )
    msgs = []  # (time, topic, msgtype, message)
    T_link6 = [T @ inv_T(T_LINK6_TOOL0) for T in Ts]
    for t, T in zip(times, T_link6, strict=False):
        msgs.append((t, "/tf", "tf2_msgs/msg/TFMessage", _tf_msg(ts, t, "base_link", "link_6", T, ros1)))
    msgs.append(
        (
            times[0],
            "/tf_static",
            "tf2_msgs/msg/TFMessage",
            _tf_msg(ts, times[0], "link_6", "tool0", T_LINK6_TOOL0, ros1),
        )
    )
    msgs.append((times[0], "/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", info))
    for t, f in images:
        if ros1:
            m = g["sensor_msgs/msg/CompressedImage"](
                header=_header(ts, t, "camera_color_optical_frame", ros1),
                format="jpeg",
                data=np.frombuffer(f.read_bytes(), np.uint8),
            )
            msgs.append((t, "/camera/color/image_raw/compressed", "sensor_msgs/msg/CompressedImage", m))
        else:
            img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            m = g["sensor_msgs/msg/Image"](
                header=_header(ts, t, "camera_color_optical_frame", ros1),
                height=h,
                width=w,
                encoding="mono8",
                is_bigendian=0,
                step=w,
                data=img.reshape(-1),
            )
            msgs.append((t, "/camera/color/image_raw", "sensor_msgs/msg/Image", m))
    msgs.sort(key=lambda m: m[0])
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=8, storage_plugin=StoragePlugin[storage.upper()])
    with writer:
        conns = {}
        for t, topic, msgtype, msg in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], int(round(t * 1e9)), ser(msg, msgtype))


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("rosbag")
    vendor = root / "vendor"
    assert main(["-q", "simulate", str(vendor), "--views", str(N_VIEWS), "--seed", "11"]) == 0
    return root, vendor


@pytest.fixture(scope="module")
def reference(rendered):
    """The vendor folder calibrated by ``handeye calibrate --export ros2`` (stdout, result folder)."""
    import contextlib
    import io

    root, vendor = rendered
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert (
            main(["-q", "calibrate", str(vendor), "--out", str(root / "res_vendor"), "--no-report", "--export", "ros2"])
            == 0
        )
    return buf.getvalue(), root / "res_vendor"


def _calibrate(session, out):
    from handeye.workflow import calibrate_session

    wr = calibrate_session(session, out_dir=out, report=False)
    assert wr.status == "ok", wr.result.get("failure_reason")
    return wr.result


def test_ros2_and_ros1_bags_calibrate_like_the_vendor_folder(rendered, reference, capsys):
    root, vendor = rendered
    write_bag(vendor, root / "bag2", ros1=False)
    write_bag(vendor, root / "cal.bag", ros1=True)
    T_ref = np.asarray(read_json(reference[1])["T_end_cam"])
    common = ["--base", "base_link", "--end", "tool0", "--target", str(root / "config_copy.yaml")]
    (root / "config_copy.yaml").write_text((vendor / "config.yaml").read_text())
    assert (
        main(
            [
                "import",
                "rosbag",
                str(root / "bag2"),
                "--image-topic",
                "/camera/color/image_raw",
                "--out",
                str(root / "s2"),
                *common,
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert f"{N_VIEWS} views from {N_VIEWS} still periods" in out
    assert "at most 3.0 ms" in out and "intrinsics: from CameraInfo (use: prior)" in out
    assert (
        main(
            [
                "import",
                "rosbag",
                str(root / "cal.bag"),
                str(root / "s1"),
                "--image-topic",
                "/camera/color/image_raw/compressed",
                "--camera-info",
                "/camera/color/camera_info",
                *common,
            ]
        )
        == 0
    )
    capsys.readouterr()
    for s in ("s2", "s1"):
        doc = yaml.safe_load((root / s / "session.yaml").read_text())
        assert len(doc["views"]) == N_VIEWS and doc["source"]["tf_chain"] == ["base_link -> link_6", "link_6 -> tool0"]
        # each view carries its vendor pose (through the moving and the static edge, interpolated 3 ms off)
        for v, T in zip(doc["views"], _vendor_poses(vendor), strict=False):
            assert np.max(np.abs(np.asarray(v["pose"]) - T)) < 1e-9
        res = _calibrate(root / s, root / f"res_{s}")
        d_mm, d_deg = pose_error(np.asarray(res["T_end_cam"]), T_ref)
        assert d_mm < 0.1 and d_deg < 0.01, (s, d_mm, d_deg)
    # a second import into a session folder is refused, as the other importers refuse it; --force replaces
    # session.yaml only into an empty images/ (an earlier import's images would mix with the new ones)
    again = ["import", "rosbag", str(root / "bag2"), "--image-topic", "/camera/color/image_raw", *common]
    before = (root / "s2" / "session.yaml").read_bytes()
    assert main([*again, "--out", str(root / "s2")]) == 2
    assert "OUT already holds a session" in capsys.readouterr().err
    assert main([*again, "--out", str(root / "s2"), "--force"]) == 2
    assert "holds the files of an earlier import" in capsys.readouterr().err
    assert (root / "s2" / "session.yaml").read_bytes() == before


def test_calibrate_export_shortcut_writes_next_to_the_result(reference):
    out, res = reference
    assert f"ros2: {res / 'hand_eye.launch.py'}" in out and f"ros2: {res / 'hand_eye.tf_static.yaml'}" in out
    tf = yaml.safe_load((res / "hand_eye.tf_static.yaml").read_text())["transforms"][0]
    t, q = tf["transform"]["translation"], tf["transform"]["rotation"]
    T = np.asarray(read_json(res)["T_end_cam"])
    assert np.max(np.abs(np.array([t["x"], t["y"], t["z"]]) - T[:3, 3])) < 1e-12
    assert np.max(np.abs(np.array([q["w"], q["x"], q["y"], q["z"]]) - quat_wxyz_from_R(T[:3, :3]))) < 1e-12
    assert (tf["header"]["frame_id"], tf["child_frame_id"]) == ("tool0", "camera_color_optical_frame")


def test_bag_without_still_periods_is_one_clear_error(rendered, capsys):
    root, vendor = rendered
    write_bag(vendor, root / "moving", ros1=False, stops=False, storage="sqlite3")
    code = main(
        [
            "import",
            "rosbag",
            str(root / "moving"),
            "--image-topic",
            "/camera/color/image_raw",
            "--base",
            "base_link",
            "--end",
            "tool0",
            "--target",
            str(vendor / "config.yaml"),
            "--out",
            str(root / "sm"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == InputError.exit_code
    assert len(err.splitlines()) == 1 and "no still periods in the bag" in err and "--min-still-s" in err
    assert not (root / "sm" / "session.yaml").exists()
    # a frame the bag does not have is named with the ones it has
    code = main(
        [
            "import",
            "rosbag",
            str(root / "moving"),
            "--image-topic",
            "/camera/color/image_raw",
            "--base",
            "base",
            "--end",
            "tool0",
            "--target",
            str(vendor / "config.yaml"),
            "--out",
            str(root / "sm"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == InputError.exit_code and "frame 'base' is not in the bag's TF" in err and "base_link" in err


def test_still_periods_are_found_under_tf_jitter():
    """Stops of 1 s, 1.5 s and 1.5 s between moves at 50 mm/s and 5 deg/s, the TF jittering by
    0.01 mm and 0.001 deg per sample (an arm at rest): three periods, each within a speed window of the
    true stop, with the shipped thresholds; also from a 10 Hz TF (fewer samples than the window)."""
    from handeye.session.rosbag import Stillness, still_periods

    rng = np.random.default_rng(4)
    t = np.arange(0.0, 6.0, 0.01)
    moves = [(1.0, 2.0), (3.5, 4.5)]
    s = np.zeros_like(t)  # path parameter: metres along x, and 100 deg/m of turn about z
    for a, b in moves:
        s += 0.05 * np.clip(t - a, 0.0, b - a)
    Ts = []
    for si in s:
        xi = np.concatenate([[0.0, 0.0, np.radians(100.0 * si)], [si, 0.0, 0.0]])
        jitter = np.concatenate([rng.normal(0, np.radians(0.001), 3), rng.normal(0, 1e-5, 3)])
        Ts.append(se3_exp(xi) @ se3_exp(jitter))
    st = Stillness.from_preset()
    for step, slack in ((1, st.speed_window_s / 2 + 0.011), (10, 0.1 + 0.011)):  # 100 Hz; 10 Hz: one sample apart
        periods = still_periods(t[::step], np.array(Ts)[::step], st)
        truth = [(0.0, 1.0), (2.0, 3.5), (4.5, t[::step][-1])]
        assert len(periods) == 3, (step, periods)
        for (a, b), (ta, tb) in zip(periods, truth, strict=False):
            assert abs(a - ta) <= slack and abs(b - tb) <= slack, (step, a, b, ta, tb)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "mono8", "mono16", "bgra8"])
def test_raw_images_are_written_as_lossless_png(encoding):
    """sensor_msgs/Image with row padding (step > width * channels) in each encoding read: the PNG holds
    the same pixels (BGR for colour, 16 bit for mono16); an unknown encoding is one clear error."""
    from types import SimpleNamespace

    from handeye.session.rosbag import _image_file

    rng = np.random.default_rng(1)
    h, w = 5, 7
    ch = {"rgb8": 3, "bgr8": 3, "mono8": 1, "mono16": 1, "bgra8": 4}[encoding]
    dtype = np.uint16 if encoding == "mono16" else np.uint8
    img = rng.integers(0, 60000 if dtype == np.uint16 else 255, size=(h, w, ch)).astype(dtype)
    pad = 3 * ch  # extra items per row
    rows = np.zeros((h, w * ch + pad), dtype)
    rows[:, : w * ch] = img.reshape(h, -1)
    msg = SimpleNamespace(
        encoding=encoding, height=h, width=w, step=rows.shape[1] * rows.itemsize, is_bigendian=0, data=rows.tobytes()
    )
    data, ext = _image_file(msg, "sensor_msgs/msg/Image")
    got = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    want = {"rgb8": img[..., ::-1], "bgr8": img, "mono8": img[..., 0], "mono16": img[..., 0], "bgra8": img[..., :3]}
    assert ext == ".png" and got.dtype == dtype and np.array_equal(got, want[encoding])
    with pytest.raises(InputError, match="image encoding 'yuv422' is not read"):
        _image_file(SimpleNamespace(**{**vars(msg), "encoding": "yuv422"}), "sensor_msgs/msg/Image")


def test_import_mode_choices_are_the_mounting_modes():
    """``handeye import --help`` stays free of numpy, so its --mode choices are written out: they must
    be handeye.mounting.MODES."""
    import argparse

    from handeye.cli import import_
    from handeye.mounting import MODES

    p = argparse.ArgumentParser()
    import_.add_arguments(p)
    (mode,) = [a for a in p._actions if "--mode" in a.option_strings]
    assert tuple(mode.choices) == tuple(MODES)


def test_calibrate_export_shortcut_skips_a_failed_verdict(reference, tmp_path, monkeypatch, capsys):
    """A run whose verdict is FAIL keeps its exit code and result, and is not exported (one line says why)."""
    import handeye.workflow as workflow
    from handeye.output import write_json
    from handeye.workflow import WorkflowResult

    res = read_json(reference[1])
    res.update(verdict="FAIL", verdict_headline="a QA check fails")
    write_json(tmp_path / "result.json", res)
    wr = WorkflowResult("ok", tmp_path, tmp_path / "result.json", res, run=object())
    monkeypatch.setattr(workflow, "calibrate_session", lambda *a, **k: wr)
    assert main(["calibrate", "whatever", "--out", str(tmp_path), "--export", "urdf"]) == 7
    err = capsys.readouterr().err
    assert "handeye: not exported:" in err and "verdict is FAIL" in err
    assert not list(tmp_path.glob("hand_eye*"))
