"""``handeye calibrate SESSION``: the whole workflow on one session folder, its summary and verdict.

stdout: the views used, the result block (matrix, forms, 1-sigma), then the verdict line and every
warning or failing QA check and finding with its fix (:mod:`.verdict`), then the files written. The
exit code is the error's, or the verdict's (:data:`handeye.errors.EXIT_CODES`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ..options import (  # noqa: F401 (check_site_config, options_from_args, POSE_ONLY_REFUSED: re-exported)
    POSE_ONLY_REFUSED,
    check_site_config,
    options_from_args,
    refuse_pose_only_flags,
)
from .numbers import positive_float, positive_int

log = logging.getLogger(__name__)


def _sigma_source_words(src: str, ref: dict) -> str:
    """result.json's sigma_source (which covariance the verdict uses) in the words of the printed result."""
    validated = (ref.get("validation") or {}).get("status") == "ok"
    return {
        "model": (
            "from the model covariance; the held-out folds agree with it"
            if validated
            else "from the model covariance; not validated"
        ),
        "validated": "from the spread over held-out folds, larger than the model's",
        "model+validated": "the larger of the model's and the held-out folds' in each direction",
    }.get(src, src) + (", plus the arm's stated accuracy" if ref.get("robot_accuracy") else "")


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..config import arm_presets
    from ..errors import exit_codes_text
    from ..mounting import MODES
    from ..records import METHOD_NAMES

    p.description = (
        "Detect the target, calibrate the camera, start from an OpenCV closed-form solution and "
        "refine jointly; writes DIR/result.json, observations.json, thumbnails/ and the reports. "
        "Prints the result, then the verdict (PASS / WARN / FAIL / REFUSED) and every warning or "
        "failure with its fix."
    )
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = exit_codes_text()
    inp = p.add_argument_group("input")
    model = p.add_argument_group("model")
    out = p.add_argument_group("output")
    rep = p.add_argument_group("reporting")
    inp.add_argument(
        "session",
        nargs="+",
        help="session folder (poses.txt + N.jpg + config.yaml, or session.yaml); several sessions of one arm, or "
        "a cell folder with cell.yaml, are calibrated as one cell (one result.json, each folder's name a camera)",
    )
    inp.add_argument(
        "--mode",
        choices=MODES,
        help="mounting mode (overrides the session's own; default: mode: in config.yaml or session.yaml, else "
        "detected from the data, eye_in_hand only when the data do not decide it)",
    )
    model.add_argument(
        "--method",
        choices=METHOD_NAMES,
        help="closed-form method reported as the seed (the result with --no-refine); the refinement "
        "starts from it unless another closed form explains the views better (default: tsai, "
        "from the preset)",
    )
    inp.add_argument("--config", type=Path, help="site YAML overriding configs/calibration.yaml (same keys)")
    out.add_argument(
        "--out",
        type=Path,
        help="output folder (default: reports/<session folder name>-<8 hex digits of its full path>); "
        "checked before the work starts and locked while the run writes into it",
    )
    model.add_argument("--no-refine", action="store_true", help="stop at the closed-form solution")
    model.add_argument("--fix-k3", action="store_true", help="hold the k3 distortion coefficient at 0")
    model.add_argument(
        "--fix",
        nargs="+",
        metavar="NAME",
        choices=["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
        help="intrinsics held at their starting values in the refinement (e.g. --fix p1 p2 k3)",
    )
    model.add_argument(
        "--robot-noise",
        choices=["estimate", "fixed", "none"],
        default=None,
        help="robot pose noise model in the refinement (default: estimate)",
    )
    model.add_argument(
        "--robot-sigma",
        nargs=2,
        type=positive_float,
        metavar=("MM", "DEG"),
        help="robot pose sigma: start value (estimate) or the value (fixed)",
    )
    model.add_argument(
        "--robot",
        metavar="ARM",
        help=f"the arm's kinematic model (a preset: {', '.join(arm_presets())}; or a DH YAML file): "
        "the refinement models the robot's "
        "error as DH offsets plus encoder noise (joint angles from the session, else by inverse "
        "kinematics of the poses); default: the session's robot: key, else an iid pose error (pose-only "
        "sessions: the DH offsets and the encoder noise enter the pose graph, the encoder noise held at the "
        "arm's prior)",
    )
    model.add_argument(
        "--robot-accuracy",
        nargs=2,
        type=positive_float,
        metavar=("MM", "DEG"),
        help="the arm's stated accuracy: its flange pose error per axis, the same over the session's workspace. "
        "The data cannot show such an error (it enters X one to one); its covariance is added to the verdict "
        "covariance (result.json refinement.robot_accuracy); also robot_accuracy: {mm, deg} in session.yaml; "
        "refused with --robot, whose DH prior states the arm's accuracy",
    )
    model.add_argument(
        "--estimate-scale",
        action="store_true",
        help="pose-only sessions: estimate the tracker's translation scale (a wrong marker size, monocular SLAM) "
        "jointly with X, with its sigma (result.json refinement.tracker_scale); also estimate_scale: true in "
        "session.yaml; image sessions refuse it (their scale is the board's square size), and so does --robot",
    )
    inp.add_argument("--workers", type=positive_int, help="threads for corner detection (default: all cores)")
    rep.add_argument(
        "--qa",
        type=Path,
        metavar="FILE",
        help="site QA thresholds for the verdict and the report (overrides configs/qa.yaml)",
    )
    rep.add_argument(
        "--no-report", action="store_true", help="write result.json, observations.json and thumbnails only"
    )
    inp.add_argument(
        "--shift-poses",
        type=int,
        default=0,
        metavar="N",
        help="pair image k with the pose written for image k+N (the constant shift a refused run names)",
    )
    model.add_argument(
        "--prior",
        type=Path,
        metavar="RESULT",
        help="an earlier result of this rig: its X and intrinsics enter as priors with their covariances "
        "(a few new views update it); result.json's prior block says whether the data contradict it "
        "(then the session is calibrated without the prior on X, and the drift is printed)",
    )
    model.add_argument(
        "--board-unmoved",
        action="store_true",
        help="with --prior: the board has not been touched since the earlier calibration (bolted to the "
        "flange or the table); when the data contradict the prior on X, the earlier board pose enters "
        "too, so each new view measures X through it (a board moved by a millimetre would then move "
        "X: a few views cannot tell that from a bumped camera)",
    )
    inp.add_argument(
        "--allow-outside",
        action="store_true",
        help="let session.yaml's image and pose-file paths leave the session folder (refused by default)",
    )
    from ..export import FORMATS as EXPORT_FORMATS

    out.add_argument(
        "--export",
        choices=list(EXPORT_FORMATS),
        metavar="FORMAT",
        help="also write the result for robot software next to result.json: "
        + ", ".join(EXPORT_FORMATS)
        + " (as handeye export; not for a FAIL or REFUSED verdict; an export that fails gives its exit code)",
    )
    p.set_defaults(func=run)


def default_out_dir(session) -> Path:
    """``reports/<session folder name>-<8 hex digits of the SHA-1 of its absolute path>``.

    Two sessions of the same folder name (a/session, b/session) never share an output folder. The name
    keeps what ``str.isprintable`` accepts (no control character, line break or undecodable byte reaches
    a file name; the hash still tells such folders apart), ``session`` when nothing is left.
    """
    import hashlib
    import os

    p = Path(session).resolve()
    folder = p.parent if p.is_file() else p
    name = "".join(c for c in folder.name if c.isprintable()).strip() or "session"
    return Path("reports") / f"{name}-{hashlib.sha1(os.fsencode(folder)).hexdigest()[:8]}"


def run(args) -> int:
    from ..report.figure_process import figure_process

    sessions = list(args.session) if isinstance(args.session, (list, tuple)) else [args.session]
    # the report's figure process: forked once the images are detected, it imports matplotlib meanwhile
    with figure_process(enabled=not args.no_report and len(sessions) == 1) as figures:
        from ..workflow import calibrate_session  # noqa: F401 - imported before the imports are frozen
        from . import freeze_imports

        freeze_imports()
        if len(sessions) > 1 or _is_cell(sessions[0]):
            return run_cell(args, sessions)
        args.session = sessions[0]
        return _run_session(args, figures)


def _run_session(args, figures) -> int:
    """``handeye calibrate SESSION``; ``figures``: the command's figure process (None: drawn in this process)."""
    from ..workflow import calibrate_session

    refuse_pose_only_flags(args)
    if getattr(args, "board_unmoved", False) and getattr(args, "prior", None) is None:
        from ..errors import InputError

        raise InputError(
            "--board-unmoved says the board stayed since the earlier calibration given by --prior",
            expected="--prior RESULT with it",
            received="no --prior",
            hint="add --prior RESULT, or drop --board-unmoved",
        )
    out = args.out or default_out_dir(args.session)
    wr = calibrate_session(
        args.session,
        out_dir=out,
        **_run_options(args),
        prior=getattr(args, "prior", None),
        board_unmoved=getattr(args, "board_unmoved", False),
        figure_process=figures,
    )
    if wr.run is None:  # the session could not be read: result.json and the report say why
        from .verdict import finding_lines

        for line in finding_lines(wr.result, skip=("session_unreadable",)):  # what else the diagnostics saw
            print(line)
        for p in wr.report_paths:
            print(f"report: {p}")
        assert wr.error is not None, "a run that could not read its session has its error"
        raise wr.error
    print(format_summary(wr.result, wr.result_path, wr.report_paths))
    if (wr.result.get("prior") or {}).get("summary"):  # --prior: what the earlier result became
        print(f"prior: {wr.result['prior']['summary']}")
    if wr.status != "ok":
        if getattr(args, "debug", False):
            assert wr.error is not None, "a failed run has its error"
            raise wr.error
        reason = str(wr.result["failure_reason"])
        what = "refused" if wr.verdict == "REFUSED" else "calibration failed"
        if reason.startswith("the session was refused"):  # says so itself: not 'refused: the session was refused'
            print(f"handeye: {reason}", file=sys.stderr)
        else:
            print(f"handeye: {what}: {reason}", file=sys.stderr)
        return wr.exit_code or 1
    if getattr(args, "export", None):
        code = _export_beside(wr.out_dir, args.export)
        if code and not wr.exit_code:
            return code
    if wr.exit_code:
        print(f"handeye: verdict {wr.verdict}: {wr.result.get('verdict_headline', '')}", file=sys.stderr)
    return wr.exit_code


def _run_options(args) -> dict:
    """The keyword arguments a session's and a cell's calibration share, from the command line."""
    return dict(
        options=options_from_args(args),
        report=not args.no_report,
        qa=getattr(args, "qa", None),
        mode=args.mode,
        progress=lambda s: log.info("%s", s),
        allow_outside=getattr(args, "allow_outside", False),
        site_files=[f for f in (getattr(args, "config", None), getattr(args, "qa", None)) if f],
    )


def _export_beside(out_dir: Path, fmt: str) -> int:
    """``handeye export RESULT --to FORMAT`` next to the result (a cell: every camera); its exit code, 0 when done.

    The calibration stands when the export is refused: the code says the export is missing.
    """
    from ..errors import HandeyeError
    from ..export import export_result
    from ..export.writers import text_line

    try:
        for path in export_result(out_dir, fmt):
            print(f"{fmt}: {text_line(path)}")
    except HandeyeError as e:
        print(f"handeye: not exported: {e}", file=sys.stderr)
        return e.exit_code
    return 0


def _is_cell(path) -> bool:
    from ..session.fields import is_cell_folder

    return is_cell_folder(path)


def run_cell(args, sessions: list) -> int:
    """``handeye calibrate S1 S2 ...`` or ``CELL_DIR``: one cell (:func:`handeye.cell.calibrate_cell`)."""
    from ..cell import calibrate_cell
    from ..errors import InputError

    if getattr(args, "prior", None):
        raise InputError(
            "--prior is for one session, not a cell",
            received=" ".join(str(s) for s in sessions),
            hint="calibrate the cell without it, or verify one camera: handeye verify SESSION --against CELL",
        )
    if args.out is None:
        raise InputError("a cell needs --out DIR", received=" ".join(str(s) for s in sessions), hint="add --out DIR")
    wr = calibrate_cell(sessions, args.out, **_run_options(args))
    print(format_cell_summary(wr.result, wr.result_path, wr.report_paths))
    if getattr(args, "export", None) and wr.result.get("status") == "ok":
        code = _export_beside(Path(args.out), args.export)
        if code and not wr.exit_code:
            return code
    if wr.exit_code:
        print(f"handeye: verdict {wr.verdict}: {wr.result.get('verdict_headline', '')}", file=sys.stderr)
    return wr.exit_code


def format_cell_summary(res: dict, result_path: Path, report_paths=()) -> str:
    """The lines ``handeye calibrate`` prints for a cell: each camera's X and sigma, the pairs, the findings."""
    from .verdict import problem_lines

    lines = [str(res.get("verdict_headline", ""))]
    for name, c in res["cameras"].items():
        if c.get("status") != "ok":
            lines.append(f"  {name}: failed: {c.get('failure_reason', '')}")
            continue
        he, r = c["hand_eye"], c.get("refinement") or {}
        t, s = he["translation_mm"], r.get("sigma_trans_mm") or [float("nan")] * 3
        agree = (r.get("solo") or {}).get("agreement") or {}
        lines.append(
            f"  {name} {he['name']}: translation [mm] {t[0]:+.2f} {t[1]:+.2f} {t[2]:+.2f} "
            f"(1-sigma {s[0]:.3f} {s[1]:.3f} {s[2]:.3f}), {c.get('verdict')}; solo vs joint Mahalanobis "
            f"{agree.get('mahalanobis', float('nan')):.2f}"
        )
        lines += ["  " + line for line in problem_lines(c)]  # the camera's own checks and findings, with fixes
    for p in (res.get("camera_pairs") or {}).values():
        t, s = p["translation_mm"], p["sigma_trans_mm"]
        lines.append(
            f"  {p['name']}: translation [mm] {t[0]:+.2f} {t[1]:+.2f} {t[2]:+.2f} (1-sigma {s[0]:.3f} {s[1]:.3f} "
            f"{s[2]:.3f}), rotation 1-sigma [deg] {' '.join(f'{x:.4f}' for x in p['sigma_rot_deg'])}"
        )
    for f in res.get("findings") or []:
        if f.get("camera") not in res["cameras"]:  # a camera's own is among its lines above
            lines.append(f"  {f['severity'].upper()} {f['title']}: {f['evidence']}")
    lines.append(f"result: {result_path}")
    for p in report_paths:
        lines.append(f"report: {p}")
    return "\n".join(lines)


def format_summary(res: dict, result_path: Path, report_paths=()) -> str:
    """The lines ``handeye calibrate`` prints on stdout.

    The lines ``handeye calibrate`` prints on stdout: views used (and the mode, when the data chose
    it), the transform and its uncertainty, the verdict with every warning and failure, the files.
    """
    import numpy as np

    from .. import __version__
    from ..mounting import mounting
    from ..report.formatting import num
    from .verdict import mode_lines, verdict_lines

    lines = []
    mode = res["mode"]
    used, total = res["n_views"]["used"], res["n_views"]["total"]
    how = (
        f", method {res['method']}" + (" + joint refinement" if res.get("refined") else " (closed form only)")
        if res["status"] == "ok"
        else ", no result"
    )
    counts = f"{used}/{total} views used" if res["status"] == "ok" else f"{total} views"
    lines.append(f"handeye {__version__}: {mode}, {counts}{how}")
    lines += mode_lines(res)
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
        lines.append(
            f"  vendor x,y,z,rx,ry,rz (m, rad; R = Rz·Ry·Rx): {he['vendor_pose_line']}"
            f"  [deg: {e[0]:+.3f} {e[1]:+.3f} {e[2]:+.3f}]"
        )
        ref = res.get("refinement") or {}
        sig = ref.get("sigma_trans_mm")
        if sig is not None:
            sr = ref.get("sigma_rot_deg") or ()  # written together with sigma_trans_mm
            src = ref.get("sigma_source")  # which covariance the verdict sigmas are (result.json's refinement block)
            lines.append(
                "  1-sigma: translation [mm] "
                + " ".join(num(x, 3) for x in sig)  # a small sigma is not 0.000
                + ", rotation [deg] "
                + " ".join(num(x, 3) for x in sr)
                + (f" ({_sigma_source_words(src, ref)})" if src else "")
            )
        if ref.get("predicted_error_mm") is not None:
            lines.append(
                f"  predicted position error at {ref.get('working_distance_m', float('nan')):.2f} m: "
                f"{ref['predicted_error_mm']:.2f} mm (1 sigma)"
            )
    elif "verdict" not in res:
        lines.append(f"FAILED: {res['failure_reason']}")
    lines += verdict_lines(res)
    lines.append(f"result: {result_path}")
    for p in report_paths:
        lines.append(f"report: {p}")
    return "\n".join(lines)
