"""Predicted hand-eye uncertainty: the automatic plan vs hand-placed-like random views.

For several simulated rigs (both mounting modes) this prints the predicted 1-sigma of the hand-eye
transform (root of the trace of its marginal covariance, from the Fisher information used by the
planner, i.e. the Cramer-Rao bound of an estimator that models pixel and robot noise) for
  * the automatic plan: start view + 3 probe views + N planned views,
  * K views drawn like a careful operator places them (handeye.sim.scenarios.sample_view_poses: 15-40 deg
    tilts in all directions, rolls up to 80 deg, 0.35-0.9 m), median over draws.

With ``--calibrate N`` it also runs N simulated automatic collections per mode (``handeye collect
--camera sim --robot sim --auto --seed k``, k = 0..N-1) and calibrates each, printing the error of
the hand-eye transform against the simulator's truth and its squared Mahalanobis distance under the
reported covariance (an honest covariance gives a chi-square(6): mean 6).

    python benchmarks/bench_collect_plan.py [--planned 8] [--random 8 15 20] [--seeds 5] [--calibrate 12]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from handeye.collect import plan as P
from handeye.mounting import mounting
from handeye.sim.devices import SimRig
from handeye.sim.scenarios import default_intrinsics, sample_view_poses


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--planned", type=int, default=8)
    ap.add_argument("--random", type=int, nargs="+", default=[8, 15, 20])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--draws", type=int, default=10, help="random view sets per rig")
    ap.add_argument(
        "--calibrate", type=int, default=0, metavar="N", help="also collect and calibrate N simulated sessions per mode"
    )
    a = ap.parse_args(argv)
    intr = default_intrinsics(1280, 720)
    cfg = P.PlanConfig()
    print(
        f"assumed noise: {cfg.pixel_noise_px} px corners, robot {cfg.robot_noise_mm} mm / {cfg.robot_noise_deg} deg "
        "per axis; sigma = root of the trace over 3 axes"
    )
    print(
        f"{'mode':12s} {'seed':>4s} {'plan views':>10s} {'plan deg':>9s} {'plan mm':>8s}"
        + "".join(f" {'rand' + str(k) + ' deg':>11s} {'mm':>6s}" for k in a.random)
        + "  plan s"
    )
    for mode in ("eye_in_hand", "eye_to_hand"):
        for seed in range(a.seeds):
            rng = np.random.default_rng(seed)
            rig = SimRig.sample(mode=mode, rng=rng, intrinsics=intr)
            T0 = rig.T_base_end_start
            C0 = mounting(mode).predict_T_cam_board(rig.T_x, rig.T_board, T0)
            probes = [pair[0] for pair in P.probe_poses(T0)]
            t = time.perf_counter()
            plan = P.make_plan(
                mode=mode,
                T_x=rig.T_x,
                T_board=rig.T_board,
                T_base_end_start=T0,
                T_cam_board_start=C0,
                T_base_end_done=[T0, *probes],
                target=rig.target,
                intrinsics=intr,
                n_views=a.planned,
                config=cfg,
            )
            dt = time.perf_counter() - t
            row = (
                f"{mode:12s} {seed:4d} {1 + len(probes) + len(plan.views):10d} "
                f"{plan.views[-1].sigma_rot_deg:9.4f} {plan.views[-1].sigma_trans_mm:8.3f}"
            )
            for k in a.random:
                sr, st = [], []
                for _ in range(a.draws):
                    Ts = sample_view_poses(
                        mode=mode,
                        n_views=k,
                        rng=rng,
                        T_x=rig.T_x,
                        T_board=rig.T_board,
                        target=rig.target,
                        intrinsics=intr,
                    )
                    info = P.information_of_views(
                        mode=mode,
                        T_x=rig.T_x,
                        T_board=rig.T_board,
                        T_base_end=Ts,
                        target=rig.target,
                        intrinsics=intr,
                        config=cfg,
                    )
                    r, s = P.predicted_sigma(info)
                    sr.append(r)
                    st.append(s)
                row += f" {np.median(sr):11.4f} {np.median(st):6.3f}"
            print(row + f"  {dt:6.2f}", flush=True)
    if a.calibrate:
        calibrate_collections(a.calibrate)
    return 0


def calibrate_collections(n: int) -> None:
    """Collect (simulated, --auto) and calibrate n sessions per mode; errors against the truth."""
    import contextlib
    import io
    import json
    import tempfile
    from pathlib import Path

    from scipy.stats import chi2

    from handeye.cli import main as cli
    from handeye.frames import pose_error, tangent_difference

    print("\nsimulated --auto collections (start + 3 probes + 8 planned views, 1280x720), then calibrate:")
    print(f"{'mode':12s} {'seed':>4s} {'err deg':>8s} {'err mm':>7s} {'d2 (6 dof)':>10s}")
    for mode in ("eye_in_hand", "eye_to_hand"):
        d2s = []
        for seed in range(n):
            with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()):
                col, res_dir = Path(tmp) / "col", Path(tmp) / "res"
                cli(
                    [
                        "-q",
                        "collect",
                        str(col),
                        "--mode",
                        mode,
                        "--camera",
                        "sim",
                        "--robot",
                        "sim",
                        "--auto",
                        "--seed",
                        str(seed),
                    ]
                )
                cli(["-q", "calibrate", str(col), "--out", str(res_dir), "--no-report"])
                truth = json.loads((col / "ground_truth.json").read_text())
                res = json.loads((res_dir / "result.json").read_text())
            name = mounting(mode).x_name
            T_est, T_true = np.asarray(res[name]), np.asarray(truth[name])
            xi = tangent_difference(T_est, T_true)
            d2 = float(xi @ np.linalg.solve(np.asarray(res["refinement"]["cov_x_6x6"], float), xi))
            r, t = pose_error(T_est, T_true)
            d2s.append(d2)
            print(f"{mode:12s} {seed:4d} {r:8.4f} {t:7.3f} {d2:10.1f}", flush=True)
        print(
            f"{mode}: mean d2 {np.mean(d2s):.2f} over {n} sessions (chi-square(6): 6, 90 % of means within "
            f"{chi2.ppf(0.05, 6 * n) / n:.2f}-{chi2.ppf(0.95, 6 * n) / n:.2f})"
        )


if __name__ == "__main__":
    sys.exit(main())
