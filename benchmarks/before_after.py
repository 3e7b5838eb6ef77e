"""The same sessions calibrated by the whole command before a change and after it: the same answers?

A speed change must not change any number, finding or figure. For each session this runs
``handeye calibrate SESSION --out DIR`` (with both reports) in a fresh process with the handeye of
``--before`` and with this checkout's, compares the two folders with ``compare_results.py`` (result.json
field by field, findings, verdict, the reports' sections, figures and tables) and prints, per session,
the verdicts, the exit codes, the number of differences, the largest relative difference of two numbers
and the wall time of each run; then every difference found. Exit code 1 when any session differs.

    python benchmarks/before_after.py --before DIR [--session FOLDER ...] [--data ../shared/data]
                                      [--no-report] [--rtol 1e-6] [--atol 1e-12]

``--before``: a checkout of handeye before the change (e.g. ``git archive HEAD~3 | tar -x -C DIR``); it
runs from a copy laid out as the installed package is (``factors/`` and ``configs/`` inside ``handeye/``),
so that nothing of this checkout stands in for it. Without ``--session``: rendered sessions (an
eye-in-hand chessboard, an eye-to-hand ChArUco with a hidden view and a wrong robot pose, a single
marker, a kinematic arm with ``--robot rm65``), pose-only sessions of both modes, and every real set under
``--data`` imported as ``bench_realdata.py`` imports it (the UR3 cameras also with their joint angles and
the nominal DH table). A cell is not a session here (``bench_cell.py --before``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def installed_layout(checkout: Path, dest: Path) -> Path:
    """A copy of ``checkout``'s package as pip installs it (handeye/, handeye/factors, handeye/configs)."""
    pkg = dest / "handeye"
    shutil.copytree(checkout / "handeye", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    for sub in ("factors", "configs"):
        if (checkout / sub).is_dir() and not (pkg / sub).exists():
            shutil.copytree(checkout / sub, pkg / sub, ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def default_sessions(tmp: Path, data: Path) -> list[tuple[str, Path, list[str]]]:
    """(name, session folder, extra calibrate flags) of the default sessions."""
    from handeye.cli.simulate import sim_target
    from handeye.sim.arm_tracker import make_arm_tracker_session
    from handeye.sim.poses import make_tracker_session
    from handeye.sim.vendor import write_vendor_session

    s = tmp / "sessions"
    out = [
        ("rendered eye-in-hand", write_vendor_session(s / "eih", n_views=20, seed=1), []),
        (
            "rendered eye-to-hand ChArUco, hidden view, wrong pose",
            write_vendor_session(
                s / "eth",
                mode="eye_to_hand",
                n_views=14,
                seed=2,
                hidden_views=("4",),
                outlier_views=("7",),
                target=sim_target("charuco"),
            ),
            [],
        ),
        (
            "rendered single marker",
            write_vendor_session(s / "marker", n_views=12, seed=3, target=sim_target("marker")),
            [],
        ),
        (
            "rendered kinematic arm, --robot rm65",
            write_vendor_session(s / "kin", mode="eye_to_hand", n_views=14, seed=4, robot_error="kinematic"),
            ["--robot", "rm65"],
        ),
        ("pose-only eye-in-hand", make_tracker_session(mode="eye_in_hand", n_views=15, seed=6).write(s / "p_eih"), []),
        (
            "pose-only eye-to-hand, arm error",
            make_arm_tracker_session(
                mode="eye_to_hand", n_views=16, seed=7, dh_length_error_mm=(0.1, 0.5), dh_angle_error_deg=(0.01, 0.05)
            ).write(s / "p_eth", state_sigma=False),
            ["--robot-accuracy", "0.5", "0.04"],
        ),
    ]
    if data.is_dir():
        sys.path.insert(0, str(HERE))
        from bench_realdata import HALF_SETS, import_set

        for name in ("visp-franka-eye-in-hand", *HALF_SETS):
            if (data / name).is_dir():
                out.append((name, import_set(name, data / name, s / name), []))
                if name.startswith("ur3"):
                    kin = import_set(name, data / name, s / f"{name}-joints", kinematic=True)
                    out.append((f"{name} (joints, DH table)", kin, []))
    return out


def calibrate(session: Path, out: Path, flags: list[str], env: dict, cwd: Path) -> tuple[int, float]:
    """(exit code, wall seconds) of ``handeye calibrate`` in a fresh process.

    ``cwd``: a folder without a ``handeye`` package (``python -m`` puts the working folder first on the path,
    before PYTHONPATH: run from a checkout, it would import that checkout's handeye on both sides).
    """
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "handeye.cli", "-q", "calibrate", str(session), "--out", str(out), *flags]
    code = subprocess.run(cmd, env=env, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    return code, time.perf_counter() - t0


def handeye_file(env: dict, cwd: Path) -> str:
    """Where ``import handeye`` finds the package in ``env``: checked, so that no side runs the other's code."""
    code = "import handeye.stats, pathlib; print(pathlib.Path(handeye.stats.__file__).resolve().parent)"
    return subprocess.run([sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True).stdout.strip()


def verdict(out: Path) -> str:
    try:
        return str(json.loads((out / "result.json").read_text(encoding="utf-8")).get("verdict"))
    except (OSError, ValueError):
        return "no result"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="a checkout of handeye before the change")
    ap.add_argument("--session", type=Path, action="append", help="a session folder (default: see above)")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data", help="the real sets")
    ap.add_argument("--no-report", action="store_true", help="calibrate without the reports")
    ap.add_argument("--rtol", type=float, default=1e-6, help="compare_results.py's relative tolerance")
    ap.add_argument("--atol", type=float, default=1e-12, help="its absolute tolerance (0: every difference counts)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="before_after_"))
    try:
        before = installed_layout(args.before.resolve(), tmp / "before")
        sessions = [(str(p), p, []) for p in args.session] if args.session else default_sessions(tmp, args.data)
        base = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONDONTWRITEBYTECODE")}
        envs = {
            "before": {**base, "PYTHONPATH": str(before), "PYTHONPYCACHEPREFIX": str(tmp / "pyc_before")},
            "after": {**base, "PYTHONPATH": str(ROOT), "PYTHONPYCACHEPREFIX": str(tmp / "pyc_after")},
        }
        flags_all = ["--no-report"] if args.no_report else []
        where = {side: handeye_file(envs[side], tmp) for side in envs}
        if where["before"] == where["after"] or not where["before"].startswith(str(before)):
            sys.exit(f"before_after: both sides import {where['before']}; expected {before} and {ROOT}")
        print(f"before: {args.before} ({where['before']})   after: {where['after']}   {len(sessions)} sessions\n")
        head = f"{'session':48s} {'verdict before / after':24s} {'exit':7s} {'diffs':>5s} {'max rel':>9s}"
        print(f"{head} {'wall b / a [s]':>15s}")
        details, any_diff = [], False
        for k, (name, session, flags) in enumerate(sessions):
            outs, codes, walls = {}, {}, {}
            for side in ("before", "after"):
                outs[side] = tmp / "results" / f"{k}_{side}"
                codes[side], walls[side] = calibrate(session, outs[side], [*flags, *flags_all], envs[side], tmp)
            cmp = subprocess.run(
                [sys.executable, str(HERE / "compare_results.py"), str(outs["before"]), str(outs["after"]),
                 "--rtol", str(args.rtol), "--atol", str(args.atol)],
                capture_output=True, text=True, env=envs["after"], cwd=tmp,
            )  # fmt: skip
            lines = [ln for ln in cmp.stdout.splitlines() if ln.strip()]
            summary = lines[-1] if lines else cmp.stderr.strip()
            n_diff = len(lines) - 1 if cmp.returncode else 0
            m = re.search(r"largest relative difference ([-+.e0-9]+)", summary)
            worst = m.group(1) if m else "-"
            same_code = codes["before"] == codes["after"]
            any_diff |= bool(cmp.returncode) or not same_code
            print(
                f"{name[:48]:48s} {verdict(outs['before']) + ' / ' + verdict(outs['after']):24s} "
                f"{codes['before']}/{codes['after']:<5d} {n_diff:5d} {worst[:9]:>9s} "
                f"{walls['before']:6.2f} / {walls['after']:5.2f}"
            )
            if cmp.returncode or not same_code:
                details.append((name, lines))
        for name, lines in details:
            print(f"\n{name}:")
            for ln in lines[:40]:
                print(f"  {ln}")
        print("\nevery session the same" if not any_diff else f"\n{len(details)} sessions differ")
        return 1 if any_diff else 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
