"""A cell: several cameras of one arm refined in one factor graph (the graph itself: :mod:`.problem`).

Each camera brings its views, intrinsics and closed-form or solo start; views with the same id share one
true robot pose, whose error model (iid, or kinematic with the arm's DH offsets estimated once) is the
cell's; cameras of one mounting mode that see one board share its pose. The pixel noise of each camera and
the robot noise are variance components (Förstner's redundancy, as :mod:`.noise` does for one camera); a
view whose robot pose disagrees with every camera loses its robot prior, a view one camera alone disagrees
with is that camera's (its image) and leaves that camera. Where the cameras' views of one pose disagree beyond
their pixel noise (:func:`.cell_checks.view_pose_test`), each camera's pose of a shared view gets its own
deviation from the view's, two more variance components. Covariances from the joint information: each X,
the boards, the intrinsics, the DH offsets and every camera-to-camera transform of cameras of one mode.

See docs/refinement.md.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from handeye.factors.reprojection import chain_residual

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..errors import InputError
from ..frames import inv_T, se3_adjoint, tangent_difference
from ..mounting import mounting
from .cell_checks import lone_camera, view_pose_test, view_tests
from .options import RefineOptions, RefineView, refine_preset
from .robot_model import build_kinematic_model, resolve_kind

log = logging.getLogger(__name__)

SIGMA_FLOOR = 1e-7  # rad, m, px: a variance component never reaches zero (the information stays finite)


@dataclass(frozen=True)
class CellCameraInput:
    """One camera of a cell: its views (ids shared with the other cameras), start values and solo decisions.

    ``masks``: view id -> corner mask of the corners the camera's own refinement kept (all when absent);
    ``removed``: view ids its own refinement dropped; ``board``: the board's identity (cameras of one mode
    with the same board share its pose); ``fix``: intrinsics held at their values; ``symmetries``: the board's
    corner-id permutations (a camera's own board frame may be a turn of another's; it is renumbered to the
    first camera's).
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
    removed: frozenset[str] = frozenset()
    board: str = "board"
    fix: tuple[str, ...] = ()
    symmetries: tuple[np.ndarray, ...] = ()  # corner-id permutations of the board's look (TargetSpec.symmetries)


class _Cam:
    """A camera's mutable part of the cell state: X, intrinsics and its observations (view index u, ...)."""

    def __init__(
        self,
        c: CellCameraInput,
        u_of: dict[str, int],
        board: int,
        options: RefineOptions,
        relabel: Optional[np.ndarray] = None,
    ):
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
            ids = np.asarray(v.corner_ids, int) if relabel is None else relabel[np.asarray(v.corner_ids, int)]
            mask = np.asarray(c.masks.get(v.view_id, np.ones(len(ids), bool)), bool)
            self.obs.append((u_of[v.view_id], obj[ids], np.asarray(v.image_points, float).reshape(-1, 2), mask))

    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_vector(self.k, self.width, self.height)


def _board_turn(c: CellCameraInput, T_board_ref: np.ndarray) -> Optional[np.ndarray]:
    """The corner-id permutation that puts camera ``c``'s board frame closest to ``T_board_ref`` (None: none).

    With ``S`` the rigid motion taking the object points onto their turned ids (``S · p_i = p_perm[i]``), the
    camera's frame renumbered by ``perm`` is ``T_board0 · inv(S)``.
    """
    obj = np.asarray(c.object_points, float)
    best: Optional[tuple[float, np.ndarray]] = None
    for perm in c.symmetries:
        perm = np.asarray(perm, int)
        src, dst = obj, obj[perm]
        cs, cd = src.mean(axis=0), dst.mean(axis=0)
        U, _sv, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
        R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
        S = np.eye(4)
        S[:3, :3], S[:3, 3] = R, cd - R @ cs
        d = tangent_difference(T_board_ref, np.asarray(c.T_board0, float) @ inv_T(S))
        cost = float(np.linalg.norm(d[:3]) + np.linalg.norm(d[3:]) / 0.1)  # 1 rad ~ 0.1 m
        if best is None or cost < best[0]:
            best = (cost, perm)
    assert best is not None, "symmetries holds the identity"
    return None if np.array_equal(best[1], np.arange(len(best[1]))) else best[1]


def robot_pose_conflict(
    view_id: str, camera: str, T_ref: np.ndarray, T: np.ndarray, *, path: Optional[Path] = None
) -> Optional[InputError]:
    """The error of a view whose robot pose ``T`` in ``camera``'s session is not ``T_ref``, another camera's, or None.

    A cell's cameras see the arm at one pose per view id: the poses must agree to 1e-6 rad and 1e-6 m (what a
    pose file's six decimals in metres hold). ``path``: the camera's pose file, named in the error.
    """
    d = tangent_difference(T_ref, T)
    if np.linalg.norm(d[:3]) <= 1e-6 and np.linalg.norm(d[3:]) <= 1e-6:
        return None
    return InputError(
        f"view {view_id}: camera {camera} has another robot pose than the cell's other cameras",
        path=path,
        expected="one robot pose per view id in every session of the cell",
        received=f"{np.degrees(np.linalg.norm(d[:3])):.4g} deg, {1e3 * np.linalg.norm(d[3:]):.4g} mm",
        hint="views with the same id must be taken at the same robot pose; rename the others",
    )


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
                    conflict = robot_pose_conflict(v.view_id, c.name, rep[v.view_id], T)
                    if conflict is not None:
                        raise conflict
                    continue
                ids.append(v.view_id)
                rep[v.view_id] = T
                if v.joint_angles is not None:
                    joints[v.view_id] = v.joint_angles
        self.ids = ids
        u_of = {vid: u for u, vid in enumerate(ids)}
        self.reported = np.stack([rep[v] for v in ids])
        self.P = self.reported.copy()
        boards: dict[tuple[str, str], int] = {}
        self.board_names: list[str] = []
        self.T_boards: list[np.ndarray] = []
        self.cams: list[_Cam] = []
        for c in cameras:
            key = (mounting(c.mode).board_name, c.board)
            relabel = None
            if key not in boards:
                boards[key] = len(boards)
                self.board_names.append(key[0])
                self.T_boards.append(np.array(c.T_board0, float))
            elif len(c.symmetries) > 1:  # the turn of the board that brings this camera's frame to the first one's
                relabel = _board_turn(c, self.T_boards[boards[key]])
            self.cams.append(_Cam(c, u_of, boards[key], options, relabel))
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
        self.dh_prior_stated = np.diag(self.kin.dh_sigma**2) if self.kin is not None and self.m_dh else np.zeros((0, 0))
        self.dh_scale = 1.0  # the DH prior's sigmas in use: dh_scale times the arm's stated ones
        self.dh_scale_estimated = False
        self.sigma_rot = np.radians(options.robot_sigma_deg)
        self.sigma_trans = options.robot_sigma_mm / 1000.0
        self.sigma_q = self.kin.encoder_sigma_rad if self.kin is not None else 0.0
        # each camera's own pose of a view several cameras see, about the shared one (rot rad, trans m): None = off
        self.view_sigma: Optional[np.ndarray] = None
        self.Q: dict[tuple[int, int], np.ndarray] = {}  # (camera, view index) -> that camera's pose of the view
        self.excluded: dict[str, dict[str, Any]] = {}  # view id -> the robot-pose test's numbers
        self.camera_removed: dict[tuple[int, str], dict[str, Any]] = {}  # (camera, view id) -> why
        preset = refine_preset()["robust"]
        self.loss, self.loss_k = options.loss, options.loss_k
        self.robot_prior_k = float(preset["robot_prior_k"])
        self.max_iterations = options.max_iterations

    @property
    def dh_prior_cov(self) -> np.ndarray:
        return self.dh_prior_stated * self.dh_scale**2

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

    def own_poses(self) -> list[tuple[int, int]]:
        """(camera, view index) with a pose of their own about the view's shared one (views several cameras see)."""
        if self.view_sigma is None:
            return []
        robot = set(self.robot_views())
        seen: dict[int, list[int]] = {}
        for c, cam in enumerate(self.cams):
            for u, _o, _i, m in cam.obs:
                if m.any() and u in robot:
                    seen.setdefault(u, []).append(c)
        return sorted((c, u) for u, cs in seen.items() if len(cs) > 1 for c in cs)

    def camera_pose(self, c: int, u: int) -> np.ndarray:
        """The robot pose camera c sees in view u: its own where it has one, else the view's shared one."""
        return self.Q[(c, u)] if self.view_sigma is not None and (c, u) in self.Q else self.robot_pose(u)

    # -- residuals
    def view_residuals(self, c: int, j: int) -> np.ndarray:
        """(n,) corner residual norms [px] of camera c's observation j (all its corners)."""
        cam = self.cams[c]
        u, obj, img, _m = cam.obs[j]
        r = chain_residual(
            T_x=cam.T_x,
            T_base_end=self.camera_pose(c, u),
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
    robot_excluded: dict[str, dict[str, Any]]
    camera_removed: dict[str, dict[str, dict[str, Any]]]  # camera -> view id -> why
    per_view: dict[str, dict[str, dict[str, Any]]]  # camera -> view id -> {rms_px, n_used, status}
    redundancy: dict[str, float]
    iterations: int
    seconds: float
    # each camera's own pose of a shared view (the test of one pose per view, and the sigmas when it failed)
    view_poses: dict[str, Any] = field(default_factory=dict)

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


def _inverse(H: np.ndarray) -> np.ndarray:
    """The covariance of an information matrix (its pseudo-inverse where a direction is not resolved)."""
    try:
        return np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(H, hermitian=True)


def _variance_components(st: CellState, rounds: int) -> tuple[dict[str, float], np.ndarray]:
    """Re-estimate each camera's pixel sigma, the robot sigmas and (when estimated) the DH prior's scale.

    Förstner's estimate per component: ``s^2 <- s^2 · e / r`` with ``e`` its whitened squared residuals and ``r``
    its redundancy (rows less ``tr(S · H_part)``). Returns the redundancies and the final information's inverse.
    """
    from .problem import cell_information, solve_cell_graph

    red: dict[str, float] = {}
    attr = {"robot:rot": "sigma_rot", "robot:trans": "sigma_trans", "robot:joint": "sigma_q"}
    own = {"view:rot": 0, "view:trans": 1}  # the cameras' own poses of a view: st.view_sigma[i]
    for _ in range(rounds):
        solve_cell_graph(st, robust=False)
        H, parts = cell_information(st)
        S = _inverse(H)
        changed = 0.0
        for label, (H_part, e, rows) in parts.items():
            if label.startswith("robot:") and not st.robot_groups:
                continue
            if label == "dh" and not st.dh_scale_estimated:
                continue
            # an iid prior's factor holds its other component at a huge sigma: 3 of its 6 rows count
            n = rows // 2 if label in ("robot:rot", "robot:trans", "view:rot", "view:trans") else rows
            redundancy = n - float(np.sum(S * H_part))
            red[label] = redundancy
            if redundancy <= 1:
                continue
            k = float(np.sqrt(e / redundancy))
            if label == "dh":  # the scale of the arm's DH prior, never below the stated one
                new = max(st.dh_scale * k, 1.0)
                changed = max(changed, abs(new / st.dh_scale - 1))
                st.dh_scale = new
            elif label in own:
                assert st.view_sigma is not None, "own poses come with their sigmas"
                i = own[label]
                new = max(st.view_sigma[i] * k, SIGMA_FLOOR)
                changed = max(changed, abs(new / st.view_sigma[i] - 1))
                st.view_sigma[i] = new
            elif label.startswith("pixels:"):
                c = int(label.split(":")[1])
                new = max(st.sigma_px[c] * k, SIGMA_FLOOR)
                changed = max(changed, abs(new / st.sigma_px[c] - 1))
                st.sigma_px[c] = new
            else:
                old = getattr(st, attr[label])
                new = max(old * k, SIGMA_FLOOR)
                changed = max(changed, abs(new / old - 1))
                setattr(st, attr[label], new)
        if changed < 0.01:
            break
    solve_cell_graph(st, robust=False)
    H, _parts = cell_information(st)
    return red, _inverse(H)


def _outlier_rounds(
    st: CellState, vce_rounds: int, readmitted: set[str]
) -> tuple[dict[str, float], int, Optional[np.ndarray]]:
    """Variance components and the view tests, round after round, until no robot pose or camera view is left out.

    Returns (the components' redundancies, the solver's iterations, the covariance of the estimate as it stands
    or None when the last round moved it); ``readmitted``: view ids whose robot pose came back (never twice).
    """
    from .problem import cell_ordering, solve_cell_graph

    red: dict[str, float] = {}
    iterations = 0
    for _round in range(max(1, st.o.max_outlier_rounds) + 1):
        red, S = _variance_components(st, vce_rounds)
        core = int(np.sum(cell_ordering(st)[1]))
        worst, bad, again = view_tests(st, S, core)
        log.debug("cell round %d: robot %s, views %s, again %s", _round, worst, bad, again)
        again = [u for u in again if st.ids[u] not in readmitted]
        if worst is None and not bad and not again:
            return red, iterations, S
        for u in again:  # the cameras agree with its reported pose now (a bad image of one camera had pulled it)
            readmitted.add(st.ids[u])
            st.excluded.pop(st.ids[u])
        # a view's disagreement is one camera's image when the others (with the reported pose) agree without it;
        # else, when the cameras agree among themselves but not with the reported pose, the robot pose's
        suspects = {st.cams[c].obs[j][0] for c, j, _i in bad} | ({worst[0]} if worst is not None else set())
        images = [(c, j, i) for u in sorted(suspects) for c, j, i in lone_camera(st, u)]
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
    return red, iterations, None


def refine_cell(
    cameras: Sequence[CellCameraInput],
    *,
    options: Optional[RefineOptions] = None,
    robot_excluded0: Sequence[str] = (),
    dh_scale0: float = 1.0,
    vce_rounds: int = 6,
) -> CellRefinement:
    """Refine the cameras of a cell jointly (see the module docstring).

    ``robot_excluded0``: view ids whose robot pose starts without its prior (e.g. those most cameras' own
    refinements excluded); the robot-pose test may exclude more. ``dh_scale0`` > 1: the cameras' own views
    contradicted the arm's stated DH prior (:mod:`.noise`); its scale starts there and is a variance component
    of the cell (never below 1). Raises InputError when the cameras disagree
    about a view's reported robot pose.
    """
    from .problem import cell_information, cell_ordering, solve_cell_graph

    t0 = time.perf_counter()
    o = RefineOptions() if options is None else options
    st = CellState(cameras, o)
    if st.m_dh and dh_scale0 > 1.0 and o.robot_noise == "estimate":
        st.dh_scale, st.dh_scale_estimated = float(dh_scale0), True
    for vid in robot_excluded0:
        if vid in st.ids and st.kind != "none":
            st.excluded[vid] = {"reason": "excluded by most of the cameras' own refinements"}
    iterations = solve_cell_graph(st, robust=True)
    readmitted: set[str] = set()
    red, it, S_now = _outlier_rounds(st, vce_rounds, readmitted)
    iterations += it
    # the cameras' views of one robot pose, against each other: a camera-and-view effect the shared pose lacks
    view_test = view_pose_test(st, float(refine_preset()["noise"]["view_pose_alpha"]))
    if view_test.get("contradicted"):
        st.view_sigma = np.array([view_test["start_rot_rad"], view_test["start_trans_m"]])
        red, it, S_now = _outlier_rounds(st, vce_rounds, readmitted)
        iterations += it
    for vid, why in st.excluded.items():  # how far the cameras put the arm from its reported pose, at the end
        u = st.ids.index(vid)
        xi = tangent_difference(st.reported[u], st.P[u])
        why.update(rot_deg=float(np.degrees(np.linalg.norm(xi[:3]))), trans_mm=float(1e3 * np.linalg.norm(xi[3:])))
    keys, sizes = cell_ordering(st)
    core = int(np.sum(sizes))
    if S_now is None:  # the last round changed the estimate: its information again
        S_now = _inverse(cell_information(st)[0])
    S = S_now[:core, :core]
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
    per_view: dict[str, dict[str, dict[str, Any]]] = {}
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
        robot_model.update(
            arm=st.kin.arm.name,
            encoder_sigma_deg=float(np.degrees(st.sigma_q)),
            dh_prior_scale=st.dh_scale,
            dh_prior_scale_estimated=st.dh_scale_estimated,
        )
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
        view_poses=_view_poses(st, view_test),
    )


def _view_poses(st: CellState, test: dict[str, Any]) -> dict[str, Any]:
    """The result's record of the cameras' own poses of shared views: the test, and the sigmas where estimated."""
    if not test:
        return {}
    out: dict[str, Any] = {"test": test, "estimated": st.view_sigma is not None}
    if st.view_sigma is not None:
        own = st.own_poses()
        dev = np.array([tangent_difference(st.P[u], st.Q[(c, u)]) for c, u in own]).reshape(-1, 6)
        out.update(
            sigma_rot_deg=float(np.degrees(st.view_sigma[0])),
            sigma_trans_mm=float(1e3 * st.view_sigma[1]),
            camera_views=len(own),
            rms_rot_deg=float(np.degrees(np.sqrt(np.mean(dev[:, :3] ** 2)))) if own else 0.0,
            rms_trans_mm=float(1e3 * np.sqrt(np.mean(dev[:, 3:] ** 2))) if own else 0.0,
        )
    return out
