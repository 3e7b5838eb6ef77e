"""A cell's joint result from its cameras' solo runs: the graph's inputs, the checks and result.json's content.

:func:`camera_input` turns a camera's :class:`handeye.pipeline.CalibrationRun` into the joint graph's input
(its views by id, its own refinement's corner and view decisions, its refined values as the start).
:func:`cell_result` writes the joint estimate over each camera's own result (X, board, intrinsics and
their covariances), adds the camera pairs and the joint covariance, and the cross-camera checks: each
solo X against the joint one, the robot poses every camera disagrees with (named once for the cell),
the views one camera alone disagrees with.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
from scipy.stats import chi2

from ..conventions import pose_forms
from ..frames import tangent_difference
from ..mounting import mounting
from ..output import plain
from ..refine.cell import CellCameraInput, CellRefinement
from ..refine.covariance import hand_eye_uncertainty
from ..refine.options import RefineView
from ..results import FINDING_KEYS

#: a solo X further than this from the joint one (its chi-square p-value under the solo covariance) is named
SOLO_AGREEMENT_P = 0.01
_RANK = {"PASS": 0, "WARN": 1, "FAIL": 2, "REFUSED": 3}


def _rank(verdict: str) -> int:
    return _RANK.get(verdict, 2)


_SEVERITY_VERDICT = {"fail": "FAIL", "warn": "WARN", "info": "PASS"}


def camera_input(name: str, run) -> CellCameraInput:
    """The joint graph's input of one camera from its solo run (refined, status ok)."""
    s, ref = run.session, run.refined
    views = []
    for vid in run.board_poses:
        v = s.view(vid)
        views.append(
            RefineView(
                vid, run.board_poses[vid].corner_ids, run.detections[vid].image_points, v.T_base_end, v.joint_angles
            )
        )
    flagged: dict[str, set] = {}
    for o in ref.outliers:
        if o.kind == "corners":
            flagged.setdefault(o.view_id, set()).update(int(c) for c in o.corner_ids)
    masks = {
        v.view_id: ~np.isin(np.asarray(v.corner_ids, int), sorted(flagged[v.view_id]))
        for v in views
        if v.view_id in flagged
    }
    removed = frozenset(vid for vid, d in ref.per_view.items() if d["status"] == "removed")
    return CellCameraInput(
        name=name,
        mode=s.mode,
        object_points=s.target.object_points(),
        views=tuple(views),
        intrinsics=ref.intrinsics,
        T_x0=ref.T_x,
        T_board0=ref.T_board,
        sigma_px=ref.sigma_px,
        masks=masks,
        removed=removed,
        board=repr(s.target.to_dict()),
        fix=tuple(ref.options.fix),
        symmetries=tuple(s.target.symmetries()),
    )


def start_options(runs: dict) -> Any:
    """The refinement options of the cell: the first camera's, with the robot noise starting at the cameras' median.

    (The noise is estimated again in the cell; a start near it saves rounds.)
    """
    from dataclasses import replace

    first = next(iter(runs.values())).refined
    o = replace(first.options, prior=None)
    if o.robot_noise != "estimate":
        return o
    models = [r.refined.robot_model for r in runs.values()]
    enc = [m["encoder_sigma_deg"] for m in models if m.get("encoder_sigma_deg")]
    if enc and first.robot_model.get("kind") in ("kinematic", "joint_space"):
        return replace(o, encoder_sigma_deg=float(np.median(enc)))
    mm = [r.refined.robot_sigma_mm for r in runs.values() if np.isfinite(r.refined.robot_sigma_mm)]
    deg = [r.refined.robot_sigma_deg for r in runs.values() if np.isfinite(r.refined.robot_sigma_deg)]
    if mm and deg and min(mm) > 0 and min(deg) > 0:
        return replace(o, robot_sigma_mm=float(np.median(mm)), robot_sigma_deg=float(np.median(deg)))
    return o


def dh_prior_scale(runs: dict) -> float:
    """The largest scale of the arm's DH prior the cameras' own refinements estimated (1: none contradicted it)."""
    return max((float(r.refined.robot_model.get("dh_prior_scale") or 1.0) for r in runs.values()), default=1.0)


def excluded_by_most(runs: dict) -> list[str]:
    """View ids whose robot pose most of the cameras that used them excluded in their own refinements."""
    seen: dict[str, int] = {}
    excl: dict[str, int] = {}
    for run in runs.values():
        for vid, d in run.refined.per_view.items():
            if d["status"] != "removed":
                seen[vid] = seen.get(vid, 0) + 1
                excl[vid] = excl.get(vid, 0) + (d["status"] == "robot_excluded")
    return sorted((v for v in seen if 2 * excl[v] > seen[v]), key=lambda v: (len(v), v))


def _finding(code: str, severity: str, title: str, evidence: str, action: str, view_ids=(), **details) -> dict:
    d = dict(code=code, severity=severity, title=title, evidence=evidence, action=action, view_ids=list(view_ids))
    return {**{k: d[k] for k in FINDING_KEYS}, "details": plain(details)}


def solo_agreement(T_solo: np.ndarray, cov_solo: np.ndarray, T_joint: np.ndarray) -> dict:
    """The joint X in the solo result's terms: Mahalanobis distance under the solo covariance and its p-value.

    ``cov_solo``: the solo result's verdict covariance (``cov_x_6x6_verdict``), whose 95 % region it reports.
    """
    xi = tangent_difference(T_solo, T_joint)
    m2 = float(xi @ np.linalg.solve(cov_solo, xi))
    return {
        "mahalanobis": float(np.sqrt(m2)),
        "p_value": float(chi2.sf(m2, 6)),
        "rot_deg": float(np.degrees(np.linalg.norm(xi[:3]))),
        "trans_mm": float(1e3 * np.linalg.norm(T_joint[:3, 3] - T_solo[:3, 3])),
        "inside_95": bool(m2 <= chi2.ppf(0.95, 6)),
    }


def _camera_entry(name: str, solo: dict, cr: CellRefinement, findings: list[dict]) -> dict:
    """A camera's entry: its solo result with the joint X, board, intrinsics, covariances and residuals."""
    e = {k: v for k, v in solo.items() if k != "handeye_result"}
    mode = mounting(cr.modes[cr.names.index(name)])
    T_x = cr.T_x[name]
    b = cr.boards[cr.board_of[name]]
    e[mode.x_name] = T_x.tolist()
    e[mode.board_name] = np.asarray(b["matrix"]).tolist()
    e["hand_eye"] = dict(name=mode.x_name, **pose_forms(T_x))
    e["board"] = dict(name=mode.board_name, **pose_forms(b["matrix"]))
    intr = cr.intrinsics[name]
    e["intrinsics"] = dict(solo.get("intrinsics") or {}, **intr.to_dict())
    ref = dict(solo.get("refinement") or {})
    for k in [k for k in ref if k.endswith("_validated") or k in ("validation", "cov_intrinsics_verdict")]:
        ref.pop(k)
    ref.pop("intrinsics_cov_names", None)
    ref.pop("intrinsics_sigma_verdict", None)
    cov_x = cr.cov_x(name)
    S_b = cr.cov_of(b["block"])
    unc = hand_eye_uncertainty(cov_x, T_x, float(ref.get("working_distance_m") or 1.0))
    k_names = cr.intrinsics_names[name]
    k_block = f"cameras.{name}.intrinsics"
    ksig = np.sqrt(np.diag(cr.cov_of(k_block))) if k_names else np.zeros(0)
    ref.update(
        {
            mode.x_name: T_x,
            mode.board_name: b["matrix"],
            "cov_x_6x6": cov_x,
            "cov_x_6x6_verdict": cov_x,
            "sigma_source": "model",
            "cell_sigma_note": "the joint graph's model covariance (no held-out refits of the cell)",
            "cov_board_6x6": S_b,
            "sigma_rot_deg": unc.sigma_rot_deg,
            "sigma_trans_mm": unc.sigma_trans_mm,
            "correlation_6x6": unc.correlation_6x6,
            "predicted_error_mm": unc.predicted_error_mm,
            "predicted_error_axes_mm": unc.predicted_error_axes_mm,
            "intrinsics": intr.to_dict(),
            "intrinsics_sigma": dict(zip(k_names, ksig.tolist(), strict=True)),
            "sigma_px": cr.sigma_px[name],
            "per_view": cr.per_view[name],
            "rms_px_after": _rms(cr.per_view[name]),
            "robot_model": dict(cr.robot_model),
            "cov_x_intrinsics": None,
        }
    )
    e["refinement"] = plain(ref)
    e["findings"] = list(solo.get("findings") or []) + findings
    worst = max((_SEVERITY_VERDICT.get(f["severity"], "PASS") for f in findings), key=_rank, default="PASS")
    e["verdict"] = max(solo.get("verdict") or "PASS", worst, key=_rank)
    return e


def _rms(per_view: dict) -> float:
    sq = [d["rms_px"] ** 2 * d["n_used"] for d in per_view.values() if d["status"] != "removed"]
    n = sum(d["n_used"] for d in per_view.values() if d["status"] != "removed")
    return float(np.sqrt(sum(sq) / n)) if n else float("nan")


def _cameras_without_shared_views(runs: dict) -> list[str]:
    """The cameras (of two or more) none of whose used view ids any other camera used."""
    used = {n: {o.view_id for o in r.outcomes if o.used} for n, r in runs.items()}
    if len(used) < 2:
        return []
    return [n for n, ids in used.items() if not ids & set().union(*(u for m, u in used.items() if m != n))]


def cell_result(cr: CellRefinement, solos: dict[str, dict], runs: dict, *, version: int) -> dict:
    """result.json of a cell (``kind: cell``) from the joint refinement and each camera's solo result.

    ``solos``: camera name -> its solo result.json content (every camera, also failed ones, which keep their
    own entry); ``runs``: camera name -> its CalibrationRun (the cameras in the joint graph).
    """
    cell_findings: list[dict] = []
    per_cam: dict[str, list[dict]] = {n: [] for n in solos}
    agreement = {}
    solo_cov = {}
    for name in cr.names:
        ref = runs[name].refined
        # the solo result's 95 % region: the covariance its verdict stands by (the model's when it has no other)
        verdict_cov = ((solos.get(name) or {}).get("refinement") or {}).get("cov_x_6x6_verdict")
        solo_cov[name] = np.asarray(ref.cov_x_6x6 if verdict_cov is None else verdict_cov, float)
        a = solo_agreement(ref.T_x, solo_cov[name], cr.T_x[name])
        agreement[name] = a
        if a["p_value"] < SOLO_AGREEMENT_P:
            per_cam[name].append(
                _finding(
                    "cell_solo_disagrees",
                    "warn",
                    f"Camera {name}'s own calibration disagrees with the cell's",
                    f"joint X {a['trans_mm']:.2f} mm / {a['rot_deg']:.3f} deg from the solo one, Mahalanobis "
                    f"{a['mahalanobis']:.2f} under the solo covariance (p = {a['p_value']:.2g})",
                    "check that the camera was not moved during the sessions and that its session is this arm's",
                    **a,
                )
            )
    if cr.robot_excluded:
        ids = sorted(cr.robot_excluded, key=lambda v: (len(v), v))
        cell_findings.append(
            _finding(
                "cell_robot_pose",
                "warn",
                f"Every camera disagrees with the reported robot pose of view{'s' if len(ids) > 1 else ''} "
                + ", ".join(ids),
                "; ".join(
                    f"view {v}: {cr.robot_excluded[v].get('trans_mm', float('nan')):.2f} mm / "
                    f"{cr.robot_excluded[v].get('rot_deg', float('nan')):.3f} deg"
                    for v in ids
                ),
                "the robot pose recorded for these views is not where the arm was (swapped or mistyped poses); "
                "the cell uses their images without the reported poses",
                view_ids=ids,
                views=cr.robot_excluded,
            )
        )
    alone = _cameras_without_shared_views(runs)
    if alone:
        cell_findings.append(
            _finding(
                "cell_no_shared_views",
                "info",
                "The cameras share no view id"
                if len(alone) == len(runs)
                else f"Camera{'s' if len(alone) > 1 else ''} {', '.join(alone)} share{'' if len(alone) > 1 else 's'} "
                "no view id with the other cameras",
                "the cell ties such a camera to the others through the arm's model alone: its views of an arm pose "
                "cannot be compared with theirs (a camera that moved, a pose it saw differently)",
                "give views taken at one arm pose the same id in every camera's session (take them together)",
                cameras=alone,
            )
        )
    vp = cr.view_poses
    if vp.get("estimated"):
        t = vp["test"]
        cell_findings.append(
            _finding(
                "cell_view_poses",
                "info",
                "The cameras' views of one arm pose disagree beyond their pixel noise",
                f"one pose per view against one per camera view: F = {t['statistic']:.2f} "
                f"({t['dof'][0]}, {t['dof'][1]} dof), p = {t['p_value']:.2g}; each camera's pose of a shared view "
                f"deviates from the view's by sigma {vp['sigma_rot_deg']:.3f} deg / {vp['sigma_trans_mm']:.3f} mm "
                "(estimated, in every covariance)",
                "the cameras saw the arm at different instants or moving, or a camera's model misses part of its "
                "image (trigger the cameras together, let the arm settle before each view); the cell models it",
                **vp,
            )
        )
    for name, views in cr.camera_removed.items():
        if views:
            ids = sorted(views, key=lambda v: (len(v), v))
            per_cam[name].append(
                _finding(
                    "cell_camera_view",
                    "warn",
                    f"Camera {name} alone disagrees with the others about the arm's pose in view"
                    f"{'s' if len(ids) > 1 else ''} {', '.join(ids)}",
                    "; ".join(f"view {v}: {views[v]['rms_px']:.2f} px RMS" for v in ids),
                    "check these images of this camera (a moved camera, a mislabelled image, motion blur); the cell "
                    "leaves them out of this camera",
                    view_ids=ids,
                    views=views,
                )
            )
    cameras = {}
    for name, solo in solos.items():
        if name in cr.names:
            cameras[name] = _camera_entry(name, solo, cr, per_cam[name])
            cameras[name]["refinement"]["solo"] = plain(
                {
                    "x": runs[name].refined.T_x,
                    "cov_x_6x6": runs[name].refined.cov_x_6x6,
                    "cov_x_6x6_verdict": solo_cov[name],
                    "agreement": agreement[name],
                }
            )
        else:
            cameras[name] = {k: v for k, v in solo.items() if k != "handeye_result"}
    pairs = {}
    for cam_a, cam_b in cr.pairs():
        T, C = cr.pair(cam_a, cam_b)
        key = f"{cam_a}/{cam_b}"
        pairs[key] = {
            "name": f"T_{cam_a}_{cam_b}",
            "matrix": T.tolist(),
            "cov_6x6": C.tolist(),
            "cov_6x6_verdict": C.tolist(),
        }
        pairs[key]["translation_mm"] = (1e3 * T[:3, 3]).tolist()
        pairs[key]["sigma_rot_deg"] = np.degrees(np.sqrt(np.diag(C)[:3])).tolist()
        pairs[key]["sigma_trans_mm"] = (1e3 * np.sqrt(np.diag(C)[3:])).tolist()
    failed = [n for n in solos if n not in cr.names]
    for n in failed:
        cell_findings.append(
            _finding(
                "cell_camera_failed",
                "fail",
                f"Camera {n} could not be calibrated and is not in the cell's graph",
                str(solos[n].get("failure_reason") or "its own calibration failed"),
                f"see camera {n}'s own result and report",
            )
        )
    verdicts = [c.get("verdict") or "FAIL" for c in cameras.values()]
    verdicts += [_SEVERITY_VERDICT.get(f["severity"], "PASS") for f in cell_findings]
    verdict = max(verdicts, key=_rank)
    refinement: dict[str, Any] = {
        "status": "ok",
        "robot_model": cr.robot_model,
        "robot_excluded": cr.robot_excluded,
        "sigma_px_cameras": cr.sigma_px,
        "redundancy": cr.redundancy,
        "iterations": cr.iterations,
        "seconds": cr.seconds,
        "solo_agreement": agreement,
        "sigma_source": "model",
    }
    if cr.view_poses:
        refinement["view_poses"] = cr.view_poses
    if cr.dh.size:
        refinement["dh_offsets"] = cr.dh
    d: dict[str, Any] = {
        "handeye_result": version,
        "kind": "cell",
        "status": "ok",
        "mode": "cell",
        "cameras": cameras,
        "camera_pairs": pairs,
        "joint_covariance": {"blocks": cr.blocks, "sizes": cr.sizes, "matrix": cr.cov.tolist()},
    }
    if len(cr.boards) == 1:  # one board for every camera: the single-camera keys
        one = cr.boards[0]
        d[one["name"]] = np.asarray(one["matrix"]).tolist()
        d["board"] = dict(name=one["name"], **pose_forms(one["matrix"]))
        refinement["cov_board_6x6"] = cr.cov_of(one["block"])
    else:
        refinement["boards"] = {
            b["block"]: {
                "name": b["name"],
                "matrix": b["matrix"],
                "cameras": b["cameras"],
                "cov_6x6": cr.cov_of(b["block"]),
            }
            for b in cr.boards
        }
    d["refinement"] = plain(refinement)
    d["findings"] = cell_findings + [dict(f, camera=n) for n in cameras for f in per_cam.get(n, [])]
    d["verdict"] = verdict
    d["verdict_headline"] = _headline(verdict, cameras, cell_findings)
    return d


def _headline(verdict: str, cameras: dict, findings: list[dict]) -> str:
    """The cell's verdict, each camera's, and why.

    For a FAIL every failing cell finding and every failing camera's own headline (its cause), else the first
    cell finding.
    """
    parts = [f"{n} {c.get('verdict', 'FAIL')}" for n, c in cameras.items()]
    lead = f"Cell of {len(cameras)} cameras: {verdict}"
    if verdict == "FAIL":
        why = [str(f["title"]) for f in findings if f["severity"] == "fail"]
        why += [
            f"{n}: {str(c.get('verdict_headline') or c.get('failure_reason') or '').rstrip('.')}"
            for n, c in cameras.items()
            if c.get("verdict") == "FAIL" and (c.get("verdict_headline") or c.get("failure_reason"))
        ]
    else:
        why = [str(findings[0]["title"])] if findings else []
    extra = "; " + "; ".join(why) if why else ""
    return f"{lead} ({', '.join(parts)}){extra}."


def view_record_count(res: dict) -> Optional[int]:
    """How many views the cell's cameras used together (distinct ids)."""
    ids = {v["id"] for c in (res.get("cameras") or {}).values() for v in c.get("views", []) if v.get("used")}
    return len(ids) if ids else None
