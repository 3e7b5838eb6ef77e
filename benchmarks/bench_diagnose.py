"""False alarms on clean sessions, sensitivity to injected faults, and the cost of handeye.diagnose.

Corner-level synthetic sessions (both modes, several seeds, robot noise levels and view counts) are
written in the vendor layout with empty images; detection is replaced by the synthetic corners, so
loading, re-reading the raw poses and calibration run as for real data. Prints, per setting, how many
clean sessions got a fail/warn finding or a crashed diagnostics stage (both count as failures), and
how often a robot-pose error or a board move of a given size was named. ``--timing`` renders a
20-view 1280x720 session (handeye.sim.vendor.write_vendor_session) and prints the median time of
diagnose_run without and with cross-validation. ``--realdata`` runs the real datasets in ../shared/data
(imported as the tests do) as recorded and with faults injected into their pose files, and prints the
findings, the cross-validation verdict and the stages.

    python benchmarks/bench_diagnose.py [--seeds 6] [--quick] [--refine] [--kinematic] [--timing] [--scaling]
        [--realdata] [--no-accuracy] [--no-sensitivity] [--forensics N]

Exit status 1 when any clean session got a fail/warn finding or any stage crashed.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

import handeye.pipeline as calibrate_mod
from handeye.conventions import VENDOR_POSE_FORMAT, PoseFormat, pose_values_from_T
from handeye.diagnose import diagnose_run
from handeye.frames import T_from_rotvec, inv_T
from handeye.mounting import mounting
from handeye.pipeline import CalibrateOptions, observe, run_calibration
from handeye.session import load_session
from handeye.sim.corners import make_corner_session
from handeye.targets import CharucoSpec, ChessboardSpec


def _write_vendor(folder: Path, cs, T) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.jpg"):  # a previous, larger session's images
        old.unlink()
    for k in range(1, cs.n_views + 1):
        (folder / f"{k}.jpg").write_bytes(b"")
    (folder / "poses.txt").write_text(
        "\n".join(",".join(f"{x:.9f}" for x in pose_values_from_T(t, VENDOR_POSE_FORMAT)) for t in T) + "\n"
    )
    (folder / "config.yaml").write_text(
        yaml.safe_dump(
            {
                "checkerboard_args": {"XX": cs.target.cols, "YY": cs.target.rows, "L": cs.target.square_m},
                "mode": cs.mode,
            }
        )
    )
    return folder


def _diagnose(folder: Path, cs) -> dict:
    return _run_and_diagnose(folder, cs)[1]


CRASHED = collections.Counter()  # (stage, error) -> sessions, over every diagnose_run of the benchmark


def _count_crashes(d: dict) -> None:
    for stage, err in d.get("stage_errors", {}).items():
        CRASHED[(stage, err)] += 1


def clean(seeds: range, root: Path, *, kinematic: bool = False) -> int:
    """Clean corner-level sessions (iid robot noise at four levels, or with ``kinematic`` the RM65 and UR5e arms
    with DH errors and encoder noise of handeye.sim.robot_error, their poses given without the arm as a vendor
    folder does). With --refine, the refinement's robot-pose statistics of all views (15 and 25 views) are
    pooled and their tail fitted (:func:`_print_tail_fit`)."""
    bad = collections.Counter()
    modes = collections.Counter()  # the mode the data decide (the session states it): right, wrong, undecided
    n = 0
    t0 = time.perf_counter()
    stats = []  # the refinement's robot-pose statistics of every view (--refine)
    for mode in ("eye_in_hand", "eye_to_hand"):
        for seed in seeds:
            levels = (
                (("rm65", 0.3), ("ur5e", 0.3))
                if kinematic
                else (((0.0, 0.0), 0.3), ((0.3, 0.05), 0.3), ((1.0, 0.1), 0.5), ((2.0, 0.3), 1.0))
            )
            for rn, px in levels:
                for nv in (8, 15, 25):
                    robot = dict(robot_error="kinematic", arm=rn) if kinematic else dict(robot_noise=rn)
                    cs = make_corner_session(mode=mode, n_views=nv, seed=seed, noise_px=px, **robot)
                    run, d = _run_and_diagnose(_write_vendor(root / "clean", cs, cs.T_base_end_reported), cs)
                    _count_crashes(d)
                    if run.refined is not None and nv > 8:
                        stats += [
                            pv["robot_vs_camera_mahalanobis"] ** 2
                            for pv in run.refined.per_view.values()
                            if "robot_vs_camera_mahalanobis" in pv
                        ]
                    n += 1
                    decided = ((d.get("mode") or {}).get("evidence") or {}).get("decided")
                    modes[decided == mode if decided else "undecided"] += 1
                    for f in d["findings"]:
                        if f["severity"] in ("fail", "warn"):
                            bad[(f["code"], rn, nv)] += 1
    print(
        f"clean sessions: {n} ({time.perf_counter() - t0:.0f} s), with a fail/warn finding: "
        f"{sum(bad.values())}; mode from the data: right {modes[True]}, wrong {modes[False]}, undecided "
        f"{modes['undecided']}"
    )
    if stats:
        _print_tail_fit(np.array(stats))
    if modes[False]:
        bad[("wrong mode detection", None, None)] += modes[False]
    for k, v in sorted(bad.items(), key=str):
        print(f"  {k}: {v}")
    return sum(bad.values())


def _print_tail_fit(stat: np.ndarray) -> None:
    """Pooled maximum-likelihood dof of the scale-mixture model of the robot-pose statistics (variance
    matched, as handeye.stats.mixture_tail_pvalue reads them): what configs/refine.yaml iid_tail_dof states."""
    from scipy.stats import chi2, f

    grid = (3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0, 17.0, 22.0, 30.0, 45.0, 70.0, 120.0, np.inf)
    x = stat[np.isfinite(stat)]
    ll = []
    for nu in grid:
        a = 1.0 if not np.isfinite(nu) else nu / (nu - 2.0)
        ll.append(
            np.sum(chi2.logpdf(x, 6)) if not np.isfinite(nu) else np.sum(f.logpdf(x * a / 6, 6, nu) + np.log(a / 6))
        )
    ll = np.array(ll)
    k = int(np.argmax(ll))
    inside = [nu for nu, v in zip(grid, ll, strict=False) if v >= ll[k] - 1.92]
    print(
        f"robot-pose statistics of {len(x)} views: mean {x.mean():.2f} (chi-square(6): 6), 99.9 % quantile "
        f"{np.quantile(x, 0.999):.1f} (chi-square(6): 22.5); pooled ML tail dof {grid[k]:g} "
        f"(log-likelihood {ll[k] - ll[-1]:.1f} above the Gaussian; 95 % interval {min(inside):g}-{max(inside):g})"
    )


def sensitivity(seeds: range, root: Path) -> None:
    hits = collections.defaultdict(list)
    for mode in ("eye_in_hand", "eye_to_hand"):
        mount = mounting(mode)
        for seed in seeds:
            for rn in ((0.3, 0.05), (1.0, 0.1)):
                cs = make_corner_session(mode=mode, n_views=15, seed=seed, robot_noise=rn)
                rng = np.random.default_rng(seed)
                u, w = (x / np.linalg.norm(x) for x in rng.normal(size=(2, 3)))
                for mm_size, deg_size in ((1.5, 0.15), (3.0, 0.3), (5.0, 0.5), (10.0, 1.0)):
                    dT = T_from_rotvec(np.radians(deg_size) * w, 1e-3 * mm_size * u)
                    T = cs.T_base_end_reported.copy()
                    T[6] = T[6] @ dT
                    d = _diagnose(_write_vendor(root / "s", cs, T), cs)
                    _count_crashes(d)
                    hits[("robot pose error, view 7", rn, mm_size, deg_size)].append(
                        any(f["code"] == "robot_pose_disagrees" and "7" in f["view_ids"] for f in d["findings"])
                    )
                    T = cs.T_base_end_reported.copy()
                    B = cs.T_board_true
                    for k in range(10, 15):
                        T[k] = mount.T_base_end_from_M(mount.M_from_T_base_end(T[k]) @ B @ dT @ inv_T(B))
                    d = _diagnose(_write_vendor(root / "s", cs, T), cs)
                    _count_crashes(d)
                    hits[("board moved after view 10", rn, mm_size, deg_size)].append(
                        any(f["code"] == "board_moved" for f in d["findings"])
                    )
                    hits[("board moved after view 10, named there", rn, mm_size, deg_size)].append(
                        any(
                            f["code"] == "board_moved" and "between views 10 and 11" in f["title"]
                            for f in d["findings"]
                        )
                    )
    print("sensitivity (15 views; robot noise per axis mm/deg; fault size mm/deg): named / sessions")
    for (what, rn, a, b), v in sorted(hits.items(), key=str):
        print(f"  {what:40s} noise {rn[0]:.1f} mm/{rn[1]:.2f} deg  fault {a:4.1f} mm/{b:.2f} deg: {sum(v)}/{len(v)}")


def timing(root: Path, *, repeats: int = 5) -> None:
    """Median wall time of diagnose_run on a rendered 20-view 1280x720 session (refined run)."""
    from handeye.sim.vendor import write_vendor_session

    folder = write_vendor_session(
        root / "rendered20",
        mode="eye_in_hand",
        n_views=20,
        seed=5,
        image_noise=1.0,
        robot_noise=(0.3, 0.05),
        overwrite=True,
    )
    run = run_calibration(load_session(folder), CalibrateOptions(refine=True))
    print(
        f"timing: rendered 20-view 1280x720 session, run {run.status}, {repeats} repeats: median wall time, "
        "and median CPU time of this process (less sensitive to other load on the machine)"
    )
    for label, kw in (
        ("diagnostics without cross-validation", {"cross_validation": False}),
        ("cross-validation alone", None),
        ("diagnostics with cross-validation", {"cross_validation": True}),
    ):
        ts, cpu = [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            if kw is None:
                from handeye.diagnose.crossval import cross_validate

                cross_validate(run)
            else:
                d = diagnose_run(run, **kw)
                _count_crashes(d)
            ts.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        print(f"  {label:40s} wall {np.median(ts):.3f} s (min {min(ts):.3f} s), CPU {np.median(cpu):.3f} s")
    print(f"  findings: {[f['code'] for f in d['findings']]}; stages: {d['stages']}")


def scaling(root: Path) -> None:
    """CPU time of diagnose_run (no images, no cross-validation) against the view count (corner sessions)."""
    print(
        "scaling: corner-level sessions, eye-in-hand, 0.3 mm / 0.05 deg robot noise; CPU time of diagnose_run "
        "without images and cross-validation"
    )
    for nv in (20, 60, 120):
        cs = make_corner_session(mode="eye_in_hand", n_views=nv, seed=1, robot_noise=(0.3, 0.05))
        dets = {d.view_id: d for d in cs.detections()}
        orig = calibrate_mod.detect_views
        calibrate_mod.detect_views = lambda items, target, dets=dets, **kw: {
            v: dets.get(v, "not found") for v, _ in items
        }
        try:
            run = run_calibration(
                load_session(_write_vendor(root / f"scale{nv}", cs, cs.T_base_end_reported)),
                CalibrateOptions(refine=False),
            )
        finally:
            calibrate_mod.detect_views = orig
        c0 = time.process_time()
        d = diagnose_run(run, images=False, cross_validation=False)
        _count_crashes(d)
        print(f"  {nv:4d} views: {time.process_time() - c0:.3f} s CPU, findings {[f['code'] for f in d['findings']]}")


REAL_SETS = ("visp-franka-eye-in-hand", "ical-mako-charuco-eye-to-hand", "ical-kinect-circlegrid-eye-in-hand")


def _real_faults(T: np.ndarray, fmt):
    """(name, the codes that name it, poses (N,4,4), the format the numbers are written in (None: as stated),
    mode swap) per fault."""
    from dataclasses import replace

    T = np.asarray(T, float)
    w = np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74])
    out = [
        ("as recorded", set(), T, None, False),  # (label, codes, poses, format written, mode swapped[, view])
        ("millimetres written, metres stated", {"translation_units"}, T, replace(fmt, translation_unit="mm"), False),
        ("inverted poses", {"poses_inverted"}, inv_T(T), None, False),
        ("mode swapped", {"mode_swapped"}, T, None, True),
        ("poses shifted by one", {"pairs_shifted"}, np.concatenate([T[1:], T[:1]]), None, False),
    ]
    if fmt.rotation in ("euler", "rotvec"):
        out.append(("degrees written, radians stated", {"angle_units"}, T, replace(fmt, angle_unit="deg"), False))
    sw = T.copy()
    sw[[1, len(T) - 2]] = T[[len(T) - 2, 1]]
    out.append(("two poses swapped", {"pairs_shuffled"}, sw, None, False))
    one = T.copy()
    one[len(T) // 2] = T[len(T) // 2] @ T_from_rotvec(np.radians(0.5) * w, 0.005 * w)
    out.append(("one pose off by 5 mm / 0.5 deg", {"robot_pose_disagrees"}, one, None, False, len(T) // 2))
    return out


def realdata(data: Path, root: Path) -> int:
    """Real datasets as recorded (no fail/warn expected... printed, not asserted) and with injected faults."""
    from handeye.conventions import pose_values_from_T
    from handeye.diagnose import diagnose_session_error
    from handeye.errors import HandeyeError
    from handeye.session.importers import import_ical, import_visp
    from handeye.session.raw import read_raw_poses

    missed = 0
    for name in REAL_SETS:
        src = data / name
        if not src.is_dir():
            print(f"{name}: not available ({src})")
            continue
        path = (import_visp if name.startswith("visp") else import_ical)(src, root / name)
        doc = yaml.safe_load(path.read_text())
        s0 = load_session(path)
        fmt = read_raw_poses(path).fmt
        T0 = np.stack([s0.view(str(v["id"])).T_base_end for v in doc["views"]])  # in the file's order
        print(f"\n{name} ({s0.mode}, {len(s0.views)} views, poses as {fmt.describe()})")
        for label, want, T, written, swap, *view in _real_faults(T0, fmt):
            d2 = dict(doc)
            d2["views"] = [
                dict(v, pose=[float(x) for x in pose_values_from_T(T[k], written or fmt)])
                for k, v in enumerate(doc["views"])
            ]
            mode = ("eye_to_hand" if s0.mode == "eye_in_hand" else "eye_in_hand") if swap else None
            f = root / f"{name}-fault" / "session.yaml"
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_text(yaml.safe_dump(d2))
            t0 = time.perf_counter()
            try:
                run = run_calibration(load_session(f, mode=mode), CalibrateOptions(refine=True))
                d = diagnose_run(run)
                how = f"run {run.status}"
            except HandeyeError as e:
                d = diagnose_session_error(f, e, observe=observe, mode=mode)
                how = "load failed"
            _count_crashes(d)
            codes = sorted({(x["code"], x["severity"]) for x in d["findings"]})
            named = want <= {c for c, sev in codes if sev in ("fail", "warn")}
            if view:  # the finding must name the view the fault was put in
                vid = str(doc["views"][view[0]]["id"])
                named = named and any(vid in x["view_ids"] for x in d["findings"] if x["code"] in want)
            missed += not named
            cv = d.get("cross_validation", {})
            cvt = (
                f"; cross-validation {cv['verdict']} (rotation {cv.get('ratio_rot')}x, translation "
                f"{cv.get('ratio_trans')}x)"
                if "verdict" in cv
                else ""
            )
            sc = d.get("scale") or {}
            if sc.get("scale") is not None:
                cvt += f"; scale {sc['scale']:.4f} +- {sc['sigma']:.4f}"
            print(
                f"  {label:32s} {how:14s} {'named' if named else 'MISSED'}: {codes}{cvt} "
                f"[{time.perf_counter() - t0:.1f} s]"
            )
    return missed


# ------------------------------------------------------------------------------ forensics (issue: name the mistake)
FORENSIC_TARGETS = {
    "chessboard 11x8": ChessboardSpec(11, 8, 0.03),
    "chessboard 7x5 (odd x odd)": ChessboardSpec(7, 5, 0.025),
    "chessboard 8x6 (even x even)": ChessboardSpec(8, 6, 0.03),
    "chessboard 6x6 (square)": ChessboardSpec(6, 6, 0.03),
    "charuco 9x7": CharucoSpec(9, 7, 0.03, 0.022),
}
SYMMETRIC = ("chessboard 7x5 (odd x odd)", "chessboard 8x6 (even x even)", "chessboard 6x6 (square)")
#: fault -> (expected code, targets it runs on)
FAULTS = {
    "square size +10 %": ("square_size", ("chessboard 11x8", "charuco 9x7")),
    "square size -10 %": ("square_size", ("chessboard 11x8", "charuco 9x7")),
    "square size +20 %": ("square_size", ("chessboard 11x8", "charuco 9x7")),
    "square size -20 %": ("square_size", ("chessboard 11x8", "charuco 9x7")),
    "Euler kind (intrinsic xyz read as extrinsic)": ("euler_order", SYMMETRIC + ("charuco 9x7",)),
    "Euler order (zyx read as xyz)": ("euler_order", SYMMETRIC + ("charuco 9x7",)),
    "mode omitted": ("mode detected", ("chessboard 11x8", "chessboard 7x5 (odd x odd)", "charuco 9x7")),
    "mode swapped": ("mode_swapped", ("chessboard 11x8", "chessboard 7x5 (odd x odd)", "charuco 9x7")),
    "shift by 1 line": ("pairs_shifted", ("chessboard 11x8", "chessboard 8x6 (even x even)", "charuco 9x7")),
    "shift by 2 lines": ("pairs_shifted", ("chessboard 11x8", "chessboard 8x6 (even x even)", "charuco 9x7")),
    "pairs shuffled": ("pairs_shuffled", ("chessboard 11x8", "chessboard 7x5 (odd x odd)", "charuco 9x7")),
    "rotation vectors read as Euler angles": ("rotation_kind", ("chessboard 11x8",) + SYMMETRIC + ("charuco 9x7",)),
    # a capture that saved its pose but no image (the images numbered on), and the reverse (the last image then
    # deleted so that the counts agree): out of step from one image on, vendor folders
    "a pose without its image": ("pairs_shuffled", ("chessboard 11x8", "chessboard 7x5 (odd x odd)")),
    "an image without its pose": ("pairs_shuffled", ("chessboard 11x8", "chessboard 7x5 (odd x odd)")),
}


def _write_session(folder: Path, cs, T, *, square_m=None, mode="same", fmt=VENDOR_POSE_FORMAT) -> Path:
    """Vendor layout for chessboards, session.yaml for ChArUco; ``mode`` "same" (the truth), None (omitted)
    or a mode name; ``square_m`` the stated square size; poses written with ``fmt``, read as the vendor's."""
    folder.mkdir(parents=True, exist_ok=True)
    for old in list(folder.glob("*.jpg")) + list(folder.glob("*.png")) + list(folder.glob("*.yaml")):
        old.unlink()
    t = cs.target
    stated_mode = cs.mode if mode == "same" else mode
    vals = [pose_values_from_T(x, fmt) for x in T]
    if t.kind == "chessboard":
        for k in range(1, cs.n_views + 1):
            (folder / f"{k}.jpg").write_bytes(b"")
        (folder / "poses.txt").write_text("\n".join(",".join(f"{x:.9f}" for x in v) for v in vals) + "\n")
        cfg = {"checkerboard_args": {"XX": t.cols, "YY": t.rows, "L": square_m or t.square_m}}
        if stated_mode:
            cfg["mode"] = stated_mode
        (folder / "config.yaml").write_text(yaml.safe_dump(cfg))
        return folder
    views = []
    for k, v in enumerate(vals):
        vid = str(k + 1)
        if k < cs.n_views:
            (folder / f"{vid}.png").write_bytes(b"")
        views.append({"id": vid, "image": f"{vid}.png", "pose": [float(x) for x in v]})
    target = dict(t.to_dict(), square_m=square_m or t.square_m)
    doc = {
        "handeye_session": 1,
        "target": target,
        "views": views[: cs.n_views],
        "pose_format": {k: getattr(VENDOR_POSE_FORMAT, k) for k in PoseFormat.__dataclass_fields__},
    }
    if stated_mode:
        doc["mode"] = stated_mode
    (folder / "poses.txt").unlink(missing_ok=True)
    (folder / "session.yaml").write_text(yaml.safe_dump(doc))
    return folder / "session.yaml"


def _turn_some_views(cs, rng):
    """A detector that numbers a symmetric board from another corner in about half of the views."""
    syms = cs.target.symmetries()
    if len(syms) < 2:
        return cs
    pts = list(cs.image_points)
    for k in rng.choice(cs.n_views, cs.n_views // 2, replace=False):
        pts[k] = pts[k][syms[1 + rng.integers(len(syms) - 1)]]
    return replace(cs, image_points=tuple(pts))


def _run_case(args) -> dict:
    """One session: clean or with one fault injected; what the run and the diagnostics said."""
    fault, tname, mode, seed, root = args
    folder = Path(root) / f"{fault}-{tname}-{mode}-{seed}".replace(" ", "_").replace("%", "pc")
    target = FORENSIC_TARGETS[tname]
    rng = np.random.default_rng(1000 + seed)
    rn = [(0.3, 0.05), (1.0, 0.1), (2.0, 0.3)][seed % 3]
    nv = (12, 15, 20)[seed % 3]
    extra = 2 if fault.startswith("shift") else 1 if fault == "a pose without its image" else 0
    cs_all = make_corner_session(
        mode=mode, n_views=nv + extra, seed=seed, robot_noise=rn, noise_px=0.3 + 0.2 * (seed % 3), target=target
    )
    cs = replace(
        cs_all, view_ids=cs_all.view_ids[:nv], corner_ids=cs_all.corner_ids[:nv], image_points=cs_all.image_points[:nv]
    )
    cs = _turn_some_views(cs, rng)
    T = cs_all.T_base_end_reported[:nv]
    kw: dict = {}
    shift = 0
    if fault.startswith("square size"):
        f = 1.0 + float(fault.split()[2]) / 100.0
        kw["square_m"] = target.square_m * f
    elif fault.startswith("Euler kind"):
        kw["fmt"] = replace(VENDOR_POSE_FORMAT, euler_kind="intrinsic")
    elif fault.startswith("Euler order"):
        kw["fmt"] = replace(VENDOR_POSE_FORMAT, euler_order="zyx")
    elif fault == "mode omitted":
        kw["mode"] = None
    elif fault == "mode swapped":
        kw["mode"] = mounting(mode).other.name
    elif fault.startswith("shift"):
        shift = int(fault.split()[2])
        T = cs_all.T_base_end_reported[shift : shift + nv]  # image k carries the pose of image k + shift
    elif fault == "rotation vectors read as Euler angles":
        kw["fmt"] = replace(VENDOR_POSE_FORMAT, rotation="rotvec")
    # the capture (0-based) that lost its image or its pose (drawn only for those faults: the others' draws stay)
    lost = int(rng.integers(3, nv - 3)) if fault in ("a pose without its image", "an image without its pose") else -1
    if fault == "a pose without its image":
        keep = [k for k in range(nv + 1) if k != lost]  # the images of all captures but one, numbered on
        cs = replace(
            cs_all,
            view_ids=cs_all.view_ids[:nv],
            corner_ids=tuple(cs_all.corner_ids[k] for k in keep),
            image_points=tuple(cs_all.image_points[k] for k in keep),
        )
        cs = _turn_some_views(cs, rng)
        T = cs_all.T_base_end_reported[: nv + 1]
    elif fault == "an image without its pose":
        cs = replace(
            cs,
            view_ids=cs.view_ids[: nv - 1],
            corner_ids=cs.corner_ids[: nv - 1],
            image_points=cs.image_points[: nv - 1],
        )
        T = np.delete(T, lost, axis=0)
    if fault == "pairs shuffled":
        T = T[rng.permutation(nv)]
    path = _write_session(folder, cs, T, **kw)
    run, d = _run_and_diagnose(path, cs)
    codes = {f["code"] for f in d["findings"] if f["severity"] in ("fail", "warn")}
    err = run.error.code if run.error is not None else None
    out = {
        "fault": fault,
        "target": tname,
        "mode": mode,
        "status": run.status,
        "error": err,
        "codes": sorted(codes),
        "crashed": dict(d.get("stage_errors", {})),
        "decision": dict(run.mode_decision),
    }
    ev = run.mode_decision.get("evidence") or {}
    out["detected"] = ev.get("decided")
    if fault == "clean":
        out["named"] = run.status == "ok" and not codes
    elif fault.startswith("square size"):
        f = next((x for x in d["findings"] if x["code"] == "square_size"), None)
        out["named"] = f is not None and abs(f["details"]["measured_mm"] / (1e3 * target.square_m) - 1) < 0.02
        out["measured_mm"] = None if f is None else f["details"]["measured_mm"]
    elif fault.startswith("Euler"):
        out["named"] = "euler_order" in codes and not (codes - {"euler_order", "weak_motion"})
    elif fault == "mode omitted":
        out["named"] = (
            run.status == "ok"
            and run.mode_decision.get("mode_source") == "detected"
            and run.session.mode == mode
            and not codes
        )
    elif fault == "mode swapped":
        out["named"] = err == "mode_swapped"
    elif fault == "pairs shuffled":
        out["named"] = err == "pairs_shuffled"
    elif fault == "rotation vectors read as Euler angles":
        out["named"] = "rotation_kind" in codes and not (codes - {"rotation_kind", "weak_motion"})
    elif fault in ("a pose without its image", "an image without its pose"):
        # the refusal (most views out of step) or the failing finding (the last few) names the pose line to delete
        # or the image that has none
        fixes = [run.error.hint or ""] if err == "pairs_shuffled" else []
        fixes += [f["action"] for f in d["findings"] if f["code"] == "pairs_shuffled" and f["severity"] == "fail"]
        says = (
            f"delete pose line {lost + 1} "
            if fault == "a pose without its image"
            else f"the pose of image {lost + 1} is missing"
        )
        out["named"] = any(says in fx for fx in fixes)
    elif fault.startswith("shift"):
        out["named"] = err == "pairs_shifted" and f"--shift-poses {-shift}" in (run.error.hint or "")
        if out["named"]:  # the offered flag must give a clean run
            run2, d2 = _run_and_diagnose(path, cs, shift_poses=-shift)
            out["named"] = run2.status == "ok" and not {
                f["code"] for f in d2["findings"] if f["severity"] in ("fail", "warn")
            }
    return out


# --refine: calibrate as `handeye calibrate` does (the refinement's robot-pose decisions); through the environment,
# so that the Dask workers, which import this script as a module, see it too
REFINE = os.environ.get("BENCH_DIAGNOSE_REFINE") == "1"


def _run_and_diagnose(path: Path, cs, **opts):
    dets = {d.view_id: d for d in cs.detections()}
    orig = calibrate_mod.detect_views
    calibrate_mod.detect_views = lambda items, target, dets=dets, **kw: {v: dets.get(v, "not found") for v, _ in items}
    try:
        run = run_calibration(load_session(path), CalibrateOptions(**{"refine": REFINE, **opts}))
    finally:
        calibrate_mod.detect_views = orig
    return run, diagnose_run(run, images=False, cross_validation=False)


def forensics(n_seeds: int, root: Path, *, workers: int = 2, n_clean: int = 0, only: str = "") -> int:
    """Every fault of FAULTS on about n_seeds sessions (both modes, its targets), and n_clean clean sessions
    (default 5 x n_seeds) of the same kind (every target, both modes, symmetric boards with turned views).

    Returns the number of failures: a fault not named with its code, a clean session with a fail/warn
    finding or a refusal, a wrong mode detection, a crashed stage."""
    from fanout import ordered_map

    cases = []
    n_clean = n_clean or 5 * n_seeds
    for fault, (_, targets) in FAULTS.items():
        if only and only not in fault:
            continue
        per = max(1, -(-n_seeds // (2 * len(targets))))  # sessions per target and mode
        for tname in targets:
            for mode in ("eye_in_hand", "eye_to_hand"):
                for seed in range(per):
                    cases.append((fault, tname, mode, seed, str(root)))
    for tname in FORENSIC_TARGETS if not only or only in "clean" else ():
        for mode in ("eye_in_hand", "eye_to_hand"):
            for seed in range(max(1, n_clean // (2 * len(FORENSIC_TARGETS)))):
                cases.append(("clean", tname, mode, seed, str(root)))
    t0 = time.perf_counter()
    rows = list(ordered_map(_run_case, cases, workers=workers))
    bad = 0
    print(f"forensics: {len(rows)} corner-level sessions ({time.perf_counter() - t0:.0f} s, {workers} workers)")
    print(f"  {'fault':46s} {'expected':15s} named / sessions   (per target)")
    for fault in ["clean"] + list(FAULTS):
        rs = [r for r in rows if r["fault"] == fault]
        if not rs:
            continue
        ok = sum(r["named"] for r in rs)
        bad += len(rs) - ok
        per_t = ", ".join(
            f"{t.split(' (')[0]} {sum(r['named'] for r in rs if r['target'] == t)}/"
            f"{sum(1 for r in rs if r['target'] == t)}"
            for t in dict.fromkeys(r["target"] for r in rs)
        )
        exp = "no fail/warn" if fault == "clean" else FAULTS[fault][0]
        print(f"  {fault:46s} {exp:15s} {ok:4d} / {len(rs):4d}   ({per_t})")
        for r in [r for r in rs if not r["named"]][:3]:
            print(
                f"      missed: {r['target']}, {r['mode']}: status {r['status']}, error {r['error']}, "
                f"codes {r['codes']}, "
                f"measured {r.get('measured_mm')}"
            )
    wrong = [
        r
        for r in rows
        if r["detected"] is not None
        and r["detected"] != r["mode"]
        and not r["fault"].startswith(("Euler", "shift", "mode swapped", "pairs"))
    ]
    decided_clean = [r for r in rows if r["fault"] == "clean"]
    print(
        f"  mode evidence on clean sessions: decided right {sum(r['detected'] == r['mode'] for r in decided_clean)}"
        f" / {len(decided_clean)}, undecided {sum(r['detected'] is None for r in decided_clean)}, wrong "
        f"{sum(r['detected'] not in (None, r['mode']) for r in decided_clean)}; wrong detections (any session "
        f"whose poses are read right): {len(wrong)}"
    )
    crashed = [r for r in rows if r["crashed"]]
    print(f"  sessions with a crashed diagnostics stage: {len(crashed)}")
    for r in crashed[:3]:
        print(f"      {r['fault']}, {r['target']}: {r['crashed']}")
    return bad + len(wrong) + len(crashed)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--quick", action="store_true", help="2 seeds")
    ap.add_argument(
        "--kinematic",
        action="store_true",
        help="the clean sessions with the kinematic robot error model instead of iid noise levels",
    )
    ap.add_argument("--no-sensitivity", action="store_true", help="skip the injected robot-pose / board faults")
    ap.add_argument(
        "--refine",
        action="store_true",
        help="run the joint refinement as `handeye calibrate` does (slower; its robot-pose decisions "
        "replace the diagnostics' own test); default: the diagnostics without refinement",
    )
    ap.add_argument("--timing", action="store_true", help="time diagnose_run on a rendered 20-view session")
    ap.add_argument("--scaling", action="store_true", help="CPU time against the view count (20, 60, 120)")
    ap.add_argument("--realdata", action="store_true", help="real datasets, as recorded and with injected faults")
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--no-accuracy", action="store_true", help="skip the false-alarm and sensitivity runs")
    ap.add_argument(
        "--forensics",
        type=int,
        metavar="N",
        default=None,
        help="the injected-fault table: N sessions per fault (>= 50 for the full figures; --quick: 8)",
    )
    ap.add_argument("--workers", type=int, default=2, help="Dask worker processes for --forensics (1: in this process)")
    ap.add_argument(
        "--only",
        default="",
        help="--forensics: only the faults whose name contains this ('clean': only the clean sessions)",
    )
    a = ap.parse_args(argv)
    global REFINE
    REFINE = a.refine
    os.environ["BENCH_DIAGNOSE_REFINE"] = "1" if a.refine else "0"
    seeds = range(2 if a.quick else a.seeds)
    false_alarms = 0
    with tempfile.TemporaryDirectory() as tmp:
        if a.forensics is not None or a.quick:
            false_alarms += forensics(
                8 if a.forensics is None else a.forensics, Path(tmp), workers=a.workers, only=a.only
            )
        if not a.no_accuracy:
            false_alarms += clean(seeds, Path(tmp), kinematic=a.kinematic)
            if not a.no_sensitivity:
                sensitivity(seeds, Path(tmp))
        if a.timing:
            timing(Path(tmp))
        if a.scaling:
            scaling(Path(tmp))
        if a.realdata:
            missed = realdata(a.data, Path(tmp))
            print(f"real-data faults not named: {missed}")
    print(f"crashed diagnostics stages: {sum(CRASHED.values())}")
    for (stage, err), k in sorted(CRASHED.items()):
        print(f"  {stage}: {err} ({k} runs)")
    return 1 if false_alarms or CRASHED else 0


if __name__ == "__main__":
    sys.exit(main())
