"""Refinement of pose-only views, whose camera -> target poses come from an external tracker.

``T_cam_board_measured_i = inv(T_x) · M_i · T_board · Exp(-n_i)`` with the tracker's noise ``n_i``
(:mod:`handeye.factors.pose`); the robot poses are taken as reported, or with a named arm corrected by its
kinematic model (:mod:`.poseonly_robot`). The tracker's sigmas are the session's or estimated by variance
components. Stages: the best closed-form start, a Huber solve,
then the outlier loop with THE robot-pose test (:func:`.outliers.robot_pose_test`) until the set of
views is stable; the kept views' noise Gaussian or a multivariate Student-t, whichever they fit best
(:mod:`.tracker_tails`); the covariance is the final solve's, with the estimated sigmas' degrees of freedom
(:mod:`.tracker_dof`). On request the tracker's translation scale is one more unknown
(:func:`handeye.factors.pose.scaled_pose_residual`). The graph is :func:`.problem.solve_pose_graph`.

See docs/refinement.md.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Mapping, Optional, Sequence, overload

import numpy as np

from handeye.factors.pose import pose_residual, scaled_pose_residual

from ..errors import ConfigError
from ..mounting import mounting
from ..records import HandEyeEstimate
from .covariance import COV_PARAMETRISATION, hand_eye_uncertainty
from .options import RefineOptions, check_T, refine_preset
from .outliers import RobotPoseGates, RobotPoseTest, leave_one_out, robot_pose_outlier, robot_pose_test
from .poseonly_result import PoseRefineResult, PoseView
from .poseonly_robot import PoseRobotModel, describe, pose_robot_model
from .problem import solve_pose_dh_graph, solve_pose_graph, solve_scaled_pose_graph
from .refitting import Refit
from .tracker_dof import NoiseDof, noise_dof
from .tracker_tails import choose_dof, information_factor, robust_sigmas, t_weights

__all__ = ["PoseRefineResult", "PoseView", "refine_poses", "refit_poses", "stated_sigmas"]

log = logging.getLogger(__name__)

#: EM on the t weights converges linearly: it takes this many times the Gaussian's noise.max_outer solves
TAIL_ROUNDS = 4


def stated_sigmas(tracker_sigma: Sequence[float]) -> np.ndarray:
    """(3,) rotation [rad], across and along the optical axis [m] from a stated (rad, m) or (rad, m, m_along)."""
    sig = np.asarray(tracker_sigma, float).ravel()
    return np.r_[sig, sig[1]] if sig.size == 2 else sig


@dataclass
class _State:
    M: np.ndarray  # shape (n, 4, 4)
    C: np.ndarray  # shape (n, 4, 4)
    T_x: np.ndarray
    T_board: np.ndarray
    sigma: np.ndarray  # (3,) rotation [rad], translation across and along the camera's optical axis [m]
    keep: np.ndarray  # (n,) bool
    iterations: int = 0
    robot: Optional[PoseRobotModel] = None  # the arm's kinematic model (:mod:`.poseonly_robot`), or None
    dh: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (m,) its DH offsets
    log_scale: Optional[float] = None  # log of the tracker's translation scale when it is estimated
    weights: Optional[np.ndarray] = None  # (n,) the heavy-tailed tracker's EM weights (:mod:`.tracker_tails`)

    def groups(self) -> np.ndarray:
        """(3, n, 6, 6) each noise group's share ``Q_g`` of every view's residual covariance (unit variance).

        The residual's translation lies in the target's frame (right perturbation), the tracker's noise in
        the camera's: ``R^T diag(...) R`` with ``R`` the measured ``T_cam_board`` rotation.
        """
        n = len(self.C)
        Q = np.zeros((3, n, 6, 6))
        Q[0, :, :3, :3] = np.eye(3)
        R = self.C[:, :3, :3]
        Rt = np.swapaxes(R, 1, 2)
        Q[1, :, 3:, 3:] = Rt @ np.diag([1.0, 1.0, 0.0]) @ R
        Q[2, :, 3:, 3:] = Rt @ np.diag([0.0, 0.0, 1.0]) @ R
        return Q if self.weights is None else Q / self.weights[None, :, None, None]

    def covariances(self) -> np.ndarray:
        """(n, 6, 6) every view's residual covariance at the current sigmas (and the encoders' share)."""
        cov = np.einsum("g,gnij->nij", self.sigma**2, self.groups())
        if self.robot is not None:
            cov = cov + self.robot.covariances(self.T_x, self.T_board, self.C, self.dh)
        return cov

    @overload
    def residuals(
        self,
        T_x: Optional[np.ndarray] = None,
        T_board: Optional[np.ndarray] = None,
        *,
        jacobians: Literal[False] = False,
    ) -> tuple[np.ndarray, None]: ...

    @overload
    def residuals(
        self, T_x: Optional[np.ndarray] = None, T_board: Optional[np.ndarray] = None, *, jacobians: Literal[True]
    ) -> tuple[np.ndarray, np.ndarray]: ...

    def residuals(
        self, T_x: Optional[np.ndarray] = None, T_board: Optional[np.ndarray] = None, *, jacobians: bool = False
    ) -> tuple[np.ndarray, Optional[np.ndarray]]:
        """(r (n,6), J (n,6,12) or None) of every view at the current (or given) solution."""
        T_x = self.T_x if T_x is None else T_x
        T_board = self.T_board if T_board is None else T_board
        if self.robot is not None:  # J (n,6,12+m): the DH offsets' columns last
            return self.robot.residuals(T_x, T_board, self.C, self.dh, jacobians=jacobians)[:2]
        if self.log_scale is None:
            out: list[tuple[Any, ...]] = [
                pose_residual(T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=C, jacobians=jacobians)
                for M, C in zip(self.M, self.C, strict=False)
            ]
        else:  # the scale is the 13th parameter
            ls = self.log_scale
            out = [
                scaled_pose_residual(
                    T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=C, log_scale=ls, jacobians=jacobians
                )
                for M, C in zip(self.M, self.C, strict=False)
            ]
        r = np.stack([o[0] for o in out])
        J = np.stack([np.hstack(o[1:]) for o in out]) if jacobians else None
        return r, J

    def W(self) -> np.ndarray:
        """(n, 6, 6) every view's weight: the inverse of its residual covariance."""
        return np.linalg.inv(self.covariances())


def _score(st: _State, T_x: np.ndarray, T_board: np.ndarray) -> float:
    """Median over the views of the whitened residual norms at the start sigmas."""
    r, _ = st.residuals(T_x, T_board)
    return float(np.median(np.sqrt(np.einsum("ni,nij,nj->n", r, st.W(), r))))


def _information(st: _State, J: np.ndarray, prior_x: Optional[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    H = np.einsum("nki,nkl,nlj->ij", J[st.keep], st.W()[st.keep], J[st.keep])
    if prior_x is not None:
        H[:6, :6] += np.linalg.inv(prior_x[1])
    if st.robot is not None and st.robot.m:
        H[12:, 12:] += st.robot.prior_information()
    return H


def _prior_x(options: RefineOptions) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """(T_x, covariance (6,6)) of the options' Gaussian prior on ``T_x``, or None."""
    if options.prior is None:
        return None
    return check_T(options.prior.T_x, "prior T_x"), np.asarray(options.prior.cov_x, float)


def _solve(
    st: _State, *, robust_k: Optional[float], prior_x: Optional[tuple[np.ndarray, np.ndarray]], max_iterations: int
) -> None:
    k = np.flatnonzero(st.keep)
    if st.robot is not None and st.robot.m:
        st.T_x, st.T_board, st.dh, it = solve_pose_dh_graph(
            T_base_end=st.robot.T_base_end[k],
            J_dh=st.robot.km.J_dh[k],
            inverts_robot=st.robot.inverts_robot,
            T_cam_board=st.C[k],
            covariances=st.covariances()[k],
            T_x0=st.T_x,
            T_board0=st.T_board,
            dh0=st.dh,
            dh_prior=st.robot.dh_prior,
            robust_k=robust_k,
            prior_x=prior_x,
            max_iterations=max_iterations,
        )
        st.iterations += it
        return
    kw = dict(M=st.M[k], T_cam_board=st.C[k], covariances=st.covariances()[k], T_x0=st.T_x, T_board0=st.T_board)
    if st.log_scale is None:
        st.T_x, st.T_board, it = solve_pose_graph(
            **kw, robust_k=robust_k, prior_x=prior_x, max_iterations=max_iterations
        )
    else:
        st.T_x, st.T_board, st.log_scale, it = solve_scaled_pose_graph(
            **kw, log_scale0=st.log_scale, robust_k=robust_k, prior_x=prior_x, max_iterations=max_iterations
        )
    st.iterations += it


def _vce_on_linearisation(
    st: _State,
    r: np.ndarray,
    J: np.ndarray,
    prior_x: Optional[tuple[np.ndarray, np.ndarray]],
    floors: np.ndarray,
    resolved: dict[str, bool],
) -> float:
    """Variance-component estimation of the three tracker sigmas on one linearisation.

    ``r`` (n,6), ``J`` (n,6,12) at the last solve. With the residual covariance ``sum_g s_g^2 Q_g`` (rotation;
    translation across and along the optical axis, :meth:`_State.groups`), the weighted least-squares step
    gives the residuals ``e`` and ``s_g^2 <- s_g^4 e^T W Q_g W e / r_g`` with the redundancy
    ``r_g = s_g^2 tr(Q_g (W - W J Sigma J^T W))`` (Foerstner), iterated until the sigmas change by less than
    ``noise.inner_tol``. Updates ``st.sigma`` and ``resolved``; returns the relative change of the sigmas.
    """
    cfg = refine_preset()["noise"]
    share, tol = float(cfg["unresolved_redundancy_share"]), float(cfg["inner_tol"])
    rk, Jk = r[st.keep], J[st.keep]
    n_k = rk.shape[0]
    start = st.sigma.copy()
    Q = st.groups()[:, st.keep]  # shape (3, n_k, 6, 6)
    dims = (3 * n_k, 2 * n_k, n_k)  # observations per group
    for _ in range(int(cfg["max_inner"])):
        W = st.W()[st.keep]
        S = np.linalg.inv(_information(st, J, prior_x))
        dx = -S @ np.einsum("nki,nkl,nl->i", Jk, W, rk)
        e = rk + np.einsum("nki,i->nk", Jk, dx)  # residuals after the step
        We = np.einsum("nij,nj->ni", W, e)
        WJ = W @ Jk  # shape (n_k, 6, 12)
        P = W - WJ @ S @ np.swapaxes(WJ, 1, 2)  # shape (n_k, 6, 6)
        new = st.sigma.copy()
        for g, name in enumerate(("rot", "trans", "trans_along")):
            th = st.sigma[g] ** 2
            red = th * float(np.einsum("nij,nji->", Q[g], P))
            if red < share * dims[g]:
                resolved[name] = False  # the data cannot resolve this group: its sigma stays
                continue
            quad = float(np.einsum("ni,nij,nj->", We, Q[g], We))
            new[g] = max(float(np.sqrt(th**2 * quad / red)), floors[g])
        change = float(np.max(np.abs(new / st.sigma - 1.0)))
        st.sigma = new
        if change < tol:
            break
    return float(np.max(np.abs(st.sigma / start - 1.0)))


def _gaussian_vce(
    st: _State,
    *,
    estimate: bool,
    prior_x: Optional[tuple[np.ndarray, np.ndarray]],
    max_iterations: int,
    floors: np.ndarray,
    resolved: dict[str, bool],
    nu: float,
) -> None:
    """Solves alternating with variance-component estimation (and at a finite ``nu`` the views' t weights).

    Solves alternating with variance-component estimation on each linearisation (:func:`_vce_on_linearisation`)
    until a solve's sigmas are within ``noise.outer_tol`` of the estimate on its linearisation (as
    :func:`.noise.solve_with_vce` does for the pixel and robot sigmas). At a finite ``nu`` each round also
    sets the kept views' EM weights (:func:`.tracker_tails.t_weights`) at the new sigmas: the weighted
    estimate of the sigmas is the EM step of the multivariate t. Ends with a solve at the final sigmas.
    """
    cfg = refine_preset()["noise"]
    rounds = int(cfg["max_outer"]) * (1 if np.isinf(nu) else TAIL_ROUNDS) if estimate else 0
    for _ in range(rounds):  # a stated sigma: one solve below
        _solve(st, robust_k=None, prior_x=prior_x, max_iterations=max_iterations)
        r, J = st.residuals(jacobians=True)
        change = _vce_on_linearisation(st, r, J, prior_x, floors, resolved)
        if np.isfinite(nu):
            old = st.weights
            st.weights = t_weights(_mahalanobis2(st, r), nu)
            change = max(change, float(np.max(np.abs(st.weights / old - 1.0)[st.keep])) if old is not None else 1.0)
        if change < float(cfg["outer_tol"]):
            break
    else:
        if estimate:
            log.warning("the tracker's noise estimate did not settle in %d solves (nu %s)", rounds, nu)
    _solve(st, robust_k=None, prior_x=prior_x, max_iterations=max_iterations)  # at the final sigmas


def _mahalanobis2(st: _State, r: np.ndarray) -> np.ndarray:
    """(n,) every view's squared Mahalanobis residual at the tracker's sigmas (no EM weight)."""
    cov = replace(st, weights=None).covariances()
    return np.einsum("ni,nij,nj->n", r, np.linalg.inv(cov), r)


def _solve_with_vce(
    st: _State,
    *,
    estimate: bool,
    prior_x: Optional[tuple[np.ndarray, np.ndarray]],
    max_iterations: int,
    floors: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, bool], float]:
    """The Gaussian or the heavy-tailed tracker model, whichever the kept views fit, solved.

    :func:`_gaussian_vce` first; with the sigmas estimated, the tail degrees of freedom are chosen on its
    residuals (:func:`.tracker_tails.choose_dof`: the profile likelihood over
    :data:`.tracker_tails.DOF_GRID`, a t only where the Gaussian's likelihood-ratio test rejects it), and
    for a t the EM solve (:func:`_gaussian_vce` with the t weights) follows from there. A stated sigma:
    Gaussian, one solve. Returns (Sigma (12,12) the inverse of the weighted normal matrix, r, J, resolved,
    nu) at the final solution.
    """
    resolved = {"rot": True, "trans": True, "trans_along": True}
    kw: dict[str, Any] = dict(prior_x=prior_x, max_iterations=max_iterations, floors=floors, resolved=resolved)
    st.weights = None
    _gaussian_vce(st, estimate=estimate, nu=float("inf"), **kw)
    nu = float("inf")
    if estimate:
        r, _ = st.residuals()
        k = st.keep
        nu, w = choose_dof(_mahalanobis2(st, r)[k], np.linalg.slogdet(st.covariances()[k])[1])
        if np.isfinite(nu):
            st.weights = np.ones(len(k))
            st.weights[k] = w
            _gaussian_vce(st, estimate=True, nu=nu, **kw)
    r, J = st.residuals(jacobians=True)
    return np.linalg.inv(_information(st, J, prior_x)), r, J, resolved if estimate else {}, nu


def _tests(st: _State, S: np.ndarray, r: np.ndarray, J: np.ndarray, gates: RobotPoseGates) -> RobotPoseTest:
    """THE robot-pose test of every view on ``T_cam_board``: leave-one-out for views in the solve.

    The leave-one-out prediction undoes each view's share of the solve (its EM-weighted covariance); the
    test is against the tracker's noise (``gates.tail_dof``: the t of :mod:`.tracker_tails`, whose variance
    is its scale's ``nu / (nu - 2)``; infinite: Gaussian), as for an arm whose error is heavy-tailed.
    """
    nu = gates.tail_dof
    R_solve = st.covariances()
    R = replace(st, weights=None).covariances() * (nu / (nu - 2.0) if np.isfinite(nu) else 1.0)
    d = np.full((len(r), 6), np.nan)
    C = np.full((len(r), 6, 6), np.nan)
    if len(r) <= 3:  # without a view, two are left: one motion, which leaves X free; no view is tested (NaN)
        return robot_pose_test(d, C, robot_covariance=R, gates=gates)
    for i in range(len(r)):
        S_p = J[i] @ S @ J[i].T  # covariance of the predicted pose
        if st.keep[i]:
            try:
                d[i], C[i] = leave_one_out(r[i], R_solve[i], S_p)
            except np.linalg.LinAlgError:  # the view alone fixes the solution: no prediction without it
                log.debug("view %d: no leave-one-out prediction (the view alone fixes the solution); not tested", i)
                continue
        else:
            d[i], C[i] = r[i], S_p
    return robot_pose_test(d, C, robot_covariance=R, gates=gates)


def refine_poses(
    *,
    mode: str,
    views: Sequence[PoseView],
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    tracker_sigma: Optional[tuple[Any, ...]] = None,
    options: Optional[RefineOptions] = None,
    starts: Optional[Mapping[str, HandEyeEstimate]] = None,
    log_scale0: Optional[float] = None,
) -> PoseRefineResult:
    """Refine ``T_x`` and ``T_board`` from pose-only views; see the module docstring.

    ``tracker_sigma``: (rotation [rad], translation [m]) of the tracker, or (rotation, across, along the
    optical axis), held; None: estimated (the three sigmas).
    ``starts``: the closed forms (method -> estimate); the refinement starts from the one the views
    agree with best. A solve that fails returns ``status="failed"`` with the reason.
    ``log_scale0``: None, the tracker's translations are metric; else the tracker's translation scale is
    estimated, from ``exp(log_scale0)`` (the seeds and ``starts`` are those of the rescaled poses).
    """
    options = RefineOptions() if options is None else options
    t0 = time.perf_counter()
    mount = mounting(mode)
    T_x0 = check_T(T_x0, f"seed {mount.x_name}")
    T_board0 = check_T(T_board0, f"seed {mount.board_name}")
    ids = [v.view_id for v in views]
    M = np.stack([mount.M_from_T_base_end(check_T(v.T_base_end, f"view {v.view_id} T_base_end")) for v in views])
    C = np.stack([check_T(v.T_cam_board, f"view {v.view_id} T_cam_board") for v in views])
    cfg = refine_preset()["noise"]
    floors = np.array([float(cfg["robot_sigma_rot_floor_rad"])] + [float(cfg["robot_sigma_trans_floor_m"])] * 2)
    estimate = tracker_sigma is None
    robot = pose_robot_model(options, mode, views)  # a named arm: its kinematic model; else None
    if robot is not None and log_scale0 is not None:
        raise ConfigError(
            "the tracker's scale (--estimate-scale / estimate_scale) and the arm's kinematic model (--robot / "
            "robot:) are not estimated together",
            hint="calibrate with one of them: the scale first (fix the marker size), then --robot",
        )
    st = _State(
        M, C, T_x0.copy(), T_board0.copy(), np.ones(3), np.ones(len(views), bool), robot=robot, log_scale=log_scale0
    )
    st.dh = np.zeros(robot.m if robot is not None else 0)
    prior_x = _prior_x(options)
    if tracker_sigma is None:
        st.sigma = robust_sigmas(C, st.residuals()[0], floors)
    else:
        st.sigma = stated_sigmas(tracker_sigma)
    start_method = "given"
    if starts:
        best = _score(st, st.T_x, st.T_board)
        for name, est in starts.items():
            if est.status != "ok" or not (np.all(np.isfinite(est.T_x)) and np.all(np.isfinite(est.T_board))):
                continue
            s = _score(st, est.T_x, est.T_board)
            if s < best:
                best, start_method, st.T_x, st.T_board = s, name, est.T_x.copy(), est.T_board.copy()
    T_x_seed, T_board_seed = st.T_x.copy(), st.T_board.copy()
    gates = RobotPoseGates.from_options(options, unmodelled_arm=False)  # a tracker's error: Gaussian or t, below
    it_max = options.max_iterations
    dec_keep: Optional[np.ndarray] = None
    test: Optional[RobotPoseTest] = None
    S: Optional[np.ndarray] = None
    r: Optional[np.ndarray] = None
    J: Optional[np.ndarray] = None
    resolved: dict[str, bool] = {}
    dof = NoiseDof({})
    tail_dof = float("inf")
    try:
        if estimate:
            st.sigma = robust_sigmas(C, st.residuals()[0], floors)
        if options.loss != "none":
            _solve(st, robust_k=options.loss_k, prior_x=prior_x, max_iterations=it_max)
            if estimate:
                st.sigma = robust_sigmas(C, st.residuals()[0], floors)
        # the first decision against the robust solution, then from scratch against each clean one
        r, J = st.residuals(jacobians=True)
        if estimate:  # the tracker's tails, as the robust solution's residuals show them: the test's null
            tail_dof = choose_dof(_mahalanobis2(st, r), np.linalg.slogdet(st.covariances())[1])[0]
            gates = replace(gates, tail_dof=tail_dof)
        S = np.linalg.inv(_information(st, J, prior_x))
        # the robust solve down-weighted the outliers: each view against that solution, as if left out
        test = _tests(replace(st, keep=np.zeros(len(views), bool)), S, r, J, gates)
        seen: list[np.ndarray] = []
        for _ in range(options.max_outlier_rounds):
            keep = ~test.flagged
            if keep.sum() < 3:
                raise np.linalg.LinAlgError(f"only {int(keep.sum())} views agree with the others; need 3")
            if seen and np.array_equal(keep, seen[-1]):
                break
            oscillates = any(np.array_equal(keep, k) for k in seen)
            if oscillates:
                log.warning("outlier decisions oscillate; keeping the latest set")
            seen.append(keep)
            st.keep = keep
            S, r, J, resolved, tail_dof = _solve_with_vce(
                st, estimate=estimate, prior_x=prior_x, max_iterations=it_max, floors=floors
            )
            gates = replace(gates, tail_dof=tail_dof)
            test = _tests(st, S, r, J, gates)
            if oscillates:
                break
        dec_keep = st.keep.copy()
        dof = noise_dof(
            st.sigma,
            st.groups()[:, st.keep],
            st.W()[st.keep],
            J[st.keep],
            S,
            resolved,
            floors=floors,
            extra=None if st.robot is None else st.robot.covariances(st.T_x, st.T_board, st.C, st.dh)[st.keep],
        )
        status, reason = "ok", ""
    except np.linalg.LinAlgError as err:
        status, reason = "failed", f"the views do not constrain the hand-eye transform ({err})"
    except RuntimeError as err:  # GTSAM raises RuntimeError (e.g. indeterminant linear system)
        status, reason = "failed", f"GTSAM: {err}"
    if status != "ok":
        log.debug("pose-only refinement failed: %s", reason)  # the result carries it, as for images
    depth = float(np.median(np.linalg.norm(C[:, :3, 3], axis=1)))  # the tracker's frame need not look along z
    wd = float(options.working_distance_m) if options.working_distance_m is not None else depth
    tails = information_factor(tail_dof)  # the t model's information is (nu + 6) / (nu + 8) of the weighted one
    S_x = None if status != "ok" or S is None else tails * dof.x_factor * S[:6, :6]
    unc = hand_eye_uncertainty(S_x, st.T_x, wd)
    per_view, outliers = {}, []
    for i, vid in enumerate(ids):
        pv = {
            "status": "used" if dec_keep is not None and dec_keep[i] else "removed",
            "n_corners": 0,
            "n_used": 0,
            "rms_px": float("nan"),
            "max_px": float("nan"),
        }
        if r is not None:
            pv["pose_residual_rot_deg"] = float(np.degrees(np.linalg.norm(r[i, :3])))
            pv["pose_residual_trans_mm"] = float(1000.0 * np.linalg.norm(r[i, 3:]))
        if test is not None and np.isfinite(test.statistic[i]):
            pv["robot_vs_camera_rot_deg"] = float(test.rot_deg[i])
            pv["robot_vs_camera_trans_mm"] = float(test.trans_mm[i])
            pv["robot_vs_camera_mahalanobis"] = float(test.distance[i])
            if test.flagged[i]:
                outliers.append(
                    robot_pose_outlier(
                        vid,
                        test,
                        i,
                        "the reported robot pose and the tracker's target pose disagree with the other views",
                        "view left out",
                    )
                )
        per_view[vid] = pv
    nan = float("nan")
    ok = status == "ok" and S is not None
    robot_mm, robot_deg = robot.equivalent_sigmas() if robot is not None else (0.0, 0.0)
    T_base_end_reported = np.stack([np.asarray(v.T_base_end, float) for v in views])  # the robot poses as reported
    return PoseRefineResult(
        status=status,
        failure_reason=reason,
        mode=mode,
        x_name=mount.x_name,
        board_name=mount.board_name,
        T_x=st.T_x.copy(),
        T_board=st.T_board.copy(),
        intrinsics=None,  # type: ignore[arg-type]  # a pose-only result has no intrinsics
        T_x_seed=T_x_seed,
        T_board_seed=T_board_seed,
        intrinsics_seed=None,  # type: ignore[arg-type]  # a pose-only result has no intrinsics
        robot_poses=dict(zip(ids, T_base_end_reported if robot is None else robot.flange_poses(st.dh), strict=True)),
        cov_x_6x6=unc.cov_x_6x6,
        cov_parametrisation=COV_PARAMETRISATION,
        sigma_rot_deg=unc.sigma_rot_deg,
        sigma_trans_mm=unc.sigma_trans_mm,
        correlation_6x6=unc.correlation_6x6,
        intrinsics_sigma={},
        working_distance_m=wd,
        predicted_error_mm=unc.predicted_error_mm,
        predicted_error_axes_mm=unc.predicted_error_axes_mm,
        sigma_px=nan,
        robot_sigma_mm=robot_mm,
        robot_sigma_deg=robot_deg,
        robot_sigma_resolved={},
        rms_px_before=nan,
        rms_px_after=nan,
        per_view=per_view,
        outliers=tuple(outliers),
        iterations=st.iterations,
        seconds=time.perf_counter() - t0,
        start_method=start_method,
        options=replace(options, robot_noise="none" if robot is None else "fixed"),
        robot_model=(
            {
                "kind": "none",
                "description": "reported robot poses taken as exact (pose-only views: the robot's "
                "noise is part of the tracker's; an arm error common to every view, a DH table that is off, "
                "enters X one to one and no view can show it: name the arm, --robot ARM, to model it, or state "
                "its accuracy, --robot-accuracy MM DEG)",
            }
            if robot is None
            else describe(robot, st.dh, S[12:, 12:] if ok and S is not None else None, estimate)
        ),
        tracker_sigma_deg=float(np.degrees(st.sigma[0])),
        tracker_sigma_mm=float(1000.0 * st.sigma[1]),
        tracker_sigma_along_mm=float(1000.0 * st.sigma[2]),
        tracker_sigma_source="estimated" if estimate else "stated",
        tracker_sigma_resolved=resolved,
        cov_board_6x6=None if status != "ok" or S is None else tails * dof.board_factor * S[6:12, 6:12],
        pose_robot=robot,
        dh_offset=None if robot is None else st.dh.copy(),
        tracker_noise_dof=dof.dof,
        cov_x_noise_dof=dof.x_dof,
        cov_x_dof_factor=dof.x_factor,
        cov_x_dof_method=dof.method,
        tracker_scale=None if st.log_scale is None else float(np.exp(st.log_scale)),
        tracker_scale_sigma=_scale_sigma(st, S, dof, tails) if status == "ok" else None,
        tracker_tail_dof=tail_dof,
        view_weights=None if st.weights is None else dict(zip(ids, st.weights.tolist(), strict=True)),
    )


def _scale_sigma(st: _State, S: Optional[np.ndarray], dof: NoiseDof, tails: float) -> Optional[float]:
    """The estimated tracker scale's sigma (with the sigmas' degrees of freedom, as X's: :mod:`.tracker_dof`)."""
    if st.log_scale is None or S is None or S.shape[0] < 13:
        return None
    return float(np.exp(st.log_scale)) * float(np.sqrt(tails * dof.scale_factor * S[12, 12]))


def refit_poses(result: PoseRefineResult, views: Sequence[PoseView], covariance: bool = True) -> Refit:
    """Solve the pose-only refinement of ``result`` again on ``views`` alone (one validation fold).

    As :func:`handeye.refine.refit` does for image views: ONE Gaussian solve from the full solution,
    with the full run's tracker sigmas, prior and outlier decisions held (views it left out are not
    used). ``covariance``: also the refit's model covariance of ``T_x`` (``cov_x``). A solve that fails
    returns ``status="failed"`` with the reason.
    """
    ids = tuple(v.view_id for v in views)
    if result.status != "ok":
        return Refit("failed", "the refinement did not succeed", None, None, None, ids)
    kept = [v for v in views if result.per_view.get(v.view_id, {}).get("status") == "used"]
    if len(kept) < 3:
        return Refit("failed", f"{len(kept)} usable views (needs 3)", None, None, None, ids)
    mount = mounting(result.mode)
    M = np.stack([mount.M_from_T_base_end(np.asarray(v.T_base_end, float)) for v in kept])
    C = np.stack([np.asarray(v.T_cam_board, float) for v in kept])
    along = result.tracker_sigma_along_mm if np.isfinite(result.tracker_sigma_along_mm) else result.tracker_sigma_mm
    sigma = np.array([np.radians(result.tracker_sigma_deg), result.tracker_sigma_mm / 1000.0, along / 1000.0])
    prior_x = _prior_x(result.options)
    log_scale = None if result.tracker_scale is None else float(np.log(result.tracker_scale))
    st = _State(M, C, result.T_x.copy(), result.T_board.copy(), sigma, np.ones(len(kept), bool), log_scale=log_scale)
    if result.view_weights is not None:  # a heavy-tailed tracker: the full run's EM weights, held
        st.weights = np.array([result.view_weights[v.view_id] for v in kept])
    if result.pose_robot is not None:  # the same arm model, its DH offsets from the full solution
        st.robot = result.pose_robot.subset([v.view_id for v in kept])
        st.dh = np.zeros(st.robot.m) if result.dh_offset is None else result.dh_offset.copy()
    try:
        _solve(st, robust_k=None, prior_x=prior_x, max_iterations=result.options.max_iterations)
        cov_x = None
        if covariance:
            _, J = st.residuals(jacobians=True)
            cov_x = np.linalg.inv(_information(st, J, prior_x))[:6, :6]
    except (np.linalg.LinAlgError, RuntimeError) as err:  # GTSAM raises RuntimeError on a singular system
        return Refit("failed", f"{type(err).__name__}: {err}", None, None, None, ids)
    return Refit("ok", "", st.T_x, st.T_board, None, tuple(v.view_id for v in kept), cov_x=cov_x)
