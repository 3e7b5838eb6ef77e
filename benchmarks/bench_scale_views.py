"""Time of every stage against the number of views: does `handeye calibrate --no-report` stay near-linear?

Sessions of 20, 50, 100, 200, 300 and 500 views (and 100 views of which 8 have a gross robot pose error)
are calibrated by handeye.workflow.calibrate_session without the report (what `handeye calibrate SESSION
--no-report` runs), with the calibration preset; the per-stage `seconds` of result.json are printed
with the ratio of the whole run (load to verdict) to the calibration stage alone, then the growth from
the smallest to the largest session: wall and CPU per view and the local exponent of the CPU time
(1: linear, 2: quadratic) between successive sizes. Targets on 2 cores: the ratio under 2 and the whole
command under 10 s wall at 300 rendered views. Prints figures; asserts nothing.

    python benchmarks/bench_scale_views.py [--kind rendered|corners] [--views 20,50,100,200,300,500]
                                           [--outliers 100:8] [--keep DIR] [--profile] [--seed 3]

``--kind rendered`` (default) renders 1280x720 vendor sessions (handeye.sim.vendor.write_vendor_session:
image noise 1 grey level, robot noise 0.3 mm / 0.05 deg per axis); ``--keep DIR`` keeps them there and
reuses them on the next run (rendering 300 views takes minutes). ``--kind corners`` uses corner-level
sessions (handeye.sim.corners.make_corner_session, 0.3 px) with the detection replaced by the synthetic
corners and the diagnostics run without the image measures (there are no images), to look at the
solver and diagnostics alone in seconds. ``--profile`` prints the 25 most expensive functions
(cumulative CPU time, cProfile) of the diagnostics of each session.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import os
import pstats
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROBOT_NOISE = (0.3, 0.05)  # mm, deg per axis


def _rendered(root: Path, n_views: int, n_out: int, seed: int) -> Path:
    from handeye.sim.vendor import write_vendor_session

    folder = root / f"rendered{n_views}_out{n_out}_seed{seed}"
    if (folder / "ground_truth.json").exists():
        return folder
    t0 = time.perf_counter()
    write_vendor_session(
        folder,
        mode="eye_in_hand",
        n_views=n_views,
        seed=seed,
        image_noise=1.0,
        robot_noise=ROBOT_NOISE,
        outlier_views=n_out,
        overwrite=True,
    )
    print(f"  (rendered {n_views} views in {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return folder


def _corner_session(root: Path, n_views: int, n_out: int, seed: int):
    from handeye.conventions import VENDOR_POSE_FORMAT, pose_values_from_T
    from handeye.sim.corners import make_corner_session

    cs = make_corner_session(
        mode="eye_in_hand", n_views=n_views, seed=seed, robot_noise=ROBOT_NOISE, noise_px=0.3, outlier_views=n_out
    )
    folder = root / f"corners{n_views}_out{n_out}_seed{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(1, n_views + 1):
        (folder / f"{k}.jpg").write_bytes(b"")
    (folder / "poses.txt").write_text(
        "\n".join(
            ",".join(f"{x:.9f}" for x in pose_values_from_T(t, VENDOR_POSE_FORMAT)) for t in cs.T_base_end_reported
        )
        + "\n"
    )
    (folder / "config.yaml").write_text(
        yaml.safe_dump(
            {
                "checkerboard_args": {"XX": cs.target.cols, "YY": cs.target.rows, "L": cs.target.square_m},
                "mode": cs.mode,
            }
        )
    )
    return folder, cs


class _Timed:
    """Wall and CPU seconds (this process, all threads) of calls to ``module.name`` while active, and an
    optional cProfile of them."""

    def __init__(self, module, name: str, prof=None):
        self.module, self.name, self.prof, self.cpu = module, name, prof, 0.0

    def __enter__(self):
        self.orig = orig = getattr(self.module, self.name)

        def timed(*a, **kw):
            c0 = time.process_time()
            if self.prof:
                self.prof.enable()
            try:
                return orig(*a, **kw)
            finally:
                if self.prof:
                    self.prof.disable()
                self.cpu += time.process_time() - c0

        setattr(self.module, self.name, timed)
        return self

    def __exit__(self, *exc):
        setattr(self.module, self.name, self.orig)


#: the calibration stages whose CPU time is measured (functions of handeye.pipeline)
CPU_STAGES = {
    "detect": "detect_views",
    "intrinsics": "calibrate_intrinsics",
    "closed_form": "_closed_forms",
    "refine": "refine_stage",
    "validate": "validate_stage",
}


@contextlib.contextmanager
def _stage_timers():
    """CPU time of each of :data:`CPU_STAGES` while active: {stage: _Timed}."""
    import handeye.pipeline as pipeline

    with contextlib.ExitStack() as stack:
        yield {k: stack.enter_context(_Timed(pipeline, name)) for k, name in CPU_STAGES.items()}


def _run_corners(folder: Path, cs, opts, profile: bool) -> tuple[dict, dict, list, str]:
    """Calibrate (detection replaced by the synthetic corners) and diagnose without image measures."""
    import handeye.pipeline as pipeline
    from handeye.diagnose import diagnose_run
    from handeye.session import load_session

    dets = {d.view_id: d for d in cs.detections()}
    orig = pipeline.detect_views
    pipeline.detect_views = lambda items, target, **kw: {v: dets.get(v, "not found") for v, _ in items}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        session = load_session(folder)
        t_load = time.perf_counter() - t0
        with _stage_timers() as stages:
            run = pipeline.run_calibration(session, opts)
    finally:
        pipeline.detect_views = orig
    c1 = time.process_time()
    prof = cProfile.Profile(time.process_time) if profile else None
    t1 = time.perf_counter()
    if prof:
        prof.enable()
    diag = diagnose_run(run, images=False)
    if prof:
        prof.disable()
    seconds = {"load": t_load, **run.seconds, "diagnose": time.perf_counter() - t1}
    seconds["total"] = time.perf_counter() - t0
    cpu = {"calibrate": c1 - c0, "diagnose": time.process_time() - c1, "total": time.process_time() - c0}
    cpu.update({k: t.cpu for k, t in stages.items()})
    return seconds, cpu, [f["code"] for f in diag["findings"] if f["severity"] in ("fail", "warn")], _top(prof)


def _run_rendered(folder: Path, out: Path, opts, profile: bool) -> tuple[dict, dict, list, str]:
    from handeye import diagnose as diagnose_pkg
    from handeye import workflow

    prof = cProfile.Profile(time.process_time) if profile else None
    c0 = time.process_time()
    with _Timed(workflow, "run_calibration") as cal, _Timed(diagnose_pkg, "diagnose_run", prof) as diag:
        with _stage_timers() as stages:
            wr = workflow.calibrate_session(folder, options=opts, out_dir=out, report=False)
    cpu = {"calibrate": cal.cpu, "diagnose": diag.cpu, "total": time.process_time() - c0}
    cpu.update({k: t.cpu for k, t in stages.items()})
    findings = wr.result.get("diagnostics", {}).get("findings", [])
    codes = [f["code"] for f in findings if f["severity"] in ("fail", "warn")]
    return dict(wr.seconds), cpu, codes, _top(prof)


def _top(prof) -> str:
    if prof is None:
        return ""
    s = io.StringIO()
    pstats.Stats(prof, stream=s).sort_stats("cumulative").print_stats(25)
    return s.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kind", choices=("rendered", "corners"), default="rendered")
    ap.add_argument("--views", default="20,50,100,200,300,500", help="comma-separated view counts (clean sessions)")
    ap.add_argument("--outliers", default="100:8", help="VIEWS:OUTLIERS sessions, comma-separated ('' for none)")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None, help="folder for the rendered sessions (reused)")
    ap.add_argument("--profile", action="store_true", help="cProfile of the diagnostics")
    a = ap.parse_args(argv)
    from handeye.cli import prepare_process

    prepare_process()  # the command's own set-up (one BLAS thread, freed memory kept), before numpy is imported
    from handeye.config import load_preset
    from handeye.pipeline import CalibrateOptions

    cases = [(int(v), 0) for v in a.views.split(",") if v.strip()]
    cases += [tuple(int(x) for x in c.split(":")) for c in a.outliers.split(",") if c.strip()]
    opts = CalibrateOptions.from_config(load_preset("calibration"))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"{a.kind} sessions, eye-in-hand, robot noise {ROBOT_NOISE[0]} mm / {ROBOT_NOISE[1]} deg, seed {a.seed}; "
        f"cores {os.cpu_count()}, load average at start {load:.1f}"
    )
    print(
        "ratio = (total without the report) / calibrate, of the wall time and of this process's CPU time (all "
        "threads; steadier on a busy machine); target < 2"
    )
    growth: list[tuple[int, float, float, dict]] = []
    with tempfile.TemporaryDirectory() as tmp:
        root = a.keep or Path(tmp)
        for n_views, n_out in cases:
            if a.kind == "rendered":
                folder = _rendered(root, n_views, n_out, a.seed)
                seconds, cpu, codes, top = _run_rendered(folder, Path(tmp) / f"out{n_views}_{n_out}", opts, a.profile)
            else:
                folder, cs = _corner_session(root, n_views, n_out, a.seed)
                seconds, cpu, codes, top = _run_corners(folder, cs, opts, a.profile)
            print(
                f"{n_views:4d} views, {n_out} outliers: wall total {seconds['total']:7.2f} s, calibrate "
                f"{seconds['calibrate']:6.2f} s, diagnose {seconds.get('diagnose', 0.0):6.2f} s, ratio "
                f"{seconds['total'] / seconds['calibrate']:4.2f}; CPU total {cpu['total']:7.2f} s, calibrate "
                f"{cpu['calibrate']:6.2f} s, diagnose {cpu['diagnose']:6.2f} s, ratio "
                f"{cpu['total'] / max(cpu['calibrate'], 1e-9):4.2f}; fail/warn findings: {codes or 'none'}"
            )
            print("    stages, wall [s]: " + ", ".join(f"{k} {v:.2f}" for k, v in seconds.items()))
            if not n_out:
                growth.append((n_views, seconds["total"], cpu["total"], cpu))
            if top:
                print(top)
            sys.stdout.flush()
    print_growth(sorted(growth))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"load average at the end {load:.1f}")
    return 0


def print_growth(rows: list[tuple[int, float, float, dict]]) -> None:
    """Wall and CPU per view of the clean sessions, and the local exponent of the CPU time between sizes."""
    import math

    if len(rows) < 2:
        return
    stages = [*CPU_STAGES, "diagnose"]
    print(f"\ngrowth {rows[0][0]} -> {rows[-1][0]} views (no report; exponent: d log CPU / d log views)")
    print(
        f"{'views':>5} {'wall [s]':>9} {'CPU [s]':>8} {'CPU/view [ms]':>13} {'exponent':>8}  "
        + " ".join(f"{k:>11}" for k in stages)
    )
    prev = None
    for n, wall, cpu, sec in rows:
        exp = f"{math.log(cpu / prev[1]) / math.log(n / prev[0]):8.2f}" if prev else f"{'':>8}"
        print(
            f"{n:5d} {wall:9.2f} {cpu:8.2f} {1e3 * cpu / n:13.1f} {exp}  "
            + " ".join(f"{sec.get(k, 0.0):11.2f}" for k in stages)
        )
        prev = (n, cpu)
    (n0, w0, c0, _), (n1, w1, c1, _) = rows[0], rows[-1]
    print(
        f"{n0} -> {n1} views: wall x{w1 / w0:.1f}, CPU x{c1 / c0:.1f} for x{n1 / n0:.1f} the views "
        "(stage columns: CPU [s])"
    )


if __name__ == "__main__":
    sys.exit(main())
