"""Covariance algebra of the refinement (pure numpy): the arrow-shaped information and derived forms.

The information of the refinement has an arrow structure: a dense core (``T_x``, ``T_board``, the
free intrinsics; ``c`` unknowns) and one 6x6 block per robot-pose variable that couples only with
the core. A Schur complement on the core inverts it exactly in O(n) instead of O(n^3). The forms
derived from the hand-eye covariance are sigmas, correlations and the predicted error.

Pose covariances are in the one tangent of :mod:`handeye.frames` (rotation first, right
perturbation): ``T_x,true = T_x · Exp(xi)``, ``xi = (omega [rad], v [m])`` along the child frame of
``T_x`` (the camera). See docs/uncertainty.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Optional, Sequence

import numpy as np

from ..frames import skew

N_POSES = 12  # T_x and T_board: the first 12 unknowns of the core, before the free intrinsics
COV_PARAMETRISATION = (
    "GTSAM Pose3 tangent, right perturbation: T_x_true = T_x · Exp(xi), xi = (omega_x, omega_y, omega_z [rad], "
    "v_x, v_y, v_z [m]), rotation first; omega and v along the axes of the camera frame (child frame of T_x)"
)
COV_BOARD_PARAMETRISATION = (
    "GTSAM Pose3 tangent, right perturbation: T_board_true = T_board · Exp(xi), xi = (omega [rad], v [m]), "
    "rotation first; along the axes of the board frame (child frame of T_board)"
)


def arrow_blocks(H: np.ndarray, c: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Hcc (c,c), Hcp (n,c,6), Hpp (n,6,6)) of a dense information matrix in arrow order."""
    Hcp = H[:c, c:].reshape(c, n, 6).transpose(1, 0, 2)
    blocks = H[c:, c:].reshape(n, 6, n, 6)
    ar = np.arange(n)
    return H[:c, :c], Hcp, blocks[ar, :, ar, :]


def arrow_inverse(H: np.ndarray, c: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal blocks of inv(H) for an arrow-shaped information matrix.

    Diagonal blocks of inv(H) for an information matrix with a dense core of size c followed by
    n 6x6 blocks that couple only with the core: (Sigma_core (c,c), Sigma_blocks (n,6,6)).
    """
    S_cc, S_pp, _ = arrow_solve(*arrow_blocks(H, c, n))
    return S_cc, S_pp


def arrow_solve(
    Hcc: np.ndarray, Hcp: np.ndarray, Hpp: np.ndarray, rhs: Optional[np.ndarray] = None, *, cross: bool = False
) -> tuple[Any, ...]:
    """Schur-complement inverse of the arrow-shaped information [[Hcc, Hcp^T...], [Hcp_i^T, Hpp_i]].

    Returns (Sigma_core, Sigma_blocks (n,6,6), solution of H x = rhs or None), and with ``cross`` also
    the core-block cross covariances (n,c,6) ``-Sigma_core Hcp_i Hpp_i^-1``. Raises LinAlgError
    when H is not positive definite (some unknown is not constrained).
    """
    n = Hpp.shape[0]
    if n == 0:
        L = np.linalg.cholesky(Hcc)
        Li = np.linalg.inv(L)
        S_cc = Li.T @ Li
        out = (S_cc, np.zeros((0, 6, 6)), None if rhs is None else S_cc @ rhs)
        return out + (np.zeros((0, Hcc.shape[0], 6)),) if cross else out
    np.linalg.cholesky(Hpp)  # raises LinAlgError when a robot pose is unconstrained
    Q = np.linalg.inv(Hpp)
    HQ = Hcp @ Q  # shape (n, c, 6)
    S = Hcc - np.tensordot(HQ, Hcp, axes=([0, 2], [0, 2]))
    L = np.linalg.cholesky(0.5 * (S + S.T))
    Li = np.linalg.inv(L)
    S_cc = Li.T @ Li
    S_pp = Q + np.swapaxes(HQ, 1, 2) @ S_cc @ HQ
    x = None
    if rhs is not None:
        c = Hcc.shape[0]
        b_c, b_p = rhs[:c], rhs[c:].reshape(n, 6)
        x_c = S_cc @ (b_c - np.einsum("nci,ni->c", HQ, b_p))
        x_p = np.einsum("nij,nj->ni", Q, b_p - np.einsum("nci,c->ni", Hcp, x_c))
        x = np.concatenate([x_c, x_p.reshape(-1)])
    if cross:
        return S_cc, S_pp, x, -(S_cc @ HQ)
    return S_cc, S_pp, x


def arrow_from_jacobians(
    factors: Iterable[tuple[np.ndarray, np.ndarray, Sequence[tuple[int, int]]]], c: int, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Gauss-Newton blocks of whitened linear factors ``|A dx - b|^2`` in arrow order.

    ``factors``: (A (r,d), b (r,), per variable of A's columns in order: (offset in the core, or -1 - j for
    robot block j, its dimension)). Returns (Hcc (c,c), Hcp (n,c,6), Hpp (n,6,6), gradient (c + 6n,) of half
    the squared error, cost = half the squared error); a factor couples at most one robot block.
    """
    Hcc, Hcp, Hpp, grad = np.zeros((c, c)), np.zeros((n, c, 6)), np.zeros((n, 6, 6)), np.zeros(c + 6 * n)
    cost = 0.0
    for A, b, slots in factors:
        cost += 0.5 * float(b @ b)
        cols, col = [], 0
        for o, d in slots:
            cols.append((o, A[:, col : col + d]))
            col += d
        for o, Ja in cols:
            at = o if o >= 0 else c + 6 * (-1 - o)
            grad[at : at + Ja.shape[1]] -= Ja.T @ b
            for o2, Jb in cols:
                if o >= 0 and o2 >= 0:
                    Hcc[o : o + Ja.shape[1], o2 : o2 + Jb.shape[1]] += Ja.T @ Jb
                elif o >= 0:
                    Hcp[-1 - o2, o : o + Ja.shape[1]] += Ja.T @ Jb
                elif o2 < 0:
                    if o != o2:
                        raise ValueError("a factor couples two robot blocks")
                    Hpp[-1 - o] += Ja.T @ Jb
    return Hcc, Hcp, Hpp, grad, cost


def robot_residual_covariances(
    S_cc: np.ndarray, S_pp: np.ndarray, S_cp: np.ndarray, J_dh: np.ndarray, dh: slice
) -> np.ndarray:
    """(n,6,6) covariance of each robot prior residual ``u_i = p_i - J_dh,i · delta``.

    (n,6,6) covariance of each robot prior residual ``u_i = p_i - J_dh,i · delta`` (p_i: the robot-pose
    block, delta: the DH offsets at ``dh`` in the core) from the marginals of :func:`arrow_solve`
    (``S_cp`` its cross covariances). Without DH offsets (m = 0) it is ``S_pp``.
    """
    if J_dh.shape[-1] == 0 or len(S_pp) == 0:
        return np.array(S_pp, float).reshape(-1, 6, 6)
    S_dp = S_cp[:, dh, :]  # shape (n, m, 6)
    S_dd = S_cc[dh, dh]
    JS = np.einsum("nim,nmj->nij", J_dh, S_dp)
    return S_pp - JS - np.swapaxes(JS, 1, 2) + J_dh @ S_dd @ np.swapaxes(J_dh, 1, 2)


def robot_prior_parts(
    S_cc: np.ndarray, S_cp: np.ndarray, J_dh: np.ndarray, dh: slice, weights: Sequence[np.ndarray], k: int = 6
) -> np.ndarray:
    """(g, k, k) the part of the first ``k`` core unknowns' covariance that each robot-prior group carries.

    With the information a sum over the sources, ``Sigma = Sigma H Sigma`` splits the covariance into one part
    per source, ``Sigma H_g Sigma``. A group of the robot priors (information ``W_g,i`` on the residual
    ``u_i = p_i - J_dh,i · delta`` of robot block i) carries ``sum_i C_i W_g,i C_i^T`` of the first ``k`` core
    unknowns, ``C_i = Cov(core[:k], u_i) = S_cp,i[:k] - S_cc[:k, dh] J_dh,i^T`` (``S_cp``: the cross covariances
    of :func:`arrow_solve`). ``weights``: per group, (n, 6, 6) its information on each block's residual.
    """
    C = np.asarray(S_cp, float)[:, :k, :]
    if J_dh.shape[-1] and len(C):
        C = C - np.einsum("xm,nim->nxi", S_cc[:k, dh], J_dh)
    return np.stack([np.einsum("nxi,nij,nyj->xy", C, W, C) for W in weights]) if len(weights) else np.zeros((0, k, k))


@dataclass(frozen=True)
class HandEyeUncertainty:
    """Forms derived from the 6x6 covariance of ``T_x`` (see :func:`hand_eye_uncertainty`)."""

    cov_x_6x6: np.ndarray  # symmetrised covariance, COV_PARAMETRISATION
    sigma_rot_deg: np.ndarray  # (3,) about the camera axes
    sigma_trans_mm: np.ndarray  # (3,) translation vector of T_x along the parent frame's axes
    correlation_6x6: np.ndarray
    predicted_error_mm: float  # RMS 3-D error of a point on the optical axis at the working distance
    predicted_error_axes_mm: np.ndarray  # (3,) per parent-frame axis


def hand_eye_uncertainty(cov_x: Optional[np.ndarray], T_x: np.ndarray, working_distance_m: float) -> HandEyeUncertainty:
    """Sigmas, correlations and the predicted error at the working distance from ``cov_x`` (6,6).

    Sigmas, correlations and the predicted error at the working distance from ``cov_x`` (6,6)
    (None: all NaN).

    The translation sigmas are those of ``T_x``'s translation vector in the parent frame
    (``R · cov_v · R^T``); the predicted error is the RMS (sqrt of the covariance trace) of the
    point ``(0, 0, working_distance_m)`` of the camera frame mapped into the parent frame by
    ``T_x``, to first order: ``d p / d xi = R · [-[p]x, I]``.
    """
    cov = np.full((6, 6), np.nan) if cov_x is None else 0.5 * (cov_x + cov_x.T)
    sd = np.sqrt(np.diag(cov))
    R = T_x[:3, :3]
    p_cam = np.array([0.0, 0.0, working_distance_m])
    J = R @ np.hstack([-skew(p_cam), np.eye(3)])  # d(point in parent frame)/d xi
    cov_p = J @ cov @ J.T
    return HandEyeUncertainty(
        cov_x_6x6=cov,
        sigma_rot_deg=np.degrees(sd[:3]),
        sigma_trans_mm=1000.0 * np.sqrt(np.diag(R @ cov[3:, 3:] @ R.T)),
        correlation_6x6=cov / np.outer(sd, sd),
        predicted_error_mm=float(1000.0 * np.sqrt(np.trace(cov_p))),
        predicted_error_axes_mm=1000.0 * np.sqrt(np.diag(cov_p)),
    )
