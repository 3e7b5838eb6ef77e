"""``handeye simulate OUT``: a rendered synthetic session in the vendor layout, with its ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .numbers import MAX_BLUR_PX, blur_px, gamma_value, non_negative_float, seed_int

#: ``--target``: the simulated targets (the chessboard is the vendor layout's; the others get a session.yaml)
TARGETS = {
    "chessboard": "chessboard 11x8 inner corners, 30 mm squares (vendor layout)",
    "charuco": "ChArUco 9x7 squares of 30 mm, 22 mm DICT_5X5_100 markers",
    "marker": "one AprilTag 36h11 (id 0) of 48 mm",
    "aprilgrid": "Kalibr AprilGrid 6x6 tags 36h11 of 25 mm, spacing 0.3",
}


def sim_target(name: str):
    """The target spec of a ``--target`` name (:data:`TARGETS`)."""
    from ..sim.scenarios import DEFAULT_TARGET
    from ..targets import AprilGridSpec, CharucoSpec, MarkerSpec

    return {
        "chessboard": DEFAULT_TARGET,
        "charuco": CharucoSpec(9, 7, 0.03, 0.022, "DICT_5X5_100"),
        "marker": MarkerSpec(0.048),
        "aprilgrid": AprilGridSpec(6, 6, 0.025, 0.3),
    }[name]


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..config import arm_presets
    from ..mounting import MODES

    p.description = (
        "Render a synthetic session in the vendor layout (N.jpg, poses.txt, config.yaml) plus "
        "ground_truth.json; targets other than the chessboard get a session.yaml instead of "
        "poses.txt and config.yaml."
    )
    p.add_argument("out", type=Path, help="output folder (created)")
    p.add_argument("--mode", choices=MODES, default="eye_in_hand")
    p.add_argument("--views", type=int, default=20)
    p.add_argument(
        "--target",
        choices=tuple(TARGETS),
        default="chessboard",
        help="; ".join(f"{k}: {v}" for k, v in TARGETS.items()),
    )
    p.add_argument("--seed", type=seed_int, default=0, help="random seed of the scene, poses and noise")
    p.add_argument(
        "--noise-px",
        type=non_negative_float,
        default=0.0,
        help="Gaussian image noise in grey levels added to the rendered images (default 0)",
    )
    p.add_argument(
        "--blur", type=blur_px, default=0.0, help=f"Gaussian blur sigma in pixels (0-{MAX_BLUR_PX:g}, default 0)"
    )
    p.add_argument(
        "--gamma",
        type=gamma_value,
        default=1.0,
        help="the camera's tone curve: grey = 255 (light / 255) ** (1 / GAMMA); 1 (the default): grey proportional"
        " to light; real cameras encode about 2.2 (sRGB)",
    )
    p.add_argument(
        "--robot-noise",
        nargs=2,
        type=non_negative_float,
        metavar=("MM", "DEG"),
        default=(0.0, 0.0),
        help="per-axis robot pose noise added to the reported poses",
    )
    p.add_argument(
        "--robot-error",
        choices=("iid", "kinematic", "none"),
        default=None,
        help="robot error model: iid (--robot-noise per pose; the default of one session), kinematic (a 6-axis "
        "arm with DH errors and encoder noise, handeye.sim.robot_error; the default of a --cell) or none",
    )
    p.add_argument(
        "--cell",
        type=int,
        choices=(2, 3, 4),
        metavar="N",
        help="a cell of N cameras (2-4) of one arm instead of one session: OUT/<camera>/ sessions with the same "
        "view ids and robot poses (fixed cameras cam1.. behind a flange board; from 3 on a wrist camera seeing "
        "a board in the cell), OUT/cell.yaml and ground_truth.json; handeye calibrate OUT --out DIR",
    )
    p.add_argument("--arm", default="rm65", help=f"kinematic arm preset ({', '.join(arm_presets())}) or DH YAML file")
    p.add_argument(
        "--dh-error",
        nargs=2,
        type=float,
        metavar=("MM", "DEG"),
        default=None,
        help="kinematic: the largest error of each DH length (mm) and angle (deg) of the simulated arm, "
        "each drawn between a fifth of it and it (default 0.5 0.05: a factory-calibrated arm; "
        "larger: an arm further from its table than its preset states)",
    )
    p.add_argument(
        "--encoder-sigma",
        type=float,
        metavar="DEG",
        default=None,
        help="kinematic: encoder noise per joint and view, 0-1 deg (default 0.005)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="write over the session files already in OUT (N.jpg, poses.txt, config.yaml, session.yaml, "
        "ground_truth.json; with --cell, cell.yaml and the camera folders' sessions); without it such a folder is "
        "refused",
    )
    p.add_argument("--hidden", nargs="*", default=[], metavar="ID", help="views rendered without the board")
    p.add_argument("--outliers", nargs="*", default=[], metavar="ID", help="views given a wrong robot pose")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import ConfigError

    if args.views < 3:
        raise ConfigError("--views must be at least 3", received=str(args.views))
    _check_view_ids(args)
    if args.robot_error is None:
        args.robot_error = "kinematic" if args.cell else "iid"
    kin: dict[str, Any] = {}
    if args.dh_error is not None or args.encoder_sigma is not None:
        if args.robot_error != "kinematic":
            raise ConfigError(
                "--dh-error and --encoder-sigma describe the kinematic robot error model",
                received=f"--robot-error {args.robot_error}",
                hint="add --robot-error kinematic",
            )
        if args.dh_error is not None:
            mm, deg = (float(x) for x in args.dh_error)
            if not (0 <= mm <= 100 and 0 <= deg <= 10):
                raise ConfigError(
                    "--dh-error must be two numbers, 0-100 mm and 0-10 deg",
                    expected="the largest DH length and angle error, e.g. 2.5 0.25",
                    received=f"{mm} {deg}",
                )
            kin.update(dh_length_error_mm=(mm / 5, mm), dh_angle_error_deg=(deg / 5, deg))
        if args.encoder_sigma is not None:
            if not 0 <= args.encoder_sigma <= 1:
                raise ConfigError(
                    "--encoder-sigma must be a number of degrees between 0 and 1",
                    expected="e.g. 0.005",
                    received=str(args.encoder_sigma),
                )
            kin["encoder_sigma_deg"] = float(args.encoder_sigma)
    from ..output import check_out_dir, new_folders_kept_only_if_used

    with new_folders_kept_only_if_used(args.out):  # refused before it wrote: no empty folder left behind
        check_out_dir(args.out, option="OUT")  # not a file, not under one, writable: before the rendering
        if args.cell:
            return _run_cell(args, kin)
        return _run_session(args, kin)


def _run_session(args, kin: dict) -> int:
    """``simulate OUT``: one rendered session (:func:`handeye.sim.vendor.write_vendor_session`)."""
    from ..sim.vendor import write_vendor_session

    path = write_vendor_session(
        args.out,
        mode=args.mode,
        n_views=args.views,
        seed=args.seed,
        image_noise=args.noise_px,
        blur_sigma_px=args.blur,
        gamma=args.gamma,
        robot_noise=tuple(args.robot_noise),
        hidden_views=tuple(args.hidden),
        outlier_views=tuple(args.outliers),
        robot_error=args.robot_error,
        arm=args.arm,
        target=sim_target(args.target),
        overwrite=bool(getattr(args, "force", False)),
        **kin,
    )
    print(f"synthetic {args.mode} session with {args.views} rendered views: {path}")
    if args.robot_error == "kinematic":  # the joints the arm recorded, and the arm, in session.yaml
        from ..sim.robot_error import write_native_session

        print(f"session with joint angles and robot: {args.arm}: {write_native_session(path)}")
    print(f"ground truth: {Path(path) / 'ground_truth.json'}")
    return 0


def _check_view_ids(args) -> None:
    """``--hidden`` and ``--outliers``: views among 1..``--views``, each once, apart, and one view at least shown.

    A ConfigError names the option otherwise.
    """
    from ..errors import ConfigError

    n = args.views
    valid = {str(k) for k in range(1, n + 1)}
    for option, ids in (("--hidden", args.hidden), ("--outliers", args.outliers)):
        bad = [v for v in ids if v not in valid]
        if bad:
            raise ConfigError(
                f"{option} names views that do not exist",
                expected=f"view ids among 1..{n} (--views {n})",
                received=" ".join(bad),
            )
        if len(set(ids)) != len(ids):
            raise ConfigError(f"{option} names a view twice", expected="each id once", received=" ".join(ids))
    both = sorted(set(args.hidden) & set(args.outliers), key=int)
    if both:
        raise ConfigError(
            "a view cannot be both in --hidden and in --outliers",
            expected="separate view ids",
            received=" ".join(both),
        )
    if len(args.hidden) == n:
        raise ConfigError(
            f"--hidden hides every view: none of the {n} would show the board",
            expected="at least 1 view showing the board (calibrate needs 3)",
            received="--hidden " + " ".join(args.hidden),
            hint="hide fewer views, or render more with --views",
        )


def _run_cell(args, kin: dict) -> int:
    """``simulate OUT --cell N``: a rendered cell (:func:`handeye.sim.cell.write_cell`)."""
    from ..errors import ConfigError
    from ..sim.cell import write_cell

    if args.target != "chessboard" or args.hidden or args.blur or args.gamma != 1.0 or kin:
        raise ConfigError(
            "a simulated cell takes --views, --seed, --noise-px, --robot-error, --robot-noise, --arm and --outliers",
            received="--target, --hidden, --blur, --gamma, --dh-error or --encoder-sigma",
            hint="leave those out with --cell",
        )
    out = write_cell(
        args.out,
        args.cell,
        n_views=args.views,
        seed=args.seed,
        robot_error=args.robot_error,
        arm=args.arm,
        image_noise=args.noise_px,
        outlier_views=tuple(args.outliers),
        robot_noise=tuple(args.robot_noise),
        overwrite=args.force,
    )
    print(f"synthetic cell of {args.cell} cameras, {args.views} robot poses: {out} (cell.yaml)")
    print(f"ground truth: {out / 'ground_truth.json'}")
    return 0
