"""The whole ``handeye calibrate`` against the bare OpenCV script it replaces, in interleaved rounds.

Prints the median wall and CPU time of each command over the rounds, the ratio to the bare script
(``vendor_bare.py``: findChessboardCorners + cornerSubPix, calibrateCamera, calibrateHandEye) with and
without the reports (targets: 2.5x and 1.5x), and where handeye's time goes, wall and CPU (this process,
all threads): the interpreter start-up, ``import handeye.cli``, ``main()`` before the workflow (the
arguments, and the imports of what the command uses), each named stage (``timed_cli.py`` wraps the stage
functions), the workflow's time outside the named stages and the interpreter's shut-down. ``CPU/N cores``: the
command's CPU time (all its processes and threads) over the cores it may use, as a ratio to the bare
script's wall time: the ratio a perfect overlap of all its work on those cores would reach, the lower
bound of what overlapping can do. The load average is printed before and after. Asserts nothing.

    python benchmarks/bench_vs_opencv.py [--views 20] [--rounds 5] [--session FOLDER ...] [--real [DATA]]
                                         [--before DIR]

Without ``--session`` or ``--real``: a rendered 1280x720 vendor session of ``--views`` views
(:func:`handeye.sim.vendor.write_vendor_session`, seed 1). ``--session`` (a vendor-layout folder) may be
given several times; each is measured on its own. ``--real`` measures the shared real recordings whose
target the bare script reads (a chessboard) and whose robot poses are flange poses: the two UR3 cameras of
``DATA`` (default ``../shared/data``), written in the vendor layout (``k.jpg`` links to the recorded PNGs,
which OpenCV reads by their content; poses.txt from the derived flange poses; config.yaml with the 9x7 / 20
mm board and ``mode: eye_to_hand``). The bare script solves them as eye-in-hand, as a vendor script does:
its matrix is not a calibration of these rigs, its time is the same. ``--before DIR``: a checkout of handeye before a
change (e.g. ``git archive HEAD~3 | tar -x -C DIR``); its two calibrate commands run in the same
interleaved rounds (with ``PYTHONPATH=DIR``), so the before/after figures share the machine's load.

Every command runs as an installed package does: with bytecode caches (kept under the run's temporary
folder, ``PYTHONPYCACHEPREFIX``, even when ``PYTHONDONTWRITEBYTECODE`` is set, which would otherwise
compile every handeye module from source in every run), written by one warm-up round that is not counted;
the "after" commands import this checkout's handeye.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def run(cmd: list[str], env: dict | None = None) -> tuple[float, float, float]:
    """(wall, CPU, end time) of one command in a fresh process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    end = time.time()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, end


def _median(xs) -> float:
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else float("nan")


#: the records' spans that are not a named stage of the workflow
_NOT_STAGES = ("import handeye.cli", "main", "workflow")


def breakdown(name: str, records: list[dict]) -> None:
    """The per-stage wall and CPU medians of ``timed_cli.py``'s records of one command."""
    print(f"\n{name}: where the time goes (median over rounds) {'wall [s]':>9s} {'CPU [s]':>8s}")

    def row(label: str, get) -> None:
        w = _median(get(r, "wall") for r in records)
        c = _median(get(r, "cpu") for r in records)
        print(f"  {label:52s} {w:9.3f} {c:8.3f}")

    row("interpreter start-up (before any handeye code)", lambda r, k: r["interpreter"][k])
    row("import handeye.cli", lambda r, k: r["stages"]["import handeye.cli"][k])
    row(
        "main() before the workflow (parsing, imports)",
        lambda r, k: r["stages"]["main"][k] - r["stages"]["workflow"][k],
    )
    stages = [k for k in records[0]["stages"] if k not in _NOT_STAGES]
    for k in stages:
        row(f"  stage {k}", lambda r, kk, s=k: r["stages"].get(s, {}).get(kk))
    row(
        "  workflow outside the named stages",
        lambda r, k: r["stages"]["workflow"][k] - sum(v[k] for s, v in r["stages"].items() if s in stages),
    )
    row("  workflow (the whole calibrate_session)", lambda r, k: r["stages"]["workflow"][k])
    row("interpreter shut-down", lambda r, k: r["exit"] if k == "wall" else None)
    row("total (the command's process)", lambda r, k: r["total"][k])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--session", type=Path, action="append", help="a vendor session folder (default: a rendered one)")
    ap.add_argument("--before", type=Path, help="a checkout of handeye before a change, measured in the same rounds")
    ap.add_argument(
        "--real",
        type=Path,
        nargs="?",
        const=HERE.parents[1] / "shared" / "data",
        help="also the shared UR3 recordings under this folder (default ../shared/data), in the vendor layout",
    )
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_vs_opencv_"))
    try:
        sessions = list(args.session or [])
        if args.real is not None:
            found = [name for name in UR3_SETS if (args.real / name).is_dir()]
            sessions += [vendor_layout(args.real / name, tmp / name) for name in found]
        if not sessions:
            from handeye.sim.vendor import write_vendor_session

            sessions = [write_vendor_session(tmp / "session", n_views=args.views, seed=1)]
        for session in sessions:
            measure(Path(session), tmp, args.rounds, before=args.before)
    finally:  # the rendered session, the results and the bytecode caches of the runs
        shutil.rmtree(tmp, ignore_errors=True)


#: the shared recordings in the vendor layout (chessboard, flange poses): the two UR3 cameras
UR3_SETS = ("ur3-eyetohand-cam1", "ur3-eyetohand-cam2")


def vendor_layout(src: Path, out: Path) -> Path:
    """A UR3 camera folder of the shared data as a vendor session: numbered image links, poses.txt, config.yaml."""
    import numpy as np
    import yaml

    from handeye.conventions import VENDOR_POSE_FORMAT, pose_values_from_T

    out.mkdir(parents=True, exist_ok=True)
    lines = []
    for row in (src / "base_T_flange_fk_derived.txt").read_text().splitlines():
        if not row.strip() or row.startswith("#"):
            continue
        parts = row.split()
        T = np.array([float(x) for x in parts[2:18]]).reshape(4, 4)
        (out / f"{len(lines) + 1}.jpg").symlink_to((src / "images" / parts[1]).resolve())
        lines.append(",".join(f"{x:.9f}" for x in pose_values_from_T(T, VENDOR_POSE_FORMAT)))
    (out / "poses.txt").write_text("\n".join(lines) + "\n")
    config = {"checkerboard_args": {"XX": 9, "YY": 7, "L": 0.02}, "mode": "eye_to_hand"}
    (out / "config.yaml").write_text(yaml.safe_dump(config))
    return out


def measure(session: Path, tmp: Path, rounds: int, *, before: Path | None = None) -> None:
    py = sys.executable
    timed = [py, str(HERE / "timed_cli.py")]
    commands = {
        "bare OpenCV script": [py, str(HERE / "vendor_bare.py"), str(session)],
        "calibrate (both reports)": [
            *timed, str(tmp / "r.json"), "-q", "calibrate", str(session), "--out", str(tmp / "r"),
        ],
        "calibrate --no-report": [
            *timed, str(tmp / "n.json"), "-q", "calibrate", str(session), "--out", str(tmp / "n"), "--no-report",
        ],
        "import handeye.cli": [py, "-c", "import handeye.cli"],
        "python -c pass": [py, "-c", "pass"],
    }  # fmt: skip
    # as installed: bytecode caches (written by the warm-up round below), this checkout's handeye
    base = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    base["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
    after = {**base, "PYTHONPATH": os.pathsep.join([str(HERE.parent), *filter(None, [os.environ.get("PYTHONPATH")])])}
    env: dict = {name: after for name in commands}
    if before is not None:
        for label, flags, out in (("(both reports)", [], "rb"), ("--no-report", ["--no-report"], "nb")):
            key = f"before: calibrate {label}"
            commands[key] = [
                *timed,
                str(tmp / f"{out}.json"),
                "-q",
                "calibrate",
                str(session),
                "--out",
                str(tmp / out),
                *flags,
            ]
            env[key] = {**base, "PYTHONPATH": str(before.resolve())}
    n_images = len(list(session.glob("*.jpg"))) + len(list(session.glob("*.png")))
    print(
        f"\nsession {session} ({n_images} images), {rounds} interleaved rounds, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    for name, cmd in commands.items():  # the warm-up round: bytecode caches, the OS's file cache
        run(cmd, env.get(name))
    times: dict = {k: [] for k in commands}
    records: dict = {}
    for _ in range(rounds):
        for name, cmd in commands.items():
            wall, cpu, end = run(cmd, env.get(name))
            times[name].append((wall, cpu))
            if cmd[:2] == timed:
                rec = json.loads(Path(cmd[2]).read_text())
                rec["exit"] = end - rec["exit_time"]
                rec["total"] = {"wall": wall, "cpu": cpu}
                records.setdefault(name, []).append(rec)
    bare = statistics.median(w for w, _ in times["bare OpenCV script"])
    bare_cpu = statistics.median(c for _, c in times["bare OpenCV script"])
    from handeye.machine import usable_cores

    cores = usable_cores()
    print(
        f"\n{'command':36s} {'wall [s]':>9s} {'CPU [s]':>8s} {'ratio':>6s} {'CPU ratio':>9s} "
        f"{'CPU/' + str(cores) + ' cores':>12s}  target"
    )
    targets = {"calibrate (both reports)": "2.5x", "calibrate --no-report": "1.5x"}
    for name, tc in times.items():
        wall, cpu = statistics.median(w for w, _ in tc), statistics.median(c for _, c in tc)
        print(
            f"{name:36s} {wall:9.2f} {cpu:8.2f} {wall / bare:6.2f}x {cpu / bare_cpu:8.2f}x "
            f"{cpu / cores / bare:11.2f}x  {targets.get(name, '')}"
        )
    print(f"load average after the rounds {os.getloadavg()[0]:.1f}")
    for name, recs in records.items():
        breakdown(name, recs)


if __name__ == "__main__":
    main()
