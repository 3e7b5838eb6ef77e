"""A cell's export: every camera of one arm in one file per format (``handeye export CELL --to FORMAT``).

One URDF (a fixed joint per camera from the flange or the robot base), one xacro (a macro per camera),
one ROS 2 launch file (a static_transform_publisher per camera), one tf2 YAML (a transform per camera),
one plain YAML / JSON (``kind: cell``, ``cameras``: name -> the one-camera export). Each camera's part is
written by the one-camera writers of :mod:`.writers`, with their escaping; :mod:`.readback` reads every
camera back from each file. See docs/export.md.
"""

from __future__ import annotations

import json
import logging
import xml.etree.ElementTree as ET

from .. import __version__
from .frames import ExportTransform
from .writers import (
    PROVENANCE_NAME,
    XACRO_MACRO,
    XACRO_NS,
    ident,
    joint_name,
    launch_text,
    node_name,
    origin,
    plain_json,
    text_line,
    tf_transform,
    xml_comment,
    xml_text,
    yaml_doc,
)
from .writers import (
    header_lines as camera_header,
)
from .writers import (
    plain_dict as camera_dict,
)

log = logging.getLogger(__name__)

#: the formats a cell writes as one file set holding every camera (the others: one set per camera)
CELL_FORMATS = ("ros2", "urdf", "yaml", "json")


def header_lines(es: list[ExportTransform]) -> list[str]:
    """What a cell's file says about itself: the cameras, then each camera's own header."""
    lines = [
        f"hand-eye calibration of a cell of {len(es)} cameras by handeye {__version__}: "
        + ", ".join(f"{e.camera} ({e.mode}, {e.parent} -> {e.child})" for e in es)
    ]
    for e in es:
        lines += [""] + camera_header(e)
    return lines


def provenance_constant(es: list[ExportTransform]) -> dict:
    """What a cell's launch file's :data:`~.writers.PROVENANCE_NAME` holds."""
    return {
        "handeye": __version__,
        "source": es[0].source,
        "cameras": {str(e.camera): {"mode": e.mode, "verdict": e.verdict} for e in es},
    }


def ros2_launch(es: list[ExportTransform]) -> str:
    """One ROS 2 launch file: a static_transform_publisher per camera."""
    head = [
        json.dumps(f"Static transforms of a cell of {len(es)} cameras from a handeye calibration."),
        f"# written by handeye {text_line(__version__)}",
    ]
    return launch_text(head, header_lines(es), provenance_constant(es), es)


def tf_static_yaml(es: list[ExportTransform]) -> str:
    """One tf2_msgs/TFMessage with a transform per camera."""
    return yaml_doc(header_lines(es), {"transforms": [tf_transform(e) for e in es]})


def urdf(es: list[ExportTransform]) -> str:
    """One URDF: the parent links (flange, base), each once, the cameras' links and a fixed joint per camera.

    A cell of fixed and wrist cameras has two parents, base and flange, which only the robot's own URDF joins:
    the file says so (a URDF parser refuses two root links on their own) and the xacro's macros are the way in.
    """
    root = ET.Element("robot", {"name": "handeye_cell"})
    parents = list(dict.fromkeys(e.parent for e in es))
    for name in parents + [e.child for e in es]:
        ET.SubElement(root, "link", {"name": name})
    for e in es:
        joint = ET.SubElement(root, "joint", {"name": joint_name(e), "type": "fixed"})
        ET.SubElement(joint, "parent", {"link": e.parent})
        ET.SubElement(joint, "child", {"link": e.child})
        origin(joint, e)
    lines = header_lines(es)
    if len(parents) > 1:
        note = (
            f"{' and '.join(parents)} are both roots here: only the robot's own URDF joins them, so this file is "
            "a part to merge into it (a URDF parser refuses two root links on their own); the xacro's macros "
            "add each camera to the robot's description, or export one camera with --camera"
        )
        log.warning("the cell's URDF: %s", note)
        lines = [*lines, "", note]
    return xml_text(root, xml_comment(lines))


def macro_name(e: ExportTransform) -> str:
    """A cell camera's xacro macro: ``handeye_camera_joint_<camera>``."""
    return f"{XACRO_MACRO}_{ident(str(e.camera))}"


def xacro(es: list[ExportTransform]) -> str:
    """One xacro file: a macro per camera (``<xacro:handeye_camera_joint_<camera>/>``), params parent and child."""
    ET.register_namespace("xacro", XACRO_NS)
    root = ET.Element("robot")
    for e in es:
        macro = ET.SubElement(
            root, f"{{{XACRO_NS}}}macro", {"name": macro_name(e), "params": f"parent:={e.parent} child:={e.child}"}
        )
        joint = ET.SubElement(macro, "joint", {"name": "${parent}_to_${child}", "type": "fixed"})
        ET.SubElement(joint, "parent", {"link": "${parent}"})
        ET.SubElement(joint, "child", {"link": "${child}"})
        origin(joint, e)
    return xml_text(root, xml_comment(header_lines(es)))


def plain_dict(es: list[ExportTransform]) -> dict:
    """The ``yaml`` / ``json`` export of a cell: ``cameras``: name -> the one-camera export."""
    from ..output import provenance

    return {
        "handeye_export": 1,
        "kind": "cell",
        "source": es[0].source,
        "cameras": {str(e.camera): camera_dict(e) for e in es},
        "provenance": provenance(),
    }


def render(fmt: str, es: list[ExportTransform]) -> list[tuple[str, str, list[tuple]]]:
    """Each file of format ``fmt`` (:data:`CELL_FORMATS`) for the cameras ``es``.

    ``(text, kind, want)``: ``kind`` names its reader in :data:`.readback.READERS`; ``want`` holds, per
    camera in order, ``(parent, child, T_parent_child, fields)`` the reader must find.
    """

    def want(fields) -> list[tuple]:
        return [(e.parent, e.child, e.T_parent_child, fields(e)) for e in es]

    if fmt == "ros2":
        prov = provenance_constant(es)
        launch = want(lambda e: {"node_name": node_name(e), PROVENANCE_NAME: prov})
        return [(ros2_launch(es), "launch.py", launch), (tf_static_yaml(es), "tf_static", want(lambda e: {}))]
    if fmt == "urdf":
        return [
            (urdf(es), "urdf", want(lambda e: {"joint_name": joint_name(e)})),
            (xacro(es), "xacro", want(lambda e: {"macro": macro_name(e)})),
        ]
    d = plain_dict(es)
    plain = want(
        lambda e: {
            "mode": e.mode,
            "verdict": e.verdict,
            "source": e.source,
            "result_name": e.x_name,
            "camera": e.camera,
        }
    )
    if fmt == "yaml":
        return [(yaml_doc(header_lines(es), d, flow=False), "plain_yaml", plain)]
    return [(plain_json(es[0], d), "plain_json", plain)]
