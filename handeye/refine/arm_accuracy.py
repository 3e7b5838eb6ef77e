"""The arm's stated absolute accuracy as a term of X's verdict covariance.

An error of the arm's reported poses that is the same in every view is invisible in the data: at the
camera's end of the chain (the flange of an eye-in-hand rig, the base of an eye-to-hand one) it gives
exactly the data of an exact arm with another X, so it enters X one to one and no residual, fold or half
can show it. X is then right in the arm's own (reported) frames, which is what grasping with the same arm
needs, and off from the mechanical X by the arm's error. The arm's kinematic model (``--robot ARM``)
bounds that error by its DH prior; without it, a stated accuracy (``robot_accuracy: {mm, deg}``:
the flange pose's error per axis, constant over the session's workspace) adds its covariance, mapped
into X's tangent, to the verdict covariance (docs/uncertainty.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frames import inv_T, se3_adjoint

#: where the constant error sits, per mounting mode
FRAMES = {
    "eye_in_hand": "the flange frame (a constant flange error moves T_end_cam one to one)",
    "eye_to_hand": "the base frame at the workspace centre (a constant base error moves T_base_cam one to one)",
}


@dataclass(frozen=True)
class ArmAccuracy:
    """A stated accuracy of the arm and its covariance in X's tangent (covariance.COV_PARAMETRISATION)."""

    sigma_mm: float
    sigma_deg: float
    frame: str
    cov_x_6x6: np.ndarray

    def describe(self) -> dict[str, object]:
        """``refinement.robot_accuracy`` of result.json."""
        return {
            "sigma_mm": self.sigma_mm,
            "sigma_deg": self.sigma_deg,
            "frame": self.frame,
            "cov_x_6x6": self.cov_x_6x6,
            "in_verdict": True,
            "note": "the arm's stated accuracy: an error common to every view that the data cannot show (it "
            "enters X one to one); its covariance is added to the verdict covariance",
        }


def arm_accuracy_covariance(
    mode: str, T_x: np.ndarray, T_base_end: np.ndarray, *, sigma_mm: float, sigma_deg: float
) -> np.ndarray:
    """Covariance (6,6) in X's right tangent of a constant arm error of ``sigma_deg`` / ``sigma_mm`` per axis.

    Eye-in-hand: reported flange poses ``T_base_end_i · E`` with one ``E = Exp(e)`` in the flange frame give
    ``T_end_cam' = E · T_end_cam``, so ``xi = -Ad(T_cam_end) e``. Eye-to-hand: ``L · T_base_end_i`` with
    ``L`` a constant error about the workspace centre ``c`` (the mean reported flange position, so that the
    stated mm is the flange's error there, not at the base's origin) give ``T_base_cam' = L^-1 · T_base_cam``,
    so ``xi = Ad(T_cam_base · T_c) e``. ``T_base_end``: the session's reported flange poses (N,4,4).
    """
    if sigma_mm < 0 or sigma_deg < 0 or not np.isfinite(sigma_mm + sigma_deg):
        raise ValueError(f"robot accuracy must be finite and non-negative, not {sigma_mm} mm / {sigma_deg} deg")
    S = np.diag([np.radians(sigma_deg) ** 2] * 3 + [(sigma_mm / 1000.0) ** 2] * 3)
    T_cam_x = inv_T(np.asarray(T_x, float))
    if mode == "eye_in_hand":
        A = se3_adjoint(T_cam_x)
    elif mode == "eye_to_hand":
        T_c = np.eye(4)
        T_c[:3, 3] = np.asarray(T_base_end, float)[:, :3, 3].mean(axis=0)
        A = se3_adjoint(T_cam_x @ T_c)
    else:
        raise ValueError(f"unknown mounting mode {mode!r}")
    return A @ S @ A.T


def arm_accuracy(mode: str, T_x: np.ndarray, T_base_end: np.ndarray, stated: tuple[float, float]) -> ArmAccuracy:
    """:class:`ArmAccuracy` of ``stated`` = (mm, deg) for a result ``T_x`` of ``mode``."""
    mm, deg = float(stated[0]), float(stated[1])
    cov = arm_accuracy_covariance(mode, T_x, T_base_end, sigma_mm=mm, sigma_deg=deg)
    return ArmAccuracy(mm, deg, FRAMES[mode], cov)
