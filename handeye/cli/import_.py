"""``handeye import``: a native session for another tool's data.

``handeye import visp|ical SRC OUT`` writes a session.yaml for a ViSP or industrial_calibration data
folder; ``handeye import rosbag BAG --image-topic T --base FRAME --end FRAME --target FILE [--out DEST]``
writes a session (session.yaml + images) from a ROS 1 or ROS 2 bag (:mod:`handeye.session.rosbag`);
``handeye import easy_handeye2|moveit SAMPLES [OUT]`` a pose-only session from another tool's saved samples.
"""

from __future__ import annotations

from pathlib import Path

from .numbers import positive_float


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    p.description = (
        "Writes OUT/session.yaml pointing at the original images; nothing is copied. visp reads ViSP's "
        "hand-eye data folders (images [PREFIX_]image-N.png, robot poses [PREFIX_]pose_rPe_N.yaml, and "
        "chessboard-data.txt or apriltag-data.txt; docs/session_format.md)."
    )
    p.add_argument(
        "kind",
        choices=["visp", "ical", "rosbag", "easy_handeye2", "moveit"],
        help="visp: ViSP hand-eye data; ical: ROS-I industrial_calibration; rosbag: a ROS 1 or ROS 2 bag; "
        "easy_handeye2: its saved samples (.samples), moveit: MoveIt Calibration's saved samples (.yaml), each as a "
        "pose-only session",
    )
    p.add_argument(
        "src",
        type=Path,
        help="the other tool's data folder, its samples file, or the bag (ROS 1 .bag, ROS 2 bag folder)",
    )
    p.add_argument("out", type=Path, nargs="?", help="folder for session.yaml (or --out)")
    p.add_argument("--given-intrinsics", action="store_true", help="use the intrinsics shipped with the data (fixed)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the session.yaml of an existing session in OUT (rosbag: its images/ must be empty)",
    )
    add_rosbag_arguments(p.add_argument_group("rosbag"))
    g = p.add_argument_group("easy_handeye2, moveit")
    g.add_argument(
        "--tracker-sigma",
        nargs=2,
        type=positive_float,
        metavar=("MM", "DEG"),
        help="the tracker's noise per axis (default: estimated at calibration)",
    )
    p.set_defaults(func=run)


def add_rosbag_arguments(g) -> None:
    """The options of ``handeye import rosbag`` (stillness defaults: configs/rosbag.yaml)."""
    g.add_argument("--image-topic", metavar="T", help="sensor_msgs/Image or CompressedImage topic")
    g.add_argument(
        "--camera-info",
        metavar="T",
        help="sensor_msgs/CameraInfo topic (default: camera_info beside the image topic, when recorded)",
    )
    g.add_argument("--base", metavar="FRAME", help="robot base frame in TF (e.g. base_link)")
    g.add_argument("--end", metavar="FRAME", help="flange / tool frame in TF (e.g. tool0)")
    g.add_argument(
        "--target",
        type=Path,
        metavar="FILE",
        help="the board: a YAML with a session.yaml target: mapping, or a vendor config.yaml",
    )
    g.add_argument(
        "--mode",
        choices=("eye_in_hand", "eye_to_hand"),  # handeye.mounting.MODES (numpy-free help)
        help="mounting mode (rosbag, easy_handeye2, moveit, visp; default: the one the source states (visp: the folder "
        "name, or eye_to_hand for its AprilTag layout), else decided from the data)",
    )
    g.add_argument(
        "--out",
        dest="out_opt",
        type=Path,
        metavar="DEST",
        help="session folder, as OUT (rosbag, easy_handeye2, moveit: default SRC_session, SRC's name without "
        "its suffix)",
    )
    g.add_argument(
        "--intrinsics-use",
        choices=["fixed", "prior", "initial"],
        default="prior",
        help="how the CameraInfo intrinsics are used (default prior)",
    )
    for name, unit in (
        ("still-trans-mm-s", "mm/s"),
        ("still-rot-deg-s", "deg/s"),
        ("speed-window-s", "s"),
        ("min-still-s", "s"),
        ("margin-s", "s"),
    ):
        g.add_argument(
            f"--{name}",
            type=float,
            metavar=unit.upper().replace("/", "_"),
            help=f"stillness: {name.replace('-', ' ')} [{unit}] (configs/rosbag.yaml)",
        )


#: option (argparse's name) -> the importers that read it; another importer refuses it rather than ignore it
OPTION_KINDS = {
    "given_intrinsics": ("visp",),
    "mode": ("visp", "rosbag", "easy_handeye2", "moveit"),
    "tracker_sigma": ("easy_handeye2", "moveit"),
    **dict.fromkeys(
        (
            "image_topic",
            "camera_info",
            "base",
            "end",
            "target",
            "intrinsics_use",
            "still_trans_mm_s",
            "still_rot_deg_s",
            "speed_window_s",
            "min_still_s",
            "margin_s",
        ),
        ("rosbag",),
    ),
}


def refuse_foreign_options(args) -> None:
    """One line for an option the chosen importer would ignore (``ical --mode eye_to_hand`` wrote the data's mode)."""
    from ..errors import InputError

    for dest, kinds in OPTION_KINDS.items():
        value = getattr(args, dest, None)
        if value in (None, False) or (dest == "intrinsics_use" and value == "prior") or args.kind in kinds:
            continue
        flag = "--" + dest.replace("_", "-")
        raise InputError(
            f"{flag} applies to handeye import {' | '.join(kinds)}, not {args.kind}",
            code="flag_not_applicable",
            hint=f"drop {flag}" + ("; calibrate --mode sets the mode of any session" if dest == "mode" else ""),
        )


def run(args) -> int:
    from ..output import new_folders_kept_only_if_used

    refuse_foreign_options(args)
    out = _out_folder(args)
    with new_folders_kept_only_if_used(out):  # a failed import leaves no empty folder behind
        if args.kind == "rosbag":
            return run_rosbag(args, out)
        if args.kind in ("easy_handeye2", "moveit"):
            return run_pose_samples(args, out)
        return run_folder(args, out)


def _out_folder(args) -> Path:
    """The session folder: OUT or --out (for a bag or a samples file, default SRC_session)."""
    from ..errors import InputError

    if args.out is not None and args.out_opt is not None and args.out != args.out_opt:
        raise InputError(
            f"OUT ({args.out}) and --out ({args.out_opt}) name two folders for session.yaml", hint="give one of them"
        )
    out = args.out or args.out_opt
    if args.kind in ("rosbag", "easy_handeye2", "moveit"):
        return out or Path(args.src.name.split(".")[0] + "_session")
    if out is None:
        raise InputError(f"handeye import {args.kind} needs OUT (or --out), the folder for session.yaml")
    return out


def run_folder(args, out: Path) -> int:
    """``handeye import visp|ical SRC OUT``."""
    from ..session.importers import import_ical, import_visp

    if args.kind == "visp":
        path = import_visp(args.src, out, use_given_intrinsics=args.given_intrinsics, force=args.force, mode=args.mode)
        from ..session.native import read_native_document

        doc = read_native_document(path)
        why = (doc.data.get("source") or {}).get("mode")
        print(f"ViSP layout: {doc.target.describe()}; mode: {doc.mode or 'from the data'} ({why})")
    else:
        path = import_ical(args.src, out, force=args.force)
    print(f"session: {path}")
    return 0


def run_pose_samples(args, out: Path) -> int:
    """``handeye import easy_handeye2|moveit SAMPLES [--out DEST] [--mode M] [--tracker-sigma MM DEG]``."""
    from ..session.easy_handeye2 import import_easy_handeye2
    from ..session.moveit_samples import import_moveit_samples

    importer = import_easy_handeye2 if args.kind == "easy_handeye2" else import_moveit_samples
    path = importer(args.src, out, mode=args.mode, tracker_sigma=args.tracker_sigma, force=args.force)
    print(f"session: {path} (pose-only: target poses from the tracker)")
    return 0


def run_rosbag(args, out: Path) -> int:
    from ..errors import InputError
    from ..session.rosbag import Stillness, import_rosbag, read_target_file

    missing = [f"--{n}" for n in ("image_topic", "base", "end", "target") if getattr(args, n) is None]
    if missing:
        raise InputError(
            "handeye import rosbag needs " + ", ".join(m.replace("_", "-") for m in missing),
            hint="e.g. --image-topic /camera/color/image_raw --base base_link --end tool0 --target config.yaml",
        )
    target, mode = read_target_file(args.target)
    st = Stillness.from_preset(
        **{
            k: getattr(args, k)
            for k in ("still_trans_mm_s", "still_rot_deg_s", "speed_window_s", "min_still_s", "margin_s")
        }
    )
    rep = import_rosbag(
        args.src,
        out,
        image_topic=args.image_topic,
        base_frame=args.base,
        end_frame=args.end,
        target=target,
        camera_info_topic=args.camera_info,
        mode=args.mode or mode,
        stillness=st,
        intrinsics_use=args.intrinsics_use,
        force=args.force,
    )
    for line in rep.summary_lines():
        print(line)
    return 0
