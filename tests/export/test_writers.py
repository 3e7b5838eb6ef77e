"""The writers are safe whatever text the result holds: hostile paths, modes and verdicts reach each file
escaped for its language (a launch file loaded runs nothing else, every XML file is well-formed, no YAML
key appears from a comment), each file reads back with its own parser, and frame names are one checked set.
"""

from __future__ import annotations

import ast
import sys
import types
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye.errors import InputError
from handeye.export import writers as w
from handeye.export.frames import ExportTransform, check_frame_name
from handeye.export.readback import ExportCheckError, check, read_back
from handeye.frames import se3_exp

PWN = '\nopen("PWNED","w").write("x")\n#'
#: text that breaks out of a comment, a string or a docstring in one of the languages written
HOSTILE = [
    PWN,
    'x"""\nopen("PWNED","w").write("x")\n"""',
    "x'''\nopen('PWNED','w').write('x')\n'''",
    '\r__import__("os").system("touch PWNED")',
    "\x85open('PWNED','w')",  # NEL: a line break for YAML
    "\u2028key: injected",  # LINE SEPARATOR: a line break for YAML
    "\u2029key: injected",
    "--> <x/> <!--",
    "a---b-",
    "-",
    "\x00\x01\x1b[31m",
    "\udc80not utf-8",  # a lone surrogate: what Python makes of an undecodable file name byte
    "\ufeffBOM",
    "# -*- coding: utf-7 -*-",
    "]]> &amp; ${x} $(find pkg)",
    "\\",
]


def _transform(text: str, *, mode="eye_in_hand", child="camera_color_optical_frame") -> ExportTransform:
    A = np.random.default_rng(1).normal(size=(6, 6)) * 1e-4
    return ExportTransform(
        parent="tool0",
        child=child,
        T_parent_child=se3_exp(np.array([0.1, -0.2, 0.3, 0.05, -0.04, 0.2])),
        camera_frame="optical",
        mode=mode,
        x_name="T_end_cam" + text,
        cov_6x6=A @ A.T,
        cov_source="cov_x_6x6" + text,
        source="/data/s" + text + "/result.json",
        verdict="PASS" + text,
    )


def _stub_launch_modules(monkeypatch):
    """Stand-ins for ROS 2's launch and launch_ros (absent here): a Node records its keywords."""
    launch = types.ModuleType("launch")
    launch.LaunchDescription = lambda entities: list(entities)
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")
    actions.Node = lambda **kw: kw
    launch_ros.actions = actions
    for name, mod in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, mod)


def _load_launch(data: bytes, tmp_path, monkeypatch) -> list:
    """Load the launch file as ``ros2 launch`` does (its module body from its bytes, then
    generate_launch_description) in an empty working folder; nothing else may appear there.
    """
    _stub_launch_modules(monkeypatch)
    cwd = tmp_path / "cwd"
    cwd.mkdir(parents=True)
    monkeypatch.chdir(cwd)
    ns: dict = {}
    exec(compile(data, "hand_eye.launch.py", "exec", dont_inherit=True), ns)
    nodes = ns["generate_launch_description"]()
    assert list(cwd.iterdir()) == []  # no PWNED
    return nodes


@pytest.mark.parametrize("text", HOSTILE, ids=range(len(HOSTILE)))
@pytest.mark.parametrize("moveit_layout", [False, True])
def test_a_launch_file_runs_nothing_but_its_node_whatever_the_result_says(tmp_path, monkeypatch, text, moveit_layout):
    e = _transform(text)
    data = w.ros2_launch(e, moveit_layout=moveit_layout).encode("utf-8")
    tree = ast.parse(data)  # bytes: an encoding line would count, as it does for ros2 launch
    assert [type(s).__name__ for s in tree.body][-4:] == ["ImportFrom", "ImportFrom", "Assign", "FunctionDef"]
    (node,) = _load_launch(data, tmp_path, monkeypatch)
    assert node["arguments"][:4] == ["--frame-id", "tool0", "--child-frame-id", "camera_color_optical_frame"]
    ns: dict = {}
    _stub_launch_modules(monkeypatch)
    exec(compile(data, "f", "exec"), ns)
    # the outside text comes back exactly from the provenance constant, escaped in the comments
    assert ns[w.PROVENANCE_NAME] == w.provenance_constant(e)
    assert ns[w.PROVENANCE_NAME]["source"] == "/data/s" + text + "/result.json"
    assert data.decode("utf-8").splitlines()[1] in (
        "# written by handeye " + w.__version__,
        '""" EYE-IN-HAND: tool0 -> camera_color_optical_frame """',
    )
    got = read_back("launch.py", data)
    check(got, parent="tool0", child="camera_color_optical_frame", T_parent_child=e.T_parent_child, name="f")


@pytest.mark.parametrize("text", HOSTILE, ids=range(len(HOSTILE)))
def test_a_hostile_mode_reaches_no_encoding_line(tmp_path, monkeypatch, text):
    """The mode is in a launch file's first lines: as a literal, never as a comment Python would read as the
    file's encoding (``# -*- coding: utf-7 -*-`` turns ``+AAo-`` into a newline)."""
    import re

    e = _transform("", mode=text + "+AAo-open('PWNED','w')")
    for moveit_layout in (False, True):
        data = w.ros2_launch(e, moveit_layout=moveit_layout).encode("utf-8")
        assert not any(re.match(rb"^[ \t\f]*#.*?coding[:=]", line) for line in data.splitlines()[:2])
        (node,) = _load_launch(data, tmp_path / str(moveit_layout), monkeypatch)
        assert node["arguments"][1] == "tool0"


@pytest.mark.parametrize("text", HOSTILE, ids=range(len(HOSTILE)))
def test_xml_files_are_well_formed_and_hold_only_their_elements(text):
    e = _transform(text, child="cam---x_optical_frame")
    for kind, data in (("urdf", w.urdf(e)), ("xacro", w.xacro(e)), ("ros1_launch", w.moveit1_launch(e))):
        root = ET.fromstring(data.encode("utf-8"))
        tags = sorted({el.tag for el in root.iter() if isinstance(el.tag, str)})
        assert (
            tags
            == {
                "urdf": ["child", "joint", "link", "origin", "parent", "robot"],
                "xacro": ["child", "joint", "origin", "parent", "robot", "{http://www.ros.org/wiki/xacro}macro"],
                "ros1_launch": ["launch", "node"],
            }[kind]
        )
        got = read_back(kind, data.encode("utf-8"))
        check(got, parent="tool0", child="cam---x_optical_frame", T_parent_child=e.T_parent_child, name=kind)


@pytest.mark.parametrize("text", HOSTILE, ids=range(len(HOSTILE)))
def test_yaml_files_gain_no_key_from_a_comment(text):
    e = _transform(text)
    for kind, data, keys in (
        ("tf_static", w.tf_static_yaml(e), {"transforms"}),
        ("calib", w.easy_handeye2_calib(e, name="hand_eye" + text, base="base_link", effector="tool0"), None),
        ("plain_yaml", w.plain_yaml(e), None),
    ):
        d = yaml.safe_load(data.encode("utf-8"))
        assert set(d) == (keys or ({"parameters", "transform"} if kind == "calib" else set(w.plain_dict(e))))
        got = read_back(kind, data.encode("utf-8"))
        check(got, parent="tool0", child="camera_color_optical_frame", T_parent_child=e.T_parent_child, name=kind)
        if kind == "calib":
            assert d["parameters"]["name"] == "hand_eye" + text
        if kind == "plain_yaml":
            assert (d["verdict"], d["source"]) == (e.verdict, e.source)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.text(), min_size=1, max_size=4))
def test_comment_lines_stay_lines_in_every_language(lines):
    text = w.comment(lines)
    assert len(text.split("\n")) == len(lines) and all(s.isprintable() for s in text.split("\n"))
    assert yaml.safe_load(text.encode("utf-8")) is None  # comments only
    # after two lines of code, as in a launch file (Python reads an encoding declaration in lines 1-2 only)
    assert [type(b).__name__ for b in ast.parse(("pass\npass\n" + text).encode("utf-8")).body] == ["Pass", "Pass"]
    xml = ET.tostring(w.xml_comment(lines), encoding="unicode")
    inner = xml[len("<!--") : -len("-->")]
    assert "--" not in inner and not inner.endswith("-")
    assert ET.fromstring(f"<r>{xml}</r>".encode()).tag == "r"


@settings(max_examples=300, deadline=None)
@given(st.text())
def test_a_docstring_literal_is_its_text(text):
    (stmt,) = ast.parse(w.py_docstring(text)).body
    assert stmt.value.value.strip(" ") == text.strip(" ") and "\n" not in w.py_docstring(text)


@pytest.mark.parametrize(
    "name", ["tool0", "camera_color_optical_frame", "cam---x_optical_frame", "arm/tool0", "_a.b-c"]
)
def test_frame_names_tf2_takes_are_accepted(name):
    assert check_frame_name(name, "--child") == name


@pytest.mark.parametrize(
    "name", ["", "my cam", "-x", "/world", "a$b", "a{b}", "a:=b", "caméra", "a\nb", 'a"b', "a<b", "a&b", "a\x00", None]
)
def test_other_frame_names_are_refused(name):
    with pytest.raises(InputError) as err:
        check_frame_name(name, "--base-frame")
    assert f"--base-frame {name!r} is not a TF frame name" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(InputError):
        _transform("", child=name)


def test_a_file_that_reads_back_otherwise_is_refused():
    e = _transform("")
    text = w.ros2_launch(e)
    for bad, says in (
        (text + "\nimport os\n", "unexpected statement"),
        (text + "\nNode = print\n", "unexpected statement"),
        (text.replace('"--qw",\n                "', '"--qw",\n                "2'), "away from the calibration"),
        (text.replace("def generate_launch_description()", "@print\ndef generate_launch_description()"), "decorators"),
        (text.replace('package="tf2_ros"', 'package=__import__("os").getcwd()'), "ValueError"),
    ):
        with pytest.raises(ExportCheckError) as err:
            check(
                read_back("launch.py", bad.encode()),
                parent="tool0",
                child=e.child,
                T_parent_child=e.T_parent_child,
                name="x.launch.py",
            )
        assert says in str(err.value) and "nothing was written" in str(err.value)
    broken = w.urdf(e).replace("<!--", "<!-- a -- b")
    with pytest.raises(ExportCheckError, match="does not read back as a urdf file"):
        read_back("urdf", broken.encode())
    with pytest.raises(ExportCheckError, match="names 'tool0' -> 'camera_color_optical_frame', not 'base_link'"):
        check(
            read_back("urdf", w.urdf(e).encode()),
            parent="base_link",
            child=e.child,
            T_parent_child=e.T_parent_child,
            name="u",
        )
