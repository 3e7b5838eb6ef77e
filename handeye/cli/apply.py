"""``handeye apply RESULT --point X Y Z | --pose ...``: camera observations in the robot base frame."""

from __future__ import annotations

import logging
from pathlib import Path

from .numbers import finite_float

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    p.description = (
        "Eye-in-hand needs the end pose at capture time (--end-pose); eye-to-hand refuses it (the camera is "
        "fixed to the base)."
    )
    p.add_argument("result", type=Path, help="result.json or the folder holding it")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument(
        "--point", nargs=3, type=finite_float, metavar=("X", "Y", "Z"), help="point in the camera frame, metres"
    )
    g.add_argument(
        "--pose",
        nargs=6,
        type=finite_float,
        metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
        help="object pose in the camera frame: metres, radians, R = Rz·Ry·Rx",
    )
    p.add_argument(
        "--end-pose",
        nargs=6,
        type=finite_float,
        metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
        help="robot end pose in the base frame at capture time (vendor convention: metres, radians, R = Rz·Ry·Rx); "
        "eye-in-hand only",
    )
    p.add_argument("--mm", action="store_true", help="--point/--pose/--end-pose translations are in millimetres")
    p.add_argument("--camera", metavar="NAME", help="a cell (several cameras of one arm): the camera observed with")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..apply import points_cam_to_base, pose_cam_to_base
    from ..contract import read_result, single_camera
    from ..conventions import VENDOR_POSE_FORMAT, T_from_pose_values, pose_forms
    from ..errors import ConfigError, InputError
    from ..mounting import mounting

    path = Path(args.result) / "result.json" if Path(args.result).is_dir() else Path(args.result)
    # every field it holds checked (a damaged one is one line naming it); status, mode and X are enough
    res = single_camera(read_result(path, partial=True), args.camera, source=str(path))  # a cell: --camera
    if not res.ok:
        raise InputError(
            f"the result is a failed calibration ({str(res.failure_reason or '').strip()})",
            path=path,
            hint="calibrate again and apply a successful result",
            code="failed_result",
        )
    mode, T_x = res.mode, res.T_x
    if T_x is None:
        raise InputError(
            f"damaged: {res.x_name} is missing",
            path=path,
            expected=f"a finite 4x4 rigid transform (mode {mode})",
            code="result_damaged",
            hint="re-run handeye calibrate",
        )
    if args.end_pose is not None and not mounting(mode).camera_moves:
        raise InputError(
            f"--end-pose does not apply to an {mode} result: the camera is fixed to the robot base, so what it "
            "sees maps into the base without the end pose",
            path=path,
            hint="drop --end-pose",
            code="flag_not_applicable",
        )
    if res.verdict == "FAIL":
        from ..recal.loaded import load_result, unfit_note

        log.warning("%s", unfit_note(load_result(path, camera=args.camera)))
    scale = 1e-3 if args.mm else 1.0

    def pose_arg(values, flag):
        from ..session.fields import session_limits

        v = np.asarray(values, float)
        v[:3] *= scale
        lim = session_limits()
        if np.any(np.abs(v[3:]) > lim["max_angle_rad"]):
            raise ConfigError(
                f"{flag}: rotation angle {np.abs(v[3:]).max():g} is larger than 2*pi",
                expected="rx, ry, rz in radians",
                hint="the angles look like degrees: convert them",
            )
        if flag == "--end-pose" and np.linalg.norm(v[:3]) > lim["max_reach_m"]:
            raise ConfigError(
                f"{flag}: the flange {np.linalg.norm(v[:3]):g} m from the base is beyond an arm's reach",
                expected="x, y, z in metres (or millimetres with --mm)",
                hint="the position looks like millimetres: add --mm",
            )
        try:
            return T_from_pose_values(v, VENDOR_POSE_FORMAT)
        except ValueError as e:
            raise ConfigError(f"{flag}: {e}") from None

    T_base_end = None if args.end_pose is None else pose_arg(args.end_pose, "--end-pose")
    if args.point is not None:
        p = np.asarray(args.point, float) * scale
        pb = points_cam_to_base(p, mode=mode, T_x=T_x, T_base_end=T_base_end)
        print(f"p_base [m]: {pb[0]:.6f} {pb[1]:.6f} {pb[2]:.6f}")
        print(f"p_base [mm]: {pb[0] * 1e3:.3f} {pb[1] * 1e3:.3f} {pb[2] * 1e3:.3f}")
    else:
        T = pose_cam_to_base(pose_arg(args.pose, "--pose"), mode=mode, T_x=T_x, T_base_end=T_base_end)
        print("T_base_obj:")
        for row in T:
            print("  [" + " ".join(f"{x:+.6f}" for x in row) + "]")
        print(f"x,y,z,rx,ry,rz (m, rad; R = Rz·Ry·Rx): {pose_forms(T)['vendor_pose_line']}")
    return 0
