"""Bad input, class "native sessions": session.yaml fields of the wrong type or value, view records
and pose files. Each case: exit code 2 and the error names session.yaml (or the record) and the field."""

from __future__ import annotations

import pytest
import yaml


def _top(**kw):
    return lambda d: d.update(kw)


def _view(k, **kw):
    return lambda d: d["views"][k].update(kw)


def _intr(**kw):
    base = {"fx": 400.0, "fy": 400.0, "cx": 200.0, "cy": 150.0, "dist": [0, 0, 0, 0, 0], "image_size": [400, 300]}
    return lambda d: d.update(intrinsics={**base, **kw})


def _target(**kw):
    return lambda d: d["target"].update(kw)


def _drop(key):
    return lambda d: d.pop(key)


# (edit of the parsed session.yaml, culprits)
CASES = [
    pytest.param(_view(2, t_image="yesterday"), ["view 3", "t_image", "'yesterday'"], id="t_image_text"),
    pytest.param(_view(2, t_pose=[1, 2]), ["view 3", "t_pose"], id="t_pose_list"),
    pytest.param(_view(2, t_image=True), ["view 3", "t_image"], id="t_image_bool"),
    pytest.param(_intr(dist=[[0, 0], [0]]), ["intrinsics.dist", "[[0, 0], [0]]"], id="dist_ragged"),
    pytest.param(_intr(dist="none"), ["intrinsics.dist", "'none'"], id="dist_none_text"),
    pytest.param(_intr(dist=[0, 0, 0]), ["intrinsics.dist"], id="dist_three"),
    pytest.param(_intr(dist=[0, 0, 0, 0, float("nan")]), ["intrinsics.dist"], id="dist_nan"),
    pytest.param(_intr(dist=[0] * 8), ["intrinsics.dist", "rational_polynomial"], id="dist_eight"),
    pytest.param(_intr(fx="big"), ["intrinsics.fx", "'big'"], id="fx_text"),
    pytest.param(_intr(fx=-400), ["intrinsics.fx"], id="fx_negative"),
    pytest.param(_intr(image_size=[400]), ["intrinsics.image_size"], id="image_size_one"),
    pytest.param(_intr(image_size=[400.5, 300]), ["intrinsics.image_size[0]"], id="image_size_fraction"),
    pytest.param(_intr(use="sometimes"), ["intrinsics.use", "'sometimes'"], id="use_unknown"),
    pytest.param(_intr(model="fisheye"), ["intrinsics model", "'fisheye'"], id="model_unknown"),
    pytest.param(_top(intrinsics=[1, 2]), ["intrinsics must be a mapping"], id="intrinsics_list"),
    pytest.param(_top(mode="hand_in_eye"), ["mode", "'hand_in_eye'"], id="mode_unknown"),
    pytest.param(_top(handeye_session=2), ["handeye_session version"], id="version"),
    pytest.param(_drop("pose_format"), ["pose_format is missing"], id="no_pose_format"),
    pytest.param(_top(pose_format="euler"), ["pose_format must be a mapping"], id="pose_format_text"),
    pytest.param(lambda d: d["pose_format"].update(colour="red"), ["pose_format field 'colour'"], id="pose_format_key"),
    pytest.param(lambda d: d["pose_format"].pop("rotation"), ["pose_format.rotation"], id="no_rotation"),
    pytest.param(lambda d: d["pose_format"].update(angle_unit="grad"), ["grad"], id="angle_unit"),
    pytest.param(_drop("target"), ["target is missing"], id="no_target"),
    pytest.param(_target(type="hexboard"), ["unknown target type", "'hexboard'"], id="target_type"),
    pytest.param(
        _target(inner_corners=[100000, 100000]), ["target.inner_corners", "10000000000 points"], id="board_100000"
    ),
    pytest.param(_target(inner_corners=[11]), ["target.inner_corners"], id="corners_one"),
    pytest.param(_target(inner_corners=["a", 8]), ["target.inner_corners[0]"], id="corners_text"),
    pytest.param(_target(square_m=30), ["target.square_m", "millimetres"], id="square_mm"),
    pytest.param(_target(square_m="0.03m"), ["target.square_m"], id="square_text"),
    pytest.param(_top(views=5), ["views must be a list"], id="views_number"),
    pytest.param(_top(views=[]), ["no views"], id="views_empty"),
    pytest.param(lambda d: d["views"].append("view 6"), ["each view must be a mapping"], id="view_text"),
    pytest.param(lambda d: d["views"][1].pop("id"), ["missing 'id'"], id="view_no_id"),
    pytest.param(_view(1, id=""), ["invalid view id"], id="view_empty_id"),
    pytest.param(_view(1, id="1"), ["duplicate view id '1'"], id="duplicate_id"),
    pytest.param(lambda d: d["views"][1].pop("image"), ["missing 'image'"], id="view_no_image"),
    pytest.param(lambda d: d["views"][1].pop("pose"), ["view 2", "pose or pose_file"], id="view_no_pose"),
    pytest.param(_view(1, pose_file="p.txt"), ["view 2", "both"], id="pose_and_file"),
    pytest.param(_view(1, pose=[0.1, 0.2]), ["view 2", "bad pose"], id="pose_short"),
    pytest.param(_view(1, pose="0.1,0.2,0.3,0,0,0"), ["view 2", "list of numbers"], id="pose_text"),
    pytest.param(_view(1, pose=[0.1, 0.2, 0.3, 0, 0, "x"]), ["view 2", "numbers"], id="pose_letter"),
    pytest.param(_view(1, pose=[0.1, 0.2, 0.3, 0, 0, True]), ["view 2", "numbers"], id="pose_bool"),
    pytest.param(_view(1, pose=[0.1, 0.2, 1e308, 0, 0, 0]), ["view 2", "1e+308"], id="pose_1e308"),
    pytest.param(_view(1, pose=[0.1, float("nan"), 0.3, 0, 0, 0]), ["view 2", "nan"], id="pose_nan"),
    pytest.param(_view(1, pose=[[1, 0, 0, 0]] * 4), ["view 2", "4x4"], id="pose_matrix_in_euler"),
    pytest.param(_view(1, joints="home"), ["view 2", "joints"], id="joints_text"),
    pytest.param(_view(1, joints=[0, 0, 90, 0, 0, 0]), ["view 2", "joint angle"], id="joints_degrees"),
    pytest.param(
        _top(view_records="../../../../etc"), ["view_records", "outside the session folder"], id="records_outside"
    ),
    pytest.param(_top(view_records=7), ["view_records must be a folder name"], id="records_number"),
    pytest.param(_top(image_folder=3), ["image_folder"], id="image_folder_number"),
]


@pytest.mark.parametrize("edit, culprits", CASES)
def test_session_yaml(edit, culprits, tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_native)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    edit(doc)
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2, err
    names(err, "session.yaml", *culprits)


# (pose file text, culprits) for view 2 given as pose_file: p2.txt
POSE_FILES = [
    pytest.param("", ["view 2", "neither one pose line nor a 4x4"], id="empty"),
    pytest.param("1 2 3\n4 5 6\n", ["view 2", "neither"], id="two_lines"),
    pytest.param("a b c d e f\n", ["view 2", "not numbers"], id="letters"),
    pytest.param("0.1 0.2 nan 0 0 0\n", ["view 2", "nan"], id="nan"),
    pytest.param("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", ["view 2", "4x4 matrix", "rotation"], id="matrix_in_euler"),
    pytest.param(b"\x00\x01" * 40, ["p2.txt", "UTF-16"], id="binary"),
]


@pytest.mark.parametrize("text, culprits", POSE_FILES)
def test_pose_file(text, culprits, tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_native)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    doc["views"][1].pop("pose")
    doc["views"][1]["pose_file"] = "p2.txt"
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    (s / "p2.txt").write_bytes(text if isinstance(text, bytes) else text.encode())
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2, err
    names(err, "p2.txt", *culprits)


@pytest.mark.parametrize(
    "pose_file, culprits",
    [
        pytest.param("../../../etc/hostname", ["outside the session folder"], id="outside"),
        pytest.param("missing.txt", ["pose file missing"], id="missing"),
        pytest.param(".", ["not a regular file"], id="folder"),
    ],
)
def test_pose_file_path(pose_file, culprits, tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_native)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    doc["views"][1].pop("pose")
    doc["views"][1]["pose_file"] = pose_file
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2, err
    names(err, "view 2", *culprits)


def test_view_record_that_is_not_a_mapping(tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path):
    s = copy_session(tiny_native)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    doc["view_records"] = "view_records"
    (s / "view_records").mkdir()
    (s / "view_records" / "006.yaml").write_text("- just\n- a list\n")
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2
    names(err, "006.yaml", "mapping")


_VALUES = __import__("hypothesis.strategies", fromlist=["x"])
_FIELDS = [
    ("view", "t_image"),
    ("view", "t_pose"),
    ("view", "pose"),
    ("view", "joints"),
    ("view", "id"),
    ("view", "image"),
    ("top", "mode"),
    ("top", "pose_format"),
    ("top", "intrinsics"),
    ("top", "target"),
    ("top", "image_folder"),
    ("top", "view_records"),
    ("top", "views"),
    ("target", "inner_corners"),
    ("target", "square_m"),
    ("target", "type"),
    ("pose_format", "rotation"),
    ("pose_format", "angle_unit"),
    ("pose_format", "euler_order"),
    ("intrinsics", "fx"),
    ("intrinsics", "dist"),
    ("intrinsics", "image_size"),
    ("intrinsics", "use"),
]


def _yaml_values():
    st = _VALUES
    scalar = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(-(10**12), 10**12),
        st.floats(allow_nan=True),
        st.text(max_size=12),
        st.sampled_from(["1e308", ".nan", "010", "eye_in_hand", "-1"]),
    )
    return st.recursive(
        scalar,
        lambda inner: st.one_of(st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
        max_leaves=12,
    )


@__import__("hypothesis").settings(
    max_examples=150, deadline=None, suppress_health_check=list(__import__("hypothesis").HealthCheck)
)
@__import__("hypothesis").given(field=_VALUES.sampled_from(_FIELDS), value=_yaml_values())
def test_any_value_in_any_field_loads_or_is_one_named_line(field, value, tiny_native, tmp_path_factory):
    """Property: session.yaml with any YAML value in one of its fields loads, or raises one HandeyeError
    line naming session.yaml; never another exception."""
    from handeye.errors import HandeyeError
    from handeye.session import load_session

    s = tmp_path_factory.mktemp("fuzz")
    for f in tiny_native.iterdir():
        (s / f.name).symlink_to(f)
    doc = yaml.safe_load((tiny_native / "session.yaml").read_text())
    doc["intrinsics"] = {
        "fx": 400.0,
        "fy": 400.0,
        "cx": 200.0,
        "cy": 150.0,
        "dist": [0, 0, 0, 0, 0],
        "image_size": [400, 300],
        "use": "initial",
    }
    where, key = field
    holder = {
        "top": doc,
        "view": doc["views"][1],
        "target": doc["target"],
        "pose_format": doc["pose_format"],
        "intrinsics": doc["intrinsics"],
    }[where]
    holder[key] = value
    (s / "session.yaml").unlink()
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    try:
        load_session(s)
    except HandeyeError as e:
        assert "\n" not in str(e) and str(e)
