"""Benchmark of the whole pipeline on rendered synthetic sessions: accuracy, honesty of the reported
uncertainty, outlier flags and failures.

Each session is written by :func:`handeye.synth.write_vendor_session` (vendor layout: N.jpg, poses.txt,
config.yaml, ground_truth.json) with settings drawn from the session index (both modes, 12-25 views,
image noise 0-4 grey levels, blur 0-1 px, robot noise none / 0.2 mm 0.05 deg / 0.5 mm 0.1 deg, one
view whose board is not visible, sometimes 1-2 wrong robot poses; default 1280x720 intrinsics and every
fourth session 640x480), then loaded and calibrated exactly as ``handeye calibrate`` does it
(:func:`handeye.session.load_session`, :func:`handeye.calibrate.run_calibration` with
``CalibrateOptions()``).

Per session and in summary (stdout): rotation / translation error of the hand-eye transform against
the truth, the reported 1-sigma (RMS over the axes), the normalised error ``d^2 = xi^T C^-1 xi`` with
``xi = Log(inv(T_est) · T_true)`` (right perturbation in the frame of X, rotation first, the
parametrisation of ``RefineResult.cov_x_6x6``) and ``C = cov_x_6x6`` (chi-square with 6 dof when the
reported covariance is honest: median 5.35, 95 % quantile 12.59), the coverage of the reported 95 %
ellipsoid, the same for the verdict covariance (``cov_x_6x6_verdict``, :mod:`handeye.refine.validation`),
the Cramer-Rao bound of the corner-level model at the truth with the pixel sigma that the
detector actually achieved on that session (measured against the true corners), outlier flags against
ground_truth.json, false flags, failures and seconds. Diagnostics of the detector: RMS corner error
against the true projections, and its per-view systematic part (RMS of each view's mean error and the
share of the corner error variance explained by a per-view similarity (shift/scale/rotation) field).

Usage: python benchmarks/bench_rendered.py --sessions 40 [--workers 2] [--first 0] [--keep DIR]
Progress to stderr, figures to stdout.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))

CHI2_95_6 = chi2.ppf(0.95, 6)
CHI2_MED_6 = chi2.ppf(0.5, 6)
ROBOT_NOISES = ((0.0, 0.0), (0.2, 0.05), (0.5, 0.1))


def session_config(k: int) -> dict:
    """Settings of session k (deterministic in k)."""
    rng = np.random.default_rng(10_000 + k)
    n_views = int(rng.integers(12, 26))
    cfg = dict(
        mode=("eye_in_hand", "eye_to_hand")[k % 2],
        n_views=n_views,
        seed=1000 + k,
        image_noise=float(np.round(rng.uniform(0.0, 4.0), 2)),
        blur_sigma_px=float(np.round(rng.uniform(0.0, 1.0), 2)),
        robot_noise=ROBOT_NOISES[(k // 2) % 3],
        hidden_views=(str(int(rng.integers(1, n_views + 1))),),
        small=(k % 4 == 3),
    )
    n_out = int(rng.choice([0, 0, 1, 2]))
    cfg["outlier_views"] = n_out
    return cfg


def _xi_error(T_est, T_true):
    """xi with T_true = T_est · Exp(xi) (GTSAM Pose3 tangent: rotation, translation; frame of X)."""
    from handeye.frames import tangent_difference

    return tangent_difference(T_est, T_true)


def _corner_errors(run, truth, target, intrinsics_true):
    """Detected minus true corner positions per used view: {vid: (N,2)}."""
    from handeye.camera import pixels_from_board_points

    obj = target.object_points()
    out = {}
    for vid, d in run.detections.items():
        T = np.asarray(truth["views"][vid]["T_cam_board_true"])
        uv = pixels_from_board_points(T, obj[d.corner_ids], intrinsics_true)
        out[vid] = np.asarray(d.image_points) - uv
    return out


def _camera_pose_errors(run, truth, target, intrinsics_true, mode):
    """Per used view, the robot pose its detected corners alone imply (PnP under the true intrinsics,
    through the true T_x and board) against the true robot pose: (rot_deg, trans_mm) of the right-tangent
    difference in the end frame. This is the detector's own contribution to the robot-pose test."""
    from handeye.frames import tangent_difference
    from handeye.initial import solve_pnp
    from handeye.mounting import mounting

    mount = mounting(mode)
    T_x, T_b = np.asarray(truth[mount.x_name]), np.asarray(truth[mount.board_name])
    obj = target.object_points()
    out = []
    for vid, d in run.detections.items():
        C, _ = solve_pnp(obj[d.corner_ids], np.asarray(d.image_points), intrinsics_true)
        implied = mount.T_base_end_from_M(T_x @ C @ np.linalg.inv(T_b))
        xi = tangent_difference(np.asarray(truth["views"][vid]["T_base_end_true"]), implied)
        out.append((float(np.degrees(np.linalg.norm(xi[:3]))), float(1000 * np.linalg.norm(xi[3:]))))
    return np.array(out).reshape(-1, 2)


def _similarity_share(errs: dict, pts: dict) -> float:
    """Share of the corner error variance explained per view by a 2-D similarity (4 dof) field."""
    tot, expl = 0.0, 0.0
    for vid, e in errs.items():
        p = pts[vid] - pts[vid].mean(axis=0)
        x, y = p[:, 0], p[:, 1]
        one, zero = np.ones_like(x), np.zeros_like(x)
        A = np.concatenate([np.stack([one, zero, x, -y], 1), np.stack([zero, one, y, x], 1)])
        b = np.concatenate([e[:, 0], e[:, 1]])
        coef, *_ = np.linalg.lstsq(A, b, rcond=None)
        tot += float(b @ b)
        expl += float(np.sum((A @ coef) ** 2))
    return expl / tot if tot > 0 else float("nan")


def run_one(k: int, keep: str | None = None) -> dict:
    try:
        return _run_one(k, keep)
    except Exception as err:  # a crash of one session is a result, not the end of the benchmark
        import traceback

        return dict(
            k=k,
            cfg=session_config(k),
            secs=float("nan"),
            render_secs=float("nan"),
            status="crashed",
            reason=f"{type(err).__name__}: {err} | {traceback.format_exc().splitlines()[-3].strip()}",
            true_out=set(),
            hidden=set(),
        )


def _run_one(k: int, keep: str | None = None, cfg: dict | None = None) -> dict:
    from bench_refine import crb_x

    from handeye.pipeline import CalibrateOptions, run_calibration
    from handeye.session import load_session
    from handeye.sim.corners import make_corner_session
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session

    cfg = session_config(k) if cfg is None else cfg
    intr = default_intrinsics(640, 480) if cfg["small"] else None
    tmp = Path(keep) / f"s{k:03d}" if keep else Path(tempfile.mkdtemp(prefix="bench_rendered_"))
    t0 = time.perf_counter()
    try:
        write_vendor_session(
            tmp,
            mode=cfg["mode"],
            n_views=cfg["n_views"],
            seed=cfg["seed"],
            image_noise=cfg["image_noise"],
            blur_sigma_px=cfg["blur_sigma_px"],
            robot_noise=cfg["robot_noise"],
            hidden_views=cfg["hidden_views"],
            outlier_views=cfg["outlier_views"],
            intrinsics=intr,
            overwrite=True,
            workers=1,
        )
        t_render = time.perf_counter() - t0
        truth = json.loads((tmp / "ground_truth.json").read_text())
        t1 = time.perf_counter()
        session = load_session(tmp)
        run = run_calibration(session, CalibrateOptions(workers=1))
        secs = time.perf_counter() - t1
    finally:
        if not keep:
            shutil.rmtree(tmp, ignore_errors=True)
    row = dict(
        k=k,
        cfg=cfg,
        secs=secs,
        render_secs=t_render,
        status=run.status,
        reason=run.failure_reason,
        true_out=set(truth["outlier_view_ids"]),
        hidden=set(truth["hidden_view_ids"]),
    )
    if run.status != "ok" or run.refined is None:
        return row
    r = run.refined
    mm_x = r.x_name
    T_true = np.asarray(truth[mm_x])
    xi = _xi_error(r.T_x, T_true)
    cov = r.cov_x_6x6
    d2 = float(xi @ np.linalg.solve(cov, xi))
    d2_rot = float(xi[:3] @ np.linalg.solve(cov[:3, :3], xi[:3]))
    d2_trans = float(xi[3:] @ np.linalg.solve(cov[3:, 3:], xi[3:]))
    val = getattr(run, "validation", None)  # the verdict covariance calibrate reports (handeye.refine.validation)
    val_ok = val is not None and val.status == "ok"
    d2_verdict = float(xi @ np.linalg.solve(val.x.cov_verdict, xi)) if val_ok else d2
    flagged = {o.view_id for o in r.outliers if o.kind in ("robot_pose", "reprojection", "too_few_corners")}
    corner_flags = sum(len(o.corner_ids) for o in r.outliers if o.kind == "corners")
    # detector accuracy against the true projections
    intr_true = intr if intr is not None else default_intrinsics()  # what write_vendor_session rendered with
    errs = _corner_errors(run, truth, session.target, intr_true)
    pts = {v: np.asarray(run.detections[v].image_points) for v in errs}
    allerr = np.concatenate(list(errs.values()))
    det_sigma = float(np.sqrt(np.mean(allerr**2)))  # per coordinate
    corner_abs = np.linalg.norm(allerr, axis=1)
    pose_err = _camera_pose_errors(run, truth, session.target, intr_true, cfg["mode"])
    view_bias = np.array([np.linalg.norm(e.mean(axis=0)) for e in errs.values()])
    cs = make_corner_session(
        mode=cfg["mode"],
        n_views=cfg["n_views"],
        seed=cfg["seed"],
        noise_px=0.0,
        robot_noise=cfg["robot_noise"],
        hidden_views=cfg["hidden_views"],
        outlier_views=cfg["outlier_views"],
        intrinsics=intr_true,
    )
    keep_idx = [i for i, v in enumerate(cs.view_ids) if v not in cs.hidden_view_ids]
    cs = SimpleNamespace(
        mode=cs.mode,
        target=cs.target,
        intrinsics=cs.intrinsics,
        T_x_true=cs.T_x_true,
        T_board_true=cs.T_board_true,
        n_views=len(keep_idx),
        view_ids=[cs.view_ids[i] for i in keep_idx],
        corner_ids=[cs.corner_ids[i] for i in keep_idx],
        T_base_end_true=cs.T_base_end_true[keep_idx],
        outlier_view_ids=cs.outlier_view_ids,
    )
    flagged_robot = {o.view_id for o in r.outliers if o.kind == "robot_pose"}
    crb = crb_x(
        cs,
        sigma_px=det_sigma,
        robot_sigma_mm=cfg["robot_noise"][0],
        robot_sigma_deg=cfg["robot_noise"][1],
        exclude=tuple(flagged_robot & set(cs.outlier_view_ids)) if cfg["robot_noise"][0] > 0 else (),
    )
    row.update(
        rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))),
        trans_mm=float(1000 * np.linalg.norm((T_true - r.T_x)[:3, 3])),
        d2=d2,
        d2_rot=d2_rot,
        d2_trans=d2_trans,
        covered=d2 <= CHI2_95_6,
        d2_verdict=d2_verdict,
        finding=bool(val_ok and val.x.finding),
        sig_rot_deg=float(np.sqrt(np.sum(r.sigma_rot_deg**2))),
        sig_trans_mm=float(1000 * np.sqrt(np.trace(cov[3:, 3:]))),
        crb_rot_deg=float(np.degrees(np.sqrt(np.trace(crb[:3, :3])))),
        crb_trans_mm=float(1000 * np.sqrt(np.trace(crb[3:, 3:]))),
        flagged=flagged,
        corner_flags=corner_flags,
        sigma_px=r.sigma_px,
        det_sigma_px=det_sigma,
        view_bias_px=float(np.sqrt(np.mean(view_bias**2))),
        sim_share=_similarity_share(errs, pts),
        corner_abs_px=corner_abs,
        camera_pose_err=pose_err,
        robot_mm=r.robot_sigma_mm,
        robot_deg=r.robot_sigma_deg,
        hidden_detected=sorted(set(cfg["hidden_views"]) & set(run.detections)),
    )
    return row


def _line(r: dict) -> str:
    c = r["cfg"]
    head = (
        f"{r['k']:3d} {c['mode'][:6]:<6} {c['n_views']:2d}v {'640' if c['small'] else '1280'} "
        f"n{c['image_noise']:.1f} b{c['blur_sigma_px']:.2f} rob{c['robot_noise'][0]:.1f} out{c['outlier_views']}"
    )
    if "d2" not in r:
        return f"{head} FAILED {r['status']}: {r['reason']}"
    false = sorted(r["flagged"] - r["true_out"], key=int)
    missed = sorted(r["true_out"] - r["flagged"], key=int)
    return (
        f"{head} | err {r['rot_deg']:.4f} deg {r['trans_mm']:.3f} mm | 1sig {r['sig_rot_deg']:.4f} deg "
        f"{r['sig_trans_mm']:.3f} mm | CRB {r['crb_rot_deg']:.4f} {r['crb_trans_mm']:.3f} | d2 {r['d2']:6.2f} "
        f"(rot {r['d2_rot']:.1f} tr {r['d2_trans']:.1f}) | sig_px {r['sigma_px']:.3f} det {r['det_sigma_px']:.3f} "
        f"bias {r['view_bias_px']:.3f} sim {r['sim_share']:.2f} | false {false} missed {missed} "
        f"corners {r['corner_flags']} | {r['secs']:.1f} s"
    )


def summarize(rows: list, label: str = "all") -> None:
    ok = [r for r in rows if "d2" in r]
    fail = [r for r in rows if "d2" not in r]
    print(f"== {label}: {len(rows)} sessions, {len(fail)} failed")
    if not ok:
        return
    rms = lambda key: float(np.sqrt(np.mean([r[key] ** 2 for r in ok])))  # noqa: E731
    d2 = np.array([r["d2"] for r in ok])
    print(
        f"  RMS error      {rms('rot_deg'):.4f} deg {rms('trans_mm'):.4f} mm | reported 1-sigma (RMS) "
        f"{rms('sig_rot_deg'):.4f} deg {rms('sig_trans_mm'):.4f} mm | CRB at the detector's sigma "
        f"{rms('crb_rot_deg'):.4f} deg {rms('crb_trans_mm'):.4f} mm (ratio {rms('rot_deg') / rms('crb_rot_deg'):.2f}"
        f" {rms('trans_mm') / rms('crb_trans_mm'):.2f})"
    )
    print(
        f"  normalised     d2 median {np.median(d2):.2f} (chi2(6) {CHI2_MED_6:.2f}), mean {d2.mean():.2f} (6), "
        f"coverage of the 95 % ellipsoid {np.mean(d2 <= CHI2_95_6) * 100:.0f} % "
        f"| rot-only d2 median {np.median([r['d2_rot'] for r in ok]):.2f} (chi2(3) {chi2.ppf(0.5, 3):.2f}), "
        f"trans-only {np.median([r['d2_trans'] for r in ok]):.2f}"
    )
    d2v = np.array([r["d2_verdict"] for r in ok])
    print(
        f"  verdict        d2 median {np.median(d2v):.2f}, coverage of the 95 % ellipsoid "
        f"{np.mean(d2v <= CHI2_95_6) * 100:.0f} % (the validation found the model's covariance too small in "
        f"{sum(r['finding'] for r in ok)} of {len(ok)} sessions)"
    )
    print(
        f"  detector       corner error {np.mean([r['det_sigma_px'] for r in ok]):.3f} px/coord (estimated sigma_px "
        f"{np.mean([r['sigma_px'] for r in ok]):.3f}), per-view mean error "
        f"{np.mean([r['view_bias_px'] for r in ok]):.3f}"
        f" px, similarity share {np.mean([r['sim_share'] for r in ok]):.2f}"
    )
    ca = np.concatenate([r["corner_abs_px"] for r in ok])
    pe = np.concatenate([r["camera_pose_err"] for r in ok])
    print(
        f"  detector       |corner error| over {ca.size} corners: median {np.median(ca):.3f} px, 99.9 % "
        f"{np.quantile(ca, 0.999):.3f} px, max {ca.max():.3f} px | robot pose implied by one view's corners (true "
        f"intrinsics, T_x, board) vs the true pose over {len(pe)} views: median {np.median(pe[:, 0]):.4f} deg "
        f"{np.median(pe[:, 1]):.3f} mm, 99 % {np.quantile(pe[:, 0], 0.99):.4f} deg "
        f"{np.quantile(pe[:, 1], 0.99):.3f} mm, "
        f"max {pe[:, 0].max():.4f} deg {pe[:, 1].max():.3f} mm"
    )
    with_out = [r for r in ok if r["true_out"]]
    n_true = sum(len(r["true_out"]) for r in ok)
    n_hit = sum(len(r["true_out"] & r["flagged"]) for r in ok)
    false = sum(len(r["flagged"] - r["true_out"]) for r in ok)
    print(
        f"  outliers       {n_hit}/{n_true} wrong robot poses flagged ({len(with_out)} sessions with some); "
        f"false view flags {false} in {len(ok)} sessions ({sum(bool(r['flagged'] - r['true_out']) for r in ok)} "
        f"sessions); corner flags {sum(r['corner_flags'] for r in ok)}"
    )
    print(
        f"  time           calibrate {np.median([r['secs'] for r in rows]):.1f} s median, "
        f"{max(r['secs'] for r in rows):.1f} s max; render "
        f"{np.median([r['render_secs'] for r in rows]):.1f} s median"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=40)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", default=None, help="write the sessions under this folder and keep them")
    args = ap.parse_args(argv)
    ks = list(range(args.first, args.first + args.sessions))
    print(f"# bench_rendered: sessions {ks[0]}..{ks[-1]}, {args.workers} workers")
    print(f"# command: python {' '.join(sys.argv)}")
    rows = []
    from fanout import ordered_map

    for r in ordered_map(run_one, ks, [args.keep] * len(ks), workers=args.workers):
        rows.append(r)
        print(_line(r), flush=True)
    summarize(rows)
    for mode in ("eye_in_hand", "eye_to_hand"):
        summarize([r for r in rows if r["cfg"]["mode"] == mode], mode)
    for rn in ROBOT_NOISES:
        summarize([r for r in rows if tuple(r["cfg"]["robot_noise"]) == rn], f"robot noise {rn}")
    summarize([r for r in rows if r["cfg"]["small"]], "640x480")
    return 0


if __name__ == "__main__":
    sys.exit(main())
