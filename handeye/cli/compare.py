"""``handeye compare RESULT_A RESULT_B``: the difference between two calibrations of one rig.

stdout: per axis the difference of X (mm, deg) with the sigma of the difference, the squared
Mahalanobis distance under the sum of the two covariances and its p-value (of X given the intrinsics
difference when both results carry the joint covariance, :mod:`handeye.recal.compare`), the same for the
intrinsics; ``--json`` prints :meth:`handeye.recal.compare.Comparison.to_dict` instead. Results
that do not describe one quantity (mode, frames, board, camera resolution) are refused in one line
(exit 2); a difference beyond the uncertainty exits with the DRIFTED code
(:data:`handeye.errors.EXIT_CODES`).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    """The command's description and arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..errors import exit_codes_text

    p.description = (
        "Compare two calibrations of one rig: B - A of the hand-eye transform per axis (mm, deg), "
        "the squared Mahalanobis distance under the sum of both covariances (the ones each "
        "result's verdict uses) with its p-value, and the same for fx, fy, cx, cy. When both results "
        "carry the joint covariance of X and the intrinsics, X is tested given the intrinsics "
        "difference (the part of the difference an intrinsics change explains taken out; the test of "
        "X alone is printed beside it). Refuses results of different modes, frames, boards or camera "
        "resolutions. The exit code follows the test of X (9: drifted); the intrinsics' test is "
        "printed beside it."
    )
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = exit_codes_text()
    p.add_argument("result_a", type=Path, help="the earlier result folder (or its result.json)")
    p.add_argument("result_b", type=Path, help="the later result folder (or its result.json)")
    p.add_argument("--alpha", type=float, default=None, help="level of the test (default 0.05)")
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument(
        "--camera",
        metavar="NAME",
        help="a cell (several cameras of one arm): compare this camera (needed when one result is a cell and the "
        "other is not; two cells without it: every common camera and camera pair)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import DRIFTED_EXIT_CODE, InputError
    from ..output import to_json
    from ..recal.compare import ALPHA, compare_results, comparison_lines

    alpha = ALPHA if args.alpha is None else float(args.alpha)
    if not 0.0 < alpha < 1.0:
        raise InputError("--alpha must be a probability", expected="0 < alpha < 1", received=str(args.alpha))
    from ..contract import read_result
    from ..recal.loaded import load_result, unfit_note

    cells = [read_result(r).is_cell for r in (args.result_a, args.result_b)]
    if all(cells) and args.camera is None:
        return run_cells(args, alpha)
    cams = [args.camera if is_cell else None for is_cell in cells]
    if args.camera is not None and not any(cells):
        cams = [args.camera, args.camera]  # refused by the reader in one line: neither is a cell
    for r, cam in zip((args.result_a, args.result_b), cams, strict=True):
        note = unfit_note(load_result(r, camera=cam))
        if note:
            log.warning("%s", note)
    c = compare_results(args.result_a, args.result_b, alpha=alpha, camera_a=cams[0], camera_b=cams[1])
    if not c.comparable:
        raise InputError(
            f"the two results are not comparable: {c.reason}",
            code="not_comparable",
            hint="compare calibrations of one rig (same mode, board and camera resolution)",
        )
    if args.json:
        print(to_json({**c.to_dict(), "camera": args.camera}))
    else:
        print("\n".join(([f"camera {args.camera}:"] if args.camera else []) + comparison_lines(c)))
    return DRIFTED_EXIT_CODE if c.drifted else 0


def run_cells(args, alpha: float) -> int:
    """Two cells: every common camera and camera pair (:mod:`handeye.recal.cells`)."""
    from ..contract import read_result
    from ..errors import DRIFTED_EXIT_CODE
    from ..output import to_json
    from ..recal.cells import cell_comparison_lines, compare_cells
    from ..recal.loaded import load_result, unfit_note

    for r in (args.result_a, args.result_b):
        for n in read_result(r).camera_names:
            note = unfit_note(load_result(r, camera=n))
            if note:
                log.warning("%s", note)
    c = compare_cells(args.result_a, args.result_b, alpha=alpha)
    print(to_json(c.to_dict()) if args.json else "\n".join(cell_comparison_lines(c)))
    return DRIFTED_EXIT_CODE if c.drifted else 0
