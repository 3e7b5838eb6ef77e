"""False alarms of the whole workflow on clean rendered sessions.

Each session is rendered by :func:`handeye.sim.vendor.write_vendor_session` with exact robot poses,
no hidden and no outlier views (both mounting modes, image noise 0 and 2 grey levels, 12-25 views,
one seed per session), and calibrated as ``handeye calibrate`` does it
(:func:`handeye.workflow.calibrate_session`, without the report). Nothing in such a session is wrong,
so every one of these is a false alarm:

* a fail or warn finding of the diagnostics;
* a robot pose flagged by the refinement (outlier kind ``robot_pose``);
* a view dropped by the refinement (kinds ``reprojection`` / ``too_few_corners``) or not detected.

Flagged single corners are counted too, for information (a corner far off its prediction may be a real
detector error), and so are the sessions whose model covariance the cross-validation finds too small
(``uncertainty_underestimated``, info when the verdict covariance covers the spread) and those whose
verdict covariance takes the validated one in some direction. Prints one line per session with a false
alarm and the counts per setting.

    python benchmarks/bench_clean_sessions.py [--seeds 30] [--first 0] [--cache DIR] [--workers 2]

``--seeds`` sessions per setting (mode x image noise); ``--cache`` keeps the rendered sessions for a
second run (e.g. before / after a change). Exit status 1 when any false alarm occurred.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

import numpy as np

MODES = ("eye_in_hand", "eye_to_hand")
IMAGE_NOISES = (0.0, 2.0)


def settings(n_per: int, first: int) -> list[dict]:
    out = []
    for k in range(first, first + n_per):
        for mode in MODES:
            for noise in IMAGE_NOISES:
                n_views = int(np.random.default_rng(30_000 + k).integers(12, 26))
                out.append(dict(mode=mode, image_noise=noise, seed=3000 + k, n_views=n_views))
    return out


def run_one(cfg: dict, cache: str) -> dict:
    from handeye.sim.vendor import write_vendor_session
    from handeye.workflow import calibrate_session

    name = f"{cfg['mode']}_n{cfg['image_noise']:g}_s{cfg['seed']}_v{cfg['n_views']}"
    folder = Path(cache) / name
    if not (folder / "ground_truth.json").exists():
        write_vendor_session(
            folder,
            mode=cfg["mode"],
            n_views=cfg["n_views"],
            seed=cfg["seed"],
            image_noise=cfg["image_noise"],
            overwrite=True,
            workers=1,
        )
    with tempfile.TemporaryDirectory() as out:
        res = calibrate_session(folder, out_dir=out, report=False).result
    all_findings = (res.get("diagnostics") or {}).get("findings", [])
    findings = [f for f in all_findings if f.get("severity") in ("fail", "warn")]
    ref = res.get("refinement") or {}
    outliers = ref.get("outliers", [])
    flagged = {o["view_id"] for o in outliers if o["kind"] != "corners"}
    not_used = [v["id"] for v in res.get("views") or [] if not v.get("used") and v["id"] not in flagged]
    return {
        "name": name,
        "status": res.get("status"),
        "findings": [f"{f['severity']}:{f['code']}" for f in findings],
        "robot": [o["view_id"] for o in outliers if o["kind"] == "robot_pose"],
        "view": [o["view_id"] for o in outliers if o["kind"] in ("reprojection", "too_few_corners")],
        "corners": sum(len(o["corner_ids"]) for o in outliers if o["kind"] == "corners"),
        "not_used": not_used,
        # the model covariance too small for the folds' spread: a finding of size (info) when the verdict covers it
        "model_underestimated": any(f.get("code") == "uncertainty_underestimated" for f in all_findings),
        "sigma_source": ref.get("sigma_source"),
        "robot_max_mahalanobis": max(
            [d.get("robot_vs_camera_mahalanobis", 0.0) for d in ref.get("per_view", {}).values()] or [0.0]
        ),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=30, help="sessions per setting (mode x image noise)")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=None, help="folder for the rendered sessions (kept)")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    cache_tmp = None
    if a.cache is None:
        cache_tmp = tempfile.TemporaryDirectory()
        a.cache = Path(cache_tmp.name)
    a.cache.mkdir(parents=True, exist_ok=True)
    cfgs = settings(a.seeds, a.first)
    counts = collections.defaultdict(collections.Counter)
    from fanout import ordered_map

    for k, r in enumerate(ordered_map(run_one, cfgs, [str(a.cache)] * len(cfgs), workers=a.workers)):
        cfg = cfgs[k]
        key = f"{cfg['mode']:12s} noise {cfg['image_noise']:g}"
        c = counts[key]
        c["sessions"] += 1
        c["failed"] += r["status"] != "ok"
        c["fail/warn finding"] += bool(r["findings"])
        c["robot-pose flag"] += bool(r["robot"])
        c["view flag"] += bool(r["view"] or r["not_used"])
        c["corner flags"] += r["corners"]
        c["model underestimated"] += r["model_underestimated"]
        c["verdict validated"] += r["sigma_source"] in ("validated", "model+validated")
        c["max_mahalanobis_x100"] = max(c["max_mahalanobis_x100"], int(100 * r["robot_max_mahalanobis"]))
        if r["status"] != "ok" or r["findings"] or r["robot"] or r["view"] or r["not_used"]:
            print(
                f"{r['name']}: status {r['status']} findings {r['findings']} robot {r['robot']} "
                f"view {r['view']} not used {r['not_used']}",
                flush=True,
            )
        print(f"[{k + 1}/{len(cfgs)}] {r['name']}", file=sys.stderr, flush=True)
    total = collections.Counter()
    print(
        f"{'setting':22s} sessions failed fail/warn robot-pose view corners max-robot-Mahalanobis "
        "model-underestimated(info) verdict-validated"
    )
    for key, c in sorted(counts.items()):
        print(
            f"{key:22s} {c['sessions']:8d} {c['failed']:6d} {c['fail/warn finding']:9d} {c['robot-pose flag']:10d} "
            f"{c['view flag']:4d} {c['corner flags']:7d} {c['max_mahalanobis_x100'] / 100:21.2f} "
            f"{c['model underestimated']:26d} {c['verdict validated']:17d}"
        )
        total.update({k: v for k, v in c.items() if k != "max_mahalanobis_x100"})
    print(
        f"{'all':22s} {total['sessions']:8d} {total['failed']:6d} {total['fail/warn finding']:9d} "
        f"{total['robot-pose flag']:10d} {total['view flag']:4d} {total['corner flags']:7d} {'':21s} "
        f"{total['model underestimated']:26d} {total['verdict validated']:17d}"
    )
    bad = total["failed"] + total["fail/warn finding"] + total["robot-pose flag"] + total["view flag"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
