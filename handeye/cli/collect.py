"""``handeye collect OUT --mode M --camera C --robot R [--auto]``: argument parsing and wiring.

The main CLI loads this module only for ``handeye collect`` and calls :func:`add_arguments`;
``add_collect_arguments(parser)`` and ``run_collect(args)`` serve other entry points and tests.
Device and user errors are raised as HandeyeError (the CLI prints them on one line).
"""

from __future__ import annotations

import argparse
import logging
import re
import secrets
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import ConfigError, DetectionError, HandeyeError, HardwareError, InputError
from ..mounting import MODES, mounting
from ..targets import CharucoSpec, ChessboardSpec, TargetSpec

log = logging.getLogger(__name__)

DEFAULT_TARGET = "chessboard:11x8:0.03"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    add_collect_arguments(parser)
    parser.set_defaults(func=run_collect)


def add_collect_arguments(parser: argparse.ArgumentParser) -> None:
    from .numbers import (
        MAX_BLUR_PX,
        blur_px,
        non_negative_float,
        positive_float,
        positive_int,
        seed_int,
        supersample_int,
    )

    parser.description = (
        "Collect a calibration session (native format, one atomic record per view) from a "
        "camera and a robot arm, or their simulators."
    )
    parser.add_argument("out", type=Path, metavar="OUT", help="new (or empty) folder for the session")
    parser.add_argument("--mode", required=True, choices=MODES, help="camera on the arm (eye_in_hand) or fixed")
    parser.add_argument(
        "--camera", required=True, metavar="CAMERA", help="realsense | bag:FILE (a RealSense recording) | sim"
    )
    parser.add_argument(
        "--robot", required=True, metavar="ROBOT", help="realman:IP[:PORT] (JSON over TCP, port 8080 by default) | sim"
    )
    parser.add_argument(
        "--auto",
        action="store_true",
        help="move the arm through an automatic plan (default: interactive, s = capture, q = quit)",
    )
    parser.add_argument(
        "--views", type=int, default=8, help="--auto: planned views after the start view and 3 probe views (default 8)"
    )
    parser.add_argument("--yes", action="store_true", help="--auto: do not ask before moving a real arm")
    parser.add_argument(
        "--verify-against",
        type=Path,
        metavar="RESULT",
        help="capture a verification session of this installed calibration (its mode, board and, "
        "with --auto, a plan that detects a 1 mm / 0.1 deg drift) and run handeye verify on it "
        "at the end (OUT/verify/; exit code 9 when drifted)",
    )
    parser.add_argument(
        "--target",
        default=DEFAULT_TARGET,
        help="chessboard:COLSxROWS:SQUARE_M (inner corners) or "
        "charuco:SQXxSQY:SQUARE_M:MARKER_M[:DICT] (default %(default)s)",
    )
    g = parser.add_argument_group("camera")
    g.add_argument("--resolution", default="1280x720", help="colour stream WIDTHxHEIGHT (default %(default)s)")
    g.add_argument("--fps", type=positive_int, default=30, help="RealSense frame rate (default %(default)s)")
    g.add_argument("--serial", help="RealSense serial number when several are connected")
    g.add_argument(
        "--settle-frames",
        type=int,
        default=30,
        help="RealSense frames skipped at start while auto exposure settles (default %(default)s)",
    )
    g.add_argument(
        "--preview", dest="preview", action="store_true", default=None, help="interactive: force the preview window"
    )
    g.add_argument("--no-preview", dest="preview", action="store_false", help="interactive: terminal prompt only")
    g = parser.add_argument_group("robot")
    g.add_argument(
        "--speed",
        type=float,
        default=0.2,
        metavar="FRACTION",
        help="--auto: motion speed as a fraction of the arm's maximum (default %(default)s)",
    )
    g.add_argument(
        "--max-speed",
        type=float,
        default=0.3,
        metavar="FRACTION",
        help="RealMan: hard cap on any motion's speed fraction (default %(default)s)",
    )
    g.add_argument(
        "--realman-motion",
        choices=("movej_p", "movel"),
        default="movej_p",
        help="RealMan motion command (default %(default)s: joint-space path to the pose)",
    )
    g.add_argument("--work-frame", default="Base", help="RealMan work frame poses are read in (default %(default)s)")
    g.add_argument(
        "--timeout",
        type=positive_float,
        default=2.0,
        metavar="S",
        help="RealMan: seconds to wait for an answer (default %(default)s)",
    )
    g = parser.add_argument_group("capture checks")
    g.add_argument(
        "--min-sharpness",
        type=positive_float,
        default=None,
        help="variance of the Laplacian around the target (default: configs/collect.yaml capture)",
    )
    g.add_argument(
        "--still-tol",
        nargs=2,
        type=positive_float,
        metavar=("MM", "DEG"),
        default=None,
        help="two pose reads around a frame must agree within this (default: configs/collect.yaml capture)",
    )
    g = parser.add_argument_group("automatic plan")
    g.add_argument(
        "--plan-pixel-noise",
        type=positive_float,
        default=None,
        metavar="PX",
        help="corner noise assumed when predicting the uncertainty (default: configs/collect.yaml plan)",
    )
    g.add_argument(
        "--plan-robot-noise",
        nargs=2,
        type=positive_float,
        metavar=("MM", "DEG"),
        default=None,
        help="robot pose noise per axis assumed when predicting (default: configs/collect.yaml plan)",
    )
    g.add_argument(
        "--min-axis-rotation",
        type=positive_float,
        default=None,
        metavar="DEG",
        help="rotate the end at least this much about each of its axes (default: configs/collect.yaml)",
    )
    g.add_argument(
        "--max-travel",
        type=positive_float,
        default=None,
        metavar="MM",
        help="keep the end within this distance of the start pose (default: configs/collect.yaml)",
    )
    g.add_argument(
        "--probe-deg",
        type=positive_float,
        default=6.0,
        help="size of the three probe rotations before planning (default %(default)s)",
    )
    g = parser.add_argument_group("simulation (--camera sim / --robot sim)")
    g.add_argument(
        "--seed",
        type=seed_int,
        help="random seed of the simulated rig and noise (default: drawn at random and recorded as "
        "collected.seed in session.yaml)",
    )
    g.add_argument(
        "--sim-pose-noise",
        nargs=2,
        type=non_negative_float,
        metavar=("MM", "DEG"),
        default=(0.1, 0.02),
        help="simulated arm: per-axis error of the reported pose (default 0.1 mm 0.02 deg)",
    )
    g.add_argument(
        "--sim-image-noise",
        type=non_negative_float,
        default=2.0,
        metavar="GREY",
        help="simulated camera: Gaussian noise in grey levels (default %(default)s)",
    )
    g.add_argument(
        "--sim-blur",
        type=blur_px,
        default=0.0,
        metavar="PX",
        help=f"simulated camera: blur sigma (0-{MAX_BLUR_PX:g}, default 0)",
    )
    g.add_argument(
        "--sim-bump",
        nargs=2,
        type=non_negative_float,
        metavar=("MM", "DEG"),
        default=None,
        help="with --verify-against: the simulated rig is the installed one with the camera moved by "
        "this much (random directions)",
    )
    g.add_argument(
        "--sim-supersample",
        type=supersample_int,
        default=2,
        help="simulated camera: anti-aliasing samples per pixel and axis, 1-16 (default %(default)s)",
    )


def parse_target_spec(text: str) -> TargetSpec:
    """``chessboard:11x8:0.03`` or ``charuco:7x5:0.04:0.03[:DICT_6X6_250]``."""
    s = text.strip()
    m = re.fullmatch(r"chessboard:(\d+)x(\d+):([0-9.eE+-]+)", s)
    if m:
        cols, rows, sq = int(m.group(1)), int(m.group(2)), float(m.group(3))
        if cols < 2 or rows < 2 or not 1e-3 <= sq <= 0.5:
            raise ConfigError(
                "invalid --target", expected="inner corners >= 2 and the square in metres (e.g. 0.03)", received=text
            )
        return ChessboardSpec(max(cols, rows), min(cols, rows), sq)
    m = re.fullmatch(r"charuco:(\d+)x(\d+):([0-9.eE+-]+):([0-9.eE+-]+)(?::(\w+))?", s)
    if m:
        sx, sy, sq, mk = int(m.group(1)), int(m.group(2)), float(m.group(3)), float(m.group(4))
        dictionary = m.group(5) or "DICT_6X6_250"
        import cv2

        if sx < 2 or sy < 2 or not 0 < mk < sq <= 0.5 or not hasattr(cv2.aruco, dictionary):
            raise ConfigError(
                "invalid --target",
                expected="squares >= 2, 0 < marker < square (metres), a known ArUco dictionary",
                received=text,
            )
        return CharucoSpec(sx, sy, sq, mk, dictionary)
    raise ConfigError(
        "invalid --target",
        expected="chessboard:COLSxROWS:SQUARE_M or charuco:SQXxSQY:SQUARE_M:MARKER_M[:DICT]",
        received=repr(text),
        hint=f"e.g. --target {DEFAULT_TARGET} (11x8 inner corners, 30 mm squares)",
    )


def _resolution(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text.strip())
    if not m:
        raise ConfigError("invalid --resolution", expected="WIDTHxHEIGHT, e.g. 1280x720", received=repr(text))
    w, h = int(m.group(1)), int(m.group(2))
    if not (16 <= w <= 16384 and 16 <= h <= 16384):
        raise ConfigError("invalid --resolution", expected="16..16384 pixels per side", received=repr(text))
    return w, h


def _confirm_on_terminal(text: str) -> bool:
    if not sys.stdin or not sys.stdin.isatty():
        raise ConfigError(
            "a real arm is about to move and there is no terminal to confirm it",
            hint="run interactively, or pass --yes once you have checked the workspace is clear",
        )
    print(text + " [y/N] ", end="", file=sys.stderr, flush=True)
    return sys.stdin.readline().strip().lower() in ("y", "yes")


def run_collect(args: argparse.Namespace) -> int:
    installed = _installed(args)  # --verify-against: the installed calibration fixes the mode and the board
    target = parse_target_spec(args.target) if installed is None else _installed_target(installed)
    if isinstance(target, ChessboardSpec) and len(target.symmetries()) > 1:
        log.warning(
            "a %dx%d chessboard looks the same turned by 180 deg; prefer cols + rows odd (e.g. 11x8)",
            target.cols,
            target.rows,
        )
    width, height = _resolution(args.resolution)
    if args.auto and args.views < 1:
        raise ConfigError("--views must be at least 1", received=str(args.views))
    for name in ("speed", "max_speed"):
        v = getattr(args, name)
        if not 0 < v <= 1:
            raise ConfigError(f"invalid --{name.replace('_', '-')}", expected="0 < fraction <= 1", received=str(v))
    if args.camera.strip() == "sim" and args.robot.strip() != "sim":
        raise ConfigError(
            "--camera sim renders what the simulated arm sees", expected="--robot sim", received=repr(args.robot)
        )
    out = Path(args.out)
    from ..collect.session_writer import unused_folder

    if out.is_dir() and not unused_folder(out):  # a file is check_out_dir's: "OUT is a file, not a folder"
        raise InputError(
            "output folder is not empty",
            path=out,
            hint="collect into a new folder; an existing session is never overwritten",
        )
    from ..output import check_out_dir, new_folders_kept_only_if_used

    # a collection that kept no view wrote only its record (the session starts at the first view), and one that
    # failed before it opened the devices nothing: the folders made for it go then, so that the command can run again
    with new_folders_kept_only_if_used(out):
        check_out_dir(out, option="OUT")  # not a file, not under one, writable: before any device is opened
        return _collect(args, installed=installed, target=target, width=width, height=height)


def _collect(args: argparse.Namespace, *, installed, target: TargetSpec, width: int, height: int) -> int:
    """Open the devices, capture into ``args.out`` and say how it went (the options are checked)."""
    from ..collect.collector import CaptureChecks, Collector
    from ..collect.plan import PlanConfig
    from ..collect.session_writer import SessionWriter

    simulated = "sim" in (args.camera.strip(), args.robot.strip())
    seed = args.seed
    if simulated and seed is None:
        seed = secrets.randbelow(2**31)  # drawn here and recorded, so that --seed reproduces the run
    if simulated:
        log.info("simulator seed %d (--seed %d repeats this run)", seed, seed)
    rng = np.random.default_rng(seed)
    robot = camera = writer = collector = None
    try:
        robot, rig = _open_robot(args, target=target, width=width, height=height, rng=rng, installed=installed)
        camera = _open_camera(args, robot=robot, width=width, height=height, rng=rng)
        intr = camera.intrinsics()
        writer = SessionWriter(
            args.out,
            mode=args.mode,
            target=target,
            intrinsics=intr,
            intrinsics_source=camera.intrinsics_source(),
            collected={
                "robot": robot.describe(),
                "camera": camera.describe(),
                "capture": "auto" if args.auto else "interactive",
                **({"seed": seed} if simulated else {}),  # the simulator's seed; real devices draw none
            },
        )
        truth_cb = None
        if rig is not None:
            truth = rig.truth()
            truth["robot_pose_noise"] = robot.describe()
            truth["seed"] = seed
            truth["views"] = {}
            writer.write_ground_truth(truth)

            def truth_cb(view_id: str) -> None:
                truth["views"][view_id] = {
                    "T_base_end_true": robot.T_true.tolist(),
                    "T_base_end_reported": robot.T_reported.tolist(),
                }
                writer.write_ground_truth(truth)

        checks = _given(
            CaptureChecks(),
            still_tol_mm=args.still_tol and args.still_tol[0],
            still_tol_deg=args.still_tol and args.still_tol[1],
            min_sharpness=args.min_sharpness,
        )
        collector = Collector(
            robot=robot, camera=camera, writer=writer, target=target, mode=args.mode, checks=checks, truth=truth_cb
        )
        log.info(
            "collecting a %s session into %s (camera: %s, robot: %s)", args.mode, args.out, camera.name, robot.name
        )
        if args.auto and installed is not None:
            from ..recal.capture import capture_verification

            confirm = (lambda text: True) if (args.yes or not robot.is_real) else _confirm_on_terminal
            capture_verification(collector, installed, n_views=args.views, speed_fraction=args.speed, confirm=confirm)
        elif args.auto:
            cfg = _given(
                PlanConfig(),
                pixel_noise_px=args.plan_pixel_noise,
                robot_noise_mm=args.plan_robot_noise and args.plan_robot_noise[0],
                robot_noise_deg=args.plan_robot_noise and args.plan_robot_noise[1],
                min_axis_rotation_deg=args.min_axis_rotation,
                max_travel_m=None if args.max_travel is None else args.max_travel / 1000.0,
            )
            confirm = (lambda text: True) if (args.yes or not robot.is_real) else _confirm_on_terminal
            collector.run_auto(
                n_views=args.views,
                speed_fraction=args.speed,
                plan_config=cfg,
                confirm=confirm,
                probe_deg=args.probe_deg,
            )
        else:
            collector.run_interactive(preview=args.preview)
        if not collector.kept:
            raise _nothing_kept(collector.rejected)
    except BaseException as e:
        if writer is not None and not writer.started:  # no view kept: the run's record, and a line that says so
            said = _ended_without_a_view(writer, e, [] if collector is None else collector.rejected)
            if said is not e:
                raise said from e
        raise
    finally:
        for dev in (camera, robot):
            if dev is not None:
                try:
                    dev.close()
                except (HandeyeError, OSError, RuntimeError) as e:
                    log.warning("closing %s: %s", getattr(dev, "name", "device"), e)
    print(f"session: {args.out} ({len(collector.kept)} views kept, {len(collector.rejected)} captures rejected)")
    if rig is not None:
        print(f"ground truth: {Path(args.out) / 'ground_truth.json'} ({mounting(args.mode).x_name})")
    if installed is not None:
        return _verify_collected(Path(args.out), installed)
    return 0


def _nothing_kept(rejected) -> HandeyeError:
    """Why a run that ended as asked kept no view: its rejections (the arm's state, else the detection)."""
    if not rejected:
        return DetectionError("no capture was taken", hint="press s + Enter to capture a view, or collect with --auto")
    if all(c.reason.startswith("the arm") for c in rejected):  # moving, not settling, errors
        hint = "check the arm's state (errors, brakes, a motion still running) and try again"
        return HardwareError(_rejections(rejected), hint=hint)
    hint = "the board must be whole in the image, sharp, with the arm still; see the reasons logged above"
    return DetectionError(_rejections(rejected), hint=hint)


def _ended_without_a_view(writer, e: BaseException, rejected) -> BaseException:
    """Record a run that ended (``e``) before its first view in OUT/collect_run.yaml; return what to raise.

    A handeye error becomes one of its class saying "no view kept: WHAT" and naming the record; an interrupt or
    another exception is raised as it is, after a log line that says so.
    """
    error = e.to_dict() if isinstance(e, HandeyeError) else None
    why = e.what if isinstance(e, HandeyeError) else "interrupted" if isinstance(e, KeyboardInterrupt) else repr(e)
    try:
        record = writer.record_empty_run(why, rejected=[c.reason for c in rejected], error=error)
    except HandeyeError as w:
        log.warning("no view kept; the run's record could not be written: %s", w)
        return e
    said = f"no view kept: {why}; this run's settings and seed: {record}"
    if not isinstance(e, HandeyeError):
        log.warning("%s", said)
        return e
    return type(e)(said, path=e.path, line=e.line, expected=e.expected, received=e.received, hint=e.hint, code=e.code)


def _rejections(rejected) -> str:
    """The reasons of the rejected captures, the most common first, with their counts."""
    if not rejected:
        return "no capture was taken"
    counts = Counter(re.split(r"[:(;]", c.reason, maxsplit=1)[0].strip() for c in rejected)
    return "; ".join(f"{k} ({v}x)" for k, v in counts.most_common(3))


def _installed(args):
    """The installed calibration of --verify-against (None without it); its mode must be --mode."""
    if getattr(args, "verify_against", None) is None:
        if getattr(args, "sim_bump", None):
            raise ConfigError("--sim-bump moves the installed camera", expected="--verify-against RESULT")
        return None
    from ..recal.loaded import load_result, require_matrix, session_camera

    hint = "collect into a folder named after the camera (--out .../NAME), or verify against its own result"
    camera = session_camera(args.verify_against, args.out, what="--verify-against", hint=hint)  # a cell
    installed = load_result(args.verify_against, camera=camera)
    require_matrix(installed)
    if installed.mode != args.mode:
        raise ConfigError(
            f"--mode {args.mode} but the installed calibration is {installed.mode}",
            path=installed.source,
            hint=f"collect with --mode {installed.mode}",
        )
    return installed


def _installed_target(installed) -> TargetSpec:
    from ..session.target_spec import parse_target

    return parse_target(installed.target, path=Path(installed.source))


def _verify_collected(out: Path, installed) -> int:
    """Handeye verify on the collected session against the installed calibration: OUT/verify/."""
    from ..recal.verify import verify_session
    from .verify import finish_verification

    return finish_verification(verify_session(out, installed), out / "verify")


def _open_robot(args, *, target: TargetSpec, width: int, height: int, rng: np.random.Generator, installed=None):
    spec = args.robot.strip()
    if spec == "sim":
        from ..sim.devices import SimRig, SimRobot
        from ..sim.scenarios import default_intrinsics

        kinematic = None
        if installed is not None:  # the simulator stands in for the installed rig (its camera bumped on request)
            rig = _installed_rig(installed, target=target, bump=getattr(args, "sim_bump", None), rng=rng)
            kinematic = _installed_arm(installed, rng=rng)
        else:
            rig = SimRig.sample(mode=args.mode, rng=rng, target=target, intrinsics=default_intrinsics(width, height))
        noise = args.sim_pose_noise
        return SimRobot(rig, pose_noise_mm=noise[0], pose_noise_deg=noise[1], rng=rng, kinematic=kinematic), rig
    if spec == "realman" or spec.startswith("realman:"):
        from ..collect.realman import RealmanArm, parse_robot_address

        host, port = parse_robot_address(spec[len("realman:") :] if ":" in spec else "")
        arm = RealmanArm(
            host,
            port,
            timeout_s=args.timeout,
            motion=args.realman_motion,
            max_speed_fraction=args.max_speed,
            work_frame=args.work_frame or None,
        )
        return arm, None
    raise ConfigError("unknown --robot", expected="realman:IP[:PORT] or sim", received=repr(args.robot))


def _open_camera(args, *, robot, width: int, height: int, rng: np.random.Generator):
    spec = args.camera.strip()
    if spec == "sim":
        from ..sim.devices import SimCamera

        return SimCamera(
            robot,
            supersample=args.sim_supersample,
            blur_sigma_px=args.sim_blur,
            noise_sigma=args.sim_image_noise,
            rng=rng,
        )
    if spec == "realsense":
        from ..collect.realsense import RealSenseCamera

        return RealSenseCamera(
            width=width, height=height, fps=args.fps, serial=args.serial, settle_frames=args.settle_frames
        )
    if spec.startswith("bag:"):
        from ..collect.realsense import BagCamera

        return BagCamera(spec[4:])
    raise ConfigError("unknown --camera", expected="realsense, bag:FILE or sim", received=repr(args.camera))


def _given(defaults, **options):
    """``defaults`` (a frozen dataclass from configs/collect.yaml) with the options given on the command line."""
    return replace(defaults, **{k: float(v) for k, v in options.items() if v is not None})


def _installed_arm(installed, *, rng: np.random.Generator):
    """The installed arm for the simulated robot when the install used the arm's kinematic model, else None.

    The arm is the preset's nominal table with the install's encoder noise. A kinematic install's check
    reads its views' joint angles through the same table, so the simulated arm must reach its poses and
    record the encoder readings as the real arm does.
    """
    from ..sim.robot_error import make_kinematic_error

    ref = installed.raw.get("refinement") or {}
    model, arm = ref.get("robot_model") or {}, (ref.get("options") or {}).get("arm")
    if model.get("kind") != "kinematic" or not isinstance(arm, str):
        return None
    sigma = model.get("encoder_sigma_deg")
    return make_kinematic_error(
        rng=rng,
        arm=arm,
        length_error_mm=(0.0, 0.0),
        angle_error_deg=(0.0, 0.0),
        encoder_sigma_deg=float(sigma) if isinstance(sigma, (int, float)) and sigma >= 0 else 0.0,
    )


def _installed_rig(installed, *, target: TargetSpec, bump, rng: np.random.Generator):
    """A simulated rig that is the installed calibration (X, board, intrinsics), started at its first view's pose.

    ``bump`` (mm, deg): the camera moved by that much in random directions.
    """
    from ..frames import se3_exp
    from ..recal.plan import installed_poses
    from ..sim.devices import SimRig

    T_x = installed.T_x
    if bump:
        w, u = rng.normal(size=3), rng.normal(size=3)
        T_x = T_x @ se3_exp(np.r_[np.radians(bump[1]) * w / np.linalg.norm(w), 1e-3 * bump[0] * u / np.linalg.norm(u)])
    poses = installed_poses(installed)
    if not poses or installed.T_board is None or installed.intrinsics is None:
        raise InputError(
            "the installed result has no robot poses, board or intrinsics to simulate its rig", path=installed.source
        )
    return SimRig(installed.mode, T_x, installed.T_board, target, installed.intrinsics, poses[0])
