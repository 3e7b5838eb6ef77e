"""Pose-format forensics: which reading of the raw robot pose numbers fits the images.

Every plausible re-reading of the numbers as written (translation units m/cm/mm, angle units rad/deg,
24 Euler conventions, quaternion orders) x {as given, inverted} is scored by the board scatter left
after solving ``C_i = A M_i B`` (:mod:`.fits`). Rotation readings are first screened by the pair
rotation-angle invariant, which does not depend on translation units, inversion or the mode. Inverted
poses and a swapped mounting mode give the same numbers; they are told apart by which physical reading
of the solution is plausible (camera near the flange or beside the robot).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from itertools import product
from typing import Optional, Sequence

import numpy as np

from ..conventions import TRANSLATION_UNITS, PoseFormat, R_from_euler, T_from_pose_values
from ..frames import R_from_rotvec, inv_T, screw_invariants
from ..mounting import mounting
from ..session.raw import RawPoses
from .findings import Finding, ids_text
from .fits import BoardFit, fit_boards
from .geometry import camera_pairs, pair_invariants, pair_motions, pairs_text, summarize_invariants, view_pairs
from .observations import PoseObservations
from .thresholds import thresholds

EULER_ORDERS = ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx", "xyx", "xzx", "yxy", "yzy", "zxz", "zyz")
#: translation units (:data:`handeye.conventions.TRANSLATION_UNITS`) as a finding names them
UNIT_NAMES = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}
#: the codes of a global fault in how the poses were read or paired (the other checks then stop)
READING_CODES = (
    "translation_units",
    "angle_units",
    "euler_order",
    "rotation_kind",
    "quaternion_order",
    "poses_inverted",
    "mode_swapped",
)


def alternative_formats(fmt: PoseFormat) -> list[tuple[PoseFormat, tuple]]:
    """Every plausible reading of numbers written for ``fmt``: (format, changed aspects).

    Aspects: translation_units (m/cm/mm), angle_units (rad/deg), euler_order (24 Euler conventions),
    rotation_kind (three angles as a rotation vector instead of Euler angles, or the reverse),
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
        # three angles may be a rotation vector (axis times angle: what Universal Robots' controllers write)
        more += [(dict(ch, rotation="rotvec"), codes + ("rotation_kind",)) for ch, codes in rot_variants[:2]]
        rot_variants += more
    elif fmt.rotation == "rotvec":  # and a stated rotation vector may be Euler angles of any convention
        rot_variants += [
            (dict(ch, rotation="euler", euler_order=order, euler_kind=kind), codes + ("rotation_kind",))
            for order, kind in product(EULER_ORDERS, ("extrinsic", "intrinsic"))
            for ch, codes in rot_variants[:2]
        ]
    if fmt.rotation == "quaternion":
        other = "xyzw" if fmt.quaternion_order == "wxyz" else "wxyz"
        rot_variants.append(({"quaternion_order": other}, ("quaternion_order",)))
    other_t = [u for u in TRANSLATION_UNITS if u != fmt.translation_unit]
    out = []
    for (ch, codes), t_alt in product(rot_variants, [None, *other_t]):
        ch2 = dict(ch, translation_unit=t_alt) if t_alt else ch
        out.append((replace(fmt, **ch2), (("translation_units",) if t_alt else ()) + codes))
    out.sort(key=lambda fc: len(fc[1]))
    return out


def read_poses(raw: RawPoses, fmt: PoseFormat, ids: Sequence[str]) -> Optional[np.ndarray]:
    """``T_base_end`` (N,4,4) of the views ``ids`` read with ``fmt`` (None if any pose does not parse).

    Vectorised for Euler angles and rotation vectors (same conversion as
    :func:`handeye.conventions.T_from_pose_values`, which handles the other forms).
    """
    try:
        V = np.stack([np.asarray(raw.values[v], float).reshape(-1) for v in ids])
    except (KeyError, ValueError):
        return None
    if V.shape[1] != fmt.n_values or not np.all(np.isfinite(V)):
        return None
    if fmt.rotation in ("euler", "rotvec"):
        scale = TRANSLATION_UNITS.get(fmt.translation_unit, 1.0)
        if fmt.rotation == "euler":
            R = R_from_euler(
                V[:, 3:6],
                order=fmt.euler_order,
                intrinsic=fmt.euler_kind == "intrinsic",
                degrees=fmt.angle_unit == "deg",
            )
        else:
            R = R_from_rotvec(np.radians(V[:, 3:6]) if fmt.angle_unit == "deg" else V[:, 3:6])
        T = np.zeros((len(V), 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = V[:, :3] * scale
        T[:, 3, 3] = 1.0
        return T
    try:
        return np.stack([T_from_pose_values(V[k], fmt) for k in range(len(V))])
    except ValueError:
        return None


def pair_angles_deg(R: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Rotation angle of R_i R_j^T for the pairs (fast, from the trace)."""
    tr = np.einsum("pab,pab->p", R[i], R[j])  # trace(R_i R_j^T)
    return np.degrees(np.arccos(np.clip(0.5 * (tr - 1.0), -1.0, 1.0)))


@dataclass(frozen=True)
class Reading:
    fmt: PoseFormat
    changes: tuple  # aspects changed w.r.t. the stated format
    invert: bool
    fit: BoardFit
    angle_res_deg: float  # median rotation-angle invariant residual over pairs
    pitch_res_mm: float
    labels: Optional[np.ndarray] = None  # symmetric boards: each view's corner ordering under this reading

    @property
    def codes(self) -> tuple:
        return self.changes + (("inverse",) if self.invert else ())

    def describe(self) -> str:
        return self.fmt.describe() + (", inverted" if self.invert else "")

    def row(self) -> dict:
        return {
            "reading": self.describe(),
            "changes": ", ".join(self.codes) or "as given",
            "board_scatter_deg": round(self.fit.median_rot_deg, 4),
            "board_scatter_mm": round(self.fit.median_trans_mm, 3),
            "pair_angle_residual_deg": round(self.angle_res_deg, 4),
            "pair_pitch_residual_mm": round(self.pitch_res_mm, 3) if np.isfinite(self.pitch_res_mm) else None,
            "cost": round(self.fit.cost, 3),
        }


def evaluate_readings(obs: PoseObservations) -> list[Reading]:
    """All plausible readings of the raw poses, best first (see :func:`alternative_formats`).

    On a symmetric board (``obs.C_candidates``) each rotation reading is scored with its own best corner
    ordering (:func:`handeye.initial.board_poses.orientation_labels`), so a misread pose cannot hide behind
    views turned by 180 (or 90) degrees to agree with it: readings and orderings are resolved together.
    """
    from ..initial.board_poses import candidate_invariants, orientation_labels

    fmt0 = obs.raw.fmt
    alts = alternative_formats(fmt0)
    joint = obs.C_candidates is not None
    inv_c = candidate_invariants(obs.C_candidates) if obs.C_candidates is not None else None  # joint
    # stage 1: rotation readings by the rotation-angle invariant (independent of translation units,
    # of inversion and of the mounting mode), each with its own ordering of a symmetric board's views
    rot_score: dict = {}
    ordered: dict = {}  # rotation key -> (C (N,4,4), orientation labels or None)
    pi, pj = view_pairs(obs.n)
    ang_c0 = pair_angles_deg(obs.C[:, :3, :3], pi, pj)
    for fmt, _ in alts:
        key = replace(fmt, translation_unit=fmt0.translation_unit)
        if key in rot_score:
            continue
        T = read_poses(obs.raw, key, obs.ids)
        if T is None:
            rot_score[key] = np.inf
            continue
        M = obs.M(T)
        if joint:
            assert inv_c is not None and obs.C_candidates is not None, "joint"
            lab = orientation_labels(inv_c, M, turns=obs.candidates_are_turns)
            C = obs.C_candidates[np.arange(obs.n), lab]
            ordered[key] = (C, lab)
            ang_c = pair_angles_deg(C[:, :3, :3], pi, pj)
        else:
            ordered[key] = (obs.C, None)
            ang_c = ang_c0
        rot_score[key] = float(np.median(np.abs(pair_angles_deg(M[:, :3, :3], pi, pj) - ang_c)))
    # keep every rotation reading that ties with the best: readings of the form R' = U R^T V (some Euler
    # misreadings) keep all pair angles, and only the full fit tells them apart
    ranked = sorted(rot_score, key=rot_score.__getitem__)
    best = rot_score[ranked[0]]
    keep = {
        k for k in ranked[: thresholds().readings.max_rotation_readings] if rot_score[k] <= max(2.0 * best, best + 0.1)
    }
    keep |= set(ranked[:2]) | {replace(fmt0)}
    out = []
    cameras: dict = {}  # id of a C in ``ordered`` (kept alive there) -> its camera_pairs
    for fmt, changes in alts:
        key = replace(fmt, translation_unit=fmt0.translation_unit)
        if key not in keep or key not in ordered:
            continue
        T = read_poses(obs.raw, fmt, obs.ids)
        if T is None:
            continue
        C, lab = ordered[key]
        if id(C) not in cameras:  # the camera side of the pairs is one for every reading of the same C
            cameras[id(C)] = camera_pairs(C)
        cam = cameras[id(C)]
        s = summarize_invariants(pair_invariants(C, obs.M(T), camera=cam))  # the same for inverted motions
        for invert in (False, True):
            M = obs.M(T, invert=invert)
            try:
                fit = fit_boards(C, M, motions=pair_motions(C, M, camera=cam))
            except np.linalg.LinAlgError:
                continue
            out.append(
                Reading(fmt, changes, invert, fit, s["median_angle_res_deg"], s["median_pitch_res_mm"], labels=lab)
            )
    out.sort(key=lambda r: (r.fit.cost, len(r.codes)))
    return out


def turned_views(obs: PoseObservations, given: Reading, best: Reading) -> list:
    """Ids of the views whose corner ordering differs between two readings (symmetric boards)."""
    if given.labels is None or best.labels is None:
        return []
    return [v for v, a, b in zip(obs.ids, given.labels, best.labels, strict=False) if a != b]


def given_reading(readings: Sequence[Reading]) -> Optional[Reading]:
    return next((r for r in readings if not r.changes and not r.invert), None)


def is_clearly_better(cost: float, than_cost: float) -> bool:
    """A fit of ``cost`` explains the data and is ``ratio`` times better than one of ``than_cost``."""
    t = thresholds().readings
    return cost < t.good_cost and cost * t.ratio < than_cost


def reading_is_wrong(given: Reading, best: Reading) -> bool:
    return given.fit.cost > thresholds().readings.bad_cost and is_clearly_better(best.fit.cost, given.fit.cost)


def format_snippet(fmt: PoseFormat) -> str:
    """The session.yaml (or vendor config.yaml) line that states ``fmt``."""
    if fmt.rotation == "euler":
        return (
            f"pose_format: {{rotation: euler, euler_order: {fmt.euler_order}, euler_kind: {fmt.euler_kind}, "
            f"angle_unit: {fmt.angle_unit}, translation_unit: {fmt.translation_unit}}}"
        )
    if fmt.rotation == "quaternion":
        return (
            f"pose_format: {{rotation: quaternion, quaternion_order: {fmt.quaternion_order}, "
            f"translation_unit: {fmt.translation_unit}}}"
        )
    if fmt.rotation == "rotvec":
        return (
            f"pose_format: {{rotation: rotvec, angle_unit: {fmt.angle_unit}, translation_unit: {fmt.translation_unit}}}"
        )
    return f"pose_format: {{rotation: matrix, translation_unit: {fmt.translation_unit}}}"


def pitch_scale(obs: PoseObservations, fmt_read: PoseFormat, fmt_true: PoseFormat) -> Optional[float]:
    """Median ratio camera pitch / robot pitch under a reading (how far off the translation scale is)."""
    T = read_poses(
        obs.raw,
        replace(
            fmt_read,
            **{
                k: getattr(fmt_true, k)
                for k in ("rotation", "euler_order", "euler_kind", "angle_unit", "quaternion_order")
            },
        ),
        obs.ids,
    )
    if T is None:
        return None
    M = obs.M(T)
    i, j = view_pairs(obs.n)
    _, pc = screw_invariants(obs.C[i] @ inv_T(obs.C[j]))
    a, pm = screw_invariants(M[i] @ inv_T(M[j]))
    ok = (a > np.radians(12)) & (a < np.radians(165)) & (np.abs(pm) > 1e-9)
    if ok.sum() < 3:
        return None
    big = ok & (np.abs(pc) > np.quantile(np.abs(pc[ok]), 0.5))
    return float(np.median(pc[big] / pm[big])) if big.sum() >= 2 else None


def inverse_reading_kind(mode: str, fit: BoardFit) -> str:
    """Which reading a fit with inverted robot motions is: poses_inverted or mode_swapped.

    For a fit with inverted robot motions: "poses_inverted" or "mode_swapped", by which reading puts
    the camera near the flange (eye-in-hand-like: |t_X| < |t_board|) or beside the robot.
    """
    t_x = float(np.linalg.norm(inv_T(fit.A)[:3, 3]))
    t_b = float(np.linalg.norm(fit.B[0][:3, 3]))
    looks_like_camera_on_robot = t_x < t_b
    return "poses_inverted" if looks_like_camera_on_robot == mounting(mode).camera_moves else "mode_swapped"


def reading_findings(obs: PoseObservations, readings: Sequence[Reading], *, session_kind: str = "native") -> list:
    """Findings for a wrong reading of the poses (units, Euler convention, inversion, mode)."""
    given = given_reading(readings)
    if given is None or not readings:
        return []
    best = readings[0]
    if best is given or not reading_is_wrong(given, best):
        return []
    fmt0 = obs.raw.fmt
    rivals = [r for r in readings[1:] if r.fit.cost < 1.5 * best.fit.cost and r.codes != best.codes][:3]
    ev = (
        f"as given ({given.describe()}): the board implied by each view scatters by {given.fit.median_rot_deg:.2f} deg"
        f" / {given.fit.median_trans_mm:.1f} mm (median), robot and camera rotation angles differ by "
        f"{given.angle_res_deg:.2f} deg (median over {pairs_text(obs.n)}); read as "
        f"{best.describe()}: {best.fit.median_rot_deg:.3f} deg / {best.fit.median_trans_mm:.2f} mm, "
        f"{best.angle_res_deg:.3f} deg (cost {best.fit.cost:.2f} against {given.fit.cost:.1f} as given: "
        f"{given.fit.cost / max(best.fit.cost, 1e-9):.0f} x better)"
    )
    if rivals:
        ev += "; about as good: " + "; ".join(
            f"{r.describe()} ({r.fit.median_rot_deg:.3f} deg / {r.fit.median_trans_mm:.2f} mm)" for r in rivals
        )
    turned = turned_views(obs, given, best)
    if turned:
        ev += (
            f"; on this symmetric board the corner order of {len(turned)} of {obs.n} views depends on the "
            f"reading (views {ids_text(turned)}): as given they were turned to agree with the misread motion, "
            f"so each reading was scored with its own best ordering"
        )
    details = {
        "given": given.row(),
        "best": best.row(),
        "rivals": [r.row() for r in rivals],
        "views_reordered": [str(v) for v in turned],
        "cost_ratio": (given.fit.cost / best.fit.cost) if best.fit.cost > 0 else None,
    }
    fix_fmt = (
        f"state the format in config.yaml: {format_snippet(best.fmt)} (or convert poses.txt to the vendor's "
        "x, y, z in metres and rx, ry, rz in radians, R = Rz·Ry·Rx)"
        if session_kind == "vendor"
        else f"state the format in session.yaml: {format_snippet(best.fmt)}"
    )
    out = []
    for code in best.changes:
        if code == "translation_units":
            scale = pitch_scale(obs, fmt0, best.fmt)
            title = (
                f"Robot translations are in {UNIT_NAMES[best.fmt.translation_unit]} but were read as "
                f"{UNIT_NAMES[fmt0.translation_unit]}"
            )
            if scale:
                e = ev + (
                    f"; as given, the robot moves {1 / scale:.4g} x farther along its rotation axes than the camera saw"
                    if abs(scale) < 1
                    else f"; as given, the camera saw {scale:.4g} x more motion along the rotation axes than the "
                    f"robot reports"
                )
            else:
                e = ev
            out.append(
                Finding(
                    "translation_units", "fail", title, e, fix_fmt, details=dict(details, camera_over_robot_pitch=scale)
                )
            )
        elif code == "angle_units":
            title = (
                "Robot angles are in degrees but were read as radians"
                if best.fmt.angle_unit == "deg"
                else "Robot angles are in radians but were read as degrees"
            )
            out.append(Finding("angle_units", "fail", title, ev, fix_fmt, details=details))
        elif code == "euler_order":
            title = (
                f"Robot angles follow another Euler convention: {best.fmt.euler_kind} {best.fmt.euler_order} "
                f"(read as {fmt0.euler_kind} {fmt0.euler_order})"
            )
            out.append(Finding("euler_order", "fail", title, ev, fix_fmt, details=details))
        elif code == "rotation_kind":
            if best.fmt.rotation == "rotvec":
                title = (
                    "Robot rotations are rotation vectors (axis x angle, as Universal Robots' controllers write "
                    f"them), read as {fmt0.euler_kind} {fmt0.euler_order} Euler angles"
                )
            else:
                title = (
                    f"Robot rotations are {best.fmt.euler_kind} {best.fmt.euler_order} Euler angles, read as a "
                    "rotation vector"
                )
            out.append(Finding("rotation_kind", "fail", title, ev, fix_fmt, details=details))
        elif code == "quaternion_order":
            title = f"Quaternions are written {best.fmt.quaternion_order}, read as {fmt0.quaternion_order}"
            out.append(Finding("quaternion_order", "fail", title, ev, fix_fmt, details=details))
    if best.invert:
        out.append(_inverse_finding(obs, best, ev, details))
    return out


def _inverse_finding(obs: PoseObservations, best: Reading, ev: str, details: dict) -> Finding:
    kind = inverse_reading_kind(obs.mode, best.fit)
    mode = mounting(obs.mode)
    other = mode.other
    fits_as = mode if kind == "poses_inverted" else other
    t_x = 1e3 * float(np.linalg.norm(inv_T(best.fit.A)[:3, 3]))
    t_b = 1e3 * float(np.linalg.norm(best.fit.B[0][:3, 3]))
    e = ev + (
        f"; with the inverted motions the camera sits {t_x:.0f} mm from the {fits_as.fixed_frame} origin and "
        f"the board {t_b:.0f} mm from the {fits_as.board_frame} origin"
    )
    if kind == "poses_inverted":
        return Finding(
            "poses_inverted",
            "fail",
            "Robot poses are inverted (the pose of the base in the flange, T_end_base, "
            "instead of the flange in the base)",
            e + f" (calibrating as {other.name} would fit equally, but puts the camera implausibly)",
            "write each robot pose as the flange in the base frame (T_base_end), i.e. invert "
            "them, or export the other pose from the robot controller",
            details=details,
        )
    return Finding(
        "mode_swapped",
        "fail",
        f"The data are {other.name.replace('_', '-')} but were calibrated as {mode.name.replace('_', '-')}",
        e + " (inverted robot poses would fit equally, but put the camera implausibly)",
        f"calibrate with --mode {other.name} (or set mode: {other.name} in config.yaml or session.yaml)",
        details=details,
    )


def reading_in_use(obs: PoseObservations, readings: Sequence[Reading], findings: Sequence[Finding]):
    """(robot motions M (N,4,4), fit) of the reading the other checks should use.

    The best reading when the given one was found wrong, else the given one.
    """
    if findings:
        best = readings[0]
        T = read_poses(obs.raw, best.fmt, obs.ids)
        return obs.M(T, invert=best.invert), best.fit
    given = given_reading(readings)
    M = obs.M()
    return M, (given.fit if given is not None else fit_boards(obs.C, M))


__all__ = [
    "EULER_ORDERS",
    "READING_CODES",
    "Reading",
    "alternative_formats",
    "read_poses",
    "evaluate_readings",
    "given_reading",
    "reading_is_wrong",
    "reading_findings",
    "reading_in_use",
]
