"""The refinement's solver state without GTSAM: views, noise levels, robot error model and residuals.

:class:`ProblemState` holds what one refine() call changes as it goes (per view: status, corner
mask, reported and estimated robot pose; the noise levels; the DH offsets of a kinematic arm) and
evaluates it in numpy. :class:`~.problem.Problem` adds the factor graph, the solves and the
marginal covariances; it is the only module here that imports GTSAM.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from handeye.factors.reprojection import stacked_chain_jacobians, stacked_chain_residual

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..errors import ConfigError
from ..frames import se3_exp, tangent_difference
from ..mounting import mounting
from .covariance import N_POSES
from .options import RefineOptions, RefineView, check_T, refine_preset
from .robot_model import build_kinematic_model, resolve_kind


@dataclass(frozen=True)
class PixelLinearisation:
    """Reprojection part of a linearisation with unit pixel sigma.

    Reprojection part of a linearisation with unit pixel sigma: information blocks (core c, then n
    robot blocks), gradient g = J^T r, r^T r and the count of observations; plus the robot prior
    residuals xi (n,6) (:meth:`Problem.prior_residuals`; rows without a prior flagged False in
    ``prior``) and their Jacobians in the DH offsets ``J_dh`` (n,6,m), the core's last m unknowns.
    """

    Hcc: np.ndarray
    Hcp: np.ndarray  # shape (n, c, 6)
    Hpp: np.ndarray  # shape (n, 6, 6)
    g: np.ndarray  # shape (c + 6n,)
    rr: float
    n_obs: int
    prior: np.ndarray
    xi: np.ndarray
    c: int
    robot_views: tuple[Any, ...]  # view index of each robot block, in order
    J_dh: np.ndarray  # shape (n, 6, m)


@dataclass(frozen=True)
class ReprojectionBlocks:
    """Per view, the Gauss-Newton blocks of its reprojections at unit pixel sigma.

    The core ``cp`` is T_x, T_board and the free intrinsics; ``p`` is the view's robot-pose variable.
    """

    Hcc: np.ndarray  # shape (k, cp, cp): J_c^T J_c
    Hcp: np.ndarray  # shape (k, cp, 6): J_c^T J_p
    Hpp: np.ndarray  # shape (k, 6, 6): J_p^T J_p
    gc: np.ndarray  # shape (k, cp): J_c^T r
    gp: np.ndarray  # shape (k, 6): J_p^T r
    rr: np.ndarray  # shape (k,): r^T r [px^2]


class ProblemState:
    """Mutable solver state for one refine() call (results are copied out of it).

    Per view: ``status`` (used | robot_excluded | removed), a corner ``mask``, the reported robot
    pose and the current estimate ``P`` of the true one. The noise levels (``sigma_px``,
    ``sigma_rot`` [rad], ``sigma_trans`` [m] of the iid robot model, ``sigma_q`` [rad] of the
    kinematic one) are the noise models of the next solve. The robot error model
    (:mod:`.robot_model`) is ``kind``; the kinematic one adds the DH offsets ``dh`` (m,) to the core,
    after the free intrinsics, with ``S_dd`` their latest marginal covariance (at first their prior).
    """

    def __init__(
        self,
        *,
        mode: str,
        object_points: np.ndarray,
        views: Sequence[RefineView],
        reported: np.ndarray,
        intrinsics: Intrinsics,
        T_x0: np.ndarray,
        T_board0: np.ndarray,
        options: RefineOptions,
    ):
        """``reported`` (n,4,4): the views' reported robot poses, checked (:func:`.options.check_inputs`)."""
        self.mode = mode
        self.mounting = mounting(mode)
        self.invert = self.mounting.inverts_robot
        self.o = options
        self.views = list(views)
        self.n = len(self.views)
        self.ids = [v.view_id for v in self.views]
        self.obj = [np.asarray(object_points, float)[np.asarray(v.corner_ids, int)] for v in self.views]
        self.img = [np.asarray(v.image_points, float).reshape(-1, 2) for v in self.views]
        self.reported = np.array(reported, float)
        # all corners stacked in view order, for the numpy evaluations of every view at once
        counts = np.array([len(o) for o in self.obj], int)
        self.offsets = np.r_[0, np.cumsum(counts)]
        self.view_of = np.repeat(np.arange(self.n), counts)  # shape (M,): the view of each corner
        self.obj_all = np.concatenate(self.obj) if self.n else np.zeros((0, 3))
        self.img_all = np.concatenate(self.img) if self.n else np.zeros((0, 2))
        self.board_centre = np.asarray(object_points, float).mean(axis=0)
        self.width, self.height = intrinsics.width, intrinsics.height
        self.k = intrinsics.as_vector().astype(float)
        self.k_given = self.k.copy()
        if options.intrinsics == "fixed":
            self.free = np.zeros(0, int)
        else:
            self.free = np.array([i for i, n in enumerate(INTRINSIC_NAMES) if n not in options.fix], int)
        self.prior_sig = None
        if options.intrinsics == "prior" and self.free.size:
            if options.intrinsics_prior_sigma is not None:
                sig = np.asarray(options.intrinsics_prior_sigma, float)
            else:
                p = refine_preset()["intrinsics_prior"]
                w = self.width if self.width > 0 else 2.0 * self.k[2]
                h = self.height if self.height > 0 else 2.0 * self.k[3]
                sig = np.r_[
                    p["focal_share"] * self.k[0],
                    p["focal_share"] * self.k[1],
                    p["centre_share"] * w,
                    p["centre_share"] * h,
                    np.asarray(p["distortion"], float),
                ]
            self.prior_sig = sig[self.free]
        # options.prior: Gaussian priors on T_x and on the free intrinsics (e.g. an earlier calibration)
        self.prior_x: Optional[tuple[np.ndarray, np.ndarray]] = None  # (T_x of the prior (4,4), its covariance (6,6))
        self.prior_k: Optional[tuple[np.ndarray, np.ndarray]] = (
            None  # (mean (nk,), covariance (nk, nk)) of the free intrinsics
        )
        self.prior_cov_xk: Optional[np.ndarray] = (
            None  # (6+nk, 6+nk): the two as one joint Gaussian (prior.cov_x_intrinsics given)
        )
        self.prior_board: Optional[tuple[np.ndarray, np.ndarray]] = (
            None  # (T_board of the prior (4,4), its covariance (6,6))
        )
        self.prior_cov_bk: Optional[np.ndarray] = (
            None  # (6+nk, 6+nk): the board and the intrinsics as one (prior.cov_board_intrinsics)
        )
        if options.prior is not None:
            p = options.prior
            self.prior_x = (check_T(p.T_x, "prior T_x"), np.asarray(p.cov_x, float))
            if p.T_board is not None:
                self.prior_board = (check_T(p.T_board, "prior T_board"), np.asarray(p.cov_board, float))
            if p.intrinsics is not None and self.free.size:
                self.prior_k = (
                    p.intrinsics.as_vector()[self.free].astype(float),
                    np.asarray(p.cov_intrinsics, float)[np.ix_(self.free, self.free)],
                )
                if p.cov_x_intrinsics is not None:
                    C = np.asarray(p.cov_x_intrinsics, float)[:, self.free]
                    self.prior_cov_xk = np.block([[self.prior_x[1], C], [C.T, self.prior_k[1]]])
                elif p.cov_board_intrinsics is not None:
                    assert self.prior_board is not None, "check_prior: cov_board_intrinsics needs T_board"
                    C = np.asarray(p.cov_board_intrinsics, float)[:, self.free]
                    self.prior_cov_bk = np.block([[self.prior_board[1], C], [C.T, self.prior_k[1]]])
        self.robot_var = options.robot_noise != "none"
        self.kind = resolve_kind(options, self.views)
        self.kin = (
            build_kinematic_model(options, self.kind, self.views, self.reported)
            if self.kind in ("kinematic", "joint_space")
            else None
        )
        self.m_dh = self.kin.m if self.kin is not None else 0
        # the DH offsets' prior: N(0, the arm's error prior), or an earlier calibration's estimate (prior.dh_offsets)
        self.prior_dh = (
            np.zeros(self.m_dh),
            np.diag(self.kin.dh_sigma**2) if self.kin is not None and self.m_dh else np.zeros((0, 0)),
        )
        self.prior_dh_earlier = False  # prior_dh is an earlier calibration's estimate, not the arm's error prior
        p = options.prior
        if self.m_dh and p is not None and p.dh_offsets is not None:
            if np.size(p.dh_offsets) != self.m_dh:
                assert self.kin is not None, "m_dh > 0 only with a kinematic model"
                raise ConfigError(
                    "prior.dh_offsets does not fit the arm's kinematic model",
                    expected=f"{self.m_dh} DH offsets ({self.kin.arm.name})",
                    received=f"{np.size(p.dh_offsets)}",
                    hint="give the DH offsets of a calibration of this arm, or none",
                )
            self.prior_dh = (np.asarray(p.dh_offsets, float).copy(), np.asarray(p.cov_dh, float).copy())
            self.prior_dh_earlier = True
        self.dh, self.S_dd = self.prior_dh[0].copy(), self.prior_dh[1].copy()  # the start: the prior's
        # the arm's stated DH error prior (scale 1), and the scale it is used at: 1 unless the views contradict it,
        # then estimated (handeye.refine.noise); the test's outcome in dh_scale_test
        self.dh_prior_stated = self.prior_dh[1].copy()
        self.dh_info_stated = np.linalg.inv(self.dh_prior_stated) if self.m_dh else np.zeros((0, 0))  # its inverse
        self.dh_scale = 1.0
        self.dh_scale_test: dict[str, Any] = {}
        self.dh_scale_dof: Optional[float] = None  # redundancy of the estimated scale (handeye.refine.noise._dh_scale)
        self.sigma_q = self.kin.encoder_sigma_rad if self.kin is not None else 0.0
        self.robot_prior_k = float(refine_preset()["robust"]["robot_prior_k"])
        self.T_x = T_x0.copy()
        self.T_board = T_board0.copy()
        self.P = self.reported.copy()  # current estimate of the true robot poses
        self.sigma_px = 1.0
        self.sigma_rot = np.radians(options.robot_sigma_deg)
        self.sigma_trans = options.robot_sigma_mm / 1000.0
        self.resolved = {g: True for g in self.robot_groups}
        self.noise_dof: dict[str, Any] = {}  # degrees of freedom of each estimated robot sigma (handeye.refine.noise)
        # X's covariance and the part of it each estimated one carries (the same), when estimated
        self.noise_parts_x: Optional[tuple[np.ndarray, dict[str, np.ndarray]]] = None
        self.status = ["used"] * self.n
        self.mask = [np.ones(len(o), bool) for o in self.obj]
        self.iterations = 0
        # per view: its corners' residual variance in its own fit [px^2] (checks.view_variance_factor);
        # filled by checks.camera_only_poses, which does not depend on the robot pose
        self.own_fit_var: dict[int, float] = {}

    # -- views
    def active(self) -> list[int]:
        return [i for i in range(self.n) if self.status[i] != "removed"]

    def has_robot_var(self, i: int) -> bool:
        return self.robot_var or self.status[i] == "robot_excluded"

    def prior_views(self) -> list[int]:
        return [i for i in self.active() if self.robot_var and self.status[i] == "used"]

    def robot_pose(self, i: int) -> np.ndarray:
        return self.P[i] if self.has_robot_var(i) else self.reported[i]

    def robot_poses(self) -> np.ndarray:
        """(n,4,4) the robot pose each view's corners are seen through now."""
        return np.stack([self.robot_pose(i) for i in range(self.n)])

    @property
    def n_core(self) -> int:
        return N_POSES + self.free.size + self.m_dh

    @property
    def dh_slice(self) -> slice:
        """The DH offsets' place in the core."""
        return slice(N_POSES + self.free.size, self.n_core)

    @property
    def dh_scale_estimable(self) -> bool:
        """Whether the scale of the DH offsets' prior is a variance component.

        Whether the scale of the DH offsets' prior is a variance component: the arm's own error prior (not an
        earlier calibration's estimate), with the robot noise estimated.
        """
        return bool(self.m_dh) and not self.prior_dh_earlier and self.o.robot_noise == "estimate"

    def set_dh_scale(self, k: float) -> None:
        """Use the arm's DH error prior at ``k`` times its stated sigmas."""
        self.dh_scale = float(k)
        self.prior_dh = (self.prior_dh[0], self.dh_prior_stated * self.dh_scale**2)

    def dh_prior_information(self, k: Optional[float] = None) -> tuple[np.ndarray, np.ndarray]:
        """Information (m,m) and gradient (m,) of the DH offsets' prior at the current offsets.

        Information (m,m) and gradient (m,) of the DH offsets' prior at the current offsets, with the prior at
        ``k`` times the stated sigmas (None: the scale in use); the terms of the graph's prior factor on them.
        """
        k = self.dh_scale if k is None else float(k)
        W = self.dh_info_stated / k**2
        return W, W @ (self.dh - self.prior_dh[0])

    # -- robot error model (handeye.refine.robot_model)
    @property
    def robot_groups(self) -> tuple[Any, ...]:
        """Names of the robot noise's variance components.

        The iid model's rotation and translation, or the encoder noise of the kinematic ones.
        """
        return ("joint",) if self.kin is not None else ("rot", "trans")

    @property
    def robot_sigmas(self) -> np.ndarray:
        return np.array([self.sigma_q] if self.kin is not None else [self.sigma_rot, self.sigma_trans], float)

    @robot_sigmas.setter
    def robot_sigmas(self, s: Sequence[float] | np.ndarray) -> None:
        if self.kin is not None:
            self.sigma_q = float(s[0])
        else:
            self.sigma_rot, self.sigma_trans = float(s[0]), float(s[1])

    def robot_group_weights(self, idx: Sequence[int]) -> list[Any]:
        """Per group, the weights (len(idx),6,6) of a view's prior residual at unit group sigma.

        The prior's information is sum_g W_g / s_g^2.
        """
        idx = list(idx)
        if self.kin is not None:
            return [np.linalg.inv(self.kin.B[idx])]
        rot, trans = np.diag([1.0] * 3 + [0.0] * 3), np.diag([0.0] * 3 + [1.0] * 3)
        return [np.broadcast_to(rot, (len(idx), 6, 6)), np.broadcast_to(trans, (len(idx), 6, 6))]

    def robot_group_counts(self) -> tuple[Any, ...]:
        """Equations per view of each group (the redundancy of the variance-component estimation)."""
        return (6,) if self.kin is not None else (3, 3)

    def robot_cov(self, idx: Sequence[int]) -> np.ndarray:
        """(len(idx),6,6): the covariance of each view's robot prior residual at the current sigmas."""
        idx = list(idx)
        if self.kin is not None:
            return self.sigma_q**2 * self.kin.B[idx]
        return np.broadcast_to(np.diag([self.sigma_rot**2] * 3 + [self.sigma_trans**2] * 3), (len(idx), 6, 6)).copy()

    def J_dh(self, idx: Sequence[int]) -> np.ndarray:
        """(len(idx),6,m): d(true robot pose, right tangent of the reported one) / d(DH offsets)."""
        if not self.m_dh:
            return np.zeros((len(list(idx)), 6, 0))
        assert self.kin is not None, "m_dh > 0 only with a kinematic model"
        return self.kin.J_dh[list(idx)]

    def prior_residuals(self, idx: Sequence[int]) -> np.ndarray:
        """(len(idx),6): each view's robot prior residual ``Log(inv(reported) · P) - J_dh · dh``."""
        return self.robot_residuals(idx) - np.einsum("nij,j->ni", self.J_dh(idx), self.dh)

    def reprojection_blocks(self, idx: Sequence[int]) -> ReprojectionBlocks:
        """Gauss-Newton blocks of the reprojections of views ``idx``, each view's own, at the current estimate.

        Unit pixel sigma, the corners in use (``mask``); the core is T_x, T_board and the free intrinsics (the
        reprojections do not involve the DH offsets). A view without a robot-pose variable has zero robot blocks.
        """
        idx = list(idx)
        cp = N_POSES + self.free.size
        k = len(idx)
        out = ReprojectionBlocks(
            np.zeros((k, cp, cp)),
            np.zeros((k, cp, 6)),
            np.zeros((k, 6, 6)),
            np.zeros((k, cp)),
            np.zeros((k, 6)),
            np.zeros(k),
        )
        if not k:
            return out
        wanted = np.zeros(self.n, bool)
        wanted[idx] = True
        sel = np.concatenate(self.mask) & wanted[self.view_of]
        r, J_x, J_r, J_b, J_k = stacked_chain_jacobians(
            T_x=self.T_x,
            T_base_end=self.robot_poses(),
            T_board=self.T_board,
            invert_robot=self.invert,
            intrinsics_vec=self.k,
            object_points=self.obj_all[sel],
            image_points=self.img_all[sel],
            view_index=self.view_of[sel],
        )
        Jc = np.hstack([J_x, J_b, J_k[:, self.free]])  # shape (2K, cp)
        rows = np.r_[0, np.cumsum(2 * np.bincount(self.view_of[sel], minlength=self.n))]  # each view's rows
        for j, i in enumerate(idx):
            a, b = rows[i], rows[i + 1]
            Jc_i, r_i = Jc[a:b], r[a:b]
            out.Hcc[j] = Jc_i.T @ Jc_i
            out.gc[j] = Jc_i.T @ r_i
            out.rr[j] = r_i @ r_i
            if self.has_robot_var(i):
                Jr_i = J_r[a:b]
                out.Hcp[j] = Jc_i.T @ Jr_i
                out.Hpp[j] = Jr_i.T @ Jr_i
                out.gp[j] = Jr_i.T @ r_i
        return out

    def pixel_linearisation(self) -> PixelLinearisation:
        """Unit-sigma information of the reprojections alone at the current estimate (the active views)."""
        act = self.active()
        b = self.reprojection_blocks(act)
        rob = [j for j, i in enumerate(act) if self.has_robot_var(i)]  # the views with a robot-pose variable
        idx_p = [act[j] for j in rob]
        c, cp = self.n_core, N_POSES + self.free.size  # the reprojections do not involve the DH offsets
        Hcc = np.zeros((c, c))
        Hcc[:cp, :cp] = b.Hcc.sum(axis=0)
        Hcp = np.zeros((len(idx_p), c, 6))
        Hcp[:, :cp] = b.Hcp[rob]
        e = self.used_corner_residuals()
        return PixelLinearisation(
            Hcc=Hcc,
            Hcp=Hcp,
            Hpp=b.Hpp[rob],
            g=np.concatenate([b.gc.sum(axis=0), np.zeros(self.m_dh), b.gp[rob].reshape(-1)]),
            rr=float(np.sum(e * e)),
            n_obs=int(e.size),
            prior=np.array([self.robot_var and self.status[i] == "used" for i in idx_p], bool),
            xi=self.prior_residuals(idx_p),
            c=c,
            robot_views=tuple(idx_p),
            J_dh=self.J_dh(idx_p),
        )

    # -- residuals (numpy, every view at once)
    def corner_residuals(
        self,
        *,
        T_robots: Optional[np.ndarray] = None,
        T_x: Optional[np.ndarray] = None,
        T_board: Optional[np.ndarray] = None,
    ) -> np.ndarray:
        """Residuals (M,2) of every corner of every view, stacked in view order.

        Residuals (M,2) of every corner of every view, stacked in view order (split them with
        :meth:`per_view`), at the current solution or the given poses (T_robots (n,4,4)).
        """
        return stacked_chain_residual(
            T_x=self.T_x if T_x is None else T_x,
            T_base_end=self.robot_poses() if T_robots is None else T_robots,
            T_board=self.T_board if T_board is None else T_board,
            invert_robot=self.invert,
            intrinsics_vec=self.k,
            object_points=self.obj_all,
            image_points=self.img_all,
            view_index=self.view_of,
        )[0]

    def per_view(self, a: np.ndarray) -> list[np.ndarray]:
        """A stacked per-corner array (M, ...) split into the views' parts."""
        return np.split(a, self.offsets[1:-1])

    def used_corner_residuals(self) -> np.ndarray:
        """Residuals (K,2) of the corners in use (active views, corners not flagged)."""
        used = np.zeros(self.n, bool)
        used[self.active()] = True
        keep = np.concatenate(self.mask) & used[self.view_of]
        return self.corner_residuals()[keep]

    def robot_residuals(self, idx: Sequence[int]) -> np.ndarray:
        """Log(inv(reported) · P) for views idx: (len, 6), rotation first."""
        if not len(idx):
            return np.zeros((0, 6))
        idx = list(idx)
        return tangent_difference(self.reported[idx], self.P[idx])

    def apply_step(self, robot_views: Sequence[int], dx: np.ndarray) -> None:
        """Move the estimates by a step ``dx`` in the order of :meth:`pixel_linearisation`.

        Move the estimates by a step ``dx`` in the order of :meth:`pixel_linearisation` (T_x, T_board,
        free intrinsics, DH offsets, then one 6-vector per view of ``robot_views``), poses by right perturbation.
        """
        c = self.n_core
        self.T_x = self.T_x @ se3_exp(dx[0:6])
        self.T_board = self.T_board @ se3_exp(dx[6:12])
        if self.free.size:
            self.k = self.k.copy()
            self.k[self.free] += dx[N_POSES : N_POSES + self.free.size]
        if self.m_dh:
            self.dh = self.dh + dx[self.dh_slice]
        if len(robot_views):
            idx = list(robot_views)
            self.P[idx] = self.P[idx] @ se3_exp(dx[c:].reshape(-1, 6))
