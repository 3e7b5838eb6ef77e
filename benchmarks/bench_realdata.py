"""Refined results on the real datasets in ../shared/data: the hand-eye transform, its
predicted uncertainty, the estimated pixel and robot noise, outliers, and the agreement with the
references in each SOURCE.md and with OpenCV's closed-form methods, and the time of the whole workflow
(load, calibrate, diagnose, write; no report) per stage. Prints figures; asserts nothing.

    python benchmarks/bench_realdata.py [--data ../shared/data]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from handeye.config import load_preset
from handeye.frames import T_from_rotvec, make_T, pose_error
from handeye.pipeline import CalibrateOptions
from handeye.session.importers import import_ical, import_visp
from handeye.workflow import calibrate_session

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for name, (ref_name, T_ref) in REFS.items():
            src = args.data / name
            if not src.is_dir():
                print(f"{name}: not available ({src})")
                continue
            variants = [("own intrinsics", lambda o: (import_visp(src, o) if name.startswith("visp")
                                                      else import_ical(src, o)))]
            if name.startswith("visp"):
                variants.append(("factory intrinsics (fixed)",
                                 lambda o: import_visp(src, o, use_given_intrinsics=True)))
            for label, imp in variants:
                path = imp(Path(tmp) / f"{name}-{len(label)}")
                t0 = time.perf_counter()
                wr = calibrate_session(path.parent, options=CalibrateOptions.from_config(load_preset("calibration")),
                                       out_dir=Path(tmp) / f"out-{name}-{len(label)}", report=False)
                dt = time.perf_counter() - t0
                run = wr.run
                print(f"\n{name} ({run.session.mode}), {label}: {run.status} {run.failure_reason}  [{dt:.1f} s: "
                      + ", ".join(f"{k} {v:.2f}" for k, v in wr.seconds.items()) + "]")
                if run.status != "ok":
                    continue
                r = run.refined
                rv = np.degrees(Rotation.from_matrix(run.T_x[:3, :3]).as_rotvec())
                print(f"  refined {r.x_name}: t = {np.round(run.T_x[:3, 3] * 1e3, 2)} mm, "
                      f"rotvec = {np.round(rv, 3)} deg")
                print(f"  1-sigma: {np.round(r.sigma_trans_mm, 2)} mm, {np.round(r.sigma_rot_deg, 3)} deg; "
                      f"predicted error {r.predicted_error_mm:.2f} mm at {r.working_distance_m:.2f} m")
                print(f"  noise: pixel {r.sigma_px:.3f} px, robot {r.robot_sigma_mm:.2f} mm / "
                      f"{r.robot_sigma_deg:.3f} deg"
                      f"; views used {len(run.used_ids)}/{len(run.outcomes)}; outliers: "
                      + (", ".join(f"{o.view_id} ({o.kind})" for o in r.outliers) or "none"))
                rd, td = pose_error(run.T_x, T_ref)
                print(f"  vs {ref_name}: {td:.2f} mm, {rd:.3f} deg")
                cf = {m: pose_error(e.T_x, run.T_x) for m, e in run.closed_forms.items() if e.status == "ok"}
                print("  closed forms vs refined: "
                      + ", ".join(f"{m} {t:.1f} mm/{a:.2f} deg" for m, (a, t) in cf.items()))
                ref_cf = {m: pose_error(e.T_x, T_ref) for m, e in run.closed_forms.items() if e.status == "ok"}
                print(f"  closed forms vs {ref_name}: " + ", ".join(f"{m} {t:.1f} mm/{a:.2f} deg"
                                                               for m, (a, t) in ref_cf.items()))


if __name__ == "__main__":
    main()
