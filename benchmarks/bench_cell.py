"""Benchmark of cells: several cameras of one arm in one graph (handeye.refine.cell) against each camera alone.

Corner-level simulated cells (:func:`handeye.sim.cell.make_cell`: 2 or 3 fixed cameras behind a board on the
flange, from 3 cameras on a wrist camera seeing a board on the table; 11x8 board, 1280x720, 0.3 px corner
noise) with the kinematic arm error of the simulator (the UR5e with DH errors of 0.1-0.5 mm / 0.01-0.05 deg
and 0.005 deg encoder noise, shared by every camera). Each camera is calibrated alone as the pipeline does
(calibrateCamera, solvePnP, every closed form, :func:`handeye.refine.refine` with the kinematic model), then
all of them jointly from the solo results (:func:`handeye.refine.cell.refine_cell`).

Printed per cell size: RMS error of X (rotation deg, translation mm) joint and solo over cameras and cells;
the ratio of the joint RMS error to the Cramér-Rao bound of the joint problem (its covariance at the truth:
the true poses, intrinsics and noise levels, the arm's stated DH prior); the share of cameras whose truth
lies inside the 95 % ellipsoid of their joint ``cov_x_6x6`` (chi-square 6 dof) and the same for every pair of
fixed cameras' ``T_a_b``; the time of the solo refinements and of the joint one. Progress on stderr, figures
on stdout.

Figures (2026-12-06, 40 views, seeds 0-29 per size, 90 cells; ``--seeds 30 --sizes 2 3 4``; the issue asks
for 200 cells, these are fewer):

| cams | X err joint (deg, mm) | X err solo (deg, mm) | joint/CRB (rot, trans) | cover X | cover T_a_b | solo/joint s |
|---|---|---|---|---|---|---|
| 2 | 0.0734, 0.586 | 0.0783, 0.656 | 1.16, 0.92 | 92 % of 60 | 87 % of 30 | 2.2 / 3.2 |
| 3 | 0.0698, 0.528 | 0.0786, 0.603 | 1.12, 0.96 | 94 % of 90 | 90 % of 30 | 1.7 / 1.8 |
| 4 | 0.0646, 0.536 | 0.0742, 0.659 | 1.10, 1.01 | 93 % of 120 | 93 % of 90 | 1.8 / 0.9 |

(30 cells per size; coverage: the share inside the 95 % ellipsoid; seconds per cell on a shared machine.)

The joint X is closer to the truth than the solo one in every size (RMS, all cameras); its rotation error is
1.10-1.16 times the joint problem's bound, its translation error 0.92-1.01 times (the bound holds the arm's
stated DH prior, wider than the simulated DH errors). The pairs' coverage of 2-3 camera cells (87-90 %, 30
pairs each) is at the low end. Times on a shared 2-core machine: a 4-camera 40-view cell takes
the four solo refinements plus about as long again for the joint graph, 6-7 times one camera's refinement
(the issue's 4x is not reached; the joint graph is Python reprojection factors, the solo ones' cost).
Whole ``handeye calibrate`` commands (``--rendered``; detection, validation, diagnostics and every report
included) of a rendered 4-camera 40-view cell against one camera's session, medians of 4 interleaved rounds on
the shared 2-core machine (load average 10.7-15.4; 2026-12-06): one camera 19.9 s wall / 7.1 s CPU, the cell
65.8 s wall / 24.8 s CPU: 3.31x wall, 3.51x CPU (the code before the cell detected each camera's images ahead:
83.0 s wall / 25.0 s CPU, 3.82x wall, 3.64x CPU, in the same rounds). Each camera's own calibration is most of
the cell's time; its joint graph 3 s wall.

Cameras that see each view's flange at their own instant (2026-12-06, ``--seeds 8 --sizes 2 3 --views 20
--view-jitter 0.1 0.2``: each fixed camera's flange moved by 0.1 deg / 0.2 mm per axis, its own draw per view):
the test of one pose per view rejects it in 16 of 16 cells and the cell estimates each camera's own pose of a
shared view (median sigma 0.079 deg / 0.175 mm; the deviation the cameras share goes to the arm's noise). X
error joint 0.151 / 0.127 deg, 1.34 / 1.15 mm (2 / 3 cameras; solo 0.162 / 0.144 deg, 2.16 / 1.79 mm), X
coverage 88 % of 16 / 92 % of 24, pairs 88 % / 75 % of 8. With one shared pose per view (``noise.view_pose_alpha:
0``) the joint X is worse than the solo one (0.288 / 0.228 deg, 3.60 / 2.22 mm), X coverage 38 % / 42 %, pairs
0 %. Without the jitter (the table above, ``--seeds 5``) the test stands in every cell and the figures are those
of one pose per view, to the digit.

Usage: python benchmarks/bench_cell.py [--seeds 10] [--sizes 2 3 4] [--views 40] [--jobs 1] [--rendered DIR]
[--view-jitter DEG MM] [--rounds 3] [--before CHECKOUT]
(``--rendered DIR``: also render a cell of the largest size into DIR/cell, or reuse it, and time ``handeye
calibrate`` of one camera's session against the whole cell in interleaved rounds; ``--before``: a checkout of the
code before a change in the same rounds; ``--seeds 0``: the rendered timing alone; ``--view-jitter DEG MM``: each
fixed camera sees each view's flange moved by its own draw of that size per axis, :func:`handeye.sim.cell.make_cell`).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_refine import closed_forms, refine_views  # noqa: E402  (one copy of the pipeline's seeding)
from fanout import ordered_map  # noqa: E402

from handeye.frames import inv_T, tangent_difference  # noqa: E402
from handeye.refine import RefineOptions, refine  # noqa: E402
from handeye.refine.cell import CellCameraInput, CellState, refine_cell  # noqa: E402
from handeye.refine.problem import cell_information, cell_ordering  # noqa: E402
from handeye.sim.cell import make_cell  # noqa: E402

ARM = "ur5e"
ROOT = Path(__file__).resolve().parent.parent
NOISE_PX = 0.3
CHI2_95 = chi2.ppf(0.95, 6)


def _inputs(cell, intr, T_x, T_board, sigma_px):
    out = []
    for name, s in zip(cell.names, cell.sessions, strict=True):
        out.append(
            CellCameraInput(
                name=name,
                mode=s.mode,
                object_points=s.target.object_points(),
                views=tuple(v for v in refine_views(s) if len(v.corner_ids)),
                intrinsics=intr[name],
                T_x0=T_x[name],
                T_board0=T_board[name],
                sigma_px=sigma_px[name],
            )
        )
    return out


def crb(cell, options) -> dict:
    """The joint problem's covariance of each X at the truth (the Cramér-Rao bound of the cell's model)."""
    names = cell.names
    st = CellState(
        _inputs(
            cell,
            {n: s.intrinsics for n, s in zip(names, cell.sessions, strict=True)},
            {n: s.T_x_true for n, s in zip(names, cell.sessions, strict=True)},
            {n: s.T_board_true for n, s in zip(names, cell.sessions, strict=True)},
            dict.fromkeys(names, NOISE_PX),
        ),
        options,
    )
    first = cell.sessions[0]
    st.P = np.array([first.T_base_end_true[first.index(v)] for v in st.ids])
    st.sigma_q = np.radians(first.robot_model["encoder_sigma_deg"])
    H, _parts = cell_information(st)
    S = np.linalg.inv(H)
    out, at = {}, 0
    keys, sizes = cell_ordering(st)
    blocks = []
    for cam in st.cams:
        blocks.append(cam.name)
        if cam.free.size:
            blocks.append(None)
    for name, size in zip(blocks + [None] * (len(sizes) - len(blocks)), sizes, strict=True):
        if name is not None:
            out[name] = S[at : at + 6, at : at + 6]
        at += size
    return out


def run_one(n_cameras: int, seed: int, n_views: int, view_jitter: tuple = (0.0, 0.0)) -> dict:
    cell = make_cell(n_cameras, n_views=n_views, seed=seed, noise_px=NOISE_PX, arm=ARM, view_jitter=view_jitter)
    o = RefineOptions(arm=ARM)
    t0 = time.perf_counter()
    solo = {}
    for name, s in zip(cell.names, cell.sessions, strict=True):
        k, closed = closed_forms(s)
        views = [v for v in refine_views(s) if len(v.corner_ids)]
        solo[name] = refine(
            mode=s.mode,
            object_points=s.target.object_points(),
            views=views,
            intrinsics=k,
            T_x0=closed["tsai"].T_x,
            T_board0=closed["tsai"].T_board,
            options=o,
            starts=closed,
        )
    t1 = time.perf_counter()
    cr = refine_cell(
        _inputs(
            cell,
            {n: r.intrinsics for n, r in solo.items()},
            {n: r.T_x for n, r in solo.items()},
            {n: r.T_board for n, r in solo.items()},
            {n: r.sigma_px for n, r in solo.items()},
        ),
        options=o,
        dh_scale0=max(float(r.robot_model.get("dh_prior_scale") or 1.0) for r in solo.values()),
    )
    t2 = time.perf_counter()
    bound = crb(cell, o)
    rows = []
    for name, s in zip(cell.names, cell.sessions, strict=True):
        xi_j = tangent_difference(cr.T_x[name], s.T_x_true)
        xi_s = tangent_difference(solo[name].T_x, s.T_x_true)
        rows.append(
            {
                "camera": name,
                "mode": s.mode,
                "joint": xi_j.tolist(),
                "solo": xi_s.tolist(),
                "m2_joint": float(xi_j @ np.linalg.solve(cr.cov_x(name), xi_j)),
                "m2_solo": float(xi_s @ np.linalg.solve(np.asarray(solo[name].cov_x_6x6), xi_s)),
                "crb_trace_rot": float(np.trace(bound[name][:3, :3])),
                "crb_trace_trans": float(np.trace(bound[name][3:, 3:])),
            }
        )
    pairs = []
    for a, b in cr.pairs():
        T, C = cr.pair(a, b)
        T_true = inv_T(cell.session(a).T_x_true) @ cell.session(b).T_x_true
        xi = tangent_difference(T, T_true)
        pairs.append(float(xi @ np.linalg.solve(C, xi)))
    own = cr.view_poses
    return {
        "n": n_cameras,
        "seed": seed,
        "rows": rows,
        "pairs": pairs,
        "solo_s": t1 - t0,
        "joint_s": t2 - t1,
        "own_poses": [own["sigma_rot_deg"], own["sigma_trans_mm"]] if own.get("estimated") else None,
    }


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else float("nan")


def summary(results: list[dict]) -> str:
    lines = [
        "| cameras | cells | X error joint (deg, mm) | X error solo (deg, mm) | joint / CRB (rot, trans) | "
        "coverage X 95 % | coverage T_a_b 95 % | solo s / joint s per cell |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n in sorted({r["n"] for r in results}):
        rs = [r for r in results if r["n"] == n]
        rows = [row for r in rs for row in r["rows"]]
        j = np.array([row["joint"] for row in rows])
        s = np.array([row["solo"] for row in rows])
        rot = lambda x: np.degrees(np.linalg.norm(x[:, :3], axis=1))  # noqa: E731
        tr = lambda x: 1e3 * np.linalg.norm(x[:, 3:], axis=1)  # noqa: E731
        crb_rot = np.sqrt(np.mean([row["crb_trace_rot"] for row in rows]))
        crb_tr = np.sqrt(np.mean([row["crb_trace_trans"] for row in rows]))
        cov_x = np.mean([row["m2_joint"] <= CHI2_95 for row in rows])
        pairs = [m for r in rs for m in r["pairs"]]
        cov_p = np.mean([m <= CHI2_95 for m in pairs]) if pairs else float("nan")
        lines.append(
            f"| {n} | {len(rs)} | {_rms(rot(j)):.4f}, {_rms(tr(j)):.3f} | {_rms(rot(s)):.4f}, {_rms(tr(s)):.3f} | "
            f"{_rms(np.linalg.norm(j[:, :3], axis=1)) / crb_rot:.2f}, "
            f"{_rms(np.linalg.norm(j[:, 3:], axis=1)) / crb_tr:.2f} | "
            f"{100 * cov_x:.0f} % of {len(rows)} | {100 * cov_p:.0f} % of {len(pairs)} | "
            f"{np.mean([r['solo_s'] for r in rs]):.1f} / {np.mean([r['joint_s'] for r in rs]):.1f} |"
        )
    own = np.array([r["own_poses"] for r in results if r.get("own_poses")]).reshape(-1, 2)
    line = f"\nEach camera's own pose of a shared view estimated in {len(own)} of {len(results)} cells"
    if len(own):
        line += f" (sigma per axis, median: {np.median(own[:, 0]):.3f} deg, {np.median(own[:, 1]):.3f} mm)"
    lines.append(line)
    return "\n".join(lines)


def _timed_command(args: list[str], root: Path = ROOT) -> tuple[float, float]:
    """(wall s, CPU s of the process and its children) of ``python -m handeye.cli ARGS`` from the checkout ``root``."""
    path = os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH", "")) if p)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "handeye.cli", *args]
    subprocess.run(cmd, env=dict(os.environ, PYTHONPATH=path), check=False, capture_output=True)  # exit: the verdict
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def rendered_timing(n_cameras: int, n_views: int, folder: Path, rounds: int = 3, before: Optional[Path] = None) -> str:
    """Whole ``handeye calibrate`` commands: one rendered camera's session against the whole rendered cell.

    The cell is rendered into ``folder/cell`` unless it is there already; both commands run with the same
    options (the session's and the cell's defaults, the arm the sessions name), ``rounds`` interleaved rounds
    (one camera, then the cell; with ``before``, a checkout of the code before a change, its two commands in
    the same rounds), each command's wall and CPU time (its process and children); the medians.
    """
    from handeye.sim.cell import write_cell

    cell = folder / "cell"
    if not (cell / "cell.yaml").is_file():
        write_cell(cell, n_cameras, n_views=n_views, seed=0, arm=ARM)
    one_cam = sorted(p.parent.name for p in cell.glob("*/session.yaml"))[0]
    codes = {"after": ROOT} if before is None else {"before": before.resolve(), "after": ROOT}
    times: dict = {(c, k): [] for c in codes for k in ("one", "cell")}
    loads = []
    for i in range(rounds):
        for code, root in codes.items():
            out = folder / code
            times[code, "one"].append(
                _timed_command(["calibrate", str(cell / one_cam), "--out", str(out / "one")], root)
            )
            times[code, "cell"].append(_timed_command(["calibrate", str(cell), "--out", str(out / "cell")], root))
            print(
                f"round {i + 1} {code}: one camera {times[code, 'one'][-1][0]:.1f} s, "
                f"the cell {times[code, 'cell'][-1][0]:.1f} s (wall)",
                file=sys.stderr,
            )
        loads.append(os.getloadavg()[0])
    lines = [
        f"handeye calibrate, rendered {n_cameras}-camera {n_views}-view cell against one camera ({one_cam}), "
        f"median of {rounds} interleaved rounds (load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} "
        "cores):"
    ]
    for code in codes:
        res = json.loads((folder / code / "cell" / "result.json").read_text(encoding="utf-8"))
        w1, c1 = np.median(times[code, "one"], axis=0)
        wn, cn = np.median(times[code, "cell"], axis=0)
        lines.append(
            f"  {code}: one camera {w1:.1f} s wall / {c1:.1f} s CPU, the cell {wn:.1f} s wall / {cn:.1f} s CPU: "
            f"{wn / w1:.2f}x wall, {cn / c1:.2f}x CPU (its joint graph {res['seconds']['joint']:.1f} s wall)"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--sizes", type=int, nargs="+", default=[2, 3, 4])
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument(
        "--view-jitter",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("DEG", "MM"),
        help="each fixed camera sees each view's flange moved by its own draw of this size per axis",
    )
    ap.add_argument("--rendered", type=Path, metavar="DIR", help="also time calibrate on a rendered cell in DIR")
    ap.add_argument("--rounds", type=int, default=3, help="with --rendered: interleaved rounds of the two commands")
    ap.add_argument(
        "--before",
        type=Path,
        metavar="CHECKOUT",
        help="with --rendered: also time a checkout of the code before a change",
    )
    args = ap.parse_args()
    if args.rendered is not None:
        print(rendered_timing(max(args.sizes), args.views, args.rendered, args.rounds, args.before))
    jobs = [(n, seed) for n in args.sizes for seed in range(args.seeds)]
    results = []
    it = ordered_map(
        run_one,
        [n for n, _ in jobs],
        [s for _, s in jobs],
        [args.views] * len(jobs),
        [tuple(args.view_jitter)] * len(jobs),
        workers=args.jobs,
    )
    for (n, seed), r in zip(jobs, it, strict=True):
        results.append(r)
        print(
            f"{n} cameras seed {seed}: m2 joint {[round(x['m2_joint'], 1) for x in r['rows']]}, "
            f"solo {r['solo_s']:.1f} s, joint {r['joint_s']:.1f} s",
            file=sys.stderr,
        )
    print(summary(results))


if __name__ == "__main__":
    main()
