"""The hand-eye result's uncertainty in every form the report shows.

Pure functions over the result transform and its 6x6 covariance (no I/O). The covariance is in the
package's one tangent convention (:mod:`handeye.frames`, GTSAM's Pose3): right perturbation
``T_x,true = T_x · Exp(xi)``, ``xi = (omega [rad], v [m])``, rotation first, along the camera axes.
Every derived sigma is first-order propagation ``J C J^T`` with ``J`` from
:func:`handeye.frames.tangent_jacobian`.
"""

from __future__ import annotations

import numpy as np

from ..conventions import vendor_euler_from_R
from ..frames import quat_wxyz_from_R, rotvec_from_R, skew, tangent_jacobian
from .formatting import num

Z95 = 1.959963984540054  # two-sided 95 % quantile of the standard normal


def _wrap_rad(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def form_sigmas(T_x: np.ndarray, cov_x_6x6: np.ndarray) -> dict:
    """1-sigma of every representation of ``T_x`` propagated from its tangent covariance.

    Returns ``translation_mm`` (3,), ``quaternion_wxyz`` (4,), ``rotvec_deg`` (3,), ``euler_vendor_deg``
    (3,) (R = Rz·Ry·Rx), ``rot_cam_deg`` (3,) (rotation about the camera axes), each a 1-sigma array,
    and ``cov_translation_mm2`` (3, 3) in the parent frame.
    """
    T_x = np.asarray(T_x, float)
    C = np.asarray(cov_x_6x6, float)
    q0 = quat_wxyz_from_R(T_x[:3, :3])
    rv0 = rotvec_from_R(T_x[:3, :3])
    e0 = vendor_euler_from_R(T_x[:3, :3])

    def sig(J):
        return np.sqrt(np.maximum(np.diag(J @ C @ J.T), 0.0))

    def quat_near(T):  # the quaternion on the same sign branch as the nominal one
        q = quat_wxyz_from_R(T[:3, :3])
        return q if q @ q0 >= 0 else -q

    def rotvec_near(T):  # the rotation vector on the same branch as the nominal one
        rv = rotvec_from_R(T[:3, :3])
        ang = np.linalg.norm(rv)
        if ang > 1e-9 and rv @ rv0 < 0:
            rv = rv / ang * (ang - 2.0 * np.pi)
        return rv

    J_t = tangent_jacobian(lambda T: T[:3, 3] * 1e3, T_x)
    J_q = tangent_jacobian(quat_near, T_x)
    J_rv = tangent_jacobian(rotvec_near, T_x)
    J_e = tangent_jacobian(lambda T: _wrap_rad(vendor_euler_from_R(T[:3, :3]) - e0), T_x)
    return {
        "translation_mm": sig(J_t),
        "quaternion_wxyz": sig(J_q),
        "rotvec_deg": np.degrees(sig(J_rv)),
        "euler_vendor_deg": np.degrees(sig(J_e)),
        "rot_cam_deg": np.degrees(np.sqrt(np.maximum(np.diag(C[:3, :3]), 0.0))),
        "cov_translation_mm2": J_t @ C @ J_t.T,
    }


def predicted_point_error(T_x: np.ndarray, cov_x_6x6: np.ndarray, *, working_distance_m: float) -> dict:
    """Error of a point on the optical axis at ``working_distance_m``, mapped into T_x's parent frame.

    ``rms_mm``: sqrt of the covariance trace (the refinement's definition); ``axes_mm`` (3,) per parent
    axis; ``r95_mm``: radius that holds the true point with 95 % probability (3-D Gaussian).
    """
    R = np.asarray(T_x, float)[:3, :3]
    p_cam = np.array([0.0, 0.0, float(working_distance_m)])
    J = R @ np.hstack([-skew(p_cam), np.eye(3)])  # d(point in the parent frame) / d xi, right tangent
    cov_p_mm2 = J @ np.asarray(cov_x_6x6, float) @ J.T * 1e6
    return {
        "rms_mm": float(np.sqrt(max(np.trace(cov_p_mm2), 0.0))),
        "axes_mm": np.sqrt(np.maximum(np.diag(cov_p_mm2), 0.0)),
        "r95_mm": radius95_mm(cov_p_mm2),
        "cov_mm2": cov_p_mm2,
    }


def radius95_mm(cov_mm2: np.ndarray, *, n_samples: int = 60_000) -> float:
    """Radius of the sphere holding 95 % of a zero-mean 3-D Gaussian (deterministic Monte Carlo)."""
    evals = np.clip(np.linalg.eigvalsh(np.asarray(cov_mm2, float)), 0.0, None)
    if not np.any(evals > 0):
        return 0.0
    z = np.random.default_rng(0).standard_normal((n_samples, evals.size))
    r2 = (z**2) @ evals
    return float(np.sqrt(np.quantile(r2, 0.95)))


def ellipse_points(cov_2x2: np.ndarray, *, k_sigma: float, n: int = 120) -> np.ndarray:
    """Points (n, 2) on the k-sigma ellipse of a 2-D covariance, centred at 0."""
    evals, evecs = np.linalg.eigh(np.asarray(cov_2x2, float))
    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    return k_sigma * (circle * np.sqrt(np.clip(evals, 0.0, None))) @ evecs.T


# ------------------------------------------------------------------------------ offsets of the result
def _span(lo: float, hi: float, digits: int) -> str:
    """``lo-hi`` with :func:`.formatting.num`'s digits for ``lo`` on both (a small ``lo`` does not read as 0)."""
    a = num(lo, digits)
    return f"{a}-{num(hi, len(a.partition('.')[2]) if 'e' not in a else digits)}"


def offset_explanation(
    rows: list,
    *,
    limit_sigma: float,
    halves_m2: float | None,
    halves_m2_limit: float,
    robot_mm: float | None,
    robot_deg: float | None,
    robot_model: str,
    tracked: bool = False,
) -> list:
    """Sentences that explain where the result lies against the closed forms and the two halves.

    ``rows``: dicts with ``name``, ``kind`` (closed_form | half), ``d_mm``, ``d_deg``, ``sigma`` (distance in
    verdict sigmas); ``limit_sigma``: a distance above it is a departure; ``halves_m2``: squared Mahalanobis
    distance between the two halves under the sum of their covariances, judged against ``halves_m2_limit``;
    ``tracked``: a pose-only session, whose views' noise is the tracker's (no pixels).
    """
    cf = [r for r in rows if r["kind"] == "closed_form" and np.isfinite(r["sigma"])]
    hv = [r for r in rows if r["kind"] == "half" and np.isfinite(r["sigma"])]
    far = [r for r in cf if r["sigma"] > limit_sigma]
    halves_near = bool(hv) and all(r["sigma"] <= limit_sigma for r in hv)
    halves_split = halves_m2 is not None and np.isfinite(halves_m2) and halves_m2 > halves_m2_limit
    noise = "the tracker's noise" if tracked else "the pixel noise"
    out = []
    if cf and 2 * len(far) > len(cf):
        mm = [r["d_mm"] for r in far]
        deg = [r["d_deg"] for r in far]
        sig = [r["sigma"] for r in far]
        which = "every closed form" if len(far) == len(cf) else f"{len(far)} of the {len(cf)} closed forms"
        s = (
            f"The refined result lies {_span(min(mm), max(mm), 1)} mm and {_span(min(deg), max(deg), 2)}° "
            f"({min(sig):.1f}-{max(sig):.1f} σ) from {which}"
        )
        if halves_near:
            s += (
                ", and each half of the views, refitted alone, lands within "
                f"{max(r['sigma'] for r in hv):.1f} σ of it: the offset is in all of the data, not in a few views."
            )
        else:
            s += "."
        out.append(s)
        off = np.array([r["offset_mm"] for r in cf], float)  # shape (n, 3): closed form minus result
        spread = float(max(np.linalg.norm(a - b) for a in off for b in off)) if len(off) > 1 else 0.0
        if spread >= 0.5 * float(np.median(mm)):
            out.append(
                f"The closed forms scatter among themselves by up to {num(spread, 1)} mm: much of the offset is "
                f"their own error (they ignore {noise} and weigh all motions alike), not the result's."
            )
        if robot_mm is not None and (robot_mm > 0 or (robot_deg or 0) > 0):
            kinematic = robot_model == "kinematic"
            unseen, aside = (
                (
                    "an error of the arm beyond its DH offsets and encoder noise (joint elasticity, "
                    "backlash, a wrong tool or base)",
                    "",
                )
                if kinematic
                else ("a robot error", " (a kinematic error of the arm)")
            )
            out.append(
                f"The refinement models robot-pose errors ({robot_model or 'robot error model'}: "
                f"{num(robot_mm, 2)} mm / {num(robot_deg or 0, 3)}° per view, estimated) and weighs each view by "
                "how well it fits; the closed forms take every robot pose as exact and weigh all motions "
                f"alike, so robot-pose errors bias them. That favours the refinement, but {unseen} that is "
                f"the same in every view{aside} moves the refinement as well, and neither the halves nor the "
                "held-out folds can show it: check the result against an independent measurement"
                + (
                    "."
                    if kinematic
                    else ", calibrate with the arm's kinematic model (--robot ARM), or state the arm's accuracy "
                    "(--robot-accuracy MM DEG) to carry it in the uncertainty."
                )
            )
        else:
            out.append(
                "The refinement weighs each view by "
                + ("the tracker's noise" if tracked else "its pixel noise")
                + "; the closed forms weigh all motions alike and are biased by noise on few or short motions."
            )
    elif far:
        names = ", ".join(r["name"] for r in far)
        out.append(
            f"{names} lie{'s' if len(far) == 1 else ''} more than {limit_sigma:.1f} σ from the result while the "
            "other closed forms agree with it: a closed form biased by noise on this data (linear "
            "solutions such as Andreff's and Li's are the most sensitive to translation noise)."
        )
    if halves_split:
        out.append(
            f"The two halves of the views disagree with each other beyond their uncertainty (squared "
            f"Mahalanobis distance {halves_m2:.1f} under the sum of their covariances; {halves_m2_limit:.1f} "
            "holds 99 % of chance splits): something differs between the halves (the board or the camera "
            "moved, robot drift, temperature, a few bad views), which no covariance of one session covers."
        )
    if not out and (cf or hv):
        out.append(
            f"The result agrees with every closed form and with both halves of the views within "
            f"{limit_sigma:.1f} σ of its verdict covariance."
        )
    return out
