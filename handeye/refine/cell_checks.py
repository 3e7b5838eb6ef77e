"""The cell's checks of its views (pure numpy): a robot pose every camera disagrees with, one camera's view.

:func:`view_tests` tests each view's robot prior residual (chi-square, 6 dof, against its covariance with the
estimate's share taken out, or added for an excluded view) and each camera view's corner residuals;
:func:`lone_camera` tells one camera's bad image from a bad robot pose by fitting the view's pose to the other
cameras and the prior. Used by :func:`handeye.refine.cell.refine_cell`.
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np
from scipy.stats import chi2

from handeye.factors.reprojection import chain_residual

from ..frames import se3_exp, tangent_difference

# ``st`` below is a :class:`handeye.refine.cell.CellState` (not imported: that module imports this one)
CellState = Any


def _robot_test(st: CellState, S: np.ndarray, core: int, u: int) -> tuple[float, float, dict[str, float]]:
    """(statistic, p-value, sizes) of view u's robot prior residual against its covariance.

    With the prior in the fit the residual's covariance is the prior's less the estimate's; without it (an
    excluded view) the prior's plus the estimate's.
    """
    robot = st.robot_views()
    r = st.prior_residual(u)
    at = core + 6 * robot.index(u)
    idx = np.r_[at : at + 6]  # the rows of S the residual involves: the pose, and the DH offsets
    J = np.eye(6)
    if st.m_dh and st.kin is not None:
        idx = np.r_[idx, core - st.m_dh : core]
        J = np.hstack([J, -st.kin.J_dh[u]])
    sign = 1.0 if st.ids[u] in st.excluded else -1.0
    C = st.prior_cov(u) + sign * J @ S[np.ix_(idx, idx)] @ J.T
    if np.min(np.linalg.eigvalsh(C)) <= 0:
        C = st.prior_cov(u)
    stat = float(r @ np.linalg.solve(C, r))
    d = tangent_difference(st.reported[u], st.P[u])
    sizes = {"rot_deg": float(np.degrees(np.linalg.norm(d[:3]))), "trans_mm": float(1e3 * np.linalg.norm(d[3:]))}
    return stat, float(chi2.sf(stat, 6)), sizes


def view_tests(
    st: CellState, S: np.ndarray, core: int
) -> tuple[Optional[tuple[int, float, dict[str, float]]], list[tuple[int, int, dict[str, float]]], list[int]]:
    """The worst robot pose the cameras disagree with, the camera views with too large residuals, and more.

    (worst robot pose (view index, statistic, numbers) or None, [(camera, observation, numbers)] of the
    camera views whose residuals are too large, view indices of excluded robot poses the cameras agree with).
    """
    o = st.o
    prior = st.prior_views()
    worst = None
    again = []
    if st.robot_groups:
        level = o.view_outlier_p / max(len(st.robot_views()), 1)
        for u in st.robot_views():
            stat, p, sizes = _robot_test(st, S, core, u)
            if st.ids[u] in st.excluded:
                if p >= level:
                    again.append(u)
                continue
            big = sizes["rot_deg"] >= o.min_robot_disagreement_deg or sizes["trans_mm"] >= o.min_robot_disagreement_mm
            if u in prior and p < level and big and (worst is None or stat > worst[1]):
                worst = (u, stat, {"p_value": p, "mahalanobis": float(np.sqrt(stat)), **sizes})
    bad = []
    n_obs = sum(len(cam.obs) for cam in st.cams)
    for c, cam in enumerate(st.cams):
        for j, (_u, _o, _i, m) in enumerate(cam.obs):
            if not m.any():
                continue
            e = st.view_residuals(c, j)[m]
            stat = float(np.sum(e**2) / st.sigma_px[c] ** 2)
            p = float(chi2.sf(stat, 2 * e.size))
            rms = float(np.sqrt(np.mean(e**2)))
            if p < o.view_outlier_p / n_obs and rms >= o.min_corner_outlier_px:
                bad.append((c, j, {"p_value": p, "rms_px": rms, "sigma_px": float(st.sigma_px[c])}))
    return worst, bad, again


def _observations(st: CellState, u: int) -> list[tuple[int, int]]:
    """(camera, observation) of every camera that sees view u with corners in use."""
    return [(c, j) for c, cam in enumerate(st.cams) for j, o in enumerate(cam.obs) if o[0] == u and o[3].any()]


def _view_stat(st: CellState, c: int, j: int, T_robot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(whitened residual (2n,), its Jacobian in the robot pose (2n,6), corner norms [px]) of one camera view."""
    cam = st.cams[c]
    _u, obj, img, m = cam.obs[j]
    r, _jx, J_r, _jb, _jk = chain_residual(
        T_x=cam.T_x,
        T_base_end=T_robot,
        T_board=st.T_boards[cam.board],
        invert_robot=cam.mount.inverts_robot,
        intrinsics_vec=cam.k,
        object_points=obj[m],
        image_points=img[m],
        jacobians=True,
    )
    assert J_r is not None, "Jacobians asked for"
    return r / st.sigma_px[c], J_r / st.sigma_px[c], np.linalg.norm(r.reshape(-1, 2), axis=1)


def _fit_pose(st: CellState, u: int, obs: list[tuple[int, int]], *, prior: bool) -> np.ndarray:
    """View u's robot pose fitted to the camera views ``obs`` (and its prior), everything else held."""
    T = st.P[u].copy()
    W = np.linalg.inv(st.prior_cov(u)) if prior else None
    for _ in range(8):
        H, g = np.zeros((6, 6)), np.zeros(6)
        for c, j in obs:
            r, J, _e = _view_stat(st, c, j, T)
            H += J.T @ J
            g += J.T @ r
        if W is not None:
            r0 = tangent_difference(st.reported[u], T)
            if st.m_dh and st.kin is not None:
                r0 = r0 - st.kin.J_dh[u] @ st.dh
            H += W
            g += W @ r0
        step = -np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(6), g)
        T = T @ se3_exp(step)
        if np.linalg.norm(step) < 1e-10:
            break
    return T


def lone_camera(st: CellState, u: int) -> list[tuple[int, int, dict[str, float]]]:
    """The one camera view of view u that disagrees with the pose the other cameras and the prior agree on.

    [] when no single camera explains it (a robot pose, or views seen by one camera only).
    """
    obs = _observations(st, u)
    if len(obs) < 2:
        return []
    level = st.o.view_outlier_p / max(sum(len(cam.obs) for cam in st.cams), 1)
    found = []
    for k, (c, j) in enumerate(obs):
        others = obs[:k] + obs[k + 1 :]
        T = _fit_pose(st, u, others, prior=st.kind != "none" and st.ids[u] not in st.excluded)
        ok_others = all(
            chi2.sf(float(np.sum(_view_stat(st, c2, j2, T)[0] ** 2)), _view_stat(st, c2, j2, T)[0].size) >= level
            for c2, j2 in others
        )
        r, _J, e = _view_stat(st, c, j, T)
        p = float(chi2.sf(float(np.sum(r**2)), r.size))
        if ok_others and p < level:
            found.append(
                (c, j, {"p_value": p, "rms_px": float(np.sqrt(np.mean(e**2))), "sigma_px": float(st.sigma_px[c])})
            )
    return found if len(found) == 1 else []


def view_pose_test(st: CellState, alpha: float) -> dict[str, Any]:
    """Do the cameras' views of one robot pose disagree beyond their pixel noise?

    For each view that two or more cameras see (corners in use), with every X, board and intrinsics held: the
    whitened corner residuals of one pose fitted to all its cameras (no robot prior) against those of each
    camera's own pose. The reduction ``D`` has ``d1 = 6 (m - 1)`` degrees of freedom per view of ``m`` cameras,
    the own fits' residual ``R`` leaves ``d2 = 2 n - 6 m``; ``F = (D / d1) / (R / d2)`` is tested at ``alpha``
    (the pixel sigmas cancel). Also the start of the per-camera pose sigmas: the RMS rotation and translation
    of the own poses about the shared one, per axis. {} when no view is shared.
    """
    from scipy.stats import f as f_dist

    D = R = 0.0
    d1 = d2 = 0
    dev: list[np.ndarray] = []
    for u in st.robot_views():
        obs = _observations(st, u)
        if len(obs) < 2:
            continue
        T = _fit_pose(st, u, obs, prior=False)
        shared = sum(float(np.sum(_view_stat(st, c, j, T)[0] ** 2)) for c, j in obs)
        own = 0.0
        for c, j in obs:
            T_c = _fit_pose(st, u, [(c, j)], prior=False)
            r = _view_stat(st, c, j, T_c)[0]
            own += float(np.sum(r**2))
            d2 += r.size - 6
            dev.append(tangent_difference(T, T_c))
        D += max(shared - own, 0.0)
        R += own
        d1 += 6 * (len(obs) - 1)
    if not d1 or d2 <= 0 or R <= 0:
        return {}
    F = (D / d1) / (R / d2)
    p = float(f_dist.sf(F, d1, d2))
    xi = np.array(dev)
    return {
        "statistic": float(F),
        "dof": [d1, d2],
        "p_value": p,
        "alpha": float(alpha),
        "contradicted": bool(p < alpha),
        "start_rot_rad": float(np.sqrt(np.mean(xi[:, :3] ** 2))),
        "start_trans_m": float(np.sqrt(np.mean(xi[:, 3:] ** 2))),
    }
