"""Throughput of ``handeye batch`` on this machine: sessions per minute with 1 and 2 embedded Dask
workers, with and without reports, and the memory a worker needs. Prints figures; asserts nothing.

    python benchmarks/bench_batch.py [--sessions 12] [--views 8] [--size 640x360] [--workers 1 2]
    python benchmarks/bench_batch.py --vs-single [--sessions 8] [--rounds 1]

``--vs-single``: ``batch --workers 2 --no-report`` over the sessions against the same sessions run one by
one (``handeye calibrate --no-report`` each in a fresh process), in interleaved rounds: the batch's wall
time over half the sum of the single runs' (1.0: a perfect split on two workers), the CPU time of each
(the batch's: every process of the embedded cluster, read from /proc before it closes) and sessions per
minute per core (by wall on 2 workers, and by CPU: what an unshared core would do). Targets: the wall ratio
at most 1.15 and at least 30 sessions a minute per core for these 8-view 640x360 sessions; on a machine
shared with other jobs the wall ratio follows the load, the CPU figures much less.

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


def _tree_cpu_s() -> float:
    """CPU seconds of this process and every descendant (live ones, and the children they reaped)."""
    import psutil

    total = 0.0
    me = psutil.Process()
    for p in [me] + me.children(recursive=True):
        try:
            t = p.cpu_times()
        except psutil.Error:
            continue
        total += t.user + t.system + (t.children_user + t.children_system if p is not me else 0.0)
    return total


def _own_cpu_s() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _batch_run(jobs, root: Path, out: Path) -> tuple[float, float]:
    """(wall, CPU) of ``batch --workers 2 --no-report`` over ``jobs``, the embedded cluster included."""
    from handeye.batch.run import run_batch

    n, seen, cpu = len(jobs), [], {}
    c0 = _own_cpu_s()

    def progress(rec):
        seen.append(rec)
        if len(seen) == n:  # every session done, the cluster still up: read its processes' CPU now
            cpu["tree"] = _tree_cpu_s()

    s = run_batch(
        jobs, out, calibrate=_calibrate_options(root, out, False), n_workers=2, force=True, timeout_s=3600,
        progress=progress,
    )  # fmt: skip
    bad = [r for r in s.records if r.get("outcome") != "done"]
    if bad:
        print(f"  {len(bad)} sessions without a result: {bad[0].get('reason')}")
    return s.seconds, cpu.get("tree", _own_cpu_s()) - c0


def _single_run(jobs, out: Path) -> tuple[float, float]:
    """(sum of wall, sum of CPU) of ``handeye calibrate --no-report`` on each session in a fresh process."""
    import resource
    import subprocess

    wall = cpu = 0.0
    for i, job in enumerate(jobs):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "handeye.cli", "-q", "calibrate", str(job.path), "--out", str(out / str(i))]
        subprocess.run(cmd + ["--no-report", "--workers", "1"], check=False, capture_output=True)
        wall += time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu += after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return wall, cpu


def vs_single(jobs, root: Path, tmp: Path, rounds: int) -> None:
    import os

    print(f"load average {os.getloadavg()[0]:.1f}; {rounds} interleaved rounds")
    rows = []
    for k in range(rounds):
        bw, bc = _batch_run(jobs, root, tmp / f"batch_{k}")
        sw, sc = _single_run(jobs, tmp / f"single_{k}")
        rows.append((bw, bc, sw, sc))
        print(
            f"  round {k + 1}: batch {bw:.1f} s wall {bc:.1f} s CPU; one by one {sw:.1f} s wall {sc:.1f} s CPU; "
            f"batch / (one by one / 2) = {bw / (sw / 2):.2f}"
        )
    bw, bc, sw, sc = (statistics.median(r[i] for r in rows) for i in range(4))
    n = len(jobs)
    print(f"median: batch --workers 2 --no-report {bw:.1f} s wall, {bc:.1f} s CPU ({bc / n:.2f} s CPU/session)")
    print(f"        one by one (sum)             {sw:.1f} s wall, {sc:.1f} s CPU ({sc / n:.2f} s CPU/session)")
    print(
        f"        batch / half the one-by-one sum: {bw / (sw / 2):.2f} (wall; target <= 1.15), CPU ratio {bc / sc:.2f}"
    )
    print(
        f"        sessions/min per core: {60 * n / bw / 2:.1f} by wall on 2 workers, {60 * n / bc:.1f} by CPU "
        "(target >= 30)"
    )
    print(f"        load average now {os.getloadavg()[0]:.1f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vs-single", action="store_true", help="batch on 2 workers against single runs")
    ap.add_argument("--rounds", type=int, default=1)
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
        if a.vs_single:
            vs_single(jobs, root, Path(tmp), a.rounds)
            return 0
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
