"""Noise levels of the refinement: the pixel sigma and the robot's (or the encoder's) sigmas.

They are variance components (with a kinematic arm, the scale of its DH prior becomes one more where
the views contradict it). On clean data they are estimated by iterated variance-component estimation
(Helmert / Förstner, the REML fixed point); before the data are clean they come from robust
statistics (:func:`handeye.stats.robust_noise_sigma`). A robot sigma the camera cannot resolve is
held and reported with ``robot_sigma_resolved = False``. Pure numpy: the problem is passed in.

See docs/refinement.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from ..stats import RAYLEIGH_MEDIAN, robust_noise_sigma
from .covariance import arrow_solve, robot_prior_parts, robot_residual_covariances
from .gauss_newton import solve_gaussian
from .options import refine_preset

if TYPE_CHECKING:
    from .checks import ViewCheck
    from .problem import Problem
    from .state import PixelLinearisation

log = logging.getLogger(__name__)


def _cfg() -> dict[str, Any]:
    return refine_preset()["noise"]


def robust_sigma_px(pb: "Problem") -> float:
    """Pixel sigma from the median corner residual of the used corners (Rayleigh median)."""
    return sigma_px_from_residuals(np.linalg.norm(pb.used_corner_residuals(), axis=1))


def sigma_px_from_residuals(e: np.ndarray) -> float:
    """Pixel sigma from corner residual norms ``e`` (N,) by their median (Rayleigh median)."""
    return max(float(np.median(e)) / RAYLEIGH_MEDIAN, float(_cfg()["sigma_px_floor"]))


def robust_robot_sigmas(pb: "Problem", checks: Mapping[int, "ViewCheck"]) -> None:
    """Robot sigmas from camera-only poses.

    Robot sigmas from camera-only poses (``checks``: view index -> its check) by the robust median
    estimator (robot_noise="estimate"). Kinematic models: the encoder sigma, with each view's
    disagreement less the current DH offsets' share and their covariance added to the camera's.
    """
    idx = [i for i, c in checks.items() if c.ok]
    if pb.o.robot_noise != "estimate" or len(idx) < 3:
        return
    d = np.stack([checks[i].delta for i in idx])
    C = np.stack([checks[i].cov_cam for i in idx])
    cfg = _cfg()
    if pb.kin is not None:
        J = pb.J_dh(idx)
        d = d - np.einsum("nij,j->ni", J, pb.dh)
        C = C + np.einsum("nim,mk,njk->nij", J, pb.S_dd, J)
        pb.sigma_q = robust_noise_sigma(d, C, floor=float(cfg["robot_sigma_rot_floor_rad"]), shape=pb.kin.B[idx])
        return
    pb.sigma_rot = robust_noise_sigma(d[:, :3], C[:, :3, :3], floor=float(cfg["robot_sigma_rot_floor_rad"]))
    pb.sigma_trans = robust_noise_sigma(d[:, 3:], C[:, 3:, 3:], floor=float(cfg["robot_sigma_trans_floor_m"]))


@dataclass(frozen=True)
class VarianceComponents:
    """Outcome of :func:`vce_on_linearisation`.

    The relative change of the sigmas over the call, and, at the final sigmas, the linear
    least-squares step and the marginal covariances (core, and per robot block the covariance of its
    prior residual, :func:`.covariance.robot_residual_covariances`).
    """

    change: float
    dx: np.ndarray  # (c + 6n,) in the order of the linearisation
    S_cc: np.ndarray
    S_pp: np.ndarray  # (n, 6, 6)


def vce_on_linearisation(pb: "Problem", lin: "PixelLinearisation") -> VarianceComponents:
    """Iterate variance-component estimation on one fixed linearisation (pure numpy, cheap).

    For sigmas s the linear least-squares step dx, the group residual sums e_g^T W_g e_g and the
    redundancies r_g = n_g - tr(W_g S_u) follow from the unit-sigma pixel information, the robot
    priors (residual ``u_i = p_i - J_dh,i · delta``: Jacobian I on the pose block and -J_dh,i on the
    DH offsets, information ``sum_g W_g,i / s_g^2``, :meth:`.problem.Problem.robot_group_weights`)
    and the priors on the core (:meth:`.problem.Problem.core_prior`); then s_g^2 = e_g^T W_g e_g / r_g.
    The groups are the iid model's rotation and translation or the kinematic models' encoder noise. With the
    kinematic model's DH offsets, their prior's scale is tested once the sigmas first settle at the stated
    prior and, where the test rejects it, estimated with them from there on (one test per round of the outlier
    loop: :func:`solve_with_vce`). Updates pb's sigmas and DH prior scale in place.
    """
    cfg = _cfg()
    groups = pb.robot_groups
    floors = np.array(
        [float(cfg["sigma_px_floor"])]
        + [
            float(cfg["robot_sigma_trans_floor_m"] if g == "trans" else cfg["robot_sigma_rot_floor_rad"])
            for g in groups
        ]
    )
    share, tol = float(cfg["unresolved_redundancy_share"]), float(cfg["inner_tol"])
    c, n = lin.c, lin.Hpp.shape[0]
    D = c + 6 * n
    estimate_robot = pb.o.robot_noise == "estimate"
    pri = lin.prior
    n_pri = int(pri.sum())
    W0 = [w * pri[:, None, None] for w in pb.robot_group_weights(lin.robot_views)]  # per group (n,6,6)
    counts = pb.robot_group_counts()
    J = lin.J_dh  # shape (n, 6, m)
    dh = pb.dh_slice
    HK, gK = pb.core_prior()  # priors on the core unknowns (intrinsics, options.prior); the DH offsets' below
    m = pb.m_dh
    k_dh = k_start = pb.dh_scale
    test_dh = bool(m) and pb.dh_scale_estimable and not pb.dh_scale_test  # once per round of the outlier loop
    scale_dh = bool(m) and pb.dh_scale_estimable and bool(pb.dh_scale_test.get("contradicted"))
    s = np.r_[pb.sigma_px, pb.robot_sigmas]
    start = s.copy()
    dof: dict[str, Any] = {}  # redundancy of each robot group whose sigma is estimated (its degrees of freedom)
    history = [np.log(s)]  # log-sigma iterates since the last extrapolation
    for _ in range(int(cfg["max_inner"])):
        w_px = 1.0 / s[0] ** 2
        W = sum(w / sg**2 for w, sg in zip(W0, s[1:], strict=False))  # shape (n, 6, 6): robot prior information
        Wr = np.einsum("nij,nj->ni", W, lin.xi)
        HKi, gKi = HK, gK
        if m:  # the DH offsets' prior at its scale k_dh
            H_dd, g_d = pb.dh_prior_information(k_dh)
            HKi, gKi = HK.copy(), gK.copy()
            HKi[dh, dh] += H_dd
            gKi[dh] += g_d
        Hcc = lin.Hcc * w_px + HKi
        Hcp = lin.Hcp * w_px
        grad = lin.g * w_px
        grad[:c] += gKi
        grad[c:] += Wr.reshape(-1)
        if J.shape[-1]:
            JW = np.einsum("nim,nij->nmj", J, W)  # shape (n, m, 6)
            Hcc[dh, dh] += np.einsum("nmj,njk->mk", JW, J)
            Hcp[:, dh, :] -= JW
            grad[dh] -= np.einsum("nmj,nj->m", JW, lin.xi)
        S_cc, S_pp, dx, S_cp = arrow_solve(Hcc, Hcp, lin.Hpp * w_px + W, -grad, cross=True)
        dc, dp = dx[:c], dx[c:].reshape(n, 6)
        Hdx_c = lin.Hcc @ dc + np.einsum("nci,ni->c", lin.Hcp, dp)
        Hdx_p = np.einsum("nci,c->ni", lin.Hcp, dc) + np.einsum("nij,nj->ni", lin.Hpp, dp)
        e_px2 = lin.rr + 2.0 * dx @ lin.g + dc @ Hdx_c + np.sum(dp * Hdx_p)
        absorbed = float(np.sum(HKi * S_cc))  # tr(H_prior Sigma_core)
        new = s.copy()
        k_new = k_dh
        if scale_dh:
            k_new = _dh_scale(pb, pb.dh + dc[dh] - pb.prior_dh[0], S_cc[dh, dh], k_dh)
        if n_pri:
            e_rob = lin.xi + dp - np.einsum("nim,m->ni", J, dc[dh])  # prior residuals after the step
            S_u = robot_residual_covariances(S_cc, S_pp, S_cp, J, dh)
            for g, name in enumerate(groups):
                tr = float(np.einsum("nij,nji->", W0[g], S_u)) / s[1 + g] ** 2
                absorbed += tr
                if not estimate_robot or not pb.resolved[name]:
                    continue
                r_g = counts[g] * n_pri - tr
                if r_g < share * counts[g] * n_pri:
                    pb.resolved[name] = False  # the camera cannot resolve this robot noise: freeze
                    dof.pop(name, None)
                    continue
                dof[name] = float(r_g)
                e2 = float(np.einsum("ni,nij,nj->", e_rob, W0[g], e_rob))
                new[1 + g] = max(float(np.sqrt(max(e2, 0.0) / r_g)), floors[1 + g])
        r_px = lin.n_obs - D + absorbed
        if r_px > 0.5:
            new[0] = max(float(np.sqrt(max(e_px2, 0.0) / r_px)), floors[0])
        change = max(float(np.max(np.abs(new / s - 1.0))), abs(k_new / k_dh - 1.0))
        s, k_dh = new, k_new
        if change < tol:
            if test_dh:  # settled at the stated DH prior: test it once; rejected, go on estimating its scale
                test_dh = False
                scale_dh = _dh_prior_test(pb, pb.dh + dc[dh] - pb.prior_dh[0], S_cc[dh, dh])
                if scale_dh:
                    continue
            break
        history.append(np.log(s))
        if len(history) == 3:
            s = np.maximum(_aitken(*history), floors)
            history = [np.log(s)]
    pb.sigma_px = float(s[0])
    pb.robot_sigmas = s[1:]
    if m:
        pb.set_dh_scale(k_dh)
        if k_dh != 1.0 and pb.dh_scale_dof:  # the DH prior's scale, estimated: one more variance component
            dof["dh_scale"] = float(pb.dh_scale_dof)
    pb.noise_dof = dof
    pb.noise_parts_x = _x_parts(pb, S_cc, S_cp, J, W0, s[1:], k_dh, dof)
    S_u = robot_residual_covariances(S_cc, S_pp, S_cp, J, dh)
    if pb.m_dh:
        pb.S_dd = S_cc[dh, dh].copy()
    change = max(float(np.max(np.abs(s / start - 1.0))), abs(k_dh / k_start - 1.0))
    return VarianceComponents(change, dx, S_cc, S_u)


def _x_parts(
    pb: "Problem",
    S_cc: np.ndarray,
    S_cp: np.ndarray,
    J: np.ndarray,
    W0: list[np.ndarray],
    sigmas: np.ndarray,
    k_dh: float,
    dof: dict[str, Any],
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(X's covariance (6,6), the part of it each estimated noise level's information carries).

    The parts: :func:`.covariance.robot_prior_parts`, and the DH prior's ``Sigma_xd H_dd Sigma_dx`` for its
    scale. Only the groups in ``dof`` (estimated); with their degrees of freedom they give X's
    (:func:`handeye.refine.result.x_dof_factor`).
    """
    at = {g: j for j, g in enumerate(pb.robot_groups) if g in dof}
    parts = robot_prior_parts(S_cc, S_cp, J, pb.dh_slice, [W0[j] / sigmas[j] ** 2 for j in at.values()])
    out = dict(zip(at, parts, strict=True))
    if "dh_scale" in dof and pb.m_dh:
        H_dd, _ = pb.dh_prior_information(k_dh)
        S_xd = S_cc[:6, pb.dh_slice]
        out["dh_scale"] = S_xd @ H_dd @ S_xd.T
    return S_cc[:6, :6].copy(), out


def _dh_prior_test(pb: "Problem", delta: np.ndarray, S_dd: np.ndarray) -> bool:
    """Do the views contradict the arm's stated DH prior?

    ``delta``, ``S_dd``: the DH offsets and their posterior covariance with the noise levels settled
    at that prior (k = 1).

    With the stated prior N(0, Sigma_0) right, the estimate ``delta`` has covariance ``Sigma_0 - S_dd``, so
    ``e = delta^T Sigma_0^-1 delta`` is ``sum lambda_i z_i^2`` with ``lambda = 1 - eig(Sigma_0^-1 S_dd)``: 1 for an
    offset the views fix, 0 for one they leave to the prior; their sum ``r`` is the offsets' redundancy (about
    how many the views resolve). ``e`` is tested against that form (Satterthwaite's scaled chi-square,
    :func:`handeye.stats.weighted_chi2_sf`); the prior stands unless p < ``noise.dh_prior_alpha`` (the arm is
    further from its table than stated: an uncalibrated arm, a nominal table, wear). Fewer than
    ``noise.unresolved_redundancy_share`` of the offsets resolved: no test, the prior stands. The outcome goes
    to ``pb.dh_scale_test``; returns whether the prior was rejected.
    """
    from ..stats import weighted_chi2_sf

    cfg = _cfg()
    m = delta.size
    L = np.linalg.cholesky(pb.dh_prior_stated)
    A = np.linalg.solve(L, np.linalg.solve(L, S_dd).T)  # L^-1 S_dd L^-T: eigenvalues of Sigma_0^-1 S_dd
    lam = np.clip(1.0 - np.linalg.eigvalsh(0.5 * (A + A.T)), 0.0, 1.0)
    r = float(lam.sum())
    if r < float(cfg["unresolved_redundancy_share"]) * m:
        pb.dh_scale_test = {"resolved": False, "redundancy": r, "contradicted": False}
        return False
    z = np.linalg.solve(L, delta)
    e = float(z @ z)
    p, nu = weighted_chi2_sf(e, lam)
    alpha = float(cfg["dh_prior_alpha"])
    pb.dh_scale_test = {
        "resolved": True,
        "statistic": e,
        "redundancy": r,
        "dof": nu,
        "p_value": p,
        "alpha": alpha,
        "contradicted": p < alpha,
        "reference": "Satterthwaite's scaled chi-square of the resolved offsets",
    }
    return bool(p < alpha)


def _dh_scale(pb: "Problem", delta: np.ndarray, S_dd: np.ndarray, k: float) -> float:
    """The next scale of the arm's DH prior.

    The next scale of the arm's DH prior (sigmas k times the stated ones) once the views have contradicted it
    (:func:`_dh_prior_test`), as a variance component: ``k^2 = e / r`` with ``e = delta^T Sigma_0^-1 delta`` and
    the redundancy ``r = m - tr(Sigma_0^-1 S_dd) / k^2`` at the current scale (recorded in ``pb.dh_scale_dof``),
    never below the stated prior: the offsets the views do not resolve are known only through that prior and
    reach ``T_x``'s covariance through it, so data on the resolved ones may widen it, not narrow it. Where the
    views no longer resolve enough of the offsets (``noise.unresolved_redundancy_share``), the scale is held.
    """
    m = delta.size
    W = pb.dh_info_stated
    r = m - float(np.sum(W * S_dd)) / k**2
    if r < float(_cfg()["unresolved_redundancy_share"]) * m:
        return k
    pb.dh_scale_dof = r
    return max(float(np.sqrt(float(delta @ W @ delta) / r)), 1.0)


def _aitken(x0: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Aitken's extrapolation of three successive log-sigma iterates, per component.

    Aitken's extrapolation of three successive log-sigma iterates, per component, where they converge
    linearly and monotonically (ratio of successive steps in (0, 0.95)); returns sigmas.

    The fixed-point iteration converges linearly, slowly (ratio ~0.93) when a robot sigma heads for
    a level the camera barely resolves: 80 iterations on a clean 200-view session. Extrapolating
    every third iterate lands near the fixed point; the plain iterations that follow it decide
    convergence, so the fixed point and the tolerance are those of the plain iteration.
    """
    d1, d2 = x1 - x0, x2 - x1
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(d1 != 0.0, d2 / d1, 0.0)
    ok = (rho > 0.0) & (rho < 0.95)
    x = x2.copy()
    x[ok] += d2[ok] * rho[ok] / (1.0 - rho[ok])
    return np.exp(x)


def solve_with_vce(pb: "Problem") -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """Gaussian solves alternating with variance-component estimation until the sigmas settle.

    Gaussian solves alternating with variance-component estimation on each linearisation until
    the sigmas settle. Returns (Sigma_core, {view index: Sigma_robot}) at the final sigmas.

    Once a solve's sigmas are within ``noise.outer_tol`` of the estimate on its linearisation, that
    solve is at the optimum of a problem whose weights differ by less than that: the Gauss-Newton
    step at the final sigmas (computed by the estimation anyway) finishes it, and the estimation's
    covariances are those of the final linearisation, so no further solve is needed.
    """
    cfg = _cfg()
    pb.resolved = {g: True for g in pb.robot_groups}  # a new set of views may resolve what the last did not
    if pb.dh_scale_estimable:  # and may agree with the arm's stated DH prior where the last did not
        pb.set_dh_scale(1.0)
        pb.dh_scale_test, pb.dh_scale_dof = {}, None
    for _ in range(int(cfg["max_outer"])):
        solve_gaussian(pb)  # from the last solution: Gauss-Newton, Levenberg-Marquardt when it does not settle
        lin = pb.pixel_linearisation()
        vce = vce_on_linearisation(pb, lin)
        log.debug(
            "VCE: sigma_px %.4f, robot %.5f deg %.5f mm (change %.3g)",
            pb.sigma_px,
            np.degrees(pb.sigma_rot),
            1000 * pb.sigma_trans,
            vce.change,
        )
        if vce.change < float(cfg["outer_tol"]):
            pb.apply_step(lin.robot_views, vce.dx)
            return vce.S_cc, dict(zip(lin.robot_views, vce.S_pp, strict=False))
    g, values, rk = pb.solve(robust=False)  # not settled: a last solve at the last sigmas
    return pb.covariances(g, values, rk)
