"""The text of each export format, from one :class:`~handeye.export.frames.ExportTransform`.

Formats: ``ros2`` (launch file and tf2 YAML), ``urdf`` (URDF and xacro macro), ``moveit`` (MoveIt
Calibration's launch files), ``easy_handeye2`` (its ``.calib``), ``yaml`` / ``json``. Every file
states its frames (parent -> child), the camera frame, the quaternion order, the rpy convention, the
1-sigma uncertainty and its provenance; numbers are written with Python's round-trip ``repr``.

Text from outside (paths, modes, verdicts, names) is written in each language's own escaping, and
:mod:`.readback` parses every file back before it is written. See docs/export.md.
"""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET

import numpy as np

from .. import __version__
from .frames import CAMERA_FRAME_TEXT, DEFAULT_FRAMES, RPY_TEXT, ExportTransform


def num(x) -> str:
    """A float as its shortest round-trip text."""
    return repr(float(x))


def text_line(s) -> str:
    r"""``s`` as one line of printable text, for a comment.

    Each character ``str.isprintable`` refuses (control characters, line and paragraph separators, NEL,
    BOM, lone surrogates) becomes its escape ``\xNN`` / ``\uNNNN``. Safe in a comment of Python, YAML
    and XML: nothing in it can end the comment's line.
    """
    out = []
    for c in str(s):
        if c.isprintable():
            out.append(c)
        else:
            o = ord(c)
            out.append(f"\\x{o:02x}" if o < 0x100 else f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}")
    return "".join(out)


def xml_comment(lines) -> ET.Element:
    r"""An XML comment holding ``lines``, each through :func:`text_line`.

    A run of ``-`` keeps its first and writes the others as ``\x2d`` (XML comments may not hold ``--``),
    and the text ends in a newline (never in the ``-`` a comment may not end with).
    """
    body = [re.sub(r"-{2,}", lambda m: "-" + "\\x2d" * (len(m.group()) - 1), text_line(s)) for s in lines]
    return ET.Comment("\n" + "".join("  " + s + "\n" for s in body))  # type: ignore[return-value]  # a comment node


def comment(lines, mark: str = "#") -> str:
    """``lines`` as comment lines of a Python or YAML file (each through :func:`text_line`)."""
    return "\n".join(f"{mark} {text_line(s)}".rstrip() for s in lines)


def py_docstring(text: str) -> str:
    """A docstring literal of ``text``.

    Between triple quotes and a space (MoveIt's layout) when the text holds no quote, backslash or
    unprintable character, else its ``repr``.
    """
    plain = text.isprintable() and '"' not in text and "\\" not in text
    return f'""" {text} """' if plain else repr(text)


def header_lines(e: ExportTransform) -> list[str]:
    """What every exported file says about itself (without comment markers)."""
    t, q, rpy = e.translation_m, e.quat_xyzw, e.rpy_rad
    of = "" if e.camera is None else f" of camera {e.camera} of a cell"
    lines = [
        f"hand-eye calibration{of} by handeye {__version__}: {e.mode}, {e.parent} -> {e.child}",
        f"T_{e.parent}_{e.child}: p_{e.parent} = T @ p_{e.child} (the pose of {e.child} in {e.parent}; "
        f"handeye's {e.x_name}" + (" @ T_optical_body)" if e.camera_frame == "body" else ")"),
        f"camera frame: {CAMERA_FRAME_TEXT[e.camera_frame]}",
        "translation [m] x y z: " + " ".join(num(v) for v in t),
        "quaternion x y z w (ROS order): " + " ".join(num(v) for v in q),
        "rpy: " + " ".join(num(v) for v in rpy) + f"  ({RPY_TEXT})",
    ]
    s = e.sigmas()
    if s is not None:
        lines.append(
            "1-sigma: translation [mm] "
            + " ".join(f"{v:.3f}" for v in s["translation_mm"])
            + ", roll pitch yaw [deg] "
            + " ".join(f"{v:.4f}" for v in s["rpy_deg"])
            + f" ({e.cov_source})"
        )
    else:
        lines.append("1-sigma: not available (the result has no covariance)")
    lines.append(f"from {e.source}, verdict {e.verdict}")
    if e.child in (DEFAULT_FRAMES["camera_optical"], DEFAULT_FRAMES["camera_body"]):
        lines.append(
            f"the RealSense driver publishes camera_link -> camera_color_frame -> camera_color_optical_frame "
            f"itself and a frame has one parent in tf2: with the driver running publish {e.parent} -> "
            f"camera_link = this transform @ inv(T_camera_link_{e.child}) (from the driver's /tf_static)"
        )
    return lines


#: the name of the provenance constant in the generated Python launch files (the result's path, mode and
#: verdict as Python literals: exact, where the header comments escape what is not printable)
PROVENANCE_NAME = "HANDEYE_CALIBRATION"


def provenance_constant(e: ExportTransform) -> dict:
    """What a launch file's :data:`PROVENANCE_NAME` holds."""
    d = {"handeye": __version__, "source": e.source, "mode": e.mode, "verdict": e.verdict}
    return d if e.camera is None else {**d, "camera": e.camera}


def stp_arguments(e: ExportTransform) -> list[str]:
    """tf2_ros static_transform_publisher's arguments (ROS 2: ``--x .. --qw --frame-id --child-frame-id``)."""
    t, q = e.translation_m, e.quat_xyzw
    pairs = [
        ("--frame-id", e.parent),
        ("--child-frame-id", e.child),
        ("--x", num(t[0])),
        ("--y", num(t[1])),
        ("--z", num(t[2])),
        ("--qx", num(q[0])),
        ("--qy", num(q[1])),
        ("--qz", num(q[2])),
        ("--qw", num(q[3])),
    ]
    return [v for pair in pairs for v in pair]


def node_name(e: ExportTransform) -> str:
    """The static_transform_publisher node's name (a ROS node name: letters, digits and _)."""
    return "handeye_" + ident(e.parent) + "_to_" + ident(e.child)


def ros2_launch(e: ExportTransform, *, moveit_layout: bool = False) -> str:
    """A ROS 2 Python launch file running tf2_ros' static_transform_publisher with the transform.

    ``moveit_layout``: the layout MoveIt 2 Calibration writes when it saves the camera pose (its two
    docstrings, the arguments one per line, roll/pitch/yaw as comments). The first two lines hold no outside
    text (Python reads an encoding declaration there); every literal is ``json.dumps`` / ``repr``.
    """
    kind = "EYE-IN-HAND" if e.mode == "eye_in_hand" else "EYE-TO-HAND"
    if moveit_layout:
        head = [
            py_docstring("Static transform publisher of a hand-eye calibration (MoveIt 2 Calibration's layout)"),
            py_docstring(f"{kind}: {e.parent} -> {e.child}"),
        ]
    else:
        head = [
            json.dumps(f"Static transform {e.parent} -> {e.child} from a handeye calibration ({e.mode})."),
            f"# written by handeye {text_line(__version__)}",
        ]
    return launch_text(head, header_lines(e), provenance_constant(e), [e])


def launch_text(head: list[str], header: list[str], provenance: dict, es: list[ExportTransform]) -> str:
    """A launch file: ``head`` (no outside text), the comment ``header``, one static_transform_publisher per ``es``."""
    nodes = []
    for e in es:
        arg_lines = [f"                {json.dumps(v)}," for v in stp_arguments(e)]
        for flag, v in zip(("--roll", "--pitch", "--yaw"), e.rpy_rad, strict=True):
            arg_lines += [f"                # {json.dumps(flag)},", f"                # {json.dumps(num(v))},"]
        nodes += [
            "        Node(",
            '            package="tf2_ros",',
            '            executable="static_transform_publisher",',
            f"            name={json.dumps(node_name(e))},",
            '            output="log",',
            "            arguments=[",
            *arg_lines,
            "            ],",
            "        ),",
        ]
    return "\n".join(
        head
        + [
            comment(header),
            "from launch import LaunchDescription",
            "from launch_ros.actions import Node",
            "",
            f"{PROVENANCE_NAME} = {provenance!r}",
            "",
            "",
            "def generate_launch_description() -> LaunchDescription:",
            "    nodes = [",
            *nodes,
            "    ]",
            "    return LaunchDescription(nodes)",
            "",
        ]
    )


def xml_text(root: ET.Element, head: ET.Element) -> str:
    """An XML document: the declaration, the comment ``head``, then ``root`` (indented), all through ElementTree."""
    ET.indent(root, space="  ")
    return "\n".join(
        [
            '<?xml version="1.0"?>',
            ET.tostring(head, encoding="unicode"),
            ET.tostring(root, encoding="unicode"),
            "",
        ]
    )


def moveit1_launch(e: ExportTransform) -> str:
    """The ROS 1 launch file MoveIt Calibration saves ("Save camera pose").

    static_transform_publisher with ``args="x y z qx qy qz qw frame_id child_frame_id"``. Its comment's rpy
    is URDF's fixed-axis roll-pitch-yaw (MoveIt's own comment writes Eigen's eulerAngles(0, 1, 2), moving
    axes, under that name).
    """
    t, q = e.translation_m, e.quat_xyzw
    xyz, rpy = " ".join(num(v) for v in t), " ".join(num(v) for v in e.rpy_rad)
    root = ET.Element("launch")
    root.append(xml_comment(header_lines(e) + [f'xyz="{xyz}" rpy="{rpy}" ({RPY_TEXT})']))
    ET.SubElement(
        root,
        "node",
        {
            "pkg": "tf2_ros",
            "type": "static_transform_publisher",
            "name": "camera_link_broadcaster",
            "args": f"{xyz} {' '.join(num(v) for v in q)} {e.parent} {e.child}",
        },
    )
    head = ET.Comment(" static transform of a hand-eye calibration (MoveIt Calibration's layout) ")
    return xml_text(root, head)  # type: ignore[arg-type]  # a comment node is an element


def ident(name: str) -> str:
    """``name`` as an identifier of letters, digits and _ (node, joint and macro names)."""
    return "".join(c if c.isascii() and c.isalnum() else "_" for c in name).strip("_") or "frame"


def yaml_doc(lines, doc: dict, *, flow: bool | None = None) -> str:
    """Comment ``lines`` then ``doc`` through ``yaml.safe_dump``.

    ``flow`` None: mappings of scalars on one line each; False: block style throughout.
    """
    import yaml

    return comment(lines) + "\n" + yaml.safe_dump(floats(doc), sort_keys=False, default_flow_style=flow)


def tf_static_dict(e: ExportTransform) -> dict:
    """The transform as a tf2_msgs/TFMessage (a dict)."""
    return {"transforms": [tf_transform(e)]}


def tf_transform(e: ExportTransform) -> dict:
    """One geometry_msgs/TransformStamped of a TFMessage (a dict)."""
    t, q = e.translation_m, e.quat_xyzw
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": e.parent},
        "child_frame_id": e.child,
        "transform": {
            "translation": {"x": t[0], "y": t[1], "z": t[2]},
            "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
        },
    }


def tf_static_yaml(e: ExportTransform) -> str:
    """The transform as a tf2_msgs/TFMessage (``ros2 topic echo /tf_static``'s layout).

    Publish it with ``ros2 topic pub --once /tf_static tf2_msgs/msg/TFMessage "$(cat FILE)"`` under a
    transient-local QoS, or read it in a node.
    """
    return yaml_doc(header_lines(e), tf_static_dict(e))


def origin(parent: ET.Element, e: ExportTransform) -> None:
    """The ``<origin xyz rpy>`` of a joint holding ``e``'s transform."""
    xyz = " ".join(num(v) for v in e.translation_m)
    rpy = " ".join(num(v) for v in e.rpy_rad)
    ET.SubElement(parent, "origin", {"xyz": xyz, "rpy": rpy})


def joint_name(e: ExportTransform) -> str:
    """The URDF joint's name."""
    return ident(e.parent) + "_to_" + ident(e.child)


def urdf(e: ExportTransform) -> str:
    """A URDF with the parent and child links and the fixed joint between them."""
    root = ET.Element("robot", {"name": "handeye_calibration"})
    ET.SubElement(root, "link", {"name": e.parent})
    ET.SubElement(root, "link", {"name": e.child})
    joint = ET.SubElement(root, "joint", {"name": joint_name(e), "type": "fixed"})
    ET.SubElement(joint, "parent", {"link": e.parent})
    ET.SubElement(joint, "child", {"link": e.child})
    origin(joint, e)
    return xml_text(root, xml_comment(header_lines(e)))


XACRO_NS = "http://www.ros.org/wiki/xacro"
XACRO_MACRO = "handeye_camera_joint"


def xacro(e: ExportTransform) -> str:
    """A xacro file defining the macro ``handeye_camera_joint``.

    Params ``parent``, ``child`` default to the exported frames: include it in the robot's xacro and call
    ``<xacro:handeye_camera_joint/>``.
    """
    ET.register_namespace("xacro", XACRO_NS)
    root = ET.Element("robot")
    macro = ET.SubElement(
        root, f"{{{XACRO_NS}}}macro", {"name": XACRO_MACRO, "params": f"parent:={e.parent} child:={e.child}"}
    )
    joint = ET.SubElement(macro, "joint", {"name": "${parent}_to_${child}", "type": "fixed"})
    ET.SubElement(joint, "parent", {"link": "${parent}"})
    ET.SubElement(joint, "child", {"link": "${child}"})
    origin(joint, e)
    return xml_text(root, xml_comment(header_lines(e)))


def calib_dict(e: ExportTransform, *, name: str, base: str, effector: str) -> dict:
    """easy_handeye2's saved calibration as a dict (see :func:`easy_handeye2_calib`)."""
    t, q = e.translation_m, e.quat_xyzw
    return {
        "parameters": {
            "name": name,
            "calibration_type": "eye_in_hand" if e.mode == "eye_in_hand" else "eye_on_base",
            "robot_base_frame": base,
            "robot_effector_frame": effector,
            "tracking_base_frame": e.child,
            "tracking_marker_frame": "handeye_target",
            "freehand_robot_movement": True,
            "move_group_namespace": "/",
            "move_group": "manipulator",
        },
        "transform": {
            "translation": {"x": t[0], "y": t[1], "z": t[2]},
            "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
        },
    }


def easy_handeye2_calib(e: ExportTransform, *, name: str, base: str, effector: str) -> str:
    """easy_handeye2's saved calibration (``~/.ros2/easy_handeye2/calibrations/NAME.calib``).

    For eye_in_hand the transform is robot_effector_frame -> tracking_base_frame (the camera), for
    eye_on_base robot_base_frame -> tracking_base_frame. ``base`` and ``effector`` are frame names.
    """
    from .frames import check_frame_name

    check_frame_name(base, "--base-frame")
    check_frame_name(effector, "--effector-frame")
    d = calib_dict(e, name=name, base=base, effector=effector)
    return yaml_doc(header_lines(e), d, flow=False)


def plain_dict(e: ExportTransform) -> dict:
    """The ``yaml`` / ``json`` export: frames, matrix, translation, quaternion.

    The ``yaml`` / ``json`` export: frames, matrix, translation, quaternion (order in the key), rpy,
    sigmas and covariance, provenance.
    """
    from ..output import provenance

    s = e.sigmas()
    q = e.quat_xyzw
    d = {
        "handeye_export": 1,
        "mode": e.mode,
        "parent_frame": e.parent,
        "child_frame": e.child,
        "transform": f"T_{e.parent}_{e.child}: p_{e.parent} = T @ p_{e.child} (pose of the child in the parent)",
        "camera_frame": e.camera_frame,
        "camera_frame_meaning": CAMERA_FRAME_TEXT[e.camera_frame],
        "result_name": e.x_name,
        "matrix": e.T_parent_child.tolist(),
        "translation_m": e.translation_m.tolist(),
        "quaternion_xyzw": q.tolist(),
        "quaternion_wxyz": [q[3], q[0], q[1], q[2]],
        "rpy_rad": e.rpy_rad.tolist(),
        "rpy_convention": RPY_TEXT,
        "sigma": None,
        "cov_6x6": None,
        "verdict": e.verdict,
        "source": e.source,
        "provenance": provenance(),
    }
    if e.camera is not None:
        d["camera"] = e.camera
    if s is not None:
        d["sigma"] = {
            "translation_mm": s["translation_mm"].tolist(),
            "rpy_deg": s["rpy_deg"].tolist(),
            "rotation_child_axes_deg": s["rotation_child_axes_deg"].tolist(),
            "source": e.cov_source,
        }
        d["cov_6x6"] = np.asarray(e.cov_6x6).tolist()
        d["cov_parametrisation"] = (
            "right perturbation T_true = T · Exp(xi), xi = (omega [rad], v [m]), "
            "rotation first, along the child frame's axes (GTSAM Pose3 tangent)"
        )
    return d


def plain_yaml(e: ExportTransform, d: dict | None = None) -> str:
    """The ``yaml`` export (``d``: :func:`plain_dict` made once, when the caller keeps it)."""
    import yaml

    return comment(header_lines(e)) + "\n" + yaml.safe_dump(floats(plain_dict(e) if d is None else d), sort_keys=False)


def plain_json(e: ExportTransform, d: dict | None = None) -> str:
    """The ``json`` export (``d`` as in :func:`plain_yaml`)."""
    from ..output import to_json

    return to_json(plain_dict(e) if d is None else d) + "\n"


def floats(o):
    """Numpy scalars as Python floats (yaml.safe_dump writes floats with repr: exact round trip)."""
    if isinstance(o, dict):
        return {k: floats(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [floats(v) for v in o]
    if isinstance(o, np.generic):
        return o.item()
    return o
