"""``handeye demo``: simulate a rendered session, calibrate it and compare with the ground truth."""

from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    """The command's arguments (its one-line help is in handeye.cli.COMMANDS)."""
    from ..mounting import MODES
    from .numbers import demo_views, seed_int

    p.add_argument("--out", type=Path, default=Path("reports/demo"), help="folder for the session and results")
    p.add_argument("--mode", choices=MODES, default="eye_in_hand")
    p.add_argument("--views", type=demo_views, default=20, help="rendered views, at least 4 (default 20)")
    p.add_argument("--seed", type=seed_int, default=0, help="random seed of the simulated session")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    import numpy as np

    from ..contract import read_result
    from ..frames import pose_error
    from ..mounting import mounting
    from ..output import check_out_dir
    from . import build_parser, calibrate, simulate

    check_out_dir(args.out, option="--out")  # not a file, not under one, writable: before the rendering
    session_dir = args.out / "session"
    log.info("rendering a synthetic %s session with %d views into %s", args.mode, args.views, session_dir)
    # a realistic session: image noise, a little blur, and one view without the board
    # parsed like the command line, so that every other simulate option keeps its default
    sim_args = build_parser().parse_args(
        [
            "simulate",
            str(session_dir),
            "--mode",
            args.mode,
            "--views",
            str(args.views),
            "--seed",
            str(args.seed),
            "--noise-px",
            "2.0",
            "--blur",
            "0.5",
            "--hidden",
            str(max(2, args.views // 2)),
            # a session an earlier demo rendered (it has its ground truth) is rendered again; anything else is
            # refused by simulate, naming the folder
            *(["--force"] if (session_dir / "ground_truth.json").is_file() else []),
        ]
    )
    simulate.run(sim_args)
    cal_args = build_parser().parse_args(["calibrate", str(session_dir), "--out", str(args.out / "result")])
    cal_args.debug = getattr(args, "debug", False)
    rc = calibrate.run(cal_args)
    res = read_result(args.out / "result" / "result.json")
    if res.ok and res.T_x is not None:  # a matrix, whatever its verdict: compare it with the truth
        truth = json.loads((session_dir / "ground_truth.json").read_text())
        name = mounting(args.mode).x_name
        r, t = pose_error(res.T_x, np.asarray(truth[name]))
        print(f"error against the ground truth: {t:.3f} mm, {r:.4f} deg")
    return rc
