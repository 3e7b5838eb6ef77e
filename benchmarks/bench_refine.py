"""Benchmark of the joint refinement on corner-level sessions: error vs the Cramer-Rao bound, coverage, flags, speed.

For each mounting mode and seed: a 20-view session (11x8 board, 1280x720, 0.3 px corner noise) from
:func:`handeye.sim.corners.make_corner_session`, seeded with OpenCV (calibrateCamera intrinsics,
per-view solvePnP, every calibrateHandEye method; Tsai's is the given start), then refined by
:func:`handeye.refine.refine`.

Printed per mode and scenario (clean; robot noise 0.2 mm / 0.05 deg; 2 of 20 robot poses wrong):
RMS rotation (deg) and translation (mm) error of T_x against the truth, the Cramer-Rao bound of
the same model at the truth (pure numpy Fisher information from the analytic Jacobians of
:mod:`handeye.factors.reprojection`, intrinsics estimated jointly, robot poses as nuisance variables
with the true robot sigma when there is robot noise), Tsai's error, the coverage of the reported
95 % ellipsoid (chi-square 6 dof), outlier flags, and timings.

The refinement gets the closed forms as candidate starts (``starts=``), as the pipeline gives it
``run.closed_forms``; their cost is the pipeline's closed-form stage, not the refinement's.

Usage: python benchmarks/bench_refine.py --seeds 50      (quick look: --seeds 5; subsets with
--modes, --scenarios clean robot outliers, --first-seed, --no-timing)
Progress goes to stderr, the figures to stdout. Timings are wall and process CPU seconds (one
thread); on a shared machine the CPU figure is the one to compare with the targets.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from scipy.stats import chi2

from handeye.factors.reprojection import chain_residual
from handeye.frames import tangent_difference
from handeye.initial import all_methods, calibrate_intrinsics, solve_pnp
from handeye.mounting import mounting
from handeye.refine import RefineOptions, refine
from handeye.sim.corners import make_corner_session

MODES = ("eye_in_hand", "eye_to_hand")
NOISE_PX = 0.3
ROBOT_NOISE = (0.2, 0.05)  # mm, deg
CHI2_95_6 = chi2.ppf(0.95, 6)


def closed_forms(s):
    """As the pipeline: calibrateCamera intrinsics, per-view solvePnP, every calibrateHandEye method on the
    reported poses; returns (intrinsics, {method: HandEyeEstimate}) (Tsai is the start, the others candidates)."""
    mount = mounting(s.mode)
    obj = s.target.object_points()
    dets = s.detections()
    intr, _ = calibrate_intrinsics(dets, obj)
    C = np.stack([solve_pnp(obj[d.corner_ids], d.image_points, intr)[0] for d in dets])
    M = mount.M_from_T_base_end(np.stack([s.T_base_end_reported[s.index(d.view_id)] for d in dets]))
    return intr, all_methods(mount, C, M)


def refine_views(s):
    """The session's views as the refinement takes them, with the encoder readings when the simulated arm
    recorded them (the kinematic robot error model), as a session with joint angles gives them."""
    return s.refine_views(getattr(s, "joints_encoder", None))


def refine_from_tsai(s, options=None):
    """The session refined as calibrate starts it: from the closed forms' Tsai estimate, all of them candidates."""
    intr, cf = closed_forms(s)
    return refine(
        mode=s.mode,
        object_points=s.target.object_points(),
        views=refine_views(s),
        intrinsics=intr,
        T_x0=cf["tsai"].T_x,
        T_board0=cf["tsai"].T_board,
        options=options,
        starts=cf,
    )


def crb_x(s, *, sigma_px: float, robot_sigma_mm: float, robot_sigma_deg: float, exclude=()) -> np.ndarray:
    """Cramer-Rao bound (6x6, GTSAM tangent of T_x) of the refinement model at the truth.

    Unknowns: T_x, T_board, the 9 intrinsics and, when the robot has noise, each view's true robot
    pose with its prior; views in ``exclude`` contribute their corners only (robot pose free)."""
    invert = mounting(s.mode).inverts_robot
    obj_all = s.target.object_points()
    k = s.intrinsics.as_vector()
    robot_var = robot_sigma_mm > 0 or robot_sigma_deg > 0
    n = s.n_views
    c = 21
    D = c + (6 * n if robot_var else 0)
    H = np.zeros((D, D))
    for i in range(n):
        if not len(s.corner_ids[i]):
            continue
        _, J_x, J_r, J_b, J_k = chain_residual(
            T_x=s.T_x_true,
            T_base_end=s.T_base_end_true[i],
            T_board=s.T_board_true,
            invert_robot=invert,
            intrinsics_vec=k,
            object_points=obj_all[s.corner_ids[i]],
            image_points=np.zeros((len(s.corner_ids[i]), 2)),
        )
        blocks = [J_x, J_b, J_k]
        if robot_var:
            blocks.append(J_r)
        J = np.hstack(blocks) / sigma_px
        idx = np.r_[0:c, (c + 6 * i + np.arange(6)) if robot_var else np.zeros(0, int)].astype(int)
        H[np.ix_(idx, idx)] += J.T @ J
        if robot_var and s.view_ids[i] not in exclude:
            w = np.r_[[np.radians(robot_sigma_deg) ** -2] * 3, [(robot_sigma_mm / 1000.0) ** -2] * 3]
            H[c + 6 * i + np.arange(6), c + 6 * i + np.arange(6)] += w
    if not robot_var and exclude:
        raise ValueError("excluded views need robot pose variables")
    return np.linalg.inv(H)[:6, :6]


def x_error(T_est, T_true):
    """(rot_deg, trans_mm, xi) with xi = Log(inv(T_est) T_true) in GTSAM's tangent."""
    xi = tangent_difference(T_est, T_true)
    return float(np.degrees(np.linalg.norm(xi[:3]))), float(1000 * np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), xi


def run_scenario(mode, seeds, *, robot_noise=(0.0, 0.0), outliers=0, label=""):
    rows = []
    for seed in seeds:
        s = make_corner_session(
            mode=mode, n_views=20, seed=seed, noise_px=NOISE_PX, robot_noise=robot_noise, outlier_views=outliers
        )
        intr, closed = closed_forms(s)
        est = closed["tsai"]
        t0, c0 = time.perf_counter(), time.process_time()
        r = refine(
            mode=mode,
            object_points=s.target.object_points(),
            views=refine_views(s),
            intrinsics=intr,
            T_x0=est.T_x,
            T_board0=est.T_board,
            options=RefineOptions(),
            starts=closed,
        )
        secs, cpu = time.perf_counter() - t0, time.process_time() - c0
        rot, trans, xi = x_error(r.T_x, s.T_x_true)
        t_rot, t_trans, _ = x_error(est.T_x, s.T_x_true)
        # the bound of the clean version of this session (robot noise as simulated, no gross errors)
        crb = crb_x(s, sigma_px=NOISE_PX, robot_sigma_mm=robot_noise[0], robot_sigma_deg=robot_noise[1])
        flagged = {o.view_id for o in r.outliers if o.kind in ("robot_pose", "reprojection", "too_few_corners")}
        maha2 = float(xi @ np.linalg.solve(r.cov_x_6x6, xi)) if r.status == "ok" else np.inf
        rows.append(
            dict(
                seed=seed,
                ok=r.status == "ok",
                rot=rot,
                trans=trans,
                tsai_rot=t_rot,
                tsai_trans=t_trans,
                crb_rot=np.degrees(np.sqrt(np.trace(crb[:3, :3]))),
                crb_trans=1000 * np.sqrt(np.trace(crb[3:, 3:])),
                covered=maha2 <= CHI2_95_6,
                secs=secs,
                cpu=cpu,
                flagged=flagged,
                true_out=set(s.outlier_view_ids),
                sigma_px=r.sigma_px,
                robot_mm=r.robot_sigma_mm,
                robot_deg=r.robot_sigma_deg,
                pred_rot=np.sqrt(np.sum(r.sigma_rot_deg**2)),
                pred_trans=np.sqrt(np.trace(r.cov_x_6x6[3:, 3:])) * 1000,
            )
        )
        print(
            f"  {label} {mode} seed {seed}: {rot:.4f} deg {trans:.4f} mm (tsai {t_rot:.3f} deg {t_trans:.3f} mm) "
            f"{secs:.2f} s flagged {sorted(flagged)} true {sorted(s.outlier_view_ids)}",
            file=sys.stderr,
        )
    return rows


def rms(rows, key):
    return float(np.sqrt(np.mean([r[key] ** 2 for r in rows])))


def summarize(label, mode, rows):
    crb_rot, crb_trans = rms(rows, "crb_rot"), rms(rows, "crb_trans")
    rot, trans = rms(rows, "rot"), rms(rows, "trans")
    mean = lambda key: float(np.mean([r[key] for r in rows]))  # noqa: E731
    print(f"{label} {mode}, {len(rows)} sessions ({sum(not r['ok'] for r in rows)} failed)")
    print(
        f"  RMS error    refined {rot:.4f} deg {trans:.4f} mm | CRB {crb_rot:.4f} deg {crb_trans:.4f} mm | "
        f"ratio {rot / crb_rot:.2f} {trans / crb_trans:.2f} | Tsai {rms(rows, 'tsai_rot'):.4f} deg "
        f"{rms(rows, 'tsai_trans'):.4f} mm"
    )
    print(
        f"  uncertainty  reported RMS {rms(rows, 'pred_rot'):.4f} deg {rms(rows, 'pred_trans'):.4f} mm | truth "
        f"inside the 95 % ellipsoid in {mean('covered') * 100:.0f} % | sigma_px {mean('sigma_px'):.3f} | "
        f"robot sigma {mean('robot_mm'):.3f} mm {mean('robot_deg'):.4f} deg"
    )
    if rows[0]["true_out"]:
        both = np.mean([r["true_out"] <= r["flagged"] for r in rows]) * 100
        print(f"  outliers     both wrong robot poses flagged in {both:.0f} % of sessions")
    false = sum(len(r["flagged"] - r["true_out"]) for r in rows)
    print(f"  false flags  {false} views in {len(rows)} sessions")
    print(
        f"  time         refine {np.median([r['secs'] for r in rows]):.2f} s wall median "
        f"({max(r['secs'] for r in rows):.2f} max), {np.median([r['cpu'] for r in rows]):.2f} s cpu median"
    )
    return dict(rot_ratio=rot / crb_rot, trans_ratio=trans / crb_trans)


def time_solves(mode, n_views, repeats=3):
    """Seconds of one Gauss-Newton/LM solve (robot pose variables, no robust loss) from the Tsai seed."""
    from handeye.refine.options import check_inputs
    from handeye.refine.problem import Problem  # times exactly one graph solve, nothing around it

    s = make_corner_session(mode=mode, n_views=n_views, seed=1, noise_px=NOISE_PX, robot_noise=ROBOT_NOISE)
    intr, closed = closed_forms(s)
    est = closed["tsai"]
    times, cpus = [], []
    for _ in range(repeats):
        obj, reported = check_inputs(s.target.object_points(), refine_views(s))
        pb = Problem(
            mode=mode,
            object_points=obj,
            views=refine_views(s),
            reported=reported,
            intrinsics=intr,
            T_x0=est.T_x,
            T_board0=est.T_board,
            options=RefineOptions(),
        )
        pb.sigma_px = NOISE_PX
        t0, c0 = time.perf_counter(), time.process_time()
        pb.solve(robust=False)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    t0, c0 = time.perf_counter(), time.process_time()
    r = refine(
        mode=mode,
        object_points=s.target.object_points(),
        views=refine_views(s),
        intrinsics=intr,
        T_x0=est.T_x,
        T_board0=est.T_board,
        starts=closed,
    )
    full, full_cpu = time.perf_counter() - t0, time.process_time() - c0
    return min(times), min(cpus), full, full_cpu, pb.iterations, r.status


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50, help="sessions per mode and scenario (default 50)")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument(
        "--scenarios", nargs="+", default=["clean", "robot", "outliers"], choices=["clean", "robot", "outliers"]
    )
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    print(
        f"# bench_refine: {args.seeds} seeds per mode and scenario; 20 views, 11x8 board, 1280x720, "
        f"{NOISE_PX} px; robot noise scenario {ROBOT_NOISE[0]} mm / {ROBOT_NOISE[1]} deg per axis"
    )
    print(f"# command: python {' '.join(sys.argv)}")
    summary = {}
    for mode in args.modes:
        if "clean" in args.scenarios:
            clean = run_scenario(mode, seeds, label="clean")
            summary[(mode, "clean")] = summarize("clean", mode, clean)
        if "robot" in args.scenarios:
            noisy = run_scenario(mode, seeds, robot_noise=ROBOT_NOISE, label="robot-noise")
            summary[(mode, "robot")] = summarize("robot-noise", mode, noisy)
        if "outliers" in args.scenarios:
            out = run_scenario(mode, seeds, outliers=2, label="2-outliers")
            summary[(mode, "out")] = summarize("2-outliers (bound: clean session)", mode, out)
        sys.stdout.flush()
    if not args.no_timing:
        for mode in args.modes:
            for n in (20, 200):
                one, one_cpu, full, full_cpu, iters, status = time_solves(mode, n)
                print(
                    f"timing {mode:<12} {n:3d} views: one solve {one:.3f} s wall / {one_cpu:.3f} s cpu "
                    f"({iters} LM iterations); full refine with outlier loop {full:.2f} s wall / {full_cpu:.2f} s cpu"
                    f" ({status}; target for 200 views: < 3 s on 2 cores)"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
