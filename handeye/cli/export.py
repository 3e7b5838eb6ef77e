"""``handeye export RESULT --to FORMAT``: the result where robot software reads it (:mod:`handeye.export`).

stdout: one line per file written (a path's unprintable characters escaped, so one line each). A result
without a matrix, or with a FAIL or REFUSED verdict (unless ``--force``), is refused with one line.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..export import FORMATS
    from ..export.frames import DEFAULT_FRAMES

    p.description = (
        "Write the hand-eye transform in a robot software's format. The transform is parent -> child "
        "(p_parent = T @ p_child): the flange (eye_in_hand) or the robot base (eye_to_hand) -> the camera. "
        "handeye's camera frame is the optical frame (z forward); --camera-frame body exports the REP 103 body "
        "frame (x forward) at the same origin. Each file states its frames, quaternion order and sigmas. "
        "Every file is parsed back by its own reader before any is written; a result folder's own files "
        "(result.json, observations.json, reports, thumbnails/ ...) are never written over. Frame names: "
        "letters, digits and _ . / - (see docs/export.md). A cell (several cameras of one arm) exports every "
        "camera into one URDF / xacro / ROS 2 launch / tf2 YAML / YAML / JSON (frames <camera>_optical_frame), "
        "MoveIt's and easy_handeye2's files one per camera (<name>_<camera>...); --camera NAME exports one."
    )
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = "formats:\n" + "\n".join(
        f"  {k:<14} {v[1]}: " + ", ".join("NAME" + s for s in v[0]) for k, v in FORMATS.items()
    )
    p.add_argument("result", type=Path, help="result folder (or its result.json)")
    p.add_argument("--to", required=True, choices=list(FORMATS), help="export format")
    p.add_argument(
        "--parent",
        metavar="FRAME",
        help=f"parent frame (default: {DEFAULT_FRAMES['eye_in_hand']} for eye_in_hand, "
        f"{DEFAULT_FRAMES['eye_to_hand']} for eye_to_hand)",
    )
    p.add_argument(
        "--child",
        metavar="FRAME",
        help=f"camera frame name (default: {DEFAULT_FRAMES['camera_optical']}, or "
        f"{DEFAULT_FRAMES['camera_body']} with --camera-frame body)",
    )
    p.add_argument(
        "--camera-frame",
        choices=["optical", "body"],
        default="optical",
        help="optical: x right, y down, z forward (default, handeye's); body: x forward, y left, z up",
    )
    p.add_argument(
        "--base-frame",
        metavar="FRAME",
        help="easy_handeye2 only: robot_base_frame of an eye_in_hand calibration (default base_link)",
    )
    p.add_argument(
        "--effector-frame",
        metavar="FRAME",
        help="easy_handeye2 only: robot_effector_frame of an eye_to_hand calibration (default tool0)",
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        help="file to write (companions share its name), or a folder (an existing one, or one ending in /, made); "
        "default RESULT/hand_eye.<format suffix>",
    )
    p.add_argument("--force", action="store_true", help="export a result whose verdict is FAIL")
    p.add_argument("--camera", metavar="NAME", help="a cell: export this camera only (default: every camera)")
    p.set_defaults(func=run)


def run(args) -> int:
    import contextlib
    import os

    from ..export import export_result
    from ..export.writers import text_line
    from ..output import new_folders_kept_only_if_used

    out = None if args.out is None else Path(args.out)
    folder = out if out is not None and args.out.endswith(("/", os.sep)) and not out.is_dir() else None  # "DIR/"
    with new_folders_kept_only_if_used(folder) if folder is not None else contextlib.nullcontext():
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)
        for path in export_result(
            args.result,
            args.to,
            out=out,
            parent=args.parent,
            child=args.child,
            camera_frame=args.camera_frame,
            force=args.force,
            base_frame=args.base_frame,
            effector_frame=args.effector_frame,
            camera=args.camera,
        ):
            print(f"{args.to}: {text_line(path)}")
    return 0
