"""Each exported file parsed back, as its reader would, before it is written.

A file's bytes go through its own language's parser (Python's compiler for launch files, an XML parser
for URDF / xacro / ROS 1 launch files, ``yaml.safe_load``, ``json.loads``) and the transform and frames
read from the parsed content must be the ones meant (:func:`check_files`). A launch file must also be
nothing but its docstrings, its two imports, the provenance constant and ``generate_launch_description``
with one static_transform_publisher node: loading it runs no other code. Whatever fails is one
:class:`ExportCheckError` and no file is written.
"""

from __future__ import annotations

import ast
import json
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..errors import OutputError
from ..frames import R_from_quat_wxyz, make_T

#: largest difference of a matrix element read back from the one meant: the numbers are written as their
#: shortest round-trip text, so a read-back matrix differs only by the rounding of recomposing it from a
#: quaternion or roll-pitch-yaw (~1e-15); 1e-9 (a nanometre, a nanoradian) tells that from any real change
T_TOLERANCE = 1e-9


class ExportCheckError(OutputError):
    """A generated file does not read back as what was meant (nothing was written)."""

    code = "export_check_failed"


@dataclass(frozen=True)
class ReadBack:
    """What a parser found in an exported file: the frames, the transform, and the text fields to compare."""

    parent: str
    child: str
    T_parent_child: np.ndarray
    fields: dict = field(default_factory=dict)


class _Bad(Exception):
    """Inside this module: the file's content is not what a writer of this module writes."""


def _rpy_R(r: float, p: float, y: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _T_xyzw(t, q_xyzw) -> np.ndarray:
    x, y, z, w = (float(v) for v in q_xyzw)
    return make_T(R_from_quat_wxyz(np.array([w, x, y, z])), np.array([float(v) for v in t]))


def _floats(text: Optional[str], n: int) -> list[float]:
    vals = [float(v) for v in str(text).split()]
    if len(vals) != n:
        raise _Bad(f"expected {n} numbers, got {text!r}")
    return vals


# ---------------------------------------------------------------- Python launch files


def _launch_py(data: bytes) -> list[ReadBack]:
    """A ROS 2 launch file: compiled from its bytes (as ``ros2 launch`` loads it, encoding line included)."""
    from .writers import PROVENANCE_NAME

    tree = compile(data, "<launch file>", "exec", flags=ast.PyCF_ONLY_AST, dont_inherit=True)
    assert isinstance(tree, ast.Module), "compile with PyCF_ONLY_AST returns a module"
    compile(tree, "<launch file>", "exec", dont_inherit=True)  # what the parser lets through, the compiler may not
    fields: dict = {}
    funcs: list[ast.FunctionDef] = []
    imports = set()
    for stmt in tree.body:
        if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant) and isinstance(stmt.value.value, str):
            continue  # a docstring
        if isinstance(stmt, ast.ImportFrom) and stmt.level == 0:
            imports.add((stmt.module, tuple((a.name, a.asname) for a in stmt.names)))
            continue
        if (
            isinstance(stmt, ast.Assign)
            and len(stmt.targets) == 1
            and isinstance(stmt.targets[0], ast.Name)
            and stmt.targets[0].id == PROVENANCE_NAME
            and PROVENANCE_NAME not in fields
        ):
            fields[stmt.targets[0].id] = ast.literal_eval(stmt.value)
            continue
        if isinstance(stmt, ast.FunctionDef) and stmt.name == "generate_launch_description" and not funcs:
            funcs.append(stmt)
            continue
        raise _Bad(f"unexpected statement at line {stmt.lineno}: {ast.dump(stmt)[:80]}")
    if imports != {("launch", (("LaunchDescription", None),)), ("launch_ros.actions", (("Node", None),))}:
        raise _Bad(f"imports {sorted(imports)}")
    if not funcs:
        raise _Bad("no generate_launch_description")
    (fn,) = funcs
    a = fn.args
    if fn.decorator_list or a.args or a.posonlyargs or a.kwonlyargs or a.vararg or a.kwarg:
        raise _Bad("generate_launch_description has decorators or arguments")
    # the body: nodes = [Node(...)]; return LaunchDescription(nodes); the return annotation names the import
    if len(fn.body) != 2:
        raise _Bad("generate_launch_description is not two statements")
    assign, ret = fn.body
    if not (
        isinstance(assign, ast.Assign)
        and [ast.dump(t) for t in assign.targets] == [ast.dump(ast.Name("nodes", ast.Store()))]
        and isinstance(assign.value, ast.List)
        and assign.value.elts
    ):
        raise _Bad("no nodes = [Node(...), ...]")
    want_ret = ast.Return(ast.Call(ast.Name("LaunchDescription", ast.Load()), [ast.Name("nodes", ast.Load())], []))
    if ast.dump(ret) != ast.dump(want_ret):
        raise _Bad("the return statement")
    if fn.returns is not None and ast.dump(fn.returns) != ast.dump(ast.Name("LaunchDescription", ast.Load())):
        raise _Bad("the return annotation")
    return [_stp_node(call, fields) for call in assign.value.elts]


def _stp_node(call: ast.expr, fields: dict) -> ReadBack:
    """One ``Node(...)`` of a launch file: a static_transform_publisher whose keywords are literals."""
    if not (
        isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == "Node" and not call.args
    ):
        raise _Bad("the node is not Node(keyword=...)")
    kw = {}
    for k in call.keywords:
        if k.arg is None or k.arg in kw:
            raise _Bad("Node's keywords")
        kw[k.arg] = ast.literal_eval(k.value)  # literals only: no call, no name
    if (kw.get("package"), kw.get("executable")) != ("tf2_ros", "static_transform_publisher"):
        raise _Bad(f"the node runs {kw.get('package')!r} {kw.get('executable')!r}")
    args = kw.get("arguments")
    if not isinstance(args, list) or len(args) % 2 or not all(isinstance(v, str) for v in args):
        raise _Bad("static_transform_publisher's arguments are not flag, value pairs")
    opts = dict(zip(args[::2], args[1::2], strict=True))
    if len(opts) != len(args) // 2 or set(opts) != {
        "--frame-id",
        "--child-frame-id",
        "--x",
        "--y",
        "--z",
        "--qx",
        "--qy",
        "--qz",
        "--qw",
    }:
        raise _Bad(f"static_transform_publisher's flags {sorted(opts)}")
    T = _T_xyzw([opts[k] for k in ("--x", "--y", "--z")], [opts[k] for k in ("--qx", "--qy", "--qz", "--qw")])
    return ReadBack(opts["--frame-id"], opts["--child-frame-id"], T, {**fields, "node_name": kw.get("name")})


# ---------------------------------------------------------------- XML


def _xml_root(data: bytes) -> ET.Element:
    return ET.fromstring(data)


def _origin_T(joint: ET.Element) -> np.ndarray:
    origin = _one(joint, "origin")
    return make_T(_rpy_R(*_floats(origin.get("rpy"), 3)), np.asarray(_floats(origin.get("xyz"), 3), float))


def _one(parent: ET.Element, tag: str) -> ET.Element:
    found = parent.findall(tag)
    if len(found) != 1:
        raise _Bad(f"{len(found)} <{tag}> in <{parent.tag}>")
    return found[0]


def _urdf(data: bytes) -> list[ReadBack]:
    """A URDF of fixed joints: its links are the joints' parents (each once) then their children."""
    root = _xml_root(data)
    if root.tag != "robot":
        raise _Bad(f"root <{root.tag}>")
    links = [link.get("name") for link in root.findall("link")]
    joints = root.findall("joint")
    if not joints or len(root) != len(links) + len(joints):
        raise _Bad(f"{len(joints)} <joint> among {len(root)} elements")
    ends = [(_one(j, "parent").get("link"), _one(j, "child").get("link")) for j in joints]
    want = list(dict.fromkeys(p for p, _ in ends)) + [c for _, c in ends]
    if any(j.get("type") != "fixed" for j in joints) or links != want or len(set(want)) != len(want):
        raise _Bad(f"links {links}, joints {ends}")
    return [
        ReadBack(str(p), str(c), _origin_T(j), {"joint_name": j.get("name")})
        for j, (p, c) in zip(joints, ends, strict=True)
    ]


def _xacro(data: bytes) -> list[ReadBack]:
    """Xacro macros of one fixed joint each (``handeye_camera_joint``, a cell's ``handeye_camera_joint_<camera>``)."""
    from .writers import XACRO_MACRO, XACRO_NS

    root = _xml_root(data)
    macros = root.findall(f"{{{XACRO_NS}}}macro")
    if root.tag != "robot" or not macros or len(root) != len(macros):
        raise _Bad(f"root <{root.tag}> with {len(root)} elements, {len(macros)} macros")
    out = []
    for macro in macros:
        params = dict(p.split(":=", 1) for p in (macro.get("params") or "").split() if ":=" in p)
        name = str(macro.get("name"))
        own = name == XACRO_MACRO if len(macros) == 1 else name.startswith(XACRO_MACRO + "_")
        if not own or set(params) != {"parent", "child"}:
            raise _Bad(f"macro {name!r} params {macro.get('params')!r}")
        joint = _one(macro, "joint")
        refs = (joint.get("name"), _one(joint, "parent").get("link"), _one(joint, "child").get("link"))
        if refs != ("${parent}_to_${child}", "${parent}", "${child}") or joint.get("type") != "fixed":
            raise _Bad(f"the joint {refs}")
        out.append(ReadBack(params["parent"], params["child"], _origin_T(joint), {"macro": name}))
    return out


def _ros1_launch(data: bytes) -> list[ReadBack]:
    root = _xml_root(data)
    if root.tag != "launch":
        raise _Bad(f"root <{root.tag}>")
    node = _one(root, "node")
    if (node.get("pkg"), node.get("type")) != ("tf2_ros", "static_transform_publisher"):
        raise _Bad(f"the node runs {node.get('pkg')!r} {node.get('type')!r}")
    a = (node.get("args") or "").split()
    if len(a) != 9:
        raise _Bad(f"args {node.get('args')!r}")
    return [ReadBack(a[7], a[8], _T_xyzw(a[:3], a[3:7]))]


# ---------------------------------------------------------------- YAML, JSON


def _yaml(data: bytes):
    import yaml

    return yaml.safe_load(data)


def _xyz_xyzw(tr: dict) -> np.ndarray:
    t, q = tr["translation"], tr["rotation"]
    return _T_xyzw([t["x"], t["y"], t["z"]], [q["x"], q["y"], q["z"], q["w"]])


def _tf_static(data: bytes) -> list[ReadBack]:
    trs = _yaml(data)["transforms"]
    if not isinstance(trs, list) or not trs:
        raise _Bad("no transforms")
    return [ReadBack(tr["header"]["frame_id"], tr["child_frame_id"], _xyz_xyzw(tr["transform"])) for tr in trs]


def _calib(data: bytes) -> list[ReadBack]:
    d = _yaml(data)
    p = d["parameters"]
    parent = p["robot_effector_frame"] if p["calibration_type"] == "eye_in_hand" else p["robot_base_frame"]
    return [ReadBack(parent, p["tracking_base_frame"], _xyz_xyzw(d["transform"]), dict(p))]


def _plain(d: dict) -> ReadBack:
    T = np.asarray(d["matrix"], float)
    if T.shape != (4, 4):
        raise _Bad(f"matrix of shape {T.shape}")
    others = [
        _T_xyzw(d["translation_m"], d["quaternion_xyzw"]),
        make_T(_rpy_R(*(float(v) for v in d["rpy_rad"])), np.asarray(d["translation_m"], float)),
    ]
    for T_other in others:  # the file agrees with itself
        if not np.max(np.abs(T_other - T)) <= T_TOLERANCE:
            raise _Bad("its matrix, quaternion and rpy differ")
    keep = ("mode", "verdict", "source", "camera_frame", "result_name", "camera")
    return ReadBack(d["parent_frame"], d["child_frame"], T, {k: d.get(k) for k in keep})


def _plain_all(d: dict) -> list[ReadBack]:
    """A plain export: one transform, or a cell's (``kind: cell``, ``cameras``: name -> one transform)."""
    if d.get("kind") != "cell":
        return [_plain(d)]
    cams = d["cameras"]
    if not isinstance(cams, dict) or not cams:
        raise _Bad("a cell without cameras")
    return [_plain(c) for c in cams.values()]


def _plain_yaml(data: bytes) -> list[ReadBack]:
    return _plain_all(_yaml(data))


def _plain_json(data: bytes) -> list[ReadBack]:
    return _plain_all(json.loads(data))


#: file kind -> its reader
READERS = {
    "launch.py": _launch_py,
    "ros1_launch": _ros1_launch,
    "urdf": _urdf,
    "xacro": _xacro,
    "tf_static": _tf_static,
    "calib": _calib,
    "plain_yaml": _plain_yaml,
    "plain_json": _plain_json,
}


def read_back(kind: str, data: bytes, *, name: str = "the file") -> ReadBack:
    """Parse ``data`` as a file of ``kind`` (:data:`READERS`) and read the one transform it holds.

    Raises :class:`ExportCheckError` naming ``name`` when it does not parse or holds something else.
    """
    got = read_back_all(kind, data, name=name)
    if len(got) != 1:
        raise _error(name, f"holds {len(got)} transforms, not one")
    return got[0]


def read_back_all(kind: str, data: bytes, *, name: str = "the file") -> list[ReadBack]:
    """Parse ``data`` as a file of ``kind`` (:data:`READERS`) and read every transform it holds, in order.

    A cell's file holds one per camera. Raises :class:`ExportCheckError` naming ``name`` when it does not parse.
    """
    import yaml

    try:
        return READERS[kind](data)
    except (_Bad, SyntaxError, ValueError, TypeError, KeyError, IndexError, ET.ParseError, yaml.YAMLError) as e:
        raise _error(name, f"does not read back as a {kind} file ({type(e).__name__}: {e})") from e


def _error(name: str, what: str) -> ExportCheckError:
    return ExportCheckError(
        f"the generated {name} {what}; nothing was written",
        hint="this is a bug of handeye export: report it with the result file",
    )


def check(got: ReadBack, *, parent: str, child: str, T_parent_child: np.ndarray, fields=None, name: str) -> None:
    """``got`` holds ``parent -> child`` with ``T_parent_child`` (to :data:`T_TOLERANCE`) and ``fields``."""
    if (got.parent, got.child) != (parent, child):
        raise _error(name, f"names {got.parent!r} -> {got.child!r}, not {parent!r} -> {child!r}")
    diff = np.max(np.abs(np.asarray(got.T_parent_child, float) - np.asarray(T_parent_child, float)))
    if not diff <= T_TOLERANCE:
        raise _error(name, f"holds a transform {diff:.3g} away from the calibration's")
    for k, v in (fields or {}).items():
        if got.fields.get(k) != v:
            raise _error(name, f"holds {k} {got.fields.get(k)!r}, not {v!r}")


def check_all(got: list[ReadBack], want: list[tuple], *, name: str) -> None:
    """``got`` holds, in order, each ``(parent, child, T_parent_child, fields)`` of ``want`` and nothing else."""
    if len(got) != len(want):
        raise _error(name, f"holds {len(got)} transforms, not {len(want)}")
    for g, (parent, child, T, fields) in zip(got, want, strict=True):
        check(g, parent=parent, child=child, T_parent_child=T, fields=fields, name=name)
