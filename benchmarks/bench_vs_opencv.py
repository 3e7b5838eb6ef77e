"""The whole ``handeye calibrate`` against the bare OpenCV script it replaces, in interleaved rounds.

Prints the median wall and CPU time of each command over the rounds, the ratio to the bare script
(``vendor_bare.py``: findChessboardCorners + cornerSubPix, calibrateCamera, calibrateHandEye), and
where handeye's time goes: the interpreter start-up and imports before ``main()``, each named stage
of result.json's ``seconds``, and the time outside the named stages. Asserts nothing.

    python benchmarks/bench_vs_opencv.py [--views 20] [--rounds 5] [--session FOLDER]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def run(cmd: list[str]) -> tuple[float, float]:
    """(wall, CPU) seconds of one command in a fresh process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--session", type=Path, help="a vendor session folder (default: a rendered one)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_vs_opencv_"))
    session = args.session
    if session is None:
        from handeye.sim.vendor import write_vendor_session

        session = write_vendor_session(tmp / "session", n_views=args.views, seed=1)
    py = sys.executable
    commands = {
        "bare OpenCV script": [py, str(HERE / "vendor_bare.py"), str(session)],
        "calibrate (both reports)": [py, "-m", "handeye.cli", "-q", "calibrate", str(session), "--out", str(tmp / "r")],
        "calibrate --no-report": [
            py, "-m", "handeye.cli", "-q", "calibrate", str(session), "--out", str(tmp / "n"), "--no-report",
        ],
        "import handeye.cli": [py, "-c", "import handeye.cli"],
        "python -c pass": [py, "-c", "pass"],
    }  # fmt: skip
    load = os.getloadavg()[0]
    print(f"session {session} ({args.views} views), {args.rounds} interleaved rounds, load average {load:.1f}")
    times: dict = {k: [] for k in commands}
    stages: dict = {}
    for _ in range(args.rounds):
        for name, cmd in commands.items():
            times[name].append(run(cmd))
        for name, folder in (("calibrate (both reports)", tmp / "r"), ("calibrate --no-report", tmp / "n")):
            sec = json.loads((folder / "result.json").read_text()).get("seconds", {})
            stages.setdefault(name, []).append(sec)
    bare = statistics.median(w for w, _ in times["bare OpenCV script"])
    bare_cpu = statistics.median(c for _, c in times["bare OpenCV script"])
    print(f"\n{'command':28s} {'wall [s]':>9s} {'CPU [s]':>8s} {'ratio':>6s} {'CPU ratio':>9s}")
    for name, tc in times.items():
        wall, cpu = statistics.median(w for w, _ in tc), statistics.median(c for _, c in tc)
        print(f"{name:28s} {wall:9.2f} {cpu:8.2f} {wall / bare:6.2f}x {cpu / bare_cpu:8.2f}x")
    print(f"load average after the rounds {os.getloadavg()[0]:.1f}")
    startup = statistics.median(w for w, _ in times["import handeye.cli"])
    for name, secs in stages.items():
        print(f"\n{name}: stages (median over rounds) [s]")
        keys = [k for k in secs[0] if k != "total"]
        for k in keys:
            print(f"  {k:14s} {statistics.median(s.get(k, 0.0) for s in secs):6.3f}")
        total = statistics.median(s.get("total", float("nan")) for s in secs)
        wall = statistics.median(w for w, _ in times[name])
        print(f"  {'in workflow':14s} {total:6.3f}")
        print(f"  {'start-up':14s} {startup:6.3f}  (python + import handeye.cli, before main())")
        print(f"  {'outside':14s} {wall - total - startup:6.3f}  (wall - workflow - start-up)")


if __name__ == "__main__":
    main()
