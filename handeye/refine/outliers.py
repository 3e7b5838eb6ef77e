"""Outlier decisions of the refinement, and THE robot-pose outlier test (pure numpy, no GTSAM).

:func:`robot_pose_test` is the one gated test of a reported robot pose against the pose the rest of
the data predict; the refinement and the diagnostics (for runs without a refinement) both call it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np

from handeye.factors.reprojection import corner_robust_scales, stacked_chain_residual

from ..errors import ConfigError
from ..frames import se3_exp, tangent_difference
from ..output import plain
from ..stats import mixture_tail_pvalue, mixture_tail_quantile
from .noise import robust_robot_sigmas, solve_with_vce
from .options import RefineOptions, refine_preset

if TYPE_CHECKING:
    from .problem import Problem

log = logging.getLogger(__name__)

ROBOT_POSE_DOF = 6


@dataclass(frozen=True)
class RobotPoseGates:
    """Gates of :func:`robot_pose_test` (configs/refine.yaml ``outliers.robot_pose``)."""

    alpha: float  # false-alarm probability per view
    min_rot_deg: float  # practical-significance floor of the rotation disagreement
    min_trans_mm: float  # ... and of the translation disagreement
    tail_dof: float = np.inf  # the null is multivariate t with this dof, variance matched (inf: Gaussian)

    @staticmethod
    def from_config(cfg: dict[str, Any] | None = None, *, unmodelled_arm: bool = True) -> "RobotPoseGates":
        """The robot-pose gates from the outlier settings ``cfg`` (default: the refine preset).

        ``unmodelled_arm``: the poses come from an arm whose kinematic error is not modelled (the null's
        tail is ``iid_tail_dof``); False: a kinematic model, or a tracker, carries the error (Gaussian).
        """
        c = (cfg if cfg is not None else refine_preset())["outliers"]["robot_pose"]
        nu = c["iid_tail_dof"]
        if isinstance(nu, bool) or not isinstance(nu, (int, float)) or not nu > 2:
            raise ConfigError(
                "outliers.robot_pose.iid_tail_dof is not a valid dof",
                path="configs/refine.yaml",
                expected="a number above 2 (the t's variance must exist), or .inf for a Gaussian",
                received=repr(nu),
            )
        return RobotPoseGates(
            alpha=float(c["alpha"]),
            min_rot_deg=float(c["min_rot_deg"]),
            min_trans_mm=float(c["min_trans_mm"]),
            tail_dof=float(c["iid_tail_dof"]) if unmodelled_arm else np.inf,
        )

    @staticmethod
    def from_options(o: RefineOptions, *, unmodelled_arm: bool = True) -> "RobotPoseGates":
        return replace(
            RobotPoseGates.from_config(unmodelled_arm=unmodelled_arm),
            alpha=o.view_outlier_p,
            min_rot_deg=o.min_robot_disagreement_deg,
            min_trans_mm=o.min_robot_disagreement_mm,
        )

    @property
    def threshold(self) -> float:
        """The statistic (squared Mahalanobis units) exceeded with probability alpha under the null.

        The chi-square(6) quantile at 1 - alpha when Gaussian.
        """
        return float(mixture_tail_quantile(self.alpha, ROBOT_POSE_DOF, np.array(self.tail_dof)))


@dataclass(frozen=True)
class RobotPoseTest:
    """Result of :func:`robot_pose_test` for n views (NaN rows: no test, never flagged)."""

    statistic: np.ndarray  # (n,) squared Mahalanobis distance, chi-square(6) for a correct pose
    p_value: np.ndarray  # (n,) P(chi-square(6) > statistic)
    flagged: np.ndarray  # (n,) bool
    rot_deg: np.ndarray  # (n,) |omega| of the disagreement
    trans_mm: np.ndarray  # (n,) |v| of the disagreement
    sigma_rot_deg: np.ndarray  # (n,) sqrt(trace) of the rotation block of C + R: RMS |omega| of a correct pose
    sigma_trans_mm: np.ndarray  # (n,) the same for the translation
    threshold: float  # the null's quantile at 1 - alpha (chi-square(6) when Gaussian)
    gates: RobotPoseGates

    @property
    def distance(self) -> np.ndarray:
        """sqrt(statistic): the disagreement in sigmas."""
        return np.sqrt(self.statistic)


def robot_pose_test(
    disagreement: np.ndarray,
    covariance: np.ndarray,
    *,
    robot_sigma_rot_rad: float = 0.0,
    robot_sigma_trans_m: float = 0.0,
    gates: RobotPoseGates | None = None,
    robot_covariance: Optional[np.ndarray] = None,
) -> RobotPoseTest:
    """Test each view's reported robot pose against the pose the rest of the data predict.

    Inputs, for n views:

    * ``disagreement`` (n, 6): ``d_i = tangent_difference(T_reported_i, T_predicted_i)``, i.e.
      ``T_predicted_i = T_reported_i · Exp(d_i)`` (:mod:`handeye.frames` convention: rotation
      [rad] first, then translation [m], right perturbation, both along the end-frame axes);
      ``T_predicted_i`` is the robot pose ``T_base_end`` that the camera and the hand-eye solution
      imply for view i, computed WITHOUT view i's reported robot pose (e.g. its PnP pose through
      the calibrated chain, or the refinement's leave-one-out prediction);
    * ``covariance`` (n, 6, 6): the covariance of that prediction in the same tangent (camera
      noise propagated through the chain; zero when unknown);
    * ``robot_sigma_rot_rad`` / ``robot_sigma_trans_m``: the robot's own noise per axis (isotropic,
      the same tangent), estimated or configured; or ``robot_covariance`` (n, 6, 6), each view's own
      (the kinematic robot error models, :mod:`.robot_model`), which replaces them.

    The check: under "the reported pose is right up to robot noise", ``d_i ~ N(0, C_i + R)`` with
    ``R = diag(s_rot^2 I3, s_trans^2 I3)``, so ``statistic_i = d_i^T (C_i + R)^-1 d_i`` is
    chi-square with 6 degrees of freedom and ``p_value_i`` its upper tail. A view is flagged when
    ``p_value_i < alpha`` AND the disagreement is practically large: its rotation exceeds
    ``min_rot_deg`` or its translation ``min_trans_mm``. Gates default to configs/refine.yaml.
    Rows with a non-finite disagreement or covariance are not tested (NaN statistic, not flagged).

    The robot's error need not be one Gaussian: a kinematic error (link lengths, joint offsets) makes
    some poses worse than others, which an iid model with one sigma per axis cannot say. When the arm's
    kinematics are not modelled, the null is a scale mixture: a multivariate t with ``gates.tail_dof``
    dof (configs/refine.yaml ``iid_tail_dof``), its covariance ``C_i + R`` (variance matched); the
    kinematic model carries the pose dependence itself, and its null stays chi-square(6).
    """
    g = gates if gates is not None else RobotPoseGates.from_config()
    d = np.asarray(disagreement, float).reshape(-1, 6)
    C = np.asarray(covariance, float).reshape(-1, 6, 6)
    if C.shape[0] != d.shape[0]:
        raise ValueError(f"disagreement has {d.shape[0]} rows but covariance {C.shape[0]}")
    R: np.ndarray = np.diag([robot_sigma_rot_rad**2] * 3 + [robot_sigma_trans_m**2] * 3)
    if robot_covariance is not None:
        R = np.asarray(robot_covariance, float).reshape(-1, 6, 6)
    ok = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(C), axis=(1, 2))
    stat = np.full(d.shape[0], np.nan)
    Ct = C + R
    if ok.any():
        stat[ok] = np.einsum("ni,ni->n", d[ok], np.linalg.solve(Ct[ok], d[ok][..., None])[..., 0])
    diag = np.diagonal(Ct, axis1=1, axis2=2)
    p = mixture_tail_pvalue(stat, ROBOT_POSE_DOF, np.full(stat.shape, g.tail_dof))
    rot_deg = np.degrees(np.linalg.norm(d[:, :3], axis=1))
    trans_mm = 1000.0 * np.linalg.norm(d[:, 3:], axis=1)
    large = (rot_deg > g.min_rot_deg) | (trans_mm > g.min_trans_mm)
    flagged = ok & (np.nan_to_num(p, nan=1.0) < g.alpha) & large
    return RobotPoseTest(
        statistic=stat,
        p_value=p,
        flagged=flagged,
        rot_deg=rot_deg,
        trans_mm=trans_mm,
        sigma_rot_deg=np.degrees(np.sqrt(diag[:, :3].sum(axis=1))),
        sigma_trans_mm=1000.0 * np.sqrt(diag[:, 3:].sum(axis=1)),
        threshold=g.threshold,
        gates=g,
    )


# ------------------------------------------------------------------------------ the refinement's decisions
@dataclass(frozen=True)
class Outlier:
    """One explicit outlier decision."""

    view_id: str
    kind: str  # corners | reprojection | too_few_corners | robot_pose
    reason: str  # one line for people
    corner_ids: tuple[Any, ...] = ()  # flagged corners (kind "corners"), else empty: the decision covers the view
    size: dict[str, Any] = field(default_factory=dict)  # size of the disagreement, names with units

    def __str__(self) -> str:
        return self.reason

    def to_dict(self) -> dict[str, Any]:
        return {
            "view_id": self.view_id,
            "kind": self.kind,
            "reason": self.reason,
            "corner_ids": [int(c) for c in self.corner_ids],
            "size": plain(self.size),
        }


@dataclass(frozen=True)
class ViewCheck:
    """One view against the current solution."""

    P_cam: np.ndarray  # (4,4) robot pose implied by the camera (alone, or in the last Gaussian solve)
    cov_cam: np.ndarray  # (6,6) its covariance (right tangent)
    resid_px: np.ndarray  # (N,) corner residual norms at P_cam
    delta: np.ndarray  # (6,) tangent_difference(reported, P_cam)
    ok: bool
    # the view's own corner variance over sigma_px^2, at least 1 (:func:`view_variance_factor`)
    variance_factor: float = 1.0


def _failed_check(P: np.ndarray, n_corners: int) -> ViewCheck:
    return ViewCheck(P, np.full((6, 6), np.nan), np.full(n_corners, np.inf), np.full(6, np.nan), False)


def own_fit_variance(resid_px: np.ndarray, *, n_params: int = 6) -> float:
    """Own-fit variance ``s^2`` [px^2] of a view's corner residuals against its own pose fit.

    ``s^2 = sum |e|^2 / (2 N - n_params)`` [px^2] of a view's N corner residual norms ``resid_px`` against
    the pose fitted to that view alone (``n_params`` = 6 pose unknowns); NaN without redundancy.
    """
    e = np.asarray(resid_px, float)
    e = e[np.isfinite(e)]
    dof = 2 * e.size - n_params
    return float(np.sum(e * e)) / dof if dof > 0 else float("nan")


def view_variance_factor(resid_px: np.ndarray, *, sigma_px: float, n_params: int = 6) -> float:
    """How much noisier one view's corners are than the run's pixel sigma.

    ``max(1, s^2 / sigma_px^2)`` with ``s^2`` the view's own-fit variance (:func:`own_fit_variance`) over
    its inlier corner residuals.

    The detector's corner error is not one iid Gaussian over the run: it differs between views
    (perspective, distance and blur change the corner's edges), and within a view it is correlated.
    The pose of a view whose corners scatter k times more than sigma_px is about k times less certain
    than ``sigma_px^2 (J^T J)^-1`` says; the test of its robot pose must use that view's own level,
    measured where the robot pose plays no part (the view's own fit), so that a wrong robot pose
    cannot hide behind it. Never below 1: a view is not held to a tighter standard than the run.
    """
    return _factor(own_fit_variance(resid_px, n_params=n_params), sigma_px)


def _factor(s2: float, sigma_px: float) -> float:
    return max(1.0, s2 / sigma_px**2) if np.isfinite(s2) and sigma_px > 0 else 1.0


def camera_only_poses(pb: "Problem", idx: Sequence[int], *, max_iters: int = 10) -> dict[int, ViewCheck]:
    """Robust Gauss-Newton for the robot pose of each view in ``idx`` from its corners alone.

    Robust Gauss-Newton (Huber, ``loss_k``) for the robot pose of each view in ``idx`` from its corners
    alone (``T_x``, ``T_board`` and the intrinsics held), all views at once, starting from the current
    estimates ``pb.P``; a view that most of its corners do not fit from there (a start far off: its
    robot pose belongs to another image, or is misread) starts again from its own PnP pose carried through
    ``T_x`` and ``T_board``, and keeps the fit with more corners within ``corner_outlier_sigmas``. The
    covariance is ``sigma_px^2 (J^T J)^-1`` over those corners. Returns {view index: ViewCheck}.
    """
    empty = {int(i): _failed_check(pb.P[i].copy(), 0) for i in idx if pb.offsets[i + 1] == pb.offsets[i]}
    ids = np.asarray([i for i in idx if i not in empty], int)
    if ids.size == 0:
        return empty
    fit = _own_fits(pb, ids, pb.P[ids].copy(), max_iters)
    poor = np.flatnonzero(fit["n_inl"] * 2 < fit["counts"])
    if poor.size:
        again = _own_fits(pb, ids[poor], _pnp_starts(pb, ids[poor], fit["P"][poor]), max_iters)
        better = again["n_inl"] > fit["n_inl"][poor]
        for k, j in zip(poor[better], np.flatnonzero(better), strict=False):
            for key in ("P", "alive", "n_inl", "H", "delta"):
                fit[key][k] = again[key][j]
            fit["e"][k] = again["e"][j]
            fit["inl"][k] = again["inl"][j]
    out = empty
    for k, i in enumerate(ids):
        e_k, P_k = fit["e"][k], fit["P"][k]
        if not fit["alive"][k]:
            out[int(i)] = _failed_check(P_k, int(fit["counts"][k]))
            continue
        cov = None
        if 2 * fit["n_inl"][k] >= 6:
            try:
                cov = pb.sigma_px**2 * np.linalg.inv(fit["H"][k])
            except np.linalg.LinAlgError:
                cov = None
        if cov is None or not np.all(np.isfinite(cov)):
            out[int(i)] = ViewCheck(P_k, np.full((6, 6), np.nan), e_k, np.full(6, np.nan), False)
        else:
            s2 = own_fit_variance(e_k[fit["inl"][k]])
            pb.own_fit_var[int(i)] = s2
            out[int(i)] = ViewCheck(P_k, cov, e_k, fit["delta"][k], True, _factor(s2, pb.sigma_px))
    return out


def _pnp_starts(pb: "Problem", idx: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Robot poses that put each view's camera at its own PnP pose of the board.

    Robot poses (len(idx),4,4) that put each view's camera at its own PnP pose of the board under the
    current ``T_x``, ``T_board`` and intrinsics (``T_cam_board = inv(T_x) M T_board``); ``fallback`` where
    PnP fails.
    """
    import cv2

    from ..camera import Intrinsics
    from ..errors import CalibrationError
    from ..frames import inv_T
    from ..initial.board_poses import solve_pnp

    intr = Intrinsics.from_vector(pb.k, pb.width, pb.height)
    out = np.array(fallback, float)
    for k, i in enumerate(idx):
        try:
            C, _ = solve_pnp(pb.obj[i], pb.img[i], intr)
        except (CalibrationError, ValueError, cv2.error):  # a view PnP cannot solve keeps its start
            continue
        out[k] = pb.mounting.T_base_end_from_M(pb.T_x @ C @ inv_T(pb.T_board))
    return out


def _own_fits(pb: "Problem", idx: np.ndarray, P: np.ndarray, max_iters: int) -> dict[str, Any]:
    """The robust Gauss-Newton of :func:`camera_only_poses` from the robot poses ``P``.

    The robust Gauss-Newton of :func:`camera_only_poses` from the robot poses ``P`` (len(idx),4,4), all views
    at once. Per view (lists in ``idx`` order): ``P``, ``alive``, ``counts``, ``n_inl`` (corners within
    ``corner_outlier_sigmas``), ``H`` (J^T J over those), ``delta`` (reported to ``P``), ``e`` (each corner's
    residual, px) and ``inl`` (its mask).
    """
    sel = np.concatenate([np.arange(pb.offsets[i], pb.offsets[i + 1]) for i in idx])
    counts = pb.offsets[idx + 1] - pb.offsets[idx]
    local = np.repeat(np.arange(idx.size), counts)  # shape (M,): position in idx of each corner's view
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    obj, img = pb.obj_all[sel], pb.img_all[sel]
    alive = counts > 0
    for it in range(max_iters + 1):
        r, J = stacked_chain_residual(
            T_x=pb.T_x,
            T_base_end=P,
            T_board=pb.T_board,
            invert_robot=pb.invert,
            intrinsics_vec=pb.k,
            object_points=obj,
            image_points=img,
            view_index=local,
            robot_jacobian=True,
        )
        assert J is not None, "robot_jacobian=True gives the Jacobian"
        finite = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(J), axis=(1, 2))
        alive &= np.logical_and.reduceat(finite, starts)
        if it == max_iters:
            break
        ok_rows = alive[local]
        r0 = np.where(ok_rows[:, None], r, 0.0)
        J0 = np.where(ok_rows[:, None, None], J, 0.0)
        _, w = corner_robust_scales(r0.reshape(-1), sigma_px=pb.sigma_px, loss="huber", k=pb.o.loss_k)
        w2 = w * w
        H = np.add.reduceat(np.einsum("mci,mcj,m->mij", J0, J0, w2), starts, axis=0)
        g = np.add.reduceat(np.einsum("mci,mc,m->mi", J0, r0, w2), starts, axis=0)
        H[~alive] = np.eye(6)
        step = np.zeros((idx.size, 6))
        for k in np.flatnonzero(alive):  # 6x6 solves; a singular one fails that view alone
            try:
                step[k] = -np.linalg.solve(H[k], g[k])
            except np.linalg.LinAlgError:
                alive[k] = False
        P = P @ se3_exp(step)
        if np.abs(step).max() < 1e-8:  # rad, m: far below any pose precision; one more evaluation at P
            max_iters = it + 1
    e = np.linalg.norm(r, axis=1)
    inl = (e <= pb.o.corner_outlier_sigmas * pb.sigma_px) & alive[local]
    assert J is not None, "robot_jacobian=True gives the Jacobian"
    Jin = np.where(inl[:, None, None], J, 0.0)
    H = np.add.reduceat(np.einsum("mci,mcj->mij", Jin, Jin), starts, axis=0)
    n_inl = np.add.reduceat(inl.astype(int), starts)
    ends = starts + counts
    return {
        "P": P,
        "alive": alive,
        "counts": counts,
        "n_inl": n_inl,
        "H": H,
        "delta": tangent_difference(pb.reported[idx], P),
        "e": [e[a:b] for a, b in zip(starts, ends, strict=False)],
        "inl": [inl[a:b] for a, b in zip(starts, ends, strict=False)],
    }


def joint_checks(pb: "Problem", S_pp: dict[int, np.ndarray]) -> dict[int, ViewCheck]:
    """The views of the last Gaussian solve as it has them.

    The views of the last Gaussian solve as it has them (their robot poses variables of that solve),
    with the marginal covariance of each robot pose. Returns {view index: ViewCheck}.
    """
    idx = sorted(S_pp)
    if not idx:
        return {}
    e = pb.per_view(np.linalg.norm(pb.corner_residuals(), axis=1))
    delta = tangent_difference(pb.reported[idx], pb.P[idx])
    return {i: ViewCheck(pb.P[i].copy(), S_pp[i], e[i], delta[k], True) for k, i in enumerate(idx)}


@dataclass(frozen=True)
class Decision:
    status: tuple[str, ...]  # per view: used | robot_excluded | removed
    masks: tuple[Any, ...]  # per view: bool array of the corners kept
    outliers: tuple[Any, ...]  # Outlier, ...
    checks: tuple[Any, ...]  # per view ViewCheck
    robot_test: RobotPoseTest  # the robot-pose test of every view

    def key(self) -> tuple[tuple[str, ...], tuple[bytes, ...]]:
        return self.status, tuple(m.tobytes() for m in self.masks)


def _robot_test_cov(pb: "Problem") -> np.ndarray:
    """(n,6,6) each view's robot noise covariance for the test.

    The model's, or for robot_noise "none" the configured iid tolerance.
    """
    if pb.robot_var:
        return pb.robot_cov(range(pb.n))
    R = np.diag([np.radians(pb.o.robot_sigma_deg) ** 2] * 3 + [(pb.o.robot_sigma_mm / 1000.0) ** 2] * 3)
    return np.broadcast_to(R, (pb.n, 6, 6)).copy()


def leave_one_out(e: np.ndarray, R: np.ndarray, S_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The prediction of a robot pose without its own prior, from a solve that had the prior.

    ``e`` (6,): the prior's residual ``tangent_difference(T_reported, P)`` at the solution ``P``;
    ``R`` (6,6): the prior's covariance (robot noise); ``S_p`` (6,6): the marginal covariance of ``P``
    in that solve. For the linearised problem, ``S_p^-1 = S_loo^-1 + R^-1`` and
    ``e = (R - S_p) R^-1 d`` with ``d`` the leave-one-out disagreement, so
    ``d = R (R - S_p)^-1 e`` and ``S_loo = R (R - S_p)^-1 R - R``; ``d^T (S_loo + R)^-1 d`` is then
    ``e^T (R - S_p)^-1 e``, Baarda's normalised residual. Raises LinAlgError when ``R - S_p`` is not
    positive definite (the solve did not weigh the prior as ``R`` says).
    """
    np.linalg.cholesky(R - S_p)
    C_inv_R = np.linalg.solve(R - S_p, R)
    return C_inv_R.T @ e, R @ C_inv_R - R


def prior_share(R: np.ndarray, S_p: np.ndarray) -> float:
    """Smallest eigenvalue of ``R^-1/2 (R - S_p) R^-1/2``.

    The share of a robot pose's information that comes from the camera (1: the camera alone fixes it; 0:
    its prior alone does). :func:`leave_one_out` divides by it, so where it is tiny (a robot sigma near
    its floor, as on a simulated exact robot) the leave-one-out prediction is the rounding error of ``R
    - S_p`` blown up.
    """
    w = 1.0 / np.sqrt(np.diag(R))
    return float(np.linalg.eigvalsh((R - S_p) * np.outer(w, w))[0])


def robot_tests(pb: "Problem", checks: Sequence[ViewCheck], S_pp: Optional[dict[int, np.ndarray]]) -> RobotPoseTest:
    """:func:`robot_pose_test` of every view's reported robot pose against what the other data imply.

    Each view's robot noise covariance R_i is its model's (:meth:`.problem.Problem.robot_cov`). With
    the covariances of a Gaussian solve (``S_pp``: the covariance of each robot-pose variable's prior
    residual, which for the kinematic model includes the DH offsets' share): for a view whose prior is in
    the solve, the leave-one-out prediction from the prior
    residual (:func:`leave_one_out`, Baarda's data snooping); for a view whose prior was excluded,
    its free pose ``P`` with covariance ``S_P``. Otherwise (robust phase, views not in the solve, or a
    view whose prior carries almost all the information about its pose, :func:`prior_share` below
    ``outliers.robot_pose.loo_min_camera_share``) the camera-only pose with its own covariance, which
    ignores the uncertainty of ``T_x``, ``T_board`` and the intrinsics (a share of about 1 / n views).
    Each view's camera-side covariance is scaled by its own corner variance
    (:func:`view_variance_factor`). Under the kinematic model the camera-only comparison is made with
    the current DH offsets taken off the disagreement and their covariance added to the camera's.
    """
    R_all = _robot_test_cov(pb)
    loo_min = float(refine_preset()["outliers"]["robot_pose"]["loo_min_camera_share"])
    d = np.full((pb.n, 6), np.nan)
    C = np.full((pb.n, 6, 6), np.nan)
    e_all = pb.prior_residuals(range(pb.n))  # shape (n, 6): prior residuals
    J_all = pb.J_dh(range(pb.n))  # shape (n, 6, m)
    dh_cov = np.einsum("nim,mk,njk->nij", J_all, pb.S_dd, J_all)  # the DH offsets' share of each pose

    def camera_side(i: int, ch: ViewCheck) -> tuple[np.ndarray, np.ndarray]:
        return ch.delta - J_all[i] @ pb.dh, ch.cov_cam * ch.variance_factor + dh_cov[i]

    own: list[int] = []  # views compared with their own fit
    for i, ch in enumerate(checks):
        Sp = None if S_pp is None else S_pp.get(i)
        f = ch.variance_factor  # the view's own corner variance (camera side only; see view_variance_factor)
        R = R_all[i]
        if Sp is not None and pb.status[i] in ("used", "robot_excluded") and pb.has_robot_var(i):
            e = e_all[i]
            try:
                if pb.status[i] == "used" and prior_share(R, Sp) < loo_min:
                    raise np.linalg.LinAlgError("the prior dominates: no reliable leave-one-out prediction")
                if pb.status[i] == "used":
                    d[i], C[i] = leave_one_out(e, R, Sp)
                else:
                    d[i], C[i] = e, Sp
                C[i] *= f
                continue
            except np.linalg.LinAlgError:  # fall back to the camera-only comparison
                own.append(i)
                continue
        if ch.ok:
            d[i], C[i] = camera_side(i, ch)
    for i, ch in camera_only_poses(pb, own).items() if own else ():  # all fall-backs in one batch
        if ch.ok:
            d[i], C[i] = camera_side(i, ch)
    return robot_pose_test(
        d, C, robot_covariance=R_all, gates=RobotPoseGates.from_options(pb.o, unmodelled_arm=pb.kind != "kinematic")
    )


def decide(pb: "Problem", *, robust_robot_sigma: bool, S_pp: Optional[dict[int, np.ndarray]] = None) -> Decision:
    """Outlier decisions for every view against the current solution.

    Outlier decisions for every view against the current solution, each with a reason and the size
    of the disagreement:

    * corners further than ``corner_outlier_sigmas`` from their prediction are flagged
      (``corners``): against the last Gaussian solve for views in it, otherwise against the pose
      that the view's corners alone imply (robust Gauss-Newton with ``T_x``, ``T_board`` and the
      intrinsics held);
    * a view keeping fewer than ``min_corners`` corners is dropped (``too_few_corners``); a view
      with more than ``outliers.reprojection_share`` of its corners flagged is dropped
      (``reprojection``);
    * the reported robot pose is tested by :func:`robot_tests`; a disagreeing view loses its robot
      prior (``robot_pose``) but keeps its corners, which still inform the intrinsics.

    ``robust_robot_sigma``: first set the robot sigmas from the camera-only poses by the robust
    (median) estimator, for decisions made before the data are clean. ``S_pp``: robot-pose
    covariances of the last Gaussian solve, for the exact robot-pose tests.
    """
    o = pb.o
    t_corner = o.corner_outlier_sigmas
    share = float(refine_preset()["outliers"]["reprojection_share"])
    # views outside the last Gaussian solve: their own fit; views in it: the variance factor of their
    # camera side from their own fit (measured without the robot pose; its residual variance hardly
    # moves between rounds, so a view's first own fit serves, divided by the current sigma_px^2)
    by_view = joint_checks(pb, S_pp) if S_pp is not None else {}
    need = [i for i in range(pb.n) if len(pb.obj[i]) >= o.min_corners and (i not in by_view or i not in pb.own_fit_var)]
    own = camera_only_poses(pb, need)
    by_view = {
        i: replace(ch, variance_factor=_factor(pb.own_fit_var.get(i, np.nan), pb.sigma_px)) for i, ch in by_view.items()
    }
    by_view.update({i: ch for i, ch in own.items() if i not in by_view})
    checks = [by_view.get(i) or _failed_check(pb.P[i], len(pb.obj[i])) for i in range(pb.n)]
    if robust_robot_sigma:
        robust_robot_sigmas(pb, {i: checks[i] for i in pb.prior_views()})
        if o.robot_noise == "estimate":
            # never below the configured start: on few views the robust estimate can fall to its floor (the
            # camera-only covariances explain the median disagreement), and a robot sigma of ~0 would flag
            # nearly every view before the variance components have spoken (VCE approaches a small robot
            # sigma from above, so the start must not be at the floor either)
            if pb.kin is not None:
                pb.sigma_q = max(pb.sigma_q, pb.kin.encoder_sigma_rad)
            else:
                pb.sigma_rot = max(pb.sigma_rot, np.radians(o.robot_sigma_deg))
                pb.sigma_trans = max(pb.sigma_trans, o.robot_sigma_mm / 1000.0)
    test = robot_tests(pb, checks, S_pp)
    status, masks, outliers = [], [], []
    for i, vid in enumerate(pb.ids):
        ch = checks[i]
        n_all = len(ch.resid_px)
        bad = ~(ch.resid_px <= max(t_corner * pb.sigma_px, o.min_corner_outlier_px))
        n_good = int((~bad).sum())
        if not ch.ok and n_all >= o.min_corners:
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(
                Outlier(
                    vid,
                    "reprojection",
                    f"view {vid}: its corners alone do not determine a pose ({n_all} corners)",
                    size={"n_corners": n_all},
                )
            )
            continue
        if n_good < o.min_corners or not ch.ok:
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(
                Outlier(
                    vid,
                    "too_few_corners",
                    f"view {vid}: {n_good} usable corners of {n_all}, need {o.min_corners}",
                    size={"n_usable": n_good, "n_corners": n_all},
                )
            )
            continue
        if bad.mean() > share:
            rms = float(np.sqrt(np.mean(ch.resid_px**2)))
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(
                Outlier(
                    vid,
                    "reprojection",
                    f"view {vid}: {int(bad.sum())} of {n_all} corners beyond "
                    f"{t_corner:g} sigma even with the pose fitted to this view alone "
                    f"(rms {rms:.2f} px, sigma {pb.sigma_px:.3f} px)",
                    size={"rms_px": rms, "max_px": float(ch.resid_px.max()), "n_flagged": int(bad.sum())},
                )
            )
            continue
        masks.append(~bad)
        if bad.any():
            ids = tuple(int(c) for c in np.asarray(pb.views[i].corner_ids)[bad])
            outliers.append(
                Outlier(
                    vid,
                    "corners",
                    f"view {vid}: {len(ids)} corner(s) beyond {t_corner:g} sigma "
                    f"(max {ch.resid_px[bad].max():.2f} px, sigma {pb.sigma_px:.3f} px)",
                    corner_ids=ids,
                    size={"residual_px": ch.resid_px[bad]},
                )
            )
        if test.flagged[i]:
            status.append("robot_excluded")
            outliers.append(
                robot_pose_outlier(
                    vid,
                    test,
                    i,
                    "reported robot pose disagrees with the camera",
                    "its corners still serve the intrinsics",
                )
            )
        else:
            status.append("used")
    return Decision(tuple(status), tuple(masks), tuple(outliers), tuple(checks), test)


def apply_decision(pb: "Problem", dec: Decision) -> None:
    pb.status = list(dec.status)
    pb.mask = [m.copy() for m in dec.masks]
    for i, ch in enumerate(dec.checks):  # start excluded / re-admitted poses from the camera's pose
        if ch.ok and dec.status[i] != "used":
            pb.P[i] = ch.P_cam


class TooFewRobotPoses(Exception):
    """Fewer than 3 views keep a robot pose that agrees with the camera."""


def outlier_loop(pb: "Problem") -> tuple[Decision, Optional[np.ndarray], Optional[dict[int, np.ndarray]]]:
    """Decide, exclude, re-solve and decide again until the set of outliers is stable.

    Decide, exclude, re-solve (Gaussian, with variance-component estimation) and decide again from
    scratch against the clean solution, so that a flagged view or corner that fits it is re-admitted,
    until the set is stable (or ``max_outlier_rounds``). Returns (Decision, Sigma_core, {view:
    Sigma_robot}); raises TooFewRobotPoses.
    """
    o = pb.o
    seen_keys: list[tuple[tuple[str, ...], tuple[bytes, ...]]] = []
    S_cc: Optional[np.ndarray] = None
    S_pp: Optional[dict[int, np.ndarray]] = None
    for rnd in range(o.max_outlier_rounds):
        dec = decide(pb, robust_robot_sigma=rnd == 0, S_pp=S_pp)
        if seen_keys and dec.key() == seen_keys[-1]:
            return dec, S_cc, S_pp
        if dec.key() in seen_keys:
            # two sets alternate (a borderline view): settle on the latest decision, solved with it
            log.warning("outlier decisions oscillate; solving once more with the latest set")
            apply_decision(pb, dec)
            S_cc, S_pp = solve_with_vce(pb)
            return dec, S_cc, S_pp
        seen_keys.append(dec.key())
        apply_decision(pb, dec)
        n_robot = len(pb.prior_views()) + (
            0 if pb.robot_var else len([i for i in pb.active() if pb.status[i] == "used"])
        )
        if n_robot < 3:
            raise TooFewRobotPoses(
                f"only {len(pb.prior_views())} views left whose robot pose agrees with the camera; need 3"
            )
        S_cc, S_pp = solve_with_vce(pb)
    log.warning("outlier decisions did not settle in %d rounds", o.max_outlier_rounds)
    return decide(pb, robust_robot_sigma=False, S_pp=S_pp), S_cc, S_pp


def robot_pose_outlier(vid: str, test: RobotPoseTest, i: int, what: str, consequence: str) -> Outlier:
    """The ``robot_pose`` outlier of view ``vid``.

    The ``robot_pose`` outlier of view ``vid`` (index ``i`` of the robot-pose ``test``): its disagreement in
    degrees, mm and Mahalanobis distance against the threshold, with what happens to the view.
    """
    rot_deg, trans_mm, dist = float(test.rot_deg[i]), float(test.trans_mm[i]), float(test.distance[i])
    thr = float(np.sqrt(test.threshold))
    nu = float(test.gates.tail_dof)
    tail = "" if not np.isfinite(nu) else f" of the unmodelled arm's error, t with {nu:g} dof"
    return Outlier(
        vid,
        "robot_pose",
        f"view {vid}: {what} by {rot_deg:.3f} deg / {trans_mm:.2f} mm (Mahalanobis "
        f"{dist:.1f}, threshold {thr:.1f}{tail}); {consequence}",
        size={
            "rot_deg": rot_deg,
            "trans_mm": trans_mm,
            "mahalanobis": dist,
            "p_value": float(test.p_value[i]),
            "threshold": thr,
            "tail_dof": nu if np.isfinite(nu) else None,
            "sigma_rot_deg": float(test.sigma_rot_deg[i]),
            "sigma_trans_mm": float(test.sigma_trans_mm[i]),
        },
    )
