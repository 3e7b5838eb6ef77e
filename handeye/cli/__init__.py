"""The ``handeye`` command line.

Progress and log lines go to stderr, results to stdout and files. A user mistake ends in one line
on stderr and a non-zero exit code, never a traceback (``--debug`` shows it).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import ConfigError, HandeyeError

log = logging.getLogger("handeye")


def _add_calibrate(sub):
    from ..records import METHOD_NAMES as METHODS

    p = sub.add_parser("calibrate", help="calibrate a session folder (vendor layout or session.yaml)",
                       description="Detect the target, calibrate the camera, seed with an OpenCV closed-form "
                                   "solver and refine jointly; writes DIR/result.json (and the reports).")
    p.add_argument("session", help="session folder (poses.txt + N.jpg + config.yaml, or session.yaml)")
    p.add_argument("--mode", choices=["eye_in_hand", "eye_to_hand"],
                   help="mounting mode (overrides the session's own; default: the session's, else eye_in_hand)")
    p.add_argument("--method", choices=METHODS, help="closed-form seed method (default: tsai, from the preset)")
    p.add_argument("--config", type=Path, help="site YAML overriding configs/calibration.yaml (same keys)")
    p.add_argument("--out", type=Path, help="output folder (default: reports/<session folder name>)")
    p.add_argument("--no-refine", action="store_true", help="stop at the closed-form seed")
    p.add_argument("--fix-k3", action="store_true", help="hold the k3 distortion coefficient at 0")
    p.add_argument("--fix", nargs="+", metavar="NAME", choices=["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                   help="intrinsics held at their starting values in the refinement (e.g. --fix p1 p2 k3)")
    p.add_argument("--robot-noise", choices=["estimate", "fixed", "none"], default=None,
                   help="robot pose noise model in the refinement (default: estimate)")
    p.add_argument("--robot-sigma", nargs=2, type=float, metavar=("MM", "DEG"),
                   help="robot pose sigma: start value (estimate) or the value (fixed)")
    p.add_argument("--workers", type=int, help="threads for corner detection (default: all cores)")
    p.add_argument("--no-report", action="store_true", help="write result.json only")
    p.set_defaults(func=cmd_calibrate)


def _add_simulate(sub):
    p = sub.add_parser("simulate", help="write a synthetic session with rendered images and ground truth",
                       description="Render a synthetic session in the vendor layout (N.jpg, poses.txt, "
                                   "config.yaml) plus ground_truth.json.")
    p.add_argument("out", type=Path, help="output folder (created)")
    p.add_argument("--mode", choices=["eye_in_hand", "eye_to_hand"], default="eye_in_hand")
    p.add_argument("--views", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--noise-px", type=float, default=0.0,
                   help="Gaussian image noise in grey levels added to the rendered images (default 0)")
    p.add_argument("--blur", type=float, default=0.0, help="Gaussian blur sigma in pixels")
    p.add_argument("--robot-noise", nargs=2, type=float, metavar=("MM", "DEG"), default=(0.0, 0.0),
                   help="per-axis robot pose noise added to the reported poses")
    p.add_argument("--hidden", nargs="*", default=[], metavar="ID", help="views rendered without the board")
    p.add_argument("--outliers", nargs="*", default=[], metavar="ID", help="views given a wrong robot pose")
    p.set_defaults(func=cmd_simulate)


def _add_demo(sub):
    p = sub.add_parser("demo", help="simulate a rendered session and calibrate it (the README's first command)")
    p.add_argument("--out", type=Path, default=Path("reports/demo"), help="folder for the session and results")
    p.add_argument("--mode", choices=["eye_in_hand", "eye_to_hand"], default="eye_in_hand")
    p.add_argument("--views", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_demo)


def _add_apply(sub):
    p = sub.add_parser("apply", help="map a point or pose seen by the camera into the robot base frame",
                       description="Eye-in-hand needs the end pose at capture time (--end-pose); "
                                   "eye-to-hand does not.")
    p.add_argument("result", type=Path, help="result.json or the folder holding it")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--point", nargs=3, type=float, metavar=("X", "Y", "Z"), help="point in the camera frame, metres")
    g.add_argument("--pose", nargs=6, type=float, metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
                   help="object pose in the camera frame: metres, radians, R = Rz·Ry·Rx")
    p.add_argument("--end-pose", nargs=6, type=float, metavar=("X", "Y", "Z", "RX", "RY", "RZ"),
                   help="robot end pose in the base frame (vendor convention: metres, radians, R = Rz·Ry·Rx)")
    p.add_argument("--mm", action="store_true", help="--point/--pose/--end-pose translations are in millimetres")
    p.set_defaults(func=cmd_apply)


def _add_import(sub):
    p = sub.add_parser("import", help="write a session.yaml for another tool's data folder (ViSP, industrial_calibration)",
                       description="Writes OUT/session.yaml pointing at the original images; nothing is copied.")
    p.add_argument("kind", choices=["visp", "ical"], help="visp: ViSP hand-eye data; ical: ROS-I industrial_calibration")
    p.add_argument("src", type=Path, help="the other tool's data folder")
    p.add_argument("out", type=Path, help="folder for session.yaml")
    p.add_argument("--given-intrinsics", action="store_true", help="use the intrinsics shipped with the data (fixed)")
    p.set_defaults(func=cmd_import)


def cmd_import(args) -> int:
    from ..session.importers import import_ical, import_visp

    if args.kind == "visp":
        path = import_visp(args.src, args.out, use_given_intrinsics=args.given_intrinsics)
    else:
        path = import_ical(args.src, args.out)
    print(f"session: {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="handeye", description="Robot hand-eye calibration with honest uncertainty.")
    p.add_argument("--version", action="version", version=f"handeye {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="more progress detail on stderr")
    p.add_argument("-q", "--quiet", action="store_true", help="only errors on stderr")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    _add_calibrate(sub)
    _add_simulate(sub)
    _add_demo(sub)
    _add_apply(sub)
    _add_import(sub)
    for extra in _EXTRA_COMMANDS:
        extra(sub)
    return p


def _report_command(sub):
    from .report import add_report_arguments, run_report

    p = sub.add_parser("report", help="(re)build report.html and report.md from a result folder")
    add_report_arguments(p)
    p.set_defaults(func=run_report)


def _collect_command(sub):
    from .collect import add_collect_arguments, run_collect

    p = sub.add_parser("collect", help="collect a session with a camera and a robot (or their simulators)")
    add_collect_arguments(p)
    p.set_defaults(func=run_collect)


_EXTRA_COMMANDS = [_report_command, _collect_command]


# ------------------------------------------------------------------------------ commands
def cmd_calibrate(args) -> int:
    from ..pipeline import CalibrateOptions, run_calibration
    from ..results import failed_load_result, observations_dict, result_dict
    from ..config import load_with_override
    from ..output import write_json
    from ..session import load_session

    out = args.out or Path("reports") / Path(args.session).resolve().name
    cfg = load_with_override("calibration", getattr(args, "config", None))
    ro = {}
    if args.robot_noise:
        ro["robot_noise"] = args.robot_noise
    if args.robot_sigma:
        ro["robot_sigma_mm"], ro["robot_sigma_deg"] = args.robot_sigma
    if getattr(args, "fix", None):
        ro["fix"] = tuple(args.fix)
    opts = CalibrateOptions.from_config(cfg, method=args.method, refine=False if args.no_refine else None,
                                        fix_k3=True if args.fix_k3 else None, workers=args.workers,
                                        refine_options=ro)
    try:
        session = load_session(args.session, mode=args.mode)
    except HandeyeError as e:
        if not (Path(args.session).exists()):
            raise
        # the session exists but cannot be read: still leave a result and a report that say why
        res = failed_load_result(args.session, e, args.mode)
        _write_failed(out, res, args)
        raise
    log.info("session %s: %d views, %s, %s", session.path, len(session.views), session.mode, session.format)
    run = run_calibration(session, opts, progress=lambda s: log.info("%s", s))
    res = result_dict(run)
    _add_diagnostics(res, run)
    out.mkdir(parents=True, exist_ok=True)
    result_path = out / "result.json"
    if run.status != "ok" and result_path.exists():
        # keep the last good result next to the failed one instead of replacing it silently
        result_path.replace(out / "result.previous.json")
    write_json(out / "observations.json", observations_dict(run))
    write_json(result_path, res)
    report_paths = []
    if not args.no_report:
        report_paths = _write_reports(run, res, out)
    print(format_summary(res, result_path, report_paths))
    if run.status != "ok":
        print(f"handeye: calibration failed: {run.failure_reason}", file=sys.stderr)
        return run.exit_code or 1
    return 0


def _write_failed(out: Path, res: dict, args) -> None:
    from ..output import write_json

    from ..diagnose import diagnose_session_error

    res["diagnostics"] = diagnose_session_error(Path(args.session), res["failure_reason"], mode=args.mode)
    out.mkdir(parents=True, exist_ok=True)
    result_path = out / "result.json"
    if result_path.exists():
        result_path.replace(out / "result.previous.json")
    write_json(result_path, res)
    if not args.no_report:
        for p in _write_reports(None, res, out):
            print(f"report: {p}")


def _add_diagnostics(res: dict, run) -> None:
    from ..diagnose import diagnose_run

    res["diagnostics"] = diagnose_run(run)


def _write_reports(run, res, out: Path) -> list[Path]:
    from ..report import write_reports

    return write_reports(run, res, out)


def format_summary(res: dict, result_path: Path, report_paths=()) -> str:
    from ..mounting import mounting

    lines = []
    mode = res["mode"]
    used, total = res["n_views"]["used"], res["n_views"]["total"]
    lines.append(f"handeye {__version__}: {mode}, {used}/{total} views used, method {res['method']}"
                 + (" + joint refinement" if res.get("refined") else " (closed form only)"))
    for v in res["views"]:
        if not v["used"]:
            lines.append(f"  view {v['id']} ({v['image']}) dropped: {v['reason']}")
    if res["status"] == "ok":
        name = mounting(mode).x_name
        he = res["hand_eye"]
        T = np.asarray(res[name])
        lines.append(f"{name} (p_{name.split('_')[1]} = {name} @ p_cam):")
        for row in T:
            lines.append("  [" + " ".join(f"{x:+.6f}" for x in row) + "]")
        t = he["translation_mm"]
        lines.append(f"  translation [mm]: {t[0]:+.2f} {t[1]:+.2f} {t[2]:+.2f}")
        q = he["quaternion_wxyz"]
        lines.append(f"  quaternion (w, x, y, z): {q[0]:+.6f} {q[1]:+.6f} {q[2]:+.6f} {q[3]:+.6f}")
        e = he["euler_vendor_deg"]
        lines.append(f"  vendor x,y,z,rx,ry,rz (m, rad; R = Rz·Ry·Rx): {he['vendor_pose_line']}"
                     f"  [deg: {e[0]:+.3f} {e[1]:+.3f} {e[2]:+.3f}]")
        ref = res.get("refinement") or {}
        sig = ref.get("sigma_trans_mm")
        if sig is not None:
            sr = ref.get("sigma_rot_deg")
            lines.append("  1-sigma: translation [mm] " + " ".join(f"{x:.3f}" for x in sig)
                         + ", rotation [deg] " + " ".join(f"{x:.3f}" for x in sr))
        if ref.get("predicted_error_mm") is not None:
            lines.append(f"  predicted position error at {ref.get('working_distance_m', float('nan')):.2f} m: "
                         f"{ref['predicted_error_mm']:.2f} mm (1 sigma)")
    else:
        lines.append(f"FAILED: {res['failure_reason']}")
    lines.append(f"result: {result_path}")
    for p in report_paths:
        lines.append(f"report: {p}")
    return "\n".join(lines)


def cmd_simulate(args) -> int:
    from ..sim.synth import write_vendor_session

    if args.views < 3:
        raise ConfigError("--views must be at least 3", received=str(args.views))
    path = write_vendor_session(args.out, mode=args.mode, n_views=args.views, seed=args.seed,
                                image_noise=args.noise_px, blur_sigma_px=args.blur,
                                robot_noise=tuple(args.robot_noise), hidden_views=tuple(args.hidden),
                                outlier_views=tuple(args.outliers))
    print(f"synthetic {args.mode} session with {args.views} rendered views: {path}")
    print(f"ground truth: {Path(path) / 'ground_truth.json'}")
    return 0


def cmd_demo(args) -> int:
    import json

    from ..frames import pose_error
    from ..mounting import mounting

    session_dir = args.out / "session"
    log.info("rendering a synthetic %s session with %d views into %s", args.mode, args.views, session_dir)
    args_sim = argparse.Namespace(out=session_dir, mode=args.mode, views=args.views, seed=args.seed, noise_px=2.0,
                                  blur=0.5, robot_noise=(0.0, 0.0), hidden=[str(max(2, args.views // 2))],
                                  outliers=[])
    cmd_simulate(args_sim)
    args_cal = build_parser().parse_args(["calibrate", str(session_dir), "--out", str(args.out / "result")])
    rc = cmd_calibrate(args_cal)
    if rc == 0:
        truth = json.loads((session_dir / "ground_truth.json").read_text())
        res = json.loads((args.out / "result" / "result.json").read_text())
        name = mounting(args.mode).x_name
        r, t = pose_error(np.asarray(res[name]), np.asarray(truth[name]))
        print(f"error against the ground truth: {t:.3f} mm, {r:.4f} deg")
    return rc


def cmd_apply(args) -> int:
    from ..apply import points_cam_to_base, pose_cam_to_base, result_transform
    from ..conventions import VENDOR_POSE_FORMAT, T_from_pose_values, pose_forms
    from ..output import read_json

    mode, T_x = result_transform(read_json(args.result))
    scale = 1e-3 if args.mm else 1.0
    T_base_end = None
    if args.end_pose is not None:
        v = np.asarray(args.end_pose, float)
        v[:3] *= scale
        try:
            T_base_end = T_from_pose_values(v, VENDOR_POSE_FORMAT)
        except ValueError as e:
            raise ConfigError(f"--end-pose: {e}") from None
    if args.point is not None:
        p = np.asarray(args.point, float) * scale
        pb = points_cam_to_base(p, mode=mode, T_x=T_x, T_base_end=T_base_end)
        print(f"p_base [m]: {pb[0]:.6f} {pb[1]:.6f} {pb[2]:.6f}")
        print(f"p_base [mm]: {pb[0] * 1e3:.3f} {pb[1] * 1e3:.3f} {pb[2] * 1e3:.3f}")
    else:
        v = np.asarray(args.pose, float)
        v[:3] *= scale
        try:
            T_cam_obj = T_from_pose_values(v, VENDOR_POSE_FORMAT)
        except ValueError as e:
            raise ConfigError(f"--pose: {e}") from None
        T = pose_cam_to_base(T_cam_obj, mode=mode, T_x=T_x, T_base_end=T_base_end)
        f = pose_forms(T)
        print("T_base_obj:")
        for row in T:
            print("  [" + " ".join(f"{x:+.6f}" for x in row) + "]")
        print(f"x,y,z,rx,ry,rz (m, rad; R = Rz·Ry·Rx): {f['vendor_pose_line']}")
    return 0


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else (logging.DEBUG if args.verbose else logging.INFO)
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr)
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    try:
        return int(args.func(args) or 0)
    except HandeyeError as e:
        if args.debug:
            raise
        print(f"handeye: error: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("handeye: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
