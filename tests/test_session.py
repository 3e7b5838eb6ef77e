"""Reading the vendor folder and the native session.yaml, and every bad input's one-line error."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.conventions import VENDOR_POSE_FORMAT, PoseFormat, T_from_pose_values, pose_values_from_T
from handeye.detect import read_gray
from handeye.errors import ConfigError, InputError
from handeye.frames import T_from_rotvec
from handeye.session import load_session
from handeye.session.raw import raw_poses_of, read_raw_poses, read_session_lenient
from handeye.session.target_spec import parse_target
from handeye.targets import CharucoSpec, ChessboardSpec, CircleGridSpec

POSES = [T_from_rotvec([0.1 * k, -0.2, 0.3], [0.3, 0.05 * k, 0.4]) for k in range(1, 5)]


def vendor(tmp_path, *, n_images=4, lines=None, config=None):
    d = tmp_path / "vendor"
    d.mkdir()
    for k in range(1, n_images + 1):
        (d / f"{k}.jpg").write_bytes(b"x")
    if lines is None:
        lines = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    (d / "poses.txt").write_text("\n".join(lines) + "\n")
    cfg = {"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}} if config is None else config
    (d / "config.yaml").write_text(yaml.safe_dump(cfg))
    return d


def test_vendor_folder_reads_poses_by_line_number(tmp_path):
    s = load_session(vendor(tmp_path))
    assert s.format == "vendor" and s.mode == "eye_in_hand"
    assert [v.view_id for v in s.views] == ["1", "2", "3", "4"]
    for v, T in zip(s.views, POSES):
        assert v.image_path.name == f"{v.view_id}.jpg"
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-8)
    assert (s.target.cols, s.target.rows, s.target.square_m) == (11, 8, 0.03)


def test_vendor_gap_keeps_later_pairs(tmp_path):
    d = vendor(tmp_path)
    (d / "2.jpg").unlink()
    s = load_session(d)
    assert [v.view_id for v in s.views] == ["1", "3", "4"]
    np.testing.assert_allclose(s.view("3").T_base_end, POSES[2], atol=1e-8)
    assert s.meta["missing_images"] == {"2": 2}


def test_vendor_mode_key_and_override(tmp_path):
    d = vendor(tmp_path, config={"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}, "mode": "eye_to_hand"})
    assert load_session(d).mode == "eye_to_hand"
    assert load_session(d, mode="eye_in_hand").mode == "eye_in_hand"


@pytest.mark.parametrize("case,match", [
    ("more_images", "5 images but 4 pose lines"),
    ("malformed", r"poses.txt:2: malformed pose line"),
    ("nan", r"poses.txt:3: bad pose: pose contains NaN"),
    ("short", r"poses.txt:1: bad pose: expected 6 numbers"),
    ("mm", r"poses.txt:1: .*millimetres"),
    ("degrees", r"poses.txt:1: .*degrees"),
    ("no_config", "config.yaml is missing"),
    ("bad_mode", "invalid mode"),
    ("square_mm", "looks like millimetres"),
    ("zero_corners", r"checkerboard_args.XX"),
    ("bad_yaml", "not valid YAML"),
])
def test_vendor_bad_inputs_give_one_line_errors(tmp_path, case, match):
    good = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    cfg = {"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}}
    kw = {}
    if case == "more_images":
        kw["n_images"] = 5
    elif case == "malformed":
        kw["lines"] = [good[0], "0.1,0.2,abc,0,0,0", *good[2:]]
    elif case == "nan":
        kw["lines"] = [good[0], good[1], "0.1,0.2,nan,0,0,0", good[3]]
    elif case == "short":
        kw["lines"] = ["0.1,0.2,0.3,0,0", *good[1:]]
    elif case == "mm":
        kw["lines"] = ["300,50,400,0.1,0.2,0.3", *good[1:]]
    elif case == "degrees":
        kw["lines"] = ["0.3,0.05,0.4,170,20,-90", *good[1:]]
    elif case == "bad_mode":
        kw["config"] = dict(cfg, mode="eye_on_hand")
    elif case == "square_mm":
        kw["config"] = {"checkerboard_args": {"XX": 11, "YY": 8, "L": 30}}
    elif case == "zero_corners":
        kw["config"] = {"checkerboard_args": {"XX": 0, "YY": 8, "L": 0.03}}
    d = vendor(tmp_path, **kw)
    if case == "no_config":
        (d / "config.yaml").unlink()
    if case == "bad_yaml":
        (d / "config.yaml").write_text("checkerboard_args: {XX: 11, YY: [8\n")
    with pytest.raises(InputError, match=match) as e:
        load_session(d)
    assert "\n" not in str(e.value)


def native(tmp_path, *, fmt=None, extra=None, views=None):
    d = tmp_path / "native"
    d.mkdir(exist_ok=True)
    fmt = fmt or PoseFormat(rotation="quaternion", quaternion_order="xyzw", translation_unit="mm")
    if views is None:
        views = []
        for k, T in enumerate(POSES, start=1):
            (d / f"img{k}.png").write_bytes(b"x")
            views.append({"id": f"v{k}", "image": f"img{k}.png", "pose": pose_values_from_T(T, fmt).tolist(),
                          "t_image": 10.0 + k, "t_pose": 10.0 + k})
    doc = {"handeye_session": 1, "mode": "eye_to_hand",
           "target": {"type": "charuco", "squares": [5, 7], "square_m": 0.036, "marker_m": 0.018,
                      "dictionary": "DICT_6X6_250"},
           "pose_format": {k: getattr(fmt, k) for k in ("rotation", "quaternion_order", "translation_unit")},
           "views": views}
    doc.update(extra or {})
    (d / "session.yaml").write_text(yaml.safe_dump(doc))
    return d


def test_native_session_converts_poses_once(tmp_path):
    s = load_session(native(tmp_path))
    assert s.format == "native" and s.mode == "eye_to_hand" and s.target.kind == "charuco"
    assert [v.view_id for v in s.views] == ["v1", "v2", "v3", "v4"]
    for v, T in zip(s.views, POSES):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-9)
    assert s.view("v2").t_image == 12.0


def _write_view_records(folder):
    """One record file per view (quaternion xyzw, millimetres), as handeye collect writes them."""
    folder.mkdir()
    fmt = PoseFormat(rotation="quaternion", quaternion_order="xyzw", translation_unit="mm")
    for k, T in enumerate(POSES, start=1):
        (folder.parent / f"img{k}.png").write_bytes(b"x")
        (folder / f"{k:04d}.yaml").write_text(yaml.safe_dump(
            {"id": str(k), "image": f"img{k}.png", "pose": pose_values_from_T(T, fmt).tolist()}))


def test_native_view_records_folder(tmp_path):
    d = native(tmp_path, views=[], extra={"view_records": "views"})
    _write_view_records(d / "views")
    (d / "views" / ".0005.yaml.tmp").write_text("partial: [")  # a record still being written is ignored
    s = load_session(d)
    assert [v.view_id for v in s.views] == ["1", "2", "3", "4"]


def test_native_given_intrinsics(tmp_path):
    intr = {"model": "opencv5", "fx": 900.0, "fy": 901.0, "cx": 640.0, "cy": 360.0, "dist": [0.1, -0.2, 0, 0, 0.05],
            "image_size": [1280, 720], "use": "prior"}
    s = load_session(native(tmp_path, extra={"intrinsics": intr}))
    assert s.intrinsics.fx == 900.0 and s.intrinsics.dist[4] == 0.05 and s.intrinsics_prior == "prior"


@pytest.mark.parametrize("extra,match", [
    ({"mode": "sideways"}, "invalid mode"),
    ({"target": {"type": "circles"}}, "unknown target type"),
    ({"target": {"type": "charuco", "squares": [5, 7], "square_m": 0.03, "marker_m": 0.04}}, "marker_m must be smaller"),
    ({"pose_format": {"rotation": "quaternion", "quaternion_order": "qxyz"}}, "quaternion_order"),
    ({"pose_format": {"rotation": "euler", "scale": 2}}, "unknown pose_format field 'scale'"),
    ({"intrinsics": {"fx": -1, "fy": 1, "cx": 1, "cy": 1, "image_size": [10, 10]}}, "intrinsics.fx"),
    ({"intrinsics": {"fx": 1, "fy": 1, "cx": 1, "cy": 1, "dist": [0, "a", 0, 0], "image_size": [10, 10]}},
     "intrinsics.dist must be 4 or 5 finite numbers"),
    ({"intrinsics": {"fx": 1, "fy": 1, "cx": 1, "cy": 1, "dist": [0, 0, 0], "image_size": [10, 10]}},
     "intrinsics.dist must be 4 or 5 finite numbers"),
    ({"intrinsics": {"fx": 1, "fy": 1, "cx": 1, "cy": 1, "image_size": [10, 10], "use": "maybe"}}, "intrinsics.use"),
    ({"target": {"type": "charuco", "squares": [5, 7], "square_m": 0.036, "marker_m": 0.018,
                 "dictionary": "DICT_9X9_1"}}, "unknown ArUco dictionary"),
    ({"views": "all of them"}, "views must be a list"),
    ({"handeye_session": 7}, "version"),
])
def test_native_bad_config(tmp_path, extra, match):
    with pytest.raises(ConfigError, match=match) as e:
        load_session(native(tmp_path, extra=extra))
    assert "\n" not in str(e.value) and "session.yaml" in str(e.value)


def test_native_rotation_matrix_that_is_not_a_rotation(tmp_path):
    M = np.eye(4)
    M[:3, :3] *= 1.1
    d = tmp_path / "native"
    d.mkdir()
    (d / "a.png").write_bytes(b"x")
    native(tmp_path, fmt=PoseFormat(rotation="matrix"), views=[{"id": "a", "image": "a.png", "pose": M.tolist()}])
    with pytest.raises(InputError, match=r"view a: bad pose: the 3x3 block is not a rotation"):
        load_session(d)


def test_native_duplicate_ids_and_missing_image(tmp_path):
    d = native(tmp_path)
    doc = yaml.safe_load((d / "session.yaml").read_text())
    doc["views"][1]["id"] = "v1"
    (d / "session.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match="duplicate view id 'v1'"):
        load_session(d)
    doc["views"][1]["id"] = "v2"
    doc["views"][1]["image"] = "gone.png"
    (d / "session.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match="gone.png: view v2: image file missing"):
        load_session(d)


def test_corrupt_image_names_the_file(tmp_path):
    p = tmp_path / "3.jpg"
    p.write_bytes(b"\xff\xd8 definitely not a jpeg")
    with pytest.raises(InputError, match=r"3.jpg: image cannot be decoded"):
        read_gray(p)


def test_missing_session(tmp_path):
    with pytest.raises(InputError, match="session not found"):
        load_session(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no session.yaml or poses.txt"):
        load_session(tmp_path / "empty")


# ------------------------------------------------------------------------------ the lenient reading
def _vendor_lines(scale_t=1.0, degrees=False):
    out = []
    for T in POSES:
        v = pose_values_from_T(T, VENDOR_POSE_FORMAT)
        v[:3] *= scale_t
        if degrees:
            v[3:] = np.degrees(v[3:])
        out.append(",".join(f"{x:.9f}" for x in v))
    return out


def test_raw_poses_are_the_numbers_as_written(tmp_path):
    d = vendor(tmp_path, lines=["# x,y,z,rx,ry,rz", *_vendor_lines(scale_t=1000.0)])
    with pytest.raises(InputError, match="millimetres"):
        load_session(d)  # the strict reading refuses millimetres ...
    raw = read_raw_poses(d)  # ... the raw reading keeps them, numbered by pose line (comments skipped)
    assert raw.fmt == VENDOR_POSE_FORMAT and raw.order == ("1", "2", "3", "4")
    for k, T in enumerate(POSES, start=1):
        np.testing.assert_allclose(raw.values[str(k)][:3], T[:3, 3] * 1000.0, atol=1e-6)
    from_file = read_raw_poses(d / "poses.txt")  # the poses.txt path names the same session
    assert from_file.order == raw.order and all(np.array_equal(from_file.values[k], raw.values[k]) for k in raw.order)
    assert read_raw_poses(tmp_path / "nothing") is None


def test_lenient_and_strict_readings_agree_on_a_clean_session(tmp_path):
    for folder in (vendor(tmp_path), native(tmp_path)):
        s = load_session(folder)
        lenient = read_session_lenient(folder)
        assert lenient.target == s.target and lenient.mode == s.mode
        assert lenient.images_by_id == {v.view_id: v.image_path for v in s.views}
        for v in s.views:  # the raw numbers read in the stated format are the loaded poses
            np.testing.assert_allclose(T_from_pose_values(lenient.raw.values[v.view_id], lenient.raw.fmt),
                                       v.T_base_end, atol=1e-12)
        assert raw_poses_of(s).source == lenient.raw.source  # still the file's numbers


def test_lenient_reading_of_a_session_written_in_degrees(tmp_path):
    d = vendor(tmp_path, lines=_vendor_lines(degrees=True),
               config={"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}, "mode": "eye_to_hand"})
    (d / "2.jpg").unlink()
    with pytest.raises(InputError, match="degrees"):
        load_session(d)
    lenient = read_session_lenient(d, mode=None)
    assert lenient.mode == "eye_to_hand" and read_session_lenient(d, mode="eye_in_hand").mode == "eye_in_hand"
    assert sorted(lenient.images_by_id) == ["1", "3", "4"] and sorted(lenient.raw.values) == ["1", "2", "3", "4"]
    np.testing.assert_allclose(np.radians(lenient.raw.values["3"][3:]),
                               pose_values_from_T(POSES[2], VENDOR_POSE_FORMAT)[3:], atol=1e-9)
    assert lenient.intrinsics is None


def test_lenient_native_keeps_given_intrinsics_and_view_records(tmp_path):
    intr = {"model": "opencv5", "fx": 900.0, "fy": 901.0, "cx": 640.0, "cy": 360.0, "image_size": [1280, 720],
            "use": "fixed"}
    d = native(tmp_path, views=[], extra={"view_records": "views", "intrinsics": intr, "mode": None})
    _write_view_records(d / "views")
    with pytest.raises(ConfigError, match="invalid mode"):
        load_session(d)  # the strict reading needs a mode
    lenient = read_session_lenient(d)
    assert lenient.mode == "eye_in_hand" and lenient.intrinsics.fx == 900.0
    assert sorted(lenient.images_by_id) == ["1", "2", "3", "4"] and lenient.raw.order == ("1", "2", "3", "4")


def test_raw_poses_of_a_session_whose_file_changed_are_the_loaded_poses(tmp_path):
    d = vendor(tmp_path)
    s = load_session(d)
    lines = _vendor_lines()
    lines[1] = "0.5,0.5,0.5,0,0,0"  # the file no longer says what was loaded
    (d / "poses.txt").write_text("\n".join(lines) + "\n")
    raw = raw_poses_of(s)
    assert raw.source == "loaded poses" and raw.fmt == VENDOR_POSE_FORMAT
    for v in s.views:
        np.testing.assert_allclose(T_from_pose_values(raw.values[v.view_id], raw.fmt), v.T_base_end, atol=1e-12)


def test_unreadable_sessions_read_leniently_are_none(tmp_path):
    d = vendor(tmp_path, lines=["not numbers"])
    assert read_session_lenient(d) is None and read_raw_poses(d) is None
    (d / "poses.txt").unlink()
    assert read_session_lenient(d) is None


@pytest.mark.parametrize("spec, text", [
    (ChessboardSpec(11, 8, 0.03), "chessboard 11x8 inner corners, 30 mm"),
    (CharucoSpec(5, 7, 0.036195, 0.018256, "DICT_6X6_250", True),
     "ChArUco 5x7 squares, 36.195 mm squares, 18.256 mm markers, DICT_6X6_250"),
    (CircleGridSpec(10, 10, 0.0254, origin_dot=True), "circle grid 10x10 dots, 25.4 mm spacing, origin dot"),
])
def test_target_specs_read_back_what_they_write(spec, text):
    assert parse_target(spec.to_dict(), path=Path("session.yaml")) == spec
    assert spec.describe() == text


# ------------------------------------------------------------------------------ importers
def test_visp_import_reads_metres_and_theta_u(tmp_path):
    from scipy.spatial.transform import Rotation

    from handeye.session.importers import import_visp

    src = tmp_path / "visp"
    src.mkdir()
    (src / "chessboard-data.txt").write_text("Chessboard: 9 x 6\nsquare size: 0.0236 m\n")
    for k, T in enumerate(POSES, start=1):
        (src / f"franka_image-{k}.png").write_bytes(b"x")
        values = [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_rotvec()]
        (src / f"franka_pose_rPe_{k}.yaml").write_text(
            "rows: 6\ncols: 1\ndata:\n" + "".join(f"  - [{float(v)!r}]\n" for v in values))
    s = load_session(import_visp(src, tmp_path / "out"))
    assert s.target == ChessboardSpec(9, 6, 0.0236) and s.mode == "eye_in_hand"
    assert [v.view_id for v in s.views] == ["1", "2", "3", "4"]
    for v, T in zip(s.views, POSES):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-12)
        assert v.image_path == src / f"franka_image-{v.view_id}.png"


def test_ical_import_reads_xyzw_quaternions_and_the_static_camera(tmp_path):
    from handeye.frames import quat_wxyz_from_R
    from handeye.session.importers import import_ical

    src = tmp_path / "ical"
    (src / "images").mkdir(parents=True)
    (src / "poses").mkdir()
    data = []
    for k, T in enumerate(POSES):
        (src / "images" / f"{k}.png").write_bytes(b"x")
        w, x, y, z = quat_wxyz_from_R(T[:3, :3])
        (src / "poses" / f"{k}.yaml").write_text(yaml.safe_dump(
            {"x": float(T[0, 3]), "y": float(T[1, 3]), "z": float(T[2, 3]),
             "qx": float(x), "qy": float(y), "qz": float(z), "qw": float(w)}))
        data.append({"image": f"images/{k}.png", "pose": f"poses/{k}.yaml"})
    (src / "cal_data.yaml").write_text(yaml.safe_dump({
        "static_camera": True, "data": data,
        "target_finder": {"type": "CharucoGridTargetFinder", "cols": 5, "rows": 7, "chessboard_dim": 0.036195,
                          "aruco_marker_dim": 0.018256, "dictionary": 10}}))
    s = load_session(import_ical(src, tmp_path / "out"))
    assert s.mode == "eye_to_hand" and s.target == CharucoSpec(5, 7, 0.036195, 0.018256, "DICT_6X6_250")
    for v, T in zip(s.views, POSES):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-12)
    (src / "cal_data.yaml").write_text(yaml.safe_dump({"data": data, "target_finder": {"type": "DotFinder"}}))
    with pytest.raises(InputError, match="unsupported industrial_calibration target finder"):
        import_ical(src, tmp_path / "out2")
