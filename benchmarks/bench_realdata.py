"""Do the reported sigmas cover the real scatter? Half-split test on the real datasets in ../shared/data.

Each set with 12 or more usable views (the two ical sets, the two UR3 cameras) is split into disjoint
halves: odd / even views and ``--halvings`` random halvings (seeded). Each half is calibrated as
``handeye calibrate`` does it (:func:`handeye.pipeline.run_calibration` with the shipped preset; the
detections of the full set are reused, nothing else), and the two halves' results are compared:

* ``X``: squared Mahalanobis distance of the right-tangent difference of the halves' hand-eye
  transforms under the SUM of their reported covariances, for the verdict covariance
  (``cov_x_6x6_verdict``, what the result reports) and for the model covariance (``cov_x_6x6``);
  chi-square(6) if the covariances are right: mean 6, 95 % below 12.6;
* ``fx fy cx cy``: the same for the intrinsics (verdict: ``cov_intrinsics_verdict``; model: the
  diagonal ``intrinsics_sigma``, all the model reports); chi-square(4): mean 4, 95 % below 9.49.

Targets: median of the verdict's distances at most 8 and at most 15 % above 12.6. The table prints,
per set, the median and the share above 12.6 (X) / 9.49 (intrinsics) for both covariances.

The 8-view ViSP set is too small to halve: each view is left out in turn, the other seven calibrated,
and the held-out view's board pose predicted through its robot pose (``T_cam_board``) against the one
observed (PnP with the fold's intrinsics), as a squared Mahalanobis distance under the predicted
covariance (the fold's verdict covariance of X propagated, plus the robot-pose noise the fold estimated
and the PnP covariance of the observation; the board transform's own uncertainty is left out, so the
distance is if anything too large): chi-square(6).

``--references`` also prints each set's full result against the reference in its SOURCE.md and the
closed forms (the figures this script printed before the half-split test).

    python benchmarks/bench_realdata.py [--data ../shared/data] [--halvings 10] [--only NAME] [--references]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from handeye.config import load_preset
from handeye.frames import T_from_rotvec, make_T, pose_error, tangent_difference, tangent_jacobian
from handeye.pipeline import CalibrateOptions, run_calibration
from handeye.session import load_session
from handeye.session.importers import import_ical, import_visp

CHI2_95 = {6: 12.592, 4: 9.488}
REFS = {
    # ViSP's documented eMc (SOURCE.md)
    "visp-franka-eye-in-hand": ("ViSP tutorial result", T_from_rotvec(
        [0.001783530, 0.009173748, 1.581782359], [0.0577152, -0.0339249, -0.0422769])),
    # PARK on the staged grayscale images (SOURCE.md)
    "ical-mako-charuco-eye-to-hand": ("PARK in SOURCE.md", make_T(
        Rotation.from_rotvec(np.radians([8.01, 98.53, -146.56])).as_matrix(),
        np.array([-18.30, 1264.28, 289.60]) / 1e3)),
    # TSAI with SOURCE.md's own intrinsics (no ground truth exists for this set)
    "ical-kinect-circlegrid-eye-in-hand": ("TSAI in SOURCE.md", make_T(
        Rotation.from_rotvec(np.radians([1.32, -0.91, -89.86])).as_matrix(), np.array([-86.16, 38.86, 77.24]) / 1e3)),
}
HALF_SETS = ("ical-mako-charuco-eye-to-hand", "ical-kinect-circlegrid-eye-in-hand", "ur3-eyetohand-cam1",
             "ur3-eyetohand-cam2")


def import_ur3(src: Path, out: Path) -> Path:
    """session.yaml for a UR3 camera folder: the derived flange poses (4x4, metres) of
    base_T_flange_fk_derived.txt, the 9x7 / 20 mm chessboard, eye-to-hand, own intrinsics."""
    views = []
    for line in (src / "base_T_flange_fk_derived.txt").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        views.append({"id": parts[0], "image": f"images/{parts[1]}", "pose": [float(x) for x in parts[2:18]]})
    doc = {"handeye_session": 1, "mode": "eye_to_hand",
           "target": {"type": "chessboard", "inner_corners": [9, 7], "square_m": 0.02},
           "pose_format": {"rotation": "matrix", "translation_unit": "m"}, "image_folder": str(src), "views": views}
    out.mkdir(parents=True, exist_ok=True)
    (out / "session.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return out / "session.yaml"


def import_set(name: str, src: Path, out: Path) -> Path:
    if name.startswith("visp"):
        return import_visp(src, out)
    if name.startswith("ical"):
        return import_ical(src, out)
    return import_ur3(src, out)


class DetectionCache:
    """Detect each image once per process: the halves reuse the full set's detections (a stand-in for
    :func:`handeye.pipeline.detect_views`, installed by :meth:`install`)."""

    def __init__(self):
        import handeye.pipeline as pipeline

        self._pipeline = pipeline
        self._detect = pipeline.detect_views
        self._cache: dict = {}

    def __call__(self, items, target, **kw):
        missing = [(v, p) for v, p in items if str(p) not in self._cache]
        if missing:
            found = self._detect(missing, target, **kw)
            self._cache.update({str(p): found[v] for v, p in missing})
        return {v: self._cache[str(p)] for v, p in items}

    def install(self) -> "DetectionCache":
        self._pipeline.detect_views = self
        return self


def calibrate(session, opts):
    run = run_calibration(session, opts)
    return run if run.status == "ok" and run.refined is not None else None


def covariances(run) -> dict:
    """T_x, intrinsics (fx fy cx cy), and their verdict and model covariances."""
    ref, val = run.refined, run.validation
    names = ("fx", "fy", "cx", "cy")
    k = np.array([getattr(ref.intrinsics, n) for n in names])
    ks_model = np.diag([ref.intrinsics_sigma.get(n, np.nan) ** 2 for n in names])
    out = {"T_x": ref.T_x, "k": k, "x_model": np.asarray(ref.cov_x_6x6), "k_model": ks_model,
           "x_verdict": np.asarray(ref.cov_x_6x6), "k_verdict": ks_model, "source": "model"}
    if val is not None and val.status == "ok":
        out["x_verdict"], out["source"] = val.x.cov_verdict, val.x.source
        if val.intrinsics is not None and all(n in val.intrinsics.names for n in names):
            idx = [val.intrinsics.names.index(n) for n in names]
            out["k_verdict"] = val.intrinsics.cov_verdict[np.ix_(idx, idx)]
    return out


def m2(delta, cov) -> float:
    try:
        return float(delta @ np.linalg.solve(cov, delta))
    except np.linalg.LinAlgError:
        return float("nan")


def halves(ids: list, n_random: int, seed: int) -> list:
    """(label, half A, half B): odd / even positions, then random halvings."""
    out = [("odd/even", ids[0::2], ids[1::2])]
    rng = np.random.default_rng(seed)
    for k in range(n_random):
        p = list(rng.permutation(len(ids)))
        a = sorted(p[: len(ids) // 2])
        out.append((f"random {k + 1}", [ids[i] for i in a], [ids[i] for i in sorted(p[len(ids) // 2:])]))
    return out


def half_split(name: str, path: Path, opts, n_random: int) -> dict:
    session = load_session(path.parent)
    full = calibrate(session, opts)
    if full is None:
        return {"name": name, "error": "the full set did not calibrate"}
    ids = [v for v in full.used_ids]
    rows = []
    for label, a, b in halves(ids, n_random, seed=17):
        runs = [calibrate(replace(session, views=tuple(v for v in session.views if v.view_id in set(h))), opts)
                for h in (a, b)]
        if any(r is None for r in runs):
            rows.append({"label": label, "failed": True})
            continue
        c1, c2 = covariances(runs[0]), covariances(runs[1])
        dx = tangent_difference(c1["T_x"], c2["T_x"])
        dk = c1["k"] - c2["k"]
        r, t = pose_error(c1["T_x"], c2["T_x"])
        rows.append({"label": label, "n": (len(runs[0].used_ids), len(runs[1].used_ids)), "deg": r, "mm": t,
                     "x_verdict": m2(dx, c1["x_verdict"] + c2["x_verdict"]),
                     "x_model": m2(dx, c1["x_model"] + c2["x_model"]),
                     "k_verdict": m2(dk, c1["k_verdict"] + c2["k_verdict"]),
                     "k_model": m2(dk, c1["k_model"] + c2["k_model"]),
                     "dk": dk, "sources": (c1["source"], c2["source"])})
        print(f"  {name} {label:10s} halves {rows[-1]['n']}: {t:6.2f} mm {r:5.2f} deg; X d2 verdict "
              f"{rows[-1]['x_verdict']:7.2f} model {rows[-1]['x_model']:8.2f}; fx fy cx cy d2 verdict "
              f"{rows[-1]['k_verdict']:7.2f} model {rows[-1]['k_model']:8.2f}  (dk {np.round(dk, 1)})",
              file=sys.stderr, flush=True)
    return {"name": name, "n_views": len(ids), "rows": rows, "full": full}


def loo_board_poses(name: str, path: Path, opts) -> list:
    """Leave-one-out on a small set: each held-out view's board pose predicted vs observed."""
    from handeye.camera import pixels_from_board_points
    from handeye.initial import solve_pnp
    from handeye.mounting import mounting

    session = load_session(path.parent)
    full = calibrate(session, opts)
    if full is None:
        return []
    mount = mounting(session.mode)
    obj = session.target.object_points()
    out = []
    for v in full.used_ids:
        run = calibrate(replace(session, views=tuple(w for w in session.views if w.view_id != v)), opts)
        if run is None:
            continue
        ref = run.refined
        c = covariances(run)
        det = full.detections[v]
        ids = full.board_poses[v].corner_ids
        T_obs, _ = solve_pnp(obj[ids], det.image_points, ref.intrinsics)
        T_be = session.view(v).T_base_end

        def pred(T_x, T_be=T_be):
            return mount.predict_T_cam_board(T_x, ref.T_board, T_be)

        d = tangent_difference(T_obs, pred(ref.T_x))
        J_x = tangent_jacobian(lambda T: tangent_difference(T_obs, pred(T)), ref.T_x)
        J_r = tangent_jacobian(lambda T: tangent_difference(T_obs, mount.predict_T_cam_board(ref.T_x, ref.T_board, T)),
                               T_be)
        robot = np.diag([np.radians(ref.robot_sigma_deg) ** 2] * 3 + [(ref.robot_sigma_mm / 1e3) ** 2] * 3)
        J_p = tangent_jacobian(lambda T: pixels_from_board_points(T, obj[ids], ref.intrinsics).ravel(), T_obs)
        pnp = np.linalg.inv(J_p.T @ J_p) * ref.sigma_px ** 2  # observed pose: d = Log(T_obs^-1 pred) moves with it
        cov_v = J_x @ c["x_verdict"] @ J_x.T + J_r @ robot @ J_r.T + pnp
        cov_m = J_x @ c["x_model"] @ J_x.T + J_r @ robot @ J_r.T + pnp
        r, t = pose_error(T_obs, pred(ref.T_x))
        out.append({"view": v, "deg": r, "mm": t, "verdict": m2(d, cov_v), "model": m2(d, cov_m)})
    return out


def _stats(x: np.ndarray, limit: float) -> str:
    x = x[np.isfinite(x)]
    if not x.size:
        return "      -      -"
    return f"{np.median(x):7.2f} {100 * np.mean(x > limit):5.0f}%"


def references(name: str, path: Path, opts) -> None:
    """The full set's result against its SOURCE.md reference and the closed forms."""
    if name not in REFS:
        return
    ref_name, T_ref = REFS[name]
    run = run_calibration(load_session(path.parent), opts)
    if run.status != "ok":
        print(f"{name}: {run.failure_reason}")
        return
    r = run.refined
    rd, td = pose_error(run.T_x, T_ref)
    print(f"\n{name}: refined {r.x_name} t = {np.round(run.T_x[:3, 3] * 1e3, 2)} mm; model 1-sigma "
          f"{np.round(r.sigma_trans_mm, 2)} mm, {np.round(r.sigma_rot_deg, 3)} deg; robot noise {r.robot_sigma_mm:.2f} mm"
          f" / {r.robot_sigma_deg:.3f} deg; vs {ref_name}: {td:.2f} mm, {rd:.3f} deg")
    cf = {m: pose_error(e.T_x, run.T_x) for m, e in run.closed_forms.items() if e.status == "ok"}
    print("  closed forms vs refined: " + ", ".join(f"{m} {t:.1f} mm/{a:.2f} deg" for m, (a, t) in cf.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--halvings", type=int, default=10, help="random halvings per set (besides odd/even)")
    ap.add_argument("--only", default=None, help="one set by name")
    ap.add_argument("--references", action="store_true")
    args = ap.parse_args()
    DetectionCache().install()
    opts = CalibrateOptions.from_config(load_preset("calibration"))
    results = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for name in HALF_SETS + ("visp-franka-eye-in-hand",):
            src = args.data / name
            if (args.only and name != args.only) or not src.is_dir():
                continue
            path = import_set(name, src, Path(tmp) / name)
            if args.references:
                references(name, path, opts)
            if name in HALF_SETS:
                results.append(half_split(name, path, opts, args.halvings))
            else:
                loo = loo_board_poses(name, path, opts)
                if loo:
                    v, m = np.array([x["verdict"] for x in loo]), np.array([x["model"] for x in loo])
                    print(f"\n{name}: leave-one-out board pose predicted vs observed ({len(loo)} views), squared "
                          f"Mahalanobis under the predicted covariance (chi2(6): median 5.35, 5 % above 12.6)")
                    for x in loo:
                        print(f"  view {x['view']:>3s}: {x['mm']:6.2f} mm {x['deg']:5.2f} deg  d2 verdict "
                              f"{x['verdict']:7.2f}  model {x['model']:7.2f}")
                    print(f"  median / share above 12.6: verdict {_stats(v, CHI2_95[6])}   model {_stats(m, CHI2_95[6])}")
    print(f"\nHalf-split test ({args.halvings} random halvings + odd/even per set): squared Mahalanobis distance "
          "between the halves' results under the sum of their covariances")
    print(f"{'set':36s} views pairs | X verdict: median >12.6 | X model: median >12.6 | fx fy cx cy verdict: "
          f"median >9.49 | model: median >9.49")
    allv, allm, allkv, allkm = [], [], [], []
    for r in results:
        if "error" in r:
            print(f"{r['name']:36s} {r['error']}")
            continue
        ok = [x for x in r["rows"] if not x.get("failed")]
        xv, xm = np.array([x["x_verdict"] for x in ok]), np.array([x["x_model"] for x in ok])
        kv, km = np.array([x["k_verdict"] for x in ok]), np.array([x["k_model"] for x in ok])
        allv += list(xv)
        allm += list(xm)
        allkv += list(kv)
        allkm += list(km)
        print(f"{r['name']:36s} {r['n_views']:5d} {len(ok):5d} |       {_stats(xv, 12.592)} |     "
              f"{_stats(xm, 12.592)} |               {_stats(kv, 9.488)} |      {_stats(km, 9.488)}")
    if results:
        print(f"{'all':36s} {'':5s} {len(allv):5d} |       {_stats(np.array(allv), 12.592)} |     "
              f"{_stats(np.array(allm), 12.592)} |               {_stats(np.array(allkv), 9.488)} |      "
              f"{_stats(np.array(allkm), 9.488)}")
        print("targets: X verdict median <= 8 and share above 12.6 <= 15 %; the same for fx fy cx cy")
    print(f"[{time.perf_counter() - t0:.0f} s]")


if __name__ == "__main__":
    main()
