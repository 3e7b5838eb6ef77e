"""An arm's kinematic error model in the refinement of pose-only views (tracker sessions).

The model of image sessions (:mod:`.robot_model`): the true flange pose is
``T_reported_i · Exp(J_dh,i · delta + J_q,i · e_i)``, DH offsets ``delta`` shared by all views under the
arm's error prior and encoder noise ``e_i``. In the pose graph ``delta`` is a variable beside ``T_x`` and
the target (:func:`.problem.solve_pose_dh_graph`); the encoder noise reaches each view's residual
covariance through the chain (:func:`handeye.factors.pose.pose_robot_residual`) and is held at its stated
sigma: from poses alone it cannot be told from the tracker's noise. X's covariance is the marginal of the
joint one, so the DH offsets the views leave at their prior carry their prior's uncertainty into it.

See docs/robot_error.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Optional, Sequence

import numpy as np

from handeye.factors.pose import pose_robot_residual

from ..frames import se3_exp
from ..mounting import mounting
from .options import RefineOptions, RefineView
from .robot_model import KinematicRobotModel, build_kinematic_model, describe_dh, kinematic_model_dict, resolve_kind

#: a DH offset is "resolved" when the views remove more than this share of its prior variance (as the report says)
RESOLVED_SHARE = 0.5


@dataclass(frozen=True)
class PoseRobotModel:
    """The kinematic model of a pose-only session's views: the arm's matrices per view and the DH prior."""

    km: KinematicRobotModel
    view_ids: tuple[str, ...]
    T_base_end: np.ndarray  # (n, 4, 4) the reported flange poses
    inverts_robot: bool  # eye-in-hand: M = inv(T_base_end)

    @property
    def m(self) -> int:
        return self.km.m

    @property
    def dh_prior(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean (m,), covariance (m,m)) of the DH offsets: N(0, the arm's error prior)."""
        return np.zeros(self.m), np.diag(self.km.dh_sigma**2)

    def prior_information(self) -> np.ndarray:
        """(m,m) the information of the DH offsets' prior."""
        return np.diag(1.0 / self.km.dh_sigma**2) if self.m else np.zeros((0, 0))

    def subset(self, view_ids: Sequence[str]) -> "PoseRobotModel":
        """The model of some of its views (by id, in the order given)."""
        pos = {v: i for i, v in enumerate(self.view_ids)}
        k = [pos[v] for v in view_ids]
        km = replace(
            self.km,
            joints=self.km.joints[k],
            joints_source=tuple(self.km.joints_source[i] for i in k),
            J_dh=self.km.J_dh[k],
            B=self.km.B[k],
        )
        return replace(self, km=km, view_ids=tuple(view_ids), T_base_end=self.T_base_end[k])

    def residuals(
        self, T_x: np.ndarray, T_board: np.ndarray, T_cam_board: np.ndarray, dh: np.ndarray, *, jacobians: bool
    ) -> tuple[np.ndarray, Optional[np.ndarray], np.ndarray]:
        """(r (n,6), J (n,6,12+m) or None, J_u (n,6,6)) of every view at ``T_x``, ``T_board`` and the offsets ``dh``.

        ``J`` in the order (T_x, T_board, DH offsets); ``J_u``: each residual's Jacobian in its flange error.
        """
        n = len(self.view_ids)
        r = np.zeros((n, 6))
        J = np.zeros((n, 6, 12 + self.m)) if jacobians else None
        J_u = np.zeros((n, 6, 6))
        for i in range(n):
            Jd = self.km.J_dh[i]
            ri, J_x, J_b, Ju = pose_robot_residual(
                T_x=T_x,
                T_base_end=self.T_base_end[i],
                u=Jd @ dh if self.m else np.zeros(6),
                T_board=T_board,
                T_cam_board_measured=T_cam_board[i],
                inverts_robot=self.inverts_robot,
            )
            assert J_x is not None and J_b is not None and Ju is not None, "asked for the Jacobians"
            r[i], J_u[i] = ri, Ju
            if J is not None:
                J[i] = np.hstack([J_x, J_b, Ju @ Jd])
        return r, J, J_u

    def covariances(self, T_x: np.ndarray, T_board: np.ndarray, T_cam_board: np.ndarray, dh: np.ndarray) -> np.ndarray:
        """(n,6,6) the encoder noise's share of every view's residual covariance: ``s_q^2 J_u B J_u^T``."""
        _, _, J_u = self.residuals(T_x, T_board, T_cam_board, dh, jacobians=False)
        return self.km.encoder_sigma_rad**2 * J_u @ self.km.B @ np.swapaxes(J_u, 1, 2)

    def flange_poses(self, dh: np.ndarray) -> np.ndarray:
        """(n,4,4) every view's flange pose as the model corrects it: ``T_reported_i · Exp(J_dh,i · dh)``."""
        if not self.m:
            return self.T_base_end.copy()
        return self.T_base_end @ se3_exp(np.einsum("nij,j->ni", self.km.J_dh, dh))

    def equivalent_sigmas(self) -> tuple[float, float]:
        """(mm, deg): the RMS per axis of the encoder noise at the flange over the views."""
        d = self.km.encoder_sigma_rad**2 * np.diagonal(self.km.B, axis1=1, axis2=2)
        return 1000.0 * float(np.sqrt(np.mean(d[:, 3:]))), float(np.degrees(np.sqrt(np.mean(d[:, :3]))))


def pose_robot_model(options: RefineOptions, mode: str, views: Sequence[Any]) -> Optional[PoseRobotModel]:
    """The kinematic model of pose-only ``views`` (``PoseView``) when the options name an arm, else None.

    ``robot_model`` auto or kinematic: DH offsets and encoder noise; joint_space: encoder noise only;
    iid (or ``robot_noise`` none): None, the robot's noise per view is part of the tracker's. Joint angles
    from the views, else by inverse kinematics of the reported poses.
    """
    if options.arm is None or options.robot_noise == "none" or options.robot_model == "iid":
        return None
    reported = np.stack([np.asarray(v.T_base_end, float) for v in views])
    rviews = [
        RefineView(v.view_id, np.zeros(0, int), np.zeros((0, 2)), reported[i], getattr(v, "joint_angles", None))
        for i, v in enumerate(views)
    ]
    km = build_kinematic_model(options, resolve_kind(options, rviews), rviews, reported)
    return PoseRobotModel(km, tuple(v.view_id for v in views), reported, mounting(mode).inverts_robot)


def describe(
    model: PoseRobotModel, dh: np.ndarray, S_dd: Optional[np.ndarray], tracker_estimated: bool
) -> dict[str, Any]:
    """``refinement.robot_model`` of a pose-only result refined with the arm's model.

    The kinematic model's description (:func:`.robot_model.kinematic_model_dict`), the DH offsets with
    their sigmas and resolved shares (``S_dd`` (m,m) their covariance, None: the prior's), and
    ``pose_only``: what poses alone cannot tell apart.
    """
    km = model.km
    d = kinematic_model_dict(
        km, ids=model.view_ids, encoder_sigma_rad=km.encoder_sigma_rad, encoder_estimated=False, encoder_resolved=None
    )
    limits: dict[str, Any] = {
        "encoder_noise": (
            "held at the arm's stated sigma: a tracker's camera -> target pose carries the encoders' noise and "
            "the tracker's in one 6-vector per view, so poses alone cannot tell them apart"
            + ("; the tracker's sigmas were estimated with the encoders' share held" if tracker_estimated else "")
        ),
    }
    if km.m:
        S = model.dh_prior[1] if S_dd is None else S_dd
        d.update(describe_dh(km, dh, S))
        share = np.asarray(d["dh_resolved_share"], float).reshape(-1)
        names = km.parameter_names()
        held = [nm for nm, s in zip(names, share, strict=True) if s <= RESOLVED_SHARE]
        limits.update(
            {
                "dh_resolved": [nm for nm, s in zip(names, share, strict=True) if s > RESOLVED_SHARE],
                "dh_held_by_prior": held,
                "dh_offsets": (
                    f"{km.m - len(held)} of {km.m} DH offsets are known more from the views than from the arm's "
                    f"prior; the other {len(held)} act on the poses as a change of the base, the tool, X or the "
                    "target does, or are too weakly moved, and stay near their prior: their prior's uncertainty "
                    "is in X's covariance (marginalised), never in its estimate's claimed accuracy"
                ),
            }
        )
    d["pose_only"] = limits
    return d
