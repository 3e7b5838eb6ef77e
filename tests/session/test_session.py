"""Reading the vendor folder and the native session.yaml, and every bad input's one-line error."""

import json
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
    for v, T in zip(s.views, POSES, strict=False):
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


def test_vendor_images_numbered_from_zero_pair_image_k_with_line_k_plus_1(tmp_path):
    d = vendor(tmp_path)
    for k in range(1, 5):  # 1.jpg..4.jpg -> 0.jpg..3.jpg, each image a distinct file
        (d / f"{k}.jpg").write_bytes(f"image {k}".encode())
    for k in range(1, 5):
        (d / f"{k}.jpg").rename(d / f"{k - 1}.jpg")
    (d / "2.jpg").unlink()  # the third pose line's image deleted
    s = load_session(d)
    assert [v.view_id for v in s.views] == ["0", "1", "3"]
    for v in s.views:
        assert v.image_path.read_bytes() == f"image {int(v.view_id) + 1}".encode()
        np.testing.assert_allclose(v.T_base_end, POSES[int(v.view_id)], atol=1e-8)
    assert s.meta["missing_images"] == {"2": 3}
    lenient = read_session_lenient(d)  # the diagnostics read the same pairing
    assert set(lenient.raw.values) == {"0", "1", "2", "3"}
    for v in s.views:
        np.testing.assert_allclose(
            T_from_pose_values(lenient.raw.values[v.view_id], lenient.raw.fmt), v.T_base_end, atol=1e-12
        )
    (d / "4.jpg").write_bytes(b"x")  # 0..4 against four pose lines: the last image has none
    with pytest.raises(
        InputError, match=r"4.jpg has no pose line: poses.txt has 4 lines; the images run to 4.jpg "
    ) as e:
        load_session(d)
    # 2.jpg was deleted with its pose line (a common clean-up): every later image is out of step, which is said
    assert "without 2.jpg -> line k+1 of poses.txt belongs to k.jpg (images numbered from 0): an image deleted " in (
        str(e.value)
    )
    assert "put a line back in its place" in str(e.value) and "renumber the later images" in str(e.value)


@pytest.mark.parametrize("header", ["x,y,z,rx,ry,rz", "x y z rx ry rz", "x[m],y[m],z[m],rx(rad),ry(rad),rz(rad)"])
def test_a_first_line_of_column_names_is_skipped(tmp_path, header):
    good = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    s = load_session(vendor(tmp_path, lines=[header, *good]))
    assert [v.source_line for v in s.views] == [2, 3, 4, 5]
    for v, T in zip(s.views, POSES, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-8)


@pytest.mark.parametrize("wrap", ["[{}]", "({})", "[ {} ]"])
def test_pose_lines_printed_as_lists_read_as_their_numbers(tmp_path, wrap):
    sep = ", " if "[" in wrap and " " not in wrap else " " if " " in wrap else ","
    lines = [wrap.format(sep.join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT))) for T in POSES]
    s = load_session(vendor(tmp_path, lines=lines))
    for v, T in zip(s.views, POSES, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-8)


def test_quoted_board_numbers_are_read_and_units_in_them_refused(tmp_path):
    s = load_session(vendor(tmp_path, config={"checkerboard_args": {"XX": "11", "YY": "8", "L": "0.03"}}))
    assert (s.target.cols, s.target.rows, s.target.square_m) == (11, 8, 0.03)
    (tmp_path / "mm").mkdir()
    with pytest.raises(
        ConfigError,
        match=r"config.yaml: invalid checkerboard_args.L; expected a number > 0; "
        r"got '30 mm' -> write the bare number, without a unit \(metres\)",
    ):
        load_session(vendor(tmp_path / "mm", config={"checkerboard_args": {"XX": 11, "YY": 8, "L": "30 mm"}}))


@pytest.mark.parametrize(
    "change,match",
    [
        (
            lambda d: (d / "config.yaml").rename(d / "config.yml"),
            r"config.yaml is missing -> rename config.yml to config.yaml",
        ),
        (
            lambda d: (d / "poses.txt").rename(d / "pose.txt"),
            r"no session.yaml or poses.txt in the folder -> rename pose.txt to poses.txt",
        ),
        (
            lambda d: [p.rename(p.with_name("image_" + p.name)) for p in d.glob("*.jpg")],
            r"no numbered images .* -> the images are named image_1.jpg, ...: rename them to the number alone",
        ),
    ],
)
def test_near_misses_of_the_vendor_names_are_named_with_the_rename(tmp_path, change, match):
    d = vendor(tmp_path)
    change(d)
    with pytest.raises(InputError, match=match):
        load_session(d)


def test_images_in_a_subfolder_are_named_in_the_error(tmp_path):
    d = vendor(tmp_path)
    (d / "images").mkdir()
    for p in d.glob("*.jpg"):
        p.rename(d / "images" / p.name)
    with pytest.raises(
        InputError,
        match=r"no numbered images .* -> the numbered images are in images/: move them "
        r"next to poses.txt",
    ):
        load_session(d)


@pytest.mark.parametrize(
    "lines,match",
    [
        (["x,y,z,rx,ry,rz", "x,y,z,rx,ry,rz"], r"poses.txt:2: malformed pose line"),  # only the first line
        (["nan,nan,nan,nan,nan,nan"], r"poses.txt:1: pose line holds a value that is not a usable number"),
        (["x,0.1,0.2,0,0,0"], r"poses.txt:1: malformed pose line"),  # names and numbers mixed: not a header
        (["x=0.5 y=0.1 z=0.4 rx=0 ry=0 rz=0"], r"poses.txt:1: malformed pose line"),  # values named: not a header
        (["None,None,None,None,None,None"], r"poses.txt:1: malformed pose line"),  # a failed read, not names
        (["x,y,z"], r"poses.txt:1: malformed pose line.*names 3 columns, the lines hold 6"),  # not these columns
    ],
)
def test_only_a_first_line_of_names_is_a_header(tmp_path, lines, match):
    good = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    with pytest.raises(InputError, match=match):
        load_session(vendor(tmp_path, lines=[*lines, *good]))


@pytest.mark.parametrize(
    "fmt",
    [
        {"rotation": "quaternion", "quaternion_order": "xyzw"},
        {"rotation": "quaternion", "quaternion_order": "wxyz", "translation_unit": "mm"},
        {"rotation": "matrix"},
        {"rotation": "euler", "euler_order": "zyx", "euler_kind": "intrinsic", "angle_unit": "deg"},
        {"rotation": "rotvec"},
    ],
)
def test_config_yaml_may_state_how_poses_txt_is_written(tmp_path, fmt):
    pf = PoseFormat(**fmt)
    lines = [" ".join(f"{v:.12g}" for v in pose_values_from_T(T, pf)) for T in POSES]
    d = vendor(tmp_path, lines=lines, config={"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}, "pose_format": fmt})
    s = load_session(d)
    assert s.pose_format == pf.validated().describe()
    for v, T in zip(s.views, POSES, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-9)
    raw = read_raw_poses(d)  # the diagnostics read the numbers in the stated format too
    assert raw.fmt == pf.validated()
    np.testing.assert_allclose(T_from_pose_values(raw.values["2"], raw.fmt), POSES[1], atol=1e-9)


@pytest.mark.parametrize(
    "lines,config,match",
    [
        (
            ["0.1,0.2,0.3,0,0,0,1"],
            None,
            r"poses.txt:1: bad pose: .*got 7.* x,y,z and a quaternion: add to config.yaml "
            r"pose_format: \{rotation: quaternion",
        ),
        ([",".join(["0"] * 15 + ["1"])], None, r"got 16.* a 4x4 matrix row by row: add to config.yaml pose_format"),
        (
            [f"{k},0.1,0.2,0.3,0,0,0" for k in range(1, 5)],
            None,
            r"got 7.* the first number of every line counts the "
            r"lines \(a view number\): remove that column",
        ),
        (
            ["0.3,0.05,0.4,170,20,-90"] * 4,
            None,
            r"poses.txt:1: .*degrees; convert them to radians or add to "
            r"config.yaml pose_format: \{rotation: euler, angle_unit: deg\}",
        ),
        (
            ["300,50,400,0.1,0.2,0.3"] * 4,
            None,
            r"millimetres or centimetres\?\); convert to metres or add to config.yaml pose_format",
        ),
        # a few lines in other units than the rest: those lines are named, and the fix converts them (a unit stated
        # for the whole file would misread the others)
        (
            ["0.3,0.05,0.4,170,20,-90"],
            None,
            r"poses.txt:1: rotation angles beyond 2\*pi on 1 of 4 pose lines \(line 1\)"
            r".*look like degrees while the others fit radians: convert those lines",
        ),
        (
            ["300,50,400,0.1,0.2,0.3"],
            None,
            r"positions beyond an arm's reach \(5 m\) on 1 of 4 pose lines.*millimetres",
        ),
        (["0.1,0.2,0.3,0,0,0"], {"rotation": "quaternion"}, r"poses.txt:1: bad pose: expected 7 numbers"),
        (
            ["0.1,0.2,0.3,0,0,0"],
            {"rotation": "euler", "units": "deg"},
            r"config.yaml: unknown pose_format field 'units'",
        ),
        (["0.1,0.2,0.3,0,0,0"], "euler", r"config.yaml: pose_format must be a mapping"),
    ],
)
def test_pose_lines_in_another_format_name_the_config_yaml_way(tmp_path, lines, config, match):
    good = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    cfg = {"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}}
    if config is not None:
        cfg["pose_format"] = config
    with pytest.raises(InputError, match=match) as e:
        load_session(vendor(tmp_path, lines=[*lines, *good[len(lines) :]], config=cfg))
    assert "\n" not in str(e.value)


def test_vendor_mode_key_and_override(tmp_path):
    d = vendor(tmp_path, config={"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}, "mode": "eye_to_hand"})
    assert load_session(d).mode == "eye_to_hand"
    assert load_session(d, mode="eye_in_hand").mode == "eye_in_hand"


def test_misspelt_config_keys_are_named_with_the_nearest_known_key(tmp_path, caplog):
    cfg = {"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03, "l": 0.025}, "mdoe": "eye_to_hand", "colour": 1}
    d = vendor(tmp_path, config=cfg)
    with caplog.at_level("WARNING", logger="handeye.session.vendor"):
        s = load_session(d)
    assert s.mode == "eye_in_hand" and s.mode_source == "default" and s.target.square_m == 0.03
    said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    where = f"{d / 'config.yaml'}: "
    assert said == [
        where + "unknown key colour is ignored; known keys: checkerboard_args, mode, pose_format",
        where + "unknown key mdoe is ignored (did you mean mode?); known keys: checkerboard_args, mode, pose_format",
        where + "unknown key checkerboard_args.l is ignored (did you mean checkerboard_args.L?); known keys: "
        "checkerboard_args.XX, checkerboard_args.YY, checkerboard_args.L",
    ]


def test_a_missing_board_key_names_its_misspelling(tmp_path):
    d = vendor(tmp_path, config={"checkerboard_args": {"XX": 11, "YY": 8, "l": 0.03}})
    with pytest.raises(ConfigError, match=r"checkerboard_args.L is missing; .* -> rename l to L"):
        load_session(d)


@pytest.mark.parametrize(
    "case,match",
    [
        ("more_images", "5 images but 4 pose lines"),
        ("malformed", r"poses.txt:2: malformed pose line"),
        ("nan", r"poses.txt:3: pose line holds a value that is not a usable number.*got nan"),
        ("short", r"poses.txt:1: bad pose: expected 6 numbers"),
        ("mm", r"poses.txt:1: .*millimetres"),
        ("degrees", r"poses.txt:1: .*degrees"),
        ("no_config", "config.yaml is missing"),
        ("bad_mode", "invalid mode"),
        ("square_mm", "looks like millimetres"),
        ("zero_corners", r"checkerboard_args.XX"),
        ("bad_yaml", "not valid YAML"),
    ],
)
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


def test_a_nan_pose_line_says_to_fix_the_line_not_remove_it_alone(tmp_path):
    good = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    d = vendor(tmp_path, lines=["# x,y,z,rx,ry,rz", good[0], good[1], "nan,0.2,0.3,0,0,0", good[3]])
    with pytest.raises(InputError) as e:
        load_session(d)
    assert str(e.value) == (
        f"{d / 'poses.txt'}:4: pose line holds a value that is not a usable number; expected finite numbers "
        "(|x| < 1e6); got nan -> fix line 4 (lines pair with images by number: removing only the line puts every "
        "later image out of step; to drop the view, remove the line and its image together and renumber the "
        "later images)"
    )


def native(tmp_path, *, fmt=None, extra=None, views=None):
    d = tmp_path / "native"
    d.mkdir(exist_ok=True)
    fmt = fmt or PoseFormat(rotation="quaternion", quaternion_order="xyzw", translation_unit="mm")
    if views is None:
        views = []
        for k, T in enumerate(POSES, start=1):
            (d / f"img{k}.png").write_bytes(b"x")
            views.append(
                {
                    "id": f"v{k}",
                    "image": f"img{k}.png",
                    "pose": pose_values_from_T(T, fmt).tolist(),
                    "t_image": 10.0 + k,
                    "t_pose": 10.0 + k,
                }
            )
    doc = {
        "handeye_session": 1,
        "mode": "eye_to_hand",
        "target": {
            "type": "charuco",
            "squares": [5, 7],
            "square_m": 0.036,
            "marker_m": 0.018,
            "dictionary": "DICT_6X6_250",
        },
        "pose_format": {k: getattr(fmt, k) for k in ("rotation", "quaternion_order", "translation_unit")},
        "views": views,
    }
    doc.update(extra or {})
    (d / "session.yaml").write_text(yaml.safe_dump(doc))
    return d


def test_native_session_converts_poses_once(tmp_path):
    s = load_session(native(tmp_path))
    assert s.format == "native" and s.mode == "eye_to_hand" and s.target.kind == "charuco"
    assert [v.view_id for v in s.views] == ["v1", "v2", "v3", "v4"]
    for v, T in zip(s.views, POSES, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-9)
    assert s.view("v2").t_image == 12.0


def _write_view_records(folder):
    """One record file per view (quaternion xyzw, millimetres), as handeye collect writes them."""
    folder.mkdir()
    fmt = PoseFormat(rotation="quaternion", quaternion_order="xyzw", translation_unit="mm")
    for k, T in enumerate(POSES, start=1):
        (folder.parent / f"img{k}.png").write_bytes(b"x")
        (folder / f"{k:04d}.yaml").write_text(
            yaml.safe_dump({"id": str(k), "image": f"img{k}.png", "pose": pose_values_from_T(T, fmt).tolist()})
        )


def test_native_view_records_folder(tmp_path):
    d = native(tmp_path, views=[], extra={"view_records": "views"})
    _write_view_records(d / "views")
    (d / "views" / ".0005.yaml.tmp").write_text("partial: [")  # a record still being written is ignored
    s = load_session(d)
    assert [v.view_id for v in s.views] == ["1", "2", "3", "4"]


def test_native_given_intrinsics(tmp_path):
    intr = {
        "model": "opencv5",
        "fx": 900.0,
        "fy": 901.0,
        "cx": 640.0,
        "cy": 360.0,
        "dist": [0.1, -0.2, 0, 0, 0.05],
        "image_size": [1280, 720],
        "use": "prior",
    }
    s = load_session(native(tmp_path, extra={"intrinsics": intr}))
    assert s.intrinsics.fx == 900.0 and s.intrinsics.dist[4] == 0.05 and s.intrinsics_prior == "prior"


@pytest.mark.parametrize(
    "extra,match",
    [
        ({"mode": "sideways"}, "invalid mode"),
        ({"target": {"type": "circles"}}, "unknown target type"),
        (
            {"target": {"type": "charuco", "squares": [5, 7], "square_m": 0.03, "marker_m": 0.04}},
            "marker_m must be smaller",
        ),
        ({"pose_format": {"rotation": "quaternion", "quaternion_order": "qxyz"}}, "quaternion_order"),
        ({"pose_format": {"rotation": "euler", "scale": 2}}, "unknown pose_format field 'scale'"),
        ({"intrinsics": {"fx": -1, "fy": 1, "cx": 1, "cy": 1, "image_size": [10, 10]}}, "intrinsics.fx"),
        (
            {"intrinsics": {"fx": 1, "fy": 1, "cx": 1, "cy": 1, "dist": [0, "a", 0, 0], "image_size": [10, 10]}},
            "intrinsics.dist must be 4 or 5 finite numbers",
        ),
        (
            {"intrinsics": {"fx": 1, "fy": 1, "cx": 1, "cy": 1, "dist": [0, 0, 0], "image_size": [10, 10]}},
            "intrinsics.dist must be 4 or 5 finite numbers",
        ),
        (
            {"intrinsics": {"fx": 1, "fy": 1, "cx": 1, "cy": 1, "image_size": [10, 10], "use": "maybe"}},
            "intrinsics.use",
        ),
        (
            {
                "target": {
                    "type": "charuco",
                    "squares": [5, 7],
                    "square_m": 0.036,
                    "marker_m": 0.018,
                    "dictionary": "DICT_9X9_1",
                }
            },
            "unknown ArUco dictionary",
        ),
        ({"views": "all of them"}, "views must be a list"),
        ({"handeye_session": 7}, "version"),
    ],
)
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
    # a pose without its image is dropped with it and listed, as in the vendor layout
    s = load_session(d)
    assert [v.view_id for v in s.views] == ["v1", "v3", "v4"]
    assert s.meta["missing_images"] == {"v2": None} and s.meta["missing_image_files"] == {"v2": str(d / "gone.png")}
    for v in doc["views"]:
        v["image"] = "gone.png"
    (d / "session.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match="gone.png: none of the 4 views' images exists"):
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
            np.testing.assert_allclose(
                T_from_pose_values(lenient.raw.values[v.view_id], lenient.raw.fmt), v.T_base_end, atol=1e-12
            )
        assert raw_poses_of(s).source == lenient.raw.source  # still the file's numbers


def test_lenient_reading_of_a_session_written_in_degrees(tmp_path):
    d = vendor(
        tmp_path,
        lines=_vendor_lines(degrees=True),
        config={"checkerboard_args": {"XX": 11, "YY": 8, "L": 0.03}, "mode": "eye_to_hand"},
    )
    (d / "2.jpg").unlink()
    with pytest.raises(InputError, match="degrees"):
        load_session(d)
    lenient = read_session_lenient(d, mode=None)
    assert lenient.mode == "eye_to_hand" and read_session_lenient(d, mode="eye_in_hand").mode == "eye_in_hand"
    assert sorted(lenient.images_by_id) == ["1", "3", "4"] and sorted(lenient.raw.values) == ["1", "2", "3", "4"]
    np.testing.assert_allclose(
        np.radians(lenient.raw.values["3"][3:]), pose_values_from_T(POSES[2], VENDOR_POSE_FORMAT)[3:], atol=1e-9
    )
    assert lenient.intrinsics is None


def test_lenient_native_keeps_given_intrinsics_and_view_records(tmp_path):
    intr = {
        "model": "opencv5",
        "fx": 900.0,
        "fy": 901.0,
        "cx": 640.0,
        "cy": 360.0,
        "image_size": [1280, 720],
        "use": "fixed",
    }
    d = native(tmp_path, views=[], extra={"view_records": "views", "intrinsics": intr, "mode": None})
    _write_view_records(d / "views")
    s = load_session(d)  # no mode stated: read as eye-in-hand until the data decide (mode_source "default")
    assert s.mode == "eye_in_hand" and s.mode_source == "default"
    assert load_session(d, mode="eye_to_hand").mode_source == "flag"
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


@pytest.mark.parametrize(
    "spec, text",
    [
        (ChessboardSpec(11, 8, 0.03), "chessboard 11x8 inner corners, 30 mm"),
        (
            CharucoSpec(5, 7, 0.036195, 0.018256, "DICT_6X6_250", True),
            "ChArUco 5x7 squares, 36.195 mm squares, 18.256 mm markers, DICT_6X6_250",
        ),
        (CircleGridSpec(10, 10, 0.0254, origin_dot=True), "circle grid 10x10 dots, 25.4 mm spacing, origin dot"),
    ],
)
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
            "rows: 6\ncols: 1\ndata:\n" + "".join(f"  - [{float(v)!r}]\n" for v in values)
        )
    s = load_session(import_visp(src, tmp_path / "out"))
    assert s.target == ChessboardSpec(9, 6, 0.0236) and s.mode == "eye_in_hand"
    assert [v.view_id for v in s.views] == ["1", "2", "3", "4"]
    for v, T in zip(s.views, POSES, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-12)
        assert v.image_path == src / f"franka_image-{v.view_id}.png"


def test_visp_import_keeps_a_pose_without_its_image_and_refuses_given_intrinsics_without_a_camera_file(tmp_path):
    """A pose file whose image is gone stays a view: the loader drops it with its reason (as in any session)
    instead of the import dropping it unsaid. --given-intrinsics without a camera file is refused."""
    from handeye.errors import InputError
    from handeye.session.importers import import_visp

    src = tmp_path / "visp"
    src.mkdir()
    (src / "chessboard-data.txt").write_text("Chessboard: 9 x 6\nsquare size: 0.0236 m\n")
    for k in range(1, 5):
        if k != 3:
            (src / f"franka_image-{k}.png").write_bytes(b"x")
        rows = "".join(f"  - [{v}]\n" for v in (0.1, 0, 0.3, 0, 0, 0))
        (src / f"franka_pose_rPe_{k}.yaml").write_text("data:\n" + rows)
    path = import_visp(src, tmp_path / "out")
    assert [v["image"] for v in yaml.safe_load(path.read_text())["views"]][2] == "franka_image-3.png"
    s = load_session(path)
    assert [v.view_id for v in s.views] == ["1", "2", "4"] and list(s.meta["missing_images"]) == ["3"]
    with pytest.raises(InputError, match="no ViSP camera file") as e:
        import_visp(src, tmp_path / "out2", use_given_intrinsics=True)
    assert "visp" in str(e.value) and not (tmp_path / "out2" / "session.yaml").exists()


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
        (src / "poses" / f"{k}.yaml").write_text(
            yaml.safe_dump(
                {
                    "x": float(T[0, 3]),
                    "y": float(T[1, 3]),
                    "z": float(T[2, 3]),
                    "qx": float(x),
                    "qy": float(y),
                    "qz": float(z),
                    "qw": float(w),
                }
            )
        )
        data.append({"image": f"images/{k}.png", "pose": f"poses/{k}.yaml"})
    (src / "cal_data.yaml").write_text(
        yaml.safe_dump(
            {
                "static_camera": True,
                "data": data,
                "target_finder": {
                    "type": "CharucoGridTargetFinder",
                    "cols": 5,
                    "rows": 7,
                    "chessboard_dim": 0.036195,
                    "aruco_marker_dim": 0.018256,
                    "dictionary": 10,
                },
            }
        )
    )
    s = load_session(import_ical(src, tmp_path / "out"))
    assert s.mode == "eye_to_hand" and s.target == CharucoSpec(5, 7, 0.036195, 0.018256, "DICT_6X6_250")
    for v, T in zip(s.views, POSES, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-12)
    (src / "cal_data.yaml").write_text(yaml.safe_dump({"data": data, "target_finder": {"type": "DotFinder"}}))
    with pytest.raises(InputError, match="unsupported industrial_calibration target finder"):
        import_ical(src, tmp_path / "out2")


# ------------------------------------------------------------------------------ the native format's rules
def _native_text(tmp_path, views_yaml: str, *, fmt: str = "{rotation: matrix}", extra: str = "", images=("a",)):
    """session.yaml written as text (so ids are exactly as a user types them), with images ``a.png`` ..."""
    d = tmp_path / "nt"
    d.mkdir(exist_ok=True)
    for name in images:
        (d / f"{name}.png").write_bytes(b"x")
    (d / "session.yaml").write_text(
        "handeye_session: 1\nmode: eye_in_hand\ntarget: {type: chessboard, inner_corners: [11, 8], square_m: 0.03}\n"
        f"pose_format: {fmt}\n{extra}views:\n{views_yaml}"
    )
    return d


_ROWS = [[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.2], [0.0, 0.0, 1.0, 0.3], [0.0, 0.0, 0.0, 1.0]]


def test_view_ids_are_kept_as_written(tmp_path):
    flat = str(sum(_ROWS, []))
    d = _native_text(
        tmp_path,
        f"  - {{id: 010, image: a.png, pose: {flat}}}\n"
        f"  - {{id: 7, image: b.png, pose: {flat}}}\n"
        f"  - {{id: '10', image: c.png, pose: {flat}}}\n",
        images="abc",
    )
    # YAML 1.1 reads an unquoted 010 as the octal number 8: the id stays "010", never "8"
    assert [v.view_id for v in load_session(d).views] == ["7", "010", "10"]
    for bad, got in (("~", "None"), ("[1, 2]", "['1', '2']"), ("''", "''")):
        d = _native_text(tmp_path, f"  - {{id: {bad}, image: a.png, pose: {flat}}}\n")
        with pytest.raises(ConfigError, match="invalid view id") as e:
            load_session(d)
        assert e.value.received in (got, repr(None), "[1, 2]")


def test_a_4x4_pose_is_nested_rows_or_16_numbers_row_by_row(tmp_path):
    nested = _native_text(tmp_path, f"  - {{id: a, image: a.png, pose: {_ROWS}}}\n")
    T = load_session(nested).views[0].T_base_end
    np.testing.assert_array_equal(T, np.array(_ROWS))
    flat = _native_text(tmp_path, f"  - {{id: a, image: a.png, pose: {sum(_ROWS, [])}}}\n")
    np.testing.assert_array_equal(load_session(flat).views[0].T_base_end, T)
    with pytest.raises(InputError, match="looks transposed: write it row by row"):  # column-major
        load_session(_native_text(tmp_path, f"  - {{id: a, image: a.png, pose: {np.array(_ROWS).T.tolist()}}}\n"))
    with pytest.raises(InputError, match="a nested pose must be a 4x4 matrix"):  # 3 x 4: not a 4x4
        load_session(_native_text(tmp_path, f"  - {{id: a, image: a.png, pose: {_ROWS[:3]}}}\n"))
    with pytest.raises(InputError, match="a nested pose must be a 4x4 matrix .* with pose_format.rotation: matrix"):
        load_session(
            _native_text(tmp_path, "  - {id: a, image: a.png, pose: [[0, 0, 0], [0, 0, 0]]}\n", fmt="{rotation: euler}")
        )


def test_a_pose_file_holds_a_4x4_or_one_pose_line_in_the_session_format(tmp_path):
    d = _native_text(tmp_path, "  - {id: a, image: a.png, pose_file: 000_pose.csv}\n")
    (d / "000_pose.csv").write_text("# T_base_end\n" + "\n".join(",".join(map(str, r)) for r in _ROWS) + "\n")
    s = load_session(d)
    np.testing.assert_array_equal(s.views[0].T_base_end, np.array(_ROWS))
    assert read_raw_poses(d).values["a"].tolist() == sum(_ROWS, [])  # the lenient reader reads it the same way
    vendor_line = pose_values_from_T(POSES[0], VENDOR_POSE_FORMAT)
    d = _native_text(
        tmp_path,
        "  - {id: a, image: a.png, pose_file: 000_pose.csv}\n",
        fmt="{rotation: euler, euler_order: xyz, euler_kind: extrinsic, angle_unit: rad}",
    )
    with pytest.raises(ConfigError, match="holds a 4x4 matrix but pose_format.rotation is euler"):
        load_session(d)
    (d / "000_pose.csv").write_text(" ".join(f"{v:.12f}" for v in vendor_line) + "\n")
    np.testing.assert_allclose(load_session(d).views[0].T_base_end, POSES[0], atol=1e-9)
    (d / "000_pose.csv").write_text("1 2 3\n4 5 6\n")
    with pytest.raises(InputError, match="neither one pose line nor a 4x4 matrix"):
        load_session(d)
    for views, match in (
        ("  - {id: a, image: a.png, pose_file: gone.csv}\n", "gone.csv: view a: pose file missing"),
        ("  - {id: a, image: a.png, pose_file: ../x.csv}\n", "view a: pose file '../x.csv' is outside"),
        ("  - {id: a, image: a.png, pose_file: p.csv, pose: [1, 2, 3, 4, 5, 6]}\n", "either pose or pose_file"),
        ("  - {id: a, image: a.png}\n", "either pose or pose_file; expected .* got neither"),
    ):
        with pytest.raises(InputError, match=match):
            load_session(_native_text(tmp_path, views))


def test_pose_format_must_state_the_rotation_kind(tmp_path):
    d = _native_text(tmp_path, "  - {id: a, image: a.png, pose: [0, 0, 0, 0, 0, 0]}\n", fmt="{angle_unit: rad}")
    with pytest.raises(ConfigError, match="pose_format.rotation is missing"):
        load_session(d)
    (d / "session.yaml").write_text((d / "session.yaml").read_text().replace("pose_format: {angle_unit: rad}\n", ""))
    with pytest.raises(ConfigError, match="pose_format is missing.* the vendor's x,y,z,rx,ry,rz lines are"):
        load_session(d)
    # the fields the rotation kind does not state take the documented defaults
    d = _native_text(
        tmp_path, "  - {id: a, image: a.png, pose: [0.1, 0.2, 0.3, 0.1, 0.2, 0.3]}\n", fmt="{rotation: euler}"
    )
    assert load_session(d).pose_format == VENDOR_POSE_FORMAT.describe()


def test_image_paths_stay_inside_the_session_folder_unless_allowed(tmp_path):
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (outside / "e.png").write_bytes(b"x")
    pose = str(sum(_ROWS, []))
    for written in ("../elsewhere/e.png", str(outside / "e.png")):
        d = _native_text(tmp_path, f"  - {{id: a, image: '{written}', pose: {pose}}}\n")
        with pytest.raises(InputError, match="view a: image .* is outside the session folder.* image_folder"):
            load_session(d)
        assert load_session(d, allow_outside=True).views[0].image_path == outside / "e.png"
    # image_folder: images kept elsewhere on purpose; paths relative to it and inside it
    d = _native_text(tmp_path, f"  - {{id: a, image: e.png, pose: {pose}}}\n", extra=f"image_folder: {outside}\n")
    assert load_session(d).views[0].image_path == outside / "e.png"
    d = _native_text(tmp_path, f"  - {{id: a, image: ../nt/a.png, pose: {pose}}}\n", extra=f"image_folder: {outside}\n")
    with pytest.raises(InputError, match="outside"):
        load_session(d)
    # a symbolic link placed in the folder is the user's choice: followed, not refused
    d = _native_text(tmp_path, f"  - {{id: a, image: link.png, pose: {pose}}}\n")
    (d / "link.png").symlink_to(outside / "e.png")
    assert load_session(d).views[0].image_path == d / "link.png"


@pytest.mark.parametrize(
    "intr,match",
    [
        ({"distortion_model": "rational_polynomial"}, "unsupported intrinsics.distortion_model.*8 coefficients"),
        ({"distortion_model": "equidistant"}, "unsupported intrinsics.distortion_model.*fisheye"),
        ({"dist": [0.1, 0.01, 0, 0, 0.001, 0, 0, 0]}, "8 coefficients: ROS's rational_polynomial"),
    ],
)
def test_ros_camera_info_distortion_other_than_plumb_bob_is_refused(tmp_path, intr, match):
    base = {"fx": 900.0, "fy": 900.0, "cx": 640.0, "cy": 360.0, "image_size": [1280, 720]}
    with pytest.raises(ConfigError, match=match):
        load_session(native(tmp_path, extra={"intrinsics": {**base, **intr}}))


def test_ros_camera_info_plumb_bob_d_is_dist_in_the_same_order(tmp_path):
    D = [0.11, -0.22, 0.001, -0.002, 0.05]  # CameraInfo D for distortion_model plumb_bob: k1, k2, t1 (p1), t2 (p2), k3
    intr = {
        "fx": 900.0,
        "fy": 900.0,
        "cx": 640.0,
        "cy": 360.0,
        "image_size": [1280, 720],
        "distortion_model": "plumb_bob",
        "dist": D,
    }
    s = load_session(native(tmp_path, extra={"intrinsics": intr}))
    assert list(s.intrinsics.dist) == D


def test_factory_prior_sigmas_in_the_doc_are_the_refinement_preset():
    import re

    from handeye.config import load_preset

    p = load_preset("refine")["intrinsics_prior"]
    doc = (Path(__file__).resolve().parents[2] / "docs" / "session_format.md").read_text()
    m = re.search(
        r"`use: prior` assumes .*?fx, fy: ([0-9.]+) %.*?cx, cy: ([0-9.]+) % of the image width, height"
        r".*?k1, k2: ([0-9.]+).*?p1, p2: ([0-9.]+).*?k3: ([0-9.]+)",
        doc,
        re.S,
    )
    assert m, "docs/session_format.md states the factory prior's sigmas"
    assert float(m.group(1)) / 100 == p["focal_share"] and float(m.group(2)) / 100 == p["centre_share"]
    d = p["distortion"]
    assert [float(m.group(k)) for k in (3, 4, 5)] == [d[0], d[2], d[4]] and d[0] == d[1] and d[2] == d[3]


def test_joint_angles_are_read_per_view(tmp_path):
    pose = str(sum(_ROWS, []))
    d = _native_text(
        tmp_path,
        f"  - {{id: a, image: a.png, pose: {pose}, joints: [0.1, -1.2, 1.5, 0, 1.57, 3.1]}}\n"
        f"  - {{id: b, image: b.png, pose: {pose}}}\n",
        images="ab",
    )
    s = load_session(d)
    assert s.view("a").joint_angles == (0.1, -1.2, 1.5, 0.0, 1.57, 3.1) and s.view("b").joint_angles is None
    for joints, match in (
        ("[0, 90, 45]", "view a: joint angle 90.0 is larger than 2\\*pi.* degrees"),
        ("[0, x]", "joints must be a list"),
        ("3", "joints must be a list"),
    ):
        d = _native_text(tmp_path, f"  - {{id: a, image: a.png, pose: {pose}, joints: {joints}}}\n")
        with pytest.raises(InputError, match=match):
            load_session(d)


def test_visp_import_names_an_unsupported_target_and_the_layout_it_reads(tmp_path):
    from handeye.session.importers import VISP_LAYOUT, import_visp

    src = tmp_path / "visp"
    src.mkdir()
    (src / "image-1.png").write_bytes(b"x")
    (src / "circles-data.txt").write_text("circle grid\n")
    with pytest.raises(InputError, match=r"unsupported ViSP target 'circles' \(circles-data.txt\)") as e:
        import_visp(src, tmp_path / "out")
    assert "apriltag-data.txt" in str(e.value) and "missing" not in str(e.value)
    (src / "circles-data.txt").unlink()
    with pytest.raises(InputError, match="no ViSP target description"):
        import_visp(src, tmp_path / "out")
    (src / "apriltag-data.txt").write_text("36h11 Apriltag\nsize: 0.048 m\n")
    with pytest.raises(InputError, match="no image shows exactly one 36h11 tag"):  # the image is not one
        import_visp(src, tmp_path / "out")
    (src / "apriltag-data.txt").write_text("Apriltag\nsize: 0.048 m\n")
    with pytest.raises(InputError, match="apriltag-data.txt unreadable"):
        import_visp(src, tmp_path / "out")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "chessboard-data.txt").write_text("9 x 6\nsquare size: 0.0236 m\n")
    with pytest.raises(InputError, match="no ViSP images") as e:
        import_visp(empty, tmp_path / "out")
    assert VISP_LAYOUT in str(e.value)


def test_visp_apriltag_layout_imports_as_a_single_marker_with_its_id(tmp_path):
    """ViSP's eye-to-hand AprilTag layout (apriltag-data.txt, franka_image-N.png, franka_pose_rPe_N.yaml) from a
    rendered single-tag session: the tag id is read from the images, the poses are the reported ones."""
    import cv2

    from handeye.camera import Intrinsics
    from handeye.frames import rotvec_from_R
    from handeye.session import load_session
    from handeye.session.importers import import_visp
    from handeye.sim.vendor import write_vendor_session
    from handeye.targets import MarkerSpec

    small = Intrinsics(fx=460.0, fy=460.0, cx=319.5, cy=239.5, dist=(0.0,) * 5, width=640, height=480)
    sim = write_vendor_session(
        tmp_path / "sim",
        mode="eye_to_hand",
        n_views=4,
        seed=2,
        intrinsics=small,
        target=MarkerSpec(0.048, marker_id=17),
    )
    truth = json.loads((sim / "ground_truth.json").read_text())
    src = tmp_path / "visp"
    src.mkdir()
    (src / "apriltag-data.txt").write_text("36h11 Ariltag\nsize: 0.048 m\n")  # ViSP's own text, typo included
    for vid, v in truth["views"].items():
        cv2.imwrite(str(src / f"franka_image-{vid}.png"), cv2.imread(str(sim / v["image"])))
        T = np.array(v["T_base_end_reported"])
        data = list(T[:3, 3]) + list(rotvec_from_R(T[:3, :3]))
        (src / f"franka_pose_rPe_{vid}.yaml").write_text(
            "rows: 6\ncols: 1\ndata:\n" + "".join(f"  - [{float(x)!r}]\n" for x in data)
        )
    path = import_visp(src, tmp_path / "out")
    s = load_session(path)
    assert s.target == MarkerSpec(0.048, "DICT_APRILTAG_36h11", 17)
    assert s.mode == "eye_to_hand" and s.mode_source == "stated"  # ViSP's AprilTag layout is its eye-to-hand one
    for v in s.views:
        assert np.allclose(v.T_base_end, truth["views"][v.view_id]["T_base_end_reported"], atol=1e-9)


def test_images_from_zero_with_a_header_and_a_gap_name_the_pose_line_by_its_count(tmp_path):
    good = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in POSES]
    d = vendor(tmp_path, lines=["# poses", "x,y,z,rx,ry,rz", *good])
    for k in range(1, 5):
        (d / f"{k}.jpg").rename(d / f"{k - 1}.jpg")
    (d / "1.jpg").unlink()  # the second pose line's image
    s = load_session(d)
    assert [v.view_id for v in s.views] == ["0", "2", "3"]
    assert [v.source_line for v in s.views] == [3, 5, 6]  # lines in the file
    assert s.meta["missing_images"] == {"1": 2}  # pose line 2: the second line with numbers
    np.testing.assert_allclose(s.view("2").T_base_end, POSES[2], atol=1e-8)


@pytest.mark.parametrize(
    "line, fix",
    [
        ("0.1;0.2;0.3;0.01;0.02;0.03", "not semicolons"),
        ("0,1;0,2;0,3;0,01;0,02;0,03", "decimal points, not decimal commas"),
        ("0.1,0.2,0.3,0.01,0.02,0.03 # view 1", "a comment on a line of its own"),
    ],
)
def test_a_malformed_pose_line_says_what_it_likely_holds(tmp_path, line, fix):
    """Semicolons, decimal commas (a European locale's export) and an inline comment: the one-line error names
    the line and the likely cause; before, only 'malformed pose line'."""
    from handeye.session.vendor import read_pose_lines

    (tmp_path / "poses.txt").write_text(line + "\n")
    with pytest.raises(InputError, match="malformed pose line") as e:
        read_pose_lines(tmp_path / "poses.txt")
    assert fix in str(e.value) and "poses.txt:1" in str(e.value)


@pytest.mark.parametrize("sep", ["\t", " ", "  "])
def test_decimal_commas_between_tabs_or_spaces_get_the_decimal_comma_hint(tmp_path, sep):
    """0,692010593<sep>-0,225705741...: commas read as separators made 12 numbers or 692010593.0."""
    from handeye.session.vendor import read_pose_lines

    good = "0.692010593,-0.225705741,0.711254499,3.117997802,-0.221434615,2.250750282"
    line = good.replace(",", sep).replace(".", ",")
    (tmp_path / "poses.txt").write_text(good + "\n" + line + "\n")
    with pytest.raises(InputError) as e:
        read_pose_lines(tmp_path / "poses.txt")
    said = (
        f"{tmp_path / 'poses.txt'}:2: malformed pose line; expected x,y,z,rx,ry,rz (metres, radians); "
        f"got {line[:80]!r} -> write decimal points, not decimal commas (a locale's export), e.g. 0.512 not 0,512"
    )
    assert str(e.value) == " ".join(said.split())  # one line: runs of white space as one space


@pytest.mark.parametrize("line", ["1,0,0,0,0,0", "1 0 0 0 0 0", "1, 0, 0, 0, 0, 0", "1\t0\t0\t3\t0\t0"])
def test_whole_numbers_between_commas_or_spaces_still_read(tmp_path, line):
    from handeye.session.vendor import read_pose_lines

    (tmp_path / "poses.txt").write_text(line + "\n")
    np.testing.assert_array_equal(
        read_pose_lines(tmp_path / "poses.txt")[0].values, [float(v) for v in line.replace(",", " ").split()]
    )
