"""Is a rendered session's reported uncertainty honest on its own geometry? New robot-noise draws, the same images.

A session that the truth left far outside its 95 % ellipsoid (``bench_rendered.py``'s ``d2``) is either a tail
draw, which one session in twenty is, or a model that is wrong on that geometry. Its images are detected once;
each draw replaces every reported robot pose by the true one (``ground_truth.json``) times a fresh error of the
simulator's iid model (:func:`handeye.sim.scenarios.perturb_T_base_end`: end frame, per-axis Gaussian
rotation vector and translation; by default the session's own sizes) and calibrates again as ``handeye
calibrate`` does (:func:`handeye.pipeline.run_calibration`, the detections reused, the command's process set-up).
Wrong robot poses the session was written with are left out: every draw starts from the true poses.

Printed per session: the squared Mahalanobis distance ``d2 = xi^T C^-1 xi`` of X's error
``xi = Log(inv(T_est) · T_true)`` under ``C = cov_x_6x6`` over the draws (chi-square with 6 dof when the
covariance is honest: mean 6, median 5.35, 95 % inside the ellipsoid), its rotation-only part (mean 3), the
RMS rotation and translation error against the RMS reported sigma, and the session's own realisation (its
``poses.txt`` calibrated as written) with the share of the draws at least as far from the truth. That rank is
uniform when the realisation is one more draw of the model: over several sessions its mean is 0.5, and 5 % of
them fall below 0.05 (printed last). Prints figures; asserts nothing.

    python benchmarks/bench_noise_draws.py SESSION [SESSION ...] [--draws 200] [--seed 0] [--robot-noise MM DEG]
                                           [--workers 2]

SESSION: a folder written by :func:`handeye.sim.vendor.write_vendor_session` (``bench_rendered.py --keep DIR``
keeps them). ``--workers``: sessions at once, on Dask (``benchmarks/fanout.py``).

Figures (2026-12-07), on the sessions of ``bench_rendered.py`` (seeds 700-1139) whose truth lay furthest outside
their ellipsoids, each a tail draw on its own geometry:

| session | noise | draws | d2 mean | inside the 95 % ellipsoid |
|---|---|---|---|---|
| 920, 926, 932, 938 (0.2 mm / 0.05 deg), plug-in covariance | 0.2 / 0.05 | 200 each | 5.99-6.64 | 92-96 % |
| the same, with X's degrees-of-freedom factor (1.03-1.06) | 0.2 / 0.05 | 200 each | 5.80-6.27 | 93-96 % |
| 1120, 1127, 1133, with the factor | 0.5 / 0.1 | 150 each | 5.72-6.52 | 92-94 % |

On 24 sessions chosen before looking (``bench_rendered.py --first 1200 --sessions 24 --keep DIR``; 100 % inside,
mean d2 5.25), the 16 with robot noise at 40 draws each: the realised distance's rank has mean 0.53, none below
0.05 or 0.1. The realisations behave like the draws.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np


def draws(folder: Path, n: int, seed: int, robot_noise: tuple[float, float] | None) -> tuple[str, float | None]:
    """(the line of figures of ``n`` robot-noise draws on the session in ``folder``, the realised distance's rank).

    The rank: the share of the draws at least as far as the session's own realisation (its ``poses.txt``
    calibrated as written); uniform on [0, 1] when the realisation is one more draw of the same model.
    """
    from scipy.stats import chi2

    from handeye.config import load_preset
    from handeye.frames import tangent_difference
    from handeye.mounting import mounting
    from handeye.pipeline import CalibrateOptions, detect_ahead, run_calibration
    from handeye.session import load_session
    from handeye.sim.scenarios import perturb_T_base_end

    truth = json.loads((folder / "ground_truth.json").read_text())
    mm, deg = robot_noise or (truth["noise"]["robot_noise_mm"], truth["noise"]["robot_noise_deg"])
    if not (mm > 0 or deg > 0):
        return f"{folder}: written without robot noise; give --robot-noise MM DEG", None
    session = load_session(folder)
    T_x_true = np.asarray(truth[mounting(session.mode).x_name])
    options = CalibrateOptions.from_config(load_preset("calibration"))
    detected = detect_ahead(session, options)

    def error(views=None):
        """(xi, cov_x_6x6) of the session calibrated with ``views`` in place of its own, or None."""
        s = session if views is None else dataclasses.replace(session, views=views)
        r = run_calibration(s, options, detected=detected).refined
        return None if r is None else (tangent_difference(r.T_x, T_x_true), r.cov_x_6x6)

    own = error()
    realised = None if own is None else float(own[0] @ np.linalg.solve(own[1], own[0]))
    T_true = np.stack([np.asarray(truth["views"][v.view_id]["T_base_end_true"]) for v in session.views])
    rng = np.random.default_rng(seed)
    d2, d2_rot, err, sig = [], [], [], []
    for _ in range(n):
        T_rep = perturb_T_base_end(T_true, rng=rng, sigma_mm=mm, sigma_deg=deg)
        got = error(tuple(dataclasses.replace(v, T_base_end=T) for v, T in zip(session.views, T_rep, strict=True)))
        if got is None:
            continue
        xi, C = got
        d2.append(float(xi @ np.linalg.solve(C, xi)))
        d2_rot.append(float(xi[:3] @ np.linalg.solve(C[:3, :3], xi[:3])))
        err.append((np.degrees(np.linalg.norm(xi[:3])), 1e3 * np.linalg.norm(xi[3:])))
        sig.append((np.degrees(np.sqrt(np.trace(C[:3, :3]))), 1e3 * np.sqrt(np.trace(C[3:, 3:]))))
    if not d2:
        return f"{folder}: no draw was refined", None
    d, e, s = np.array(d2), np.sqrt(np.mean(np.square(err), axis=0)), np.sqrt(np.mean(np.square(sig), axis=0))
    rank = None if realised is None else float(np.mean(d >= realised))
    own_text = "" if rank is None else f" | realised d2 {realised:.2f}, rank among the draws {rank:.2f}"
    return (
        f"{folder.name}: {len(d)} draws of {mm:g} mm / {deg:g} deg | d2 mean {d.mean():.2f} (6), median "
        f"{np.median(d):.2f} (5.35), inside the 95 % ellipsoid {100 * np.mean(d <= chi2.ppf(0.95, 6)):.0f} % | "
        f"rotation d2 mean {np.mean(d2_rot):.2f} (3) | RMS error {e[0]:.4f} deg {e[1]:.3f} mm, reported sigma "
        f"{s[0]:.4f} deg {s[1]:.3f} mm{own_text}"
    ), rank


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sessions", type=Path, nargs="+", help="rendered session folders with ground_truth.json")
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--robot-noise", type=float, nargs=2, metavar=("MM", "DEG"), help="per axis (default: the session's own)"
    )
    ap.add_argument("--workers", type=int, default=1, help="sessions at once (Dask worker processes)")
    args = ap.parse_args()
    from fanout import ordered_map

    from handeye.cli import prepare_process

    prepare_process()  # the command's own set-up, before numpy's BLAS starts
    k = len(args.sessions)
    noise = tuple(args.robot_noise) if args.robot_noise else None
    ranks = []
    for line, rank in ordered_map(
        draws, args.sessions, [args.draws] * k, [args.seed] * k, [noise] * k, workers=args.workers
    ):
        print(line, flush=True)
        if rank is not None:
            ranks.append(rank)
    if len(ranks) > 1:
        r = np.array(ranks)
        print(
            f"{len(r)} sessions: the realised distance's rank among its own draws, mean {r.mean():.2f} (0.5); "
            f"below 0.05 in {int(np.sum(r < 0.05))} (5 % expected), below 0.1 in {int(np.sum(r < 0.1))} (10 %)"
        )


if __name__ == "__main__":
    main()
