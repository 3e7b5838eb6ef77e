"""Each view against the current solution: the pose its corners alone imply, and how noisy they are.

:func:`camera_only_poses` fits each view's robot pose to its corners alone (``T_x``, ``T_board`` and
the intrinsics held); :func:`joint_checks` reads the same record off the last Gaussian solve. The
outlier decisions (:mod:`.outliers`) and the noise estimation (:mod:`.noise`) use the
:class:`ViewCheck` records (pure numpy, no GTSAM).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from handeye.factors.reprojection import corner_robust_scales, stacked_chain_residual

from ..frames import se3_exp, tangent_difference

if TYPE_CHECKING:
    from .problem import Problem


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
        Jw_T = np.swapaxes(J0 * w2[:, None, None], 1, 2)  # shape (M, 6, 2)
        H = np.add.reduceat(Jw_T @ J0, starts, axis=0)
        g = np.add.reduceat((Jw_T @ r0[:, :, None])[:, :, 0], starts, axis=0)
        H[~alive] = np.eye(6)
        step = np.zeros((idx.size, 6))
        live = np.flatnonzero(alive)
        try:  # all views' 6x6 solves at once
            step[live] = -np.linalg.solve(H[live], g[live][:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # one by one: a singular one fails that view alone
            for k in live:
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
    H = np.add.reduceat(np.swapaxes(Jin, 1, 2) @ Jin, starts, axis=0)
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
