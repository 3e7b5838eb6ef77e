"""``handeye export`` of a cell: every camera in one file per format, or one camera with --camera."""

import json
import shutil
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from handeye.cli import main
from handeye.contract import read_result
from handeye.export.readback import _rpy_R, read_back_all


def _xs(cell) -> dict:
    res = read_result(cell["cell"])
    return {n: (res.camera_result(n).mode, res.camera_result(n).T_x) for n in res.camera_names}


def test_a_cell_exports_every_camera_into_one_urdf_launch_and_tf_yaml(cell, tmp_path, capsys, caplog):
    xs = _xs(cell)
    assert main(["export", str(cell["cell"]), "--to", "urdf", "--out", str(tmp_path)]) == 0
    assert main(["export", str(cell["cell"]), "--to", "ros2", "--out", str(tmp_path)]) == 0
    assert main(["export", str(cell["cell"]), "--to", "json", "--out", str(tmp_path)]) == 0
    root = ET.parse(tmp_path / "hand_eye.urdf").getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    assert set(joints) == {f"{n}_optical_frame" for n in xs}
    for name, (mode, T) in xs.items():
        j = joints[f"{name}_optical_frame"]
        assert j.find("parent").get("link") == ("tool0" if mode == "eye_in_hand" else "base_link")
        o = j.find("origin")
        np.testing.assert_allclose([float(v) for v in o.get("xyz").split()], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(_rpy_R(*(float(v) for v in o.get("rpy").split())), T[:3, :3], atol=1e-12)
    assert [link.get("name") for link in root.findall("link")][:2] == ["tool0", "base_link"]
    # fixed and wrist cameras: two roots, which only the robot's URDF joins; the file and the command say so
    assert "tool0 and base_link are both roots here" in (tmp_path / "hand_eye.urdf").read_text()
    assert "both roots" in caplog.text
    # the launch file: one static_transform_publisher per camera; the tf2 YAML: one transform per camera
    launch = read_back_all("launch.py", (tmp_path / "hand_eye.launch.py").read_bytes())
    tf = yaml.safe_load((tmp_path / "hand_eye.tf_static.yaml").read_text())["transforms"]
    xacro = read_back_all("xacro", (tmp_path / "hand_eye.urdf.xacro").read_bytes())
    for got in (launch, read_back_all("tf_static", (tmp_path / "hand_eye.tf_static.yaml").read_bytes()), xacro):
        assert [g.child for g in got] == [f"{n}_optical_frame" for n in xs]
        for g, (_, T) in zip(got, xs.values(), strict=True):
            np.testing.assert_allclose(g.T_parent_child, T, atol=1e-12)
    assert len(tf) == 3 and {g.fields["macro"] for g in xacro} == {f"handeye_camera_joint_{n}" for n in xs}
    d = json.loads((tmp_path / "hand_eye.json").read_text())
    assert d["kind"] == "cell" and list(d["cameras"]) == list(xs)
    assert d["cameras"]["fixed1"]["result_name"] == "T_base_cam" and d["cameras"]["wrist"]["camera"] == "wrist"
    np.testing.assert_allclose(d["cameras"]["fixed2"]["matrix"], xs["fixed2"][1], atol=0)


def test_moveit_and_easy_handeye2_write_one_file_per_camera_and_camera_picks_one(cell, tmp_path, capsys):
    xs = _xs(cell)
    assert main(["export", str(cell["cell"]), "--to", "easy_handeye2", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.rsplit("/", 1)[1] for line in out] == [f"hand_eye_{n}.calib" for n in xs]
    for name, (mode, T) in xs.items():
        d = yaml.safe_load((tmp_path / f"hand_eye_{name}.calib").read_text())
        p = d["parameters"]
        assert p["tracking_base_frame"] == f"{name}_optical_frame" and p["name"] == f"hand_eye_{name}"
        assert p["calibration_type"] == ("eye_in_hand" if mode == "eye_in_hand" else "eye_on_base")
        assert d["transform"]["translation"]["x"] == pytest.approx(T[0, 3], abs=1e-12)
    assert main(["export", str(cell["cell"]), "--to", "moveit", "--out", str(tmp_path / "m.moveit.launch.py")]) == 0
    assert sorted(p.name for p in tmp_path.glob("m_*")) == sorted(
        f"m_{n}.moveit.launch{s}" for n in xs for s in ("", ".py")
    )
    # one camera, under the frame it would have in the cell's file (or the one asked for)
    assert (
        main(["export", str(cell["cell"]), "--to", "yaml", "--camera", "fixed1", "--out", str(tmp_path / "f.yaml")])
        == 0
    )
    d = yaml.safe_load((tmp_path / "f.yaml").read_text())
    assert d["camera"] == "fixed1" and d["child_frame"] == "fixed1_optical_frame" and d["parent_frame"] == "base_link"
    np.testing.assert_allclose(d["matrix"], xs["fixed1"][1], atol=0)
    args = ["export", str(cell["cell"]), "--to", "urdf", "--camera", "wrist", "--child", "cam_optical_frame"]
    assert main(args + ["--out", str(tmp_path / "w.urdf")]) == 0
    assert "cam_optical_frame" in (tmp_path / "w.urdf").read_text()


def test_a_cell_export_refuses_one_frame_for_all_cameras_and_an_unknown_or_failed_camera(cell, tmp_path, capsys):
    for extra, words in (
        (["--parent", "flange"], "--parent names one frame, the result is a cell of 3 cameras"),
        (["--camera", "cam9"], "has no camera 'cam9' of 3 cameras (wrist, fixed1, fixed2)"),
    ):
        assert main(["export", str(cell["cell"]), "--to", "urdf", "--out", str(tmp_path), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0]
    bad = tmp_path / "bad"
    shutil.copytree(cell["cell"], bad)
    d = json.loads((bad / "result.json").read_text())
    d["cameras"]["fixed2"]["verdict"] = "FAIL"
    (bad / "result.json").write_text(json.dumps(d))
    assert main(["export", str(bad), "--to", "urdf", "--out", str(tmp_path / "x.urdf")]) == 2
    err = capsys.readouterr().err.strip()
    assert "camera fixed2" in err and "FAIL" in err and not (tmp_path / "x.urdf").exists()
    assert main(["export", str(bad), "--to", "urdf", "--out", str(tmp_path / "x.urdf"), "--camera", "wrist"]) == 0


@pytest.mark.parametrize("fmt", ["ros2", "urdf", "yaml", "json", "moveit", "easy_handeye2"])
def test_every_cameras_text_is_escaped_and_read_back_from_a_nasty_folder(cell, tmp_path, fmt):
    """A result folder whose name holds quotes, markup, a comment end and a line break: every format of the cell
    is written (each file parsed back before) and its launch files compile to what was meant."""
    nasty = tmp_path / "a\"b'<c>&--d\n#e"
    shutil.copytree(cell["cell"], nasty)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["export", str(nasty), "--to", fmt, "--out", str(out)]) == 0
    files = sorted(p for p in out.iterdir())
    assert files
    for p in files:
        text = p.read_text()
        assert "\n#e" not in text.replace("\\n#e", "")  # the line break never reaches the file as one
        if p.name.endswith(".launch.py"):  # the provenance constant holds the path exactly
            import ast

            tree = ast.parse(text)
            (prov,) = [
                n.value for n in tree.body if isinstance(n, ast.Assign) and n.targets[0].id == "HANDEYE_CALIBRATION"
            ]
            assert ast.literal_eval(prov)["source"] == str(nasty / "result.json")


def test_an_out_ending_in_a_slash_is_a_folder_made_for_the_files(cell, tmp_path):
    """``--out DIR/`` (not there yet) is a folder: made, the files in it under their default names; a refused
    export leaves no folder behind. Before, ``DIR/`` was the files' stem (DIR.urdf beside it)."""
    assert main(["-q", "export", str(cell["solo"]["wrist"]), "--to", "urdf", "--out", f"{tmp_path / 'a' / 'b'}/"]) == 0
    assert sorted(p.name for p in (tmp_path / "a" / "b").iterdir()) == ["hand_eye.urdf", "hand_eye.urdf.xacro"]
    assert not list(tmp_path.glob("*.urdf*")) and not list((tmp_path / "a").glob("*.urdf*"))
    assert main(["-q", "export", str(tmp_path / "nothing"), "--to", "urdf", "--out", f"{tmp_path / 'c' / 'd'}/"]) == 2
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("fmt", ["ros2", "urdf", "yaml", "json", "moveit", "easy_handeye2"])
def test_a_cell_export_replaces_its_own_files_and_its_result_knows_them(cell, tmp_path, fmt):
    """A cell's files begin "hand-eye calibration of a cell of 3 cameras by handeye" (one camera's: "... of camera
    cam1 of a cell by handeye"): the test of a file an export wrote took them for a user's, refused to export the cell
    again over them, and a new cell result left them beside it."""
    from pathlib import Path

    from handeye.export import exports_of

    folder = tmp_path / "cell"
    shutil.copytree(cell["cell"], folder)
    assert main(["export", str(folder), "--to", fmt]) == 0
    written = sorted(p.name for p in folder.glob("hand_eye*"))
    assert written and main(["export", str(folder), "--to", fmt]) == 0  # its own files: replaced
    assert main(["export", str(folder), "--to", fmt, "--camera", "wrist", "--out", str(folder / "one")]) == 0
    assert main(["export", str(folder), "--to", fmt, "--camera", "wrist", "--out", str(folder / "one")]) == 0
    assert sorted(p.name for p in exports_of(Path(folder / "result.json"))) == written
