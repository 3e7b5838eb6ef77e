"""Wall time of a whole `handeye calibrate` on a rendered 20-view 1280x720 session, with and without
the reports, with the per-stage `seconds` result.json records, and the start-up cost of the command.
Targets on 2 cores: under 3 s without reports, under 5 s with both reports.
Prints figures; asserts nothing.

    python benchmarks/bench_calibrate.py [--views 20] [--repeat 3] [--mode eye_in_hand]

The command runs in a fresh interpreter each time (as a user runs it), so its wall time includes the
imports; `in-process` is the same workflow (handeye.workflow.calibrate_session) in this process,
after a warm-up, so the difference is the start-up. CPU is the command's user + system time (best
run): on a busy machine (see the load average printed first) it is the steadier figure.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_CPU: list[float] = []  # CPU seconds (user + sys) of each command run, for figures on a busy machine


def _wall(cmd: list[str]) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    _CPU.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return wall


def _fmt(walls: list[float]) -> str:
    cpu, _CPU[:] = min(_CPU[-len(walls) :]), []
    return (
        f"{min(walls):6.2f} s (best of {len(walls)}; all: "
        + ", ".join(f"{w:.2f}" for w in walls)
        + f"; CPU {cpu:.2f} s)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mode", default="eye_in_hand")
    args = ap.parse_args()
    from handeye.cli import prepare_process

    prepare_process()  # the in-process runs get the command's own set-up
    from handeye.config import load_preset
    from handeye.pipeline import CalibrateOptions
    from handeye.sim.vendor import write_vendor_session
    from handeye.workflow import calibrate_session

    py = sys.executable
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    with tempfile.TemporaryDirectory() as tmp:
        sess = write_vendor_session(
            Path(tmp) / "s", mode=args.mode, n_views=args.views, seed=7, hidden_views=("5",), image_noise=2.0
        )
        print(
            f"session: {args.views} rendered 1280x720 views ({args.mode}), one without the board; "
            f"cores: {os.cpu_count()}, load average at start: {load:.1f}"
        )
        print(f"{'python -c pass':32s} wall {_fmt([_wall([py, '-c', 'pass']) for _ in range(args.repeat)])}")
        print(
            f"{'handeye --help':32s} wall "
            f"{_fmt([_wall([py, '-m', 'handeye.cli', '--help']) for _ in range(args.repeat)])}"
        )
        imports = "import handeye.cli, handeye.workflow, handeye.session, handeye.refine, handeye.diagnose"
        walls = [_wall([py, "-c", imports]) for _ in range(args.repeat)]
        print(f"{'imports of the calibrate path':32s} wall {_fmt(walls)}")
        for label, extra in (("calibrate --no-report", ["--no-report"]), ("calibrate (both reports)", [])):
            walls = []
            for k in range(args.repeat):
                out = Path(tmp) / f"out{k}{len(extra)}"
                walls.append(_wall([py, "-m", "handeye.cli", "-q", "calibrate", str(sess), "--out", str(out), *extra]))
                stages = json.loads((out / "result.json").read_text())["seconds"]
            target = 3.0 if extra else 5.0
            print(f"{label:32s} wall {_fmt(walls)}  target < {target:g} s")
            print("    stages [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in stages.items()))
        opts = CalibrateOptions.from_config(load_preset("calibration"))
        for report in (False, True):
            calibrate_session(sess, options=opts, out_dir=Path(tmp) / "warm", report=report)
            walls = []
            for k in range(args.repeat):
                t0, c0 = time.perf_counter(), time.process_time()
                calibrate_session(sess, options=opts, out_dir=Path(tmp) / f"in{k}{report}", report=report)
                walls.append(time.perf_counter() - t0)
                _CPU.append(time.process_time() - c0)  # this process only (report plots may use others)
            print(f"{'in-process, ' + ('with reports' if report else 'no report'):32s} wall {_fmt(walls)}")


if __name__ == "__main__":
    main()
