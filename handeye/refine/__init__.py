"""Joint maximum-likelihood refinement in a GTSAM factor graph, with noise estimation, outlier
decisions and the covariance of the hand-eye transform.

This is the only module that builds factor graphs and ``gtsam.Values``; the residuals and their
Jacobians live in :mod:`handeye.factors.reprojection` (pure numpy), the factor wrappers in
:mod:`handeye.factors.gtsam_factors`.

Model
-----
Both mounting modes are ``T_cam_board_i = inv(T_x) · M_i · T_board`` (see :mod:`handeye.mounting`).
Variables:

* ``T_x``   (Pose3): ``T_end_cam`` (eye-in-hand) or ``T_base_cam`` (eye-to-hand);
* ``T_board`` (Pose3): ``T_base_board`` (eye-in-hand) or ``T_end_board`` (eye-to-hand);
* intrinsics: the free subset of ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` as one vector
  (``options.fix`` names the fixed ones; ``intrinsics="fixed"`` fixes all; ``"prior"`` adds a
  Gaussian prior around the given intrinsics);
* per view, the true robot pose ``T_base_end_i`` (Pose3), tied to the reported pose by a prior
  ``Log(inv(T_reported) · T_base_end_i) ~ N(0, diag(s_rot^2 I3, s_trans^2 I3))`` (end frame,
  rotation first). ``robot_noise="none"`` holds the reported poses exact instead.

Measurements: every corner gives ``project(K, T_cam_board_i · p) - uv ~ N(0, sigma_px^2 I2)``;
one GTSAM ``CustomFactor`` per view carries all its corners.

Noise estimation
----------------
``sigma_px`` and the robot sigmas (rotation, translation) are three variance components. On the
cleaned data they are estimated by iterated variance-component estimation (Helmert / Förstner):
for each group ``g``, ``sigma_g^2 = e_g^T e_g / r_g`` with ``e_g`` the group's residuals and
``r_g = n_g - tr(W_g J_g Sigma J_g^T)`` its redundancy, taken from the marginal covariances of the
robot-pose variables (the information has an arrow structure, inverted exactly by a Schur
complement); the pixel group gets the remaining redundancy. This is the REML fixed point: for
Gaussian data it converges to unbiased sigmas. The fixed-point iteration runs in numpy on one
linearisation (unit-sigma pixel information from GTSAM plus the priors), then GTSAM re-solves with
the new sigmas and the iteration repeats on the new linearisation until the sigmas change by less
than 1 %. The robot sigmas start from the larger of the robust estimate and the configured value,
so that a robot noise the camera cannot see is approached from above. When a robot group's
redundancy falls below 3 % of its count, the camera can no longer resolve that robot noise: its
sigma stays where it is (the robot is effectively exact at that level) and is reported with
``robot_sigma_resolved = False``. Before the data are clean, the sigmas come from robust statistics
instead: ``sigma_px`` from the median corner residual, and each robot sigma from the value that
makes the median per-view Mahalanobis distance between the reported robot pose and the pose the
camera alone implies equal to the chi-square median.

Outliers
--------
1. Guard: the first solves use a per-corner robust loss (``options.loss``, Huber or Cauchy with
   threshold ``loss_k`` sigmas) and a Huber loss on each robot prior.
2. Decisions (``outlier_loop``), made for every view against the current solution, each with a
   reason and the size of the disagreement:

   * corners further than ``corner_outlier_sigmas`` from their prediction are flagged
     (``corners``): against the last Gaussian solve for views in it, otherwise against the pose that
     the view's corners alone imply (robust Gauss-Newton with ``T_x``, ``T_board`` and intrinsics
     held);
   * a view keeping fewer than ``min_corners`` corners is dropped (``too_few_corners``); a view
     with more than half of its corners flagged is dropped (``reprojection``);
   * the reported robot pose is compared with what the rest of the data implies: after a Gaussian
     solve, by the normalised residual of its prior (Baarda's data snooping; for a view already
     excluded, its free pose against the robot noise plus that pose's covariance), which accounts
     for the uncertainty of everything else; in the first round (robust solve) by the pose its
     corners alone imply, with that pose's covariance plus the robot noise. The squared Mahalanobis
     distance is tested against the chi-square(6) quantile at ``1 - view_outlier_p``. A disagreeing
     view loses its robot prior (``robot_pose``) but keeps its corners, which still inform the
     intrinsics.

   The flagged data are excluded, the problem is re-solved without robust losses and with
   variance-component estimation, and the decisions are made again from scratch against the clean
   solution, so a flagged view or corner that fits it is re-admitted. This repeats until the set
   is stable (or ``max_outlier_rounds``).

Start
-----
The given seed, unless a closed-form solution (every OpenCV method on every view's PnP pose and the
reported robot poses) explains more of the views: the start is the candidate with the lowest median
over the views of the view's median corner residual through its reported robot pose. One closed-form
method can be tens of degrees off when a robot pose is wrong, where another is within a degree;
the local solves below cannot recover from such a start.

Solver
------
Levenberg-Marquardt with diagonal (Marquardt) damping, ``lambda · diag(H)``. GTSAM's default damping
``lambda · I`` is not scale-free: on rendered images ``sigma_px`` is ~0.03 px, so the information
of the poses is ~1e10 and the largest default lambda (1e5) cannot shorten a Gauss-Newton step
that overshoots; LM then stops at once, far from the optimum (seen on a 12-view session with two
wrong robot poses: a common ~1 deg rotation of all robot poses left in the solution, every view
then flagged and the refinement failed). Damping proportional to the diagonal shrinks the step
whatever the units and noise levels.

Covariance
----------
From the information matrix of the final (Gaussian) linearisation, in which the estimated sigmas
are the noise models, so it is already scaled by the estimated noise. ``cov_x_6x6`` is the
marginal of ``T_x`` in GTSAM's Pose3 tangent: ``T_x,true = T_x · Exp(xi)``, ``xi = (omega [rad],
v [m])`` with both parts along the axes of the camera frame (the child frame of ``T_x``).
``sigma_trans_mm`` are the sigmas of the translation vector of ``T_x`` along the parent frame's axes
(``end`` or ``base``), ``sigma_rot_deg`` the rotation sigmas about the camera axes.
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Optional, Sequence

import cv2
import gtsam
import numpy as np
from scipy.stats import chi2

from handeye.factors.gtsam_factors import intrinsics_prior, robot_pose_prior, view_reprojection_factor
from handeye.factors.reprojection import (INTRINSIC_NAMES, LOSSES, chain_residual,
                                          corner_robust_scales)

from ..errors import ConfigError, HandeyeError, InputError
from ..frames import inv_T, is_rotation, make_T, project_to_rotation, skew
from ..mounting import mounting
from ..stats import robust_noise_sigma
from ..camera import Intrinsics

log = logging.getLogger(__name__)

INTRINSICS_MODES = ("estimate", "fixed", "prior")
ROBOT_NOISE_MODES = ("estimate", "fixed", "none")
# Floors keep the information matrix well conditioned when a noise component is (numerically) zero,
# as on noiseless synthetic data; they sit far below any real detector or robot (GTSAM would treat
# sigmas below ~1e-9 as hard constraints).
SIGMA_PX_FLOOR = 1e-3
ROBOT_SIGMA_ROT_FLOOR_RAD = 1e-6
ROBOT_SIGMA_TRANS_FLOOR_M = 1e-6
RAYLEIGH_MEDIAN = np.sqrt(2.0 * np.log(2.0))  # median of |e|/sigma for a 2-D Gaussian
UNRESOLVED_REDUNDANCY_SHARE = 0.03
COV_PARAMETRISATION = (
    "GTSAM Pose3 tangent, right perturbation: T_x_true = T_x · Exp(xi), xi = (omega_x, omega_y, omega_z [rad], "
    "v_x, v_y, v_z [m]), rotation first; omega and v along the axes of the camera frame (child frame of T_x)")

_KEY_X = gtsam.symbol("x", 0)
_KEY_B = gtsam.symbol("b", 0)
_KEY_K = gtsam.symbol("k", 0)


def _key_robot(i: int) -> int:
    return gtsam.symbol("p", i)


# ------------------------------------------------------------------------------ public data
@dataclass(frozen=True)
class RefineView:
    """One view for the refinement: detected corners and the reported robot pose."""

    view_id: str
    corner_ids: np.ndarray  # (N,) int, index object_points
    image_points: np.ndarray  # (N, 2) pixels
    T_base_end: np.ndarray  # (4, 4) reported robot pose, metres


@dataclass(frozen=True)
class RefineOptions:
    intrinsics: str = "estimate"  # estimate | fixed | prior
    intrinsics_prior_sigma: Optional[tuple] = None  # 9 sigmas (fx, fy, cx, cy [px], k1, k2, p1, p2, k3)
    fix: tuple = ()  # names of intrinsics held at their given values, e.g. ("k3", "p1", "p2")
    robot_noise: str = "estimate"  # estimate | fixed | none
    robot_sigma_mm: float = 0.2  # start value (estimate) or the value (fixed)
    robot_sigma_deg: float = 0.05
    loss: str = "huber"  # robust loss of the guard solves: huber | cauchy | none
    outlier_loop: bool = True
    working_distance_m: Optional[float] = None  # default: median board distance
    max_iterations: int = 100  # per Levenberg-Marquardt solve
    loss_k: float = 3.0  # robust threshold, in sigmas
    corner_outlier_sigmas: float = 4.8  # |e| / sigma_px beyond which a corner is flagged (chi2(2) p=1e-5)
    view_outlier_p: float = 1e-4  # false-alarm probability of the robot-pose test per view
    # practical significance: a statistically significant disagreement smaller than these is not flagged
    # (a clean camera resolves robot-pose differences far below any robot's repeatability; on such data
    # unmodelled per-view corner bias, ~0.05 px, would otherwise flag clean views)
    min_corner_outlier_px: float = 0.25
    min_robot_disagreement_mm: float = 0.5
    min_robot_disagreement_deg: float = 0.1
    min_corners: int = 8
    max_outlier_rounds: int = 6
    closed_form_starts: bool = True  # also try every OpenCV closed form as the start (off: trust T_x0)
    max_vce_iterations: int = 20


@dataclass(frozen=True)
class Outlier:
    """One explicit outlier decision."""

    view_id: str
    kind: str  # corners | reprojection | too_few_corners | robot_pose
    reason: str  # one line for people
    corner_ids: tuple = ()  # flagged corners (kind "corners"), else empty: the decision covers the view
    size: dict = field(default_factory=dict)  # size of the disagreement, names with units

    def __str__(self) -> str:
        return self.reason

    def to_dict(self) -> dict:
        return {"view_id": self.view_id, "kind": self.kind, "reason": self.reason,
                "corner_ids": [int(c) for c in self.corner_ids], "size": _jsonable(self.size)}


@dataclass(frozen=True)
class RefineResult:
    status: str  # "ok" | "failed"
    failure_reason: str
    mode: str
    x_name: str
    board_name: str
    T_x: np.ndarray
    T_board: np.ndarray
    intrinsics: Intrinsics
    T_x_seed: np.ndarray
    T_board_seed: np.ndarray
    intrinsics_seed: Intrinsics
    robot_poses: dict  # view_id -> refined T_base_end (4,4)
    cov_x_6x6: np.ndarray
    cov_parametrisation: str
    sigma_rot_deg: np.ndarray  # (3,) about the camera axes
    sigma_trans_mm: np.ndarray  # (3,) translation of T_x along the parent frame's axes
    correlation_6x6: np.ndarray
    intrinsics_sigma: dict  # name -> sigma of the free intrinsics
    working_distance_m: float
    predicted_error_mm: float  # RMS 3-D error of a point on the optical axis at the working distance
    predicted_error_axes_mm: np.ndarray  # (3,) per parent-frame axis
    sigma_px: float
    robot_sigma_mm: float
    robot_sigma_deg: float
    robot_sigma_resolved: dict  # {"rot": bool, "trans": bool}; False: below what the camera resolves (an upper value)
    rms_px_before: float
    rms_px_after: float
    per_view: dict  # view_id -> dict(rms_px, max_px, n_corners, n_used, status, robot disagreement)
    outliers: tuple  # tuple[Outlier, ...]
    iterations: int
    seconds: float
    options: RefineOptions = RefineOptions()

    @property
    def used_view_ids(self) -> list:
        return [v for v, d in self.per_view.items() if d["status"] == "used"]

    def to_dict(self) -> dict:
        """JSON-ready content for result.json (nested lists, names with units)."""
        mode = mounting(self.mode)
        parent = mode.fixed_frame
        return _jsonable({
            "status": self.status,
            "failure_reason": self.failure_reason,
            "mode": self.mode,
            "x_name": self.x_name,
            self.x_name: self.T_x,
            "board_name": self.board_name,
            self.board_name: self.T_board,
            "intrinsics": self.intrinsics.to_dict(),
            "intrinsics_sigma": self.intrinsics_sigma,
            "seed": {self.x_name: self.T_x_seed, self.board_name: self.T_board_seed,
                     "intrinsics": self.intrinsics_seed.to_dict()},
            "cov_x_6x6": self.cov_x_6x6,
            "cov_parametrisation": self.cov_parametrisation,
            "correlation_6x6": self.correlation_6x6,
            "sigma_rot_deg": self.sigma_rot_deg,
            "sigma_rot_axes": "camera frame (right perturbation)",
            "sigma_trans_mm": self.sigma_trans_mm,
            "sigma_trans_axes": f"{parent} frame (translation vector of {self.x_name})",
            "working_distance_m": self.working_distance_m,
            "predicted_error_mm": self.predicted_error_mm,
            "predicted_error_definition": ("RMS 3-D error (sqrt of the covariance trace) of a point on the optical "
                                           f"axis at working_distance_m, mapped into the {parent} frame by "
                                           f"{self.x_name}"),
            "predicted_error_axes_mm": self.predicted_error_axes_mm,
            "sigma_px": self.sigma_px,
            "robot_sigma_mm": self.robot_sigma_mm,
            "robot_sigma_deg": self.robot_sigma_deg,
            "robot_sigma_resolved": self.robot_sigma_resolved,
            "robot_noise_model": self.options.robot_noise,
            "rms_px_before": self.rms_px_before,
            "rms_px_after": self.rms_px_after,
            "per_view": self.per_view,
            "outliers": [o.to_dict() for o in self.outliers],
            "robot_poses_refined_T_base_end": self.robot_poses,
            "iterations": self.iterations,
            "seconds": self.seconds,
            "options": asdict(self.options),
        })


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return o


# ------------------------------------------------------------------------------ validation
def _check_options(o: RefineOptions) -> None:
    def bad(field_name, expected, got):
        raise ConfigError(f"refine option {field_name} is invalid", expected=expected, received=repr(got),
                          hint=f"fix refine.{field_name} in the config or the command line")

    if o.intrinsics not in INTRINSICS_MODES:
        bad("intrinsics", " | ".join(INTRINSICS_MODES), o.intrinsics)
    if o.robot_noise not in ROBOT_NOISE_MODES:
        bad("robot_noise", " | ".join(ROBOT_NOISE_MODES), o.robot_noise)
    if o.loss not in LOSSES:
        bad("loss", " | ".join(LOSSES), o.loss)
    unknown = [n for n in o.fix if n not in INTRINSIC_NAMES]
    if unknown:
        bad("fix", "names among " + ", ".join(INTRINSIC_NAMES), tuple(o.fix))
    if o.intrinsics_prior_sigma is not None:
        s = np.asarray(o.intrinsics_prior_sigma, float).reshape(-1)
        if s.size != 9 or not np.all(s > 0):
            bad("intrinsics_prior_sigma", "9 positive sigmas (fx, fy, cx, cy, k1, k2, p1, p2, k3)",
                o.intrinsics_prior_sigma)
    for name in ("robot_sigma_mm", "robot_sigma_deg", "loss_k", "corner_outlier_sigmas"):
        v = getattr(o, name)
        if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
            bad(name, "a positive number", v)
    if not (0.0 < o.view_outlier_p < 0.5):
        bad("view_outlier_p", "a probability in (0, 0.5)", o.view_outlier_p)
    for name in ("min_corner_outlier_px", "min_robot_disagreement_mm", "min_robot_disagreement_deg"):
        if not getattr(o, name) >= 0:
            bad(name, "a number >= 0", getattr(o, name))
    if o.working_distance_m is not None and not (o.working_distance_m > 0):
        bad("working_distance_m", "a positive distance in metres or null", o.working_distance_m)
    for name in ("max_iterations", "min_corners", "max_outlier_rounds", "max_vce_iterations"):
        v = getattr(o, name)
        if not (isinstance(v, (int, np.integer)) and v >= 1):
            bad(name, "a positive integer", v)


def _check_T(T, what: str) -> np.ndarray:
    """A rigid 4x4 transform, its rotation re-orthonormalised (inputs rounded to a few decimals)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not is_rotation(T[:3, :3], tol=1e-3) \
            or not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"{what} is not a rigid 4x4 transform", expected="(4,4) with a rotation block and "
                         "last row 0 0 0 1", received=f"shape {T.shape}", hint="check the seed / pose conversion")
    return make_T(project_to_rotation(T[:3, :3]), T[:3, 3])


# ------------------------------------------------------------------------------ internal state
class _Problem:
    """Mutable solver state for one refine() call (private; results are copied out)."""

    def __init__(self, *, mode, object_points, views, intrinsics, T_x0, T_board0, options):
        self.mode = mode
        self.invert = mounting(mode).inverts_robot
        self.o = options
        self.views = list(views)
        self.n = len(self.views)
        self.ids = [v.view_id for v in self.views]
        self.obj = [np.asarray(object_points, float)[np.asarray(v.corner_ids, int)] for v in self.views]
        self.img = [np.asarray(v.image_points, float).reshape(-1, 2) for v in self.views]
        self.reported = np.stack([_check_T(v.T_base_end, f"view {v.view_id} T_base_end") for v in self.views])
        self.board_centre = np.asarray(object_points, float).mean(axis=0)
        self.width, self.height = intrinsics.width, intrinsics.height
        self.k = intrinsics.as_vector().astype(float)
        self.k_given = self.k.copy()
        if options.intrinsics == "fixed":
            self.free = np.zeros(0, int)
        else:
            self.free = np.array([i for i, n in enumerate(INTRINSIC_NAMES) if n not in options.fix], int)
        self.prior_sig = None
        if options.intrinsics == "prior" and self.free.size:
            if options.intrinsics_prior_sigma is not None:
                sig = np.asarray(options.intrinsics_prior_sigma, float)
            else:  # a loose factory prior: 2 % on focal lengths and principal point, 0.05 / 0.002 on distortion
                w = self.width if self.width > 0 else 2.0 * self.k[2]
                h = self.height if self.height > 0 else 2.0 * self.k[3]
                sig = np.array([0.02 * self.k[0], 0.02 * self.k[1], 0.02 * w, 0.02 * h, 0.05, 0.05, 0.002, 0.002, 0.05])
            self.prior_sig = sig[self.free]
        self.robot_var = options.robot_noise != "none"
        self.T_x = T_x0.copy()
        self.T_board = T_board0.copy()
        self.P = self.reported.copy()  # current estimate of the true robot poses
        self.sigma_px = 1.0
        self.sigma_rot = np.radians(options.robot_sigma_deg)
        self.sigma_trans = options.robot_sigma_mm / 1000.0
        self.resolved = {"rot": True, "trans": True}
        self.status = ["used"] * self.n  # used | robot_excluded | removed
        self.mask = [np.ones(len(o), bool) for o in self.obj]
        self.iterations = 0

    # -- graph
    def active(self) -> list[int]:
        return [i for i in range(self.n) if self.status[i] != "removed"]

    def has_robot_var(self, i: int) -> bool:
        return self.robot_var or self.status[i] == "robot_excluded"

    def build(self, *, robust: bool, pixel_only: bool = False):
        """Graph and Values of the current problem; ``pixel_only`` keeps only the reprojection factors,
        with unit pixel sigma (for the variance-component estimation)."""
        g = gtsam.NonlinearFactorGraph()
        v = gtsam.Values()
        v.insert(_KEY_X, gtsam.Pose3(self.T_x))
        v.insert(_KEY_B, gtsam.Pose3(self.T_board))
        key_k = _KEY_K if self.free.size else None
        if key_k is not None:
            v.insert(key_k, self.k[self.free].copy())
        robot_keys = {}
        for i in self.active():
            key_r = None
            if self.has_robot_var(i):
                key_r = _key_robot(i)
                v.insert(key_r, gtsam.Pose3(self.P[i]))
                robot_keys[i] = key_r
            m = self.mask[i]
            g.add(view_reprojection_factor(
                mode=self.mode, key_x=_KEY_X, key_board=_KEY_B, key_robot=key_r, key_intrinsics=key_k,
                object_points=self.obj[i][m], image_points=self.img[i][m],
                sigma_px=1.0 if pixel_only else self.sigma_px,
                intrinsics_vec=self.k, free_intrinsics=self.free, T_base_end=self.reported[i],
                loss=self.o.loss if robust else "none", loss_k=self.o.loss_k))
            if key_r is not None and self.status[i] == "used" and not pixel_only:
                g.add(robot_pose_prior(key_robot=key_r, T_base_end_reported=self.reported[i],
                                       sigma_rot_rad=self.sigma_rot, sigma_trans_m=self.sigma_trans,
                                       robust_k=3.5 if robust and self.o.loss != "none" else None))
        if self.prior_sig is not None and not pixel_only:
            g.add(intrinsics_prior(key_intrinsics=_KEY_K, prior_values=self.k_given[self.free], sigmas=self.prior_sig))
        return g, v, robot_keys

    def solve(self, *, robust: bool):
        g, v, robot_keys = self.build(robust=robust)
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self.o.max_iterations)
        params.setRelativeErrorTol(1e-9)
        params.setAbsoluteErrorTol(0.0)
        params.setErrorTol(0.0)
        params.setDiagonalDamping(True)  # scale-free damping (see "Solver" in the module docstring)
        opt = gtsam.LevenbergMarquardtOptimizer(g, v, params)
        res = opt.optimize()
        self.iterations += opt.iterations()
        self.T_x = res.atPose3(_KEY_X).matrix()
        self.T_board = res.atPose3(_KEY_B).matrix()
        if self.free.size:
            self.k = self.k.copy()
            self.k[self.free] = res.atVector(_KEY_K)
        for i, key in robot_keys.items():
            self.P[i] = res.atPose3(key).matrix()
        return g, res, robot_keys

    # -- residuals
    def robot_pose(self, i: int) -> np.ndarray:
        return self.P[i] if self.has_robot_var(i) else self.reported[i]

    def view_residual(self, i: int, T_robot: Optional[np.ndarray] = None) -> np.ndarray:
        """Residuals (N,2) of all corners of view i at the current solution."""
        T_r = self.robot_pose(i) if T_robot is None else T_robot
        r = chain_residual(T_x=self.T_x, T_base_end=T_r, T_board=self.T_board, invert_robot=self.invert,
                           intrinsics_vec=self.k, object_points=self.obj[i], image_points=self.img[i],
                           jacobians=False)[0]
        return r.reshape(-1, 2)

    def used_corner_residuals(self) -> np.ndarray:
        return np.concatenate([self.view_residual(i)[self.mask[i]] for i in self.active()])

    def prior_views(self) -> list[int]:
        return [i for i in self.active() if self.robot_var and self.status[i] == "used"]

    def robot_residuals(self, idx: Sequence[int]) -> np.ndarray:
        """Log(inv(reported) · P) for views idx: (len, 6), rotation first."""
        if not len(idx):
            return np.zeros((0, 6))
        return np.stack([gtsam.Pose3.Logmap(gtsam.Pose3(inv_T(self.reported[i]) @ self.P[i])) for i in idx])

    # -- covariance
    def _ordering(self, robot_keys):
        ordering = gtsam.Ordering()
        for k in [_KEY_X, _KEY_B] + ([_KEY_K] if self.free.size else []) + [robot_keys[i] for i in sorted(robot_keys)]:
            ordering.push_back(k)
        return ordering

    def covariances(self, g, values, robot_keys):
        """Marginal covariances (core block, {view index: 6x6 robot block}) from the information matrix."""
        H, _ = g.linearize(values).hessian(self._ordering(robot_keys))
        c = 12 + self.free.size
        idx_p = sorted(robot_keys)
        S_cc, S_pp = _arrow_inverse(H, c, len(idx_p))
        return S_cc, dict(zip(idx_p, S_pp))

    def pixel_linearisation(self) -> "_PixelLin":
        """Unit-sigma information of the reprojection factors alone at the current estimate."""
        g, v, robot_keys = self.build(robust=False, pixel_only=True)
        H, eta = g.linearize(v).hessian(self._ordering(robot_keys))
        idx_p = sorted(robot_keys)
        n, c = len(idx_p), 12 + self.free.size
        e = self.used_corner_residuals()
        prior = np.array([self.robot_var and self.status[i] == "used" for i in idx_p], bool)
        xi = self.robot_residuals(idx_p)  # shape (n, 6)
        blocks = H[c:, c:].reshape(n, 6, n, 6)
        ar = np.arange(n)
        return _PixelLin(Hcc=H[:c, :c], Hcp=H[:c, c:].reshape(c, n, 6).transpose(1, 0, 2),
                         Hpp=blocks[ar, :, ar, :], g=-np.asarray(eta).reshape(-1), rr=float(np.sum(e * e)),
                         n_obs=int(e.size), prior=prior, xi=xi, c=c)


@dataclass(frozen=True)
class _PixelLin:
    """Reprojection part of a linearisation with unit pixel sigma: information blocks (core c, then n
    robot blocks), gradient g = J^T r, r^T r and the count of observations; plus the robot prior
    residuals xi (n,6) (rows without a prior flagged False in ``prior``)."""

    Hcc: np.ndarray
    Hcp: np.ndarray  # shape (n, c, 6)
    Hpp: np.ndarray  # shape (n, 6, 6)
    g: np.ndarray  # shape (c + 6n,)
    rr: float
    n_obs: int
    prior: np.ndarray
    xi: np.ndarray
    c: int


def _arrow_inverse(H: np.ndarray, c: int, n: int):
    """Diagonal blocks of inv(H) for an information matrix with a dense core of size c followed by
    n 6x6 blocks that couple only with the core: (Sigma_core (c,c), Sigma_blocks (n,6,6))."""
    Hcp = H[:c, c:].reshape(c, n, 6).transpose(1, 0, 2)  # shape (n, c, 6)
    blocks = H[c:, c:].reshape(n, 6, n, 6)
    ar = np.arange(n)
    S_cc, S_pp, _ = _arrow_solve(H[:c, :c], Hcp, blocks[ar, :, ar, :])
    return S_cc, S_pp


def _arrow_solve(Hcc: np.ndarray, Hcp: np.ndarray, Hpp: np.ndarray, rhs: Optional[np.ndarray] = None):
    """Schur-complement inverse of the arrow-shaped information [[Hcc, Hcp^T...], [Hcp_i^T, Hpp_i]].

    Returns (Sigma_core, Sigma_blocks (n,6,6), solution of H x = rhs or None). Raises LinAlgError
    when H is not positive definite (some unknown is not constrained)."""
    n = Hpp.shape[0]
    if n == 0:
        L = np.linalg.cholesky(Hcc)
        Li = np.linalg.inv(L)
        S_cc = Li.T @ Li
        return S_cc, np.zeros((0, 6, 6)), None if rhs is None else S_cc @ rhs
    np.linalg.cholesky(Hpp)  # raises LinAlgError when a robot pose is unconstrained
    Q = np.linalg.inv(Hpp)
    HQ = Hcp @ Q  # shape (n, c, 6)
    S = Hcc - np.einsum("nci,ndi->cd", HQ, Hcp)
    L = np.linalg.cholesky(0.5 * (S + S.T))
    Li = np.linalg.inv(L)
    S_cc = Li.T @ Li
    S_pp = Q + np.einsum("nci,cd,ndj->nij", HQ, S_cc, HQ)
    if rhs is None:
        return S_cc, S_pp, None
    c = Hcc.shape[0]
    b_c, b_p = rhs[:c], rhs[c:].reshape(n, 6)
    x_c = S_cc @ (b_c - np.einsum("nci,ni->c", HQ, b_p))
    x_p = np.einsum("nij,nj->ni", Q, b_p - np.einsum("nci,c->ni", Hcp, x_c))
    return S_cc, S_pp, np.concatenate([x_c, x_p.reshape(-1)])


# ------------------------------------------------------------------------------ per-view tests
@dataclass(frozen=True)
class _ViewCheck:
    P_cam: np.ndarray  # (4,4) robot pose implied by the camera alone
    cov_cam: np.ndarray  # (6,6) its covariance (right tangent)
    resid_px: np.ndarray  # (N,) corner residual norms at P_cam
    delta: np.ndarray  # (6,) Log(inv(reported) · P_cam)
    ok: bool


def _camera_only_pose(pb: _Problem, i: int, P_init: np.ndarray, *, max_iters: int = 10) -> _ViewCheck:
    """Robust Gauss-Newton for view i's robot pose from its corners alone (T_x, T_board, K held)."""
    P = P_init.copy()
    obj, img = pb.obj[i], pb.img[i]
    fail = _ViewCheck(P, np.full((6, 6), np.nan), np.full(len(obj), np.inf), np.full(6, np.nan), False)
    for it in range(max_iters + 1):
        r, _, J_r, _, _ = chain_residual(T_x=pb.T_x, T_base_end=P, T_board=pb.T_board, invert_robot=pb.invert,
                                         intrinsics_vec=pb.k, object_points=obj, image_points=img, robot_only=True)
        if not np.all(np.isfinite(r)):
            return fail
        if it == max_iters:
            break
        _, w = corner_robust_scales(r, sigma_px=pb.sigma_px, loss="huber", k=pb.o.loss_k)
        w2 = np.repeat(w * w, 2)
        Jw = J_r * w2[:, None]
        try:
            step = -np.linalg.solve(Jw.T @ J_r, Jw.T @ r)
        except np.linalg.LinAlgError:
            return fail
        P = gtsam.Pose3(P).retract(step).matrix()
        if np.abs(step).max() < 1e-8:  # rad, m: far below any pose precision; one more evaluation at P
            max_iters = it + 1
    e = np.linalg.norm(r.reshape(-1, 2), axis=1)
    inl = np.repeat(e <= pb.o.corner_outlier_sigmas * pb.sigma_px, 2)
    J = J_r[inl]
    if J.shape[0] < 6:
        return _ViewCheck(P, fail.cov_cam, e, fail.delta, False)
    try:
        cov = pb.sigma_px ** 2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return _ViewCheck(P, fail.cov_cam, e, fail.delta, False)
    delta = gtsam.Pose3.Logmap(gtsam.Pose3(inv_T(pb.reported[i]) @ P))
    return _ViewCheck(P, cov, e, delta, bool(np.all(np.isfinite(cov))))


def _joint_check(pb: _Problem, i: int, cov: np.ndarray) -> _ViewCheck:
    """View i as the last Gaussian solve has it (its robot pose a variable of that solve)."""
    P = pb.P[i]
    e = np.linalg.norm(pb.view_residual(i), axis=1)
    delta = gtsam.Pose3.Logmap(gtsam.Pose3(inv_T(pb.reported[i]) @ P))
    return _ViewCheck(P.copy(), cov, e, delta, True)


def _robot_mahalanobis(checks: Sequence[_ViewCheck], sigma_rot: float, sigma_trans: float) -> np.ndarray:
    d = np.stack([c.delta for c in checks])
    C = np.stack([c.cov_cam for c in checks]) + np.diag([sigma_rot ** 2] * 3 + [sigma_trans ** 2] * 3)
    return np.einsum("ni,ni->n", d, np.linalg.solve(C, d[..., None])[..., 0])


def _robust_robot_sigma(checks: Sequence[_ViewCheck], part: slice, floor: float) -> float:
    """Sigma s with median_i d_i^T (C_i + s^2 I)^-1 d_i = chi2(3) median, over the views' 3-D part."""
    return robust_noise_sigma(np.stack([c.delta[part] for c in checks]),
                              np.stack([c.cov_cam[part, part] for c in checks]), floor=floor)


def _robust_sigma_px(pb: _Problem) -> float:
    e = np.linalg.norm(pb.used_corner_residuals(), axis=1)
    return max(float(np.median(e)) / RAYLEIGH_MEDIAN, SIGMA_PX_FLOOR)


@dataclass(frozen=True)
class _Decision:
    status: tuple
    masks: tuple  # tuple of bool arrays
    outliers: tuple
    checks: tuple  # per view _ViewCheck
    mahalanobis: np.ndarray  # (n,) squared Mahalanobis distance of each view's robot-pose disagreement
    disagreement: np.ndarray  # (n, 6) reported robot pose vs the other data (Log, rotation first)

    def key(self):
        return self.status, tuple(m.tobytes() for m in self.masks)


def _robot_test_sigmas(pb: _Problem) -> tuple[float, float]:
    if pb.o.robot_noise == "estimate" or pb.robot_var:
        return pb.sigma_rot, pb.sigma_trans
    return np.radians(pb.o.robot_sigma_deg), pb.o.robot_sigma_mm / 1000.0  # "none": configured tolerance


def _robot_tests(pb: _Problem, checks: Sequence[_ViewCheck], S_pp: Optional[dict]):
    """Per view: squared Mahalanobis distance between the reported robot pose and what the other data
    imply, and that disagreement (6,) (Log, rotation first).

    With the covariances of a Gaussian solve (``S_pp``, marginal covariance of each robot-pose
    variable): for a view whose prior is in the solve, the normalised prior residual (Baarda's
    test: e^T (R - Sigma_P)^-1 e, disagreement R (R - Sigma_P)^-1 e, both the leave-one-out
    values); for a view whose prior was excluded, Log(inv(reported) · P) against R + Sigma_P.
    Otherwise (robust phase, views not in the solve) the camera-only pose against its own
    covariance plus R, which ignores the uncertainty of T_x, T_board and the intrinsics."""
    s_rot, s_trans = _robot_test_sigmas(pb)
    R = np.diag([s_rot ** 2] * 3 + [s_trans ** 2] * 3)
    maha = np.full(pb.n, np.nan)
    disagree = np.full((pb.n, 6), np.nan)
    for i, ch in enumerate(checks):
        Sp = None if S_pp is None else S_pp.get(i)
        if Sp is not None and pb.status[i] in ("used", "robot_excluded") and pb.has_robot_var(i):
            e = gtsam.Pose3.Logmap(gtsam.Pose3(inv_T(pb.reported[i]) @ pb.P[i]))
            try:
                if pb.status[i] == "used":
                    C = R - Sp
                    np.linalg.cholesky(C)
                    Ce = np.linalg.solve(C, e)
                    maha[i], disagree[i] = float(e @ Ce), R @ Ce
                else:
                    maha[i], disagree[i] = float(e @ np.linalg.solve(R + Sp, e)), e
                continue
            except np.linalg.LinAlgError:  # fall back to the camera-only comparison
                ch = _camera_only_pose(pb, i, pb.P[i])
        if ch.ok:
            maha[i] = float(_robot_mahalanobis([ch], s_rot, s_trans)[0])
            disagree[i] = ch.delta
    return maha, disagree


def _decide(pb: _Problem, *, robust_robot_sigma: bool, S_pp: Optional[dict] = None) -> _Decision:
    """Outlier decisions for every view against the current solution (see the module docstring).

    ``robust_robot_sigma``: first set the robot sigmas from the camera-only poses by the robust
    (median) estimator, for decisions made before the data are clean. ``S_pp``: robot-pose
    covariances of the last Gaussian solve, for the exact robot-pose tests."""
    o = pb.o
    t_corner = o.corner_outlier_sigmas
    t_view = chi2.ppf(1.0 - o.view_outlier_p, 6)
    checks = [_joint_check(pb, i, S_pp[i]) if S_pp is not None and i in S_pp
              else _camera_only_pose(pb, i, pb.P[i]) if len(pb.obj[i]) >= o.min_corners
              else _ViewCheck(pb.P[i], np.full((6, 6), np.nan), np.full(len(pb.obj[i]), np.inf), np.full(6, np.nan),
                              False)
              for i in range(pb.n)]
    if robust_robot_sigma:
        _robust_robot_sigmas(pb, [checks[i] for i in pb.prior_views()])
    status, masks, outliers = [], [], []
    maha, disagree = _robot_tests(pb, checks, S_pp)
    for i, vid in enumerate(pb.ids):
        ch = checks[i]
        n_all = len(ch.resid_px)
        bad = ~(ch.resid_px <= max(t_corner * pb.sigma_px, o.min_corner_outlier_px))
        n_good = int((~bad).sum())
        if not ch.ok and n_all >= o.min_corners:
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(Outlier(vid, "reprojection", f"view {vid}: its corners alone do not determine a pose "
                                    f"({n_all} corners)", size={"n_corners": n_all}))
            continue
        if n_good < o.min_corners or not ch.ok:
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(Outlier(vid, "too_few_corners", f"view {vid}: {n_good} usable corners of {n_all}, "
                                    f"need {o.min_corners}", size={"n_usable": n_good, "n_corners": n_all}))
            continue
        if bad.mean() > 0.5:
            rms = float(np.sqrt(np.mean(ch.resid_px ** 2)))
            status.append("removed")
            masks.append(np.ones(n_all, bool))
            outliers.append(Outlier(vid, "reprojection", f"view {vid}: {int(bad.sum())} of {n_all} corners beyond "
                                    f"{t_corner:g} sigma even with the pose fitted to this view alone "
                                    f"(rms {rms:.2f} px, sigma {pb.sigma_px:.3f} px)",
                                    size={"rms_px": rms, "max_px": float(ch.resid_px.max()),
                                          "n_flagged": int(bad.sum())}))
            continue
        masks.append(~bad)
        if bad.any():
            ids = tuple(int(c) for c in np.asarray(pb.views[i].corner_ids)[bad])
            outliers.append(Outlier(vid, "corners", f"view {vid}: {len(ids)} corner(s) beyond {t_corner:g} sigma "
                                    f"(max {ch.resid_px[bad].max():.2f} px, sigma {pb.sigma_px:.3f} px)",
                                    corner_ids=ids, size={"residual_px": ch.resid_px[bad]}))
        rot_deg = float(np.degrees(np.linalg.norm(disagree[i, :3])))
        trans_mm = float(1000.0 * np.linalg.norm(disagree[i, 3:]))
        if maha[i] > t_view and (trans_mm > o.min_robot_disagreement_mm or rot_deg > o.min_robot_disagreement_deg):
            status.append("robot_excluded")
            outliers.append(Outlier(vid, "robot_pose", f"view {vid}: reported robot pose disagrees with the camera by "
                                    f"{rot_deg:.3f} deg / {trans_mm:.2f} mm (Mahalanobis {np.sqrt(maha[i]):.1f}, "
                                    f"threshold {np.sqrt(t_view):.1f}); its corners still serve the intrinsics",
                                    size={"rot_deg": rot_deg, "trans_mm": trans_mm,
                                          "mahalanobis": float(np.sqrt(maha[i])),
                                          "threshold": float(np.sqrt(t_view))}))
        else:
            status.append("used")
    return _Decision(tuple(status), tuple(masks), tuple(outliers), tuple(checks), maha, disagree)


def _apply(pb: _Problem, dec: _Decision) -> None:
    pb.status = list(dec.status)
    pb.mask = [m.copy() for m in dec.masks]
    for i, ch in enumerate(dec.checks):  # start excluded / re-admitted poses from the camera's pose
        if ch.ok and dec.status[i] != "used":
            pb.P[i] = ch.P_cam


# ------------------------------------------------------------------------------ noise estimation
def _robust_robot_sigmas(pb: _Problem, checks: Sequence[_ViewCheck]) -> None:
    """Robot sigmas from camera-only poses by the robust median estimator (robot_noise="estimate")."""
    checks = [c for c in checks if c.ok]
    if pb.o.robot_noise != "estimate" or len(checks) < 3:
        return
    pb.sigma_rot = _robust_robot_sigma(checks, slice(0, 3), ROBOT_SIGMA_ROT_FLOOR_RAD)
    pb.sigma_trans = _robust_robot_sigma(checks, slice(3, 6), ROBOT_SIGMA_TRANS_FLOOR_M)


def _vce_on_linearisation(pb: _Problem, lin: _PixelLin, *, max_iters: int = 500, tol: float = 1e-4) -> float:
    """Iterate variance-component estimation on one fixed linearisation (pure numpy, cheap).

    For sigmas s the linear least-squares step dx, the group residual sums e_g^T e_g and the
    redundancies r_g = n_g - tr(W_g J_g Sigma J_g^T) follow from the unit-sigma pixel information,
    the robot priors (Jacobian I on their pose block) and the intrinsics prior; then
    s_g^2 = e_g^T e_g / r_g. Updates pb's sigmas in place; returns the relative change."""
    c, n = lin.c, lin.Hpp.shape[0]
    D = c + 6 * n
    estimate_robot = pb.o.robot_noise == "estimate"
    pri = lin.prior
    n_pri = int(pri.sum())
    HK = np.zeros(c)
    gK = np.zeros(c)
    if pb.prior_sig is not None:
        nk = pb.free.size
        HK[12:12 + nk] = 1.0 / pb.prior_sig ** 2
        gK[12:12 + nk] = (pb.k[pb.free] - pb.k_given[pb.free]) / pb.prior_sig ** 2
    s_px, s_rot, s_trans = pb.sigma_px, pb.sigma_rot, pb.sigma_trans
    start = np.array([s_px, s_rot, s_trans])
    eye6 = np.eye(6)
    for _ in range(max_iters):
        w_px = 1.0 / s_px ** 2
        w_rob = np.array([1.0 / s_rot ** 2] * 3 + [1.0 / s_trans ** 2] * 3)
        Wp = pri[:, None] * w_rob[None, :]  # shape (n, 6): prior weights per robot block
        Hpp = lin.Hpp * w_px + Wp[:, :, None] * eye6
        grad = lin.g * w_px
        grad[:c] += gK
        grad[c:] += (Wp * lin.xi).reshape(-1)
        S_cc, S_pp, dx = _arrow_solve(lin.Hcc * w_px + np.diag(HK), lin.Hcp * w_px, Hpp, -grad)
        dc, dp = dx[:c], dx[c:].reshape(n, 6)
        Hdx_c = lin.Hcc @ dc + np.einsum("nci,ni->c", lin.Hcp, dp)
        Hdx_p = np.einsum("nci,c->ni", lin.Hcp, dc) + np.einsum("nij,nj->ni", lin.Hpp, dp)
        e_px2 = lin.rr + 2.0 * dx @ lin.g + dc @ Hdx_c + np.sum(dp * Hdx_p)
        absorbed = float(np.sum(HK * np.diag(S_cc)))
        new = [s_px, s_rot, s_trans]
        if n_pri:
            e_rob = (lin.xi + dp)[pri]
            d_pp = np.diagonal(S_pp[pri], axis1=1, axis2=2)  # shape (n_pri, 6)
            tr_rot = float(np.sum(d_pp[:, :3])) / s_rot ** 2
            tr_trans = float(np.sum(d_pp[:, 3:])) / s_trans ** 2
            absorbed += tr_rot + tr_trans
            if estimate_robot:
                for g, (part, tr, floor) in enumerate(((slice(0, 3), tr_rot, ROBOT_SIGMA_ROT_FLOOR_RAD),
                                                       (slice(3, 6), tr_trans, ROBOT_SIGMA_TRANS_FLOOR_M))):
                    name = ("rot", "trans")[g]
                    r_g = 3 * n_pri - tr
                    if not pb.resolved[name]:
                        continue
                    if r_g < UNRESOLVED_REDUNDANCY_SHARE * 3 * n_pri:
                        pb.resolved[name] = False  # the camera cannot resolve this robot noise: freeze
                        continue
                    new[1 + g] = max(float(np.sqrt(np.sum(e_rob[:, part] ** 2) / r_g)), floor)
        r_px = lin.n_obs - D + absorbed
        if r_px > 0.5:
            new[0] = max(float(np.sqrt(max(e_px2, 0.0) / r_px)), SIGMA_PX_FLOOR)
        change = max(abs(a / b - 1.0) for a, b in zip(new, (s_px, s_rot, s_trans)))
        s_px, s_rot, s_trans = new
        if change < tol:
            break
    pb.sigma_px, pb.sigma_rot, pb.sigma_trans = s_px, s_rot, s_trans
    return float(np.max(np.abs(np.array([s_px, s_rot, s_trans]) / start - 1.0)))


def _solve_with_vce(pb: _Problem, *, max_outer: int = 5):
    """Gaussian solves alternating with variance-component estimation on each linearisation until
    the sigmas settle. Returns (Sigma_core, {view index: Sigma_robot}) at the final sigmas."""
    pb.resolved = {"rot": True, "trans": True}  # a new set of views may resolve what the last did not
    for _ in range(max_outer):
        pb.solve(robust=False)
        change = _vce_on_linearisation(pb, pb.pixel_linearisation())
        log.debug("VCE: sigma_px %.4f, robot %.5f deg %.5f mm (change %.3g)", pb.sigma_px,
                  np.degrees(pb.sigma_rot), 1000 * pb.sigma_trans, change)
        if change < 0.01:
            break
    g, values, rk = pb.solve(robust=False)
    return pb.covariances(g, values, rk)


# ------------------------------------------------------------------------------ start
def _seed_score(pb: _Problem, T_x: np.ndarray, T_board: np.ndarray) -> float:
    """Median over the views of each view's median corner residual (px) through the reported robot
    pose: a start that half the views agree with scores low, whatever the other views do."""
    per_view = []
    for i in range(pb.n):
        if len(pb.obj[i]) < pb.o.min_corners:
            continue
        r = chain_residual(T_x=T_x, T_base_end=pb.reported[i], T_board=T_board, invert_robot=pb.invert,
                           intrinsics_vec=pb.k, object_points=pb.obj[i], image_points=pb.img[i],
                           jacobians=False)[0].reshape(-1, 2)
        e = np.linalg.norm(r, axis=1)
        per_view.append(float(np.median(e)) if np.all(np.isfinite(e)) else np.inf)
    return float(np.median(per_view)) if per_view else np.inf


def _best_start(pb: _Problem, mm, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """The given seed, or the closed-form solution (every OpenCV method on every view's PnP pose)
    with the lowest robust score (:func:`_seed_score`) when that is lower. One closed-form method
    can be far off when some robot poses are wrong (Tsai 120 deg off on a 12-view session with one
    wrong pose, where Park was within 1 deg), and the local solves cannot recover from such a start."""
    from ..initial import all_methods, solve_pnp  # OpenCV's closed forms; imported here to keep refine light

    best = (pb.T_x, pb.T_board)
    best_score = _seed_score(pb, *best)
    idx = [i for i in range(pb.n) if len(pb.obj[i]) >= max(pb.o.min_corners, 6)]
    if len(idx) < 3:
        return best
    K = Intrinsics.from_vector(pb.k, intrinsics.width, intrinsics.height)
    try:
        C = np.stack([solve_pnp(pb.obj[i], pb.img[i], K)[0] for i in idx])
    except (HandeyeError, cv2.error, np.linalg.LinAlgError):
        return best
    M = mm.M_from_T_base_end(pb.reported[idx])
    for name, est in all_methods(mm, C, M).items():
        if est.status != "ok" or not (np.all(np.isfinite(est.T_x)) and np.all(np.isfinite(est.T_board))):
            continue
        score = _seed_score(pb, est.T_x, est.T_board)
        if score < best_score:
            log.info("starting the refinement from the %s closed form (median view residual %.3g px; given seed "
                     "%.3g px)", name, score, _seed_score(pb, pb.T_x, pb.T_board))
            best, best_score = (_check_T(est.T_x, f"{name} {mm.x_name}"), _check_T(est.T_board, name)), score
    return best


# ------------------------------------------------------------------------------ refine
def refine(*, mode: str, object_points: np.ndarray, views: Sequence[RefineView], intrinsics: Intrinsics,
           T_x0: np.ndarray, T_board0: np.ndarray, options: RefineOptions = RefineOptions()) -> RefineResult:
    """Refine hand-eye, board, intrinsics and robot poses jointly; see the module docstring.

    Raises ConfigError / InputError for invalid options or inputs; a solve that fails returns a
    result with ``status="failed"`` and a ``failure_reason``.
    """
    t0 = time.perf_counter()
    mm = mounting(mode)
    _check_options(options)
    T_x0 = _check_T(T_x0, f"seed {mm.x_name}")
    T_board0 = _check_T(T_board0, f"seed {mm.board_name}")
    object_points = np.asarray(object_points, float)
    if object_points.ndim != 2 or object_points.shape[1] != 3:
        raise InputError("object_points must be (N, 3)", received=f"shape {object_points.shape}")
    seen = set()
    for v in views:
        if v.view_id in seen:
            raise InputError("duplicate view id in the refinement", received=repr(v.view_id),
                             hint="views are linked by id; give each view a unique id")
        seen.add(v.view_id)
        n = len(np.asarray(v.corner_ids))
        if np.asarray(v.image_points).reshape(-1, 2).shape[0] != n:
            raise InputError(f"view {v.view_id}: corner_ids and image_points differ in length",
                             expected=f"{n} image points", received=str(np.asarray(v.image_points).shape))
        _check_T(v.T_base_end, f"view {v.view_id} T_base_end")
    if len(views) < 3:
        raise InputError("the refinement needs at least 3 views", received=f"{len(views)} views",
                         hint="capture more views with the board visible")

    pb = _Problem(mode=mode, object_points=object_points, views=views, intrinsics=intrinsics,
                  T_x0=T_x0, T_board0=T_board0, options=options)
    if options.closed_form_starts:
        pb.T_x, pb.T_board = _best_start(pb, mm, intrinsics)
    e_before = np.concatenate([pb.view_residual(i, pb.reported[i]) for i in range(pb.n)])
    rms_before = float(np.sqrt(np.mean(np.sum(e_before ** 2, axis=1))))
    sparse = []  # views that cannot even start (the outlier loop re-examines them with reasons)
    for i, vid in enumerate(pb.ids):
        if len(pb.obj[i]) < options.min_corners:
            pb.status[i] = "removed"
            sparse.append(Outlier(vid, "too_few_corners", f"view {vid}: {len(pb.obj[i])} corners, need "
                                  f"{options.min_corners}", size={"n_usable": len(pb.obj[i]),
                                                                  "n_corners": len(pb.obj[i])}))

    def failed(reason: str) -> RefineResult:
        log.warning("refinement failed: %s", reason)
        return _result(pb, mm, "failed", reason, None, None, None, rms_before, T_x0, T_board0, intrinsics, t0,
                       sparse)

    try:
        # start: sigmas from each view's own fit at the seed
        pb.sigma_px = 1.0
        checks0 = [_camera_only_pose(pb, i, pb.P[i]) for i in pb.active()]
        e0 = np.concatenate([c.resid_px for c in checks0 if c.ok]) if checks0 else np.zeros(0)
        if e0.size:
            pb.sigma_px = max(float(np.median(e0)) / RAYLEIGH_MEDIAN, 1e-3)
            checks0 = [replace(c, cov_cam=c.cov_cam * pb.sigma_px ** 2) for c in checks0]  # were for sigma 1 px
        _robust_robot_sigmas(pb, checks0)
        # guard: robust solves, pixel sigma from the median residual in between
        for _ in range(2):
            pb.solve(robust=options.loss != "none")
            pb.sigma_px = _robust_sigma_px(pb)
        dec = None
        if options.outlier_loop:
            seen_keys = []
            S_pp = None
            for rnd in range(options.max_outlier_rounds):
                dec = _decide(pb, robust_robot_sigma=rnd == 0, S_pp=S_pp)
                if seen_keys and dec.key() == seen_keys[-1]:
                    break
                if dec.key() in seen_keys:
                    log.warning("outlier decisions oscillate; keeping the previous set")
                    break
                seen_keys.append(dec.key())
                _apply(pb, dec)
                if len(pb.prior_views()) + (0 if pb.robot_var else len(
                        [i for i in pb.active() if pb.status[i] == "used"])) < 3:
                    return failed(f"only {len(pb.prior_views())} views left whose robot pose agrees with the camera; "
                                  "need 3")
                if rnd == 0 and options.robot_noise == "estimate":
                    # VCE approaches a small robot sigma from above; a robust estimate at the floor
                    # would freeze it there before the data have spoken
                    pb.sigma_rot = max(pb.sigma_rot, np.radians(options.robot_sigma_deg))
                    pb.sigma_trans = max(pb.sigma_trans, options.robot_sigma_mm / 1000.0)
                S_cc, S_pp = _solve_with_vce(pb)
            else:
                log.warning("outlier decisions did not settle in %d rounds", options.max_outlier_rounds)
                dec = _decide(pb, robust_robot_sigma=False, S_pp=S_pp)
        else:
            _robust_robot_sigmas(pb, [_camera_only_pose(pb, i, pb.P[i]) for i in pb.prior_views()])
            g, values, rk = pb.solve(robust=options.loss != "none")
            S_cc, S_pp = pb.covariances(g, values, rk)
    except np.linalg.LinAlgError as err:
        return failed(f"the information matrix is singular ({err}); the views do not constrain all unknowns")
    except RuntimeError as err:  # GTSAM raises RuntimeError (e.g. indeterminant linear system)
        return failed(f"GTSAM: {err}")
    return _result(pb, mm, "ok", "", S_cc, S_pp, dec, rms_before, T_x0, T_board0, intrinsics, t0, sparse)


def _result(pb, mm, status, reason, S_cc, S_pp, dec, rms_before, T_x0, T_board0, intrinsics0, t0,
            sparse=()) -> RefineResult:
    nan6 = np.full((6, 6), np.nan)
    if S_cc is not None:
        cov = 0.5 * (S_cc[:6, :6] + S_cc[:6, :6].T)
    else:
        cov = nan6
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    R = pb.T_x[:3, :3]
    sigma_trans_mm = 1000.0 * np.sqrt(np.diag(R @ cov[3:, 3:] @ R.T))
    intr = Intrinsics.from_vector(pb.k, pb.width, pb.height)
    intr_sigma = {}
    if S_cc is not None:
        for j, fi in enumerate(pb.free):
            intr_sigma[INTRINSIC_NAMES[fi]] = float(np.sqrt(S_cc[12 + j, 12 + j]))
    # working distance: median distance of the board centre along the optical axis
    centre = pb.board_centre
    depths = []
    for i in pb.active():
        M = inv_T(pb.robot_pose(i)) if pb.invert else pb.robot_pose(i)
        T_cb = inv_T(pb.T_x) @ M @ pb.T_board
        depths.append((T_cb[:3, :3] @ centre + T_cb[:3, 3])[2])
    wd = pb.o.working_distance_m if pb.o.working_distance_m is not None else (
        float(np.median(depths)) if depths else float("nan"))
    p_cam = np.array([0.0, 0.0, wd])
    J = R @ np.hstack([-skew(p_cam), np.eye(3)])  # d(point in parent frame)/d xi
    cov_p = J @ cov @ J.T
    per_view, robot_poses = {}, {}
    for i, vid in enumerate(pb.ids):
        res = pb.view_residual(i)
        e = np.linalg.norm(res, axis=1)
        st = pb.status[i]
        used = pb.mask[i] if st != "removed" else np.zeros(len(e), bool)
        d = {"status": st, "n_corners": int(len(e)), "n_used": int(used.sum())}
        if st == "removed" and dec is not None and dec.checks[i].ok:
            e = dec.checks[i].resid_px  # a dropped view: residuals against its own best pose
        sel = e[used] if used.any() else e
        d["rms_px"] = float(np.sqrt(np.mean(sel ** 2))) if sel.size else float("nan")
        d["max_px"] = float(sel.max()) if sel.size else float("nan")
        if dec is not None and np.isfinite(dec.mahalanobis[i]):
            dl = dec.disagreement[i]
            d["robot_vs_camera_rot_deg"] = float(np.degrees(np.linalg.norm(dl[:3])))
            d["robot_vs_camera_trans_mm"] = float(1000.0 * np.linalg.norm(dl[3:]))
            d["robot_vs_camera_mahalanobis"] = float(np.sqrt(dec.mahalanobis[i]))
        per_view[vid] = d
        robot_poses[vid] = pb.robot_pose(i).copy()
    if pb.active():
        e_after = pb.used_corner_residuals()
        rms_after = float(np.sqrt(np.mean(np.sum(e_after ** 2, axis=1))))
    else:
        rms_after = float("nan")
    robot_sigma_mm = 1000.0 * pb.sigma_trans if pb.robot_var else 0.0
    robot_sigma_deg = float(np.degrees(pb.sigma_rot)) if pb.robot_var else 0.0
    return RefineResult(
        status=status, failure_reason=reason, mode=pb.mode, x_name=mm.x_name, board_name=mm.board_name,
        T_x=pb.T_x.copy(), T_board=pb.T_board.copy(), intrinsics=intr, T_x_seed=T_x0.copy(),
        T_board_seed=T_board0.copy(), intrinsics_seed=intrinsics0, robot_poses=robot_poses,
        cov_x_6x6=cov, cov_parametrisation=COV_PARAMETRISATION, sigma_rot_deg=np.degrees(sd[:3]),
        sigma_trans_mm=sigma_trans_mm, correlation_6x6=corr, intrinsics_sigma=intr_sigma,
        working_distance_m=wd, predicted_error_mm=float(1000.0 * np.sqrt(np.trace(cov_p))),
        predicted_error_axes_mm=1000.0 * np.sqrt(np.diag(cov_p)), sigma_px=float(pb.sigma_px),
        robot_sigma_mm=float(robot_sigma_mm), robot_sigma_deg=robot_sigma_deg,
        robot_sigma_resolved=dict(pb.resolved) if pb.o.robot_noise == "estimate" else {},
        rms_px_before=rms_before, rms_px_after=rms_after, per_view=per_view,
        outliers=tuple(dec.outliers) if dec is not None else tuple(sparse), iterations=int(pb.iterations),
        seconds=time.perf_counter() - t0, options=pb.o)
