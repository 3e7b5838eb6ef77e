"""Benchmark of cells: several cameras of one arm in one graph (handeye.refine.cell) against each camera alone.

Corner-level simulated cells (:func:`handeye.sim.cell.make_cell`: 2 or 3 fixed cameras behind a board on the
flange, from 3 cameras on a wrist camera seeing a board on the table; 11x8 board, 1280x720, 0.3 px corner
noise) with the kinematic arm error of the simulator (the UR5e with DH errors of 0.1-0.5 mm / 0.01-0.05 deg
and 0.005 deg encoder noise, shared by every camera). Each camera is calibrated alone as the pipeline does
(calibrateCamera, solvePnP, every closed form, :func:`handeye.refine.refine` with the kinematic model), then
all of them jointly from the solo results (:func:`handeye.refine.cell.refine_cell`).

Printed per cell size and over all cells: RMS error of X (rotation deg, translation mm) joint and solo; the
ratio of the joint RMS error to the Cramér-Rao bound of the joint problem as simulated (the information at the
truth: true poses, intrinsics, 0.3 px and the true encoder noise; the DH prior the simulator's own spread of
DH errors, RMS 0.321 mm / 0.0321 deg, where the estimator assumes the arm's stated 0.3 mm / 0.03 deg) with
its 95 % interval (bootstrap over cells: a cell's cameras share one arm); the share of cameras whose truth
lies inside the 95 % ellipsoid of their joint ``cov_x_6x6`` (chi-square 6 dof) and the same for every pair of
fixed cameras' ``T_a_b``, each with its exact binomial 95 % interval; the time of the solo refinements and of
the joint one. Then per camera the joint and solo errors and how often the joint one is closer; then the
ratios to the bound with the stated prior, to the error the estimator is expected to make on each cell's own
arm (its noise part plus its prior's pull towards the nominal arm) and the pairs' ratios. Progress on stderr,
figures on stdout; ``--out FILE`` keeps each cell's record (a rerun skips the cells in it), ``--summary FILE``
prints the tables of saved records.

Figures (2026-12-06, 40 views, 210 cells: ``--seeds 70 --sizes 2 3 4``, two runs of 35 seeds each with
``--first-seed 0`` / ``35``; a size's cells are the simulator's seeds 1000 (n - 2) + 0..69, no two sizes share an
arm or a camera):

| n | cells | joint (deg, mm) | solo (deg, mm) | /CRB rot | /CRB trans | cover X % | cover T_a_b % |
|---|---|---|---|---|---|---|---|
| 2 | 70 | 0.0682, 0.593 | 0.0748, 0.678 | 1.05 [0.96, 1.14] | 0.91 [0.83, 0.99] | 93.6 [88, 97] | 90.0 [80, 96] |
| 3 | 70 | 0.0656, 0.583 | 0.0752, 0.673 | 1.00 [0.94, 1.06] | 0.98 [0.90, 1.06] | 96.2 [93, 98] | 92.9 [84, 98] |
| 4 | 70 | 0.0613, 0.567 | 0.0729, 0.688 | 1.00 [0.95, 1.05] | 1.01 [0.95, 1.08] | 98.6 [96, 100] | 97.1 [94, 99] |
| all | 210 | 0.0643, 0.578 | 0.0741, 0.681 | 1.01 [0.98, 1.05] | 0.98 [0.93, 1.02] | 96.7 [95, 98] | 94.9 [92, 97] |

(ratios with their 95 % bootstrap interval over cells; coverages with their exact binomial 95 % interval, of
140, 210, 280 and 630 cameras and of 70, 70, 210 and 350 pairs.)

The joint X is closer to the truth than the solo one for every camera (RMS over 70 cells), the fixed cameras by
7-22 % in rotation and 7-26 % in translation; the wrist camera's error equals its solo one (0.0705 / 0.0715 deg,
0.495 / 0.499 mm with 3 cameras; 0.0718 / 0.0718 deg, 0.456 / 0.469 mm with 4) and its joint bound (0.070 deg, 0.50
mm): the fixed cameras add little about it. The joint error is at the bound of the problem as simulated (1.01 and
0.98 over all cells); with the arm's stated DH prior instead the ratios are 1.03 [1.00, 1.07] and 1.01 [0.97,
1.05], and against the error expected on each cell's own arm 1.03 [0.99, 1.06] and 0.99 [0.95, 1.03]: the estimator
is efficient. The 4-camera cells' X coverage (98.6 %) is above 95 % with a mean Mahalanobis distance of 6.00: the
simulator's DH errors, whose magnitudes are uniform in a range, have lighter tails than the Gaussian prior. A side
check (not in this script), the same 40 4-camera cells (seeds 2000-2039) with the DH draw replaced by Gaussian
errors of the same RMS: 93.8 % [89, 97] of the X inside (mean 6.03), against 97.5 % (mean 6.07) with the
simulator's draw. Earlier figures of 30 cells per size (1.10-1.16 in rotation, 87-93 % of the pairs) drew every
size from the same seeds (one seed's 2- and 3-camera cells held the same two fixed cameras and noise, all sizes one
arm), so their rows moved together, and held the stated DH prior in the bound.
Times on a shared 2-core machine, refinements alone: a 4-camera 40-view cell's joint graph costs about as much
as its four solo refinements together (Python reprojection factors). The whole commands:
Whole ``handeye calibrate`` commands (``--rendered``; detection, validation, diagnostics and every report
included) of a rendered 4-camera 40-view cell against one camera's session, medians of 4 interleaved rounds on
the shared 2-core machine (load average 10.7-15.4; 2026-12-06): one camera 19.9 s wall / 7.1 s CPU, the cell
65.8 s wall / 24.8 s CPU: 3.31x wall, 3.51x CPU (the code before the cell detected each camera's images ahead:
83.0 s wall / 25.0 s CPU, 3.82x wall, 3.64x CPU, in the same rounds). Each camera's own calibration is most of
the cell's time; its joint graph 3 s wall. The same command with the faster single-session stages, the
cameras' own poses of a shared view and the drift test (2026-12-06, load average 1.6-1.9, 3 rounds): one camera
6.4 s wall / 8.1 s CPU, the cell 23.3 s wall / 31.6 s CPU: 3.65x wall, 3.91x CPU (its joint graph 4.7 s wall).

Cameras that see each view's flange at their own instant (2026-12-06, ``--seeds 8 --sizes 2 3 --views 20
--view-jitter 0.1 0.2``: each fixed camera's flange moved by 0.1 deg / 0.2 mm per axis, its own draw per view):
the test of one pose per view rejects it in 16 of 16 cells and the cell estimates each camera's own pose of a
shared view (median sigma 0.079 deg / 0.175 mm; the deviation the cameras share goes to the arm's noise). X
error joint 0.151 / 0.127 deg, 1.34 / 1.15 mm (2 / 3 cameras; solo 0.162 / 0.144 deg, 2.16 / 1.79 mm), X
coverage 88 % of 16 / 92 % of 24, pairs 88 % / 75 % of 8. With one shared pose per view (``noise.view_pose_alpha:
0``) the joint X is worse than the solo one (0.288 / 0.228 deg, 3.60 / 2.22 mm), X coverage 38 % / 42 %, pairs
0 %. Without the jitter (``--seeds 5``, 15 cells) the test stands in every cell and the figures are those
of one pose per view, to the digit.

Usage: python benchmarks/bench_cell.py [--seeds 10] [--first-seed 0] [--sizes 2 3 4] [--views 40] [--jobs 1]
[--out FILE] [--summary FILE ...] [--view-jitter DEG MM] [--rendered DIR] [--rounds 3] [--before CHECKOUT]
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
from scipy.stats import binomtest, chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_refine import closed_forms, refine_views  # noqa: E402  (one copy of the pipeline's seeding)
from fanout import ordered_map  # noqa: E402

from handeye.errors import ConfigError  # noqa: E402
from handeye.frames import inv_T, se3_adjoint, tangent_difference  # noqa: E402
from handeye.refine import RefineOptions, refine  # noqa: E402
from handeye.refine.cell import CellCameraInput, CellState, refine_cell  # noqa: E402
from handeye.refine.problem import cell_information  # noqa: E402
from handeye.sim.cell import make_cell  # noqa: E402
from handeye.sim.robot_error import DH_ANGLE_ERROR_DEG, DH_LENGTH_ERROR_MM  # noqa: E402

ARM = "ur5e"
ROOT = Path(__file__).resolve().parent.parent
NOISE_PX = 0.3
CHI2_95 = chi2.ppf(0.95, 6)
SIZE_SEED_STRIDE = 1000  # cell k of size n is the simulator's seed 1000 (n - 2) + k


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


def sim_dh_second_moment(length_error_mm=DH_LENGTH_ERROR_MM, angle_error_deg=DH_ANGLE_ERROR_DEG) -> np.ndarray:
    """(2,) E[e^2] of one DH length (m^2) and angle (rad^2) error as the simulator draws them.

    :func:`handeye.sim.robot_error.sample_true_arm`: a magnitude uniform in [lo, hi] with a random sign, so
    E[e^2] = (hi^3 - lo^3) / (3 (hi - lo)) (the RMS of 0.1-0.5 mm is 0.321 mm, of 0.01-0.05 deg 0.0321 deg).
    """

    def m2(lo: float, hi: float) -> float:
        return (hi**3 - lo**3) / (3 * (hi - lo)) if hi > lo else lo**2

    return np.array([m2(*length_error_mm) * 1e-6, m2(*np.radians(angle_error_deg))])


def crb(cell, options) -> dict:
    """Bounds of the joint problem at the truth (the true poses, intrinsics and noise levels, the true arm's joints).

    Per camera (``cameras``) and per pair of fixed cameras (``pairs``), three (6,6) matrices: ``sim`` the bound
    of the problem as simulated, its DH prior the simulator's own spread of DH errors
    (:func:`sim_dh_second_moment`); ``stated`` the same with the arm's stated DH prior (what the estimator
    assumes); ``expected`` the mean squared error the estimator with the stated prior has on this cell's
    arm (the noise part ``S - S Pi S`` plus the prior's pull ``S Pi d d^T Pi S``, ``Pi`` the prior's
    information, ``d`` the true DH errors): the efficiency check without the spread of the DH draw.
    """
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
    x_at, at = {}, 0  # cell_ordering: each camera's X then its free intrinsics, the boards, the DH offsets
    for cam in st.cams:
        x_at[cam.name] = at
        at += 6 + cam.free.size
    core = at + 6 * len(st.T_boards) + st.m_dh
    S = np.linalg.inv(H)
    dh = slice(core - st.m_dh, core)
    Pi = np.zeros_like(H)  # the stated DH prior's information, in the full order
    Pi[dh, dh] = np.linalg.inv(st.dh_prior_cov)
    H_sim = H - Pi
    H_sim[dh, dh] += np.diag(1.0 / np.tile(sim_dh_second_moment()[[0, 1, 0, 1]], st.m_dh // 4))
    d = np.zeros(len(H))
    d[dh] = (np.asarray(first.robot_model["dh_true"]) - np.asarray(first.robot_model["dh_nominal"])).ravel()
    SPi = S @ Pi
    bias = SPi @ d
    full = {"stated": S, "sim": np.linalg.inv(H_sim), "expected": S - SPi @ S + np.outer(bias, bias)}
    out: dict = {"cameras": {}, "pairs": {}}
    for name, at in x_at.items():
        out["cameras"][name] = {k: M[at : at + 6, at : at + 6] for k, M in full.items()}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if cell.session(a).mode != "eye_to_hand" or cell.session(b).mode != "eye_to_hand":
                continue
            T_ab = inv_T(cell.session(a).T_x_true) @ cell.session(b).T_x_true
            J = np.zeros((6, len(H)))
            J[:, x_at[a] : x_at[a] + 6] = -se3_adjoint(inv_T(T_ab))
            J[:, x_at[b] : x_at[b] + 6] = np.eye(6)
            out["pairs"][(a, b)] = {k: J @ M @ J.T for k, M in full.items()}
    return out


def _traces(M: np.ndarray) -> list[float]:
    """(rotation, translation) traces of a (6,6) covariance: the expected squared error of each part."""
    return [float(np.trace(M[:3, :3])), float(np.trace(M[3:, 3:]))]


def cell_seed(n_cameras: int, seed: int) -> int:
    """The simulator's seed of cell ``seed`` of a size: sizes never share one (make_cell draws the arm, the wrist
    camera and the fixed cameras from it, so one seed's 2- and 3-camera cells would hold the same two cameras)."""
    return SIZE_SEED_STRIDE * (n_cameras - 2) + seed


def run_one(n_cameras: int, seed: int, n_views: int, view_jitter: tuple = (0.0, 0.0)) -> dict:
    """One cell: every camera alone, then jointly; errors, Mahalanobis distances and the bounds' traces."""
    try:
        cell = make_cell(
            n_cameras,
            n_views=n_views,
            seed=cell_seed(n_cameras, seed),
            noise_px=NOISE_PX,
            arm=ARM,
            view_jitter=tuple(view_jitter),
        )
    except ConfigError as e:  # no place for the fixed cameras: the cell is skipped, and counted
        return {"n": n_cameras, "seed": seed, "cell_seed": cell_seed(n_cameras, seed), "skipped": str(e)}
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
                "bound": {k: _traces(M) for k, M in bound["cameras"][name].items()},
            }
        )
    pairs = []
    for a, b in cr.pairs():
        T, C = cr.pair(a, b)
        T_true = inv_T(cell.session(a).T_x_true) @ cell.session(b).T_x_true
        xi = tangent_difference(T, T_true)
        pairs.append(
            {
                "pair": [a, b],
                "xi": xi.tolist(),
                "m2": float(xi @ np.linalg.solve(C, xi)),
                "bound": {k: _traces(M) for k, M in bound["pairs"][(a, b)].items()},
            }
        )
    own = cr.view_poses
    return {
        "n": n_cameras,
        "seed": seed,
        "cell_seed": cell_seed(n_cameras, seed),
        "rows": rows,
        "pairs": pairs,
        "solo_s": t1 - t0,
        "joint_s": t2 - t1,
        "sigma_px": cr.sigma_px,
        "robot_model": {k: v for k, v in cr.robot_model.items() if isinstance(v, (int, float, str, bool))},
        "robot_excluded": sorted(cr.robot_excluded),
        "camera_removed": {k: sorted(v) for k, v in cr.camera_removed.items()},
        "own_poses": [own["sigma_rot_deg"], own["sigma_trans_mm"]] if own.get("estimated") else None,
    }


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else float("nan")


def _binomial(k: int, n: int) -> str:
    """``k / n`` as a percentage with its exact (Clopper-Pearson) 95 % interval."""
    if n == 0:
        return "-"
    ci = binomtest(k, n).proportion_ci(0.95)
    return f"{100 * k / n:.1f} % [{100 * ci.low:.0f}, {100 * ci.high:.0f}] of {n}"


def _ratio(cells: list[tuple[np.ndarray, np.ndarray]], *, draws: int = 2000) -> str:
    """RMS error over sqrt(mean bound) (``sqrt(sum e^2 / sum b)``) with its 95 % interval over the cells.

    ``cells``: per cell (squared errors, bound traces) of its cameras or pairs. The interval is the percentile
    bootstrap resampling whole cells (a cell's cameras share the arm's error, so they are not independent).
    """
    e = np.array([float(np.sum(a)) for a, _b in cells])
    b = np.array([float(np.sum(bb)) for _a, bb in cells])
    if not len(e) or b.sum() <= 0:
        return "-"
    pick = np.random.default_rng(0).integers(0, len(e), size=(draws, len(e)))
    boot = np.sqrt(e[pick].sum(axis=1) / b[pick].sum(axis=1))
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return f"{np.sqrt(e.sum() / b.sum()):.2f} [{lo:.2f}, {hi:.2f}]"


def _parts(items: list[dict], key: str, bound: str, part: int) -> tuple[np.ndarray, np.ndarray]:
    """(squared errors, bound traces) of one part (0 rotation, 1 translation) of cameras' or pairs' errors."""
    sl = slice(0, 3) if part == 0 else slice(3, 6)
    return (
        np.array([np.sum(np.square(np.asarray(it[key])[sl])) for it in items]),
        np.array([it["bound"][bound][part] for it in items]),
    )


def ratio(cells: list[dict], what: str, key: str, bound: str, part: int) -> str:
    """:func:`_ratio` of the cameras (``what`` "rows") or pairs ("pairs") of ``cells`` against one bound."""
    return _ratio([_parts(r[what], key, bound, part) for r in cells if r[what]])


def summary(results: list[dict]) -> str:
    """The printed tables: per cell size and over all cells."""
    skipped = [r for r in results if "skipped" in r]
    if skipped:
        print(f"{len(skipped)} cells skipped: {[(r['n'], r['cell_seed']) for r in skipped]}", file=sys.stderr)
    results = [r for r in results if "skipped" not in r]
    sizes: list = sorted({r["n"] for r in results}) + ["all"]
    main = [
        "| cameras | cells | X error joint (deg, mm) | X error solo (deg, mm) | joint / CRB rot | joint / CRB trans | "
        "coverage X 95 % | coverage T_a_b 95 % | solo s / joint s per cell |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    per_cam = [
        "| cameras | camera | mode | n | X error joint (deg, mm) | X error solo (deg, mm) | "
        "joint closer (rot, trans) |",
        "|---|---|---|---|---|---|---|",
    ]
    diag = [
        "| cameras | X / stated-prior CRB (rot, trans) | X / expected on the cell's arm (rot, trans) | "
        "T_a_b / its CRB (rot, trans) | T_a_b / expected on the cell's arm (rot, trans) | mean m2 X, T_a_b (6) |",
        "|---|---|---|---|---|---|",
    ]
    rot = lambda x: np.degrees(np.linalg.norm(np.asarray(x)[:, :3], axis=1))  # noqa: E731
    tr = lambda x: 1e3 * np.linalg.norm(np.asarray(x)[:, 3:], axis=1)  # noqa: E731
    for n in sizes:
        rs = [r for r in results if n == "all" or r["n"] == n]
        rows = [row for r in rs for row in r["rows"]]
        pairs = [p for r in rs for p in r["pairs"]]
        j = np.array([row["joint"] for row in rows])
        s = np.array([row["solo"] for row in rows])

        cam_ratio = [ratio(rs, "rows", "joint", "sim", p) for p in (0, 1)]
        k_x = sum(row["m2_joint"] <= CHI2_95 for row in rows)
        k_p = sum(p["m2"] <= CHI2_95 for p in pairs)
        main.append(
            f"| {n} | {len(rs)} | {_rms(rot(j)):.4f}, {_rms(tr(j)):.3f} | {_rms(rot(s)):.4f}, {_rms(tr(s)):.3f} | "
            f"{cam_ratio[0]} | {cam_ratio[1]} | {_binomial(k_x, len(rows))} | {_binomial(k_p, len(pairs))} | "
            f"{np.mean([r['solo_s'] for r in rs]):.1f} / {np.mean([r['joint_s'] for r in rs]):.1f} |"
        )
        stated = ", ".join(ratio(rs, "rows", "joint", "stated", p) for p in (0, 1))
        expected = ", ".join(ratio(rs, "rows", "joint", "expected", p) for p in (0, 1))
        pair_ratio = ", ".join(ratio(rs, "pairs", "xi", "sim", p) for p in (0, 1)) if pairs else "-"
        pair_expected = ", ".join(ratio(rs, "pairs", "xi", "expected", p) for p in (0, 1)) if pairs else "-"
        m2p = f"{np.mean([p['m2'] for p in pairs]):.2f}" if pairs else "-"
        m2x = f"{np.mean([row['m2_joint'] for row in rows]):.2f}"
        diag.append(f"| {n} | {stated} | {expected} | {pair_ratio} | {pair_expected} | {m2x}, {m2p} |")
        if n == "all":
            continue
        for name in dict.fromkeys(row["camera"] for row in rows):
            sel = [row for row in rows if row["camera"] == name]
            jj, ss = np.array([x["joint"] for x in sel]), np.array([x["solo"] for x in sel])
            closer = [
                sum(np.linalg.norm(x["joint"][sl]) <= np.linalg.norm(x["solo"][sl]) for x in sel)
                for sl in (slice(0, 3), slice(3, 6))
            ]
            per_cam.append(
                f"| {n} | {name} | {sel[0]['mode']} | {len(sel)} | {_rms(rot(jj)):.4f}, {_rms(tr(jj)):.3f} | "
                f"{_rms(rot(ss)):.4f}, {_rms(tr(ss)):.3f} | {closer[0]}, {closer[1]} of {len(sel)} |"
            )
    own = np.array([r["own_poses"] for r in results if r.get("own_poses")]).reshape(-1, 2)
    line = f"\nEach camera's own pose of a shared view estimated in {len(own)} of {len(results)} cells"
    if len(own):
        line += f" (sigma per axis, median: {np.median(own[:, 0]):.3f} deg, {np.median(own[:, 1]):.3f} mm)"
    return "\n".join(main + [""] + per_cam + [""] + diag + [line])


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
    ap.add_argument("--first-seed", type=int, default=0)
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
    ap.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="append each cell's record to FILE (JSON lines; its cells are not rerun)",
    )
    ap.add_argument("--summary", type=Path, nargs="+", metavar="FILE", help="only print the tables of saved records")
    ap.add_argument("--rendered", type=Path, metavar="DIR", help="also time calibrate on a rendered cell in DIR")
    ap.add_argument("--rounds", type=int, default=3, help="with --rendered: interleaved rounds of the two commands")
    ap.add_argument(
        "--before",
        type=Path,
        metavar="CHECKOUT",
        help="with --rendered: also time a checkout of the code before a change",
    )
    args = ap.parse_args()
    if args.summary:
        print(summary([json.loads(line) for f in args.summary for line in f.read_text().splitlines() if line.strip()]))
        return
    if args.rendered is not None:
        print(rendered_timing(max(args.sizes), args.views, args.rendered, args.rounds, args.before))
    # seed by seed through the sizes, so that a run cut short has every size; cells already in --out are kept
    results = (
        [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
        if args.out and args.out.exists()
        else []
    )
    done = {
        (r["n"], r["seed"])
        for r in results
        if r["n"] in args.sizes
        and r["seed"] in range(args.first_seed, args.first_seed + args.seeds)
        and r.get("cell_seed", r["seed"]) == cell_seed(r["n"], r["seed"])
    }
    results = [r for r in results if (r["n"], r["seed"]) in done]
    jobs = [
        (n, seed)
        for seed in range(args.first_seed, args.first_seed + args.seeds)
        for n in args.sizes
        if (n, seed) not in done
    ]
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
        if args.out is not None:
            with args.out.open("a") as f:
                f.write(json.dumps(r) + "\n")
        if "skipped" in r:
            print(f"{n} cameras seed {seed}: skipped, {r['skipped']}", file=sys.stderr)
            continue
        print(
            f"{n} cameras seed {seed}: m2 joint {[round(x['m2_joint'], 1) for x in r['rows']]}, "
            f"pairs {[round(p['m2'], 1) for p in r['pairs']]}, solo {r['solo_s']:.1f} s, joint {r['joint_s']:.1f} s",
            file=sys.stderr,
        )
    if results:  # (--seeds 0: the rendered timing alone)
        print(summary(results))


if __name__ == "__main__":
    main()
