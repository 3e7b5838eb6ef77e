"""Dataset diagnostics that name the mistake, and validation by held-out views.

:func:`diagnose_run` looks at a :class:`handeye.calibrate.CalibrationRun` (successful or failed) and
returns ``{"findings": [...], "cross_validation": {...}, ...}`` for ``result.json["diagnostics"]``;
:func:`diagnose_session_error` does what it can for a session that does not even load (robot poses
that look like millimetres or degrees): it re-reads the raw pose values in every plausible way and
says which reading fits the images.

Each :class:`Finding` has a stable ``code``, a ``severity`` (fail | warn | info), a one-line
``title``, the ``evidence`` (numbers) and an ``action``; docs/diagnostics.md lists every code with
its evidence, thresholds and measured false-alarm rate. In short:

* pose readings (translation_units, angle_units, euler_order, quaternion_order, poses_inverted,
  mode_swapped): every plausible re-reading of the raw pose values is scored by the board scatter left
  after solving ``C_i = A M_i B`` (Park & Martin on all view pairs, robust) and the pairs' rotation-angle
  invariant; inverted poses and a swapped mode give the same numbers and are told apart by which
  physical reading of the solution is plausible;
* pairing (pairs_shifted): image k with pose k+s (|s| <= 5), a full shuffle (views matched by their
  sorted pair-angle signatures) and poses that belong to another (possibly undetected) view;
* board_moved: the best split of the view sequence into two boards, Hotelling's two-sample test of the
  implied boards;
* robot_pose_disagrees / corner_order_flipped: the refinement's robot-pose decisions when it made them,
  else a robust per-view test (camera-only pose covariance including the intrinsics' uncertainty plus
  robustly estimated robot noise, and a size gate); a view that fits after renumbering its corners is
  a detector flip, not a robot error;
* weak_motion, too_few_views; target_not_found, partial_target (where the board would have been, from
  the robot pose); blurred, overexposed (edge width and saturation measured on the images);
  corners_bunched (image coverage); zero_distortion_given, intrinsics_mismatch (given intrinsics
  against calibrateCamera on the same corners); uncertainty_underestimated (cross-validation).

Cross-validation: leave-one-out (10-fold above 20 views) of the hand-eye result, refitted with the
refinement (one solve per fold, noise held at the full run's levels) when the run was refined, else
with the closed-form method; the jackknife spread is compared with the refinement's sigmas.

All functions are pure (no printing, no writing); images are only read.
"""
from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, replace
from itertools import product
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ..conventions import VENDOR_POSE_FORMAT, PoseFormat, T_from_pose_values
from .geometry import (RAYLEIGH_MEDIAN, all_pairs, implied_boards, jackknife_sigmas, log6, pair_invariants,
                            camera_pose_covariances, pose_differences, propagate, robust_noise_sigma,
                            robust_mean_T, solve_A_from_pairs, summarize_invariants)
from ..frames import inv_T
from ..output import plain
from ..mounting import mounting
from ..records import view_id_key
from ..session.raw import RawPoses, raw_poses_of, read_session_lenient

log = logging.getLogger(__name__)

SEVERITIES = ("fail", "warn", "info")

# ------------------------------------------------------------------------------ thresholds
#: a reading's cost is hypot(median board scatter / 1 deg, median board scatter / 10 mm)
COST_DEG = 1.0
COST_MM = 10.0
#: the reading as given is called wrong when its cost exceeds BAD, another reading's is below GOOD,
#: and the other is RATIO times better (clean real data: cost 0.2-0.8)
READING_BAD_COST = 3.0
READING_GOOD_COST = 2.0
READING_RATIO = 5.0
MAX_SHIFT = 5
#: views: fewer than FAIL cannot be calibrated; fewer than WARN leave no redundancy; RECOMMENDED
MIN_VIEWS_FAIL = 3
MIN_VIEWS_WARN = 6
RECOMMENDED_VIEWS = 10
#: motion: largest relative rotation and spread of rotation axes (deg); fail values are the seed's
MOTION_FAIL_ROT_DEG = 10.0
MOTION_FAIL_SPREAD_DEG = 5.0
MOTION_WARN_ROT_DEG = 20.0
MOTION_WARN_SPREAD_DEG = 10.0
#: robot pose vs camera: false-alarm probability per view of the robust test, and floors below which
#: a disagreement is never reported
VIEW_OUTLIER_P = 1e-4
VIEW_OUTLIER_MIN_DEG = 0.3
VIEW_OUTLIER_MIN_MM = 3.0
#: ... and a flagged view's rotation or translation disagreement is this many times the others' median
#: (times 1 + 2.5 / n_views: 3.9 with 8 views, 3.3 with 25)
VIEW_OUTLIER_RATIO = 3.0
#: robust scales never below these (noise-free synthetic data)
SCALE_FLOOR_DEG = 0.02
SCALE_FLOOR_MM = 0.2
#: board move: the split must explain the data this much better, and the step must be this large
STEP_MIN_SEGMENT = 3
STEP_P = 1e-3  # family-wise false-alarm probability of the step test over all splits (>= 9 views)
STEP_GAIN = 3.0  # fewer views: the split must explain the views this much better
STEP_MIN_GAIN = 1.3
STEP_MIN_DEG = 0.5
STEP_MIN_MM = 3.0
#: ChArUco views with fewer than this share of the board's corners are called partial
PARTIAL_SHARE = 0.5
CHI3_MEDIAN = float(np.sqrt(chi2.ppf(0.5, 3)))


@dataclass(frozen=True)
class Finding:
    code: str  # stable machine name, e.g. "translation_units"
    severity: str  # fail | warn | info
    title: str  # one line a person understands
    evidence: str  # the numbers that show it
    action: str  # what to do
    view_ids: tuple = ()
    details: dict = field(default_factory=dict)  # machine-readable numbers behind the evidence

    def __post_init__(self):
        if self.severity not in SEVERITIES:
            raise ValueError(f"severity must be one of {SEVERITIES}, got {self.severity!r}")


def _finding_dict(f: Finding) -> dict:
    d = asdict(f)
    d["view_ids"] = [str(v) for v in f.view_ids]
    d["details"] = _jsonable(f.details)
    return d


def _jsonable(o):
    return plain(o, nan_to_none=True)


def _ids_text(ids: Sequence[str], limit: int = 12) -> str:
    ids = [str(v) for v in ids]
    return ", ".join(ids[:limit]) + (f" and {len(ids) - limit} more" if len(ids) > limit else "")


def _axis_text(a: np.ndarray, frame: str) -> str:
    a = np.asarray(a, float) / max(np.linalg.norm(a), 1e-12)
    a = a if a[np.argmax(np.abs(a))] >= 0 else -a
    k = int(np.argmax(np.abs(a)))
    name = "xyz"[k]
    vec = "[" + ", ".join(f"{x:+.2f}" for x in a) + "]"
    if abs(a[k]) > 0.9:
        return f"the {frame} {name} axis {vec}"
    return f"{vec} in the {frame} frame"


# ------------------------------------------------------------------------------ readings
EULER_ORDERS = ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx", "xyx", "xzx", "yxy", "yzy", "zxz", "zyz")


def _fmt_text(fmt: PoseFormat) -> str:
    return fmt.describe()


def alternative_formats(fmt: PoseFormat) -> list[tuple[PoseFormat, tuple]]:
    """Every plausible reading of numbers written for ``fmt``: (format, changed aspects).

    Aspects: translation_units (m/mm), angle_units (rad/deg), euler_order (24 Euler conventions),
    quaternion_order (wxyz/xyzw). The first entry is ``fmt`` itself with no changes.
    """
    rot_variants: list[tuple[dict, tuple]] = [({}, ())]
    if fmt.rotation in ("euler", "rotvec"):
        other = "deg" if fmt.angle_unit == "rad" else "rad"
        rot_variants.append(({"angle_unit": other}, ("angle_units",)))
    if fmt.rotation == "euler":
        more = []
        for order, kind in product(EULER_ORDERS, ("extrinsic", "intrinsic")):
            if (order, kind) == (fmt.euler_order, fmt.euler_kind):
                continue
            for ch, codes in rot_variants[:2]:
                more.append((dict(ch, euler_order=order, euler_kind=kind), codes + ("euler_order",)))
        rot_variants += more
    if fmt.rotation == "quaternion":
        other = "xyzw" if fmt.quaternion_order == "wxyz" else "wxyz"
        rot_variants.append(({"quaternion_order": other}, ("quaternion_order",)))
    other_t = "mm" if fmt.translation_unit == "m" else "m"
    out = []
    for (ch, codes), t_alt in product(rot_variants, (False, True)):
        ch2 = dict(ch, translation_unit=other_t) if t_alt else ch
        out.append((replace(fmt, **ch2), (("translation_units",) if t_alt else ()) + codes))
    out.sort(key=lambda fc: len(fc[1]))
    return out


def _read_all(raw: RawPoses, fmt: PoseFormat, ids: Sequence[str]) -> Optional[np.ndarray]:
    """``T_base_end`` (N,4,4) of the views ``ids`` read with ``fmt`` (None if any pose does not parse).

    Vectorised for Euler angles and rotation vectors (same conversion as
    :func:`handeye.conventions.T_from_pose_values`, which handles the other forms)."""
    try:
        V = np.stack([np.asarray(raw.values[v], float).reshape(-1) for v in ids])
    except (KeyError, ValueError):
        return None
    if V.shape[1] != fmt.n_values or not np.all(np.isfinite(V)):
        return None
    if fmt.rotation in ("euler", "rotvec"):
        scale = 1e-3 if fmt.translation_unit == "mm" else 1.0
        if fmt.rotation == "euler":
            seq = fmt.euler_order.lower() if fmt.euler_kind == "extrinsic" else fmt.euler_order.upper()
            R = Rotation.from_euler(seq, V[:, 3:6], degrees=fmt.angle_unit == "deg").as_matrix()
        else:
            rv = np.radians(V[:, 3:6]) if fmt.angle_unit == "deg" else V[:, 3:6]
            R = Rotation.from_rotvec(rv).as_matrix()
        T = np.zeros((len(V), 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = V[:, :3] * scale
        T[:, 3, 3] = 1.0
        return T
    try:
        return np.stack([T_from_pose_values(V[k], fmt) for k in range(len(V))])
    except ValueError:
        return None


def _pair_angles_deg(R: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Rotation angle of R_i R_j^T for the pairs (fast, from the trace)."""
    tr = np.einsum("pab,pab->p", R[i], R[j])  # trace(R_i R_j^T)
    return np.degrees(np.arccos(np.clip(0.5 * (tr - 1.0), -1.0, 1.0)))


# ------------------------------------------------------------------------------ model fits
@dataclass(frozen=True)
class _Fit:
    A: np.ndarray
    B: np.ndarray  # (G,4,4) one board per group
    labels: np.ndarray  # (N,) group of each view
    board_rot_deg: np.ndarray  # (N,) implied board vs its group's board
    board_trans_mm: np.ndarray
    median_rot_deg: float
    median_trans_mm: float

    @property
    def cost(self) -> float:
        return float(np.hypot(self.median_rot_deg / COST_DEG, self.median_trans_mm / COST_MM))


def _fit(C: np.ndarray, M: np.ndarray, *, labels: Optional[np.ndarray] = None,
         use: Optional[np.ndarray] = None, robust: bool = True) -> _Fit:
    """Park & Martin on all pairs within a group (among views in ``use``), one board per group.

    ``robust``: refit twice without the views whose implied board is more than 3x the median
    deviation away, so a minority of wrong views does not tilt the fit of the others.
    """
    n = len(C)
    labels = np.zeros(n, int) if labels is None else np.asarray(labels)
    use0 = np.ones(n, bool) if use is None else np.asarray(use, bool)
    use = use0.copy()
    i, j = all_pairs(n)
    groups = np.unique(labels)
    gi = np.searchsorted(groups, labels)
    for rnd in range(3 if robust else 1):
        sel = (labels[i] == labels[j]) & use[i] & use[j]
        if sel.sum() < 3:
            break
        A = solve_A_from_pairs(C, M, (i[sel], j[sel]))
        Bs = implied_boards(A, C, M)
        B = np.stack([robust_mean_T(Bs[(labels == g) & use] if ((labels == g) & use).sum() else Bs[labels == g])
                      for g in groups])
        rot, trans = pose_differences(B[gi], Bs)
        d = np.hypot(rot / COST_DEG, trans / COST_MM)
        if float(np.median(d[use0])) > 10.0 * READING_BAD_COST:
            break  # hopeless: refitting without wild views cannot rescue this model
        new_use = use0 & (d <= max(3.0 * float(np.median(d[use0])), 0.05))
        if rnd == 2 or np.array_equal(new_use, use) or new_use.sum() < max(3, 0.5 * use0.sum()):
            break
        use = new_use
    return _Fit(A, B, labels, rot, trans, float(np.median(rot[use0])), float(np.median(trans[use0])))


def _plausible_reading_of_inverse(mode: str, fit: _Fit) -> str:
    """For a fit with inverted robot motions: "poses_inverted" or "mode_swapped", by which reading puts
    the camera near the flange (eye-in-hand-like: |t_X| < |t_board|) or beside the robot."""
    t_x = float(np.linalg.norm(inv_T(fit.A)[:3, 3]))
    t_b = float(np.linalg.norm(fit.B[0][:3, 3]))
    eih_like = t_x < t_b
    if mode == "eye_in_hand":
        return "poses_inverted" if eih_like else "mode_swapped"
    return "mode_swapped" if eih_like else "poses_inverted"


# ------------------------------------------------------------------------------ observations
@dataclass(frozen=True)
class _Obs:
    """What the pose-level detectors work on: views with a board pose, in session order."""

    mode: str
    ids: tuple
    C: np.ndarray  # (N,4,4) T_cam_board from PnP
    T: np.ndarray  # (N,4,4) reported T_base_end as loaded
    raw: RawPoses
    times: dict  # view id -> (t_image, t_pose) where recorded
    corners: tuple = ()  # per view (object_points (K,3), image_points (K,2)) for the PnP covariances
    intr: object = None
    target: object = None
    intrinsics_estimated: bool = True  # intrinsics come from these corners (their uncertainty counts)

    @property
    def n(self) -> int:
        return len(self.ids)

    def pnp_covariances(self) -> Optional[np.ndarray]:
        """(N,6,6) covariance of each view's board pose (left perturbation, camera frame), with the pixel
        noise taken robustly from all PnP residuals; None without corners."""
        from ..initial import project

        if not self.corners or self.intr is None:
            return None
        res = [np.linalg.norm(project(o, C, self.intr) - im, axis=1) for (o, im), C in zip(self.corners, self.C)]
        sigma_px = max(float(np.median(np.concatenate(res))) / RAYLEIGH_MEDIAN, 0.02)
        return camera_pose_covariances(self.corners, self.C, self.intr.K, self.intr.dist_array, sigma_px,
                                       intrinsics_estimated=self.intrinsics_estimated)

    def M(self, T: Optional[np.ndarray] = None, *, invert: bool = False) -> np.ndarray:
        M = mounting(self.mode).M_from_T_base_end(self.T if T is None else T)
        return inv_T(M) if invert else M


def _obs_from_run(run) -> Optional[_Obs]:
    s = run.session
    ids = [v.view_id for v in s.views if v.view_id in (run.board_poses or {})]
    if len(ids) < MIN_VIEWS_FAIL:
        return None
    C = np.stack([run.board_poses[v].T_cam_board for v in ids])
    T = np.stack([s.view(v).T_base_end for v in ids])
    times = {v.view_id: (v.t_image, v.t_pose) for v in s.views if v.t_image is not None and v.t_pose is not None}
    obj = s.target.object_points()
    corners = tuple((obj[run.board_poses[v].corner_ids], run.detections[v].image_points) for v in ids) \
        if run.detections and all(v in run.detections for v in ids) else ()
    estimated = not (s.intrinsics is not None and s.intrinsics_prior == "fixed")
    return _Obs(s.mode, tuple(ids), C, T, raw_poses_of(s), times, corners, run.intrinsics, s.target, estimated)


# ------------------------------------------------------------------------------ readings of the poses
@dataclass(frozen=True)
class _Reading:
    fmt: PoseFormat
    changes: tuple  # aspects changed w.r.t. the stated format
    invert: bool
    fit: _Fit
    angle_res_deg: float  # median rotation-angle invariant residual over pairs
    pitch_res_mm: float

    @property
    def codes(self) -> tuple:
        return self.changes + (("inverse",) if self.invert else ())

    def describe(self) -> str:
        return _fmt_text(self.fmt) + (", inverted" if self.invert else "")

    def row(self) -> dict:
        return {"reading": self.describe(), "changes": ", ".join(self.codes) or "as given",
                "board_scatter_deg": round(self.fit.median_rot_deg, 4),
                "board_scatter_mm": round(self.fit.median_trans_mm, 3),
                "pair_angle_residual_deg": round(self.angle_res_deg, 4),
                "pair_pitch_residual_mm": round(self.pitch_res_mm, 3) if np.isfinite(self.pitch_res_mm) else None,
                "cost": round(self.fit.cost, 3)}


def evaluate_readings(obs: _Obs, *, max_rotations: int = 16) -> list:
    """All plausible readings of the raw poses, best first (see :func:`alternative_formats`)."""
    fmt0 = obs.raw.fmt
    alts = alternative_formats(fmt0)
    # stage 1: rotation readings by the rotation-angle invariant (independent of translation units,
    # of inversion and of the mounting mode)
    rot_score: dict = {}
    pi, pj = all_pairs(obs.n)
    ang_c = _pair_angles_deg(obs.C[:, :3, :3], pi, pj)
    for fmt, _ in alts:
        key = replace(fmt, translation_unit=fmt0.translation_unit)
        if key in rot_score:
            continue
        T = _read_all(obs.raw, key, obs.ids)
        if T is None:
            rot_score[key] = np.inf
            continue
        rot_score[key] = float(np.median(np.abs(_pair_angles_deg(obs.M(T)[:, :3, :3], pi, pj) - ang_c)))
    # keep every rotation reading that ties with the best: readings of the form R' = U R^T V (some Euler
    # misreadings) keep all pair angles, and only the full fit tells them apart
    ranked = sorted(rot_score, key=rot_score.get)
    best = rot_score[ranked[0]]
    keep = {k for k in ranked[:max_rotations] if rot_score[k] <= max(2.0 * best, best + 0.1)}
    keep |= set(ranked[:2]) | {replace(fmt0)}
    out = []
    for fmt, changes in alts:
        if replace(fmt, translation_unit=fmt0.translation_unit) not in keep:
            continue
        T = _read_all(obs.raw, fmt, obs.ids)
        if T is None:
            continue
        s = summarize_invariants(pair_invariants(obs.C, obs.M(T)))  # the same for inverted motions
        for invert in (False, True):
            M = obs.M(T, invert=invert)
            try:
                fit = _fit(obs.C, M)
            except np.linalg.LinAlgError:
                continue
            out.append(_Reading(fmt, changes, invert, fit, s["median_angle_res_deg"], s["median_pitch_res_mm"]))
    out.sort(key=lambda r: (r.fit.cost, len(r.codes)))
    return out


def _given(readings: list) -> Optional[_Reading]:
    return next((r for r in readings if not r.changes and not r.invert), None)


def _reading_is_wrong(given: _Reading, best: _Reading) -> bool:
    return (given.fit.cost > READING_BAD_COST and best.fit.cost < READING_GOOD_COST
            and best.fit.cost * READING_RATIO < given.fit.cost)


def _format_snippet(fmt: PoseFormat) -> str:
    if fmt.rotation == "euler":
        return (f"pose_format: {{rotation: euler, euler_order: {fmt.euler_order}, euler_kind: {fmt.euler_kind}, "
                f"angle_unit: {fmt.angle_unit}, translation_unit: {fmt.translation_unit}}}")
    if fmt.rotation == "quaternion":
        return (f"pose_format: {{rotation: quaternion, quaternion_order: {fmt.quaternion_order}, "
                f"translation_unit: {fmt.translation_unit}}}")
    if fmt.rotation == "rotvec":
        return f"pose_format: {{rotation: rotvec, angle_unit: {fmt.angle_unit}, translation_unit: {fmt.translation_unit}}}"
    return f"pose_format: {{rotation: matrix, translation_unit: {fmt.translation_unit}}}"


def _pitch_scale(obs: _Obs, fmt_read: PoseFormat, fmt_true: PoseFormat) -> Optional[float]:
    """Median ratio camera pitch / robot pitch under a reading (how far off the translation scale is)."""
    T = _read_all(obs.raw, replace(fmt_read, **{k: getattr(fmt_true, k) for k in
                                                ("rotation", "euler_order", "euler_kind", "angle_unit",
                                                 "quaternion_order")}), obs.ids)
    if T is None:
        return None
    M = obs.M(T)
    i, j = all_pairs(obs.n)
    rc, rm = obs.C[i] @ inv_T(obs.C[j]), M[i] @ inv_T(M[j])
    rv_c = Rotation.from_matrix(rc[:, :3, :3]).as_rotvec()
    rv_m = Rotation.from_matrix(rm[:, :3, :3]).as_rotvec()
    a = np.linalg.norm(rv_m, axis=1)
    pc = np.einsum("ni,ni->n", rv_c / np.maximum(np.linalg.norm(rv_c, axis=1), 1e-12)[:, None], rc[:, :3, 3])
    pm = np.einsum("ni,ni->n", rv_m / np.maximum(a, 1e-12)[:, None], rm[:, :3, 3])
    ok = (a > np.radians(12)) & (a < np.radians(165)) & (np.abs(pm) > 1e-9)
    if ok.sum() < 3:
        return None
    big = ok & (np.abs(pc) > np.quantile(np.abs(pc[ok]), 0.5))
    return float(np.median(pc[big] / pm[big])) if big.sum() >= 2 else None


def reading_findings(obs: _Obs, readings: list, *, session_kind: str = "native") -> list:
    """Findings for a wrong reading of the poses (units, Euler convention, inversion, mode)."""
    given = _given(readings)
    if given is None or not readings:
        return []
    best = readings[0]
    if best is given or not _reading_is_wrong(given, best):
        return []
    fmt0 = obs.raw.fmt
    rivals = [r for r in readings[1:] if r.fit.cost < 1.5 * best.fit.cost and r.codes != best.codes][:3]
    ev = (f"as given ({given.describe()}): the board implied by each view scatters by {given.fit.median_rot_deg:.2f} deg"
          f" / {given.fit.median_trans_mm:.1f} mm (median), robot and camera rotation angles differ by "
          f"{given.angle_res_deg:.2f} deg (median over {obs.n * (obs.n - 1) // 2} view pairs); read as "
          f"{best.describe()}: {best.fit.median_rot_deg:.3f} deg / {best.fit.median_trans_mm:.2f} mm, "
          f"{best.angle_res_deg:.3f} deg")
    if rivals:
        ev += "; about as good: " + "; ".join(f"{r.describe()} ({r.fit.median_rot_deg:.3f} deg / "
                                              f"{r.fit.median_trans_mm:.2f} mm)" for r in rivals)
    details = {"given": given.row(), "best": best.row(), "rivals": [r.row() for r in rivals]}
    fix_fmt = ("convert the poses file to the vendor format (x, y, z in metres; rx, ry, rz in radians, "
               f"R = Rz·Ry·Rx) or describe it in a session.yaml with {_format_snippet(best.fmt)}"
               if session_kind == "vendor" else f"state the format in session.yaml: {_format_snippet(best.fmt)}")
    out = []
    for code in best.changes:
        if code == "translation_units":
            scale = _pitch_scale(obs, fmt0, best.fmt)
            title = ("Robot translations are in millimetres but were read as metres" if best.fmt.translation_unit == "mm"
                     else "Robot translations are in metres but were read as millimetres")
            if scale:
                e = ev + (f"; as given, the robot moves {1 / scale:.4g} x farther along its rotation axes than the "
                          f"camera saw" if abs(scale) < 1 else
                          f"; as given, the camera saw {scale:.4g} x more motion along the rotation axes than the "
                          f"robot reports")
            else:
                e = ev
            out.append(Finding("translation_units", "fail", title, e, fix_fmt,
                               details=dict(details, camera_over_robot_pitch=scale)))
        elif code == "angle_units":
            title = ("Robot angles are in degrees but were read as radians" if best.fmt.angle_unit == "deg"
                     else "Robot angles are in radians but were read as degrees")
            out.append(Finding("angle_units", "fail", title, ev, fix_fmt, details=details))
        elif code == "euler_order":
            title = (f"Robot angles follow another Euler convention: {best.fmt.euler_kind} {best.fmt.euler_order} "
                     f"(read as {fmt0.euler_kind} {fmt0.euler_order})")
            out.append(Finding("euler_order", "fail", title, ev, fix_fmt, details=details))
        elif code == "quaternion_order":
            title = f"Quaternions are written {best.fmt.quaternion_order}, read as {fmt0.quaternion_order}"
            out.append(Finding("quaternion_order", "fail", title, ev, fix_fmt, details=details))
    if best.invert:
        kind = _plausible_reading_of_inverse(obs.mode, best.fit)
        other = "eye_to_hand" if obs.mode == "eye_in_hand" else "eye_in_hand"
        t_x = 1e3 * float(np.linalg.norm(inv_T(best.fit.A)[:3, 3]))
        t_b = 1e3 * float(np.linalg.norm(best.fit.B[0][:3, 3]))
        e = ev + (f"; with the inverted motions the camera sits {t_x:.0f} mm from the "
                  f"{mounting(obs.mode).fixed_frame if kind == 'poses_inverted' else mounting(other).fixed_frame} "
                  f"origin and the board {t_b:.0f} mm from the "
                  f"{mounting(obs.mode).board_frame if kind == 'poses_inverted' else mounting(other).board_frame} origin")
        if kind == "poses_inverted":
            out.append(Finding("poses_inverted", "fail",
                               "Robot poses are inverted (the pose of the base in the flange, T_end_base, "
                               "instead of the flange in the base)", e + " (calibrating as "
                               f"{other} would fit equally, but puts the camera implausibly)",
                               "write each robot pose as the flange in the base frame (T_base_end), i.e. invert "
                               "them, or export the other pose from the robot controller", details=details))
        else:
            out.append(Finding("mode_swapped", "fail",
                               f"The data are {other.replace('_', '-')} but were calibrated as "
                               f"{obs.mode.replace('_', '-')}",
                               e + " (inverted robot poses would fit equally, but put the camera implausibly)",
                               f"calibrate with --mode {other} (or set mode: {other} in the session)",
                               details=details))
    return out


# ------------------------------------------------------------------------------ pairing of images and poses
def _shifted(obs: _Obs, fmt: PoseFormat, shift: int) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(views kept (bool N), T (K,4,4)) when the image at sequence position p takes the pose at p+shift."""
    order = obs.raw.order
    pos = {v: k for k, v in enumerate(order)}
    keep = np.array([v in pos and 0 <= pos[v] + shift < len(order) for v in obs.ids])
    keys = [order[pos[v] + shift] for v, k in zip(obs.ids, keep) if k]
    return keep, _read_all(obs.raw, fmt, keys)


def _assignment_by_signature(obs: _Obs, fmt: PoseFormat, invert: bool) -> Optional[dict]:
    """Match images to poses by their sorted pair-rotation-angle signatures (a shuffled poses file).

    Returns view id -> pose key, or None. Angles of relative motions do not depend on A or B, so the
    sorted list of a view's angles to all others identifies its pose up to noise."""
    order = list(obs.raw.order)
    T_all = _read_all(obs.raw, fmt, order)
    if T_all is None or obs.n < 5:
        return None
    M_all = obs.M(T_all, invert=invert)
    R_c = obs.C[:, :3, :3]
    R_m = M_all[:, :3, :3]

    def angles(R):
        rel = np.einsum("aij,bkj->abik", R, R)  # R_a R_b^T
        return np.degrees(np.linalg.norm(Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec(), axis=1)).reshape(
            len(R), len(R))

    A_c, A_m = angles(R_c), angles(R_m)
    sig_c = [np.sort(np.delete(A_c[i], i)) for i in range(obs.n)]
    sig_m = [np.sort(np.delete(A_m[p], p)) for p in range(len(order))]
    cost = np.empty((obs.n, len(order)))
    for i in range(obs.n):
        for p in range(len(order)):
            # every camera angle must appear among the pose's angles (poses may have more views)
            d = np.abs(sig_c[i][:, None] - sig_m[p][None, :]).min(axis=1)
            cost[i, p] = float(np.mean(d))
    r, c = linear_sum_assignment(cost)
    return {obs.ids[i]: order[p] for i, p in zip(r, c)}


def pairing_findings(obs: _Obs, fmt: PoseFormat, *, invert: bool = False, given_cost: float) -> list:
    """Images and poses out of step (shift by +-1..5) or shuffled."""
    if given_cost <= READING_BAD_COST:
        return []
    kmax = min(MAX_SHIFT, max(1, len(obs.raw.order) // 3))
    best = None
    for s in range(-kmax, kmax + 1):
        if s == 0:
            continue
        keep, T = _shifted(obs, fmt, s)
        if T is None or keep.sum() < max(4, int(np.ceil(0.6 * obs.n))):
            continue
        fit = _fit(obs.C[keep], obs.M(T, invert=invert))
        if best is None or fit.cost < best[1].cost:
            best = (s, fit, keep)
    if best is not None and best[1].cost < READING_GOOD_COST and best[1].cost * READING_RATIO < given_cost:
        s, fit, keep = best
        direction = f"+{s}" if s > 0 else str(s)
        kind_hint = (f"the first {s} pose line(s) belong to no image: delete them" if s > 0 else
                     f"the pose(s) of the first {-s} image(s) are missing: pose line 1 holds image {1 - s}'s pose")
        return [Finding(
            "pairs_shifted", "fail", f"Images and robot poses are out of step by {abs(s)}: image k belongs to pose "
                                     f"k{direction}",
            f"pairing image k with pose k{direction}: board scatter {fit.median_rot_deg:.3f} deg / "
            f"{fit.median_trans_mm:.2f} mm (median over {int(keep.sum())} views) against "
            f"{given_cost:.1f} (cost) as paired now",
            f"re-pair the poses with the images ({kind_hint}); capture poses and images together, by view id",
            details={"shift": s, "views_compared": int(keep.sum()), "board_scatter_deg": fit.median_rot_deg,
                     "board_scatter_mm": fit.median_trans_mm})]
    # a shuffle: match by signature, then check the matched pairing with a full fit
    assign = _assignment_by_signature(obs, fmt, invert)
    if assign is None:
        return []
    moved = [v for v in obs.ids if assign[v] != v]
    T = _read_all(obs.raw, fmt, [assign[v] for v in obs.ids])
    if T is None or len(moved) < 2:
        return []
    fit = _fit(obs.C, obs.M(T, invert=invert))
    if fit.cost < READING_GOOD_COST and fit.cost * READING_RATIO < given_cost:
        pairs = ", ".join(f"image {v} <- pose {assign[v]}" for v in moved[:10])
        return [Finding(
            "pairs_shifted", "fail", f"Images and robot poses are shuffled: {len(moved)} of {obs.n} images carry "
                                     "another view's pose",
            f"matched by the rotation angles between views: {pairs}{' ...' if len(moved) > 10 else ''}; with this "
            f"pairing the board scatters by {fit.median_rot_deg:.3f} deg / {fit.median_trans_mm:.2f} mm (median) "
            f"against a cost of {given_cost:.1f} as paired now",
            "re-pair images and poses by view id (the recording lost the order); re-capture if unsure",
            view_ids=tuple(moved), details={"assignment": {v: assign[v] for v in moved},
                                            "board_scatter_deg": fit.median_rot_deg,
                                            "board_scatter_mm": fit.median_trans_mm})]
    return []


# ------------------------------------------------------------------------------ per view: robot vs camera
def view_disagreements(mode: str, fit: _Fit, C: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rot_deg, trans_mm) per view between the reported robot pose and the one the camera implies
    (``M_i* = inv(A) C_i inv(B)``), as ``inv(T_reported) T_implied`` (end frame)."""
    mm = mounting(mode)
    gi = np.searchsorted(np.unique(fit.labels), fit.labels)
    M_star = inv_T(fit.A) @ C @ inv_T(fit.B[gi])
    return pose_differences(T, mm.T_base_end_from_M(M_star))


def robot_pose_test(obs: _Obs, fit: _Fit, T: np.ndarray, *, inliers: np.ndarray,
                    covs: Optional[np.ndarray] = None) -> dict:
    """Per-view test of the reported robot pose against the one the camera implies.

    The disagreement ``e_i = Log(inv(T_reported) T_implied)`` (end frame) is compared with its covariance:
    the view's PnP covariance propagated to the implied pose, plus isotropic robot noise (rotation and
    translation) estimated robustly from the inlier views (median Mahalanobis = chi-square median).
    Without corners, the covariance is the robust isotropic spread of the inliers alone.
    Returns rot_deg, trans_mm, distance (sigmas), flags, threshold and the noise levels.
    """
    mm = mounting(obs.mode)
    gi = np.searchsorted(np.unique(fit.labels), fit.labels)
    A_inv = inv_T(fit.A)
    B_inv = inv_T(fit.B[gi])
    T_star = mm.T_base_end_from_M(A_inv @ obs.C @ B_inv)
    e = log6(inv_T(T) @ T_star)  # (N,6)
    rot = np.degrees(np.linalg.norm(e[:, :3], axis=1))
    trans = 1e3 * np.linalg.norm(e[:, 3:], axis=1)
    if covs is not None:
        P = np.stack([propagate(lambda C, k=k: mm.T_base_end_from_M(A_inv @ C @ B_inv[k]), obs.C[k], covs[k])
                      for k in range(obs.n)])
    else:
        P = np.zeros((obs.n, 6, 6))
    use = inliers if inliers.sum() >= 3 else np.ones(obs.n, bool)
    s_rot = robust_noise_sigma(e[use, :3], P[use][:, :3, :3], floor=np.radians(SCALE_FLOOR_DEG))
    s_tr = robust_noise_sigma(e[use, 3:], P[use][:, 3:, 3:], floor=SCALE_FLOOR_MM / 1e3)
    Ct = P + np.diag([s_rot ** 2] * 3 + [s_tr ** 2] * 3)
    d2 = np.einsum("ni,ni->n", e, np.linalg.solve(Ct, e[..., None])[..., 0])
    thr = float(chi2.ppf(1.0 - VIEW_OUTLIER_P, 6))
    # and the disagreement must stand out from the others' in size (the covariance model is approximate)
    med_rot = max(float(np.median(rot[use])), SCALE_FLOOR_DEG)
    med_tr = max(float(np.median(trans[use])), SCALE_FLOOR_MM)
    ratio = np.maximum(rot / med_rot, trans / med_tr)
    ratio_thr = VIEW_OUTLIER_RATIO * (1.0 + 2.5 / max(int(use.sum()), 1))  # medians of few views are noisy
    flags = (d2 > thr) & (ratio > ratio_thr) & ((rot > VIEW_OUTLIER_MIN_DEG) | (trans > VIEW_OUTLIER_MIN_MM))
    return {"rot_deg": rot, "trans_mm": trans, "distance": np.sqrt(d2), "flags": flags, "size_ratio": ratio,
            "threshold_sigmas": float(np.sqrt(thr)), "robot_sigma_deg": float(np.degrees(s_rot)),
            "robot_sigma_mm": float(1e3 * s_tr), "with_camera_covariance": covs is not None}


def _board_deviations(fit: _Fit, C: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(N,6) implied board of each view against the first group's board: rotation vector [deg], translation
    difference [mm] along the board's parent frame."""
    Bs = implied_boards(fit.A, C, M)
    B0 = fit.B[0]
    rv = Rotation.from_matrix(np.swapaxes(B0[:3, :3], 0, 1) @ Bs[:, :3, :3]).as_rotvec()
    return np.concatenate([np.degrees(rv), 1e3 * (Bs[:, :3, 3] - B0[:3, 3])], axis=1)


def _step_test(v: np.ndarray, labels: np.ndarray, use: np.ndarray) -> tuple[float, float]:
    """Hotelling's two-sample test of equal mean board in the two segments: (T^2, p-value).

    The pooled within-segment covariance of the implied boards (6-D) is the noise; the p-value is
    from ``T^2 (nu - 5) / (6 nu) ~ F(6, nu - 5)``, ``nu = n0 + n1 - 2``."""
    from scipy.stats import f as f_dist

    a, b = v[(labels == 0) & use], v[(labels == 1) & use]
    n0, n1 = len(a), len(b)
    nu = n0 + n1 - 2
    if n0 < 2 or n1 < 2 or nu < 7:
        return 0.0, 1.0
    S = ((a - a.mean(0)).T @ (a - a.mean(0)) + (b - b.mean(0)).T @ (b - b.mean(0))) / nu
    S += np.diag(np.maximum(np.diag(S), 1e-12)) * 1e-6
    d = a.mean(0) - b.mean(0)
    try:
        t2 = float(n0 * n1 / (n0 + n1) * d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return 0.0, 1.0
    F = t2 * (nu - 5) / (6 * nu)
    return t2, float(f_dist.sf(F, 6, nu - 5))


def _split_fits(obs: _Obs, M: np.ndarray):
    """Best two-segment split of the view sequence (one board per segment), or None.

    Returns (single fit, its score, (split score, k, split fit, p-value)); the score is the sum of the
    views' capped board deviations (small is good)."""
    n = obs.n
    if n < 2 * STEP_MIN_SEGMENT:
        return None
    single = _fit(obs.C, M)
    d1 = np.hypot(single.board_rot_deg / COST_DEG, single.board_trans_mm / COST_MM)
    cap = 10.0 * max(float(np.median(d1)), 0.05)
    best = None
    for k in range(STEP_MIN_SEGMENT, n - STEP_MIN_SEGMENT + 1):
        labels = (np.arange(n) >= k).astype(int)
        try:
            f = _fit(obs.C, M, labels=labels)
        except np.linalg.LinAlgError:
            continue
        d = np.hypot(f.board_rot_deg / COST_DEG, f.board_trans_mm / COST_MM)
        use = d <= max(3.0 * float(np.median(d)), 0.05)
        _, p = _step_test(_board_deviations(f, obs.C, M), labels, use)
        score = float(np.sum(np.minimum(d, cap)))
        key = (p, score)
        if best is None or key < best[0]:
            best = (key, (score, k, f, p))
    if best is None:
        return None
    return single, float(np.sum(np.minimum(d1, cap))), best[1]


def board_moved_findings(obs: _Obs, M: np.ndarray) -> tuple[list, Optional[_Fit]]:
    """A step in the implied board transform: (findings, segment fit to use for the other checks)."""
    r = _split_fits(obs, M)
    if r is None:
        return [], None
    single, s1, (s2, k, f, p) = r
    step_rot, step_mm = (float(x[0]) for x in pose_differences(f.B[0], f.B[1]))
    within_rot = float(np.median(f.board_rot_deg))
    within_mm = float(np.median(f.board_trans_mm))
    big = (step_rot > max(STEP_MIN_DEG, 3 * within_rot)) or (step_mm > max(STEP_MIN_MM, 3 * within_mm))
    n_splits = obs.n - 2 * STEP_MIN_SEGMENT + 1
    significant = p < STEP_P / n_splits if p < 1.0 else s1 > STEP_GAIN * s2
    if not (significant and big and s1 > STEP_MIN_GAIN * s2):
        return [], None
    mode = obs.mode
    before, after = obs.ids[:k], obs.ids[k:]
    minority = after if len(after) <= len(before) else before
    if mode == "eye_in_hand":
        code_title = f"The board moved on the table between views {obs.ids[k - 1]} and {obs.ids[k]}"
        action = ("fix the board (clamp or tape it) and re-capture, or calibrate the views before and after the "
                  "move as separate sessions")
    else:
        code_title = f"The board slipped in the gripper between views {obs.ids[k - 1]} and {obs.ids[k]}"
        action = "clamp the board rigidly to the flange and re-capture, or calibrate each part as its own session"
    ev = (f"views {before[0]}..{before[-1]} and {after[0]}..{after[-1]} each fit one board "
          f"(median scatter {within_rot:.3f} deg / {within_mm:.2f} mm) but the two boards differ by "
          f"{step_rot:.2f} deg / {step_mm:.1f} mm; one board for all views leaves "
          f"{single.median_rot_deg:.2f} deg / {single.median_trans_mm:.1f} mm (median); the split explains the "
          f"views {s1 / max(s2, 1e-9):.1f}x better" + (f" (two-sample test of the boards: p = {p:.1e})" if p < 1.0
                                                       else ""))
    fnd = Finding("board_moved", "fail", code_title, ev, action, view_ids=tuple(minority),
                  details={"split_after_view": obs.ids[k - 1], "step_deg": step_rot, "step_mm": step_mm,
                           "within_deg": within_rot, "within_mm": within_mm, "p_value": p})
    return [fnd], f


def _board_turns(target) -> list:
    """Board-frame transforms (name, F) for a detector's corner numbering turned by 180 (or 90) degrees:
    the true ``T_cam_board`` is ``C @ F`` when the corners were numbered from the other end."""
    from ..targets import ChessboardSpec

    if not isinstance(target, ChessboardSpec):
        return []
    L = target.square_m
    c = np.array([(target.cols - 1) * L / 2.0, (target.rows - 1) * L / 2.0, 0.0])
    turns = [("180 deg", np.pi)] + ([("90 deg", np.pi / 2), ("-90 deg", -np.pi / 2)] if target.cols == target.rows
                                    else [])
    out = []
    for name, a in turns:
        R = Rotation.from_rotvec([0.0, 0.0, a]).as_matrix()
        F = np.eye(4)
        F[:3, :3] = R
        F[:3, 3] = c - R @ c
        out.append((name, F))
    return out


def robot_pose_findings(obs: _Obs, M: np.ndarray, fit: _Fit, *, refined=None, exclude: Sequence[str] = (),
                        fmt: Optional[PoseFormat] = None) -> list:
    """Views whose reported robot pose disagrees with the camera (and swapped pairs among them)."""
    d = np.hypot(fit.board_rot_deg / COST_DEG, fit.board_trans_mm / COST_MM)
    inliers = d <= max(3.0 * float(np.median(d)), 0.05)
    if inliers.sum() < 3:
        inliers = np.ones(obs.n, bool)
    covs = obs.pnp_covariances()
    test = robot_pose_test(obs, fit, obs.T, inliers=inliers, covs=covs)
    rot, trans, flags = test["rot_deg"], test["trans_mm"], test["flags"]
    idx = {v: k for k, v in enumerate(obs.ids)}
    ref_flags = {}
    if (refined is not None and getattr(refined, "status", "") == "ok"
            and getattr(getattr(refined, "options", None), "outlier_loop", True)):
        for o in getattr(refined, "outliers", ()):
            if getattr(o, "kind", "") == "robot_pose":
                ref_flags[o.view_id] = o
        flagged = [v for v in obs.ids if v in ref_flags]
        source = "the refinement's robot-pose test (Mahalanobis distance with the estimated robot and pixel noise)"
    else:
        flagged = [v for v, f in zip(obs.ids, flags) if f]
        source = (f"a robust fit without the wild views: beyond {test['threshold_sigmas']:.1f} sigma of each view's "
                  f"camera uncertainty plus robot noise ({test['robot_sigma_deg']:.3f} deg, "
                  f"{test['robot_sigma_mm']:.2f} mm per axis, estimated from the other views)")
    flagged = [v for v in flagged if v not in set(exclude)]
    out = []
    # a detector that numbered the corners from the other end (the board turned by 180 or 90 degrees)
    flipped = {}
    for v in flagged:
        for name, F in _board_turns(obs.target):
            C2 = obs.C.copy()
            C2[idx[v]] = obs.C[idx[v]] @ F
            t2 = robot_pose_test(replace(obs, C=C2), fit, obs.T, inliers=inliers, covs=covs)
            if not t2["flags"][idx[v]] and t2["rot_deg"][idx[v]] < 0.5 * rot[idx[v]]:
                flipped[v] = (name, float(t2["rot_deg"][idx[v]]), float(t2["trans_mm"][idx[v]]))
                break
    if flipped:
        vs = list(flipped)
        out.append(Finding(
            "corner_order_flipped", "warn",
            f"The corners were numbered from the other end of the board in {len(vs)} view(s): {_ids_text(vs)}",
            "; ".join(f"view {v}: camera and robot disagree by {rot[idx[v]]:.1f} deg / {trans[idx[v]]:.0f} mm, with the "
                      f"board turned by {flipped[v][0]} they agree to {flipped[v][1]:.2f} deg / {flipped[v][2]:.1f} mm"
                      for v in vs),
            "the detector cannot tell this board's orientation in these views; use a ChArUco board (or a chessboard "
            "with a mark) or leave these views out; the robot poses are fine",
            view_ids=tuple(vs), details={"turns": {v: flipped[v][0] for v in vs}}))
    flagged = [v for v in flagged if v not in flipped]
    # poses that belong to another view: two detected views swapped, or an image carrying the pose recorded
    # for a view whose image was not usable
    swapped = set()
    if fmt is not None and 1 <= len(flagged) <= 8:
        all_keys = [k for k in obs.raw.order if k in obs.raw.values]
        T_all = _read_all(obs.raw, fmt, all_keys)
        for a in flagged:
            if a in swapped or T_all is None:
                continue
            fits = []
            for key, T_k in zip(all_keys, T_all):
                if key == a:
                    continue
                T_try = obs.T.copy()
                T_try[idx[a]] = T_k
                t_try = robot_pose_test(obs, fit, T_try, inliers=inliers, covs=covs)
                if not t_try["flags"][idx[a]] and t_try["distance"][idx[a]] < 0.5 * test["distance"][idx[a]]:
                    fits.append((key, float(t_try["rot_deg"][idx[a]]), float(t_try["trans_mm"][idx[a]])))
            if len(fits) != 1:
                continue
            b, r_b, t_b = fits[0]
            if b in idx and b in flagged and b not in swapped:
                T_sw = obs.T.copy()
                T_sw[[idx[a], idx[b]]] = obs.T[[idx[b], idx[a]]]
                t_sw = robot_pose_test(obs, fit, T_sw, inliers=inliers, covs=covs)
                if t_sw["flags"][idx[b]]:
                    continue
                swapped |= {a, b}
                out.append(Finding(
                    "pairs_shifted", "fail", f"The robot poses of views {a} and {b} are swapped",
                    f"view {a} disagrees with its own pose by {rot[idx[a]]:.2f} deg / {trans[idx[a]]:.1f} mm and "
                    f"view {b} by {rot[idx[b]]:.2f} deg / {trans[idx[b]]:.1f} mm; with each other's pose they "
                    f"agree ({t_sw['rot_deg'][idx[a]]:.3f} deg / {t_sw['trans_mm'][idx[a]]:.2f} mm and "
                    f"{t_sw['rot_deg'][idx[b]]:.3f} deg / {t_sw['trans_mm'][idx[b]]:.2f} mm)",
                    "swap the two pose entries (and pair images and poses by view id when recording)",
                    view_ids=(a, b), details={"swapped": [a, b]}))
            elif b not in idx:
                swapped.add(a)
                out.append(Finding(
                    "pairs_shifted", "fail", f"View {a}'s image carries the robot pose recorded for view {b}",
                    f"view {a} disagrees with its own pose by {rot[idx[a]]:.2f} deg / {trans[idx[a]]:.1f} mm but agrees "
                    f"with the pose of view {b} ({r_b:.3f} deg / {t_b:.2f} mm), whose image was not used",
                    f"swap the pose entries of views {a} and {b} (and pair images and poses by view id when "
                    "recording)", view_ids=(a, b), details={"swapped": [a, b]}))
    rest = [v for v in flagged if v not in swapped]
    if rest:
        parts = []
        for v in rest:
            k = idx[v]
            txt = f"view {v}: {rot[k]:.2f} deg / {trans[k]:.1f} mm ({test['distance'][k]:.0f} sigma)"
            if v in ref_flags and getattr(ref_flags[v], "size", None):
                sz = ref_flags[v].size
                txt += f" (refinement: {sz.get('rot_deg', float('nan')):.2f} deg / {sz.get('trans_mm', float('nan')):.1f} mm"
                txt += f", {sz.get('mahalanobis', float('nan')):.1f} sigma)" if "mahalanobis" in sz else ")"
            if v in obs.times:
                ti, tp = obs.times[v]
                txt += f", image and pose {1e3 * abs(ti - tp):.0f} ms apart"
            parts.append(txt)
        typical = (f"the other views agree to {float(np.median(rot[inliers])):.3f} deg / "
                   f"{float(np.median(trans[inliers])):.2f} mm (median)")
        sev = "warn" if len(rest) <= max(1, int(0.2 * obs.n)) else "fail"
        out.append(Finding(
            "robot_pose_disagrees", sev,
            f"{len(rest)} view(s) where the robot pose disagrees with what the camera saw: {_ids_text(rest)}",
            "reported vs camera-implied robot pose, " + "; ".join(parts) + f"; {typical}; flagged by {source}",
            "check these views: was the robot still moving at capture (wait for it to settle), did the board or the "
            "camera move, is the pose from another view? Re-capture them or leave them out",
            view_ids=tuple(rest),
            details={"per_view": {v: {"rot_deg": float(rot[idx[v]]), "trans_mm": float(trans[idx[v]])} for v in rest},
                     "inlier_median_deg": float(np.median(rot[inliers])),
                     "inlier_median_mm": float(np.median(trans[inliers])), "source": source}))
    return out


# ------------------------------------------------------------------------------ motion and view count
def motion_findings(mode: str, M: np.ndarray, *, A: Optional[np.ndarray] = None) -> list:
    """Weak or degenerate robot motion (small rotations, one rotation axis), too few views."""
    from ..initial import motion_quality

    n = len(M)
    out = []
    if n < MIN_VIEWS_WARN:
        sev = "fail" if n < MIN_VIEWS_FAIL else "warn"
        out.append(Finding("too_few_views", sev, f"Only {n} usable views",
                           f"{n} views with the board found and a robot pose; the hand-eye solution needs at least "
                           f"{MIN_VIEWS_FAIL}, and {RECOMMENDED_VIEWS}-20 give redundancy to check them",
                           f"capture {RECOMMENDED_VIEWS - n} or more views, tilted 20-45 deg about different axes"))
    elif n < RECOMMENDED_VIEWS:
        out.append(Finding("too_few_views", "info", f"{n} usable views; {RECOMMENDED_VIEWS}-20 are recommended",
                           f"{n} views: outlier checks and cross-validation have little redundancy",
                           f"add {RECOMMENDED_VIEWS - n} or more views, tilted about different axes"))
    if n < MIN_VIEWS_FAIL:
        return out
    mm = mounting(mode)
    mq = motion_quality(M, frame=mm.fixed_frame)
    frame = mm.fixed_frame
    weak = mq.weak_axes  # (2,3): the least-rotated directions, weakest first
    add = "add views rotated 20-45 deg about " + _rotations_to_add(M, frame)
    if A is not None:
        add += " (in the camera frame: about " + _rotations_to_add(M, "camera", R=A[:3, :3]) + ")"
    details = {"max_rotation_deg": mq.max_rotation_deg, "axis_spread_deg": mq.axis_spread_deg,
               "main_axis": mq.main_axis, "weak_axes": weak, "frame": frame}
    ev = (f"largest rotation between two views {mq.max_rotation_deg:.1f} deg, rotation axes spread "
          f"{mq.axis_spread_deg:.1f} deg around {_axis_text(mq.main_axis, frame)} ({n} views)")
    if mq.max_rotation_deg < MOTION_FAIL_ROT_DEG or mq.axis_spread_deg < MOTION_FAIL_SPREAD_DEG:
        what = ("the robot barely rotates between views" if mq.max_rotation_deg < MOTION_FAIL_ROT_DEG
                else "all rotations are about one axis")
        out.append(Finding("weak_motion", "fail", f"Degenerate motion: {what}; the hand-eye transform is not "
                                                  "determined", ev + f"; needs >= {MOTION_FAIL_ROT_DEG:g} deg and a "
                                                  f"spread >= {MOTION_FAIL_SPREAD_DEG:g} deg", add, details=details))
    elif mq.max_rotation_deg < MOTION_WARN_ROT_DEG or mq.axis_spread_deg < MOTION_WARN_SPREAD_DEG:
        what = ("small rotations between views" if mq.max_rotation_deg < MOTION_WARN_ROT_DEG
                else "rotation axes nearly parallel")
        out.append(Finding("weak_motion", "warn", f"Weak motion: {what}; the result is poorly constrained",
                           ev + f"; recommended >= {MOTION_WARN_ROT_DEG:g} deg and a spread >= "
                                f"{MOTION_WARN_SPREAD_DEG:g} deg", add, details=details))
    return out


def _rotations_to_add(M: np.ndarray, frame: str, *, R: Optional[np.ndarray] = None) -> str:
    """The axes the relative robot rotations lack, in words (``R`` maps them into another frame).

    When the two least-rotated directions are about equally weak (all rotations about one axis), any
    two axes across the main axis will do: name the frame's axes closest to that plane."""
    n = len(M)
    i, j = all_pairs(n)
    rv = Rotation.from_matrix((M[i] @ inv_T(M[j]))[:, :3, :3]).as_rotvec()
    ang = np.linalg.norm(rv, axis=1)
    W = rv * np.minimum(ang, np.pi / 2)[:, None] / np.maximum(ang, 1e-12)[:, None]
    ev, V = np.linalg.eigh(W.T @ W)  # ascending
    if R is not None:
        V = R @ V
    weak1, weak2, main = V[:, 0], V[:, 1], V[:, 2]
    if ev[1] < 4.0 * max(ev[0], 1e-12 * max(ev[2], 1e-12)):  # a weak plane: rotations about one axis only
        k = int(np.argmax(np.abs(main)))
        if abs(main[k]) > 0.9:
            a, b = [name for m, name in enumerate("xyz") if m != k]
            return f"the {frame} {a} axis and the {frame} {b} axis (across the {frame} {'xyz'[k]} axis, the only one used)"
        return (f"two axes across {_axis_text(main, frame)} (the only one used), e.g. {_axis_text(weak1, frame)} and "
                f"{_axis_text(weak2, frame)}")
    return f"{_axis_text(weak1, frame)}"


# ------------------------------------------------------------------------------ detection outcomes
def _image_r2_max(intr) -> float:
    """Largest squared undistorted normalized radius inside the image (the lens model's valid range)."""
    import cv2

    W, H = intr.width, intr.height
    t = np.linspace(0.0, 1.0, 17)
    border = np.concatenate([np.c_[t * (W - 1), np.zeros_like(t)], np.c_[t * (W - 1), np.full_like(t, H - 1)],
                             np.c_[np.zeros_like(t), t * (H - 1)], np.c_[np.full_like(t, W - 1), t * (H - 1)]])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    xy = cv2.undistortPointsIter(border.reshape(-1, 1, 2), intr.K, intr.dist_array, None, None, crit).reshape(-1, 2)
    return float(np.max(np.sum(xy ** 2, axis=1)))


def _board_visibility(target, intr, T_cam_board: np.ndarray) -> float:
    """Share (0..1) of the board's corners that project inside the image, in front of the camera.

    Points beyond the image's undistorted radius do not count even if the distortion polynomial folds
    them back into the image."""
    from ..initial import project

    obj = target.object_points()
    p_cam = obj @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    front = p_cam[:, 2] > 0.02
    if not front.any():
        return 0.0
    x = p_cam[front, :2] / p_cam[front, 2:3]
    in_lens = np.sum(x ** 2, axis=1) <= 1.02 * _image_r2_max(intr)
    uv = project(obj[front], T_cam_board, intr)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= intr.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= intr.height - 1)
    return float((inside & in_lens).sum()) / len(obj)


def _why_not_found(run, vid: str, C_pred: np.ndarray) -> str:
    """Look where the board should be in an image whose target was not found: blur, exposure."""
    from ..detect import read_gray
    from .imaging import view_blur, view_exposure
    from ..errors import HandeyeError
    from ..initial import project

    s = run.session
    try:
        gray = read_gray(s.view(vid).image_path)
    except (HandeyeError, KeyError, OSError):
        return " (image unreadable)"
    obj = s.target.object_points()
    uv = project(obj, C_pred, run.intrinsics)
    ids = np.arange(len(obj))
    b = view_blur(gray, uv, ids, obj, s.target.square_m, charuco=s.target.kind == "charuco")
    e = view_exposure(gray, uv)
    why = []
    if np.isfinite(b["blur_sigma_px"]) and b["blur_sigma_px"] > BLUR_WARN_PX:
        why.append(f"the image is blurred there (edges about {b['blur_sigma_px']:.1f} px)")
    if e["saturated_share"] > OVEREXPOSED_WARN_SHARE:
        why.append(f"{100 * e['saturated_share']:.0f}% of that region is saturated")
    if np.isfinite(b.get("contrast", np.nan)) and b["contrast"] < 20:
        why.append(f"there is little contrast there ({b['contrast']:.0f} grey levels)")
    return (": " + ", ".join(why)) if why else " (blur, exposure, glare or something in front of it?)"


def detection_findings(run, *, A: Optional[np.ndarray] = None, B: Optional[np.ndarray] = None) -> list:
    """Dropped views (target not found, too few corners) with where the board would have been."""
    s = run.session
    mm = mounting(s.mode)
    dropped = [o for o in run.outcomes if not o.used and not str(o.reason).startswith("outlier")]
    not_found = [o for o in dropped if o.view_id not in (run.detections or {})]
    n_total = len(run.outcomes) or len(s.views)
    n_found = len(run.detections or {})
    out = []
    intr = run.intrinsics
    can_predict = A is not None and B is not None and intr is not None and intr.width > 0
    few = [o for o in not_found if "corners" in str(o.reason) and "only" in str(o.reason)]
    missing = [o for o in not_found if o not in few]
    notes, cut = {}, {}
    for o in missing:
        note = f"view {o.view_id}: {o.reason}"
        try:
            T = s.view(o.view_id).T_base_end
        except KeyError:
            T = None
        if can_predict and T is not None:
            C_pred = A @ mm.M_from_T_base_end(T) @ B
            vis = _board_visibility(s.target, intr, C_pred)
            if 0.0 < vis < 0.999:
                cut[o.view_id] = f"view {o.view_id}: not found; at this robot pose only {100 * vis:.0f}% of the " \
                                 "board's corners are in the image"
                continue
            if vis == 0.0:
                note += " - at this robot pose the board is outside the image"
            else:
                note += " - at this robot pose the whole board should be in the image" + _why_not_found(run, o.view_id,
                                                                                                      C_pred)
        notes[o.view_id] = note
    missing = [o for o in missing if o.view_id in notes]
    if missing:
        share = len(missing) / max(n_total, 1)
        failed = n_found < MIN_VIEWS_FAIL
        sev = "fail" if failed else ("warn" if share > 0.3 else "info")
        title = (f"The target was found in only {n_found} of {n_total} images" if failed or share > 0.3 else
                 f"Target not found in {len(missing)} of {n_total} images (dropped with their poses)")
        action = ("check the board size in the session (inner corners, not squares), lighting and focus, and that "
                  "the whole board is in every image" if failed or share > 0.3 else
                  "nothing to do if few; otherwise keep the whole board in the image at every robot pose")
        out.append(Finding("target_not_found", sev, title, "; ".join(notes[o.view_id] for o in missing), action,
                           view_ids=tuple(o.view_id for o in missing)))
    partial = [(o.view_id, str(o.reason)) for o in few] + [(v, t.split(": ", 1)[1]) for v, t in cut.items()]
    n_board = s.target.n_corners
    for vid, det in (run.detections or {}).items():
        if s.target.kind == "charuco" and len(det.corner_ids) < PARTIAL_SHARE * n_board:
            partial.append((vid, f"{len(det.corner_ids)} of {n_board} corners"))
    if partial:
        sev = "warn" if len(partial) > 0.3 * max(n_total, 1) else "info"
        out.append(Finding("partial_target", sev, f"Board only partly visible in {len(partial)} view(s)",
                           "; ".join(f"view {v}: {r}" for v, r in partial),
                           "keep the whole board inside the image; partial views add little and corners near the "
                           "board's edge constrain the pose poorly", view_ids=tuple(v for v, _ in partial)))
    return out


# ------------------------------------------------------------------------------ intrinsics
#: distortion effect (RMS px the fitted distortion explains) for info / warn, and the relative RMS drop
DIST_INFO_PX = 0.2
DIST_WARN_PX = 0.5
DIST_WARN_SHIFT_PX = 1.5
DIST_RMS_RATIO = 0.8


def distortion_findings(run) -> list:
    """Given intrinsics without distortion (or that do not fit) against calibrateCamera on the same corners."""
    import cv2

    from ..initial import calibrate_intrinsics

    s = run.session
    given = s.intrinsics
    if given is None or s.intrinsics_prior not in ("fixed", "prior") or len(run.detections or {}) < 3:
        return []
    obj = s.target.object_points()
    ids = [v for v in run.detections if v in (run.board_poses or {})]
    if len(ids) < 3:
        return []
    dets = [replace(run.detections[v], corner_ids=run.board_poses[v].corner_ids) for v in ids]
    n_pts = np.array([len(d.corner_ids) for d in dets])
    rms_given = float(np.sqrt(np.sum(n_pts * np.array([run.board_poses[v].rms_px for v in ids]) ** 2) / n_pts.sum()))
    W, H = given.width, given.height
    objs = [obj[d.corner_ids].astype(np.float32) for d in dets]
    imgs = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in dets]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    flags0 = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
              | cv2.CALIB_ZERO_TANGENT_DIST)
    try:
        rms_pin, K_pin, _, rv, tv = cv2.calibrateCamera(objs, imgs, (W, H), given.K.copy(), np.zeros(5),
                                                        flags=flags0, criteria=crit)
        fit, rms_full = calibrate_intrinsics(dets, obj, fix_k3=len(dets) < 10)
    except (cv2.error, Exception) as e:  # noqa: BLE001 - a failed fit only means no finding
        log.debug("distortion check skipped: %s", e)
        return []
    zero_dist = bool(np.all(np.abs(given.dist_array) < 1e-12))
    effect = float(np.sqrt(max(rms_pin ** 2 - rms_full ** 2, 0.0)))
    # how far the fitted lens moves the detected corners, and how radial the pinhole fit's residuals are
    shifts, radial_e, tot_e = [], 0.0, 0.0
    for o, im, r, t in zip(objs, imgs, rv, tv):
        p_pin = cv2.projectPoints(o, r, t, K_pin, np.zeros(5))[0].reshape(-1, 2)
        res = im.reshape(-1, 2) - p_pin
        d = p_pin - np.array([K_pin[0, 2], K_pin[1, 2]])
        er = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        radial_e += float(np.sum(np.einsum("ni,ni->n", res, er) ** 2))
        tot_e += float(np.sum(res ** 2))
        xn = cv2.undistortPoints(im, fit.K, fit.dist_array).reshape(-1, 2)
        p_d = cv2.projectPoints(np.c_[xn, np.ones(len(xn))], np.zeros(3), np.zeros(3), fit.K, fit.dist_array)[0]
        p_u = cv2.projectPoints(np.c_[xn, np.ones(len(xn))], np.zeros(3), np.zeros(3), fit.K, np.zeros(5))[0]
        shifts.append(np.linalg.norm(p_d.reshape(-1, 2) - p_u.reshape(-1, 2), axis=1))
    shift95 = float(np.percentile(np.concatenate(shifts), 95))
    radial_share = radial_e / max(tot_e, 1e-12)
    details = {"rms_given_px": rms_given, "rms_pinhole_fit_px": float(rms_pin), "rms_full_fit_px": float(rms_full),
               "distortion_effect_px": effect, "corner_shift_p95_px": shift95, "radial_share": radial_share,
               "fitted": fit.to_dict()}
    dist_txt = ", ".join(f"{n}={v:+.4f}" for n, v in zip(("k1", "k2", "p1", "p2", "k3"), fit.dist))
    if zero_dist:
        ratio = rms_full / max(rms_given, 1e-12)
        if effect < DIST_INFO_PX or ratio > DIST_RMS_RATIO:
            return []
        warn = effect >= DIST_WARN_PX and shift95 >= DIST_WARN_SHIFT_PX
        ev = (f"with the given intrinsics (no distortion) the corners fit to {rms_given:.2f} px RMS, refitting only "
              f"the focal length and centre to {rms_pin:.2f} px, adding distortion ({dist_txt}) to {rms_full:.2f} px; "
              f"the distortion explains {effect:.2f} px RMS, moves the detected corners by up to {shift95:.1f} px "
              f"(95th percentile), and {100 * radial_share:.0f}% of the distortion-free residual points radially")
        return [Finding("zero_distortion_given", "warn" if warn else "info",
                        "The given intrinsics have no lens distortion, but the images show distortion" if warn else
                        "The given intrinsics have no lens distortion; the images show a little",
                        ev, "estimate the intrinsics from the images (drop the intrinsics section or set use: "
                            "initial), or give the lens's distortion coefficients", details=details)]
    if rms_given > 2.0 * rms_full and rms_given > rms_full + 0.5:
        return [Finding("intrinsics_mismatch", "warn", "The given intrinsics do not fit the images",
                        f"with the given intrinsics the corners fit to {rms_given:.2f} px RMS, with intrinsics fitted "
                        f"to the same corners to {rms_full:.2f} px", "check that the intrinsics belong to this camera "
                        "and resolution, or let handeye estimate them", details=details)]
    return []


# ------------------------------------------------------------------------------ images
#: blur (Gaussian sigma of the board's edges beyond a sharp image) is reported when above both
BLUR_WARN_PX = 2.0
BLUR_WARN_SQUARE_SHARE = 0.04
#: a view this much blurrier than the session's median (and above BLUR_OUTLIER_PX) is reported too
BLUR_OUTLIER_RATIO = 2.5
BLUR_OUTLIER_PX = 1.5
#: exposure: share of the board at >= 250 grey levels; the black squares' level
OVEREXPOSED_WARN_SHARE = 0.45
OVEREXPOSED_INFO_SHARE = 0.2
WASHED_OUT_BLACK = 110
#: coverage of an 8x6 grid of image cells by the corners of all views
COVERAGE_WARN_SHARE = 0.3


def image_metrics(run, *, max_views: int = 200) -> dict:
    """Per used view: blur and exposure measured on the image; unreadable images are skipped."""
    from ..detect import read_gray
    from .imaging import view_blur, view_exposure
    from ..errors import HandeyeError

    s = run.session
    obj = s.target.object_points()
    out = {}
    for vid, det in list((run.detections or {}).items())[:max_views]:
        try:
            gray = read_gray(s.view(vid).image_path)
        except (HandeyeError, KeyError, OSError):
            continue
        ids = run.board_poses[vid].corner_ids if vid in (run.board_poses or {}) else det.corner_ids
        m = view_blur(gray, det.image_points, ids, obj, s.target.square_m, charuco=s.target.kind == "charuco")
        m.update(view_exposure(gray, det.image_points))
        out[vid] = m
    return out


def image_findings(run, metrics: dict) -> list:
    out = []
    if metrics:
        blur = {v: m for v, m in metrics.items() if np.isfinite(m.get("blur_sigma_px", np.nan))}
        if blur:
            med = float(np.median([m["blur_sigma_px"] for m in blur.values()]))
            bad = []
            for v, m in blur.items():
                b, sq = m["blur_sigma_px"], m.get("square_px", np.inf)
                if (b > BLUR_WARN_PX and b > BLUR_WARN_SQUARE_SHARE * sq) or (
                        b > BLUR_OUTLIER_PX and b > BLUR_OUTLIER_RATIO * max(med, SHARP_BLUR_FLOOR)):
                    bad.append(v)
            if bad:
                ev = "; ".join(f"view {v}: edges blurred by {blur[v]['blur_sigma_px']:.1f} px (squares "
                               f"{blur[v].get('square_px', float('nan')):.0f} px)" for v in bad[:12])
                ev += f"; median of all views {med:.2f} px (a sharp image: < 0.5 px)"
                sev = "warn"
                out.append(Finding("blurred", sev, f"Blurred images: {len(bad)} view(s)", ev,
                                   "focus the lens at the working distance, use a shorter exposure (more light) "
                                   "and let the robot settle before each capture", view_ids=tuple(bad),
                                   details={v: {"blur_sigma_px": blur[v]["blur_sigma_px"]} for v in bad}))
        over_w = [v for v, m in metrics.items() if m.get("saturated_share", 0) > OVEREXPOSED_WARN_SHARE
                  or m.get("p5", 0) > WASHED_OUT_BLACK]
        over_i = [v for v, m in metrics.items() if v not in over_w
                  and m.get("saturated_share", 0) > OVEREXPOSED_INFO_SHARE]
        if over_w:
            ev = "; ".join(f"view {v}: {100 * metrics[v]['saturated_share']:.0f}% of the board saturated, black squares "
                           f"at grey {metrics[v]['p5']:.0f}" for v in over_w[:12])
            out.append(Finding("overexposed", "warn", f"Overexposed images: {len(over_w)} view(s)", ev,
                               "reduce exposure or gain (or light) until the white squares are just below "
                               "saturation; clipped, blooming whites shift the corners", view_ids=tuple(over_w)))
        elif over_i:
            ev = "; ".join(f"view {v}: {100 * metrics[v]['saturated_share']:.0f}% of the board saturated"
                           for v in over_i[:12])
            out.append(Finding("overexposed", "info", f"White squares clipped in {len(over_i)} view(s)", ev,
                               "a slightly shorter exposure would keep the whites below saturation",
                               view_ids=tuple(over_i)))
    return out


SHARP_BLUR_FLOOR = 0.3


def coverage_findings(run) -> list:
    from .imaging import coverage, uncovered_regions

    dets = list((run.detections or {}).values())
    if not dets:
        return []
    W, H = dets[0].image_size
    pts = np.concatenate([d.image_points for d in dets])
    cov = coverage(pts, W, H)
    if cov["cell_share"] >= COVERAGE_WARN_SHARE:
        return []
    empty = uncovered_regions(np.array(cov["grid"]))
    given = run.session.intrinsics is not None and run.session.intrinsics_prior in ("fixed", "prior")
    why = ("the hand-eye result relies on image regions the board never reached" if given else
           "the lens distortion is only measured where the corners are; elsewhere it is extrapolated")
    return [Finding("corners_bunched", "warn", "The corners cover only part of the image",
                    f"corners of all {len(dets)} views fall in {100 * cov['cell_share']:.0f}% of an 8x6 grid over the "
                    f"image ({100 * cov['border_share']:.0f}% of the border cells); no corner in: "
                    f"{', '.join(empty) if empty else '-'}; {why}",
                    "add views with the board near the image's edges and corners (move or tilt so the board "
                    "fills those regions)", details=cov)]


# ------------------------------------------------------------------------------ cross-validation
#: leave-one-out up to this many views, k-fold (CV_FOLDS interleaved folds) above; a refitted
#: refinement costs ~0.1 s a fold, so it uses fewer folds than the closed form
CV_LOO_MAX_VIEWS = 20
CV_FOLDS = 10
CV_LOO_MAX_VIEWS_REFINED = 8
CV_FOLDS_REFINED = 8
CV_MIN_VIEWS = 6
#: jackknife spread / predicted sigma beyond which the model is said to miss an error source
CV_RATIO_HIGH = 2.0
CV_RATIO_LOW = 0.5


def _x_delta(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(rot about the camera axes [deg] (3), translation along the parent axes [mm] (3)) of T vs T_ref,
    in the parametrisation of the refinement's sigmas (T = T_ref Exp(omega), t - t_ref)."""
    om = Rotation.from_matrix(T_ref[:3, :3].T @ T[:3, :3]).as_rotvec()
    return np.concatenate([np.degrees(om), 1e3 * (T[:3, 3] - T_ref[:3, 3])])


def _cv_views(run) -> list:
    ids = [v for v in run.session.views if v.view_id in (run.board_poses or {})]
    ids = [v.view_id for v in ids]
    ref = run.refined
    if ref is not None and getattr(ref, "status", "") == "ok":
        pv = getattr(ref, "per_view", {}) or {}
        ids = [v for v in ids if pv.get(v, {}).get("status", "used") == "used"]
    return ids


def _folds(n: int, *, refined: bool) -> list:
    loo_max, k = (CV_LOO_MAX_VIEWS_REFINED, CV_FOLDS_REFINED) if refined else (CV_LOO_MAX_VIEWS, CV_FOLDS)
    if n <= loo_max:
        return [np.array([i]) for i in range(n)]
    return [np.arange(f, n, k) for f in range(k)]


def cross_validate(run) -> dict:
    """Leave-one-out / k-fold cross-validation of the hand-eye result (see the module docstring)."""
    from ..initial import project, solve_closed_form

    if run.T_x is None or not run.board_poses:
        return {"summary": "not run: no hand-eye result"}
    s = run.session
    mm = mounting(s.mode)
    ids = _cv_views(run)
    n = len(ids)
    if n < CV_MIN_VIEWS:
        return {"summary": f"not run: {n} usable views (needs {CV_MIN_VIEWS})", "n_views": n}
    ref = run.refined if (run.refined is not None and getattr(run.refined, "status", "") == "ok") else None
    obj = s.target.object_points()
    folds = _folds(n, refined=ref is not None)
    T_rep = {v: s.view(v).T_base_end for v in ids}
    C = np.stack([run.board_poses[v].T_cam_board for v in ids])
    M = mm.M_from_T_base_end(np.stack([T_rep[v] for v in ids]))
    intr = run.intrinsics
    estimates = []
    if ref is not None:
        from ..refine import RefineView, refine

        flagged = {}
        for o in getattr(ref, "outliers", ()):
            if getattr(o, "corner_ids", ()):
                flagged.setdefault(o.view_id, set()).update(int(c) for c in o.corner_ids)
        views = []
        for v in ids:
            cid = np.asarray(run.board_poses[v].corner_ids)
            keep = np.array([int(c) not in flagged.get(v, ()) for c in cid], bool)
            views.append(RefineView(v, cid[keep], run.detections[v].image_points[keep], T_rep[v]))
        o0 = ref.options
        robot = "fixed" if o0.robot_noise == "estimate" else o0.robot_noise
        opts = replace(o0, robot_noise=robot, robot_sigma_mm=max(ref.robot_sigma_mm, 1e-6) if robot == "fixed"
                       else o0.robot_sigma_mm, robot_sigma_deg=max(ref.robot_sigma_deg, 1e-6) if robot == "fixed"
                       else o0.robot_sigma_deg, outlier_loop=False, loss="none", closed_form_starts=False)
        method = (f"refinement refitted per fold (one solve, noise held at the full run's "
                  f"{ref.robot_sigma_mm:.3f} mm / {ref.robot_sigma_deg:.4f} deg robot, {ref.sigma_px:.3f} px)")
        for f in folds:
            tr = [views[k] for k in range(n) if k not in set(f.tolist())]
            try:
                r = refine(mode=s.mode, object_points=obj, views=tr, intrinsics=ref.intrinsics, T_x0=ref.T_x,
                           T_board0=ref.T_board, options=opts)
            except Exception as e:  # noqa: BLE001 - a fold that cannot be solved is reported, not fatal
                log.debug("cv fold failed: %s", e)
                r = None
            if r is None or r.status != "ok":
                estimates.append(None)
            else:
                estimates.append((r.T_x, r.T_board, r.intrinsics))
        T_full = ref.T_x
    else:
        meth = run.options.method
        method = f"closed-form {meth} refitted per fold"
        for f in folds:
            keep = np.ones(n, bool)
            keep[f] = False
            try:
                e = solve_closed_form(mm, C[keep], M[keep], method=meth)
            except Exception as ex:  # noqa: BLE001 - OpenCV may raise on a degenerate fold
                log.debug("cv fold failed: %s", ex)
                e = None
            estimates.append(None if e is None or e.status != "ok" else (e.T_x, e.T_board, intr))
        T_full = run.T_x
    ok = [k for k, e in enumerate(estimates) if e is not None]
    if len(ok) < max(3, len(folds) // 2):
        return {"summary": f"not run: only {len(ok)} of {len(folds)} folds could be solved", "method": method}
    deltas = np.stack([_x_delta(T_full, estimates[k][0]) for k in ok])
    d = int(round(np.mean([len(folds[k]) for k in ok])))
    jk = jackknife_sigmas(deltas, n, d)
    rows = []
    held_px = []
    for k in ok:
        T_x, T_b, intr_k = estimates[k]
        for i in folds[k]:
            v = ids[i]
            C_pred = mm.predict_T_cam_board(T_x, T_b, T_rep[v])
            bp = run.board_poses[v]
            r = np.linalg.norm(project(obj[bp.corner_ids], C_pred, intr_k) - run.detections[v].image_points, axis=1)
            C_in = mm.predict_T_cam_board(T_full, ref.T_board if ref is not None else run.T_board, T_rep[v])
            r_in = np.linalg.norm(project(obj[bp.corner_ids], C_in, ref.intrinsics if ref is not None else intr)
                                  - run.detections[v].image_points, axis=1)
            dx = deltas[ok.index(k)]
            rows.append({"view": v, "held_out_rms_px": round(float(np.sqrt(np.mean(r ** 2))), 3),
                         "in_sample_rms_px": round(float(np.sqrt(np.mean(r_in ** 2))), 3),
                         "x_shift_deg": round(float(np.linalg.norm(dx[:3])), 4),
                         "x_shift_mm": round(float(np.linalg.norm(dx[3:])), 3)})
            held_px.append(float(np.sqrt(np.mean(r ** 2))))
    out = {"method": method, "scheme": "leave-one-out" if d == 1 else f"{len(folds)}-fold (interleaved)",
           "n_views": n, "n_folds": len(folds), "folds_solved": len(ok),
           "jackknife_sigma_rot_deg": [round(float(x), 5) for x in jk[:3]],
           "jackknife_sigma_trans_mm": [round(float(x), 4) for x in jk[3:]],
           "axes": f"rotation about the camera axes, translation of {mm.x_name} along the {mm.fixed_frame} axes",
           "held_out_rms_px_median": round(float(np.median(held_px)), 3), "per_view": rows}
    if ref is not None:
        pr, pt = np.asarray(ref.sigma_rot_deg, float), np.asarray(ref.sigma_trans_mm, float)
        out["predicted_sigma_rot_deg"] = [round(float(x), 5) for x in pr]
        out["predicted_sigma_trans_mm"] = [round(float(x), 4) for x in pt]
        rr = float(np.sqrt(np.mean(jk[:3] ** 2)) / max(np.sqrt(np.mean(pr ** 2)), 1e-12))
        rt = float(np.sqrt(np.mean(jk[3:] ** 2)) / max(np.sqrt(np.mean(pt ** 2)), 1e-12))
        out["ratio_rot"], out["ratio_trans"] = round(rr, 3), round(rt, 3)
        worst = max(rr, rt)
        if worst > CV_RATIO_HIGH:
            out["verdict"] = "spread_exceeds_prediction"
            out["summary"] = (f"the result moves {worst:.1f}x more between folds than its covariance predicts "
                              f"(rotation {rr:.2f}x, translation {rt:.2f}x): the model misses an error source (robot "
                              "pose errors larger than modelled, a moved board, timing, or wrong intrinsics); "
                              "trust the spread, not the covariance")
        elif max(rr, rt) < CV_RATIO_LOW:
            out["verdict"] = "spread_below_prediction"
            out["summary"] = (f"the result moves less between folds than predicted (rotation {rr:.2f}x, translation "
                              f"{rt:.2f}x): the covariance is conservative")
        else:
            out["verdict"] = "consistent"
            out["summary"] = (f"the spread between folds matches the predicted uncertainty (rotation {rr:.2f}x, "
                              f"translation {rt:.2f}x of the predicted sigma)")
    else:
        out["verdict"] = "no_prediction"
        out["summary"] = (f"the closed-form result moves by {float(np.sqrt(np.sum(jk[3:] ** 2))):.2f} mm / "
                          f"{float(np.sqrt(np.sum(jk[:3] ** 2))):.3f} deg (jackknife 1 sigma); no covariance to "
                          "compare with (refinement not run)")
    return out


# ------------------------------------------------------------------------------ entry points
def _sorted(findings: list) -> list:
    order = {s: k for k, s in enumerate(SEVERITIES)}
    return sorted(findings, key=lambda f: order[f.severity])


def _pose_level(obs: _Obs, *, refined=None, session_kind: str = "native") -> dict:
    """Readings, pairing, board move, per-view disagreement and motion on one set of observations."""
    readings = evaluate_readings(obs)
    given = _given(readings)
    out: dict = {"findings": [], "readings": [r.row() for r in readings[:8]], "global_fault": False}
    if given is None and readings and readings[0].fit.cost < READING_GOOD_COST:
        given_cost = float("inf")  # the stated reading does not even parse
        rf = reading_findings(obs, [replace(readings[0], changes=(), invert=False)] + readings, session_kind=session_kind)
    else:
        given_cost = given.fit.cost if given is not None else float("inf")
        rf = reading_findings(obs, readings, session_kind=session_kind)
    out["findings"] += rf
    if rf:
        best = readings[0]
        T_use = _read_all(obs.raw, best.fmt, obs.ids)
        M_use = obs.M(T_use, invert=best.invert)
        fit = best.fit
        out["global_fault"] = True
    else:
        M_use = obs.M()
        fit = given.fit if given is not None else _fit(obs.C, M_use)
        pf = pairing_findings(obs, obs.raw.fmt, given_cost=given_cost)
        out["findings"] += pf
        out["global_fault"] = bool(pf)
        if not pf:
            bm, segfit = board_moved_findings(obs, M_use)
            out["findings"] += bm
            fit = segfit or fit
            rot, trans = view_disagreements(obs.mode, fit, obs.C, obs.T)
            out["per_view"] = {v: {"robot_vs_camera_rot_deg": float(rot[k]), "robot_vs_camera_trans_mm": float(trans[k]),
                                   "implied_board_rot_deg": float(fit.board_rot_deg[k]),
                                   "implied_board_trans_mm": float(fit.board_trans_mm[k])}
                               for k, v in enumerate(obs.ids)}
            out["findings"] += robot_pose_findings(obs, M_use, fit, refined=refined,
                                                   exclude=bm[0].view_ids if bm else (), fmt=obs.raw.fmt)
    out["findings"] += motion_findings(obs.mode, M_use, A=fit.A)
    out["fit"] = fit
    out["M"] = M_use
    return out


def diagnose_run(run, *, images: bool = True, cross_validation: bool = True) -> dict:
    """Diagnostics of a calibration run (successful or failed) for ``result.json["diagnostics"]``.

    Returns ``{"findings": [Finding as dict, worst first], "cross_validation": {...}, "readings": [...],
    "per_view": {view_id: {...}}, "images": {view_id: {...}}}``. ``images=False`` skips reading the
    images (blur, exposure); ``cross_validation=False`` skips the refits.
    """
    s = run.session
    findings: list = []
    result: dict = {"version": 1}
    problems: list = []

    def guard(name, fn, *args, default=None, **kw):
        """Run one stage; an unexpected error becomes a note instead of breaking result.json."""
        try:
            return fn(*args, **kw)
        except Exception as e:  # noqa: BLE001 - diagnostics must never stop a calibration from being written
            log.warning("diagnostics stage %s failed: %s", name, e)
            log.debug("diagnostics stage %s failed", name, exc_info=True)
            problems.append(f"{name}: {type(e).__name__}: {e}")
            return default

    obs = guard("observations", _obs_from_run, run)
    predict = None
    global_fault = False
    per_view: dict = {}
    pl = guard("pose checks", _pose_level, obs, refined=run.refined, session_kind=s.format) if obs is not None \
        else None
    if pl is not None:
        findings += pl["findings"]
        global_fault = pl["global_fault"]
        result["readings"] = pl["readings"]
        per_view = pl.get("per_view", {})
        fit = pl["fit"]
        if not global_fault and run.T_x is not None and run.T_board is not None and run.status == "ok":
            predict = (inv_T(run.T_x), run.T_board, False)
        elif fit is not None:
            inverted = global_fault and any(f.code in ("poses_inverted", "mode_swapped") for f in pl["findings"])
            predict = (fit.A, fit.B[0], inverted)
    elif obs is None:
        n = len(run.board_poses or {})
        if n < MIN_VIEWS_FAIL and (run.detections or run.outcomes):
            findings += guard("motion", motion_findings, s.mode, np.zeros((n, 4, 4)) + np.eye(4), default=[])
    findings += guard("detection", _detection_with_prediction, run, predict, default=[])
    findings += guard("intrinsics", distortion_findings, run, default=[])
    metrics = guard("images", image_metrics, run, default={}) if images else {}
    findings += guard("images", image_findings, run, metrics, default=[])
    findings += guard("coverage", coverage_findings, run, default=[])
    if metrics:
        result["images"] = {v: {k: (round(float(x), 4) if isinstance(x, (float, np.floating)) else x)
                                for k, x in m.items()} for v, m in metrics.items()}
    if cross_validation and not global_fault and run.status == "ok":
        cv = guard("cross-validation", cross_validate, run, default=None) or {"summary": "not run: it failed"}
    else:
        cv = {"summary": "not run: " + ("the robot poses do not match the images as read" if global_fault
                                        else "no hand-eye result" if run.status != "ok" else "disabled")}
    result["cross_validation"] = cv
    if cv.get("verdict") == "spread_exceeds_prediction":
        findings.append(Finding("uncertainty_underestimated", "warn" if cv.get("n_views", 0) >= RECOMMENDED_VIEWS
                                else "info", "The result varies more between held-out folds than its uncertainty says",
                                cv["summary"] + f" (jackknife over {cv.get('n_folds')} folds: rotation "
                                f"{cv.get('ratio_rot')}x, translation {cv.get('ratio_trans')}x)",
                                "use the cross-validation spread as the uncertainty; look for robot pose errors "
                                "(estimate robot noise: --robot-noise estimate), a moving board or timing problems"))
    if problems:
        findings.append(Finding("diagnostics_incomplete", "info", "Some diagnostics could not run",
                                "; ".join(problems), "report this with the session if it persists"))
    result["per_view"] = _jsonable(per_view)
    result["findings"] = [_finding_dict(f) for f in _sorted(findings)]
    return _jsonable(result)


def _detection_with_prediction(run, predict) -> list:
    """detection_findings with the board predicted through the best model available:
    ``predict = (A, B, inverted)``; ``inverted`` when the robot motions fit only inverted."""
    if predict is None or run.intrinsics is None:
        return detection_findings(run)
    A, B, inverted = predict
    if not inverted:
        return detection_findings(run, A=A, B=B)
    s = run.session
    inv_session = replace(s, views=tuple(replace(v, T_base_end=inv_T(v.T_base_end)) for v in s.views))
    return detection_findings(replace(run, session=inv_session), A=A, B=B)


# ------------------------------------------------------------------------------ failed loads
def diagnose_session_error(path, error, *, mode: Optional[str] = None, images: bool = True) -> dict:
    """What can be said about a session that failed to load (e.g. poses that look like mm or degrees).

    Reads the session leniently (raw pose values, target, images), finds the board, calibrates the
    camera, and tests every plausible reading of the raw poses against the images. Returns
    ``{"findings": [...], "readings": [...], "load_error": str}``. Never raises for bad input.
    """
    err = str(error)
    base = {"version": 1, "load_error": err, "findings": [], "cross_validation": {"summary": "not run: the session "
                                                                                             "did not load"}}
    try:
        sess = read_session_lenient(Path(path), mode=mode)
    except Exception as e:  # noqa: BLE001 - whatever is wrong, say it rather than crash the failure path
        log.debug("lenient read failed: %s", e)
        sess = None
    if sess is None:
        base["findings"] = [_finding_dict(Finding("session_unreadable", "fail", "The session could not be read",
                                                  err, "fix what the message names (see docs/session_format.md)"))]
        return _jsonable(base)
    target, sess_mode, raw, images_by_id, intr_given = (sess.target, sess.mode, sess.raw, sess.images_by_id,
                                                       sess.intrinsics)
    try:
        obs, n_det, n_img = _observe(target, sess_mode, raw, images_by_id, intr_given)
    except Exception as e:  # noqa: BLE001
        log.debug("lenient observation failed: %s", e)
        obs, n_det, n_img = None, 0, len(images_by_id)
    if obs is None:
        few = n_det < MIN_VIEWS_FAIL
        base["findings"] = [_finding_dict(Finding(
            "target_not_found" if few else "session_unreadable", "fail",
            f"The session could not be read, and the board was found in only {n_det} of {n_img} images" if few
            else "The session could not be read, and its robot poses could not be compared with the images",
            err, "fix what the message names; check the board size (inner corners) in the session"))]
        return _jsonable(base)
    pl = _pose_level(obs, session_kind="vendor" if raw.fmt is VENDOR_POSE_FORMAT else "native")
    findings = [f for f in pl["findings"] if f.code not in ("too_few_views",) or f.severity != "info"]
    if not any(f.code in ("translation_units", "angle_units", "euler_order", "quaternion_order", "poses_inverted",
                          "mode_swapped", "pairs_shifted") for f in findings):
        given = next((r for r in pl["readings"] if r["changes"] == "as given"), None)
        if given is not None and given["cost"] < READING_GOOD_COST:
            findings.insert(0, Finding("poses_fit_as_stated", "info", "The robot poses fit the images as stated",
                                       f"read as stated the board scatters by {given['board_scatter_deg']:.3f} deg / "
                                       f"{given['board_scatter_mm']:.2f} mm; the load error is about something else",
                                       "fix what the load error names"))
    base["findings"] = [_finding_dict(f) for f in _sorted(findings)]
    base["readings"] = pl["readings"]
    base["n_views"] = {"images": n_img, "board_found": n_det}
    return _jsonable(base)


def _observe(target, mode, raw: RawPoses, images_by_id: dict, intr_given):
    """Detections, intrinsics and board poses of a leniently read session: (_Obs | None, n_found, n_images)."""
    from ..detect import detect_views
    from ..initial import board_poses, calibrate_intrinsics
    from ..records import Detection

    items = [(v, images_by_id[v]) for v in sorted(images_by_id, key=view_id_key) if v in raw.values]
    det = detect_views(items, target)
    dets = {v: d for v, d in det.items() if isinstance(d, Detection)}
    if len(dets) < MIN_VIEWS_FAIL:
        return None, len(dets), len(items)
    intr = intr_given
    if intr is None:
        intr, _ = calibrate_intrinsics(list(dets.values()), target.object_points())
    ids = [v for v in sorted(dets, key=view_id_key)]
    # a reading that parses, for ordering symmetric boards (re-done below with the best reading)
    fmt = raw.fmt
    T = _read_all(raw, fmt, ids)
    if T is None:
        for f2, _ in alternative_formats(fmt):
            T = _read_all(raw, f2, ids)
            if T is not None:
                break
    if T is None:
        return None, len(dets), len(items)
    mm = mounting(mode)

    def make_obs(T_for_order):
        M = {v: mm.M_from_T_base_end(T_for_order[k]) for k, v in enumerate(ids)}
        bp = board_poses([dets[v] for v in ids], target, intr, M)
        C = np.stack([bp[v].T_cam_board for v in ids])
        obj = target.object_points()
        corners = tuple((obj[bp[v].corner_ids], dets[v].image_points) for v in ids)
        return _Obs(mode, tuple(ids), C, T, raw, {}, corners, intr, target, intr_given is None)

    obs = make_obs(T)
    if len(target.symmetries()) > 1:
        readings = evaluate_readings(obs)
        if readings:
            best = readings[0]
            T_best = _read_all(raw, best.fmt, ids)
            if T_best is not None:
                T_order = inv_T(T_best) if best.invert else T_best
                obs = replace(make_obs(T_order), T=T)
    return obs, len(dets), len(items)
