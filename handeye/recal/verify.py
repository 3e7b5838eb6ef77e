"""Verify an installed calibration with a few new views, without re-solving it.

The new views are refined with X free, the installed intrinsics (and a kinematic install's DH
offsets) as priors and the board a nuisance. :func:`joint_drift_test` estimates the change
``d = X_new - X_old`` jointly with the parameters the views share with the install, so their error is
not counted twice, and tests ``H0: X_new = X_old`` by Wald's test (chi-square, or F when the install
estimated its robot noise); :func:`drift_test` is the plain form for older results. The report says
what moved: the camera mount, the board, robot poses or the intrinsics.

See docs/recalibrate.md.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..config import load_preset
from ..errors import CalibrationError, InputError
from ..frames import inv_T, mean_T, pose_error, rotvec_from_R, se3_adjoint, se3_exp, tangent_difference
from ..mounting import mounting
from ..output import plain
from ..stats import wald_p_value
from .loaded import VAGUE_COV_X, LoadedResult, installed_prior

log = logging.getLogger(__name__)


def _from_preset(section: str, key: str):
    return field(default_factory=lambda: float(load_preset("recal")[section][key]))


@dataclass(frozen=True)
class VerifyOptions:
    """Settings of a verification (defaults: configs/recal.yaml, where each is explained)."""

    alpha: float = _from_preset("test", "alpha")
    min_variance_share: float = _from_preset("test", "min_variance_share")
    board_sigmas: float = _from_preset("board", "sigmas")
    board_min_mm: float = _from_preset("board", "min_mm")
    board_min_deg: float = _from_preset("board", "min_deg")

    @staticmethod
    def from_config(cfg: Optional[dict] = None, **overrides) -> "VerifyOptions":
        """From a ``recal`` preset (default: the shipped one), with the overrides that are not None."""
        cfg = load_preset("recal") if cfg is None else cfg
        kw = dict(
            alpha=float(cfg["test"]["alpha"]),
            min_variance_share=float(cfg["test"]["min_variance_share"]),
            board_sigmas=float(cfg["board"]["sigmas"]),
            board_min_mm=float(cfg["board"]["min_mm"]),
            board_min_deg=float(cfg["board"]["min_deg"]),
        )
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return VerifyOptions(**kw)


# ------------------------------------------------------------------------------ the test (pure math)
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

    @property
    def reference(self) -> str:
        """The distribution the p-value is taken from under H0."""
        if self.noise_dof is None:
            return f"chi-square({self.dof})"
        return f"{self.dof} F({self.dof}, {self.noise_dof:.0f}) (the robot noise level estimated)"


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


# ------------------------------------------------------------------------------ the verification
@dataclass(frozen=True)
class Verification:
    """The outcome of :func:`verify_views` (``to_dict`` is verify.json's body)."""

    verdict: str  # "still valid" | "drifted"
    headline: str
    mode: str
    frame: str
    test: DriftTest
    alpha: float
    change: dict  # change_in_result_frame of test.change_xi
    T_x_installed: np.ndarray
    T_x_posterior: np.ndarray
    cov_x_posterior: np.ndarray
    board: dict  # installed vs new board pose, moved: bool
    robot: dict  # views whose robot pose disagrees with the camera
    intrinsics: dict  # source (installed | session) and the update per name
    what_moved: tuple  # lines for people
    views: dict  # view_id -> {status, rms_px, ...}
    n_views: int
    sigma_px: float
    cov_source: str
    seconds: float
    refined: object = field(default=None, repr=False)

    @property
    def drifted(self) -> bool:
        return self.verdict == "drifted"

    def to_dict(self) -> dict:
        t = self.test
        return plain(
            {
                "verdict": self.verdict,
                "headline": self.headline,
                "drifted": self.drifted,
                "mode": self.mode,
                "frame": self.frame,
                "test": {
                    "kind": t.kind,
                    "statistic": t.statistic,
                    "dof": t.dof,
                    "p_value": t.p_value,
                    "alpha": self.alpha,
                    "reference": t.reference,
                    "robot_noise_dof": t.noise_dof,
                    "variance_share": t.variance_share,
                    "covariance_used": self.cov_source,
                },
                "change": dict(
                    self.change,
                    xi_rad_m=t.change_xi,
                    cov_6x6=t.change_cov,
                    definition=(
                        "X_new - X_installed in X_installed's right tangent, as the test estimates "
                        "it (see test.kind); sigma: its 1-sigma, the installed and the new views' "
                        "uncertainty; translation along the parent frame's axes, rotation about "
                        "the camera axes"
                    ),
                ),
                "installed": {self.frame: self.T_x_installed},
                "posterior": {self.frame: self.T_x_posterior, "cov_x_6x6": self.cov_x_posterior},
                "board": self.board,
                "robot": self.robot,
                "intrinsics": self.intrinsics,
                "what_moved": list(self.what_moved),
                "views": self.views,
                "n_views": self.n_views,
                "sigma_px": self.sigma_px,
                "seconds": self.seconds,
            },
            nan_to_none=True,
        )


def nearest_board_turn(
    T_board_installed: Optional[np.ndarray], T_board_new: np.ndarray, turns: Sequence[np.ndarray]
) -> np.ndarray:
    """The board turn ``H`` that brings the installed board frame nearest the new one.

    Of the identity and ``turns`` (board-frame motions of a symmetric board's other numberings), the ``H``
    that brings the installed board frame nearest the new one (``T_board_installed H`` against
    ``T_board_new``, by rotation, then translation): a later session may number such a board from another
    corner. Identity when there is no installed board or no turn.
    """
    H = [np.eye(4)] + [np.asarray(F, float) for F in turns]
    if T_board_installed is None or len(H) == 1:
        return H[0]
    d = [pose_error(T_board_installed @ h, T_board_new) for h in H]
    return H[min(range(len(H)), key=lambda i: (round(d[i][0], 1), d[i][1]))]


def board_from_views(mode: str, T_x: np.ndarray, T_base_end: np.ndarray, T_cam_board: np.ndarray) -> np.ndarray:
    """Per view (n,4,4) the board transform that ``T_x`` and the view imply: ``B_i = M_i^-1 X C_i``."""
    m = mounting(mode)
    return inv_T(m.M_from_T_base_end(T_base_end)) @ T_x @ T_cam_board


def verify_views(
    installed: LoadedResult,
    *,
    views: Sequence,
    object_points: np.ndarray,
    intrinsics: Optional[Intrinsics] = None,
    options: VerifyOptions = VerifyOptions(),
    board_turns: Sequence[np.ndarray] = (),
) -> Verification:
    """Test the installed calibration on ``views``.

    Test the installed calibration on ``views`` (:class:`handeye.refine.RefineView`, corners in the
    board's order). ``intrinsics``: the session's own (held fixed); None uses the installed ones with
    their sigmas as a prior. ``board_turns``: the board-frame motions (4,4) of a symmetric board's other
    numberings (:func:`handeye.diagnose.consistency.board_turns`); the installed board pose is turned into the
    new views' numbering (the turn nearest theirs) before the comparison (``board["turn_deg"]``,
    ``board["T_turn"]``, ``board["installed_in_session_numbering"]``; ``board["installed"]`` is result.json's).
    """
    from ..initial import solve_pnp
    from ..refine import RefineOptions, refine

    t0 = time.perf_counter()
    if not installed.ok:
        raise InputError(
            f"the installed result has no hand-eye matrix (status {installed.status})",
            path=installed.source,
            hint="verify against a result with status ok",
        )
    if len(views) < 3:
        raise InputError(
            "a verification needs at least 3 views with the target",
            received=f"{len(views)} views",
            hint="capture 3-8 views with the whole board visible and the robot turned between them",
        )
    mode, X0 = installed.mode, installed.T_x
    assert X0 is not None, "an ok result has X"
    session_intr = intrinsics is not None
    intr = intrinsics if session_intr else installed.intrinsics
    if intr is None:
        raise InputError(
            "no intrinsics: the installed result has none and the session gives none", path=installed.source
        )
    prior, fixed = installed_prior(installed, session_intrinsics=session_intr, cov_x=VAGUE_COV_X)
    C = np.stack([solve_pnp(object_points[v.corner_ids], v.image_points, intr)[0] for v in views])
    E = np.stack([np.asarray(v.T_base_end, float) for v in views])
    B_views = board_from_views(mode, X0, E, C)
    B0 = mean_T(B_views)
    H = nearest_board_turn(installed.T_board, B0, board_turns)
    installed_T_board = installed.T_board
    installed = installed.with_board_turned(H)  # its board pose in the new views' numbering
    rs_mm, rs_deg = installed.robot_sigma_mm or 0.0, installed.robot_sigma_deg or 0.0
    robot = installed_robot_model(installed)
    prior = with_installed_dh(prior, installed, robot, views)
    ro = RefineOptions(
        intrinsics="fixed" if session_intr else "estimate",
        fix=fixed,
        robot_noise="fixed" if (rs_mm > 0 and rs_deg > 0) else "none",
        robot_sigma_mm=rs_mm if rs_mm > 0 else 0.1,
        robot_sigma_deg=rs_deg if rs_deg > 0 else 0.01,
        prior=prior,
        **robot,
    )
    r = refine(
        mode=mode, object_points=object_points, views=list(views), intrinsics=intr, T_x0=X0, T_board0=B0, options=ro
    )
    if r.status != "ok":
        hint = "capture views with the whole board visible and the robot turned between them"
        if r.failure_code == "too_few_robot_poses":  # the views' robot poses scatter beyond the installed noise
            err = np.array([pose_error(B, B0) for B in B_views])
            hint = (
                f"the board each view implies through its robot pose and the installed {installed.x_name} "
                f"scatters by {np.median(err[:, 1]):.1f} mm / {np.median(err[:, 0]):.2f} deg (median), against "
                f"an installed robot noise of {rs_mm:.2f} mm / {rs_deg:.3f} deg: make sure the robot is at rest "
                "at each capture and that the poses are the flange's of this robot, then capture again"
            )
        raise CalibrationError(
            f"the verification solve failed: {r.failure_reason}", code="refinement_failed", hint=hint
        )
    test = test_refined(installed, r, prior, min_variance_share=options.min_variance_share)
    drifted = test.p_value < options.alpha
    change = change_in_result_frame(X0, test.change_xi, test.change_cov)
    board = _board_change(installed, r, mode, E, C, options, change)
    if installed.T_board is not None:  # result.json's board, and the same board in this session's numbering
        board.update(
            installed=installed_T_board,
            installed_in_session_numbering=installed.T_board,
            T_turn=H,
            turn_deg=float(np.degrees(np.linalg.norm(rotvec_from_R(H[:3, :3])))),
        )
    robot = _robot_disagreement(r)
    intr_d = _intrinsics_update(installed, r, session_intr)
    moved = what_moved(
        mode=mode,
        frame=installed.x_name,
        drifted=drifted,
        change=change,
        board=board,
        robot=robot,
        intrinsics=intr_d,
        dof=test.dof,
    )
    verdict = "drifted" if drifted else "still valid"
    headline = (
        f"{installed.x_name} {'DRIFTED' if drifted else 'still valid'}: test statistic {test.statistic:.2f} "
        f"({test.dof} dof), p = {test.p_value:.3g} at alpha {options.alpha:g}; estimated change "
        f"{change['trans_mm']:.2f} mm, {change['rot_deg']:.3f} deg"
    )
    views_d = {
        vid: {
            k: d.get(k)
            for k in (
                "status",
                "rms_px",
                "max_px",
                "n_corners",
                "n_used",
                "robot_vs_camera_trans_mm",
                "robot_vs_camera_rot_deg",
            )
        }
        for vid, d in r.per_view.items()
    }
    return Verification(
        verdict=verdict,
        headline=headline,
        mode=mode,
        frame=installed.x_name,
        test=test,
        alpha=options.alpha,
        change=change,
        T_x_installed=X0,
        T_x_posterior=X0 @ se3_exp(test.posterior_xi),
        cov_x_posterior=test.posterior_cov,
        board=board,
        robot=robot,
        intrinsics=intr_d,
        what_moved=moved,
        views=views_d,
        n_views=len(r.used_view_ids),
        sigma_px=r.sigma_px,
        cov_source=installed.cov_source,
        seconds=time.perf_counter() - t0,
        refined=r,
    )


def installed_robot_model(installed: LoadedResult) -> dict:
    """RefineOptions for the robot error model of the installed result when it names an arm.

    RefineOptions for the robot error model of the installed result when it names an arm (``calibrate
    --robot`` or session.yaml's ``robot:``): the arm's kinematic model (DH offsets held by the prior the
    install used, encoder noise fixed at the installed value) from the DH table result.json records (or, in
    results written before it did, the shipped preset or DH file it names); {} (the iid model at the
    installed sigmas) otherwise.
    """
    ref = installed.raw.get("refinement") or {}
    rm = ref.get("robot_model") or {}
    if rm.get("kind") != "kinematic" or not rm.get("arm"):
        return {}
    from ..kinematics import PRESETS, chain_from_dict, load_arm

    name = (ref.get("options") or {}).get("arm")  # the preset or DH file the install named, when it named one
    if isinstance(rm.get("dh_table"), dict):
        arm = chain_from_dict(rm["dh_table"], source=f"{installed.source} refinement.robot_model.dh_table")
    elif name in PRESETS or (isinstance(name, str) and Path(name).is_file()):
        arm = load_arm(name)  # type: ignore[arg-type]  # a preset name or a file path here
    else:
        log.warning(
            "the installed result's arm %s is neither recorded as a table nor a shipped preset or DH file "
            "that still exists: verifying with the iid robot model",
            rm["arm"],
        )
        return {}
    out = {"robot_model": "kinematic", "arm": arm}
    if rm.get("encoder_sigma_deg"):
        out["encoder_sigma_deg"] = float(rm["encoder_sigma_deg"])
    prior_sd = rm.get("dh_prior_sigma") or {}
    if prior_sd.get("length_mm") and prior_sd.get("angle_deg"):
        out.update(dh_sigma_mm=float(prior_sd["length_mm"]), dh_sigma_deg=float(prior_sd["angle_deg"]))
    return out


def with_installed_dh(prior, installed: LoadedResult, robot: dict, views: Sequence = ()):
    """``prior`` with the installed arm's estimated DH offsets and their covariance.

    ``prior`` with the installed arm's estimated DH offsets and their covariance (the install's posterior)
    as the new views' DH prior, when the install modelled the same arm kinematically
    (:func:`installed_robot_model`) and recorded them; the arm's own prior otherwise. The arm's systematic
    error is then the install's, not a fresh unknown: the new views see X as precisely as that allows, and
    the test takes the shared offsets apart like the shared intrinsics. Only when the install's views and
    ``views`` carry recorded joint angles: joints from inverse kinematics of a reported pose may be another
    arm configuration than the one that took the view, for which the shared offsets are wrong. Not when the
    session brings its own intrinsics (``prior`` without them): the joint test, which takes shared
    parameters apart, then does not run.
    """
    if prior.intrinsics is None or not shares_dh(installed, robot):
        return prior
    if any(getattr(v, "joint_angles", None) is None for v in views):
        return prior
    dh = installed.dh_joint
    assert dh is not None, "shares_dh: the install recorded its DH offsets"
    return replace(prior, dh_offsets=dh[0], cov_dh=dh[3])


def shares_dh(installed: LoadedResult, robot: Optional[dict] = None) -> bool:
    """Whether a verification with recorded joint angles shares the install's DH offsets.

    Whether a verification with recorded joint angles shares the install's DH offsets
    (:func:`with_installed_dh`): the install recorded them for an arm verify can rebuild
    (``robot``, default :func:`installed_robot_model`) with as many offsets, from recorded joint angles.
    ``verify --plan`` asks the same question, so that it plans against the uncertainty verify will face.
    """
    robot = installed_robot_model(installed) if robot is None else robot
    dh, arm = installed.dh_joint, robot.get("arm")
    return (
        dh is not None
        and robot.get("robot_model") == "kinematic"
        and arm is not None
        and len(dh[0]) == 4 * arm.n_joints
        and installed.joints_recorded
    )


def test_refined(installed: LoadedResult, r, prior, *, min_variance_share: float) -> DriftTest:
    """The test of ``X = X0`` on new views refined (``r``) with X free under ``prior``.

    The test of ``X = X0`` on new views refined (``r``) with X free under ``prior``
    (:func:`handeye.recal.loaded.installed_prior`): :func:`joint_drift_test` when the new views share the
    installed intrinsics (and DH offsets, :func:`with_installed_dh`) and both results carry the joint
    covariance of X and the intrinsics, else :func:`drift_test` (the session's own intrinsics: nothing shared;
    an older result: the installed X covariance added whole, a conservative test).
    """
    assert installed.T_x is not None and installed.cov_x is not None, "installed_prior checked both"
    t = _joint_test(installed, r, prior, min_variance_share) if prior.intrinsics is not None else None
    if t is None:
        t = drift_test(
            cov_installed=installed.cov_x,
            T_x_installed=installed.T_x,
            T_x_new=r.T_x,
            cov_new=r.cov_x_6x6,
            min_variance_share=min_variance_share,
        )
    nu = installed.robot_noise_dof  # the new views' robot noise is the installed estimate too
    return replace(t, p_value=wald_p_value(t.statistic, t.dof, nu), noise_dof=nu) if nu is not None else t


def _joint_test(installed: LoadedResult, r, prior, min_variance_share: float) -> Optional[DriftTest]:
    """:func:`joint_drift_test` of the refinement ``r``.

    :func:`joint_drift_test` of the refinement ``r`` (made under ``prior``), or None when the installed
    result or the refinement lacks the joint covariance of X and the intrinsics, or their free intrinsics
    differ.
    """
    j, jr = installed.cov_x_intrinsics, r.cov_x_intrinsics
    if j is None or jr is None or tuple(jr["intrinsics"]) != j[0] or prior.cov_intrinsics is None:
        return None
    idx = [INTRINSIC_NAMES.index(n) for n in j[0]]
    C_k, K_k = np.asarray(jr["cross_6xk"], float), np.asarray(jr["intrinsics_kxk"], float)
    assert installed.intrinsics is not None, "a joint covariance comes with the intrinsics"
    assert installed.T_x is not None and installed.cov_x is not None, "installed_prior checked both"
    dk = r.intrinsics.as_vector()[idx] - installed.intrinsics.as_vector()[idx]
    cov_xk, cov_kk, cov_k_prior = j[1], j[2], np.asarray(prior.cov_intrinsics)[np.ix_(idx, idx)]
    dh = installed.dh_joint
    shared_dh = prior.dh_offsets is not None and dh is not None and "dh_offsets" in jr
    if shared_dh:
        assert dh is not None, "shared_dh"
        # the arm's DH offsets are shared too (with_installed_dh): appended to the shared parameters
        m = len(dh[0])
        C_k = np.hstack([C_k, np.asarray(jr["cross_6xm"], float)])
        K_k = np.block(
            [
                [K_k, np.asarray(jr["cross_kxm"], float)],
                [np.asarray(jr["cross_kxm"], float).T, np.asarray(jr["dh_mxm"], float)],
            ]
        )
        dk = np.r_[dk, np.asarray(jr["dh_offsets"], float) - dh[0]]
        cov_xk = np.hstack([cov_xk, dh[1]])
        cov_kk = np.block([[cov_kk, dh[2]], [dh[2].T, dh[3]]])
        cov_k_prior = np.block(
            [[cov_k_prior, np.zeros((len(idx), m))], [np.zeros((m, len(idx))), np.asarray(prior.cov_dh, float)]]
        )
    nk = len(dk)
    cov_new = np.zeros((6 + nk, 6 + nk))
    cov_new[:6, :6], cov_new[:6, 6:], cov_new[6:, 6:] = r.cov_x_6x6, C_k, K_k
    cov_new[6:, :6] = cov_new[:6, 6:].T
    try:
        t = joint_drift_test(
            T_x_installed=installed.T_x,
            cov_installed=installed.cov_x,
            cov_xk_installed=cov_xk,
            cov_kk_installed=cov_kk,
            T_x_new=r.T_x,
            dk_new=dk,
            cov_new=cov_new,
            cov_k_prior=cov_k_prior,
            cov_x_prior=prior.cov_x,
            min_variance_share=min_variance_share,
        )
        return replace(t, kind=JOINT_DH_KIND) if shared_dh else t
    except np.linalg.LinAlgError as e:
        log.warning("the joint test of X and the intrinsics failed (%s); testing X alone", e)
        return None


def _board_change(
    installed: LoadedResult, r, mode: str, E: np.ndarray, C: np.ndarray, o: VerifyOptions, change: dict
) -> dict:
    """The new board pose against the installed one.

    Its sigma: the scatter of the per-view board poses through the new X (the mean's standard error)
    and, in quadrature, the sigma of the change of X (the board is found through X, so an error of X
    moves it as much, to first order).
    """
    m = mounting(mode)
    d = {"name": m.board_name, "installed": installed.T_board, "new": r.T_board}
    if installed.T_board is None:
        return dict(d, moved=False, known=False)
    rot_deg, trans_mm = pose_error(r.T_board, installed.T_board)
    B = board_from_views(mode, r.T_x, E, C)
    xi = tangent_difference(r.T_board, B)  # (n, 6) per-view scatter about the estimate
    n = len(B)
    se_rot = float(np.degrees(np.sqrt(np.sum(np.var(xi[:, :3], axis=0, ddof=1)) / n))) if n > 1 else float("inf")
    t_views = B[:, :3, 3]
    se_t = float(1000.0 * np.sqrt(np.sum(np.var(t_views, axis=0, ddof=1)) / n)) if n > 1 else float("inf")
    se_t = float(np.hypot(se_t, np.linalg.norm(change["sigma_trans_mm"])))
    se_rot = float(np.hypot(se_rot, np.linalg.norm(change["sigma_rot_deg"])))
    moved = bool(
        (trans_mm > max(o.board_sigmas * se_t, o.board_min_mm))
        or (rot_deg > max(o.board_sigmas * se_rot, o.board_min_deg))
    )
    return dict(
        d,
        known=True,
        trans_mm=trans_mm,
        rot_deg=rot_deg,
        sigma_trans_mm=se_t,
        sigma_rot_deg=se_rot,
        moved=moved,
        frame=m.board_frame,
    )


def _robot_disagreement(r) -> dict:
    bad = [o for o in r.outliers if o.kind == "robot_pose"]
    return {
        "views": [o.view_id for o in bad],
        "reasons": [o.reason for o in bad],
        "robot_sigma_mm": r.robot_sigma_mm,
        "robot_sigma_deg": r.robot_sigma_deg,
    }


def _intrinsics_update(installed: LoadedResult, r, session_intr: bool) -> dict:
    if session_intr or installed.intrinsics is None:
        return {"source": "session" if session_intr else "none"}
    d: dict[str, Any] = {"source": "installed (prior)"}
    new = r.intrinsics
    for n in ("fx", "fy", "cx", "cy"):
        s = installed.intrinsics_sigma.get(n, 0.0)
        diff = float(getattr(new, n) - getattr(installed.intrinsics, n))
        d[n] = {
            "installed": float(getattr(installed.intrinsics, n)),
            "new": float(getattr(new, n)),
            "diff": diff,
            "sigma_installed": s,
            "z": diff / s if s > 0 else float("nan"),
        }
    return d


def what_moved(
    *, mode: str, frame: str, drifted: bool, change: dict, board: dict, robot: dict, intrinsics: dict, dof: int
) -> tuple:
    """Lines for people: which part of the rig the evidence points at."""
    m = mounting(mode)
    lines = []
    size = f"{change['trans_mm']:.2f} mm, {change['rot_deg']:.3f} deg"
    if drifted:
        if m.camera_moves:
            lines.append(f"the camera moved on the flange ({frame} changed by {size}): the camera mount")
        else:
            lines.append(
                f"the camera moved against the robot base ({frame} changed by {size}): the camera "
                "mount, or the robot base itself (the two cannot be told apart)"
            )
    if board.get("moved"):
        where = "on the table (in the base frame)" if m.board_frame == "base" else "on the flange"
        lines.append(
            f"the board moved {where} by {board['trans_mm']:.2f} mm, {board['rot_deg']:.3f} deg "
            f"(its pose is re-estimated; {frame} does not depend on it)"
        )
    if robot.get("views"):
        lines.append(
            f"the robot poses of views {', '.join(robot['views'])} disagree with the camera (a collision, "
            "a changed tool frame or a robot fault); those views were not used"
        )
    zs = {n: v["z"] for n, v in intrinsics.items() if isinstance(v, dict) and np.isfinite(v.get("z", np.nan))}
    big = [n for n, z in zs.items() if abs(z) > 3.0]
    if big:
        lines.append(
            f"the camera intrinsics moved ({', '.join(big)} beyond 3 installed sigmas): refocused or "
            "zoomed? a full recalibration is advised"
        )
    if dof < 6:
        lines.append(
            f"the views constrain only {dof} of the 6 directions of {frame}: turn the robot about more "
            "axes between views"
        )
    if not lines:
        lines.append("nothing moved beyond the uncertainty")
    return tuple(lines)


# ------------------------------------------------------------------------------ a session folder
@dataclass(frozen=True)
class SessionVerification:
    """:func:`verify_session`'s outcome: the verification and what the session gave it."""

    verification: Verification
    session_path: str
    installed_source: str
    outcomes: tuple  # ViewOutcome per view of the session (detected or why not)
    target_text: str
    image_size: tuple
    intrinsics_source: str
    seconds: dict


def session_for_installed(session_path, installed: LoadedResult, *, mode: Optional[str] = None):
    """The session, read in the installed result's mounting mode.

    Refuses a session of another mode or board (one line naming the difference).
    """
    from ..session import load_session

    s = load_session(session_path, mode=mode)
    if s.mode_source == "default" and mode is None:  # the session does not say: the installed mode
        from dataclasses import replace

        s = replace(s, mode=installed.mode, mode_source="flag")
    if s.mode != installed.mode:
        said = f"--mode {mode} was given" if mode is not None else f"the session is {s.mode}"
        raise InputError(
            f"{said} but the installed calibration is {installed.mode}",
            path=s.path,
            code="not_comparable",
            hint="verify against a result of this rig's mounting mode"
            + ("" if mode is None else f", or drop --mode (the installed {installed.mode} is used)"),
        )
    if installed.target is not None and s.target.to_dict() != installed.target:
        raise InputError(
            f"the session's board ({s.target.describe()}) is not the installed calibration's",
            path=s.path,
            expected=str(installed.target),
            code="not_comparable",
            hint="verify with the board the rig was calibrated with",
        )
    return s


def installed_images_among(installed: LoadedResult, session) -> int:
    """How many of the session's images are files the installed calibration read.

    How many of the session's images are files the installed calibration read, when its robot poses are too (by
    their SHA-256 in the installed result's provenance): the installed session itself, not a new one. (Rendered
    sessions of one scene can share images while their poses differ.)
    """
    from ..output import file_sha256

    known = {
        str(i.get("sha256")) for i in (installed.raw.get("provenance") or {}).get("inputs") or [] if isinstance(i, dict)
    }
    if not known:
        return 0
    images = {Path(v.image_path) for v in session.views if v.image_path is not None}
    folder = Path(session.path)
    others = [
        Path(f)
        for f in session.meta.get("files_read") or [folder / "poses.txt", folder / "session.yaml"]
        if Path(f).name != "config.yaml"
    ]  # the board's description is the same for every session of a rig
    if not any(f.is_file() and f not in images and file_sha256(f) in known for f in others):
        return 0
    return sum(1 for p in images if p.is_file() and file_sha256(p) in known)


def check_resolution(installed: LoadedResult, session) -> None:
    """The session's images (read from their headers) must have the installed calibration's resolution.

    Its intrinsics describe that image; else a one-line InputError (``not_comparable``).
    """
    from ..session import image_sizes

    size = next(iter(image_sizes(session).values()), None)
    if size and installed.image_size and tuple(size) != tuple(installed.image_size):
        raise InputError(
            f"the session's images are {size[0]}x{size[1]} but the installed calibration's are "
            f"{installed.image_size[0]}x{installed.image_size[1]}",
            path=session.path,
            code="not_comparable",
            hint="capture at the calibrated resolution (the installed intrinsics describe that image)",
        )


def verify_session(
    session_path, against, *, options: VerifyOptions = VerifyOptions(), mode: Optional[str] = None, progress=None
) -> SessionVerification:
    """Detect the target in a short session and test the installed calibration ``against``.

    Detect the target in a short session (:func:`handeye.pipeline.observe`) and test the installed
    calibration ``against`` (a result folder, result.json or loaded dict) on it (:func:`verify_views`).
    """
    from ..diagnose.consistency import board_turns
    from ..pipeline import CalibrateOptions, observe, target_text
    from ..refine import RefineView
    from .loaded import load_result

    t0 = time.perf_counter()
    installed = against if isinstance(against, LoadedResult) else load_result(against)
    if not installed.ok:
        raise InputError(
            f"the installed result has no hand-eye matrix (status {installed.status})",
            path=installed.source,
            hint="verify against a result with status ok",
        )
    s = session_for_installed(session_path, installed, mode=mode)
    check_resolution(installed, s)
    reused = installed_images_among(installed, s)
    if reused:
        log.warning(
            "%s: %d of %d images are the installed calibration's own (the same files): verify tests new views "
            "against the installed calibration, and its own views cannot show a drift",
            s.path,
            reused,
            len(s.views),
        )
    m = mounting(s.mode)
    own = s.intrinsics if (s.intrinsics is not None and s.intrinsics_prior in ("fixed", "prior")) else None
    intr = own if own is not None else installed.intrinsics
    M_all = {v.view_id: m.M_from_T_base_end(v.T_base_end) for v in s.views}
    obs = observe(
        target=s.target,
        items=[(v.view_id, v.image_path) for v in s.views],
        intrinsics=intr,
        intrinsics_prior="fixed",
        M_by_id=M_all,
        options=CalibrateOptions(),
        intrinsics_source="session" if own is not None else "installed",
        progress=progress,
    )
    if obs.error is not None:
        raise obs.error if obs.error.path is not None else obs.error.at(s.path)
    size = next(iter(obs.detections.values())).image_size
    t1 = time.perf_counter()
    views = [
        RefineView(
            vid, bp.corner_ids, obs.detections[vid].image_points, s.view(vid).T_base_end, s.view(vid).joint_angles
        )
        for vid, bp in obs.board_poses.items()
    ]
    v = verify_views(
        installed,
        views=views,
        object_points=s.target.object_points(),
        intrinsics=own,
        options=options,
        board_turns=[F for _, F in board_turns(s.target)],
    )
    seconds = dict(obs.seconds, verify=time.perf_counter() - t1, total=time.perf_counter() - t0)
    return SessionVerification(
        verification=v,
        session_path=str(s.path),
        installed_source=installed.source,
        outcomes=obs.ordered_outcomes(),
        target_text=target_text(s.target),
        image_size=tuple(size),
        intrinsics_source=obs.intrinsics_source,
        seconds=seconds,
    )


def verify_dict(sv: SessionVerification) -> dict:
    """verify.json: the verification with its inputs and provenance."""
    from ..output import provenance

    d = sv.verification.to_dict()
    d = {
        "handeye_verify": 1,
        **d,
        "session": {
            "path": sv.session_path,
            "target": sv.target_text,
            "image_size": list(sv.image_size),
            "intrinsics": sv.intrinsics_source,
        },
        "against": sv.installed_source,
        "view_outcomes": [
            {"id": o.view_id, "image": o.image, "detected": o.used, "reason": o.reason, "n_corners": o.n_corners}
            for o in sv.outcomes
        ],
        "seconds_by_stage": sv.seconds,
        "provenance": provenance(),
    }
    return plain(d, nan_to_none=True)
