"""A cell: several cameras of one arm refined in one factor graph (the graph itself: :mod:`.problem`).

Each camera brings its views, intrinsics and closed-form or solo start; views with the same id share one
true robot pose, whose error model (iid, or kinematic with the arm's DH offsets estimated once) is the
cell's; cameras of one mounting mode that see one board share its pose. The pixel noise of each camera and
the robot noise are variance components (Förstner's redundancy, as :mod:`.noise` does for one camera); a
view whose robot pose disagrees with every camera loses its robot prior, a view one camera alone disagrees
with is that camera's (its image) and leaves that camera. Covariances from the joint information: each X,
the boards, the intrinsics, the DH offsets and every camera-to-camera transform of cameras of one mode.

See docs/refinement.md.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from scipy.stats import chi2

from handeye.factors.reprojection import chain_residual

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..errors import InputError
from ..frames import inv_T, se3_adjoint, se3_exp, tangent_difference
from ..mounting import mounting
from .options import RefineOptions, RefineView, refine_preset
from .robot_model import build_kinematic_model, resolve_kind

log = logging.getLogger(__name__)

SIGMA_FLOOR = 1e-7  # rad, m, px: a variance component never reaches zero (the information stays finite)


@dataclass(frozen=True)
class CellCameraInput:
    """One camera of a cell: its views (ids shared with the other cameras), start values and solo decisions.

    ``masks``: view id -> corner mask of the corners the camera's own refinement kept (all when absent);
    ``removed``: view ids its own refinement dropped; ``board``: the board's identity (cameras of one mode
    with the same board share its pose); ``fix``: intrinsics held at their values.
    """

    name: str
    mode: str
    object_points: np.ndarray
    views: tuple[RefineView, ...]
    intrinsics: Intrinsics
    T_x0: np.ndarray
    T_board0: np.ndarray
    sigma_px: float = 1.0
    masks: Mapping[str, np.ndarray] = field(default_factory=dict)
    removed: frozenset = frozenset()
    board: str = "board"
    fix: tuple = ()


class _Cam:
    """A camera's mutable part of the cell state: X, intrinsics and its observations (view index u, ...)."""

    def __init__(self, c: CellCameraInput, u_of: dict, board: int, options: RefineOptions):
        self.name, self.mode, self.board = c.name, c.mode, board
        self.mount = mounting(c.mode)
        self.T_x = np.array(c.T_x0, float)
        self.k = c.intrinsics.as_vector().astype(float)
        self.width, self.height = c.intrinsics.width, c.intrinsics.height
        held = INTRINSIC_NAMES if options.intrinsics == "fixed" else c.fix
        self.free = np.array([i for i, n in enumerate(INTRINSIC_NAMES) if n not in held], int)
        obj = np.asarray(c.object_points, float)
        self.obs = []  # (u, object points (n,3), image points (n,2), mask (n,))
        for v in c.views:
            if v.view_id in c.removed:
                continue
            ids = np.asarray(v.corner_ids, int)
            mask = np.asarray(c.masks.get(v.view_id, np.ones(len(ids), bool)), bool)
            self.obs.append((u_of[v.view_id], obj[ids], np.asarray(v.image_points, float).reshape(-1, 2), mask))

    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_vector(self.k, self.width, self.height)


class CellState:
    """The solver state of a cell: cameras, boards, the union of views (one robot pose each), noise levels."""

    def __init__(self, cameras: Sequence[CellCameraInput], options: RefineOptions):
        self.o = options
        ids: list[str] = []
        rep: dict[str, np.ndarray] = {}
        joints: dict[str, Any] = {}
        for c in cameras:
            for v in c.views:
                T = np.asarray(v.T_base_end, float)
                if v.view_id in rep:
                    d = tangent_difference(rep[v.view_id], T)
                    if np.linalg.norm(d[:3]) > 1e-6 or np.linalg.norm(d[3:]) > 1e-6:
                        raise InputError(
                            f"view {v.view_id}: camera {c.name} has another robot pose than the cell's other cameras",
                            expected="one robot pose per view id in every session of the cell",
                            received=f"{np.degrees(np.linalg.norm(d[:3])):.4g} deg, "
                            f"{1e3 * np.linalg.norm(d[3:]):.4g} mm",
                            hint="views with the same id must be taken at the same robot pose; rename the others",
                        )
                    continue
                ids.append(v.view_id)
                rep[v.view_id] = T
                if v.joint_angles is not None:
                    joints[v.view_id] = v.joint_angles
        self.ids = ids
        u_of = {vid: u for u, vid in enumerate(ids)}
        self.reported = np.stack([rep[v] for v in ids])
        self.P = self.reported.copy()
        boards: dict[tuple, int] = {}
        self.board_names: list[str] = []
        self.T_boards: list[np.ndarray] = []
        self.cams: list[_Cam] = []
        for c in cameras:
            key = (mounting(c.mode).board_name, c.board)
            if key not in boards:
                boards[key] = len(boards)
                self.board_names.append(key[0])
                self.T_boards.append(np.array(c.T_board0, float))
            self.cams.append(_Cam(c, u_of, boards[key], options))
        self.sigma_px = np.array([max(float(c.sigma_px), SIGMA_FLOOR) for c in cameras])
        union = [RefineView(v, np.zeros(0, int), np.zeros((0, 2)), rep[v], joints.get(v)) for v in ids]
        self.kind = resolve_kind(options, union)
        self.kin = (
            build_kinematic_model(options, self.kind, union, self.reported)
            if self.kind in ("kinematic", "joint_space")
            else None
        )
        self.m_dh = self.kin.m if self.kin is not None else 0
        self.dh = np.zeros(self.m_dh)
        self.dh_prior_cov = np.diag(self.kin.dh_sigma**2) if self.kin is not None and self.m_dh else np.zeros((0, 0))
        self.sigma_rot = np.radians(options.robot_sigma_deg)
        self.sigma_trans = options.robot_sigma_mm / 1000.0
        self.sigma_q = self.kin.encoder_sigma_rad if self.kin is not None else 0.0
        self.excluded: dict[str, dict] = {}  # view id -> the robot-pose test's numbers
        self.camera_removed: dict[tuple[int, str], dict] = {}  # (camera, view id) -> why
        preset = refine_preset()["robust"]
        self.loss, self.loss_k = options.loss, options.loss_k
        self.robot_prior_k = float(preset["robot_prior_k"])
        self.max_iterations = options.max_iterations

    # -- views
    def seen(self) -> list[int]:
        return sorted({u for cam in self.cams for u, _o, _i, m in cam.obs if m.any()})

    def robot_views(self) -> list[int]:
        """Views whose true robot pose is a variable (every seen view, unless the robot poses are exact)."""
        return [] if self.kind == "none" else self.seen()

    def prior_views(self) -> list[int]:
        """Robot-pose variables with their prior (the others were excluded by the robot-pose test)."""
        return [u for u in self.robot_views() if self.ids[u] not in self.excluded]

    def robot_pose(self, u: int) -> np.ndarray:
        return self.reported[u] if self.kind == "none" else self.P[u]

    # -- residuals
    def view_residuals(self, c: int, j: int) -> np.ndarray:
        """(n,) corner residual norms [px] of camera c's observation j (all its corners)."""
        cam = self.cams[c]
        u, obj, img, _m = cam.obs[j]
        r = chain_residual(
            T_x=cam.T_x,
            T_base_end=self.robot_pose(u),
            T_board=self.T_boards[cam.board],
            invert_robot=cam.mount.inverts_robot,
            intrinsics_vec=cam.k,
            object_points=obj,
            image_points=img,
            jacobians=False,
        )[0]
        return np.linalg.norm(np.asarray(r).reshape(-1, 2), axis=1)

    def prior_residual(self, u: int) -> np.ndarray:
        """(6,) the robot prior's residual of view u: ``Log(inv(reported) · P) - J_dh · dh``."""
        r = tangent_difference(self.reported[u], self.P[u])
        return r - self.kin.J_dh[u] @ self.dh if self.m_dh and self.kin is not None else r

    def prior_cov(self, u: int) -> np.ndarray:
        if self.kin is not None:
            return self.sigma_q**2 * self.kin.B[u]
        return np.diag([self.sigma_rot**2] * 3 + [self.sigma_trans**2] * 3)

    @property
    def robot_groups(self) -> tuple[str, ...]:
        if self.kind == "none" or self.o.robot_noise != "estimate":
            return ()
        return ("joint",) if self.kin is not None else ("rot", "trans")


@dataclass
class CellRefinement:
    """What :func:`refine_cell` estimated, with the joint covariance of the core (robot poses marginalised).

    ``blocks`` / ``sizes`` name the rows of ``cov`` (``cameras.<name>.<x_name>``, ``cameras.<name>.intrinsics``
    (the free ones, ``intrinsics_names``), the boards by frame name, ``dh_offsets``).
    """

    names: list[str]
    modes: list[str]
    T_x: dict[str, np.ndarray]
    intrinsics: dict[str, Intrinsics]
    intrinsics_names: dict[str, list[str]]
    boards: list[dict[str, Any]]  # {"name", "matrix", "cameras", "block"}
    board_of: dict[str, int]
    robot_poses: dict[str, np.ndarray]
    dh: np.ndarray
    blocks: list[str]
    sizes: list[int]
    cov: np.ndarray
    sigma_px: dict[str, float]
    robot_model: dict[str, Any]
    robot_excluded: dict[str, dict]
    camera_removed: dict[str, dict[str, dict]]  # camera -> view id -> why
    per_view: dict[str, dict[str, dict]]  # camera -> view id -> {rms_px, n_used, status}
    redundancy: dict[str, float]
    iterations: int
    seconds: float

    def block(self, name: str) -> slice:
        at = int(np.sum(self.sizes[: self.blocks.index(name)]))
        return slice(at, at + self.sizes[self.blocks.index(name)])

    def cov_of(self, a: str, b: Optional[str] = None) -> np.ndarray:
        return self.cov[self.block(a), self.block(a if b is None else b)]

    def x_block(self, name: str) -> str:
        return f"cameras.{name}.{mounting(self.modes[self.names.index(name)]).x_name}"

    def cov_x(self, name: str) -> np.ndarray:
        return self.cov_of(self.x_block(name))

    def pair(self, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
        """(T_a_b (4,4), its covariance (6,6)) of two cameras of one mounting mode, cross-covariance included.

        With right perturbations ``X_a Exp(e_a)``, ``X_b Exp(e_b)``: ``T_a_b Exp(e_b - Ad(T_b_a) e_a)``.
        """
        T_ab = inv_T(self.T_x[a]) @ self.T_x[b]
        J = np.hstack([-se3_adjoint(inv_T(T_ab)), np.eye(6)])
        xa, xb = self.x_block(a), self.x_block(b)
        S = np.block([[self.cov_of(xa), self.cov_of(xa, xb)], [self.cov_of(xb, xa), self.cov_of(xb)]])
        C = J @ S @ J.T
        return T_ab, 0.5 * (C + C.T)

    def pairs(self) -> list[tuple[str, str]]:
        """Every pair of cameras of one mounting mode (a camera-to-camera transform is constant only there)."""
        out = []
        for i, a in enumerate(self.names):
            for b in self.names[i + 1 :]:
                if (
                    mounting(self.modes[self.names.index(a)]).fixed_frame
                    == mounting(self.modes[self.names.index(b)]).fixed_frame
                ):
                    out.append((a, b))
        return out


def _variance_components(st: CellState, rounds: int) -> dict[str, float]:
    """Re-estimate each camera's pixel sigma and the robot sigmas (redundancy-weighted); returns the redundancies."""
    from .problem import build_cell_graph, cell_information, solve_cell_graph

    red: dict[str, float] = {}
    for _ in range(rounds):
        solve_cell_graph(st, robust=False)
        S = np.linalg.pinv(cell_information(st), hermitian=True)
        changed = 0.0
        parts = [f"pixels:{c}" for c in range(len(st.cams))]
        parts += [f"robot:{gname}" for gname in st.robot_groups]
        for part in parts:
            g, v = build_cell_graph(st, part=part)
            e = 2.0 * g.error(v)
            r = float(np.trace(S @ cell_information(st, part)))
            if part.startswith("pixels"):
                c = int(part.split(":")[1])
                n = 2 * sum(int(m.sum()) for _u, _o, _i, m in st.cams[c].obs)
                redundancy = n - r
                if redundancy > 1:
                    new = max(st.sigma_px[c] * np.sqrt(e / redundancy), SIGMA_FLOOR)
                    changed = max(changed, abs(new / st.sigma_px[c] - 1))
                    st.sigma_px[c] = new
            else:
                gname = part.split(":")[1]
                n = len(st.prior_views()) * (6 if gname == "joint" else 3)
                redundancy = n - r
                if redundancy > 1:
                    attr = {"rot": "sigma_rot", "trans": "sigma_trans", "joint": "sigma_q"}[gname]
                    old = getattr(st, attr)
                    new = max(old * np.sqrt(e / redundancy), SIGMA_FLOOR)
                    changed = max(changed, abs(new / old - 1))
                    setattr(st, attr, new)
            red[part] = n - r
        if changed < 0.01:
            break
    solve_cell_graph(st, robust=False)
    return red


def _robot_test(st: CellState, S: np.ndarray, core: int, u: int) -> tuple[float, float, dict[str, float]]:
    """(statistic, p-value, sizes) of view u's robot prior residual against its covariance.

    With the prior in the fit the residual's covariance is the prior's less the estimate's; without it (an
    excluded view) the prior's plus the estimate's.
    """
    robot = st.robot_views()
    r = st.prior_residual(u)
    at = core + 6 * robot.index(u)
    J = np.zeros((6, S.shape[0]))
    J[:, at : at + 6] = np.eye(6)
    if st.m_dh and st.kin is not None:
        J[:, core - st.m_dh : core] = -st.kin.J_dh[u]
    sign = 1.0 if st.ids[u] in st.excluded else -1.0
    C = st.prior_cov(u) + sign * J @ S @ J.T
    if np.min(np.linalg.eigvalsh(C)) <= 0:
        C = st.prior_cov(u)
    stat = float(r @ np.linalg.solve(C, r))
    d = tangent_difference(st.reported[u], st.P[u])
    sizes = {"rot_deg": float(np.degrees(np.linalg.norm(d[:3]))), "trans_mm": float(1e3 * np.linalg.norm(d[3:]))}
    return stat, float(chi2.sf(stat, 6)), sizes


def _tests(st: CellState, S: np.ndarray, core: int) -> tuple[Optional[tuple], list[tuple], list[int]]:
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


def _lone_camera(st: CellState, u: int, bad: list[tuple]) -> list[tuple]:
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


def refine_cell(
    cameras: Sequence[CellCameraInput],
    *,
    options: Optional[RefineOptions] = None,
    robot_excluded0: Sequence[str] = (),
    vce_rounds: int = 6,
) -> CellRefinement:
    """Refine the cameras of a cell jointly (see the module docstring).

    ``robot_excluded0``: view ids whose robot pose starts without its prior (e.g. those most cameras' own
    refinements excluded); the robot-pose test may exclude more. Raises InputError when the cameras disagree
    about a view's reported robot pose.
    """
    from .problem import cell_information, cell_ordering, solve_cell_graph

    t0 = time.perf_counter()
    o = RefineOptions() if options is None else options
    st = CellState(cameras, o)
    for vid in robot_excluded0:
        if vid in st.ids and st.kind != "none":
            st.excluded[vid] = {"reason": "excluded by most of the cameras' own refinements"}
    iterations = solve_cell_graph(st, robust=True)
    red: dict[str, float] = {}
    readmitted: set[str] = set()
    for _round in range(max(1, o.max_outlier_rounds) + 1):
        red = _variance_components(st, vce_rounds if st.robot_groups or len(st.cams) else 1)
        core = int(np.sum(cell_ordering(st)[1]))
        S = np.linalg.pinv(cell_information(st), hermitian=True)
        worst, bad, again = _tests(st, S, core)
        log.debug("cell round %d: robot %s, views %s, again %s", _round, worst, bad, again)
        again = [u for u in again if st.ids[u] not in readmitted]
        if worst is None and not bad and not again:
            break
        for u in again:  # the cameras agree with its reported pose now (a bad image of one camera had pulled it)
            readmitted.add(st.ids[u])
            st.excluded.pop(st.ids[u])
        # a view's disagreement is one camera's image when the others (with the reported pose) agree without it;
        # else, when the cameras agree among themselves but not with the reported pose, the robot pose's
        suspects = {st.cams[c].obs[j][0] for c, j, _i in bad} | ({worst[0]} if worst is not None else set())
        images = [(c, j, i) for u in sorted(suspects) for c, j, i in _lone_camera(st, u, bad)]
        if images:
            bad = images
        elif worst is not None:
            u, _stat, info = worst
            st.excluded[st.ids[u]] = {"reason": "every camera disagrees with the reported robot pose", **info}
            bad = []
        for c, j, info in bad:
            u, obj, img, m = st.cams[c].obs[j]
            st.cams[c].obs[j] = (u, obj, img, np.zeros_like(m))
            st.camera_removed[(c, st.ids[u])] = {"reason": "this camera alone disagrees with the arm's pose", **info}
        iterations += solve_cell_graph(st, robust=False)
    keys, sizes = cell_ordering(st)
    core = int(np.sum(sizes))
    H = cell_information(st)
    S = np.linalg.inv(H)[:core, :core]
    S = 0.5 * (S + S.T)
    blocks: list[str] = []
    for cam in st.cams:
        blocks.append(f"cameras.{cam.name}.{cam.mount.x_name}")
        if cam.free.size:
            blocks.append(f"cameras.{cam.name}.intrinsics")
    board_blocks = []
    for b, name in enumerate(st.board_names):
        label = name if st.board_names.count(name) == 1 else f"{name}.{b + 1}"
        board_blocks.append(label)
    blocks += board_blocks + (["dh_offsets"] if st.m_dh else [])
    per_view: dict[str, dict[str, dict]] = {}
    for c, cam in enumerate(st.cams):
        d = {}
        for j, (u, _o, _i, m) in enumerate(cam.obs):
            e = st.view_residuals(c, j)
            sel = e[m] if m.any() else e
            status = "removed" if not m.any() else ("robot_excluded" if st.ids[u] in st.excluded else "used")
            d[st.ids[u]] = {
                "status": status,
                "n_corners": int(e.size),
                "n_used": int(m.sum()),
                "rms_px": float(np.sqrt(np.mean(sel**2))),
                "max_px": float(np.max(sel)),
            }
        per_view[cam.name] = d
    robot_model: dict[str, Any] = {"kind": st.kind}
    if st.kin is not None:
        robot_model.update(arm=st.kin.arm.name, encoder_sigma_deg=float(np.degrees(st.sigma_q)))
    elif st.kind == "iid":
        robot_model.update(sigma_rot_deg=float(np.degrees(st.sigma_rot)), sigma_trans_mm=float(1e3 * st.sigma_trans))
    return CellRefinement(
        names=[cam.name for cam in st.cams],
        modes=[cam.mode for cam in st.cams],
        T_x={cam.name: cam.T_x for cam in st.cams},
        intrinsics={cam.name: cam.intrinsics() for cam in st.cams},
        intrinsics_names={cam.name: [INTRINSIC_NAMES[i] for i in cam.free] for cam in st.cams},
        boards=[
            {
                "name": st.board_names[b],
                "block": board_blocks[b],
                "matrix": T,
                "cameras": [cam.name for cam in st.cams if cam.board == b],
            }
            for b, T in enumerate(st.T_boards)
        ],
        board_of={cam.name: cam.board for cam in st.cams},
        robot_poses={st.ids[u]: st.P[u].copy() for u in st.robot_views()},
        dh=st.dh.copy(),
        blocks=blocks,
        sizes=[int(s) for s in sizes],
        cov=S,
        sigma_px={cam.name: float(st.sigma_px[c]) for c, cam in enumerate(st.cams)},
        robot_model=robot_model,
        robot_excluded=dict(st.excluded),
        camera_removed={
            cam.name: {vid: why for (c, vid), why in st.camera_removed.items() if c == ci}
            for ci, cam in enumerate(st.cams)
        },
        per_view=per_view,
        redundancy=red,
        iterations=iterations,
        seconds=time.perf_counter() - t0,
    )
