"""``handeye import visp|ical SRC OUT``: a session.yaml for another tool's data folder."""
from __future__ import annotations

from pathlib import Path


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    p.description = "Writes OUT/session.yaml pointing at the original images; nothing is copied."
    p.add_argument("kind", choices=["visp", "ical"],
                   help="visp: ViSP hand-eye data; ical: ROS-I industrial_calibration")
    p.add_argument("src", type=Path, help="the other tool's data folder")
    p.add_argument("out", type=Path, help="folder for session.yaml")
    p.add_argument("--given-intrinsics", action="store_true", help="use the intrinsics shipped with the data (fixed)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..session.importers import import_ical, import_visp

    if args.kind == "visp":
        path = import_visp(args.src, args.out, use_given_intrinsics=args.given_intrinsics)
    else:
        path = import_ical(args.src, args.out)
    print(f"session: {path}")
    return 0
