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
    return {"rms_mm": float(np.sqrt(max(np.trace(cov_p_mm2), 0.0))),
            "axes_mm": np.sqrt(np.maximum(np.diag(cov_p_mm2), 0.0)),
            "r95_mm": radius95_mm(cov_p_mm2), "cov_mm2": cov_p_mm2}


def radius95_mm(cov_mm2: np.ndarray, *, n_samples: int = 60_000) -> float:
    """Radius of the sphere holding 95 % of a zero-mean 3-D Gaussian (deterministic Monte Carlo)."""
    evals = np.clip(np.linalg.eigvalsh(np.asarray(cov_mm2, float)), 0.0, None)
    if not np.any(evals > 0):
        return 0.0
    z = np.random.default_rng(0).standard_normal((n_samples, evals.size))
    r2 = (z ** 2) @ evals
    return float(np.sqrt(np.quantile(r2, 0.95)))


def ellipse_points(cov_2x2: np.ndarray, *, k_sigma: float, n: int = 120) -> np.ndarray:
    """Points (n, 2) on the k-sigma ellipse of a 2-D covariance, centred at 0."""
    evals, evecs = np.linalg.eigh(np.asarray(cov_2x2, float))
    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    return k_sigma * (circle * np.sqrt(np.clip(evals, 0.0, None))) @ evecs.T
