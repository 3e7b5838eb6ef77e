"""Numbers the report shows that result.json does not hold directly.

Everything here works from result.json + observations.json (plain dicts), so that a report can be
rebuilt without the run. Pure functions, no I/O except :func:`camera_only_fits` calling OpenCV.

Conventions: ``T_a_b`` maps points of b into a; the covariance of the hand-eye transform ``T_x`` is
GTSAM's Pose3 tangent, right perturbation ``T_x,true = T_x · Exp(xi)``, ``xi = (omega [rad], v [m])``
(rotation first), both along the axes of the camera frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
from scipy.spatial.transform import Rotation

from ..conventions import vendor_euler_from_R
from ..frames import inv_T, make_T

Z95 = 1.959963984540054  # two-sided 95 % quantile of the standard normal


# ------------------------------------------------------------------------------ small helpers
def finite(x) -> bool:
    try:
        return x is not None and bool(np.all(np.isfinite(np.asarray(x, float))))
    except (TypeError, ValueError):
        return False


def _finite_array(x, shape: tuple) -> Optional[np.ndarray]:
    """A float array of ``shape`` from nested lists, or None when absent, malformed or not finite."""
    if x is None:
        return None
    try:
        a = np.asarray(x, float)
    except (TypeError, ValueError):
        return None
    return a if a.shape == shape and np.all(np.isfinite(a)) else None


def as_T(x) -> Optional[np.ndarray]:
    """A 4x4 float array from nested lists, or None when absent or not a finite 4x4."""
    return _finite_array(x, (4, 4))


def as_cov6(x) -> Optional[np.ndarray]:
    C = _finite_array(x, (6, 6))
    return None if C is None else 0.5 * (C + C.T)


def intrinsics_arrays(intr: dict | None):
    """(K (3,3), dist (5,), (width, height)) from result.json's ``intrinsics``, or None."""
    if not intr:
        return None
    try:
        K = np.array([[intr["fx"], 0.0, intr["cx"]], [0.0, intr["fy"], intr["cy"]], [0.0, 0.0, 1.0]], float)
        d = intr.get("dist", {})
        dist = np.array([d.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")], float) if isinstance(d, dict) \
            else np.asarray(d, float).reshape(-1)[:5]
        size = tuple(int(v) for v in intr.get("image_size", (0, 0)))
    except (KeyError, TypeError, ValueError):
        return None
    return K, dist, size


# ------------------------------------------------------------------------------ uncertainty
def _exp_se3_first_order(xi: np.ndarray) -> np.ndarray:
    """Exp of a Pose3 tangent (omega, v); exact rotation, translation v (enough for derivatives at 0)."""
    return make_T(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])


def _wrap_rad(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def tangent_jacobian(T_x: np.ndarray, f: Callable[[np.ndarray], np.ndarray], *, h: float = 1e-6,
                     angular: bool = False) -> np.ndarray:
    """Central-difference Jacobian (m, 6) of ``f(T_x · Exp(xi))`` at ``xi = 0``.

    ``angular``: the outputs are angles in radians; differences are wrapped to (-pi, pi].
    """
    cols = []
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        d = f(T_x @ _exp_se3_first_order(e)) - f(T_x @ _exp_se3_first_order(-e))
        cols.append((_wrap_rad(d) if angular else d) / (2.0 * h))
    return np.stack(cols, axis=1)


def _quat_wxyz_aligned(T: np.ndarray, ref: np.ndarray) -> np.ndarray:
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    q = np.array([q[3], q[0], q[1], q[2]])
    return q if q @ ref >= 0 else -q


def quat_wxyz(T: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0."""
    q = Rotation.from_matrix(np.asarray(T, float)[:3, :3]).as_quat()
    q = np.array([q[3], q[0], q[1], q[2]])
    return q if q[0] >= 0 else -q


def form_sigmas(T_x: np.ndarray, cov_x_6x6: np.ndarray) -> dict:
    """1-sigma of every representation of ``T_x`` propagated from its tangent covariance.

    Returns ``translation_mm`` (3,), ``quaternion_wxyz`` (4,), ``rotvec_deg`` (3,), ``euler_vendor_deg``
    (3,) (R = Rz·Ry·Rx), ``rot_cam_deg`` (3,) (rotation about the camera axes), each a 1-sigma array,
    and ``cov_translation_mm2`` (3, 3) in the parent frame.
    """
    T_x = np.asarray(T_x, float)
    C = np.asarray(cov_x_6x6, float)
    q0 = quat_wxyz(T_x)
    rv0 = Rotation.from_matrix(T_x[:3, :3]).as_rotvec()

    def sig(J):
        return np.sqrt(np.maximum(np.diag(J @ C @ J.T), 0.0))

    J_t = tangent_jacobian(T_x, lambda T: T[:3, 3] * 1e3)
    J_q = tangent_jacobian(T_x, lambda T: _quat_wxyz_aligned(T, q0))

    def rotvec_near(T):  # the rotation vector on the same branch as the nominal one
        rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        ang = np.linalg.norm(rv)
        if ang > 1e-9 and rv @ rv0 < 0:
            rv = rv / ang * (ang - 2.0 * np.pi)
        return rv

    J_rv = tangent_jacobian(T_x, rotvec_near)
    J_e = tangent_jacobian(T_x, lambda T: vendor_euler_from_R(T[:3, :3]), angular=True)
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
    p = np.array([0.0, 0.0, float(working_distance_m)])
    S = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
    J = R @ np.hstack([-S, np.eye(3)])  # d(point in parent frame) / d xi
    cov_p_mm2 = J @ np.asarray(cov_x_6x6, float) @ J.T * 1e6
    return {"rms_mm": float(np.sqrt(max(np.trace(cov_p_mm2), 0.0))),
            "axes_mm": np.sqrt(np.maximum(np.diag(cov_p_mm2), 0.0)),
            "r95_mm": radius95_mm(cov_p_mm2), "cov_mm2": cov_p_mm2}


def radius95_mm(cov_mm2: np.ndarray, *, n_samples: int = 200_000) -> float:
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


# ------------------------------------------------------------------------------ per view
@dataclass(frozen=True)
class ViewFit:
    """One view's corners against the board pose that its corners alone imply (final intrinsics)."""

    view_id: str
    corner_ids: np.ndarray  # (N,)
    image_points_px: np.ndarray  # (N, 2)
    residual_px: np.ndarray  # (N, 2) detected - predicted, camera-only fit
    T_cam_board: Optional[np.ndarray]
    residual_chain_px: Optional[np.ndarray]  # (N, 2) through the reported robot pose and the result
    T_cam_board_chain: Optional[np.ndarray]

    @property
    def rms_px(self) -> float:
        return rms_norm(self.residual_px)

    @property
    def max_px(self) -> float:
        return float(np.linalg.norm(self.residual_px, axis=1).max()) if len(self.residual_px) else float("nan")

    @property
    def chain_rms_px(self) -> float:
        return rms_norm(self.residual_chain_px) if self.residual_chain_px is not None else float("nan")


def rms_norm(r) -> float:
    r = np.asarray(r, float).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) if len(r) else float("nan")


def camera_only_fits(obs: dict, intrinsics: dict | None) -> dict[str, ViewFit]:
    """Each view's board pose from its corners alone, and the residuals of that fit.

    observations.json already holds them under the final intrinsics (``T_cam_board_pnp``,
    ``residual_pnp_px``); a view without them (e.g. a hand-edited file) is fitted here (OpenCV PnP).
    """
    import cv2

    arrs = intrinsics_arrays(intrinsics)
    obj_all = np.asarray(obs.get("object_points_m") or [], float).reshape(-1, 3)
    out: dict[str, ViewFit] = {}
    for vid, v in (obs.get("views") or {}).items():
        try:
            ids = np.asarray(v["corner_ids"], int)
            uv = np.asarray(v["image_points_px"], float).reshape(-1, 2)
        except (KeyError, TypeError, ValueError):
            continue
        T0 = as_T(v.get("T_cam_board_pnp"))
        Tc = as_T(v.get("T_cam_board_chain"))
        chain = v.get("residual_chain_px")
        chain = np.asarray(chain, float).reshape(-1, 2) if chain is not None else None
        resid = np.asarray(v.get("residual_pnp_px") or np.full((len(ids), 2), np.nan), float).reshape(-1, 2)
        T_fit = T0
        have_fit = T0 is not None and len(resid) == len(ids) and np.all(np.isfinite(resid))
        if (not have_fit and arrs is not None and len(ids) >= 4 and obj_all.size
                and ids.max(initial=-1) < len(obj_all)):
            K, dist, _ = arrs
            P = obj_all[ids]
            ok, rvec, tvec = cv2.solvePnP(P, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
            if ok:
                T_fit = make_T(cv2.Rodrigues(rvec)[0], tvec.ravel())
                proj = cv2.projectPoints(P, rvec, tvec, K, dist)[0].reshape(-1, 2)
                resid = uv - proj
        out[str(vid)] = ViewFit(str(vid), ids, uv, resid, T_fit, chain, Tc)
    return out


def board_disagreement(fit: ViewFit, board_centre_m: np.ndarray) -> tuple[float, float]:
    """(deg, mm) between the board pose the camera saw and the one predicted through the robot chain."""
    if fit.T_cam_board is None or fit.T_cam_board_chain is None:
        return float("nan"), float("nan")
    D = inv_T(fit.T_cam_board) @ fit.T_cam_board_chain
    ang = float(np.degrees(np.linalg.norm(Rotation.from_matrix(D[:3, :3]).as_rotvec())))
    c = np.append(board_centre_m, 1.0)
    mm = float(1e3 * np.linalg.norm((fit.T_cam_board @ c)[:3] - (fit.T_cam_board_chain @ c)[:3]))
    return ang, mm


# ------------------------------------------------------------------------------ coverage and motion
def coverage_counts(points_px: np.ndarray, *, width: int, height: int, cells_x: int = 16) -> np.ndarray:
    """Corner counts in a grid of square-ish cells over the image (rows, cols)."""
    cells_y = max(1, int(round(cells_x * height / max(width, 1))))
    pts = np.asarray(points_px, float).reshape(-1, 2)
    counts = np.zeros((cells_y, cells_x), int)
    if len(pts):
        cx = np.clip((pts[:, 0] / width * cells_x).astype(int), 0, cells_x - 1)
        cy = np.clip((pts[:, 1] / height * cells_y).astype(int), 0, cells_y - 1)
        np.add.at(counts, (cy, cx), 1)
    return counts


def relative_rotvecs(T_base_end: np.ndarray, *, mode: str) -> np.ndarray:
    """Rotation vectors (P, 3) of all pairwise robot motions ``M_i · M_j^-1`` (as the seed's motion check).

    Eye-in-hand ``M = T_end_base`` (axes in the end frame), eye-to-hand ``M = T_base_end`` (base frame).
    """
    T = np.asarray(T_base_end, float).reshape(-1, 4, 4)
    if len(T) < 2:
        return np.zeros((0, 3))
    M = inv_T(T) if mode == "eye_in_hand" else T
    iu, ju = np.triu_indices(len(M), 1)
    rel = M[iu] @ inv_T(M[ju])
    return Rotation.from_matrix(rel[:, :3, :3]).as_rotvec()


def axis_spread(rotvecs: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(max rotation deg, axis spread deg, weak axes (2, 3)) of relative rotations, as the seed measures them."""
    rv = np.asarray(rotvecs, float).reshape(-1, 3)
    if not len(rv):
        return 0.0, 0.0, np.eye(3)[:2]
    ang = np.linalg.norm(rv, axis=1)
    W = rv * np.minimum(ang, np.pi / 2)[:, None] / np.maximum(ang, 1e-12)[:, None]
    evals, evecs = np.linalg.eigh(W.T @ W)
    spread = float(np.degrees(np.arctan2(np.sqrt(max(evals[1], 0)), np.sqrt(max(evals[2], 1e-30)))))
    return float(np.degrees(ang.max())), spread, evecs[:, :2].T


def fmt_axis(a: np.ndarray) -> str:
    a = np.asarray(a, float)
    a = a / max(np.linalg.norm(a), 1e-12)
    a = a if a[np.argmax(np.abs(a))] >= 0 else -a
    names = "xyz"
    k = int(np.argmax(np.abs(a)))
    if abs(a[k]) > 0.95:
        return f"{names[k]}"
    return "[" + ", ".join(f"{x:+.2f}" for x in a) + "]"
