"""Automatic pose plan: few views, chosen to make the hand-eye result as certain as possible.

Pure math on the one model ``T_cam_board_i = inv(T_x) · M_i · T_board`` (:mod:`handeye.mounting`).
Candidate views orbit the board from the current view; each is mapped to a robot pose through the
current hand-eye estimate and kept when the board stays in the image. A greedy D-optimal design then
adds, one at a time, the candidate that most reduces ``log det`` of the predicted covariance of
``T_x`` (Fisher information of the corners, robot noise marginalised), while requiring rotation about
all three end-frame axes. The predicted sigma is the root of the trace (deg, mm).

See docs/collect.md.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from ..camera import Intrinsics, pixels_from_cam_points
from ..config import load_preset
from ..errors import ConfigError
from ..frames import R_from_rotvec, T_from_rotvec, inv_T, make_T, rotvec_from_R, se3_exp
from ..mounting import mounting
from ..targets import TargetSpec
from .visibility import board_center, board_in_image

log = logging.getLogger(__name__)

_H = 1e-6  # finite-difference step (rad, m)


_PLAN = load_preset("collect")["plan"]  # the defaults below; configs/collect.yaml says where each comes from


@dataclass(frozen=True)
class PlanConfig:
    """Assumptions and limits of the planner (units in the names; defaults: configs/collect.yaml ``plan:``)."""

    pixel_noise_px: float = float(_PLAN["pixel_noise_px"])  # corner noise assumed for the prediction
    robot_noise_mm: float = float(_PLAN["robot_noise_mm"])  # per-axis robot pose noise assumed (end frame)
    robot_noise_deg: float = float(_PLAN["robot_noise_deg"])
    min_axis_rotation_deg: float = float(_PLAN["min_axis_rotation_deg"])  # rotate the end this much about x, y, z
    tilt_deg: tuple = tuple(_PLAN["tilt_deg"])  # camera tilts about the board centre (x and y)
    roll_deg: tuple = tuple(_PLAN["roll_deg"])  # camera roll about its optical axis
    distance_scales: tuple = tuple(_PLAN["distance_scales"])
    max_view_angle_deg: float = float(_PLAN["max_view_angle_deg"])  # board normal vs optical axis
    max_end_rotation_deg: float = float(_PLAN["max_end_rotation_deg"])  # from the start pose
    max_travel_m: float = float(_PLAN["max_travel_m"])  # end translation from the start pose
    margin_px: Optional[float] = _PLAN["margin_px"]  # pattern-to-border margin (None: visibility's default)
    min_separation_deg: float = float(_PLAN["min_separation_deg"])  # planned views differ at least this much

    @staticmethod
    def from_config(cfg: dict) -> "PlanConfig":
        """From a ``collect`` preset (``load_preset("collect")``, possibly merged with a site file)."""
        p = cfg["plan"]
        return PlanConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in p.items()})  # type: ignore[arg-type]


@dataclass(frozen=True)
class Candidate:
    T_base_end: np.ndarray  # (4, 4) robot pose to command
    T_cam_board: np.ndarray  # (4, 4) predicted board pose in the camera
    end_rotvec_deg: np.ndarray  # (3,) end rotation from the start pose, in the start end frame
    info: np.ndarray  # (12, 12) Fisher information of (xi_x, xi_board)
    label: str


@dataclass(frozen=True)
class PlannedView:
    index: int  # 1-based order of execution
    candidate: Candidate
    sigma_rot_deg: float  # predicted for the views so far, this one included
    sigma_trans_mm: float


@dataclass(frozen=True)
class Plan:
    views: tuple  # tuple[PlannedView, ...]
    start_sigma_rot_deg: float
    start_sigma_trans_mm: float
    axis_rotation_deg: np.ndarray  # (3,) largest |end rotation| about x, y, z over start + plan
    status: str = "ok"
    failure_reason: str = ""


# ------------------------------------------------------------------------------ information
#: (12, 4, 4): Exp(+h e_k), Exp(-h e_k) for k = 0..5 (tangent order: rotation, translation)
_DELTAS = se3_exp(np.kron(np.eye(6), [[1.0], [-1.0]]) * _H)


def _perturbations(T: np.ndarray) -> np.ndarray:
    """(12, 4, 4): T·Exp(+h e_k) and T·Exp(-h e_k) for k = 0..5 (interleaved +/-)."""
    return np.asarray(T, float) @ _DELTAS


def view_information(
    *,
    mode: str,
    T_x: np.ndarray,
    T_board: np.ndarray,
    T_base_end: np.ndarray,
    object_points: np.ndarray,
    intrinsics: Intrinsics,
    pixel_noise_px: float,
    robot_noise_mm: float,
    robot_noise_deg: float,
) -> np.ndarray:
    """Fisher information (12, 12) of one view about (xi_x, xi_board), robot noise marginalised."""
    mount = mounting(mode)
    Px, Pb, Pe = _perturbations(T_x), _perturbations(T_board), _perturbations(T_base_end)
    # 36 perturbed chains: 12 for T_x, 12 for T_board, 12 for T_base_end
    X = np.concatenate([Px, np.broadcast_to(T_x, (24, 4, 4))])
    B = np.concatenate([np.broadcast_to(T_board, (12, 4, 4)), Pb, np.broadcast_to(T_board, (12, 4, 4))])
    E = np.concatenate([np.broadcast_to(T_base_end, (24, 4, 4)), Pe])
    C = mount.predict_T_cam_board(X, B, E)  # (36, 4, 4)
    p_cam = np.einsum("kij,nj->kni", C[:, :3, :3], object_points) + C[:, None, :3, 3]  # shape (36, N, 3)
    uv = pixels_from_cam_points(intrinsics.as_vector(), p_cam.reshape(-1, 3), jacobians=False)[0]
    uv = uv.reshape(18, 2, -1)  # (18 params, +/-, 2N)
    J = ((uv[:, 0] - uv[:, 1]) / (2 * _H)).T  # (2N, 18)
    J_th, J_m = J[:, :12], J[:, 12:]
    s2 = float(pixel_noise_px) ** 2
    sm = np.array([np.radians(robot_noise_deg)] * 3 + [robot_noise_mm * 1e-3] * 3) ** 2
    if np.all(sm == 0):
        return J_th.T @ J_th / s2
    # (s2 I + J_m S J_m^T)^-1 by Woodbury: (1/s2)(I - J_m (s2 S^-1 + J_m^T J_m)^-1 J_m^T)
    inner = np.diag(s2 / np.maximum(sm, 1e-30)) + J_m.T @ J_m
    A = J_th.T @ J_m
    return (J_th.T @ J_th - A @ np.linalg.solve(inner, A.T)) / s2


def _prior() -> np.ndarray:
    return np.eye(12)  # 1 rad / 1 m prior sigma: keeps the matrix invertible, negligible otherwise


def predicted_sigma(info: np.ndarray) -> tuple[float, float]:
    """(sigma_rot_deg, sigma_trans_mm) of ``T_x``: root of the trace of its marginal covariance."""
    cov = np.linalg.inv(info + _prior())[:6, :6]
    return float(np.degrees(np.sqrt(max(np.trace(cov[:3, :3]), 0.0)))), float(
        1e3 * np.sqrt(max(np.trace(cov[3:, 3:]), 0.0))
    )


def _logdet_x(info: np.ndarray) -> float:
    cov = np.linalg.inv(info + _prior())[:6, :6]
    sign, ld = np.linalg.slogdet(cov)
    return float(ld) if sign > 0 else float("inf")


# ------------------------------------------------------------------------------ candidates
def orbit_T_cam_board(
    T_cam_board_0: np.ndarray, *, center_board: np.ndarray, rotvec_cam: np.ndarray, distance_scale: float = 1.0
) -> np.ndarray:
    """The camera of ``T_cam_board_0`` turned by ``rotvec_cam`` (its own axes) about the board centre.

    The board centre keeps its direction in the camera; its distance is scaled by ``distance_scale``.
    """
    T_board_cam0 = inv_T(T_cam_board_0)
    R0, o0 = T_board_cam0[:3, :3], T_board_cam0[:3, 3]
    Q = R_from_rotvec(np.asarray(rotvec_cam, float))
    G = R0 @ Q @ R0.T  # the same rotation expressed in the board frame
    o = center_board + distance_scale * (G @ (o0 - center_board))
    return inv_T(make_T(R0 @ Q, o))


def end_rotvec_deg(T_base_end_start: np.ndarray, T_base_end: np.ndarray) -> np.ndarray:
    """Rotation of the end from the start pose, as a rotation vector in the start end frame (deg)."""
    return np.degrees(rotvec_from_R(T_base_end_start[:3, :3].T @ T_base_end[:3, :3]))


def candidate_views(
    *,
    mode: str,
    T_x: np.ndarray,
    T_board: np.ndarray,
    T_base_end_start: np.ndarray,
    T_cam_board_start: np.ndarray,
    target: TargetSpec,
    intrinsics: Intrinsics,
    config: PlanConfig = PlanConfig(),
    pose_ok: Optional[Callable[[np.ndarray], bool]] = None,
) -> list[Candidate]:
    """Feasible orbit views around the start view, with their Fisher information."""
    mount = mounting(mode)
    obj = target.object_points()
    c = board_center(target)
    grid = [
        g
        for g in itertools.product(config.tilt_deg, config.tilt_deg, config.roll_deg, config.distance_scales)
        if not (g[0] == g[1] == g[2] == 0 and g[3] == 1.0)
    ]  # all but the start view itself
    ax, ay, roll, scale = (np.array(v, float) for v in zip(*grid, strict=False))
    zeros = np.zeros_like(ax)
    # tilt about the camera's x, then its y, then roll about the optical axis
    Q = (
        R_from_rotvec(np.radians(np.stack([zeros, zeros, roll], 1)))
        @ R_from_rotvec(np.radians(np.stack([zeros, ay, zeros], 1)))
        @ R_from_rotvec(np.radians(np.stack([ax, zeros, zeros], 1)))
    )  # (K, 3, 3)
    T_board_cam0 = inv_T(T_cam_board_start)
    R0, o0 = T_board_cam0[:3, :3], T_board_cam0[:3, 3]
    R_board_cam = R0 @ Q  # (K, 3, 3); the same turn about the board centre: G = R0 Q R0^T
    o = c + scale[:, None] * np.einsum("kij,j->ki", R_board_cam @ R0.T, o0 - c)
    T_board_cam = np.tile(np.eye(4), (len(grid), 1, 1))
    T_board_cam[:, :3, :3], T_board_cam[:, :3, 3] = R_board_cam, o
    C = inv_T(T_board_cam)  # (K, 4, 4) candidate T_cam_board
    view_angle = np.degrees(np.arccos(np.clip(np.abs(C[:, 2, 2]), 0.0, 1.0)))
    T_be = mount.T_base_end_from_M(T_x @ C @ inv_T(T_board))
    R_rel = np.einsum("ji,kjl->kil", T_base_end_start[:3, :3], T_be[:, :3, :3])
    rv_deg = np.degrees(rotvec_from_R(R_rel))
    travel = np.linalg.norm(T_be[:, :3, 3] - T_base_end_start[:3, 3], axis=1)
    keep = (
        (view_angle <= config.max_view_angle_deg)
        & (np.linalg.norm(rv_deg, axis=1) <= config.max_end_rotation_deg)
        & (travel <= config.max_travel_m)
    )
    out = []
    for k in np.flatnonzero(keep):
        if not board_in_image(target, intrinsics, C[k], margin_px=config.margin_px):
            continue
        if pose_ok is not None and not pose_ok(T_be[k]):
            continue
        info = view_information(
            mode=mode,
            T_x=T_x,
            T_board=T_board,
            T_base_end=T_be[k],
            object_points=obj,
            intrinsics=intrinsics,
            pixel_noise_px=config.pixel_noise_px,
            robot_noise_mm=config.robot_noise_mm,
            robot_noise_deg=config.robot_noise_deg,
        )
        out.append(
            Candidate(
                T_be[k],
                C[k],
                rv_deg[k],
                info,
                f"tilt x {ax[k]:+.0f} y {ay[k]:+.0f} roll {roll[k]:+.0f} dist x{scale[k]:.2f}",
            )
        )
    return out


# ------------------------------------------------------------------------------ greedy choice
def greedy_plan(
    candidates: Sequence[Candidate],
    *,
    n_views: int,
    info_start: np.ndarray,
    rotvec_done_deg: Sequence[np.ndarray] = (),
    config: PlanConfig = PlanConfig(),
    on_step: Optional[Callable[[PlannedView], None]] = None,
) -> Plan:
    """Pick ``n_views`` candidates greedily (D-optimal for ``T_x``), meeting the rotation coverage."""
    if n_views < 1:
        raise ConfigError("the plan needs at least one view", expected="n_views >= 1", received=str(n_views))
    info = np.array(info_start, float)
    s0 = predicted_sigma(info)
    cover = np.zeros(3)
    for rv in rotvec_done_deg:
        cover = np.maximum(cover, np.abs(rv))
    pool = list(range(len(candidates)))
    chosen: list[PlannedView] = []
    need = config.min_axis_rotation_deg
    for step in range(n_views):
        if not pool:
            break
        missing = cover < need
        slots_left = n_views - step
        eligible = pool
        if missing.any() and slots_left <= int(missing.sum()):
            eligible = [i for i in pool if np.any(np.abs(candidates[i].end_rotvec_deg)[missing] >= need)] or pool
        scores = [_logdet_x(info + candidates[i].info) for i in eligible]
        best = eligible[int(np.argmin(scores))]
        cand = candidates[best]
        info = info + cand.info
        cover = np.maximum(cover, np.abs(cand.end_rotvec_deg))
        sr, st = predicted_sigma(info)
        pv = PlannedView(step + 1, cand, sr, st)
        chosen.append(pv)
        if on_step is not None:
            on_step(pv)
        pool = [
            i
            for i, sep in zip(pool, _separation_deg(candidates, pool, cand), strict=False)
            if i != best and sep >= config.min_separation_deg
        ]
    status, reason = "ok", ""
    if len(chosen) < n_views:
        status, reason = "short", f"only {len(chosen)} feasible views for the {n_views} asked"
    lacking = [a for a, v in zip("xyz", cover, strict=False) if v < need]
    if lacking:
        status = "short"
        reason = (reason + "; " if reason else "") + (
            f"end rotation about {', '.join(lacking)} stays below {need:g} deg within the limits "
            f"(max {', '.join(f'{v:.0f}' for v in cover)} deg about x, y, z)"
        )
    return Plan(tuple(chosen), s0[0], s0[1], cover, status, reason)


def _separation_deg(candidates: Sequence[Candidate], idx: Sequence[int], ref: Candidate) -> np.ndarray:
    """How different each candidate view is from ``ref``: rotation (deg) + 1 deg per cm of distance."""
    if not idx:
        return np.zeros(0)
    C = np.stack([candidates[i].T_cam_board for i in idx])
    cos = (np.einsum("nij,ij->n", C[:, :3, :3], ref.T_cam_board[:3, :3]) - 1.0) / 2.0
    d_rot = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    d_dist = np.abs(np.linalg.norm(C[:, :3, 3], axis=1) - np.linalg.norm(ref.T_cam_board[:3, 3]))
    return d_rot + 100.0 * d_dist


def make_plan(
    *,
    mode: str,
    T_x: np.ndarray,
    T_board: np.ndarray,
    T_base_end_start: np.ndarray,
    T_cam_board_start: np.ndarray,
    T_base_end_done: Sequence[np.ndarray],
    target: TargetSpec,
    intrinsics: Intrinsics,
    n_views: int,
    config: PlanConfig = PlanConfig(),
    pose_ok: Optional[Callable[[np.ndarray], bool]] = None,
    on_step: Optional[Callable[[PlannedView], None]] = None,
) -> Plan:
    """Plan ``n_views`` more views around the start view, given the views already captured.

    ``T_x``/``T_board`` are the current (rough) estimates; ``T_base_end_done`` the poses of the
    views already captured (their information counts, so the plan complements them).
    """
    info0 = information_of_views(
        mode=mode,
        T_x=T_x,
        T_board=T_board,
        T_base_end=T_base_end_done,
        target=target,
        intrinsics=intrinsics,
        config=config,
    )
    cands = candidate_views(
        mode=mode,
        T_x=T_x,
        T_board=T_board,
        T_base_end_start=T_base_end_start,
        T_cam_board_start=T_cam_board_start,
        target=target,
        intrinsics=intrinsics,
        config=config,
        pose_ok=pose_ok,
    )
    log.info("planning: %d feasible candidate views around the start pose", len(cands))
    done_rv = [end_rotvec_deg(T_base_end_start, T) for T in T_base_end_done]
    return greedy_plan(
        cands, n_views=n_views, info_start=info0, rotvec_done_deg=done_rv, config=config, on_step=on_step
    )


def information_of_views(
    *,
    mode: str,
    T_x: np.ndarray,
    T_board: np.ndarray,
    T_base_end: Sequence[np.ndarray],
    target: TargetSpec,
    intrinsics: Intrinsics,
    config: PlanConfig = PlanConfig(),
) -> np.ndarray:
    """Summed Fisher information (12, 12) of views at the given robot poses."""
    obj = target.object_points()
    info = np.zeros((12, 12))
    for T in T_base_end:
        info += view_information(
            mode=mode,
            T_x=T_x,
            T_board=T_board,
            T_base_end=T,
            object_points=obj,
            intrinsics=intrinsics,
            pixel_noise_px=config.pixel_noise_px,
            robot_noise_mm=config.robot_noise_mm,
            robot_noise_deg=config.robot_noise_deg,
        )
    return info


def probe_poses(T_base_end_start: np.ndarray, *, probe_deg: float = 6.0) -> list[tuple[np.ndarray, ...]]:
    """Small rotations of the end about its own x, y and z axes (for a first rough hand-eye).

    Per axis, the poses to try in order until one shows the board: +probe_deg, -probe_deg, and
    half those angles.
    """
    out = []
    for e in np.eye(3):
        out.append(
            tuple(
                T_base_end_start @ T_from_rotvec(np.radians(a) * e, np.zeros(3))
                for a in (probe_deg, -probe_deg, probe_deg / 2, -probe_deg / 2)
            )
        )
    return out
