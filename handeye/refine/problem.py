"""The refinement problem in GTSAM: the ONLY module of handeye that builds factor graphs and Values.

Variables: ``T_x``, ``T_board``, the free intrinsics and, per view, the true robot pose. Factors: one
reprojection ``CustomFactor`` per view (:mod:`handeye.factors.gtsam_factors`), a prior per robot pose
and optional priors from an earlier calibration (``options.prior``). The solver is Levenberg-Marquardt
with diagonal (Marquardt) damping, which stays scale-free whatever the units and noise levels. The
state it solves for, and its numpy evaluations, are :class:`.state.ProblemState`.

See docs/refinement.md.
"""

from __future__ import annotations

import functools
from typing import Any, Optional, Sequence

import gtsam
import numpy as np

from handeye.factors.gtsam_factors import (
    gaussian_prior,
    intrinsics_prior,
    joint_gaussian_prior,
    kinematic_robot_prior,
    robot_pose_prior,
    view_reprojection_factor,
)

from ..frames import tangent_difference, tangent_jacobian
from .covariance import N_POSES, arrow_blocks, arrow_from_jacobians, arrow_solve, robot_residual_covariances
from .options import refine_preset
from .state import ProblemState

KEY_X = gtsam.symbol("x", 0)
KEY_BOARD = gtsam.symbol("b", 0)
KEY_INTRINSICS = gtsam.symbol("k", 0)
KEY_DH = gtsam.symbol("d", 0)
KEY_SCALE = gtsam.symbol("s", 0)  # log of a tracker's translation scale (pose-only views)


def lm_params(max_iterations: int) -> "gtsam.LevenbergMarquardtParams":
    """The solver settings of every solve.

    At most ``max_iterations``, the preset's relative tolerance, and scale-free diagonal damping
    (see the module docstring).
    """
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    params.setRelativeErrorTol(float(refine_preset()["solver"]["relative_error_tol"]))
    params.setAbsoluteErrorTol(0.0)
    params.setErrorTol(0.0)
    params.setDiagonalDamping(True)
    return params


def key_robot(i: int) -> int:
    return gtsam.symbol("p", i)


class Problem(ProblemState):
    """The refinement problem of one refine() call: its state (:class:`.state.ProblemState`) in GTSAM.

    Builds the factor graph and Values of the current state, solves it in place and reads the
    marginal covariances and the unit-sigma linearisation off it.
    """

    # -- graph
    def build(
        self, *, robust: bool, pixel_only: bool = False, reprojection: bool = True
    ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, int]]:
        """Graph and Values of the current problem.

        ``pixel_only`` keeps only the reprojection factors, with unit pixel sigma (for the
        variance-component estimation); ``reprojection=False`` leaves them out (every other factor).
        """
        g = gtsam.NonlinearFactorGraph()
        v = gtsam.Values()
        v.insert(KEY_X, gtsam.Pose3(self.T_x))
        v.insert(KEY_BOARD, gtsam.Pose3(self.T_board))
        key_k = KEY_INTRINSICS if self.free.size else None
        if key_k is not None:
            v.insert(key_k, self.k[self.free].copy())
        key_dh = KEY_DH if self.m_dh and not pixel_only else None
        if key_dh is not None:
            v.insert(key_dh, self.dh.copy())
        robot_keys: dict[int, int] = {}
        for i in self.active():
            key_r = None
            if self.has_robot_var(i):
                key_r = key_robot(i)
                v.insert(key_r, gtsam.Pose3(self.P[i]))
                robot_keys[i] = key_r
            m = self.mask[i]
            if reprojection:
                g.add(
                    view_reprojection_factor(
                        mode=self.mode,
                        key_x=KEY_X,
                        key_board=KEY_BOARD,
                        key_robot=key_r,
                        key_intrinsics=key_k,
                        object_points=self.obj[i][m],
                        image_points=self.img[i][m],
                        sigma_px=1.0 if pixel_only else self.sigma_px,
                        intrinsics_vec=self.k,
                        free_intrinsics=self.free,
                        T_base_end=self.reported[i],
                        loss=self.o.loss if robust else "none",
                        loss_k=self.o.loss_k,
                    )
                )
            if key_r is not None and self.status[i] == "used" and not pixel_only:
                robust_k = self.robot_prior_k if robust and self.o.loss != "none" else None
                if self.kin is None:
                    g.add(
                        robot_pose_prior(
                            key_robot=key_r,
                            T_base_end_reported=self.reported[i],
                            sigma_rot_rad=self.sigma_rot,
                            sigma_trans_m=self.sigma_trans,
                            robust_k=robust_k,
                        )
                    )
                else:
                    g.add(
                        kinematic_robot_prior(
                            key_robot=key_r,
                            key_dh=key_dh,
                            T_base_end_reported=self.reported[i],
                            J_dh=self.kin.J_dh[i],
                            cov=self.robot_cov([i])[0],
                            robust_k=robust_k,
                        )
                    )
        if key_dh is not None:
            g.add(gaussian_prior(key=key_dh, mean=self.prior_dh[0], cov=self.prior_dh[1]))
        if self.prior_sig is not None and not pixel_only:
            g.add(
                intrinsics_prior(
                    key_intrinsics=KEY_INTRINSICS, prior_values=self.k_given[self.free], sigmas=self.prior_sig
                )
            )
        if not pixel_only:
            # the priors of options.prior (the same terms as core_prior): X and the board, each alone or in one joint
            # Gaussian with the intrinsics when their cross-covariance is given; the intrinsics alone otherwise
            for key, prior, joint in self._pose_priors():
                if joint is not None:
                    assert self.prior_k is not None, "a joint prior comes with the intrinsics prior"
                    g.add(
                        joint_gaussian_prior(
                            key_pose=key,
                            key_vector=KEY_INTRINSICS,
                            mean_pose=prior[0],
                            mean_vector=self.prior_k[0],
                            cov=joint,
                        )
                    )
                elif prior is not None:
                    g.add(gaussian_prior(key=key, mean=prior[0], cov=prior[1]))
            if self.prior_k is not None and self.prior_cov_xk is None and self.prior_cov_bk is None:
                g.add(gaussian_prior(key=KEY_INTRINSICS, mean=self.prior_k[0], cov=self.prior_k[1]))
        return g, v, robot_keys

    def solve(self, *, robust: bool) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, int]]:
        """One Levenberg-Marquardt solve of the current problem; updates the estimates in place."""
        g, v, robot_keys = self.build(robust=robust)
        opt = gtsam.LevenbergMarquardtOptimizer(g, v, lm_params(self.o.max_iterations))
        res = opt.optimize()
        self.iterations += opt.iterations()
        self.T_x = res.atPose3(KEY_X).matrix()
        self.T_board = res.atPose3(KEY_BOARD).matrix()
        if self.free.size:
            self.k = self.k.copy()
            self.k[self.free] = res.atVector(KEY_INTRINSICS)
        if self.m_dh:
            self.dh = np.asarray(res.atVector(KEY_DH), float).copy()
        for i, key in robot_keys.items():
            self.P[i] = res.atPose3(key).matrix()
        return g, res, robot_keys

    def _pose_priors(self) -> tuple[Any, ...]:
        """The priors on T_x and on the board: key, (mean, covariance) or None, joint covariance.

        (key, (mean (4,4), covariance (6,6)) or None, joint covariance with the free intrinsics or None) of the
        priors on T_x and on the board, in the core order.
        """
        return ((KEY_X, self.prior_x, self.prior_cov_xk), (KEY_BOARD, self.prior_board, self.prior_cov_bk))

    def core_prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Information (c,c) and gradient of the priors on the core unknowns but the DH offsets.

        At the current estimate, gradient J^T W r (c,): the intrinsics prior of ``intrinsics="prior"`` and
        ``options.prior``, in the core order of :meth:`pixel_linearisation`; the same terms as the graph's prior
        factors. The DH offsets' prior, whose scale the noise estimation may change: :meth:`dh_prior_information`.
        """
        c = self.n_core
        H, g = np.zeros((c, c)), np.zeros(c)
        ks = slice(N_POSES, N_POSES + self.free.size)
        if self.prior_sig is not None:
            W = np.diag(1.0 / self.prior_sig**2)
            H[ks, ks] += W
            g[ks] += W @ (self.k[self.free] - self.k_given[self.free])
        if self.prior_k is not None and self.prior_cov_xk is None and self.prior_cov_bk is None:
            W = np.linalg.inv(self.prior_k[1])
            H[ks, ks] += W
            g[ks] += W @ (self.k[self.free] - self.prior_k[0])
        for (_key, prior, joint), at, T in zip(self._pose_priors(), (0, 6), (self.T_x, self.T_board), strict=False):
            if prior is None:
                continue
            T_p, cov = prior
            r = tangent_difference(T_p, T)
            J = tangent_jacobian(functools.partial(tangent_difference, T_p), T)
            if joint is None:
                JW = J.T @ np.linalg.inv(cov)
                H[at : at + 6, at : at + 6] += JW @ J
                g[at : at + 6] += JW @ r
            else:  # the pose and the free intrinsics as one joint Gaussian
                assert self.prior_k is not None, "a joint prior comes with the intrinsics prior"
                idx = np.r_[at : at + 6, N_POSES : N_POSES + self.free.size]
                Jj = np.zeros((idx.size, idx.size))
                Jj[:6, :6], Jj[6:, 6:] = J, np.eye(self.free.size)
                JW = Jj.T @ np.linalg.inv(joint)
                H[np.ix_(idx, idx)] += JW @ Jj
                g[idx] += JW @ np.r_[r, self.k[self.free] - self.prior_k[0]]
        return H, g

    # -- information
    def _ordering(self, robot_keys: dict[int, int]) -> gtsam.Ordering:
        ordering = gtsam.Ordering()
        keys = [KEY_X, KEY_BOARD] + ([KEY_INTRINSICS] if self.free.size else [])
        keys += [KEY_DH] if self.m_dh else []
        for k in keys + [robot_keys[i] for i in sorted(robot_keys)]:
            ordering.push_back(k)
        return ordering

    def covariances(
        self, g: gtsam.NonlinearFactorGraph, values: gtsam.Values, robot_keys: dict[int, int]
    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
        """Marginal covariances of the core block and of each robot prior residual.

        Marginal covariances (core block, {view index: 6x6 covariance of its robot prior residual})
        from the information matrix of graph ``g`` at ``values`` (arrow order: T_x, T_board, intrinsics,
        DH offsets, robot poses); see :func:`.covariance.robot_residual_covariances`.
        """
        H, _ = g.linearize(values).hessian(self._ordering(robot_keys))
        idx_p = sorted(robot_keys)
        Hcc, Hcp, Hpp = arrow_blocks(H, self.n_core, len(idx_p))
        S_cc, S_pp, _, S_cp = arrow_solve(Hcc, Hcp, Hpp, cross=True)
        S_u = robot_residual_covariances(S_cc, S_pp, S_cp, self.J_dh(idx_p), self.dh_slice)
        if self.m_dh:
            self.S_dd = S_cc[self.dh_slice, self.dh_slice].copy()
        return S_cc, dict(zip(idx_p, S_u, strict=False))

    def prior_blocks(self, robot_views: Sequence[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """Gauss-Newton blocks of every factor but the reprojections (Gaussian); robot blocks ``robot_views``."""
        # the factors depend on the views' status and the noise levels, not on the estimate: built once for them
        built = (tuple(self.status), self.sigma_rot, self.sigma_trans, self.sigma_q, self.dh_scale)
        if getattr(self, "_priors", (None,))[0] != built:
            self._priors = (built, *self.build(robust=False, reprojection=False))
        _, g, v, robot_keys = self._priors
        v.update(KEY_X, gtsam.Pose3(self.T_x))
        v.update(KEY_BOARD, gtsam.Pose3(self.T_board))
        if self.free.size:
            v.update(KEY_INTRINSICS, self.k[self.free].copy())
        if self.m_dh:
            v.update(KEY_DH, self.dh.copy())
        for i, key in robot_keys.items():
            v.update(key, gtsam.Pose3(self.P[i]))
        keys = (KEY_X, KEY_BOARD, KEY_INTRINSICS, KEY_DH)
        at = dict(zip(keys, ((0, 6), (6, 6), (N_POSES, self.free.size), (self.dh_slice.start, self.m_dh)), strict=True))
        at.update({robot_keys[i]: (-1 - j, 6) for j, i in enumerate(robot_views)})
        lin = ((*g.at(f).linearize(v).jacobian(), [at[k] for k in g.at(f).keys()]) for f in range(g.size()))
        return arrow_from_jacobians(lin, self.n_core, len(robot_views))


# ------------------------------------------------------------------------------ pose-only views
def solve_pose_graph(
    *,
    M: np.ndarray,
    T_cam_board: np.ndarray,
    covariances: np.ndarray,
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    robust_k: Optional[float] = None,
    prior_x: Optional[tuple[np.ndarray, np.ndarray]] = None,
    max_iterations: int = 100,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Levenberg-Marquardt on ``T_x`` and ``T_board`` from measured camera -> target poses.

    Pose-only views (:mod:`handeye.factors.pose`): ``M`` (n,4,4) the views' robot motions, ``T_cam_board`` (n,4,4)
    the tracker's poses, ``covariances`` (n,6,6) each view's residual covariance (rotation [rad] first);
    ``prior_x`` (T_x (4,4), covariance (6,6)) an optional Gaussian prior on ``T_x``. Returns
    (T_x, T_board, iterations).
    """
    T_x, T_board, _, it = _solve_pose_graph(
        M, T_cam_board, covariances, T_x0, T_board0, robust_k, prior_x, max_iterations, None
    )
    return T_x, T_board, it


def solve_scaled_pose_graph(
    *,
    M: np.ndarray,
    T_cam_board: np.ndarray,
    covariances: np.ndarray,
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    log_scale0: float,
    robust_k: Optional[float] = None,
    prior_x: Optional[tuple[np.ndarray, np.ndarray]] = None,
    max_iterations: int = 100,
) -> tuple[np.ndarray, np.ndarray, float, int]:
    """:func:`solve_pose_graph` with the tracker's translation scale ``s = exp(log_scale)`` as one more unknown.

    The factors are :func:`handeye.factors.pose.scaled_pose_factor`; returns (T_x, T_board, log_scale,
    iterations).
    """
    T_x, T_board, log_scale, it = _solve_pose_graph(
        M, T_cam_board, covariances, T_x0, T_board0, robust_k, prior_x, max_iterations, float(log_scale0)
    )
    assert log_scale is not None, "a scaled solve returns its scale"
    return T_x, T_board, log_scale, it


def _solve_pose_graph(
    M: np.ndarray,
    T_cam_board: np.ndarray,
    covariances: np.ndarray,
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    robust_k: Optional[float],
    prior_x: Optional[tuple[np.ndarray, np.ndarray]],
    max_iterations: int,
    log_scale0: Optional[float],
) -> tuple[np.ndarray, np.ndarray, Optional[float], int]:
    """The pose graph of :func:`solve_pose_graph`, with ``log(s)`` a variable unless ``log_scale0`` is None."""
    from handeye.factors.pose import pose_factor, scaled_pose_factor

    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    v.insert(KEY_X, gtsam.Pose3(np.asarray(T_x0, float)))
    v.insert(KEY_BOARD, gtsam.Pose3(np.asarray(T_board0, float)))
    if log_scale0 is not None:
        v.insert(KEY_SCALE, np.array([log_scale0]))
    for Mi, Ci, Si in zip(M, T_cam_board, covariances, strict=True):
        kw = dict(key_x=KEY_X, key_board=KEY_BOARD, M=Mi, T_cam_board_measured=Ci, covariance=Si, robust_k=robust_k)
        g.add(pose_factor(**kw) if log_scale0 is None else scaled_pose_factor(key_log_scale=KEY_SCALE, **kw))
    if prior_x is not None:
        g.add(gaussian_prior(key=KEY_X, mean=prior_x[0], cov=prior_x[1]))
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, lm_params(max_iterations))
    res = opt.optimize()
    log_scale = None if log_scale0 is None else float(res.atVector(KEY_SCALE)[0])
    return res.atPose3(KEY_X).matrix(), res.atPose3(KEY_BOARD).matrix(), log_scale, int(opt.iterations())


def solve_pose_dh_graph(
    *,
    T_base_end: np.ndarray,
    J_dh: np.ndarray,
    inverts_robot: bool,
    T_cam_board: np.ndarray,
    covariances: np.ndarray,
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    dh0: np.ndarray,
    dh_prior: tuple[np.ndarray, np.ndarray],
    robust_k: Optional[float] = None,
    prior_x: Optional[tuple[np.ndarray, np.ndarray]] = None,
    max_iterations: int = 100,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Levenberg-Marquardt on ``T_x``, ``T_board`` and an arm's DH offsets from measured camera -> target poses.

    As :func:`solve_pose_graph`, with each view's true flange pose ``T_base_end_i · Exp(J_dh_i · delta)``
    (``T_base_end`` (n,4,4) the reported poses, ``J_dh`` (n,6,m), :mod:`handeye.refine.robot_model`) and
    ``delta`` under its Gaussian prior ``dh_prior`` (mean (m,), covariance (m,m)); ``covariances`` (n,6,6)
    hold the tracker's and the encoders' noise. Returns (T_x, T_board, delta, iterations).
    """
    from handeye.factors.pose import pose_dh_factor

    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    v.insert(KEY_X, gtsam.Pose3(np.asarray(T_x0, float)))
    v.insert(KEY_BOARD, gtsam.Pose3(np.asarray(T_board0, float)))
    v.insert(KEY_DH, np.asarray(dh0, float).copy())
    for T_be, Jd, Ci, Si in zip(T_base_end, J_dh, T_cam_board, covariances, strict=True):
        g.add(
            pose_dh_factor(
                key_x=KEY_X,
                key_board=KEY_BOARD,
                key_dh=KEY_DH,
                T_base_end=T_be,
                J_dh=Jd,
                inverts_robot=inverts_robot,
                T_cam_board_measured=Ci,
                covariance=Si,
                robust_k=robust_k,
            )
        )
    g.add(gaussian_prior(key=KEY_DH, mean=dh_prior[0], cov=dh_prior[1]))
    if prior_x is not None:
        g.add(gaussian_prior(key=KEY_X, mean=prior_x[0], cov=prior_x[1]))
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, lm_params(max_iterations))
    res = opt.optimize()
    dh = np.asarray(res.atVector(KEY_DH), float).copy()
    return res.atPose3(KEY_X).matrix(), res.atPose3(KEY_BOARD).matrix(), dh, int(opt.iterations())


# ------------------------------------------------------------------------------ a cell of cameras
def _cell_key(kind: str, j: int) -> int:
    """Keys of the cell graph: ``x`` / ``k`` per camera, ``b`` per board, ``d`` the DH offsets, ``p`` per view."""
    return int(gtsam.symbol(kind, j))


def _own_key(c: int, u: int) -> int:
    """Key of camera c's own pose of view u (``q``; :meth:`handeye.refine.cell.CellState.own_poses`)."""
    return int(gtsam.symbol("q", c * 1_000_000 + u))


def cell_ordering(st: Any) -> tuple[list[int], list[int]]:
    """(keys in the cell's core order, sizes): each camera's X then its free intrinsics, the boards, the DH offsets.

    The robot poses of :meth:`handeye.refine.cell.CellState.robot_views` follow, 6 each (see
    :func:`cell_information`).
    """
    keys, sizes = [], []
    for c, cam in enumerate(st.cams):
        keys += [_cell_key("x", c)]
        sizes += [6]
        if cam.free.size:
            keys += [_cell_key("k", c)]
            sizes += [int(cam.free.size)]
    for b in range(len(st.T_boards)):
        keys += [_cell_key("b", b)]
        sizes += [6]
    if st.m_dh:
        keys += [_cell_key("d", 0)]
        sizes += [int(st.m_dh)]
    return keys, sizes


def build_cell_graph(
    st: Any, *, robust: bool = False, labels: Optional[list[str]] = None
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Graph and Values of a cell (:class:`handeye.refine.cell.CellState`): all cameras, one robot pose per view.

    ``labels`` (a list, filled): each factor's variance component, ``pixels:<c>`` camera c's reprojections,
    ``robot:rot`` / ``robot:trans`` (iid: one factor each) or ``robot:joint`` (kinematic) the robot priors,
    ``dh`` the DH offsets' prior, ``view:rot`` / ``view:trans`` each camera's own pose of a view (``st.own_poses()``).
    ``robust``: Huber on the robot priors and the corners (guard solve).
    """
    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    out = labels if labels is not None else []

    def add(f: gtsam.NonlinearFactor, label: str) -> None:
        g.add(f)
        out.append(label)

    for c, cam in enumerate(st.cams):
        v.insert(_cell_key("x", c), gtsam.Pose3(cam.T_x))
        if cam.free.size:
            v.insert(_cell_key("k", c), cam.k[cam.free].copy())
    for b, T in enumerate(st.T_boards):
        v.insert(_cell_key("b", b), gtsam.Pose3(T))
    if st.m_dh:
        v.insert(_cell_key("d", 0), st.dh.copy())
    for u in st.robot_views():
        v.insert(_cell_key("p", u), gtsam.Pose3(st.P[u]))
    robot_keyed = set(st.robot_views())
    own = set(st.own_poses())
    for c, u in own:
        v.insert(_own_key(c, u), gtsam.Pose3(st.camera_pose(c, u)))
    for c, cam in enumerate(st.cams):
        for u, obj, img, mask in cam.obs:
            if not mask.any():
                continue
            key_r = _own_key(c, u) if (c, u) in own else _cell_key("p", u) if u in robot_keyed else None
            add(
                view_reprojection_factor(
                    mode=cam.mode,
                    key_x=_cell_key("x", c),
                    key_board=_cell_key("b", cam.board),
                    key_robot=key_r,
                    key_intrinsics=_cell_key("k", c) if cam.free.size else None,
                    object_points=obj[mask],
                    image_points=img[mask],
                    sigma_px=float(st.sigma_px[c]),
                    intrinsics_vec=cam.k,
                    free_intrinsics=cam.free,
                    T_base_end=st.reported[u],
                    loss=st.loss if robust else "none",
                    loss_k=st.loss_k,
                ),
                f"pixels:{c}",
            )
    robust_k = st.robot_prior_k if robust else None
    big = 1e6  # the other component of an iid prior's factor: no information
    for u in st.prior_views():
        if st.kin is None:
            for label, s_rot, s_trans in (("robot:rot", st.sigma_rot, big), ("robot:trans", big, st.sigma_trans)):
                add(
                    robot_pose_prior(
                        key_robot=_cell_key("p", u),
                        T_base_end_reported=st.reported[u],
                        sigma_rot_rad=s_rot,
                        sigma_trans_m=s_trans,
                        robust_k=robust_k,
                    ),
                    label,
                )
        else:
            add(
                kinematic_robot_prior(
                    key_robot=_cell_key("p", u),
                    key_dh=_cell_key("d", 0) if st.m_dh else None,
                    T_base_end_reported=st.reported[u],
                    J_dh=st.kin.J_dh[u],
                    cov=st.sigma_q**2 * st.kin.B[u],
                    robust_k=robust_k,
                ),
                "robot:joint",
            )
    if st.m_dh:
        add(gaussian_prior(key=_cell_key("d", 0), mean=np.zeros(st.m_dh), cov=st.dh_prior_cov), "dh")
    for i, label in enumerate(("view:rot", "view:trans") if own else ()):  # camera c's own pose of view u:
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.where(np.arange(6) // 3 == i, st.view_sigma[i], big))
        for c, u in own:  # Log(inv(P_u) · Q_cu) ~ N(0, s^2)
            add(gtsam.BetweenFactorPose3(_cell_key("p", u), _own_key(c, u), gtsam.Pose3(), noise), label)
    return g, v


def solve_cell_graph(st: Any, *, robust: bool) -> int:
    """One Levenberg-Marquardt solve of the cell; the estimates of ``st`` move in place. Returns the iterations."""
    g, v = build_cell_graph(st, robust=robust)
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, lm_params(st.max_iterations))
    res = opt.optimize()
    for c, cam in enumerate(st.cams):
        cam.T_x = res.atPose3(_cell_key("x", c)).matrix()
        if cam.free.size:
            cam.k = cam.k.copy()
            cam.k[cam.free] = res.atVector(_cell_key("k", c))
    st.T_boards = [res.atPose3(_cell_key("b", b)).matrix() for b in range(len(st.T_boards))]
    if st.m_dh:
        st.dh = np.asarray(res.atVector(_cell_key("d", 0)), float).copy()
    for u in st.robot_views():
        st.P[u] = res.atPose3(_cell_key("p", u)).matrix()
    st.Q.update({(c, u): res.atPose3(_own_key(c, u)).matrix() for c, u in st.own_poses()})
    return int(opt.iterations())


def cell_information(st: Any) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, float, int]]]:
    """The cell's information matrix at the current estimate, and per variance component its part.

    (H (dense), {label: (its factors' information, their whitened squared residuals, their rows)}), from one
    linearisation. Order: :func:`cell_ordering`'s core, the poses of ``st.robot_views()``, ``st.own_poses()`` (6 each).
    """
    labels: list[str] = []
    g, v = build_cell_graph(st, labels=labels)
    keys, sizes = cell_ordering(st)
    poses = [_cell_key("p", u) for u in st.robot_views()] + [_own_key(c, u) for c, u in st.own_poses()]
    keys, sizes = keys + poses, sizes + [6] * len(poses)
    start = np.r_[0, np.cumsum(sizes)]
    at = {k: np.arange(start[i], start[i + 1]) for i, k in enumerate(keys)}
    n = int(start[-1])
    lin = g.linearize(v)
    groups: dict[str, list[int]] = {}
    for i, label in enumerate(labels):
        groups.setdefault(label, []).append(i)

    def hessian(idx: list[int]) -> tuple[np.ndarray, float, int]:
        sub = gtsam.GaussianFactorGraph()
        present: list[int] = []
        e, rows = 0.0, 0
        for i in idx:
            f = lin.at(i)
            sub.push_back(f)
            e += 2.0 * float(g.at(i).error(v))  # whitened squared residual (no robust loss here)
            rows += int(g.at(i).dim())
            present += [k for k in f.keys() if k not in present]
        ordering = gtsam.Ordering()
        present = [k for k in keys if k in set(present)]
        for k in present:
            ordering.push_back(k)
        Hp, _ = sub.hessian(ordering)
        idx_all = np.concatenate([at[k] for k in present])
        H = np.zeros((n, n))
        H[np.ix_(idx_all, idx_all)] = Hp
        return H, e, rows

    parts = {label: hessian(idx) for label, idx in groups.items()}
    H = sum((p[0] for p in parts.values()), np.zeros((n, n)))
    return H, parts
