"""Inputs of the refinement: its options, one view, and their validation.

Defaults come from configs/refine.yaml; validation is done once, at the boundary, with messages that
name the field.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NoReturn, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

from handeye.factors.reprojection import LOSSES

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..config import load_preset
from ..errors import ConfigError, InputError
from ..kinematics import DHChain

INTRINSICS_MODES = ("estimate", "fixed", "prior")
ROBOT_NOISE_MODES = ("estimate", "fixed", "none")
ROBOT_MODELS = ("auto", "iid", "kinematic", "joint_space")  # handeye.refine.robot_model


@functools.lru_cache(maxsize=None)
def refine_preset() -> dict[str, Any]:
    """configs/refine.yaml, parsed once (callers must not change it)."""
    return load_preset("refine")


def _from_preset(*path: str) -> Any:
    def get() -> Any:
        v = refine_preset()
        for k in path:
            v = v[k]
        return v

    return field(default_factory=get)


@dataclass(frozen=True)
class RefineView:
    """One view for the refinement: detected corners and the reported robot pose."""

    view_id: str
    corner_ids: np.ndarray  # (N,) int, index object_points
    image_points: np.ndarray  # (N, 2) pixels
    T_base_end: np.ndarray  # (4, 4) reported robot pose, metres
    joint_angles: Optional[np.ndarray] = None  # (n_joints,) the arm's joint readings (radians), when recorded


@dataclass(frozen=True, eq=False)
class Prior:
    """Gaussian prior knowledge of the hand-eye transform.

    Gaussian prior knowledge of the hand-eye transform (and optionally the intrinsics), e.g. an
    earlier calibration of the same rig.

    ``T_x`` (4,4): the prior's ``T_end_cam`` (eye-in-hand) / ``T_base_cam`` (eye-to-hand); ``cov_x``
    (6,6): its covariance in the GTSAM right tangent of ``T_x`` (``T_x_true = T_x · Exp(xi)``,
    ``xi = (omega [rad], v [m])``, the parametrisation of ``RefineResult.cov_x_6x6``).
    ``intrinsics`` / ``cov_intrinsics`` (9,9) in the order of ``INTRINSIC_NAMES``: a prior on the
    free intrinsics (only their rows and columns are used); it adds to ``intrinsics="prior"``'s
    factory prior when both are given. ``cov_x_intrinsics`` (6,9): the cross-covariance of X's tangent and
    the intrinsics (an earlier calibration's errors of the two are correlated: a principal point error tilts
    X); with it the two priors are one joint Gaussian. ``dh_offsets`` (m,) / ``cov_dh`` (m,m): the kinematic
    robot model's DH offsets (:mod:`handeye.refine.robot_model`, in its order) as an earlier calibration of the
    same arm estimated them; they replace the arm's own prior N(0, error_prior) (used only with that model).
    ``T_board`` / ``cov_board`` (6,6): the board's pose (``T_base_board`` / ``T_end_board``) and its covariance in
    its right tangent, e.g. an earlier calibration's when the board has not moved since (a bumped camera does not
    move it); ``cov_board_intrinsics`` (6,9): its cross-covariance with the intrinsics (one joint Gaussian with
    them; not together with ``cov_x_intrinsics``).
    """

    T_x: np.ndarray
    cov_x: np.ndarray
    intrinsics: Optional[Intrinsics] = None
    cov_intrinsics: Optional[np.ndarray] = None
    cov_x_intrinsics: Optional[np.ndarray] = None
    dh_offsets: Optional[np.ndarray] = None
    cov_dh: Optional[np.ndarray] = None
    T_board: Optional[np.ndarray] = None
    cov_board: Optional[np.ndarray] = None
    cov_board_intrinsics: Optional[np.ndarray] = None


@dataclass(frozen=True)
class RefineOptions:
    """What to estimate and how to decide outliers; thresholds default to configs/refine.yaml."""

    intrinsics: str = "estimate"  # estimate | fixed | prior
    intrinsics_prior_sigma: Optional[tuple[Any, ...]] = None  # 9 sigmas (fx, fy, cx, cy [px], k1, k2, p1, p2, k3)
    fix: tuple[Any, ...] = ()  # names of intrinsics held at their given values, e.g. ("k3", "p1", "p2")
    robot_noise: str = "estimate"  # estimate | fixed | none
    robot_sigma_mm: float = _from_preset("robot_prior", "sigma_mm")  # start value (estimate) or the value (fixed)
    robot_sigma_deg: float = _from_preset("robot_prior", "sigma_deg")
    # robot error model (handeye.refine.robot_model): auto | iid | kinematic | joint_space; auto is kinematic
    # when ``arm`` is named (joint angles from the views, else by inverse kinematics), else iid
    robot_model: str = "auto"
    # the arm's kinematic model: a preset name (kinematics.PRESETS), a DH YAML path, its table or a DHChain
    arm: Union[str, Path, dict[str, Any], DHChain, None] = None
    dh_sigma_mm: Optional[float] = None  # prior sigma of each DH length offset (None: the arm's error_prior)
    dh_sigma_deg: Optional[float] = None  # ... of each DH angle offset
    encoder_sigma_deg: Optional[float] = None  # encoder noise per joint: start (estimate) or value (fixed)
    loss: str = _from_preset("robust", "loss")  # robust loss of the guard solves: huber | cauchy | none
    outlier_loop: bool = True
    working_distance_m: Optional[float] = None  # default: median board distance
    max_iterations: int = _from_preset("solver", "max_iterations")  # per Levenberg-Marquardt solve
    loss_k: float = _from_preset("robust", "loss_k")  # robust threshold, in sigmas
    corner_outlier_sigmas: float = _from_preset("outliers", "corner", "sigmas")  # |e| / sigma_px flagged beyond
    view_outlier_p: float = _from_preset("outliers", "robot_pose", "alpha")  # false alarms per view, robot-pose test
    min_corner_outlier_px: float = _from_preset("outliers", "corner", "min_px")
    min_robot_disagreement_mm: float = _from_preset("outliers", "robot_pose", "min_trans_mm")
    min_robot_disagreement_deg: float = _from_preset("outliers", "robot_pose", "min_rot_deg")
    min_corners: int = _from_preset("outliers", "min_corners")
    max_outlier_rounds: int = _from_preset("outliers", "max_rounds")
    prior: Optional[Prior] = None  # Gaussian prior on T_x (and the free intrinsics), e.g. an earlier calibration


#: ``bad(field, expected, got)``: raises the ConfigError naming an invalid option
BadField = Callable[[str, str, object], NoReturn]


def check_options(o: RefineOptions) -> None:
    def bad(field_name: str, expected: str, got: object) -> NoReturn:
        raise ConfigError(
            f"refine option {field_name} is invalid",
            expected=expected,
            received=repr(got),
            hint=f"fix refine.{field_name} in the config or the command line",
        )

    if o.intrinsics not in INTRINSICS_MODES:
        bad("intrinsics", " | ".join(INTRINSICS_MODES), o.intrinsics)
    if o.robot_noise not in ROBOT_NOISE_MODES:
        bad("robot_noise", " | ".join(ROBOT_NOISE_MODES), o.robot_noise)
    if o.robot_model not in ROBOT_MODELS:
        bad("robot_model", " | ".join(ROBOT_MODELS), o.robot_model)
    for name in ("dh_sigma_mm", "dh_sigma_deg", "encoder_sigma_deg"):
        v = getattr(o, name)
        if v is not None and not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
            bad(name, "a positive number or null", v)
    if o.loss not in LOSSES:
        bad("loss", " | ".join(LOSSES), o.loss)
    unknown = [n for n in o.fix if n not in INTRINSIC_NAMES]
    if unknown:
        bad("fix", "names among " + ", ".join(INTRINSIC_NAMES), tuple(o.fix))
    if o.intrinsics_prior_sigma is not None:
        s = np.asarray(o.intrinsics_prior_sigma, float).reshape(-1)
        if s.size != 9 or not np.all(s > 0):
            bad(
                "intrinsics_prior_sigma",
                "9 positive sigmas (fx, fy, cx, cy, k1, k2, p1, p2, k3)",
                o.intrinsics_prior_sigma,
            )
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
    for name in ("max_iterations", "min_corners", "max_outlier_rounds"):
        v = getattr(o, name)
        if not (isinstance(v, (int, np.integer)) and v >= 1):
            bad(name, "a positive integer", v)
    if o.prior is not None:
        check_prior(o.prior, bad)


def _is_covariance(C: Optional[npt.ArrayLike], n: int) -> bool:
    C = np.asarray(C, float) if C is not None else np.zeros(0)
    if C.shape != (n, n) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T, rtol=1e-8, atol=0.0):
        return False
    try:
        np.linalg.cholesky(0.5 * (C + C.T))
    except np.linalg.LinAlgError:
        return False
    return True


def check_prior(p: "Prior", bad: BadField) -> None:
    """A prior's shapes and covariances (symmetric positive definite); ``bad(field, expected, got)`` raises."""
    if not isinstance(p, Prior):
        bad("prior", "a handeye.refine.options.Prior", type(p).__name__)
    if np.shape(p.T_x) != (4, 4):
        bad("prior.T_x", "a rigid 4x4 transform", np.shape(p.T_x))
    if not _is_covariance(p.cov_x, 6):
        bad("prior.cov_x", "a symmetric positive definite 6x6 covariance (rad^2, m^2)", np.shape(p.cov_x))
    if (p.intrinsics is None) != (p.cov_intrinsics is None):
        bad("prior.cov_intrinsics", "intrinsics and cov_intrinsics both given or both None", "only one of them")
    if p.cov_intrinsics is not None and not _is_covariance(p.cov_intrinsics, len(INTRINSIC_NAMES)):
        bad(
            "prior.cov_intrinsics",
            "a symmetric positive definite 9x9 covariance in the order " + ", ".join(INTRINSIC_NAMES),
            np.shape(p.cov_intrinsics),
        )
    if (p.dh_offsets is None) != (p.cov_dh is None):
        bad("prior.cov_dh", "dh_offsets and cov_dh both given or both None", "only one of them")
    if p.dh_offsets is not None and (
        np.ndim(p.dh_offsets) != 1 or not _is_covariance(p.cov_dh, int(np.size(p.dh_offsets)))
    ):
        bad(
            "prior.cov_dh",
            "DH offsets (m,) with a symmetric positive definite (m,m) covariance",
            f"{np.shape(p.dh_offsets)} and {np.shape(p.cov_dh)}",  # type: ignore[arg-type]  # np.shape(None) is ()
        )
    if p.cov_x_intrinsics is not None:
        _check_joint_with_intrinsics(bad, "cov_x_intrinsics", "X", p.cov_x, p.cov_x_intrinsics, p.cov_intrinsics)
    if (p.T_board is None) != (p.cov_board is None):
        bad("prior.cov_board", "T_board and cov_board both given or both None", "only one of them")
    if p.cov_board is not None and not _is_covariance(p.cov_board, 6):
        bad("prior.cov_board", "a symmetric positive definite 6x6 covariance", np.shape(p.cov_board))
    if p.cov_board_intrinsics is not None:
        if p.cov_x_intrinsics is not None:
            bad(
                "prior.cov_board_intrinsics",
                "one joint prior with the intrinsics: X's or the board's",
                "both cov_x_intrinsics and cov_board_intrinsics",
            )
        _check_joint_with_intrinsics(
            bad, "cov_board_intrinsics", "the board", p.cov_board, p.cov_board_intrinsics, p.cov_intrinsics
        )


def _check_joint_with_intrinsics(
    bad: BadField,
    field_name: str,
    pose: str,
    cov_pose: Optional[np.ndarray],
    cross: np.ndarray,
    cov_k: Optional[np.ndarray],
) -> None:
    """``cross`` (6,9) of a pose prior (covariance ``cov_pose``) with the intrinsics prior.

    ``cross`` (6,9) of a pose prior (covariance ``cov_pose``) with the intrinsics prior (``cov_k``): given with
    both, and keeping their joint covariance positive definite.
    """
    nk = len(INTRINSIC_NAMES)
    if cov_pose is None or cov_k is None or np.shape(cross) != (6, nk):
        bad(
            f"prior.{field_name}",
            f"a 6x{nk} cross-covariance of {pose} and the intrinsics, with its covariance and cov_intrinsics",
            np.shape(cross),
        )
    joint = np.block(
        [
            [np.asarray(cov_pose, float), np.asarray(cross, float)],
            [np.asarray(cross, float).T, np.asarray(cov_k, float)],
        ]
    )
    if not _is_covariance(joint, 6 + nk):
        bad(
            f"prior.{field_name}",
            f"a cross-covariance that keeps the joint covariance of {pose} and the intrinsics positive definite",
            "a joint covariance that is not",
        )


def check_T(T: npt.ArrayLike, what: str) -> np.ndarray:
    """A rigid 4x4 transform, its rotation re-orthonormalised (inputs rounded to a few decimals)."""
    return (
        check_T_stack(np.asarray(T, dtype=float)[None], [what])[0]
        if np.shape(T) == (4, 4)
        else _not_rigid(what, np.shape(T))
    )


def _not_rigid(what: str, shape: tuple[int, ...]) -> NoReturn:
    raise InputError(
        f"{what} is not a rigid 4x4 transform",
        expected="(4,4) with a rotation block and last row 0 0 0 1",
        received=f"shape {shape}",
        hint="check the seed / pose conversion",
    )


def check_T_stack(Ts: np.ndarray, whats: Sequence[str]) -> np.ndarray:
    """:func:`check_T` of (n,4,4) transforms at once; ``whats`` names each one for the message."""
    Ts = np.asarray(Ts, dtype=float)
    R = Ts[:, :3, :3]
    finite = np.all(np.isfinite(Ts), axis=(1, 2))
    R0 = np.where(finite[:, None, None], R, np.eye(3))
    # a rotation to 1e-3 (is_rotation's test), and the last row 0 0 0 1
    ortho = np.all(np.abs(np.swapaxes(R0, 1, 2) @ R0 - np.eye(3)) <= 1e-3, axis=(1, 2))
    proper = np.abs(np.linalg.det(R0) - 1.0) < 1e-3
    last = np.all(np.isclose(Ts[:, 3], [0.0, 0.0, 0.0, 1.0]), axis=1)
    bad = ~(finite & ortho & proper & last)
    if bad.any():
        _not_rigid(list(whats)[int(np.flatnonzero(bad)[0])], Ts.shape[1:])
    U, _, Vt = np.linalg.svd(R)  # nearest rotations
    D = np.ones((len(Ts), 3))
    D[:, 2] = np.linalg.det(U @ Vt)
    out = Ts.copy()
    out[:, :3, :3] = (U * D[:, None, :]) @ Vt
    out[:, 3] = [0.0, 0.0, 0.0, 1.0]
    return out


def check_inputs(object_points: npt.ArrayLike, views: Sequence[RefineView]) -> tuple[np.ndarray, np.ndarray]:
    """Validate the board points (N,3) and the views.

    Validate the board points (N,3) and the views (unique ids, matching lengths, rigid poses);
    returns the board points as float and the reported robot poses (n,4,4), re-orthonormalised.
    """
    object_points = np.asarray(object_points, float)
    if object_points.ndim != 2 or object_points.shape[1] != 3:
        raise InputError("object_points must be (N, 3)", received=f"shape {object_points.shape}")
    seen: set[str] = set()
    for v in views:
        if v.view_id in seen:
            raise InputError(
                "duplicate view id in the refinement",
                received=repr(v.view_id),
                hint="views are linked by id; give each view a unique id",
            )
        seen.add(v.view_id)
        n = len(np.asarray(v.corner_ids))
        if np.asarray(v.image_points).reshape(-1, 2).shape[0] != n:
            raise InputError(
                f"view {v.view_id}: corner_ids and image_points differ in length",
                expected=f"{n} image points",
                received=str(np.asarray(v.image_points).shape),
            )
        if np.shape(v.T_base_end) != (4, 4):
            _not_rigid(f"view {v.view_id} T_base_end", np.shape(v.T_base_end))
    if len(views) < 3:
        raise InputError(
            "the refinement needs at least 3 views",
            received=f"{len(views)} views",
            hint="capture more views with the board visible",
        )
    reported = check_T_stack(
        np.stack([np.asarray(v.T_base_end, float) for v in views]), [f"view {v.view_id} T_base_end" for v in views]
    )
    return object_points, reported
