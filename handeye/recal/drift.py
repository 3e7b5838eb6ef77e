"""The drift test of an installed hand-eye matrix against new views (pure math).

:func:`joint_drift_test` estimates the change ``d = X_new - X_old`` jointly with the parameters the new
views share with the install, so their error is not counted twice, and tests ``H0: X_new = X_old`` by
Wald's test (chi-square, or F when the install estimated its robot noise); :func:`drift_test` is the
plain form for older results. :func:`change_in_result_frame` states a change as the result shows X.

See docs/recalibrate.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..frames import inv_T, se3_adjoint, tangent_difference
from ..stats import wald_p_value


@dataclass(frozen=True)
class DriftTest:
    """The test of ``X = X0`` and the change (see the module docstring); tangents in ``X0``'s."""

    statistic: float
    dof: int
    p_value: float
    change_xi: np.ndarray  # (6,) rad, m: X_new - X_old in X0's right tangent, as the test estimates it
    change_cov: np.ndarray  # (6,6): the error of change_xi against the true change
    posterior_xi: np.ndarray  # (6,): the installed and the new information combined, Log(X0^-1 X_post)
    posterior_cov: np.ndarray  # (6,6)
    variance_share: np.ndarray  # (6,) installed over the change's variance per whitened direction, descending
    kind: str = (
        "Wald test of X = X_installed under the installed covariance plus the new views' noise "
        "(the intrinsics not shared)"
    )
    # degrees of freedom of the installed robot noise level both covariances rest on (None: known, chi-square)
    noise_dof: Optional[float] = None
    # (6,6) the new views' own part of change_cov (their noise alone; the rest is the install's error)
    change_cov_new: Optional[np.ndarray] = None

    @property
    def reference(self) -> str:
        """The distribution the p-value is taken from under H0."""
        if self.noise_dof is None:
            return f"chi-square({self.dof})"
        return f"{self.dof} × F({self.dof}, {self.noise_dof:.0f}) (the robot noise level estimated)"


def drift_test(
    *,
    cov_installed: np.ndarray,
    T_x_installed: np.ndarray,
    T_x_new: np.ndarray,
    cov_new: np.ndarray,
    min_variance_share: float = 1e-3,
) -> DriftTest:
    """The Wald test of ``X_new`` against the installed ``X0``.

    The Wald test of ``X_new`` (covariance ``cov_new`` in its right tangent) against the installed
    ``X0`` (``cov_installed``), counting only the directions the new estimate constrains.
    """
    from .compare import x_difference

    diff = x_difference(T_x_installed, cov_installed, T_x_new, cov_new)
    d, S = diff["xi"], diff["S"]
    S0 = 0.5 * (cov_installed + cov_installed.T)
    S_new = S - S0  # S = S0 + Ad cov_new Ad^T
    T, dof, p, lam, Q, proj = _whitened_wald(d, S, S0, min_variance_share)
    L = np.linalg.cholesky(S0)
    lam = np.minimum(lam, 1.0)  # S >= S0: the new views' share of the combined information
    post_xi = L @ (Q @ (proj * lam))
    post_cov = L @ (Q * (1.0 - lam)) @ Q.T @ L.T
    return DriftTest(
        statistic=T,
        dof=dof,
        p_value=p,
        change_xi=d,
        change_cov=S,
        posterior_xi=post_xi,
        posterior_cov=post_cov,
        variance_share=lam,
        change_cov_new=0.5 * (S_new + S_new.T),
    )


def joint_drift_test(
    *,
    T_x_installed: np.ndarray,
    cov_installed: np.ndarray,
    cov_xk_installed: np.ndarray,
    cov_kk_installed: np.ndarray,
    T_x_new: np.ndarray,
    dk_new: np.ndarray,
    cov_new: np.ndarray,
    cov_k_prior: np.ndarray,
    cov_x_prior: np.ndarray,
    min_variance_share: float = 1e-3,
) -> DriftTest:
    """The Wald test of ``X_new = X0`` with the installed intrinsics as the new views' prior.

    The Wald test of ``X_new = X0`` when the new views were refined with the installed intrinsics ``K0`` as
    their prior: the installed ``(X0, K0)`` and the new views share the intrinsics' error, so the new views'
    information is taken apart from that prior and the change is estimated jointly (module docstring).

    ``cov_installed`` (6,6), ``cov_xk_installed`` (6,k), ``cov_kk_installed`` (k,k): the installed joint
    covariance of X's tangent and the free intrinsics; ``T_x_new`` and ``dk_new`` (k,) = ``K_new - K0``: the
    new views' refinement with covariance ``cov_new`` (6+k, 6+k; X in its own right tangent) under the priors
    ``N(X0, cov_x_prior)`` and ``N(K0, cov_k_prior)``.
    """
    nk = len(dk_new)
    Ad = se3_adjoint(inv_T(T_x_installed) @ T_x_new)
    A = np.eye(6 + nk)
    A[:6, :6] = Ad
    # the algebra in units of the installed sigmas: radians, metres, pixels and distortion coefficients
    # differ by orders of magnitude, and the new views' information is a difference of two inverses
    s_x = np.sqrt(np.diag(cov_installed))
    scale = np.r_[s_x, np.sqrt(np.diag(cov_kk_installed))]
    Dn = np.diag(1.0 / scale)
    P_v = Dn @ A @ cov_new @ A.T @ Dn  # the refinement's posterior with X in X0's tangent
    m_v = Dn @ np.r_[tangent_difference(T_x_installed, T_x_new), dk_new]
    info_v = _inv_sym(P_v)
    eta = info_v @ m_v  # both priors are centred at (X0, K0): zero in these coordinates
    H = info_v.copy()
    H[:6, :6] -= _inv_sym(Dn[:6, :6] @ cov_x_prior @ Dn[:6, :6])
    H[6:, 6:] -= _inv_sym(Dn[6:, 6:] @ cov_k_prior @ Dn[6:, 6:])  # the new views' own information on (X_new, K)
    S_inst = np.block([[cov_installed, cov_xk_installed], [cov_xk_installed.T, cov_kk_installed]])
    J_inst = _inv_sym(Dn @ S_inst @ Dn)
    # unknowns (X_old, K, X_new): the installed information on (X_old, K), the new views' on (X_new, K)
    n = 12 + nk
    xo, kk, xn = slice(0, 6), slice(6, 6 + nk), slice(6 + nk, n)
    J = np.zeros((n, n))
    J[: 6 + nk, : 6 + nk] += J_inst
    iv = np.r_[np.arange(6 + nk, n), np.arange(6, 6 + nk)]  # (X_new, K) in the order of H
    J[np.ix_(iv, iv)] += H
    b = np.zeros(n)
    b[iv] = eta
    Sigma = _inv_sym(J)
    theta = Sigma @ b
    d = s_x * (theta[xn] - theta[xo])
    V = np.outer(s_x, s_x) * (Sigma[xn, xn] + Sigma[xo, xo] - Sigma[xn, xo] - Sigma[xo, xn])
    V = 0.5 * (V + V.T)
    # the new views' part of V: their noise enters through eta alone (cov H), Sigma[.., iv] H Sigma[iv, ..]
    E = np.zeros((6, n))
    E[:, xn], E[:, xo] = np.eye(6), -np.eye(6)
    G = (E @ Sigma)[:, iv]
    V_new = np.outer(s_x, s_x) * (G @ H @ G.T)
    T, dof, p, lam, _, _ = _whitened_wald(d, V, cov_installed, min_variance_share)
    # under H0 (X_new = X_old): the two share one X
    J0 = J[: 6 + nk, : 6 + nk].copy()
    J0[:6, :6] += J[xn, xn]
    J0[:6, 6:] += J[xn, kk]
    J0[6:, :6] += J[kk, xn]
    S_post = _inv_sym(J0)
    post = S_post @ np.r_[b[xn], b[kk]]
    return DriftTest(
        statistic=T,
        dof=dof,
        p_value=p,
        change_xi=d,
        change_cov=V,
        posterior_xi=s_x * post[:6],
        posterior_cov=np.outer(s_x, s_x) * S_post[:6, :6],
        variance_share=lam,
        kind=JOINT_KIND,
        change_cov_new=0.5 * (V_new + V_new.T),
    )


JOINT_KIND = (
    "Wald test of X = X_installed, the change estimated jointly with the intrinsics the new views share "
    "with the installed calibration (its joint covariance of X and the intrinsics)"
)
JOINT_DH_KIND = (
    "Wald test of X = X_installed, the change estimated jointly with the intrinsics and the arm's DH "
    "offsets the new views share with the installed calibration (its joint covariance of X, the "
    "intrinsics and the DH offsets)"
)


def _inv_sym(M: np.ndarray) -> np.ndarray:
    """The inverse of a symmetric positive definite matrix (symmetrised)."""
    M = 0.5 * (M + M.T)
    Li = np.linalg.inv(np.linalg.cholesky(M))
    return Li.T @ Li


def _whitened_wald(d: np.ndarray, V: np.ndarray, S0: np.ndarray, min_variance_share: float):
    """Wald statistic of the change ``d`` (6,) with covariance ``V`` over its well-measured directions.

    Wald statistic of the change ``d`` (6,) with covariance ``V`` over the directions where ``V`` is at most
    ``S0 / min_variance_share`` (whitened by ``S0 = L L^T``: ``W = L^-1 V L^-T = Q diag(w) Q^T``,
    ``lambda = 1 / w``): (statistic, dof, p, lambda descending, Q, projections of ``L^-1 d``).
    """
    L = np.linalg.cholesky(0.5 * (S0 + S0.T))
    Li = np.linalg.inv(L)
    W = Li @ V @ Li.T
    w, Q = np.linalg.eigh(0.5 * (W + W.T))
    lam = 1.0 / np.maximum(w, 1e-12)
    order = np.argsort(lam)[::-1]
    lam, Q = lam[order], Q[:, order]
    keep = lam >= float(min_variance_share)
    proj = Q.T @ (Li @ d)
    T = float(np.sum(proj[keep] ** 2 * lam[keep]))
    dof = int(keep.sum())
    return T, dof, wald_p_value(T, dof), lam, Q, proj


def change_in_result_frame(T_x0: np.ndarray, xi: np.ndarray, cov: np.ndarray) -> dict:
    """A tangent change of ``X0`` as the result shows X, with its 1-sigma.

    A tangent change of ``X0`` as the result shows X: translation (mm) along the parent frame's
    axes, rotation (deg) about the camera axes, with 1-sigma of each (first order).
    """
    R = T_x0[:3, :3]
    cov_t = R @ cov[3:, 3:] @ R.T
    d_t = 1000.0 * (R @ xi[3:])
    d_r = np.degrees(xi[:3])
    return {
        "d_trans_mm": d_t,
        "sigma_trans_mm": 1000.0 * np.sqrt(np.maximum(np.diag(cov_t), 0.0)),
        "d_rot_deg": d_r,
        "sigma_rot_deg": np.degrees(np.sqrt(np.maximum(np.diag(cov[:3, :3]), 0.0))),
        "trans_mm": float(np.linalg.norm(d_t)),
        "rot_deg": float(np.linalg.norm(d_r)),
    }
