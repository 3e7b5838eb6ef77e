"""Outlier decisions of the refinement, and THE robot-pose outlier test (pure numpy, no GTSAM).

:func:`robot_pose_test` is the one gated test of a reported robot pose against the pose the rest of
the data predict; the refinement and the diagnostics (for runs without a refinement) both call it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc, chdtri

from ..config import load_preset

ROBOT_POSE_DOF = 6


@dataclass(frozen=True)
class RobotPoseGates:
    """Gates of :func:`robot_pose_test` (configs/refine.yaml ``outliers.robot_pose``)."""

    alpha: float  # false-alarm probability per view
    min_rot_deg: float  # practical-significance floor of the rotation disagreement
    min_trans_mm: float  # ... and of the translation disagreement

    @staticmethod
    def from_config(cfg: dict | None = None) -> "RobotPoseGates":
        c = (cfg if cfg is not None else load_preset("refine"))["outliers"]["robot_pose"]
        return RobotPoseGates(alpha=float(c["alpha"]), min_rot_deg=float(c["min_rot_deg"]),
                              min_trans_mm=float(c["min_trans_mm"]))

    @property
    def threshold(self) -> float:
        """The chi-square(6) quantile at 1 - alpha (squared Mahalanobis units)."""
        return float(chdtri(ROBOT_POSE_DOF, self.alpha))


@dataclass(frozen=True)
class RobotPoseTest:
    """Result of :func:`robot_pose_test` for n views (NaN rows: no test, never flagged)."""

    statistic: np.ndarray  # (n,) squared Mahalanobis distance, chi-square(6) for a correct pose
    p_value: np.ndarray  # (n,) P(chi-square(6) > statistic)
    flagged: np.ndarray  # (n,) bool
    rot_deg: np.ndarray  # (n,) |omega| of the disagreement
    trans_mm: np.ndarray  # (n,) |v| of the disagreement
    threshold: float  # chi-square(6) quantile at 1 - alpha
    gates: RobotPoseGates

    @property
    def distance(self) -> np.ndarray:
        """sqrt(statistic): the disagreement in sigmas."""
        return np.sqrt(self.statistic)


def robot_pose_test(disagreement: np.ndarray, covariance: np.ndarray, *, robot_sigma_rot_rad: float,
                    robot_sigma_trans_m: float, gates: RobotPoseGates | None = None) -> RobotPoseTest:
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
      the same tangent), estimated or configured.

    The check: under "the reported pose is right up to robot noise", ``d_i ~ N(0, C_i + R)`` with
    ``R = diag(s_rot^2 I3, s_trans^2 I3)``, so ``statistic_i = d_i^T (C_i + R)^-1 d_i`` is
    chi-square with 6 degrees of freedom and ``p_value_i`` its upper tail. A view is flagged when
    ``p_value_i < alpha`` AND the disagreement is practically large: its rotation exceeds
    ``min_rot_deg`` or its translation ``min_trans_mm``. Gates default to configs/refine.yaml.
    Rows with a non-finite disagreement or covariance are not tested (NaN statistic, not flagged).
    """
    g = gates if gates is not None else RobotPoseGates.from_config()
    d = np.asarray(disagreement, float).reshape(-1, 6)
    C = np.asarray(covariance, float).reshape(-1, 6, 6)
    if C.shape[0] != d.shape[0]:
        raise ValueError(f"disagreement has {d.shape[0]} rows but covariance {C.shape[0]}")
    R = np.diag([robot_sigma_rot_rad ** 2] * 3 + [robot_sigma_trans_m ** 2] * 3)
    ok = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(C), axis=(1, 2))
    stat = np.full(d.shape[0], np.nan)
    if ok.any():
        Ct = C[ok] + R
        stat[ok] = np.einsum("ni,ni->n", d[ok], np.linalg.solve(Ct, d[ok][..., None])[..., 0])
    p = np.where(ok, chdtrc(ROBOT_POSE_DOF, np.where(ok, stat, 0.0)), np.nan)
    rot_deg = np.degrees(np.linalg.norm(d[:, :3], axis=1))
    trans_mm = 1000.0 * np.linalg.norm(d[:, 3:], axis=1)
    large = (rot_deg > g.min_rot_deg) | (trans_mm > g.min_trans_mm)
    flagged = ok & (np.nan_to_num(p, nan=1.0) < g.alpha) & large
    return RobotPoseTest(statistic=stat, p_value=p, flagged=flagged, rot_deg=rot_deg, trans_mm=trans_mm,
                         threshold=g.threshold, gates=g)
