"""The refinement's result: what it found, how sure it is, and every outlier decision with its reason."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..mounting import mounting
from ..output import plain
from ..stats import estimated_parts_region_factor
from .covariance import COV_BOARD_PARAMETRISATION, COV_PARAMETRISATION, N_POSES, hand_eye_uncertainty
from .options import RefineOptions
from .robot_model import describe_dh, kinematic_model_dict
from .tracker_dof import REGION_P

if TYPE_CHECKING:
    from .outliers import Decision
    from .problem import Problem


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
    robot_poses: dict[str, Any]  # view_id -> refined T_base_end (4,4)
    cov_x_6x6: np.ndarray
    cov_parametrisation: str
    sigma_rot_deg: np.ndarray  # (3,) about the camera axes
    sigma_trans_mm: np.ndarray  # (3,) translation of T_x along the parent frame's axes
    correlation_6x6: np.ndarray
    intrinsics_sigma: dict[str, Any]  # name -> sigma of the free intrinsics
    working_distance_m: float
    predicted_error_mm: float  # RMS 3-D error of a point on the optical axis at the working distance
    predicted_error_axes_mm: np.ndarray  # (3,) per parent-frame axis
    sigma_px: float
    robot_sigma_mm: float
    robot_sigma_deg: float
    robot_sigma_resolved: dict[
        str, Any
    ]  # {"rot": bool, "trans": bool}; False: below what the camera resolves (an upper value)
    rms_px_before: float
    rms_px_after: float
    per_view: dict[str, Any]  # view_id -> dict(rms_px, max_px, n_corners, n_used, status, robot disagreement)
    outliers: tuple[Any, ...]  # tuple[Outlier, ...]
    iterations: int
    seconds: float
    start_method: str = "given"  # the start the refinement used: "given" (T_x0, T_board0) or a closed form
    options: RefineOptions = RefineOptions()
    # the robot error model (handeye.refine.robot_model): kind none | iid | joint_space | kinematic, its
    # parameters, and what was estimated (:func:`robot_model_dict`)
    robot_model: dict[str, Any] = field(default_factory=dict)
    # marginal covariance (6,6) of T_board (T_base_board / T_end_board): right tangent, rotation first, along
    # the board frame's axes (COV_BOARD_PARAMETRISATION); None when the refinement failed
    cov_board_6x6: Optional[np.ndarray] = None
    # the joint marginal covariance of T_x and the free intrinsics: {"intrinsics": names in INTRINSIC_NAMES
    # order, "cross_6xk": cov(xi_x, k) (6,nk), "intrinsics_kxk": cov(k) (nk,nk), "cross_board_6xk":
    # cov(xi_board, k) (6,nk) (the board's own block is cov_board_6x6); with the kinematic robot model
    # also "dh_offsets" (m,), "cross_6xm", "cross_kxm", "dh_mxm"}; None when failed or none free
    cov_x_intrinsics: Optional[dict[str, Any]] = None
    # degrees of freedom (redundancy) of each robot sigma the variance-component estimation estimated
    # ({"rot": r, "trans": r} or {"joint": r}, plus "dh_scale" where the views widened the arm's DH prior);
    # empty when none was estimated or resolved
    robot_noise_dof: dict[str, Any] = field(default_factory=dict)
    # Satterthwaite's degrees of freedom of X's covariance over the estimated robot noise levels, and the factor
    # the plug-in covariance of X was multiplied by for them (:func:`x_dof_factor`); None and 1 when none estimated
    cov_x_noise_dof: Optional[float] = None
    cov_x_dof_factor: float = 1.0
    cov_x_dof_method: str = ""  # how the factor was found: satterthwaite | resampled ("" when 1)
    #: why a failed refinement failed, for programs: "too_few_robot_poses" (fewer than 3 views keep a robot
    #: pose that agrees with the camera), "singular", "solver"; empty when it did not fail
    failure_code: str = ""

    @property
    def used_view_ids(self) -> list[Any]:
        return [v for v, d in self.per_view.items() if d["status"] == "used"]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready content for result.json (nested lists, names with units)."""
        parent = mounting(self.mode).fixed_frame
        return plain(
            {
                "status": self.status,
                "failure_reason": self.failure_reason,
                "mode": self.mode,
                "x_name": self.x_name,
                self.x_name: self.T_x,
                "board_name": self.board_name,
                self.board_name: self.T_board,
                "intrinsics": self.intrinsics.to_dict(),
                "intrinsics_sigma": self.intrinsics_sigma,
                "seed": {
                    self.x_name: self.T_x_seed,
                    self.board_name: self.T_board_seed,
                    "intrinsics": self.intrinsics_seed.to_dict(),
                },
                "start_method": self.start_method,
                "cov_x_6x6": self.cov_x_6x6,
                "cov_parametrisation": self.cov_parametrisation,
                "cov_board_6x6": self.cov_board_6x6,
                "cov_board_parametrisation": COV_BOARD_PARAMETRISATION,
                "cov_x_intrinsics": self.cov_x_intrinsics,
                "correlation_6x6": self.correlation_6x6,
                "sigma_rot_deg": self.sigma_rot_deg,
                "sigma_rot_axes": "camera frame (right perturbation)",
                "sigma_trans_mm": self.sigma_trans_mm,
                "sigma_trans_axes": f"{parent} frame (translation vector of {self.x_name})",
                "working_distance_m": self.working_distance_m,
                "predicted_error_mm": self.predicted_error_mm,
                "predicted_error_definition": (
                    "RMS 3-D error (sqrt of the covariance trace) of a point on the optical "
                    f"axis at working_distance_m, mapped into the {parent} frame by "
                    f"{self.x_name}"
                ),
                "predicted_error_axes_mm": self.predicted_error_axes_mm,
                "sigma_px": self.sigma_px,
                "robot_sigma_mm": self.robot_sigma_mm,
                "robot_sigma_deg": self.robot_sigma_deg,
                "robot_sigma_resolved": self.robot_sigma_resolved,
                "robot_noise_dof": self.robot_noise_dof,
                "cov_x_noise_dof": self.cov_x_noise_dof,
                "cov_x_dof_factor": self.cov_x_dof_factor,
                "cov_x_dof_method": self.cov_x_dof_method or None,
                "robot_noise_model": self.options.robot_noise,
                "robot_model": self.robot_model,
                "rms_px_before": self.rms_px_before,
                "rms_px_after": self.rms_px_after,
                "per_view": self.per_view,
                "outliers": [o.to_dict() for o in self.outliers],
                "robot_poses_refined_T_base_end": self.robot_poses,
                "iterations": self.iterations,
                "seconds": self.seconds,
                "options": _options_dict(self.options),
            }
        )


def _options_dict(o: RefineOptions) -> dict[str, Any]:
    d = asdict(o)
    if o.arm is not None and not isinstance(o.arm, str):  # a DHChain: its name (the table is in robot_model)
        d["arm"] = getattr(o.arm, "name", str(o.arm))
    return d


def robot_model_dict(pb: "Problem", S_cc: Optional[np.ndarray]) -> dict[str, Any]:
    """JSON-ready description of the robot error model of a solved problem.

    JSON-ready description of the robot error model of a solved problem (``S_cc``: its core covariance,
    None when it failed): kind, parameters and what was estimated.
    """
    estimated = pb.o.robot_noise == "estimate"
    if pb.kind == "none":
        return {"kind": "none", "description": "reported robot poses taken as exact"}
    if pb.kin is None:
        return {
            "kind": "iid",
            "description": "independent Gaussian error per view and axis, end frame",
            "sigma_mm": 1000.0 * pb.sigma_trans,
            "sigma_deg": float(np.degrees(pb.sigma_rot)),
            "estimated": ["sigma_mm", "sigma_deg"] if estimated else [],
            "resolved": dict(pb.resolved) if estimated else {},
        }
    km = pb.kin
    d = kinematic_model_dict(
        km,
        ids=pb.ids,
        encoder_sigma_rad=pb.sigma_q,
        encoder_estimated=estimated,
        encoder_resolved=bool(pb.resolved.get("joint", True)) if estimated else None,
    )
    if km.m:
        S_dd = pb.S_dd if S_cc is None else S_cc[pb.dh_slice, pb.dh_slice]
        d.update(
            describe_dh(
                km,
                pb.dh,
                S_dd,
                pb.prior_dh[1] if pb.prior_dh_earlier else None,
                scale=pb.dh_scale,
                test=pb.dh_scale_test,
                scale_dof=pb.dh_scale_dof,
            )
        )
        if pb.dh_scale != 1.0:
            d["estimated"].append("dh_prior_scale")
    return d


def _equivalent_robot_sigmas(pb: "Problem") -> tuple[float, float]:
    """(mm, deg): the robot sigma per axis, or its RMS equivalent for the kinematic models.

    (mm, deg): the robot sigma per axis, or for the kinematic models the RMS per axis of each view's
    encoder-noise covariance over the views.
    """
    if not pb.robot_var:
        return 0.0, 0.0
    if pb.kin is None:
        return 1000.0 * pb.sigma_trans, float(np.degrees(pb.sigma_rot))
    d = np.diagonal(pb.robot_cov(range(pb.n)), axis1=1, axis2=2)
    return 1000.0 * float(np.sqrt(np.mean(d[:, 3:]))), float(np.degrees(np.sqrt(np.mean(d[:, :3]))))


def _resolved(pb: "Problem") -> dict[str, Any]:
    if pb.o.robot_noise != "estimate":
        return {}
    if pb.kin is None:
        return dict(pb.resolved)
    j = bool(pb.resolved.get("joint", True))
    return {"rot": j, "trans": j, "joint": j}


def _working_distance(pb: "Problem") -> float:
    """The configured working distance, else the median depth of the board centre over the views."""
    if pb.o.working_distance_m is not None:
        return float(pb.o.working_distance_m)
    depths = []
    for i in pb.active():
        T_cb = pb.mounting.predict_T_cam_board(pb.T_x, pb.T_board, pb.robot_pose(i))
        depths.append((T_cb[:3, :3] @ pb.board_centre + T_cb[:3, 3])[2])
    return float(np.median(depths)) if depths else float("nan")


def _per_view(pb: "Problem", dec: Optional["Decision"]) -> dict[str, Any]:
    per_view = {}
    e_all = pb.per_view(np.linalg.norm(pb.corner_residuals(), axis=1))
    for i, vid in enumerate(pb.ids):
        e = e_all[i]
        st = pb.status[i]
        used = pb.mask[i] if st != "removed" else np.zeros(len(e), bool)
        d = {"status": st, "n_corners": int(len(e)), "n_used": int(used.sum())}
        if st == "removed" and dec is not None and dec.checks[i].ok:
            e = dec.checks[i].resid_px  # a dropped view: residuals against its own best pose
        sel = e[used] if used.any() else e
        d["rms_px"] = float(np.sqrt(np.mean(sel**2))) if sel.size else float("nan")
        d["max_px"] = float(sel.max()) if sel.size else float("nan")
        if dec is not None and np.isfinite(dec.robot_test.statistic[i]):
            d["robot_vs_camera_rot_deg"] = float(dec.robot_test.rot_deg[i])
            d["robot_vs_camera_trans_mm"] = float(dec.robot_test.trans_mm[i])
            d["robot_vs_camera_mahalanobis"] = float(dec.robot_test.distance[i])
        per_view[vid] = d
    return per_view


def build_result(
    pb: "Problem",
    *,
    status: str,
    reason: str,
    S_cc: Optional[np.ndarray],
    dec: Optional["Decision"],
    rms_before: float,
    T_x0: np.ndarray,
    T_board0: np.ndarray,
    intrinsics0: Intrinsics,
    t0: float,
    outliers: tuple[Any, ...],
    start_method: str,
    failure_code: str = "",
) -> RefineResult:
    """The result from the final state of the problem and the core covariance ``S_cc`` (None: failed).

    With robot noise levels estimated, X's rows and columns of ``S_cc`` are scaled by the square root of
    :func:`x_dof_factor`'s factor first, so X's covariance and its joint one with the intrinsics take it.
    """
    nu, factor = x_dof_factor(pb) if S_cc is not None else (None, 1.0)
    if factor != 1.0:
        assert S_cc is not None, "a factor only with a covariance"
        d = np.ones(len(S_cc))
        d[:6] = np.sqrt(factor)
        S_cc = S_cc * np.outer(d, d)
    wd = _working_distance(pb)
    unc = hand_eye_uncertainty(None if S_cc is None else S_cc[:6, :6], pb.T_x, wd)
    intr_sigma = (
        {}
        if S_cc is None
        else {INTRINSIC_NAMES[fi]: float(np.sqrt(S_cc[N_POSES + j, N_POSES + j])) for j, fi in enumerate(pb.free)}
    )
    robot_sigma_mm, robot_sigma_deg = _equivalent_robot_sigmas(pb)
    rms_after = float("nan")
    if pb.active():
        rms_after = float(np.sqrt(np.mean(np.sum(pb.used_corner_residuals() ** 2, axis=1))))
    return RefineResult(
        status=status,
        failure_reason=reason,
        mode=pb.mode,
        x_name=pb.mounting.x_name,
        board_name=pb.mounting.board_name,
        T_x=pb.T_x.copy(),
        T_board=pb.T_board.copy(),
        intrinsics=Intrinsics.from_vector(pb.k, pb.width, pb.height),
        T_x_seed=T_x0.copy(),
        T_board_seed=T_board0.copy(),
        intrinsics_seed=intrinsics0,
        robot_poses={vid: pb.robot_pose(i).copy() for i, vid in enumerate(pb.ids)},
        cov_x_6x6=unc.cov_x_6x6,
        cov_parametrisation=COV_PARAMETRISATION,
        sigma_rot_deg=unc.sigma_rot_deg,
        sigma_trans_mm=unc.sigma_trans_mm,
        correlation_6x6=unc.correlation_6x6,
        intrinsics_sigma=intr_sigma,
        working_distance_m=wd,
        predicted_error_mm=unc.predicted_error_mm,
        predicted_error_axes_mm=unc.predicted_error_axes_mm,
        sigma_px=float(pb.sigma_px),
        robot_sigma_mm=robot_sigma_mm,
        robot_sigma_deg=robot_sigma_deg,
        robot_sigma_resolved=_resolved(pb),
        rms_px_before=rms_before,
        rms_px_after=rms_after,
        per_view=_per_view(pb, dec),
        outliers=tuple(outliers),
        iterations=int(pb.iterations),
        seconds=time.perf_counter() - t0,
        start_method=start_method,
        failure_code=failure_code,
        options=pb.o,
        robot_model=robot_model_dict(pb, S_cc),
        cov_board_6x6=None if S_cc is None else 0.5 * (S_cc[6:N_POSES, 6:N_POSES] + S_cc[6:N_POSES, 6:N_POSES].T),
        cov_x_intrinsics=_x_intrinsics_covariance(pb, S_cc),
        robot_noise_dof=dict(pb.noise_dof) if pb.o.robot_noise == "estimate" else {},
        cov_x_noise_dof=nu,
        cov_x_dof_factor=factor,
        cov_x_dof_method="" if nu is None else "satterthwaite",
    )


def x_dof_factor(pb: "Problem") -> tuple[Optional[float], float]:
    """(nu, factor) of X's covariance when robot noise levels were estimated from the views.

    The plug-in covariance treats the estimated sigmas as known; with them estimated, X's Wald statistic is
    about ``6 F(6, nu)`` rather than chi-square(6), with Satterthwaite's ``nu`` over each estimated level's part
    of X's covariance (``pb.noise_parts_x``) and its degrees of freedom (``pb.noise_dof``); the rest (the pixel
    noise, known from thousands of corners, and the priors) counts as known. ``factor``: the ratio of the 95 %
    points (:func:`handeye.stats.estimated_parts_region_factor`), as for a pose-only result's tracker sigmas
    (:mod:`.tracker_dof`). (None, 1.0) when no level was estimated.
    """
    dof = pb.noise_dof if pb.o.robot_noise == "estimate" else {}
    if pb.noise_parts_x is None:
        return None, 1.0
    S_x, parts = pb.noise_parts_x
    names = [g for g in dof if g in parts]
    return estimated_parts_region_factor(S_x, [parts[g] for g in names], [float(dof[g]) for g in names], p=REGION_P)


def _x_intrinsics_covariance(pb: "Problem", S_cc: Optional[np.ndarray]) -> Optional[dict[str, Any]]:
    """The joint marginal covariance of T_x's tangent and the free intrinsics.

    The joint marginal covariance of T_x's tangent and the free intrinsics (``cov_x_intrinsics``), with the
    kinematic robot model's DH offsets (their estimate and covariance with both) when it has them.
    """
    nk = len(pb.free)
    if S_cc is None or nk == 0:
        return None
    k = slice(N_POSES, N_POSES + nk)
    S_kk = S_cc[k, k]
    out = {
        "intrinsics": [INTRINSIC_NAMES[fi] for fi in pb.free],
        "cross_6xk": S_cc[:6, k].copy(),
        "intrinsics_kxk": 0.5 * (S_kk + S_kk.T),
        "cross_board_6xk": S_cc[6:N_POSES, k].copy(),
    }
    if pb.m_dh:  # the kinematic model's DH offsets (SI units, the model's order) and their covariance with both
        d = pb.dh_slice
        S_dd = S_cc[d, d]
        out.update(
            dh_offsets=pb.dh.copy(),
            cross_6xm=S_cc[:6, d].copy(),
            cross_kxm=S_cc[k, d].copy(),
            dh_mxm=0.5 * (S_dd + S_dd.T),
        )
    return out
