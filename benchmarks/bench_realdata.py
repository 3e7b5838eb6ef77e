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
per set, the median and the share above 12.6 (X) / 9.49 (intrinsics) for both covariances, and for
``handeye compare``'s statistic on the two halves' results (X given the intrinsics difference,
:mod:`handeye.recal.compare`).

The 8-view ViSP set is too small to halve: each view is left out in turn, the other seven calibrated,
and the held-out view's board pose predicted through its robot pose (``T_cam_board``) against the one
observed (PnP with the fold's intrinsics), as a squared Mahalanobis distance under the predicted
covariance (the fold's verdict covariance of X propagated, plus the robot-pose noise the fold estimated
and the PnP covariance of the observation; the board transform's own uncertainty is left out, so the
distance is if anything too large): chi-square(6).

The two UR3 cameras run with both robot error models (``--model``): ``iid`` on the derived flange poses
(base_T_flange_fk_derived.txt), ``kinematic`` on the recorded joint angles with the nominal DH table as
the session's ``robot:`` (DH offsets with their prior + encoder noise, :mod:`handeye.refine.robot_model`).
Each model gets its rows in the half-split table and a **cross-camera check**: the two cameras see the
same board on the same flange, so their ``T_end_board`` must agree. Printed: the difference in mm / deg
and its squared Mahalanobis distance under the sum of the two reported covariances of ``T_end_board``
(model: the refinement's marginal ``cov_board_6x6``; verdict: built from the validation's fold refits by
the rule of the verdict covariance of X), chi-square(6) if they are right (95 % below 12.6, 99 % below
16.8). The cameras themselves differ, so their ``T_base_cam`` are only compared with the author's
reference and with each other through ``T_cam1_cam2``; what the two results say about the shared robot
is compared too: the correction each refinement made to every view's flange pose (RMS, difference,
correlation between the cameras) and, for the kinematic model, the two cameras' DH offsets.

``--references`` also prints each set's full result against the reference in its SOURCE.md and the
closed forms (the figures this script printed before the half-split test).

    python benchmarks/bench_realdata.py [--data ../shared/data] [--halvings 10] [--only PREFIX]
                                        [--model iid|kinematic|both] [--references]

``--only ur3`` runs the two UR3 cameras (the cross-camera check needs both).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from handeye.config import load_preset
from handeye.frames import T_from_rotvec, inv_T, make_T, pose_error, tangent_difference, tangent_jacobian
from handeye.kinematics import load_arm
from handeye.pipeline import CalibrateOptions, run_calibration
from handeye.session import load_session
from handeye.session.importers import import_ical, import_visp

CHI2_95 = {6: 12.592, 4: 9.488}
REFS = {
    # ViSP's documented eMc (SOURCE.md)
    "visp-franka-eye-in-hand": (
        "ViSP tutorial result",
        T_from_rotvec([0.001783530, 0.009173748, 1.581782359], [0.0577152, -0.0339249, -0.0422769]),
    ),
    # PARK on the staged grayscale images (SOURCE.md)
    "ical-mako-charuco-eye-to-hand": (
        "PARK in SOURCE.md",
        make_T(
            Rotation.from_rotvec(np.radians([8.01, 98.53, -146.56])).as_matrix(),
            np.array([-18.30, 1264.28, 289.60]) / 1e3,
        ),
    ),
    # TSAI with SOURCE.md's own intrinsics (no ground truth exists for this set)
    "ical-kinect-circlegrid-eye-in-hand": (
        "TSAI in SOURCE.md",
        make_T(
            Rotation.from_rotvec(np.radians([1.32, -0.91, -89.86])).as_matrix(), np.array([-86.16, 38.86, 77.24]) / 1e3
        ),
    ),
}
MODELS = {"iid": (False,), "kinematic": (True,), "both": (False, True)}  # UR3 sets: kinematic robot model or not
HALF_SETS = (
    "ical-mako-charuco-eye-to-hand",
    "ical-kinect-circlegrid-eye-in-hand",
    "ur3-eyetohand-cam1",
    "ur3-eyetohand-cam2",
)


UR3_TABLE = "robot_model_dh_nominal_ur3a.json"  # the nominal standard-DH table (m, rad) of a UR3 folder
UR3_JOINTS = "dataset_ur3a_joint_images_40poses.json"  # the joint angles (deg) per pose_id


def import_ur3(src: Path, out: Path, *, kinematic: bool = False, ids: Optional[Sequence[str]] = None) -> Path:
    """session.yaml for a UR3 camera folder: eye-to-hand, the 9x7 / 20 mm chessboard, own intrinsics, and

    * ``kinematic=False``: the derived flange poses (4x4, metres) of base_T_flange_fk_derived.txt (the iid
      robot model);
    * ``kinematic=True``: each view's joint angles (upstream degrees, wrapped to (-pi, pi] radians), the
      nominal DH table as ``robot:`` (so the refinement uses the kinematic robot error model) and the poses
      computed from the joints through that table (handeye.kinematics.load_arm reads it as it is).

    ``ids``: only these pose ids (all when None)."""
    views = []
    for line in (src / "base_T_flange_fk_derived.txt").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        if ids is None or parts[0] in ids:
            views.append({"id": parts[0], "image": f"images/{parts[1]}", "pose": [float(x) for x in parts[2:18]]})
    doc = {
        "handeye_session": 1,
        "mode": "eye_to_hand",
        "target": {"type": "chessboard", "inner_corners": [9, 7], "square_m": 0.02},
        "pose_format": {"rotation": "matrix", "translation_unit": "m"},
        "image_folder": str(src),
    }
    if kinematic:
        arm = load_arm(src / UR3_TABLE)
        poses = json.loads((src / UR3_JOINTS).read_text())["poses"]
        deg = {str(p["pose_id"]): [p["joint_angles_deg"][f"joint_{k + 1}"] for k in range(arm.n_joints)] for p in poses}
        for v in views:
            q = (np.radians(deg[v["id"]]) + np.pi) % (2 * np.pi) - np.pi
            v["joints"] = [float(x) for x in q]
            v["pose"] = [float(x) for x in arm.T_base_end(q).ravel()]
        doc["robot"] = str(src / UR3_TABLE)
    doc["views"] = views
    out.mkdir(parents=True, exist_ok=True)
    (out / "session.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return out / "session.yaml"


def import_set(name: str, src: Path, out: Path, *, kinematic: bool = False) -> Path:
    if name.startswith("visp"):
        return import_visp(src, out)
    if name.startswith("ical"):
        return import_ical(src, out)
    return import_ur3(src, out, kinematic=kinematic)


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
    out = {
        "T_x": ref.T_x,
        "k": k,
        "x_model": np.asarray(ref.cov_x_6x6),
        "k_model": ks_model,
        "x_verdict": np.asarray(ref.cov_x_6x6),
        "k_verdict": ks_model,
        "source": "model",
    }
    if val is not None and val.status == "ok":
        out["x_verdict"], out["source"] = val.x.cov_verdict, val.x.source
        if val.intrinsics is not None and all(n in val.intrinsics.names for n in names):
            idx = [val.intrinsics.names.index(n) for n in names]
            out["k_verdict"] = val.intrinsics.cov_verdict[np.ix_(idx, idx)]
    return out


def compared(runs, target) -> float:
    """``handeye compare``'s squared Mahalanobis distance between the two runs' results (the test of X given
    the intrinsics difference when both carry the joint covariance, :mod:`handeye.recal.compare`)."""
    from handeye.recal.compare import compare_loaded
    from handeye.recal.loaded import load_result, result_from_refinement

    a, b = (load_result(result_from_refinement(r.refined, target=target, validation=r.validation)) for r in runs)
    return compare_loaded(a, b).mahalanobis2


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
        out.append((f"random {k + 1}", [ids[i] for i in a], [ids[i] for i in sorted(p[len(ids) // 2 :])]))
    return out


def half_split(name: str, path: Path, opts, n_random: int) -> dict:
    session = load_session(path.parent)
    full = calibrate(session, opts)
    if full is None:
        return {"name": name, "error": "the full set did not calibrate"}
    ids = [v for v in full.used_ids]
    rows = []
    for label, a, b in halves(ids, n_random, seed=17):
        runs = [
            calibrate(replace(session, views=tuple(v for v in session.views if v.view_id in set(h))), opts)
            for h in (a, b)
        ]
        if any(r is None for r in runs):
            rows.append({"label": label, "failed": True})
            continue
        c1, c2 = covariances(runs[0]), covariances(runs[1])
        dx = tangent_difference(c1["T_x"], c2["T_x"])
        dk = c1["k"] - c2["k"]
        r, t = pose_error(c1["T_x"], c2["T_x"])
        rows.append(
            {
                "label": label,
                "n": (len(runs[0].used_ids), len(runs[1].used_ids)),
                "deg": r,
                "mm": t,
                "x_verdict": m2(dx, c1["x_verdict"] + c2["x_verdict"]),
                "x_model": m2(dx, c1["x_model"] + c2["x_model"]),
                "k_verdict": m2(dk, c1["k_verdict"] + c2["k_verdict"]),
                "k_model": m2(dk, c1["k_model"] + c2["k_model"]),
                "x_compare": compared(runs, session.target),
                "dk": dk,
                "sources": (c1["source"], c2["source"]),
            }
        )
        print(
            f"  {name} {label:10s} halves {rows[-1]['n']}: {t:6.2f} mm {r:5.2f} deg; X d2 verdict "
            f"{rows[-1]['x_verdict']:7.2f} model {rows[-1]['x_model']:8.2f}; fx fy cx cy d2 verdict "
            f"{rows[-1]['k_verdict']:7.2f} model {rows[-1]['k_model']:8.2f}  (dk {np.round(dk, 1)}); compare's "
            f"d2 {rows[-1]['x_compare']:7.2f}",
            file=sys.stderr,
            flush=True,
        )
    return {"name": name, "n_views": len(ids), "rows": rows, "full": full}


# ------------------------------------------------------------------------------ cross-camera check (UR3)
def board_symmetry_transforms(target) -> list:
    """``T_board_boardturned`` (4,4) of each corner-order symmetry of ``target`` (identity first): the
    rigid motion that takes the object points onto the points whose ids the turned order gives them. Two
    sessions of one board may settle on different turns of a symmetric board; their board frames then
    differ by one of these."""
    obj = target.object_points()
    out = []
    for perm in target.symmetries():
        src, dst = obj, obj[perm]
        cs, cd = src.mean(0), dst.mean(0)
        U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R = Vt.T @ D @ U.T
        out.append(make_T(R, cd - R @ cs))
    return out


def board_covariances(run) -> dict:
    """T_board (T_end_board eye-to-hand) with its model covariance (the refinement's marginal,
    ``cov_board_6x6``) and a verdict covariance built as the verdict of T_x is: the model's, unless the
    validation found the model's covariance of T_x too small on these folds (``val.x.finding``: the same
    refits, the same error sources); then the generalised maximum of the model and the shrunk jackknife
    covariance of the validation's fold refits."""
    from handeye.refine.validation import generalised_max, shrunk_jackknife

    ref, val = run.refined, run.validation
    out = {
        "T": ref.T_board,
        "model": np.asarray(ref.cov_board_6x6),
        "verdict": np.asarray(ref.cov_board_6x6),
        "source": "model",
    }
    ok = [r for r in (val.refits if val is not None else ()) if r.status == "ok"]
    if val is not None and val.status == "ok" and val.x.finding and len(ok) >= 3:
        V, _, _ = shrunk_jackknife(np.stack([tangent_difference(ref.T_board, r.T_board) for r in ok]), out["model"])
        out["verdict"], lam = generalised_max(out["model"], V)
        out["source"] = "model" if np.all(lam <= 1) else "validated" if np.all(lam > 1) else "model+validated"
    return out


def cross_camera(run_a, run_b) -> dict:
    """The board mount (``T_end_board``) of two eye-to-hand runs of one arm and board seen by two cameras:
    the difference in mm / deg and its squared Mahalanobis distance under the sum of the two model and of
    the two verdict covariances (chi-square(6): 95 % below 12.6, 99 % below 16.8), the second board frame
    turned by the board symmetry that brings it closest to the first. The two runs share the robot's real
    pose errors, which the sum of the covariances treats as independent."""
    from handeye.frames import se3_adjoint

    a, b = board_covariances(run_a), board_covariances(run_b)
    best = None
    for S in board_symmetry_transforms(run_a.session.target):
        for S_turn in (S, inv_T(S)):
            T_b = b["T"] @ S_turn
            r, t = pose_error(a["T"], T_b)
            if best is None or t + r < best[0]:
                best = (t + r, S_turn, T_b, r, t)
    _, S_turn, T_b, r, t = best
    Ad = se3_adjoint(inv_T(S_turn))  # T_b Exp(xi) S = T_b S Exp(Ad(S^-1) xi)
    dx = tangent_difference(a["T"], T_b)
    out = {
        "mm": t,
        "deg": r,
        "turned": not np.allclose(S_turn, np.eye(4)),
        "dx": dx,
        "d2_model": m2(dx, a["model"] + Ad @ b["model"] @ Ad.T),
        "d2_verdict": m2(dx, a["verdict"] + Ad @ b["verdict"] @ Ad.T),
        "sources": (a["source"], b["source"]),
        "sigma_mm": [1e3 * np.sqrt(np.diag(c["verdict"])[3:]) for c in (a, b)],
        "t_mm": (1e3 * a["T"][:3, 3], 1e3 * T_b[:3, 3]),
    }
    return out


def robot_agreement(run_a, run_b) -> dict:
    """What the two cameras' results say about the robot they share: the correction each refinement
    made to the reported flange pose of each view seen by both (``u = Log(T_reported^-1 T_refined)``),
    its RMS per camera, the RMS of the difference and the correlation of the two cameras' corrections
    (near 1: both see the same real robot error; near 0: each camera's corrections are its own noise),
    and for the kinematic model the two cameras' DH offsets (mm / deg) with their sigmas."""
    common = [v for v in run_a.used_ids if v in set(run_b.used_ids)]
    u = []
    for run in (run_a, run_b):
        rep = np.stack([run.session.view(v).T_base_end for v in common])
        u.append(tangent_difference(rep, np.stack([run.refined.robot_poses[v] for v in common])))
    ua, ub = u

    def rms(x, sl, scale):
        return float(scale * np.sqrt(np.mean(np.sum(x[:, sl] ** 2, axis=1))))

    def corr(sl):
        x, y = ua[:, sl].ravel(), ub[:, sl].ravel()
        return float(np.corrcoef(x, y)[0, 1]) if x.std() > 0 and y.std() > 0 else float("nan")

    rot, tr = slice(0, 3), slice(3, 6)
    out = {
        "n": len(common),
        "rms_mm": (rms(ua, tr, 1e3), rms(ub, tr, 1e3)),
        "rms_deg": (rms(ua, rot, np.degrees(1)), rms(ub, rot, np.degrees(1))),
        "diff_mm": rms(ua - ub, tr, 1e3),
        "diff_deg": rms(ua - ub, rot, np.degrees(1)),
        "corr_trans": corr(tr),
        "corr_rot": corr(rot),
    }
    rm = [r.refined.robot_model for r in (run_a, run_b)]
    if all("dh_offset" in m for m in rm):
        d = [np.asarray(m["dh_offset"], float) for m in rm]
        s = [np.asarray(m["dh_offset_sigma"], float) for m in rm]
        z = (d[0] - d[1]) / np.sqrt(s[0] ** 2 + s[1] ** 2)
        out["dh"] = {
            "offset": d,
            "sigma": s,
            "z": z,
            "columns": rm[0]["dh_columns"],
            "encoder_sigma_deg": tuple(m["encoder_sigma_deg"] for m in rm),
        }
    return out


def ur3_reference(src: Path) -> dict:
    """The author's base_T_camera of each camera (tf_base_to_camera.json), by camera name."""
    doc = json.loads((src / "tf_base_to_camera.json").read_text())["T_base_to_camera"]
    return {k: np.array(v["T_4x4"], float) for k, v in doc.items()}


def print_cross_camera(label: str, run_a, run_b, src: Path) -> dict:
    """The cross-camera check of the two UR3 cameras for one robot model (printed; returned as a dict)."""
    cc = cross_camera(run_a, run_b)
    ra = robot_agreement(run_a, run_b)
    print(f"\nCross-camera check, {label}: T_end_board from cam1 and from cam2 (the same board on the same flange)")
    print(
        f"  cam1 t = {np.round(cc['t_mm'][0], 2)} mm, cam2 t = {np.round(cc['t_mm'][1], 2)} mm"
        f"{' (cam2 board frame turned by its symmetry)' if cc['turned'] else ''}"
    )
    print(
        f"  verdict 1-sigma t (mm): cam1 {np.round(cc['sigma_mm'][0], 2)}, cam2 {np.round(cc['sigma_mm'][1], 2)}"
        f" (sources {cc['sources'][0]} / {cc['sources'][1]})"
    )
    print(
        f"  difference {cc['mm']:.2f} mm, {cc['deg']:.3f} deg; squared Mahalanobis under the sum of the covariances: "
        f"verdict {cc['d2_verdict']:.2f}, model {cc['d2_model']:.2f} (chi2(6): 95 % below 12.6, 99 % below 16.8)"
    )
    ref = ur3_reference(src)
    T_a, T_b = run_a.T_x, run_b.T_x
    for cam, T in (("cam1", T_a), ("cam2", T_b)):
        r, t = pose_error(T, ref[cam])
        print(f"  {cam} T_base_cam vs the author's base_T_camera: {t:.2f} mm, {r:.3f} deg")
    r, t = pose_error(inv_T(T_a) @ T_b, inv_T(ref["cam1"]) @ ref["cam2"])
    print(f"  T_cam1_cam2 (from the two results) vs the author's: {t:.2f} mm, {r:.3f} deg")
    print(
        f"  robot pose corrections over {ra['n']} common views: RMS cam1 {ra['rms_mm'][0]:.2f} mm / "
        f"{ra['rms_deg'][0]:.3f} deg, cam2 {ra['rms_mm'][1]:.2f} mm / {ra['rms_deg'][1]:.3f} deg; their difference "
        f"{ra['diff_mm']:.2f} mm / {ra['diff_deg']:.3f} deg; correlation cam1-cam2 translation {ra['corr_trans']:.2f}, "
        f"rotation {ra['corr_rot']:.2f}"
    )
    if "dh" in ra:
        dh = ra["dh"]
        print(
            f"  encoder sigma estimated: cam1 {dh['encoder_sigma_deg'][0]:.4f} deg, "
            f"cam2 {dh['encoder_sigma_deg'][1]:.4f} deg;"
            f" DH offsets ({', '.join(dh['columns'])}) cam1 / cam2 (z of the difference):"
        )
        for j in range(dh["offset"][0].shape[0]):
            cells = "  ".join(
                f"{dh['offset'][0][j, c]:+7.3f}/{dh['offset'][1][j, c]:+7.3f} ({dh['z'][j, c]:+5.1f})"
                for c in range(dh["offset"][0].shape[1])
            )
            print(f"    joint {j + 1}: {cells}")
    return {"label": label, **cc, "robot": ra}


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

        def pred(T_x, T_be=T_be, ref=ref):
            return mount.predict_T_cam_board(T_x, ref.T_board, T_be)

        d = tangent_difference(T_obs, pred(ref.T_x))
        J_x = tangent_jacobian(lambda T, T_obs=T_obs, pred=pred: tangent_difference(T_obs, pred(T)), ref.T_x)
        J_r = tangent_jacobian(
            lambda T, T_obs=T_obs, ref=ref: tangent_difference(
                T_obs, mount.predict_T_cam_board(ref.T_x, ref.T_board, T)
            ),
            T_be,
        )
        robot = np.diag([np.radians(ref.robot_sigma_deg) ** 2] * 3 + [(ref.robot_sigma_mm / 1e3) ** 2] * 3)
        J_p = tangent_jacobian(
            lambda T, ids=ids, ref=ref: pixels_from_board_points(T, obj[ids], ref.intrinsics).ravel(), T_obs
        )
        pnp = np.linalg.inv(J_p.T @ J_p) * ref.sigma_px**2  # observed pose: d = Log(T_obs^-1 pred) moves with it
        cov_v = J_x @ c["x_verdict"] @ J_x.T + J_r @ robot @ J_r.T + pnp
        cov_m = J_x @ c["x_model"] @ J_x.T + J_r @ robot @ J_r.T + pnp
        r, t = pose_error(T_obs, pred(ref.T_x))
        out.append({"view": v, "deg": r, "mm": t, "verdict": m2(d, cov_v), "model": m2(d, cov_m)})
    return out


def _row(label: str, rows: list, n_views: Optional[int]) -> str:
    """One line of the half-split table: median and share above the 95 % level, X and fx fy cx cy, verdict
    and model covariances."""
    xv, xm, kv, km, xc = (
        np.array([x[k] for x in rows]) for k in ("x_verdict", "x_model", "k_verdict", "k_model", "x_compare")
    )
    views = f"{n_views:5d}" if n_views is not None else " " * 5
    return (
        f"{label:46s} {views} {len(rows):5d} |       {_stats(xv, CHI2_95[6])} |     {_stats(xm, CHI2_95[6])} |"
        f"               {_stats(kv, CHI2_95[4])} |      {_stats(km, CHI2_95[4])} |     {_stats(xc, CHI2_95[6])}"
    )


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
    print(
        f"\n{name}: refined {r.x_name} t = {np.round(run.T_x[:3, 3] * 1e3, 2)} mm; model 1-sigma "
        f"{np.round(r.sigma_trans_mm, 2)} mm, {np.round(r.sigma_rot_deg, 3)} deg; robot noise {r.robot_sigma_mm:.2f} mm"
        f" / {r.robot_sigma_deg:.3f} deg; vs {ref_name}: {td:.2f} mm, {rd:.3f} deg"
    )
    cf = {m: pose_error(e.T_x, run.T_x) for m, e in run.closed_forms.items() if e.status == "ok"}
    print("  closed forms vs refined: " + ", ".join(f"{m} {t:.1f} mm/{a:.2f} deg" for m, (a, t) in cf.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--halvings", type=int, default=10, help="random halvings per set (besides odd/even)")
    ap.add_argument("--only", default=None, help="the sets whose name starts with this (e.g. ur3)")
    ap.add_argument("--references", action="store_true")
    ap.add_argument(
        "--model",
        choices=tuple(MODELS),
        default="both",
        help="robot error model of the UR3 sets: iid (derived flange poses), kinematic (joint angles + "
        "the nominal DH table) or both (default; the cross-camera check is printed for each)",
    )
    args = ap.parse_args()
    DetectionCache().install()
    opts = CalibrateOptions.from_config(load_preset("calibration"))
    results = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for name in HALF_SETS + ("visp-franka-eye-in-hand",):
            src = args.data / name
            if (args.only and not name.startswith(args.only)) or not src.is_dir():
                continue
            models = MODELS[args.model] if name.startswith("ur3") else (False,)
            for kinematic in models:
                label = f"{name} {'kinematic' if kinematic else 'iid'}" if name.startswith("ur3") else name
                path = import_set(name, src, Path(tmp) / label.replace(" ", "_"), kinematic=kinematic)
                if args.references:
                    references(name, path, opts)
                if name in HALF_SETS:
                    results.append(
                        dict(
                            half_split(label, path, opts, args.halvings),
                            set=name,
                            kinematic=kinematic if name.startswith("ur3") else None,
                        )
                    )
                else:
                    loo = loo_board_poses(name, path, opts)
                    if loo:
                        v, m = np.array([x["verdict"] for x in loo]), np.array([x["model"] for x in loo])
                        print(
                            f"\n{name}: leave-one-out board pose predicted vs observed ({len(loo)} views), squared "
                            f"Mahalanobis under the predicted covariance (chi2(6): median 5.35, 5 % above 12.6)"
                        )
                        for x in loo:
                            print(
                                f"  view {x['view']:>3s}: {x['mm']:6.2f} mm {x['deg']:5.2f} deg  d2 verdict "
                                f"{x['verdict']:7.2f}  model {x['model']:7.2f}"
                            )
                        print(
                            f"  median / share above 12.6: verdict {_stats(v, CHI2_95[6])}   "
                            f"model {_stats(m, CHI2_95[6])}"
                        )
    for kinematic in (False, True):
        full = {r["set"]: r["full"] for r in results if r.get("kinematic") == kinematic and "full" in r}
        if "ur3-eyetohand-cam1" in full and "ur3-eyetohand-cam2" in full:
            print_cross_camera(
                "kinematic robot model (joints + DH table)" if kinematic else "iid robot model (derived flange poses)",
                full["ur3-eyetohand-cam1"],
                full["ur3-eyetohand-cam2"],
                args.data / "ur3-eyetohand-cam1",
            )
    print(
        f"\nHalf-split test ({args.halvings} random halvings + odd/even per set): squared Mahalanobis distance "
        "between the halves' results under the sum of their covariances"
    )
    print(
        f"{'set':46s} views pairs | X verdict: median >12.6 | X model: median >12.6 | fx fy cx cy verdict: "
        f"median >9.49 | model: median >9.49 | compare: median >12.6"
    )
    for r in results:
        if "error" in r:
            print(f"{r['name']:46s} {r['error']}")
            continue
        print(_row(r["name"], [x for x in r["rows"] if not x.get("failed")], r["n_views"]))
    for kinematic in (False, True):  # pooled: the UR3 sets with one robot model, with the other sets
        if any(r.get("kinematic") == kinematic for r in results):
            rows = [
                x
                for r in results
                if "error" not in r and r["kinematic"] in (None, kinematic)
                for x in r["rows"]
                if not x.get("failed")
            ]
            print(_row(f"all (UR3 {'kinematic' if kinematic else 'iid'})", rows, None))
    if results:
        print("targets: X verdict median <= 8 and share above 12.6 <= 15 %; the same for fx fy cx cy")
    print(f"[{time.perf_counter() - t0:.0f} s]")


if __name__ == "__main__":
    main()
