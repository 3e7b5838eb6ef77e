"""Exports round-trip: each file is read back by the tool that reads it (URDF by yourdfpy, xacro by
xacro, YAML by PyYAML, the launch files executed with stand-ins for ROS 2's launch classes and their
arguments parsed as static_transform_publisher does) and the transform recomposed equals result.json's
to 1e-9. The body-frame export is the optical one times the fixed rotation."""

from __future__ import annotations

import json
import sys
import types
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from handeye.cli import main
from handeye.errors import InputError
from handeye.export import FORMATS, export_result
from handeye.export.frames import R_OPTICAL_BODY, T_OPTICAL_BODY, quat_xyzw_from_R
from handeye.frames import R_from_quat_wxyz, make_T, se3_exp
from handeye.output import write_json

TOL = 1e-9


def _rpy_to_R(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _T_xyzw(t, q_xyzw):
    x, y, z, w = q_xyzw
    return make_T(R_from_quat_wxyz(np.array([w, x, y, z], float)), np.asarray(t, float))


def _result(folder, mode, *, seed=0, verdict="PASS", status="ok"):
    rng = np.random.default_rng(seed)
    T = se3_exp(np.concatenate([rng.uniform(-2, 2, 3), rng.uniform(-0.3, 0.3, 3)]))
    A = rng.normal(size=(6, 6)) * 1e-4
    cov = A @ A.T
    name = "T_end_cam" if mode == "eye_in_hand" else "T_base_cam"
    d = {
        "handeye_result": 1,
        "status": status,
        "mode": mode,
        "hand_eye": {"name": name},
        "verdict": verdict,
        "verdict_headline": "test",
        "failure_reason": None if status == "ok" else "no views",
        "refinement": {
            "cov_x_6x6": cov.tolist(),
            "cov_parametrisation": "GTSAM Pose3 tangent, right perturbation: T_x_true = T_x · Exp(xi), rotation first",
        },
    }
    if status == "ok":
        d[name] = T.tolist()
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / "result.json", d)
    return T, cov


def _launch_transform(path):
    """Run the launch file's generate_launch_description with stand-ins for launch / launch_ros and
    read static_transform_publisher's arguments (--x .. --qw or --roll --pitch --yaw, frames)."""
    nodes = []

    class Node:
        def __init__(self, **kw):
            nodes.append(kw)

    launch = types.ModuleType("launch")
    launch.LaunchDescription = lambda entities: list(entities)
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")
    actions.Node = Node
    launch_ros.actions = actions
    saved = {k: sys.modules.get(k) for k in ("launch", "launch_ros", "launch_ros.actions")}
    sys.modules.update({"launch": launch, "launch_ros": launch_ros, "launch_ros.actions": actions})
    try:
        ns = {}
        exec(compile(path.read_text(), str(path), "exec"), ns)
        ns["generate_launch_description"]()
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    (node,) = nodes
    assert node["package"] == "tf2_ros" and node["executable"] == "static_transform_publisher"
    a = node["arguments"]
    opts = {a[i]: a[i + 1] for i in range(0, len(a), 2)}
    t = [float(opts[k]) for k in ("--x", "--y", "--z")]
    if "--qx" in opts:
        T = _T_xyzw(t, [float(opts[k]) for k in ("--qx", "--qy", "--qz", "--qw")])
    else:
        T = make_T(_rpy_to_R(*[float(opts[k]) for k in ("--roll", "--pitch", "--yaw")]), np.array(t))
    return opts["--frame-id"], opts["--child-frame-id"], T


def _ros1_launch_transform(path):
    """ROS 1 static_transform_publisher's args: x y z qx qy qz qw frame_id child_frame_id."""
    import xml.etree.ElementTree as ET

    (node,) = ET.parse(path).getroot().findall("node")
    assert (node.get("pkg"), node.get("type")) == ("tf2_ros", "static_transform_publisher")
    a = node.get("args").split()
    assert len(a) == 9
    return a[7], a[8], _T_xyzw([float(v) for v in a[:3]], [float(v) for v in a[3:7]])


def _tf_yaml_transform(path):
    d = yaml.safe_load(path.read_text())
    (tr,) = d["transforms"]
    t, q = tr["transform"]["translation"], tr["transform"]["rotation"]
    return (
        tr["header"]["frame_id"],
        tr["child_frame_id"],
        _T_xyzw([t["x"], t["y"], t["z"]], [q["x"], q["y"], q["z"], q["w"]]),
    )


def _urdf_transform(path):
    import yourdfpy

    robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=False)
    (joint,) = robot.robot.joints
    assert joint.type == "fixed"
    return joint.parent, joint.child, np.asarray(joint.origin, float)


def _xacro_transform(path, tmp_path):
    return _xacro_with(path, tmp_path, "tool0", "camera_color_optical_frame")


def _calib_transform(path):
    d = yaml.safe_load(path.read_text())
    p, t, q = d["parameters"], d["transform"]["translation"], d["transform"]["rotation"]
    parent = p["robot_effector_frame"] if p["calibration_type"] == "eye_in_hand" else p["robot_base_frame"]
    return parent, p["tracking_base_frame"], _T_xyzw([t["x"], t["y"], t["z"]], [q["x"], q["y"], q["z"], q["w"]])


def _plain_transform(d):
    T = np.asarray(d["matrix"], float)
    T_q = _T_xyzw(d["translation_m"], d["quaternion_xyzw"])
    w, x, y, z = d["quaternion_wxyz"]
    assert np.allclose([x, y, z, w], d["quaternion_xyzw"], atol=0)
    T_rpy = make_T(_rpy_to_R(*d["rpy_rad"]), np.asarray(d["translation_m"]))
    assert np.max(np.abs(T_q - T)) < TOL and np.max(np.abs(T_rpy - T)) < TOL
    return d["parent_frame"], d["child_frame"], T


def _read_all(paths, fmt, tmp_path):
    """(parent, child, T) of every file a format wrote."""
    if fmt == "ros2":
        return [_launch_transform(paths[0]), _tf_yaml_transform(paths[1])]
    if fmt == "urdf":
        return [_urdf_transform(paths[0]), _xacro_transform(paths[1], tmp_path)]
    if fmt == "moveit":
        return [_launch_transform(paths[0]), _ros1_launch_transform(paths[1])]
    if fmt == "easy_handeye2":
        return [_calib_transform(paths[0])]
    if fmt == "yaml":
        return [_plain_transform(yaml.safe_load(paths[0].read_text()))]
    return [_plain_transform(json.loads(paths[0].read_text()))]


@pytest.mark.parametrize("fmt", list(FORMATS))
@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_export_round_trips_through_its_reader(tmp_path, fmt, mode):
    T, _ = _result(tmp_path / "res", mode, seed=3 if mode == "eye_in_hand" else 4)
    paths = export_result(tmp_path / "res", fmt)
    assert [p.parent for p in paths] == [tmp_path / "res"] * len(FORMATS[fmt][0])
    parent = "tool0" if mode == "eye_in_hand" else "base_link"
    for got_parent, got_child, T_got in _read_all(paths, fmt, tmp_path):
        assert (got_parent, got_child) == (parent, "camera_color_optical_frame")
        assert np.max(np.abs(T_got - T)) < TOL, (fmt, T_got - T)


@pytest.mark.parametrize("fmt", ["ros2", "urdf", "easy_handeye2", "yaml"])
def test_body_frame_export_is_the_optical_one_times_the_fixed_rotation(tmp_path, fmt):
    T, _ = _result(tmp_path / "res", "eye_in_hand", seed=5)
    paths = export_result(
        tmp_path / "res",
        fmt,
        camera_frame="body",
        child="cam_body" if fmt != "urdf" else None,
        out=tmp_path / "body" / "cam",
    )
    child = "cam_body" if fmt != "urdf" else "camera_color_frame"
    if fmt == "urdf":
        got = [_urdf_transform(paths[0])]
    else:
        got = _read_all(paths, fmt, tmp_path)
    for _, got_child, T_body in got:
        assert got_child == child
        assert np.max(np.abs(T_body - T @ T_OPTICAL_BODY)) < TOL
    # REP 103 body axes: x forward = optical z, y left = -optical x, z up = -optical y
    assert np.array_equal(R_OPTICAL_BODY @ [1, 0, 0], [0, 0, 1])
    assert np.array_equal(R_OPTICAL_BODY @ [0, 1, 0], [-1, 0, 0])
    assert np.array_equal(R_OPTICAL_BODY @ [0, 0, 1], [0, -1, 0])
    # the RealSense driver's camera_color_frame -> camera_color_optical_frame rotation, x y z w
    assert np.allclose(quat_xyzw_from_R(R_OPTICAL_BODY.T), [-0.5, 0.5, -0.5, 0.5], atol=1e-15)


def test_sigmas_follow_the_covariance_and_the_camera_frame(tmp_path):
    T, cov = _result(tmp_path / "res", "eye_in_hand", seed=6)
    opt = yaml.safe_load(export_result(tmp_path / "res", "yaml", out=tmp_path / "o.yaml")[0].read_text())
    body = yaml.safe_load(
        export_result(tmp_path / "res", "yaml", out=tmp_path / "b.yaml", camera_frame="body")[0].read_text()
    )
    R = T[:3, :3]
    sig_t_mm = np.sqrt(np.diag(R @ cov[3:, 3:] @ R.T)) * 1e3  # translation of T moves by R v (first order)
    assert np.allclose(opt["sigma"]["translation_mm"], sig_t_mm, rtol=1e-4)
    assert np.allclose(body["sigma"]["translation_mm"], sig_t_mm, rtol=1e-4)  # same origin, same parent axes
    assert np.allclose(opt["sigma"]["rotation_child_axes_deg"], np.degrees(np.sqrt(np.diag(cov[:3, :3]))))
    # body axes: the rotation perturbation is the optical one seen in the body frame
    Rb = R_OPTICAL_BODY.T
    assert np.allclose(np.asarray(body["cov_6x6"])[:3, :3], Rb @ cov[:3, :3] @ Rb.T, atol=1e-18)
    assert opt["sigma"]["source"] == "cov_x_6x6"


@pytest.mark.parametrize("verdict", ["FAIL", "REFUSED"])
def test_unusable_verdict_is_refused_unless_forced(tmp_path, verdict, capsys):
    T, _ = _result(tmp_path / "res", "eye_in_hand", verdict=verdict)
    with pytest.raises(InputError) as e:
        export_result(tmp_path / "res", "yaml")
    assert e.value.code == "result_not_usable" and verdict in str(e.value)
    assert main(["export", str(tmp_path / "res"), "--to", "ros2"]) == InputError.exit_code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"verdict is {verdict}" in err and "--force" in err
    assert not (tmp_path / "res" / "hand_eye.launch.py").exists()
    (p,) = export_result(tmp_path / "res", "json", force=True)
    assert np.max(np.abs(np.asarray(json.loads(p.read_text())["matrix"]) - T)) < TOL


def test_failed_result_is_refused_even_forced(tmp_path, capsys):
    _result(tmp_path / "res", "eye_in_hand", status="failed", verdict="FAIL")
    assert main(["export", str(tmp_path / "res"), "--to", "urdf", "--force"]) == InputError.exit_code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no usable transform (no views)" in err


def test_cli_names_frames_and_out_file(tmp_path, capsys):
    T, _ = _result(tmp_path / "res", "eye_to_hand", seed=8)
    assert (
        main(
            [
                "export",
                str(tmp_path / "res" / "result.json"),
                "--to",
                "ros2",
                "--parent",
                "world",
                "--child",
                "cam_optical",
                "--out",
                str(tmp_path / "ros" / "cam.launch.py"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out.split()
    assert out == [
        "ros2:",
        str(tmp_path / "ros" / "cam.launch.py"),
        "ros2:",
        str(tmp_path / "ros" / "cam.tf_static.yaml"),
    ]
    parent, child, T_got = _launch_transform(tmp_path / "ros" / "cam.launch.py")
    assert (parent, child) == ("world", "cam_optical") and np.max(np.abs(T_got - T)) < TOL
    text = (tmp_path / "ros" / "cam.launch.py").read_text()
    assert "optical frame (x right, y down, z forward" in text and "quaternion x y z w" in text
    (tmp_path / "urdf").mkdir()
    assert main(["export", str(tmp_path / "res"), "--to", "urdf", "--out", str(tmp_path / "urdf")]) == 0
    assert sorted(p.name for p in (tmp_path / "urdf").iterdir()) == ["hand_eye.urdf", "hand_eye.urdf.xacro"]
    assert main(["export", str(tmp_path / "res"), "--to", "urdf", "--child", "my cam"]) == InputError.exit_code
    assert "--child 'my cam' is not a TF frame name" in capsys.readouterr().err


@pytest.mark.parametrize(
    "out,written",
    [
        ("r2.urdf.xacro", ["r2.urdf", "r2.urdf.xacro"]),  # the macro's name given: each file on its own ending
        ("r2.urdf", ["r2.urdf", "r2.urdf.xacro"]),
        ("r2.xml", ["r2.urdf.xacro", "r2.xml"]),  # another extension: the URDF as named, the macro on its stem
    ],
)
def test_out_names_one_of_the_files_and_the_companions_share_its_stem(tmp_path, capsys, out, written):
    _result(tmp_path / "res", "eye_in_hand", seed=2)
    (tmp_path / "o").mkdir()
    assert main(["export", str(tmp_path / "res"), "--to", "urdf", "--out", str(tmp_path / "o" / out)]) == 0
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == written
    assert (
        main(["export", str(tmp_path / "res"), "--to", "moveit", "--out", str(tmp_path / "m" / "cam.launch.py")]) == 0
    )
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["cam.launch.py", "cam.moveit.launch"]


@pytest.mark.parametrize(
    "mode,argv,says",
    [
        (
            "eye_in_hand",
            ["--to", "ros2", "--camera-frame", "body", "--child", "camera_color_optical_frame"],
            "--child camera_color_optical_frame names an optical frame but --camera-frame is body",
        ),
        (
            "eye_in_hand",
            ["--to", "ros2", "--child", "camera_link"],
            "--child camera_link names a body frame but --camera-frame is optical",
        ),
        (
            "eye_to_hand",
            ["--to", "easy_handeye2", "--base-frame", "world"],
            "--base-frame names the robot frame of an eye_in_hand calibration, this one is eye_to_hand",
        ),
        (
            "eye_in_hand",
            ["--to", "easy_handeye2", "--effector-frame", "flange"],
            "--effector-frame names the robot frame of an eye_to_hand calibration, this one is eye_in_hand",
        ),
        ("eye_in_hand", ["--to", "ros2", "--base-frame", "world"], "--base-frame applies to --to easy_handeye2 only"),
    ],
)
def test_frame_options_that_contradict_the_export_are_refused(tmp_path, capsys, mode, argv, says):
    """A camera frame named for the other rotation convention (90 degrees off in every consumer), or a robot frame
    option of the other mounting mode (its file would contradict its own header), is refused in one line."""
    _result(tmp_path / "res", mode, seed=3)
    rc = main(["export", str(tmp_path / "res"), *argv, "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == InputError.exit_code and len(err) == 1 and says in err[0], err
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


PWN = '\nopen("PWNED","w").write("x")\n#'


def _no_pwned(*folders):
    for f in folders:
        assert not list(f.rglob("PWNED")), f


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_hostile_result_path_and_verdict_export_safely_to_every_format(tmp_path, capsys, fmt):
    """A result folder whose name holds code after a newline and '---': every file of every format is read
    back by its real reader (the launch files executed in this test's own working folder), holds the
    transform, and no PWNED file appears. A verdict edited to hold code is refused by the result reader
    (the writers' own escaping of such text is tested in tests/export/test_writers.py)."""
    res = tmp_path / ("r---" + PWN + "-")
    T, _ = _result(res, "eye_in_hand", seed=9, verdict="WARN" + PWN)
    assert main(["export", str(res), "--to", fmt]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "verdict" in err[0] and not list(res.glob("hand_eye*"))
    T, _ = _result(res, "eye_in_hand", seed=9, verdict="WARN")
    assert main(["export", str(res), "--to", fmt]) == 0
    paths = [res / ("hand_eye" + s) for s in FORMATS[fmt][0]]
    shown = str(tmp_path / 'r---\\x0aopen("PWNED","w").write("x")\\x0a#-')  # one line per file
    assert capsys.readouterr().out.splitlines() == [f"{fmt}: {shown}/{p.name}" for p in paths]
    for _, _, T_got in _read_all(paths, fmt, tmp_path):
        assert np.max(np.abs(T_got - T)) < TOL
    for p in paths:
        if p.name.endswith((".urdf", ".xacro", ".launch")):
            ET.parse(p)
    _no_pwned(tmp_path)


def test_a_session_folder_named_with_code_calibrates_and_exports_safely(tmp_path, capsys, monkeypatch):
    """The issue's case: ``calibrate --export`` of a session folder whose name holds a newline and code. The
    default output folder's name has no control character; the launch files load without running it."""
    session = tmp_path / ("s" + PWN)
    assert main(["-q", "simulate", str(session), "--views", "8", "--seed", "3"]) == 0
    capsys.readouterr()
    assert main(["-q", "calibrate", str(session), "--no-report", "--export", "ros2"]) == 0
    out = capsys.readouterr().out
    (res,) = (tmp_path / "reports").iterdir()
    assert res.name.isprintable() and res.name.startswith('sopen("PWNED","w").write("x")#-')
    assert f"ros2: reports/{res.name}/hand_eye.launch.py" in out.splitlines()
    parent, child, T = _launch_transform(res / "hand_eye.launch.py")
    T_result = np.asarray(json.loads((res / "result.json").read_text())["T_end_cam"])
    assert (parent, child) == ("tool0", "camera_color_optical_frame") and np.max(np.abs(T - T_result)) < TOL
    # the result's own path holding the newline: export into it
    hostile = tmp_path / ("m" + PWN)
    hostile.mkdir()
    assert main(["export", str(res), "--to", "moveit", "--out", str(hostile)]) == 0
    parent, child, T = _launch_transform(hostile / "hand_eye.moveit.launch.py")
    assert np.max(np.abs(T - T_result)) < TOL
    assert _ros1_launch_transform(hostile / "hand_eye.moveit.launch")[:2] == ("tool0", "camera_color_optical_frame")
    _no_pwned(tmp_path)
    # an export that fails after a usable run: the run stands, the exit code says the file is missing
    from handeye.export import writers

    monkeypatch.setattr(writers, "urdf", lambda e: "<robot")
    assert main(["-q", "calibrate", str(session), "--no-report", "--export", "urdf"]) == InputError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("handeye: not exported: ") and "nothing was written" in err[0]
    assert not (res / "hand_eye.urdf").exists() and (res / "result.json").exists()


def _xacro_with(path, tmp_path, parent, child):
    import xacro

    wrapper = tmp_path / "robot.urdf.xacro"
    root = ET.Element("robot", {"name": "r", "xmlns:xacro": "http://www.ros.org/wiki/xacro"})
    ET.SubElement(root, "xacro:include", {"filename": str(path)})
    for name in (parent, child):
        ET.SubElement(root, "link", {"name": name})
    ET.SubElement(root, "xacro:handeye_camera_joint")
    wrapper.write_bytes(ET.tostring(root))
    out = tmp_path / "expanded.urdf"
    out.write_text(xacro.process_file(str(wrapper)).toxml())
    return _urdf_transform(out)


def test_dashes_in_the_child_frame_and_the_result_path_keep_xml_well_formed(tmp_path, capsys):
    res = tmp_path / "res---x--"
    T, _ = _result(res, "eye_in_hand", seed=10)
    child = "cam---x_optical_frame"
    out = tmp_path / "o---"
    out.mkdir()
    for fmt in ("urdf", "moveit"):
        assert main(["export", str(res), "--to", fmt, "--child", child, "--out", str(out)]) == 0
    for name in ("hand_eye.urdf", "hand_eye.urdf.xacro", "hand_eye.moveit.launch"):
        ET.parse(out / name)  # well-formed
        assert "---" in (out / name).read_text()  # the child's name, in the attributes
    assert _urdf_transform(out / "hand_eye.urdf")[:2] == ("tool0", child)
    parent, got_child, T_got = _xacro_with(out / "hand_eye.urdf.xacro", tmp_path, "tool0", child)
    assert (parent, got_child) == ("tool0", child) and np.max(np.abs(T_got - T)) < TOL
    assert _ros1_launch_transform(out / "hand_eye.moveit.launch")[1] == child
    assert _launch_transform(out / "hand_eye.moveit.launch.py")[1] == child


@pytest.mark.parametrize(
    "fmt,name",
    [
        ("json", "result.json"),
        ("urdf", "observations.json"),
        ("yaml", "result.last-good.json"),
        ("ros2", "report.html"),
        ("easy_handeye2", "report.md"),
        ("json", "verify.json"),
        ("yaml", "batch.json"),
        ("json", "thumbnails/view_01.jpg"),
    ],
)
def test_export_never_writes_over_a_result_folders_own_files(tmp_path, capsys, fmt, name):
    _result(tmp_path / "res", "eye_in_hand", seed=11)
    target = tmp_path / "res" / name
    target.parent.mkdir(exist_ok=True)
    if not target.exists():
        target.write_bytes(b"\x00the folder's own bytes\n")
    before = {p: p.read_bytes() for p in (tmp_path / "res").rglob("*") if p.is_file()}
    assert main(["export", str(tmp_path / "res"), "--to", fmt, "--out", str(target)]) == InputError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"will not write {fmt} over" in err[0] and "-> name another file" in err[0], err
    assert {p: p.read_bytes() for p in (tmp_path / "res").rglob("*") if p.is_file()} == before
    # the same name in another result folder, reached through a relative path, is refused too
    _result(tmp_path / "other", "eye_in_hand", seed=12)
    (tmp_path / "other" / "observations.json").write_text("{}")
    rel = tmp_path / "res" / ".." / "other" / "observations.json"
    assert main(["export", str(tmp_path / "res"), "--to", "json", "--out", str(rel)]) == InputError.exit_code
    assert (tmp_path / "other" / "observations.json").read_text() == "{}"
    # a result file of another name, exported over itself
    mine = tmp_path / "mine.json"
    (tmp_path / "res" / "result.json").rename(mine)
    data = mine.read_bytes()
    assert main(["export", str(mine), "--to", "json", "--out", str(mine)]) == InputError.exit_code
    assert "it is the result being exported" in capsys.readouterr().err and mine.read_bytes() == data


@pytest.mark.parametrize("flag", ["--parent", "--child", "--base-frame", "--effector-frame"])
@pytest.mark.parametrize("name", ["my cam", "-x", "a${b}", "a\nb"])
def test_every_frame_option_is_checked_as_a_frame_name(tmp_path, capsys, flag, name):
    _result(tmp_path / "res", "eye_in_hand", seed=13)
    rc = main(
        ["export", str(tmp_path / "res"), "--to", "easy_handeye2", f"{flag}={name}", "--out", str(tmp_path / "x")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == InputError.exit_code and len(err) == 1 and f"{flag} {name!r} is not a TF frame name" in err[0], err
    assert not (tmp_path / "x").exists()


def test_a_result_whose_mode_is_no_mounting_mode_is_refused(tmp_path, capsys):
    _result(tmp_path / "res", "eye_in_hand", seed=14)
    d = json.loads((tmp_path / "res" / "result.json").read_text())
    d["mode"] = 'eye_in_hand"""\nopen("PWNED","w")'
    write_json(tmp_path / "res" / "result.json", d)
    assert main(["export", str(tmp_path / "res"), "--to", "ros2"]) == InputError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mode" in err[0] and "eye_in_hand" in err[0] and "eye_to_hand" in err[0]
    assert not (tmp_path / "res" / "hand_eye.launch.py").exists()


def test_a_file_that_does_not_read_back_is_not_written(tmp_path, capsys, monkeypatch):
    """A writer whose file would not read back (here: a URDF with a joint 1 mm off) fails the command and
    writes none of the format's files."""
    from handeye.export import writers

    _result(tmp_path / "res", "eye_in_hand", seed=15)
    good = writers.urdf

    def shifted(e):
        text = good(e)
        head, rest = text.split('xyz="', 1)
        x, rest = rest.split(" ", 1)
        return head + f'xyz="{float(x) + 1e-3!r} ' + rest

    monkeypatch.setattr(writers, "urdf", shifted)
    assert main(["export", str(tmp_path / "res"), "--to", "urdf"]) == InputError.exit_code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "hand_eye.urdf holds a transform 0.001 away" in err[0] and "nothing was written" in err[0]
    assert sorted(p.name for p in (tmp_path / "res").iterdir()) == ["result.json"]


def test_a_refused_write_leaves_every_file_of_the_format_as_it_was(tmp_path, monkeypatch):
    """The disk refuses the second file of ros2: the first, already staged, is not renamed into place either."""
    import errno

    import handeye.output as output
    from handeye.output import OutputWriteError

    _result(tmp_path / "res", "eye_in_hand", seed=16)
    old = export_result(tmp_path / "res", "ros2")
    before = {p: p.read_bytes() for p in old}
    _result(tmp_path / "res", "eye_in_hand", seed=17)  # a new calibration
    real, calls = output.atomic_write_bytes, []

    def full_disk_on_second(path, data, **kw):
        calls.append(path)
        if len(calls) == 2:
            raise OutputWriteError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, data, **kw)

    monkeypatch.setattr(output, "atomic_write_bytes", full_disk_on_second)
    with pytest.raises(OutputWriteError):
        export_result(tmp_path / "res", "ros2")
    assert {p: p.read_bytes() for p in old} == before
    assert sorted(p.name for p in (tmp_path / "res").iterdir()) == sorted(["result.json", *(p.name for p in old)])
    monkeypatch.setattr(output, "atomic_write_bytes", real)
    assert export_result(tmp_path / "res", "ros2") == old and old[0].read_bytes() != before[old[0]]


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_an_export_never_replaces_a_file_it_did_not_write(tmp_path, fmt):
    """``export R --to yaml --out SESSION/session.yaml`` replaced the recorded session without a word (any file
    outside a result folder was fair game). A file an export wrote is replaced; any other is refused, unchanged."""
    _result(tmp_path / "r", "eye_in_hand")
    res = tmp_path / "r"
    own = tmp_path / "robot" / f"cam{FORMATS[fmt][0][0]}"
    first = export_result(res, fmt, out=own)
    assert first[0] == own and export_result(res, fmt, out=own) == first  # its own files: replaced
    session = tmp_path / "rec" / "session.yaml"
    session.parent.mkdir()
    session.write_text("handeye_session: 1\nviews: []\n")
    with pytest.raises(InputError, match="is not a file handeye export wrote") as e:
        export_result(res, fmt, out=session)
    assert e.value.code == "export_over_file" and "remove that file first" in str(e.value)
    assert session.read_text() == "handeye_session: 1\nviews: []\n"
    assert sorted(p.name for p in session.parent.iterdir()) == ["session.yaml"]  # nothing written beside it


def test_a_frame_is_not_its_own_parent(tmp_path):
    """``--parent cam --child cam`` was reported as a bug of handeye export (its URDF did not read back)."""
    _result(tmp_path / "r", "eye_to_hand")
    res = tmp_path / "r"
    with pytest.raises(InputError, match="--parent and --child name the same frame 'cam'"):
        export_result(res, "urdf", parent="cam", child="cam", out=tmp_path / "x")
    assert not (tmp_path / "x").exists()
