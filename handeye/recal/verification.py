"""Test an installed calibration on new views, and say what moved.

:func:`verify_views` refines the new views with X free, the installed intrinsics (and a kinematic
install's DH offsets) as priors and the board a nuisance, tests ``X = X0``
(:func:`handeye.recal.joint.test_refined`) and compares the board, the robot poses and the intrinsics
with the install's: a :class:`Verification`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np

from ..camera import Intrinsics
from ..config import load_preset
from ..errors import CalibrationError, InputError
from ..frames import inv_T, mean_T, pose_error, rotvec_from_R, se3_exp, tangent_difference
from ..mounting import mounting
from ..output import plain
from .drift import DriftTest, change_in_result_frame
from .joint import installed_robot_model, test_refined, with_installed_dh
from .loaded import VAGUE_COV_X, LoadedResult, installed_prior, require_matrix


def _from_preset(section: str, key: str):
    return field(default_factory=lambda: float(load_preset("recal")[section][key]))


@dataclass(frozen=True)
class VerifyOptions:
    """Settings of a verification (defaults: configs/recal.yaml, where each is explained)."""

    alpha: float = _from_preset("test", "alpha")
    min_variance_share: float = _from_preset("test", "min_variance_share")
    board_sigmas: float = _from_preset("board", "sigmas")
    board_min_mm: float = _from_preset("board", "min_mm")
    board_min_deg: float = _from_preset("board", "min_deg")

    @staticmethod
    def from_config(cfg: Optional[dict] = None, **overrides) -> "VerifyOptions":
        """From a ``recal`` preset (default: the shipped one), with the overrides that are not None."""
        cfg = load_preset("recal") if cfg is None else cfg
        kw = dict(
            alpha=float(cfg["test"]["alpha"]),
            min_variance_share=float(cfg["test"]["min_variance_share"]),
            board_sigmas=float(cfg["board"]["sigmas"]),
            board_min_mm=float(cfg["board"]["min_mm"]),
            board_min_deg=float(cfg["board"]["min_deg"]),
        )
        kw.update({k: v for k, v in overrides.items() if v is not None})
        return VerifyOptions(**kw)


# ------------------------------------------------------------------------------ the verification
@dataclass(frozen=True)
class Verification:
    """The outcome of :func:`verify_views` (``to_dict`` is verify.json's body)."""

    verdict: str  # "still valid" | "drifted"
    headline: str
    mode: str
    frame: str
    test: DriftTest
    alpha: float
    change: dict  # change_in_result_frame of test.change_xi
    T_x_installed: np.ndarray
    T_x_posterior: np.ndarray
    cov_x_posterior: np.ndarray
    board: dict  # installed vs new board pose, moved: bool
    robot: dict  # views whose robot pose disagrees with the camera
    intrinsics: dict  # source (installed | session) and the update per name
    what_moved: tuple  # lines for people
    views: dict  # view_id -> {status, rms_px, ...}
    n_views: int
    sigma_px: float
    cov_source: str
    seconds: float
    refined: object = field(default=None, repr=False)

    @property
    def drifted(self) -> bool:
        return self.verdict == "drifted"

    def to_dict(self) -> dict:
        t = self.test
        return plain(
            {
                "verdict": self.verdict,
                "headline": self.headline,
                "drifted": self.drifted,
                "mode": self.mode,
                "frame": self.frame,
                "test": {
                    "kind": t.kind,
                    "statistic": t.statistic,
                    "dof": t.dof,
                    "p_value": t.p_value,
                    "alpha": self.alpha,
                    "reference": t.reference,
                    "robot_noise_dof": t.noise_dof,
                    "variance_share": t.variance_share,
                    "covariance_used": self.cov_source,
                },
                "change": dict(
                    self.change,
                    xi_rad_m=t.change_xi,
                    cov_6x6=t.change_cov,
                    definition=(
                        "X_new - X_installed in X_installed's right tangent, as the test estimates "
                        "it (see test.kind); sigma: its 1-sigma, the installed and the new views' "
                        "uncertainty; translation along the parent frame's axes, rotation about "
                        "the camera axes"
                    ),
                ),
                "installed": {self.frame: self.T_x_installed},
                "posterior": {self.frame: self.T_x_posterior, "cov_x_6x6": self.cov_x_posterior},
                "board": self.board,
                "robot": self.robot,
                "intrinsics": self.intrinsics,
                "what_moved": list(self.what_moved),
                "views": self.views,
                "n_views": self.n_views,
                "sigma_px": self.sigma_px,
                "seconds": self.seconds,
            },
            nan_to_none=True,
        )


def nearest_board_turn(
    T_board_installed: Optional[np.ndarray], T_board_new: np.ndarray, turns: Sequence[np.ndarray]
) -> np.ndarray:
    """The board turn ``H`` that brings the installed board frame nearest the new one.

    Of the identity and ``turns`` (board-frame motions of a symmetric board's other numberings), the ``H``
    that brings the installed board frame nearest the new one (``T_board_installed H`` against
    ``T_board_new``, by rotation, then translation): a later session may number such a board from another
    corner. Identity when there is no installed board or no turn.
    """
    H = [np.eye(4)] + [np.asarray(F, float) for F in turns]
    if T_board_installed is None or len(H) == 1:
        return H[0]
    d = [pose_error(T_board_installed @ h, T_board_new) for h in H]
    return H[min(range(len(H)), key=lambda i: (round(d[i][0], 1), d[i][1]))]


def board_from_views(mode: str, T_x: np.ndarray, T_base_end: np.ndarray, T_cam_board: np.ndarray) -> np.ndarray:
    """Per view (n,4,4) the board transform that ``T_x`` and the view imply: ``B_i = M_i^-1 X C_i``."""
    m = mounting(mode)
    return inv_T(m.M_from_T_base_end(T_base_end)) @ T_x @ T_cam_board


def odd_view(B_views: np.ndarray, *, sigma_mm: np.ndarray) -> Optional[tuple[int, float, float]]:
    """(index, mm, mm) of the view whose implied board lies farthest apart from the others', or None.

    The reference is the view whose board has the smallest median distance to the others' (robust to several
    far-off views); the others agree with it within the median of their distances to it. The farthest view is
    named when it lies more than 5 times both that agreement and its ``sigma_mm`` (n,) (the spread the robot
    noise alone gives each view's board, :func:`robot_board_sigma_mm`); with at least 3 others.
    """
    n = len(B_views)
    if n < 4:
        return None
    D = np.array([[pose_error(a, b)[1] for b in B_views] for a in B_views])  # mm, symmetric
    ref = int(np.argmin([np.median(np.delete(D[k], k)) for k in range(n)]))
    far = int(np.argmax(D[ref]))
    agree = float(np.median(np.delete(D[ref], [ref, far])))
    return (far, float(D[ref, far]), agree) if D[ref, far] > 5.0 * max(agree, float(sigma_mm[far])) else None


def robot_board_sigma_mm(
    mode: str, T_x: np.ndarray, T_cam_board: np.ndarray, B_views: np.ndarray, sigma_mm: float, sigma_deg: float
) -> np.ndarray:
    """(n,) mm: the 3-D spread robot pose noise gives each view's implied board.

    Robot pose noise of ``sigma_mm`` / ``sigma_deg`` per axis (in the flange frame): the translation's, and the
    rotation's about the flange times the board's distance from it.
    """
    in_flange = (T_x @ T_cam_board)[:, :3, 3] if mode == "eye_in_hand" else B_views[:, :3, 3]
    lever_mm = 1000.0 * np.linalg.norm(in_flange, axis=1)
    return np.sqrt(3.0 * sigma_mm**2 + 2.0 * (np.radians(sigma_deg) * lever_mm) ** 2)


def verify_views(
    installed: LoadedResult,
    *,
    views: Sequence,
    object_points: np.ndarray,
    intrinsics: Optional[Intrinsics] = None,
    options: VerifyOptions = VerifyOptions(),
    board_turns: Sequence[np.ndarray] = (),
) -> Verification:
    """Test the installed calibration on ``views``.

    Test the installed calibration on ``views`` (:class:`handeye.refine.RefineView`, corners in the
    board's order). ``intrinsics``: the session's own (held fixed); None uses the installed ones with
    their sigmas as a prior. ``board_turns``: the board-frame motions (4,4) of a symmetric board's other
    numberings (:func:`handeye.diagnose.consistency.board_turns`); the installed board pose is turned into the
    new views' numbering (the turn nearest theirs) before the comparison (``board["turn_deg"]``,
    ``board["T_turn"]``, ``board["installed_in_session_numbering"]``; ``board["installed"]`` is result.json's).
    A solve that keeps fewer than 3 robot poses is tried again without the view whose implied board lies far
    from the others' (:func:`odd_view`), one view at a time while 3 remain; each is then a robot-pose outlier
    of the verification.
    """
    from ..initial import solve_pnp
    from ..refine import RefineOptions, refine

    t0 = time.perf_counter()
    require_matrix(installed)
    if len(views) < 3:
        raise InputError(
            "a verification needs at least 3 views with the target",
            received=f"{len(views)} views",
            hint="capture 3-8 views with the whole board visible and the robot turned between them",
        )
    mode, X0 = installed.mode, installed.T_x
    assert X0 is not None, "an ok result has X"
    session_intr = intrinsics is not None
    intr = intrinsics if session_intr else installed.intrinsics
    if intr is None:
        raise InputError(
            "no intrinsics: the installed result has none and the session gives none", path=installed.source
        )
    prior, fixed = installed_prior(installed, session_intrinsics=session_intr, cov_x=VAGUE_COV_X)
    C = np.stack([solve_pnp(object_points[v.corner_ids], v.image_points, intr)[0] for v in views])
    E = np.stack([np.asarray(v.T_base_end, float) for v in views])
    B_views = board_from_views(mode, X0, E, C)
    B0 = mean_T(B_views)
    H = nearest_board_turn(installed.T_board, B0, board_turns)
    installed_T_board = installed.T_board
    installed = installed.with_board_turned(H)  # its board pose in the new views' numbering
    rs_mm, rs_deg = installed.robot_sigma_mm or 0.0, installed.robot_sigma_deg or 0.0
    robot = installed_robot_model(installed)
    prior = with_installed_dh(prior, installed, robot, views)
    ro = RefineOptions(
        intrinsics="fixed" if session_intr else "estimate",
        fix=fixed,
        robot_noise="fixed" if (rs_mm > 0 and rs_deg > 0) else "none",
        robot_sigma_mm=rs_mm if rs_mm > 0 else 0.1,
        robot_sigma_deg=rs_deg if rs_deg > 0 else 0.01,
        prior=prior,
        **robot,
    )
    r = refine(
        mode=mode, object_points=object_points, views=list(views), intrinsics=intr, T_x0=X0, T_board0=B0, options=ro
    )
    # few views, robot poses far off drag the solve (X is free) until too few are kept: the one whose board lies
    # apart from the others' is left out and the rest solved, again while another stands out and 3 views remain
    set_aside: list[tuple[str, float, float]] = []
    keep = list(range(len(views)))
    sigma_b = robot_board_sigma_mm(mode, X0, C, B_views, rs_mm, rs_deg)
    while r.failure_code == "too_few_robot_poses" and len(keep) > 3:
        odd = odd_view(B_views[keep], sigma_mm=sigma_b[keep])
        if odd is None:
            break
        set_aside.append((views[keep[odd[0]]].view_id, odd[1], odd[2]))
        del keep[odd[0]]
        r_rest = refine(
            mode=mode,
            object_points=object_points,
            views=[views[i] for i in keep],
            intrinsics=intr,
            T_x0=X0,
            T_board0=mean_T(B_views[keep]),
            options=ro,
        )
        if r_rest.status == "ok" or r_rest.failure_code != "too_few_robot_poses":
            r = r_rest
            break
    if r.status != "ok":
        hint = "capture views with the whole board visible and the robot turned between them"
        if r.failure_code == "too_few_robot_poses":  # the views' robot poses scatter beyond the installed noise
            err = np.array([pose_error(B, B0) for B in B_views])
            hint = (
                f"the board each view implies through its robot pose and the installed {installed.x_name} "
                f"scatters by {np.median(err[:, 1]):.1f} mm / {np.median(err[:, 0]):.2f} deg (median), against "
                f"an installed robot noise of {rs_mm:.2f} mm / {rs_deg:.3f} deg: make sure the robot is at rest "
                "at each capture and that the poses are the flange's of this robot, then capture again"
            )
        raise CalibrationError(
            f"the verification solve failed: {r.failure_reason}", code="refinement_failed", hint=hint
        )
    test = test_refined(installed, r, prior, min_variance_share=options.min_variance_share)
    drifted = test.p_value < options.alpha
    change = change_in_result_frame(X0, test.change_xi, test.change_cov)
    in_solve = set(r.used_view_ids)
    used = np.array([v.view_id in in_solve for v in views])  # not the views whose robot pose is out
    board = _board_change(installed, r, mode, E[used], C[used], options, change)
    if installed.T_board is not None:  # result.json's board, and the same board in this session's numbering
        board.update(
            installed=installed_T_board,
            installed_in_session_numbering=installed.T_board,
            T_turn=H,
            turn_deg=float(np.degrees(np.linalg.norm(rotvec_from_R(H[:3, :3])))),
        )
    robot = _robot_disagreement(r)
    for vid, far_mm, agree_mm in set_aside:
        robot["views"].append(vid)
        robot["reasons"].append(
            f"view {vid}: the board its robot pose puts through the installed {installed.x_name} lies {far_mm:.1f} mm "
            f"from where the other views put it (they agree within {agree_mm:.1f} mm); solved without it"
        )
    intr_d = _intrinsics_update(installed, r, session_intr)
    moved = what_moved(
        mode=mode,
        frame=installed.x_name,
        drifted=drifted,
        change=change,
        board=board,
        robot=robot,
        intrinsics=intr_d,
        dof=test.dof,
        n_views=len(views),
    )
    verdict = "drifted" if drifted else "still valid"
    headline = (
        f"{installed.x_name} {'DRIFTED' if drifted else 'still valid'}: test statistic {test.statistic:.2f} "
        f"({test.dof} dof), p = {test.p_value:.3g} at alpha {options.alpha:g}; estimated change "
        f"{change['trans_mm']:.2f} mm, {change['rot_deg']:.3f} deg"
    )
    views_d = {
        vid: {
            k: d.get(k)
            for k in (
                "status",
                "rms_px",
                "max_px",
                "n_corners",
                "n_used",
                "robot_vs_camera_trans_mm",
                "robot_vs_camera_rot_deg",
            )
        }
        for vid, d in r.per_view.items()
    }
    for vid, far_mm, _ in set_aside:
        views_d[vid] = dict.fromkeys(views_d[next(iter(views_d))], None) | {
            "status": "robot_excluded",
            "robot_vs_camera_trans_mm": far_mm,
        }
    return Verification(
        verdict=verdict,
        headline=headline,
        mode=mode,
        frame=installed.x_name,
        test=test,
        alpha=options.alpha,
        change=change,
        T_x_installed=X0,
        T_x_posterior=X0 @ se3_exp(test.posterior_xi),
        cov_x_posterior=test.posterior_cov,
        board=board,
        robot=robot,
        intrinsics=intr_d,
        what_moved=moved,
        views=views_d,
        n_views=len(r.used_view_ids),
        sigma_px=r.sigma_px,
        cov_source=installed.cov_source,
        seconds=time.perf_counter() - t0,
        refined=r,
    )


def _board_change(
    installed: LoadedResult, r, mode: str, E: np.ndarray, C: np.ndarray, o: VerifyOptions, change: dict
) -> dict:
    """The new board pose against the installed one.

    Its sigma: the scatter of the per-view board poses through the new X (the mean's standard error) over
    the views the solve used (``E``, ``C``: theirs) and, in quadrature, the sigma of the change of X (the
    board is found through X, so an error of X moves it as much, to first order).
    """
    m = mounting(mode)
    d = {"name": m.board_name, "installed": installed.T_board, "new": r.T_board}
    if installed.T_board is None:
        return dict(d, moved=False, known=False)
    rot_deg, trans_mm = pose_error(r.T_board, installed.T_board)
    B = board_from_views(mode, r.T_x, E, C)
    xi = tangent_difference(r.T_board, B)  # (n, 6) per-view scatter about the estimate
    n = len(B)
    se_rot = float(np.degrees(np.sqrt(np.sum(np.var(xi[:, :3], axis=0, ddof=1)) / n))) if n > 1 else float("inf")
    t_views = B[:, :3, 3]
    se_t = float(1000.0 * np.sqrt(np.sum(np.var(t_views, axis=0, ddof=1)) / n)) if n > 1 else float("inf")
    se_t = float(np.hypot(se_t, np.linalg.norm(change["sigma_trans_mm"])))
    se_rot = float(np.hypot(se_rot, np.linalg.norm(change["sigma_rot_deg"])))
    moved = bool(
        (trans_mm > max(o.board_sigmas * se_t, o.board_min_mm))
        or (rot_deg > max(o.board_sigmas * se_rot, o.board_min_deg))
    )
    return dict(
        d,
        known=True,
        trans_mm=trans_mm,
        rot_deg=rot_deg,
        sigma_trans_mm=se_t,
        sigma_rot_deg=se_rot,
        moved=moved,
        frame=m.board_frame,
    )


def _robot_disagreement(r) -> dict:
    bad = [o for o in r.outliers if o.kind == "robot_pose"]
    return {
        "views": [o.view_id for o in bad],
        "reasons": [o.reason for o in bad],
        "robot_sigma_mm": r.robot_sigma_mm,
        "robot_sigma_deg": r.robot_sigma_deg,
    }


def _intrinsics_update(installed: LoadedResult, r, session_intr: bool) -> dict:
    if session_intr or installed.intrinsics is None:
        return {"source": "session" if session_intr else "none"}
    d: dict[str, Any] = {"source": "installed (prior)"}
    new = r.intrinsics
    for n in ("fx", "fy", "cx", "cy"):
        s = installed.intrinsics_sigma.get(n, 0.0)
        diff = float(getattr(new, n) - getattr(installed.intrinsics, n))
        d[n] = {
            "installed": float(getattr(installed.intrinsics, n)),
            "new": float(getattr(new, n)),
            "diff": diff,
            "sigma_installed": s,
            "z": diff / s if s > 0 else float("nan"),
        }
    return d


def disagreeing_poses(views) -> str:
    """``poses of views 1, 3 disagree with the camera`` (one view: ``pose of view 3 disagrees ...``): robot poses."""
    many = len(views) > 1
    return (
        f"pose{'s' * many} of view{'s' * many} {', '.join(str(v) for v in views)} "
        f"disagree{'s' * (not many)} with the camera"
    )


def what_moved(
    *,
    mode: str,
    frame: str,
    drifted: bool,
    change: dict,
    board: dict,
    robot: dict,
    intrinsics: dict,
    dof: int,
    n_views: int = 0,
) -> tuple:
    """Lines for people: which part of the rig the evidence points at.

    ``n_views``: the views the verification was given. When its robot-pose outliers are half of them or more, the
    first line says that the views kept decide the verdict: past half, the outliers are no longer the exceptions
    a robust solve can tell from the rule.
    """
    m = mounting(mode)
    lines = []
    n_out = len(robot.get("views") or ())
    if n_views and 2 * n_out >= n_views:
        lines.append(
            f"only {n_views - n_out} of the {n_views} views agree with one another ({n_out} left out for their robot "
            f"poses), and the verdict rests on those {n_views - n_out}: when so many views disagree, more often the "
            f"board moved {m.board_location} during the check or the poses are not this robot's flange poses; check "
            "both and capture the views again"
        )
    size = f"{change['trans_mm']:.2f} mm, {change['rot_deg']:.3f} deg"
    if drifted:
        if m.camera_moves:
            lines.append(f"the camera moved on the flange ({frame} changed by {size}): the camera mount")
        else:
            lines.append(
                f"the camera moved against the robot base ({frame} changed by {size}): the camera "
                "mount, or the robot base itself (the two cannot be told apart)"
            )
    if board.get("moved"):
        where = "on the table (in the base frame)" if m.board_frame == "base" else "on the flange"
        lines.append(
            f"the board moved {where} by {board['trans_mm']:.2f} mm, {board['rot_deg']:.3f} deg "
            f"(its pose is re-estimated; {frame} does not depend on it)"
        )
    if robot.get("views"):
        lines.append(
            f"the robot {disagreeing_poses(robot['views'])} (a collision, a changed tool frame or a robot fault); "
            + ("those views were not used" if len(robot["views"]) > 1 else "that view was not used")
        )
    zs = {n: v["z"] for n, v in intrinsics.items() if isinstance(v, dict) and np.isfinite(v.get("z", np.nan))}
    big = [n for n, z in zs.items() if abs(z) > 3.0]
    if big:
        lines.append(
            f"the camera intrinsics moved ({', '.join(big)} beyond 3 installed sigmas): refocused or "
            "zoomed? a full recalibration is advised"
        )
    if dof < 6:
        lines.append(
            f"the views constrain only {dof} of the 6 directions of {frame}: turn the robot about more "
            "axes between views"
        )
    if not lines:
        lines.append("nothing moved beyond the uncertainty")
    return tuple(lines)
