"""``handeye verify SESSION --against RESULT``: whether an installed calibration is still valid.

A short session (3-8 views, the board anywhere) is tested against the installed hand-eye transform
(and intrinsics, unless the session brings its own) without re-solving it
(:mod:`handeye.recal.verify`). stdout: the verdict line (still valid / DRIFTED) with the test
statistic and p-value, the estimated change per axis with 1-sigma, what moved, the files written
(verify.json, verify.html, verify.md). Exit 0 when still valid, 9 (DRIFTED) when drifted.

``handeye verify --plan --against RESULT [--drift-mm 1 --drift-deg 0.1]``: how many views, and which
robot poses, detect that drift with 95 % power (:mod:`handeye.recal.plan`); nothing is captured.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..errors import exit_codes_text
    from ..mounting import MODES

    p.description = (
        "Check a short session (3-8 views; the board may be anywhere) against an installed calibration "
        "without re-solving it: a Wald test of X = X_installed, the change of X estimated jointly with "
        "the installed intrinsics the new views share (under the installed covariances its verdict "
        "uses and the new views' noise), its p-value, the estimated change of X with 1-sigma, what "
        "moved (camera mount, board, robot), and the verdict 'still valid' or 'drifted' (exit code 9). Writes "
        "verify.json, verify.html and verify.md. With --plan: the views and robot poses that detect a "
        "drift of --drift-mm / --drift-deg with 95 % power."
    )
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = exit_codes_text()
    p.add_argument(
        "session",
        nargs="*",
        help="the verification session folder (not with --plan); against a cell, one per camera, each folder "
        "named after its camera",
    )
    p.add_argument(
        "--against",
        required=True,
        type=Path,
        metavar="RESULT",
        help="the installed calibration: a result folder or its result.json",
    )
    p.add_argument(
        "--out",
        type=Path,
        help="output folder (default: reports/<session folder>-<hash>-verify); with "
        "--plan: where plan.json is written (default: printed only)",
    )
    p.add_argument("--mode", choices=MODES, help="mounting mode of the session (default: the installed result's)")
    p.add_argument(
        "--camera",
        metavar="NAME",
        help="against a cell (several cameras of one arm): the camera the session is of (default: the session "
        "folder's name when it is one of the cell's cameras)",
    )
    p.add_argument("--alpha", type=float, help="level of the test (default 0.05, configs/recal.yaml)")
    p.add_argument("--no-report", action="store_true", help="write verify.json only")
    p.add_argument("--json", action="store_true", help="print verify.json's content instead of the summary")
    p.add_argument("--plan", action="store_true", help="plan a verification instead of running one")
    p.add_argument("--drift-mm", type=float, help="with --plan: translation drift to detect (default 1 mm)")
    p.add_argument("--drift-deg", type=float, help="with --plan: rotation drift to detect (default 0.1 deg)")
    p.add_argument("--power", type=float, help="with --plan: detection probability wanted (default 0.95)")
    p.set_defaults(func=run)


def _check_probability(name: str, v) -> None:
    from ..errors import InputError

    if v is not None and not 0.0 < float(v) < 1.0:
        raise InputError(f"{name} must be a probability", expected="a number between 0 and 1", received=str(v))


def run(args) -> int:
    from ..errors import InputError

    _check_probability("--alpha", args.alpha)
    _check_probability("--power", args.power)
    from ..contract import read_result

    cameras = read_result(args.against).camera_names  # [] for a one-camera result
    if args.plan:
        if args.session:
            raise InputError(
                "--plan takes no session",
                received=" ".join(args.session),
                hint="handeye verify --plan --against RESULT",
            )
        warn_unfit(args.against, args.camera)
        return run_plan(args)
    if not args.session:
        raise InputError("no session to verify", hint="handeye verify SESSION --against RESULT (or --plan)")
    for name in ("drift_mm", "drift_deg", "power"):
        if getattr(args, name) is not None:
            raise InputError(f"--{name.replace('_', '-')} only applies with --plan")
    if len(args.session) > 1:
        if args.json:
            raise InputError(
                "--json prints one verification",
                received=f"{len(args.session)} sessions",
                hint="read each camera's verify.json (--out OUT: OUT/<camera>/verify.json), or verify one session",
            )
        if not cameras or args.camera is not None:
            raise InputError(
                f"{len(args.session)} sessions: several sessions are verified against a cell, each its camera "
                "by its folder's name" + (" (without --camera)" if cameras else ""),
                hint="verify one session per run" + (", or drop --camera" if cameras else ""),
            )
        return run_cell_verify(args, cameras)
    from ..recal.loaded import session_camera

    session = args.session[0]
    camera = session_camera(args.against, session, args.camera)
    warn_unfit(args.against, camera)
    return run_verify(args, session, camera)


def warn_unfit(against, camera) -> None:
    """Log a warning when the installed result (a cell's camera) has a FAIL verdict."""
    from ..recal.loaded import load_result, unfit_note

    note = unfit_note(load_result(against, camera=camera))
    if note:
        log.warning("%s", note)


def run_verify(args, session, camera) -> int:
    from ..recal.loaded import load_result
    from ..recal.verify import VerifyOptions, verify_session
    from .calibrate import default_out_dir

    opts = VerifyOptions.from_config(alpha=args.alpha)
    installed = load_result(args.against, camera=camera)
    sv = verify_session(session, installed, options=opts, mode=args.mode, progress=log.info)
    calibrate_out = default_out_dir(session)
    out = Path(args.out) if args.out else calibrate_out.with_name(calibrate_out.name + "-verify")
    return finish_verification(sv, out, reports=not args.no_report, as_json=args.json)


def run_cell_verify(args, cameras: list[str]) -> int:
    """Several sessions against a cell: each its camera's verification (``--out``/<camera>), then the cell's verdict."""
    from ..errors import DRIFTED_EXIT_CODE, InputError
    from ..recal.loaded import session_camera

    named = [str(session_camera(args.against, s)) for s in args.session]  # a cell: each session names one
    twice = sorted({n for n in named if named.count(n) > 1})
    if twice:
        raise InputError(f"two sessions are of camera {twice[0]}", hint="verify one session per camera")
    drifted = []
    for session, camera in zip(args.session, named, strict=True):
        warn_unfit(args.against, camera)
        print(f"camera {camera}:")
        sub = argparse.Namespace(**{**vars(args), "out": None if args.out is None else Path(args.out) / camera})
        if run_verify(sub, session, camera) == DRIFTED_EXIT_CODE:
            drifted.append(camera)
    print(
        f"cell: DRIFTED ({', '.join(drifted)})"
        if drifted
        else f"cell: still valid ({len(named)} of {len(cameras)} cameras verified)"
    )
    return DRIFTED_EXIT_CODE if drifted else 0


def finish_verification(sv, out: Path, *, reports: bool = True, as_json: bool = False) -> int:
    """Write verify.json (and its reports) to ``out``, print the summary.

    Write verify.json (and its reports) to ``out``, print the summary (or the JSON) and the files written;
    the exit code: DRIFTED when drifted, else 0.
    """
    from ..errors import DRIFTED_EXIT_CODE
    from ..output import to_json
    from ..recal.report import write_verification

    d, files = write_verification(sv, out, reports=reports)
    if as_json:
        print(to_json(d))
    else:
        print("\n".join(verification_lines(d)))
        for f in files:
            print(f"written: {f}")
    return DRIFTED_EXIT_CODE if sv.verification.drifted else 0


def verification_lines(d: dict) -> list[str]:
    """The summary a person reads: verdict, test, change per axis, what moved."""
    from ..recal.loaded import axes_words
    from ..report.formatting import num

    t, c = d["test"], d["change"]
    lines = [
        d["headline"],
        f"estimated change of {d['frame']} (new - installed; +- 1 sigma, the installed uncertainty included; "
        f"{axes_words(d['frame'])}):",
    ]
    for k, ax in enumerate("xyz"):  # a sigma below the digits is not 0.000; a change of 0 is not -0.000
        lines.append(
            f"  {ax}: {num(c['d_trans_mm'][k], 3, signed=True):>8} +- {num(c['sigma_trans_mm'][k], 3)} mm   "
            f"{num(c['d_rot_deg'][k], 4, signed=True):>8} +- {num(c['sigma_rot_deg'][k], 4)} deg"
        )
    lines.append(
        f"test: statistic {t['statistic']:.2f}, {t['dof']} dof, p = {t['p_value']:.3g} "
        f"(alpha {t['alpha']:g}; reference {t.get('reference') or 'chi-square'}); "
        f"{d['n_views']} views"
    )
    lines += [f"- {s}" for s in d["what_moved"]]
    return lines


def run_plan(args) -> int:
    from ..recal.loaded import load_result
    from ..recal.plan import plan_lines, plan_verification

    p = plan_verification(
        load_result(args.against, camera=args.camera),
        drift_mm=args.drift_mm,
        drift_deg=args.drift_deg,
        power=args.power,
        alpha=args.alpha,
    )
    if args.json:
        from ..output import to_json

        print(to_json(p.to_dict()))
    else:
        print("\n".join(plan_lines(p)))
    if args.out:
        from ..output import check_out_dir, write_json

        path = write_json(check_out_dir(args.out) / "plan.json", p.to_dict())
        if not args.json:
            print(f"written: {path}")
    return 0
