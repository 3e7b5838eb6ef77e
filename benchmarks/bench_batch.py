"""Throughput of ``handeye batch`` on this machine: sessions per minute with 1 and 2 embedded Dask
workers, with and without reports, and the memory a worker needs. Prints figures; asserts nothing.

    python benchmarks/bench_batch.py [--sessions 12] [--views 8] [--size 640x360] [--workers 1 2]

A fleet of ``--sessions`` rendered eye-in-hand sessions (:func:`handeye.sim.fleet.write_fleet`, 3 per
install, ``--views`` views of ``--size`` pixels) is calibrated by :func:`handeye.batch.run.run_batch`
into a fresh folder per configuration (``force``: every session runs). Per configuration:

* ``sessions/min``: sessions over the batch's wall time, the embedded cluster's start and stop included;
* ``s/session``: the median wall time of one session's task (the child process: interpreter start,
  imports, the workflow), as batch.json records it;
* ``memory``: the RSS of an idle worker process (Dask's own) and the peak RSS of a session's child
  process (the calibration): a worker needs about their sum.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path


def _calibrate_options(root: Path, out: Path, report: bool) -> dict:
    from handeye.cli import build_parser
    from handeye.cli.batch import calibrate_options

    args = build_parser().parse_args(["batch", str(root), "--out", str(out)] + ([] if report else ["--no-report"]))
    return calibrate_options(args)


def _idle_worker_rss_mb() -> float:
    from handeye.batch.run import open_client

    client = open_client(n_workers=1)
    try:
        rss = client.run(lambda: __import__("psutil").Process().memory_info().rss)
    finally:
        cluster = client.cluster
        client.close()
        cluster.close()
    return max(rss.values()) / 2**20


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=12)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    a = ap.parse_args(argv)
    import os

    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    from handeye.batch.discover import discover
    from handeye.batch.run import run_batch
    from handeye.sim.fleet import write_fleet

    w, h = (int(x) for x in a.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "root"
        n_installs = max(1, -(-a.sessions // 3))
        t0 = time.perf_counter()
        write_fleet(root, n_installs=n_installs, sessions_per_install=3, n_views=a.views, image_size=(w, h))
        jobs = discover(root)[: a.sessions]
        print(
            f"fleet: {len(jobs)} sessions of {a.views} views at {w}x{h} written in "
            f"{time.perf_counter() - t0:.1f} s; {os.cpu_count()} CPUs"
        )
        print(
            f"{'workers':>7} {'reports':>7} {'sessions/min':>12} {'s/session':>9} {'wall s':>7} {'peak child MiB':>14}"
        )
        for n in a.workers:
            for report in (False, True):
                out = Path(tmp) / f"out_{n}_{int(report)}"
                s = run_batch(
                    jobs, out, calibrate=_calibrate_options(root, out, report), n_workers=n, force=True, timeout_s=3600
                )
                per = [r["seconds"] for r in s.records if r.get("seconds")]
                rss = [r["peak_rss_mb"] for r in s.records if r.get("peak_rss_mb")]
                print(
                    f"{n:>7} {'yes' if report else 'no':>7} {60 * len(jobs) / s.seconds:>12.1f} "
                    f"{statistics.median(per):>9.1f} {s.seconds:>7.1f} {max(rss):>14.0f}"
                )
                sys.stdout.flush()
        print(f"idle Dask worker process: {_idle_worker_rss_mb():.0f} MiB RSS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
