"""Consistency of the views with one hand-eye model: board moved, robot poses, corner order, motion.

* board_moved: the best split of the view sequence into two boards, Hotelling's two-sample test of
  the implied boards;
* robot_pose_disagrees: the refinement's robot-pose decisions when it made them; otherwise the one
  robot-pose test (:func:`handeye.refine.outliers.robot_pose_test`) of each reported pose against the
  pose the camera implies, with the camera-only covariance and robot noise estimated robustly;
* corner_order_flipped: a flagged view that agrees once its board is turned by 180 (or 90) degrees;
* weak_motion, too_few_views: :func:`handeye.initial.motion.motion_quality` with the warn levels of
  configs/diagnostics.yaml.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..frames import inv_T, make_T, rotvec_from_R, se3_adjoint, tangent_difference, tangent_jacobian
from ..initial.motion import axis_text, motion_quality, rotations_to_add
from ..mounting import mounting
from ..refine.outliers import RobotPoseGates, RobotPoseTest, robot_pose_test
from ..stats import robust_noise_sigma
from .drift import drift_finding, drift_or_step, ramp_test
from .findings import Finding, ids_text
from .fits import BoardFit, fit_boards
from .geometry import implied_boards, pair_motions, pose_differences
from .observations import PoseObservations
from .thresholds import thresholds


# ------------------------------------------------------------------------------ robot pose vs camera
def implied_robot_poses(mode: str, fit: BoardFit, C: np.ndarray) -> np.ndarray:
    """``T_base_end`` (N,4,4) the camera implies for each view: ``M_i* = inv(A) C_i inv(B)``."""
    gi = fit.group_index()
    return mounting(mode).T_base_end_from_M(inv_T(fit.A) @ C @ inv_T(fit.B[gi]))


def view_disagreements(mode: str, fit: BoardFit, C: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rot_deg, trans_mm) per view between the reported robot pose and the one the camera implies.

    (rot_deg, trans_mm) per view between the reported robot pose and the one the camera implies,
    as ``inv(T_reported) T_implied`` (end frame).
    """
    return pose_differences(T, implied_robot_poses(mode, fit, C))


def _implied_pose_covariances(
    mode: str, fit: BoardFit, idx: np.ndarray, C: np.ndarray, cov_C: np.ndarray
) -> np.ndarray:
    """Covariances (K,6,6) of the implied robot poses.

    Covariances (K,6,6) of the implied robot poses (right tangent) of views ``idx`` with board poses ``C``
    (K,4,4) from the board poses' covariances ``cov_C`` (K,6,6, right tangent): ``J S J^T`` with the
    Jacobian of the implied pose taken numerically for all views at once (central differences).
    """
    mount = mounting(mode)
    A_inv, B_inv = inv_T(fit.A), inv_T(fit.B[fit.group_index()[idx]])
    T0 = mount.T_base_end_from_M(A_inv @ C @ B_inv)
    J = tangent_jacobian(lambda Cs: tangent_difference(T0, mount.T_base_end_from_M(A_inv @ Cs @ B_inv)), C)  # (K,6,6)
    return J @ cov_C @ np.swapaxes(J, 1, 2)


@dataclass(frozen=True)
class RobotPoseCheck:
    """The reported robot pose of every view against the pose the camera implies (see the module doc)."""

    mode: str
    fit: BoardFit
    T_implied: np.ndarray  # (N,4,4)
    cov_implied: np.ndarray  # (N,6,6) right tangent of T_implied (zeros without corners)
    inliers: np.ndarray  # (N,) views the robot noise was estimated from
    sigma_rot_rad: float
    sigma_trans_m: float
    test: RobotPoseTest  # of the reported poses
    with_camera_covariance: bool

    def test_poses(
        self, k: int, T_reported: np.ndarray, *, C_k: Optional[np.ndarray] = None, cov_C_k: Optional[np.ndarray] = None
    ) -> RobotPoseTest:
        """The same test of view k against other reported poses.

        The same test of view k against other reported poses (K,4,4) in one vectorised call, or of
        another board pose ``C_k`` (with its covariance) against the view's own reported pose.
        """
        if C_k is None:
            T_star, P = self.T_implied[k], self.cov_implied[k]
        else:
            T_star = implied_robot_poses(self.mode, self.fit, C_k[None])[0]
            P = (
                _implied_pose_covariances(self.mode, self.fit, np.array([k]), C_k[None], cov_C_k[None])[0]
                if cov_C_k is not None
                else np.zeros((6, 6))
            )
        T_rep = np.asarray(T_reported, float).reshape(-1, 4, 4)
        d = tangent_difference(T_rep, np.broadcast_to(T_star, T_rep.shape))
        return robot_pose_test(
            d,
            np.broadcast_to(P, (len(T_rep), 6, 6)),
            robot_sigma_rot_rad=self.sigma_rot_rad,
            robot_sigma_trans_m=self.sigma_trans_m,
            gates=self.test.gates,
        )


def robot_pose_check(obs: PoseObservations, fit: BoardFit, *, covs: Optional[np.ndarray] = None) -> RobotPoseCheck:
    """Test every view's reported pose against the camera-implied one.

    The disagreement ``d_i = tangent_difference(T_reported_i, T_implied_i)`` is compared with its covariance:
    the view's camera-only board-pose covariance ``covs`` (right tangent) propagated to the implied pose,
    plus isotropic robot noise estimated robustly from the inlier views (median Mahalanobis = chi-square
    median). Without ``covs`` the covariance is the robust isotropic spread of the inliers alone.
    """
    th = thresholds().robot_pose
    T_star = implied_robot_poses(obs.mode, fit, obs.C)
    e = tangent_difference(obs.T, T_star)  # (N,6)
    if covs is not None:
        P = _implied_pose_covariances(obs.mode, fit, np.arange(obs.n), obs.C, covs)
    else:
        P = np.zeros((obs.n, 6, 6))
    use = fit.inliers()
    s_rot = robust_noise_sigma(e[use, :3], P[use][:, :3, :3], floor=np.radians(th.noise_floor_deg))
    s_tr = robust_noise_sigma(e[use, 3:], P[use][:, 3:, 3:], floor=th.noise_floor_mm / 1e3)
    # this test models no arm's kinematics (one robust sigma per axis): an arm's pose-dependent error is in
    # the null's tail; a tracker's error is Gaussian
    gates = RobotPoseGates.from_config(unmodelled_arm=not obs.tracker)
    test = robot_pose_test(e, P, robot_sigma_rot_rad=s_rot, robot_sigma_trans_m=s_tr, gates=gates)
    return RobotPoseCheck(obs.mode, fit, T_star, P, use, s_rot, s_tr, test, covs is not None)


def flagged_views(
    obs: PoseObservations,
    check: RobotPoseCheck,
    *,
    refined=None,
    check_with_intrinsics: Optional[RobotPoseCheck] = None,
) -> tuple[list, dict, str]:
    """(flagged view ids, the refinement's robot-pose outliers by view, where the decision came from).

    A refinement that ran its outlier loop decided already: its decisions are used. Otherwise the
    diagnostics' own run of the one test decides: ``check`` with the PnP-only covariances and, when the
    intrinsics were estimated from the same corners, ``check_with_intrinsics`` with their uncertainty
    added. The truth lies between the two (the fitted A, B absorb the part of the intrinsics' error common
    to all views, but not all of it), so a view is flagged only when both tests flag it.
    """
    if (
        refined is not None
        and getattr(refined, "status", "") == "ok"
        and getattr(getattr(refined, "options", None), "outlier_loop", True)
    ):
        ref = {o.view_id: o for o in getattr(refined, "outliers", ()) if getattr(o, "kind", "") == "robot_pose"}
        return (
            [v for v in obs.ids if v in ref],
            ref,
            "the refinement's robot-pose test (Mahalanobis distance with the estimated robot and pixel noise)",
        )
    t = check.test
    g = t.gates
    flags = t.flagged & (check_with_intrinsics.test.flagged if check_with_intrinsics is not None else True)
    flags &= standing_out(check)
    null = (
        "chi-square(6)"
        if not np.isfinite(g.tail_dof)
        else f"multivariate t ({g.tail_dof:g} dof: an arm's pose-dependent error)"
    )
    src = (
        f"the robot-pose test without the wild views: {null} beyond {np.sqrt(t.threshold):.1f} sigma "
        f"(p < {g.alpha:g}) of each view's camera uncertainty plus robot noise "
        f"({np.degrees(check.sigma_rot_rad):.3f} deg, {1e3 * check.sigma_trans_m:.2f} mm per axis, estimated from "
        f"the other views), with and without the intrinsics' uncertainty, larger than {g.min_rot_deg:g} deg "
        f"or {g.min_trans_mm:g} mm, and {thresholds().robot_pose.size_ratio:g} x (1 + 2.5 / n) the other views' "
        "median disagreement"
    )
    return [v for v, f in zip(obs.ids, flags, strict=False) if f], {}, src


def standing_out(check: RobotPoseCheck) -> np.ndarray:
    """(N,) views whose disagreement exceeds a multiple of the inlier views' median.

    (N,) views whose disagreement (rotation or translation) exceeds ``size_ratio x (1 + 2.5 / n)`` times the
    inlier views' median: the noise model of a run without refinement is estimated from the same few views,
    so a flagged view must also stand out from them (medians of few views are noisy, hence 1 + 2.5 / n).
    """
    th = thresholds().robot_pose
    t, use = check.test, check.inliers
    med_rot = max(float(np.median(t.rot_deg[use])), th.noise_floor_deg)
    med_tr = max(float(np.median(t.trans_mm[use])), th.noise_floor_mm)
    ratio = np.maximum(t.rot_deg / med_rot, t.trans_mm / med_tr)
    return ratio > th.size_ratio * (1.0 + 2.5 / max(int(use.sum()), 1))


def board_turns(target) -> list:
    """Board-frame transforms (name, F) for each way a detector can number a symmetric board's corners.

    Board-frame transforms (name, F) for each way a detector can number a symmetric board's corners
    (:meth:`TargetSpec.symmetries`, identity left out): the true ``T_cam_board`` is ``C @ F`` when the
    corners were numbered that way. ``F`` is the rigid motion of the board plane that takes each corner to
    the one it was confused with (a turn about the board's normal).
    """
    obj = target.object_points()
    out = []
    for perm in target.symmetries()[1:]:
        G = _rigid_motion(obj, obj[perm])  # obj[perm[k]] = G obj[k]
        angle = np.degrees(rotvec_from_R(G[:3, :3]))[2]
        out.append((f"{angle:.0f} deg", inv_T(G)))
    return out


def _rigid_motion(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The rigid transform (4,4) taking points p (N,3) onto q (N,3) in least squares (Kabsch)."""
    pc, qc = p.mean(axis=0), q.mean(axis=0)
    U, _, Vt = np.linalg.svd((p - pc).T @ (q - qc))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return make_T(R, qc - R @ pc)


def corner_flip_findings(
    obs: PoseObservations, check: RobotPoseCheck, flagged: Sequence[str], covs: Optional[np.ndarray]
) -> tuple[list, set]:
    """Flagged views that agree once the board is turned: (findings, those view ids)."""
    idx = {v: k for k, v in enumerate(obs.ids)}
    ratio = thresholds().robot_pose.flip_agreement_ratio
    rot, trans = check.test.rot_deg, check.test.trans_mm
    flipped = {}
    for v in flagged:
        k = idx[v]
        for name, F in board_turns(obs.target):
            # the covariance of C F Exp(xi') in the right tangent: xi' = Ad(inv F) xi
            cov = None if covs is None else se3_adjoint(inv_T(F)) @ covs[k] @ se3_adjoint(inv_T(F)).T
            t2 = check.test_poses(k, obs.T[k], C_k=obs.C[k] @ F, cov_C_k=cov)
            if not t2.flagged[0] and t2.rot_deg[0] < ratio * rot[k]:
                flipped[v] = (name, float(t2.rot_deg[0]), float(t2.trans_mm[0]))
                break
    if not flipped:
        return [], set()
    vs = list(flipped)
    return [
        Finding(
            "corner_order_flipped",
            "warn",
            f"The corners were numbered from the other end of the board in {len(vs)} view(s): {ids_text(vs)}",
            "; ".join(
                f"view {v}: camera and robot disagree by {rot[idx[v]]:.1f} deg / {trans[idx[v]]:.0f} mm, with the "
                f"board turned by {flipped[v][0]} they agree to {flipped[v][1]:.2f} deg / {flipped[v][2]:.1f} mm"
                for v in vs
            ),
            "the detector cannot tell this board's orientation in these views; use a ChArUco board (or a chessboard "
            "with a mark) or leave these views out; the robot poses are fine",
            view_ids=tuple(vs),
            details={"turns": {v: flipped[v][0] for v in vs}},
        )
    ], set(vs)


def robot_pose_findings(
    obs: PoseObservations, check: RobotPoseCheck, rest: Sequence[str], *, ref_flags: dict, source: str
) -> list:
    """The robot_pose_disagrees finding for the flagged views that no other explanation took."""
    if not rest:
        return []
    idx = {v: k for k, v in enumerate(obs.ids)}
    t = check.test
    rot, trans = t.rot_deg, t.trans_mm
    parts = []
    for v in rest:
        k = idx[v]
        here = f"{rot[k]:.2f} deg / {trans[k]:.1f} mm ({t.distance[k]:.0f} sigma) against the common board fit"
        if v in ref_flags and getattr(ref_flags[v], "size", None):  # the refinement's measure, which flagged it
            sz = ref_flags[v].size
            txt = (
                f"view {v}: {sz.get('rot_deg', float('nan')):.2f} deg / {sz.get('trans_mm', float('nan')):.1f} mm "
                "in the refinement"
                + (
                    f" (Mahalanobis {sz['mahalanobis']:.1f} under its own pose covariance)"
                    if "mahalanobis" in sz
                    else ""
                )
                + f"; {here}"
            )
        else:
            txt = f"view {v}: {here}"
        if v in obs.times:
            ti, tp = obs.times[v]
            txt += f", image and pose {1e3 * abs(ti - tp):.0f} ms apart"
        parts.append(txt)
    inl = check.inliers
    typical = (
        f"against the common board fit the other views agree to {float(np.median(rot[inl])):.3f} deg / "
        f"{float(np.median(trans[inl])):.2f} mm (median)"
    )
    sev = "warn" if len(rest) <= max(1, int(0.2 * obs.n)) else "fail"
    tracked = getattr(obs.target, "kind", "") == "tracked"  # pose-only: the tracker's pose may be the wrong one
    seen = "the tracker's pose" if tracked else "what the camera saw"
    action = (
        "check these views: was the robot still moving at capture (wait for it to settle), did the tracker lose "
        "or mistake the target (a glint, a partly hidden marker), is the pose from another view? Re-capture them "
        "or leave them out"
        if tracked
        else "check these views: was the robot still moving at capture (wait for it to settle), did the board or "
        "the camera move, is the pose from another view? Re-capture them or leave them out"
    )
    return [
        Finding(
            "robot_pose_disagrees",
            sev,
            f"{len(rest)} view(s) where the robot pose disagrees with {seen} (view"
            f"{'s' if len(rest) > 1 else ''} {ids_text(rest)})",
            "reported vs camera-implied robot pose, " + "; ".join(parts) + f"; {typical}; flagged by {source}",
            action,
            view_ids=tuple(rest),
            details={
                "per_view": {
                    v: {
                        "rot_deg": float(rot[idx[v]]),
                        "trans_mm": float(trans[idx[v]]),
                        "sigmas": float(t.distance[idx[v]]),
                    }
                    for v in rest
                },
                "inlier_median_deg": float(np.median(rot[inl])),
                "inlier_median_mm": float(np.median(trans[inl])),
                "robot_sigma_deg": float(np.degrees(check.sigma_rot_rad)),
                "robot_sigma_mm": float(1e3 * check.sigma_trans_m),
                "source": source,
            },
        )
    ]


# ------------------------------------------------------------------------------ board moved
def _board_deviations(fit: BoardFit, C: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(N,6) implied board of each view against the first group's board.

    Rotation vector [deg], translation difference [mm] along the board's parent frame.
    """
    Bs = implied_boards(fit.A, C, M)
    B0 = fit.B[0]
    rv = rotvec_from_R(np.swapaxes(B0[:3, :3], 0, 1) @ Bs[:, :3, :3])
    return np.concatenate([np.degrees(rv), 1e3 * (Bs[:, :3, 3] - B0[:3, 3])], axis=1)


def step_test(v: np.ndarray, labels: np.ndarray, use: np.ndarray) -> tuple[float, float]:
    """Hotelling's two-sample test of equal mean board in the two segments: (T^2, p-value).

    The pooled within-segment covariance of the implied boards (6-D) is the noise; the p-value is
    from ``T^2 (nu - 5) / (6 nu) ~ F(6, nu - 5)``, ``nu = n0 + n1 - 2``.
    """
    from ..special import fdtrc

    a, b = v[(labels == 0) & use], v[(labels == 1) & use]
    n0, n1 = len(a), len(b)
    nu = n0 + n1 - 2
    if n0 < 2 or n1 < 2 or nu < 7:
        return 0.0, 1.0
    S = ((a - a.mean(0)).T @ (a - a.mean(0)) + (b - b.mean(0)).T @ (b - b.mean(0))) / nu
    S += np.diag(np.maximum(np.diag(S), 1e-12)) * 1e-6
    d = a.mean(0) - b.mean(0)
    try:
        t2 = float(n0 * n1 / (n0 + n1) * d @ np.linalg.solve(S, d))
    except np.linalg.LinAlgError:
        return 0.0, 1.0
    F = t2 * (nu - 5) / (6 * nu)
    return t2, float(fdtrc(6, nu - 5, F))


#: the board-moved search fits every split of the sequence up to this many splits; above, every s-th split
#: (s = ceil(splits / this)) and then every split within s of the two best of those, so its cost grows
#: linearly with the views (a move's score grows with the views put on the wrong side of it)
SPLIT_SCAN_MAX = 64


def split_candidates(lo: int, hi: int) -> tuple[list[int], int]:
    """(the coarse splits, the step s) of the board-moved search over the splits ``lo..hi`` (inclusive).

    Every split when there are at most :data:`SPLIT_SCAN_MAX`; else every s-th one and the last.
    """
    ks = list(range(lo, hi + 1))
    step = max(1, -(-len(ks) // SPLIT_SCAN_MAX))
    coarse = ks[::step]
    if ks and coarse[-1] != ks[-1]:
        coarse.append(ks[-1])
    return coarse, step


def _split_fits(obs: PoseObservations, M: np.ndarray):
    """Best two-segment split of the view sequence (one board per segment, the lowest score), or None.

    Returns (single fit, its score, (split score, k, split fit, p-value)); the score is the sum of the
    views' capped board deviations (small is good). Above :data:`SPLIT_SCAN_MAX` splits the search is
    coarse to fine (:func:`split_candidates`).
    """
    th = thresholds()
    n, seg = obs.n, th.board_moved.min_segment
    if n < 2 * seg:
        return None
    motions = pair_motions(obs.C, M)  # shared by every split
    single = fit_boards(obs.C, M, motions=motions)
    d1 = single.view_costs()
    cap = 10.0 * max(float(np.median(d1)), 0.05)

    def scored(k: int):
        labels = (np.arange(n) >= k).astype(int)
        try:
            f = fit_boards(obs.C, M, labels=labels, motions=motions)
        except np.linalg.LinAlgError:
            return None
        d = f.view_costs()
        use = d <= max(3.0 * float(np.median(d)), 0.05)
        _, p = step_test(_board_deviations(f, obs.C, M), labels, use)
        score = float(np.sum(np.minimum(d, cap)))
        # where the board moved is the split that fits best (its views' capped deviations), not the one whose test,
        # run on its inliers, is the most significant: a view put on the wrong side is trimmed from the test, so a
        # split one view off can reach the same p (0 at a large move)
        return (score, p), (score, k, f, p)

    lo, hi = seg, n - seg
    coarse, step = split_candidates(lo, hi)
    tried = {k: scored(k) for k in coarse}
    if step > 1:
        for kc in sorted((k for k in coarse if tried[k] is not None), key=lambda k: tried[k][0])[:2]:
            for k in range(max(lo, kc - step + 1), min(hi, kc + step - 1) + 1):
                if k not in tried:
                    tried[k] = scored(k)
    found = [r for _, r in sorted(tried.items()) if r is not None]
    if not found:
        return None
    return single, float(np.sum(np.minimum(d1, cap))), min(found, key=lambda r: r[0])[1]


def board_moved_findings(obs: PoseObservations, M: np.ndarray) -> tuple[list, Optional[BoardFit]]:
    """A step (or a drift) in the implied board transform: (findings, segment fit to use for the other checks)."""
    r = _split_fits(obs, M)
    if r is None:
        return [], None
    bm = thresholds().board_moved
    single, s1, (s2, k, f, p) = r
    step_rot, step_mm = (float(x[0]) for x in pose_differences(f.B[0], f.B[1]))
    within_rot = float(np.median(f.board_rot_deg))
    within_mm = float(np.median(f.board_trans_mm))
    big = (step_rot > max(bm.min_step_deg, bm.within_factor * within_rot)) or (
        step_mm > max(bm.min_step_mm, bm.within_factor * within_mm)
    )
    n_splits = obs.n - 2 * bm.min_segment + 1
    significant = p < bm.p_value / n_splits if p < 1.0 else s1 > bm.gain * s2
    if not (significant and big and s1 > bm.min_gain * s2):
        # no single move: a steady drift (a tracker's odometry, a creeping board) has its own test
        d1 = single.view_costs()
        v1 = _board_deviations(single, obs.C, M)
        k1, p1, shift = ramp_test(v1, d1 <= max(3.0 * float(np.median(d1)), 0.05))
        moved = float(np.linalg.norm(shift[:3])) > bm.min_step_deg or float(np.linalg.norm(shift[3:])) > bm.min_step_mm
        if k1 and p1 < bm.p_value and moved:
            return [drift_finding(obs, k1, float("nan"), v1 - v1[:k1].mean(axis=0))], None
        return [], None
    d = f.view_costs()
    kind, k_drift, share = drift_or_step(
        _board_deviations(f, obs.C, M), d <= max(3.0 * float(np.median(d)), 0.05), min_segment=bm.min_segment
    )
    if kind == "drift":
        return [drift_finding(obs, k_drift, share, _board_deviations(f, obs.C, M))], None
    mode = mounting(obs.mode)
    before, after = obs.ids[:k], obs.ids[k:]
    minority = after if len(after) <= len(before) else before
    where = f"between views {obs.ids[k - 1]} and {obs.ids[k]}"
    if mode.camera_moves:  # the board lies on the table
        title = f"The board moved on the table {where}"
        action = (
            "fix the board (clamp or tape it) and re-capture, or calibrate the views before and after the "
            "move as separate sessions"
        )
    else:  # the board is held by the robot
        title = f"The board slipped in the gripper {where}"
        action = "clamp the board rigidly to the flange and re-capture, or calibrate each part as its own session"
    ev = (
        f"views {before[0]}..{before[-1]} and {after[0]}..{after[-1]} each fit one board "
        f"(median scatter {within_rot:.3f} deg / {within_mm:.2f} mm) but the two boards differ by "
        f"{step_rot:.2f} deg / {step_mm:.1f} mm; one board for all views leaves "
        f"{single.median_rot_deg:.2f} deg / {single.median_trans_mm:.1f} mm (median); the split explains the "
        f"views {s1 / max(s2, 1e-9):.1f}x better"
        + (f" (two-sample test of the boards: p = {p:.1e})" if p < 1.0 else "")
    )
    fnd = Finding(
        "board_moved",
        "fail",
        title,
        ev,
        action,
        view_ids=tuple(minority),
        details={
            "split_after_view": obs.ids[k - 1],
            "step_deg": step_rot,
            "step_mm": step_mm,
            "within_deg": within_rot,
            "within_mm": within_mm,
            "p_value": p,
        },
    )
    return [fnd], f


# ------------------------------------------------------------------------------ motion and view count
def view_count_findings(n: int) -> list:
    """too_few_views: fail below the minimum, warn below min_warn, info below the recommended count."""
    v = thresholds().views
    if n < v.min_warn:
        sev = "fail" if n < v.min_fail else "warn"
        return [
            Finding(
                "too_few_views",
                sev,
                f"Only {n} usable views",
                f"{n} views with the board found and a robot pose; the hand-eye solution needs at least "
                f"{v.min_fail}, and {v.recommended}-20 give redundancy to check them",
                f"capture {v.recommended - n} or more further views, tilted 20-45 deg about different axes",
            )
        ]
    if n < v.recommended:
        return [
            Finding(
                "too_few_views",
                "info",
                f"{n} usable views; {v.recommended}-20 are recommended",
                f"{n} views: outlier checks and cross-validation have little redundancy",
                f"add {v.recommended - n} or more views, tilted about different axes",
            )
        ]
    return []


def motion_findings(mode: str, M: np.ndarray, *, A: Optional[np.ndarray] = None) -> list:
    """Weak or degenerate robot motion (small rotations, one rotation axis), too few views."""
    n = len(M)
    out = view_count_findings(n)
    if n < thresholds().views.min_fail:
        return out
    w = thresholds().motion
    frame = mounting(mode).fixed_frame
    mq = motion_quality(M, frame=frame)
    add = "add views rotated 20-45 deg about " + rotations_to_add(M, frame)
    if A is not None:
        add += " (in the camera frame: about " + rotations_to_add(M, "camera", R=A[:3, :3]) + ")"
    details = {
        "max_rotation_deg": mq.max_rotation_deg,
        "axis_spread_deg": mq.axis_spread_deg,
        "main_axis": mq.main_axis,
        "weak_axes": mq.weak_axes,
        "frame": frame,
    }
    ev = (
        f"largest rotation between two views {mq.max_rotation_deg:.1f} deg, rotation axes spread "
        f"{mq.axis_spread_deg:.1f} deg around {axis_text(mq.main_axis, frame)} ({n} views)"
    )
    if mq.status != "ok":
        small = mq.max_rotation_deg < mq.min_rotation_deg
        what = "the robot barely rotates between views" if small else "all rotations are about one axis"
        out.append(
            Finding(
                "weak_motion",
                "fail",
                f"Degenerate motion: {what}; the hand-eye transform is not determined",
                ev + f"; needs >= {mq.min_rotation_deg:g} deg and a spread >= {mq.min_axis_spread_deg:g} deg",
                add,
                details=details,
            )
        )
    elif mq.max_rotation_deg < w.warn_rotation_deg or mq.axis_spread_deg < w.warn_axis_spread_deg:
        what = (
            "small rotations between views"
            if mq.max_rotation_deg < w.warn_rotation_deg
            else "rotation axes nearly parallel"
        )
        out.append(
            Finding(
                "weak_motion",
                "warn",
                f"Weak motion: {what}; the result is poorly constrained",
                ev + f"; recommended >= {w.warn_rotation_deg:g} deg and a spread >= {w.warn_axis_spread_deg:g} deg",
                add,
                details=details,
            )
        )
    return out
