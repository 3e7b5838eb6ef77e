"""Wall time of a whole `handeye calibrate` on a rendered 20-view 1280x720 session (issue 3, target 5:
under 5 s on 2 cores), with the stage breakdown from result.json. Prints figures; asserts nothing.

    python benchmarks/bench_calibrate.py [--views 20] [--repeat 3] [--mode eye_in_hand]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mode", default="eye_in_hand")
    args = ap.parse_args()
    from handeye.sim.vendor import write_vendor_session

    with tempfile.TemporaryDirectory() as tmp:
        sess = write_vendor_session(Path(tmp) / "s", mode=args.mode, n_views=args.views, seed=7,
                                    hidden_views=("5",), image_noise=2.0)
        print(f"session: {args.views} rendered 1280x720 views ({args.mode}), one without the board; cores: {os.cpu_count()}")
        for label, extra in (("calibrate (result.json only)", ["--no-report"]), ("calibrate + reports", [])):
            walls = []
            for k in range(args.repeat):
                out = Path(tmp) / f"out{k}{len(extra)}"
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "handeye.cli", "-q", "calibrate", str(sess), "--out", str(out),
                                *extra], check=True, stdout=subprocess.DEVNULL)
                walls.append(time.perf_counter() - t0)
                stages = json.loads((out / "result.json").read_text())["seconds"]
            print(f"{label:32s} wall {min(walls):6.2f} s (best of {args.repeat}; all: "
                  + ", ".join(f"{w:.2f}" for w in walls) + ")")
            print("    stages [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in stages.items()))


if __name__ == "__main__":
    main()
