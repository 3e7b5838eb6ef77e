"""Seconds per rendered 1280x720 view (handeye.sim.render.render_view), and the sharpness of rendered
boards against blur (the scale of the collector's sharpness check), printed to stdout.

Usage: python benchmarks/bench_render.py [--views 10] [--supersample 4] [--width 1280 --height 720]
The grid figure is the one-off cost of the cached undistortion grid for the intrinsics. Wall-clock
figures depend on machine load; the CPU time (all threads) is printed too. The sharpness table is the
variance of the Laplacian inside the detected board (handeye.detect.sharpness, the measure of
configs/collect.yaml capture.min_sharpness) over the same views with 2 grey levels of image noise.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from handeye.detect import detect_gray, sharpness
from handeye.sim import render
from handeye.sim.corners import make_corner_session
from handeye.sim.scenarios import default_intrinsics


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=10)
    ap.add_argument("--supersample", type=int, default=4)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    args = ap.parse_args()
    k = default_intrinsics(args.width, args.height)
    s = make_corner_session(n_views=args.views, seed=0, intrinsics=k)
    t0 = time.perf_counter()
    render.undistorted_sample_grid(k, supersample=args.supersample)
    t_grid = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    times, cpu = [], []
    for T in s.T_cam_board_true:
        t0, c0 = time.perf_counter(), time.process_time()
        render.render_view(s.target, k, T, supersample=args.supersample, blur_sigma_px=0.5, noise_sigma=2.0, rng=rng)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    print(
        f"{args.width}x{args.height} supersample {args.supersample}: undistortion grid (once per intrinsics) "
        f"{t_grid:.2f} s; render {np.median(times):.3f} s/view median, {np.max(times):.3f} s max "
        f"over {len(times)} views (CPU time, all threads: {np.median(cpu):.3f} s/view; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)"
    )
    print("blur sigma px | sharpness min / median over the views (variance of the Laplacian, grey levels^2)")
    for blur in (0.0, 1.0, 2.0, 4.0):
        values = []
        for T in s.T_cam_board_true:
            img = render.render_view(
                s.target, k, T, supersample=args.supersample, blur_sigma_px=blur, noise_sigma=2.0, rng=rng
            )
            found = detect_gray(img, s.target)
            values.append(np.nan if isinstance(found, str) else sharpness(img, found[1]))
        print(
            f"{blur:13.1f} | {np.nanmin(values):8.1f} / {np.nanmedian(values):8.1f}  "
            f"({int(np.sum(np.isfinite(values)))}/{len(values)} detected)"
        )


if __name__ == "__main__":
    main()
