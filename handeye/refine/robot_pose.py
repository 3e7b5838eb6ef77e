"""THE robot-pose outlier test, and the record of one outlier decision (pure numpy, no GTSAM).

:func:`robot_pose_test` is the one gated test of a reported robot pose against the pose the rest of
the data predict; the refinement (:mod:`.outliers`) and the diagnostics (for runs without a
refinement) both call it. :class:`Outlier` is one decision with its reason, for either.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Optional

import numpy as np

from ..errors import ConfigError
from ..output import plain
from ..stats import mixture_tail_pvalue, mixture_tail_quantile
from .options import RefineOptions, refine_preset

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
    # a prediction whose covariance is not positive definite (e.g. from two views, one motion, which leaves X
    # free about its axis) says nothing to test the reported pose against
    ok &= np.all(np.isfinite(Ct), axis=(1, 2))
    ok[ok] &= np.linalg.eigvalsh(0.5 * (Ct[ok] + np.swapaxes(Ct[ok], 1, 2)))[:, 0] > 0
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
        sigma_rot_deg=np.where(ok, np.degrees(np.sqrt(np.abs(diag[:, :3].sum(axis=1)))), np.nan),
        sigma_trans_mm=np.where(ok, 1000.0 * np.sqrt(np.abs(diag[:, 3:].sum(axis=1))), np.nan),
        threshold=g.threshold,
        gates=g,
    )


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
