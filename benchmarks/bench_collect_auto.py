"""Consecutive simulated ``handeye collect --auto`` runs without ``--seed``: views kept and the seed recorded.

Each run is the command a user types (``handeye collect OUT --mode M --camera sim --robot sim --auto``,
no ``--seed``), so the simulator draws its own seed; the benchmark reads that seed back from the
session (``collected.seed`` in session.yaml) and prints, per run, the views kept, the captures
rejected, the planned poses that missed the board and the seed that repeats the run. The summary
line per mode gives the fewest views kept and whether every session recorded an integer seed.
``--seeds S ...`` runs the given seeds instead (e.g. the ones a previous run printed).

    python benchmarks/bench_collect_auto.py [--runs 10] [--modes eye_in_hand eye_to_hand] [--views 8]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import logging
import shutil
import sys
import tempfile
import time
from pathlib import Path

import yaml

from handeye.cli import main as handeye_main


class _Misses(logging.Handler):
    """Counts the planned views skipped because the board was not in the image."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.n = 0

    def emit(self, record):
        text = record.getMessage()
        if text.startswith("planned view") and "target not detected" in text:
            self.n += 1


def one_run(mode: str, views: int, seed: int | None) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="bench_collect_auto_"))
    out = tmp / "session"
    argv = ["-q", "collect", str(out), "--mode", mode, "--camera", "sim", "--robot", "sim", "--auto"]
    argv += ["--views", str(views)] + ([] if seed is None else ["--seed", str(seed)])
    misses = _Misses()
    logging.getLogger("handeye.collect").addHandler(misses)
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stdout(io.StringIO()) as printed:
            rc = handeye_main(argv)
        header = yaml.safe_load((out / "session.yaml").read_text()) if (out / "session.yaml").is_file() else {}
        n_views = len(list((out / "views").glob("*.yaml"))) if (out / "views").is_dir() else 0
    finally:
        logging.getLogger("handeye.collect").removeHandler(misses)
        shutil.rmtree(tmp, ignore_errors=True)
    line = printed.getvalue().strip().splitlines()[:1]
    rejected = int(line[0].split(", ")[1].split()[0]) if line and "captures rejected" in line[0] else -1
    return {
        "rc": rc,
        "views": n_views,
        "rejected": rejected,
        "missed": misses.n,
        "seed": (header.get("collected") or {}).get("seed"),
        "seconds": time.perf_counter() - t0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10, help="runs per mode (default 10)")
    ap.add_argument("--modes", nargs="+", default=["eye_in_hand", "eye_to_hand"])
    ap.add_argument("--views", type=int, default=8, help="planned views per run (default 8: 12 views in all)")
    ap.add_argument("--seeds", type=int, nargs="+", help="run these seeds instead of drawn ones")
    ap.add_argument("--min-views", type=int, default=10, help="a run keeping fewer views counts as failed")
    a = ap.parse_args(argv)
    root = logging.getLogger()  # warnings reach the counter, not the terminal (the CLI adds no handler then)
    root.addHandler(logging.NullHandler())
    root.setLevel(logging.WARNING)
    failed = 0
    for mode in a.modes:
        rows = [one_run(mode, a.views, s) for s in (a.seeds or [None] * a.runs)]
        print(f"{mode}:  run  exit  views  rejected  missed  seconds  seed")
        for k, r in enumerate(rows, 1):
            print(
                f"{'':{len(mode) + 2}}{k:4d}  {r['rc']:4d}  {r['views']:5d}  {r['rejected']:8d}  {r['missed']:6d}"
                f"  {r['seconds']:7.1f}  {r['seed']}"
            )
        seeded = all(isinstance(r["seed"], int) for r in rows)
        low = [r["seed"] for r in rows if r["views"] < a.min_views or r["rc"] != 0]
        failed += len(low) + (0 if seeded else 1)
        print(
            f"{mode}: {len(rows)} runs, views kept min {min(r['views'] for r in rows)} "
            f"median {sorted(r['views'] for r in rows)[len(rows) // 2]}, "
            f"{sum(r['missed'] for r in rows)} planned poses missed the board, every seed recorded: {seeded}; "
            f"runs below {a.min_views} views or failed: {low or 'none'}",
            flush=True,
        )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
