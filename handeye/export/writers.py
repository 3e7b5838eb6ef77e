"""The text of each export format, from one :class:`~handeye.export.frames.ExportTransform`.

Every file states the frames (parent -> child, ``p_parent = T @ p_child``), which camera frame the
child is, the quaternion order, the roll-pitch-yaw convention, the 1-sigma uncertainty when the result
has a covariance, and where it came from (handeye version, result file, verdict, time). Numbers are
written with Python's shortest round-trip ``repr``, so a reader recovers the matrix to float precision.

========================  ==================================================================================
format                    files
========================  ==================================================================================
``ros2``                  ``NAME.launch.py`` (tf2_ros static_transform_publisher with --x --y --z --qx --qy
                          --qz --qw --frame-id --child-frame-id) and ``NAME.tf_static.yaml`` (the same as a
                          tf2_msgs/TFMessage, as ``ros2 topic echo /tf_static`` prints it)
``urdf``                  ``NAME.urdf`` (the two links and a fixed joint, origin xyz rpy) and
                          ``NAME.urdf.xacro`` (a macro ``handeye_camera_joint`` with parent and child params)
``moveit``                ``NAME.moveit.launch.py`` and ``NAME.moveit.launch``: the launch files MoveIt 2 and
                          MoveIt (ROS 1) Calibration save the camera pose in
``easy_handeye2``         ``NAME.calib``: easy_handeye2's saved calibration (parameters + transform)
``yaml`` / ``json``       frames, matrix, translation, quaternion (xyzw and wxyz), rpy, sigmas, covariance
========================  ==================================================================================
"""

from __future__ import annotations

import json

import numpy as np

from .. import __version__
from .frames import CAMERA_FRAME_TEXT, DEFAULT_FRAMES, RPY_TEXT, ExportTransform


def num(x) -> str:
    """A float as its shortest round-trip text."""
    return repr(float(x))


def header_lines(e: ExportTransform) -> list[str]:
    """What every exported file says about itself (without comment markers)."""
    t, q, rpy = e.translation_m, e.quat_xyzw, e.rpy_rad
    lines = [
        f"hand-eye calibration by handeye {__version__}: {e.mode}, {e.parent} -> {e.child}",
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


def _comment(lines, mark: str) -> str:
    return "\n".join(f"{mark} {s}".rstrip() for s in lines)


def _stp_arguments(e: ExportTransform) -> list[tuple[str, str]]:
    t, q = e.translation_m, e.quat_xyzw
    return [
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


def ros2_launch(e: ExportTransform, *, moveit_layout: bool = False) -> str:
    """A ROS 2 Python launch file running tf2_ros' static_transform_publisher with the transform.

    ``moveit_layout``: the layout MoveIt 2 Calibration writes when it saves the camera pose (its two
    docstrings, the arguments one per line, roll/pitch/yaw as comments).
    """
    args = _stp_arguments(e)
    kind = "EYE-IN-HAND" if e.mode == "eye_in_hand" else "EYE-TO-HAND"
    if moveit_layout:
        head = [
            '""" Static transform publisher of a hand-eye calibration (MoveIt 2 Calibration\'s layout) """',
            f'""" {kind}: {e.parent} -> {e.child} """',
        ]
    else:
        head = [f'"""Static transform {e.parent} -> {e.child} from a handeye calibration ({e.mode})."""']
    rpy = e.rpy_rad
    arg_lines = []
    for flag, value in args:
        arg_lines += [f"                {json.dumps(flag)},", f"                {json.dumps(value)},"]
    for flag, v in zip(("--roll", "--pitch", "--yaw"), rpy, strict=False):
        arg_lines += [f"                # {json.dumps(flag)},", f"                # {json.dumps(num(v))},"]
    return "\n".join(
        head
        + [
            _comment(header_lines(e), "#"),
            "from launch import LaunchDescription",
            "from launch_ros.actions import Node",
            "",
            "",
            "def generate_launch_description() -> LaunchDescription:",
            "    nodes = [",
            "        Node(",
            '            package="tf2_ros",',
            '            executable="static_transform_publisher",',
            f"            name={json.dumps('handeye_' + _ident(e.parent) + '_to_' + _ident(e.child))},",
            '            output="log",',
            "            arguments=[",
            *arg_lines,
            "            ],",
            "        ),",
            "    ]",
            "    return LaunchDescription(nodes)",
            "",
        ]
    )


def moveit1_launch(e: ExportTransform) -> str:
    """The ROS 1 launch file MoveIt Calibration saves.

    The ROS 1 launch file MoveIt Calibration saves ("Save camera pose"): static_transform_publisher
    with ``args="x y z qx qy qz qw frame_id child_frame_id"``. Its comment's rpy is URDF's fixed-axis
    roll-pitch-yaw (MoveIt's own comment writes Eigen's eulerAngles(0, 1, 2), moving axes, under that name).
    """
    from xml.sax.saxutils import quoteattr

    t, q = e.translation_m, e.quat_xyzw
    xyz, rpy = " ".join(num(v) for v in t), " ".join(num(v) for v in e.rpy_rad)
    args = f"{xyz}   {' '.join(num(v) for v in q)} {e.parent} {e.child}"
    return "\n".join(
        [
            "<launch>",
            "  " + _xml_comment(e).replace("\n", "\n  "),
            f'  <!-- xyz="{xyz}" rpy="{rpy}" ({RPY_TEXT}) -->',
            '  <node pkg="tf2_ros" type="static_transform_publisher" name="camera_link_broadcaster"',
            f"      args={quoteattr(args)} />",
            "</launch>",
            "",
        ]
    )


def _ident(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_") or "frame"


def tf_static_yaml(e: ExportTransform) -> str:
    """The transform as a tf2_msgs/TFMessage.

    The transform as a tf2_msgs/TFMessage (``ros2 topic echo /tf_static``'s layout; publish it with
    ``ros2 topic pub --once /tf_static tf2_msgs/msg/TFMessage "$(cat FILE)"`` under a transient-local QoS,
    or read it in a node).
    """
    t, q = e.translation_m, e.quat_xyzw
    return "\n".join(
        [
            _comment(header_lines(e), "#"),
            "transforms:",
            "- header:",
            "    stamp: {sec: 0, nanosec: 0}",
            f"    frame_id: {json.dumps(e.parent)}",
            f"  child_frame_id: {json.dumps(e.child)}",
            "  transform:",
            f"    translation: {{x: {num(t[0])}, y: {num(t[1])}, z: {num(t[2])}}}",
            f"    rotation: {{x: {num(q[0])}, y: {num(q[1])}, z: {num(q[2])}, w: {num(q[3])}}}",
            "",
        ]
    )


def _xml_comment(e: ExportTransform) -> str:
    return "<!--\n" + "\n".join("  " + s.replace("--", "- -") for s in header_lines(e)) + "\n-->"


def _origin(e: ExportTransform) -> str:
    xyz = " ".join(num(v) for v in e.translation_m)
    rpy = " ".join(num(v) for v in e.rpy_rad)
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def urdf(e: ExportTransform) -> str:
    """A URDF with the parent and child links and the fixed joint between them."""
    from xml.sax.saxutils import quoteattr

    return "\n".join(
        [
            '<?xml version="1.0"?>',
            _xml_comment(e),
            '<robot name="handeye_calibration">',
            f"  <link name={quoteattr(e.parent)}/>",
            f"  <link name={quoteattr(e.child)}/>",
            f'  <joint name={quoteattr(_ident(e.parent) + "_to_" + _ident(e.child))} type="fixed">',
            f"    <parent link={quoteattr(e.parent)}/>",
            f"    <child link={quoteattr(e.child)}/>",
            f"    {_origin(e)}",
            "  </joint>",
            "</robot>",
            "",
        ]
    )


def xacro(e: ExportTransform) -> str:
    """A xacro file defining the macro ``handeye_camera_joint``.

    A xacro file defining the macro ``handeye_camera_joint`` (params ``parent``, ``child``, defaulting
    to the exported frames): include it in the robot's xacro and call ``<xacro:handeye_camera_joint/>``.
    """
    from xml.sax.saxutils import quoteattr

    params = f"parent:={e.parent} child:={e.child}"
    return "\n".join(
        [
            '<?xml version="1.0"?>',
            _xml_comment(e),
            '<robot xmlns:xacro="http://www.ros.org/wiki/xacro">',
            f'  <xacro:macro name="handeye_camera_joint" params={quoteattr(params)}>',
            '    <joint name="${parent}_to_${child}" type="fixed">',
            '      <parent link="${parent}"/>',
            '      <child link="${child}"/>',
            f"      {_origin(e)}",
            "    </joint>",
            "  </xacro:macro>",
            "</robot>",
            "",
        ]
    )


def easy_handeye2_calib(e: ExportTransform, *, name: str, base: str, effector: str) -> str:
    """easy_handeye2's saved calibration.

    easy_handeye2's saved calibration (``~/.ros2/easy_handeye2/calibrations/NAME.calib``): for
    eye_in_hand the transform is robot_effector_frame -> tracking_base_frame (the camera), for
    eye_on_base robot_base_frame -> tracking_base_frame.
    """
    t, q = e.translation_m, e.quat_xyzw
    kind = "eye_in_hand" if e.mode == "eye_in_hand" else "eye_on_base"
    return "\n".join(
        [
            _comment(header_lines(e), "#"),
            "parameters:",
            f"  name: {json.dumps(name)}",
            f"  calibration_type: {kind}",
            f"  robot_base_frame: {json.dumps(base)}",
            f"  robot_effector_frame: {json.dumps(effector)}",
            f"  tracking_base_frame: {json.dumps(e.child)}",
            "  tracking_marker_frame: handeye_target",
            "  freehand_robot_movement: true",
            "  move_group_namespace: /",
            "  move_group: manipulator",
            "transform:",
            "  translation:",
            f"    x: {num(t[0])}",
            f"    y: {num(t[1])}",
            f"    z: {num(t[2])}",
            "  rotation:",
            f"    x: {num(q[0])}",
            f"    y: {num(q[1])}",
            f"    z: {num(q[2])}",
            f"    w: {num(q[3])}",
            "",
        ]
    )


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


def plain_yaml(e: ExportTransform) -> str:
    import yaml

    return _comment(header_lines(e), "#") + "\n" + yaml.safe_dump(_floats(plain_dict(e)), sort_keys=False)


def plain_json(e: ExportTransform) -> str:
    from ..output import to_json

    return to_json(plain_dict(e)) + "\n"


def _floats(o):
    """Numpy scalars as Python floats (yaml.safe_dump writes floats with repr: exact round trip)."""
    if isinstance(o, dict):
        return {k: _floats(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_floats(v) for v in o]
    if isinstance(o, np.generic):
        return o.item()
    return o
