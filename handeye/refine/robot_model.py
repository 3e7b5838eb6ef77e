"""The refinement's robot error models (pure numpy) and the per-view matrices built from them.

The true flange pose is ``T_reported_i · Exp(u_i)`` in the tangent of :mod:`handeye.frames`. Kinds:
``none`` (exact poses), ``iid`` (independent per view), ``kinematic`` (shared DH offsets ``delta``
with the arm's prior plus encoder noise, ``u_i = J_dh,i · delta + J_q,i · e_i``) and ``joint_space``
(encoder noise only). Joint angles come from the session or from inverse kinematics; a constant tool
offset between the flange and the reported frame is estimated from the views.

See docs/robot_error.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from ..errors import ConfigError, InputError
from ..frames import inv_T, mean_T, se3_adjoint, tangent_difference
from ..kinematics import PARAMETER_NAMES, PRESETS, DHChain, chain_to_dict, default_ik_seeds, load_arm, solve_ik
from .options import RefineOptions, RefineView, refine_preset

LENGTH_PARAMETERS = (0, 2)  # a, d in a DH row (a, alpha, d, theta_offset); the others are angles


@dataclass(frozen=True)
class KinematicRobotModel:
    """The per-view matrices of the ``kinematic`` / ``joint_space`` robot models.

    The per-view matrices of the ``kinematic`` / ``joint_space`` models for n views of an arm with
    m DH parameters (m = 0 for ``joint_space``).
    """

    kind: str  # kinematic | joint_space
    arm: DHChain
    joints: np.ndarray  # (n, n_joints) radians
    joints_source: tuple[str, ...]  # per view: "recorded" | "inverse_kinematics"
    J_dh: np.ndarray  # (n, 6, m): d u_i / d delta
    B: np.ndarray  # (n, 6, 6): J_q J_q^T + ridge, u_i's covariance per unit encoder variance
    dh_sigma: np.ndarray  # (m,) prior sigma of each DH offset (m, rad)
    encoder_sigma_rad: float  # start value (estimate) or value (fixed) of the encoder noise
    T_tool: np.ndarray  # (4,4) reported frame in the flange frame (identity: the flange)
    tool_spread: tuple[
        float, float
    ]  # (rot deg, trans mm): largest departure of an agreeing view's tool offset from T_tool
    joints_disagree: tuple[str, ...] = ()  # ids of views whose joint angles do not give their reported pose

    @property
    def m(self) -> int:
        return int(self.J_dh.shape[2])

    def parameter_names(self) -> list[str]:
        return [f"{p}_{j + 1}" for j in range(self.arm.n_joints) for p in PARAMETER_NAMES][: self.m]


def _arm(o: RefineOptions) -> Optional[DHChain]:
    if o.arm is None:
        return None
    return o.arm if isinstance(o.arm, DHChain) else load_arm(o.arm)


def resolve_kind(o: RefineOptions, views: Sequence[RefineView]) -> str:
    """The robot model of ``o.robot_model`` for these views: None, iid, kinematic or joint_space.

    None | iid | kinematic | joint_space: the model of ``o.robot_model`` for these views. ``auto``
    is ``kinematic`` when an arm is named (views without joint angles get them by inverse kinematics),
    else ``iid``.
    """
    if o.robot_noise == "none":
        return "none"
    if o.robot_model == "auto":
        return "kinematic" if o.arm is not None else "iid"
    if o.robot_model in ("kinematic", "joint_space") and o.arm is None:
        raise ConfigError(
            f"robot_model {o.robot_model} needs the arm's kinematic model",
            expected=f"refine option arm: a preset ({', '.join(PRESETS)}) or a DH table file",
            received="none",
            hint="name the arm (session.yaml robot: rm65) or use robot_model iid",
        )
    return o.robot_model


def _joints(arm: DHChain, views: Sequence[RefineView], reported: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """(n, joints) every view's joint angles (recorded, else by inverse kinematics) and their sources.

    A pose is reached by several configurations of the arm (a UR arm's shoulder, elbow and wrist flips),
    each with its own Jacobians. The one the arm was in: the solution within the joint limits nearest the
    previous view's joints (an arm does not flip between neighbouring views), for the first view nearest
    the arm's home (the preset's ``home``, the configuration its programs run about); an arm without a
    home takes the first solution of the default seeds. A reported pose the arm cannot reach (source
    ``unreachable``) keeps the joints of the view before it, for the robot-pose test to exclude; InputError
    when most are.
    """
    out: list[np.ndarray] = []
    source: list[str] = []
    prev: Optional[np.ndarray] = None
    q: Optional[np.ndarray]
    unreachable: list[tuple[str, np.ndarray]] = []
    for v, T in zip(views, reported, strict=False):
        if v.joint_angles is not None:
            q = np.asarray(v.joint_angles, float).reshape(-1)
            if q.shape != (arm.n_joints,):
                raise InputError(
                    f"view {v.view_id}: {q.size} joint angles for the {arm.n_joints}-joint {arm.name}",
                    expected=f"{arm.n_joints} joint angles (radians)",
                    received=str(q.size),
                    hint="name the arm the session was recorded with",
                )
            out.append(q)
            source.append("recorded")
            prev = q
            continue
        ref = prev if prev is not None else arm.home_rad  # the configuration the arm is in: see below
        home = [arm.home_rad] if arm.home_rad is not None and prev is not None else []  # a seed where prev is far
        q = solve_ik(arm, T, seeds=home + default_ik_seeds(arm, T), nearest=ref)
        if q is None:
            # a pose the arm cannot reach is a wrong pose: the view keeps the joints of the last one reached (its
            # tool offset then disagrees, and the robot-pose test excludes it with its reason); most such views
            # mean the table is not the arm's
            unreachable.append((v.view_id, T))
            out.append(np.zeros(arm.n_joints) if ref is None else np.asarray(ref, float))  # ref: prev, else home
            source.append("unreachable")
            continue
        out.append(q)
        source.append("inverse_kinematics")
        prev = q
    if 2 * len(unreachable) > len(out):
        vid, T = unreachable[0]
        raise InputError(
            f"view {vid}: the {arm.name} cannot reach the reported pose ({len(unreachable)} of {len(out)} views)",
            expected="a pose within the arm's reach and joint limits",
            received=f"flange at {np.round(T[:3, 3], 3).tolist()} m",
            hint="check the arm named for the session, or use robot_model iid",
        )
    return np.array(out), tuple(source)


def build_kinematic_model(
    o: RefineOptions, kind: str, views: Sequence[RefineView], reported: np.ndarray
) -> KinematicRobotModel:
    """The matrices of the ``kinematic`` or ``joint_space`` model at the views' joint angles."""
    arm = _arm(o)
    assert arm is not None, "resolve_kind gives a kinematic model only with an arm"
    cfg = refine_preset()["robot_model"]
    prior = arm.error_prior or (
        float(cfg["dh_length_sigma_mm"]) * 1e-3,
        float(np.radians(cfg["dh_angle_sigma_deg"])),
        float(np.radians(cfg["encoder_sigma_deg"])),
    )
    length_sigma = prior[0] if o.dh_sigma_mm is None else o.dh_sigma_mm * 1e-3
    angle_sigma = prior[1] if o.dh_sigma_deg is None else float(np.radians(o.dh_sigma_deg))
    encoder_sigma = prior[2] if o.encoder_sigma_deg is None else float(np.radians(o.encoder_sigma_deg))
    q, source = _joints(arm, views, reported)
    FK = arm.T_base_end(q).reshape(-1, 4, 4)
    tools = inv_T(FK) @ reported  # shape (n, 4, 4): reported frame in the flange frame, per view
    tol_deg, tol_mm = float(cfg["tool_spread_deg"]), float(cfg["tool_spread_mm"])

    def within(T_ref: np.ndarray) -> np.ndarray:
        d = tangent_difference(T_ref, tools)
        return (np.degrees(np.linalg.norm(d[:, :3], axis=1)) <= tol_deg) & (
            1e3 * np.linalg.norm(d[:, 3:], axis=1) <= tol_mm
        )

    # the tool offset most views agree with (a view whose pose is wrong, not its joints, is left to the
    # robot-pose test); most views disagreeing means the table is not the controller's
    candidates = tools[:: max(1, len(tools) // 15)]  # at most ~15 candidates: O(n) for long sessions
    agree = max((within(T) for T in candidates), key=lambda m: int(m.sum()))
    if 2 * int(agree.sum()) <= len(tools):
        raise ConfigError(
            f"the joint angles do not give the reported poses through the {arm.name}'s table",
            expected=f"one constant tool offset within {tol_mm} mm / {tol_deg} deg for most views",
            received=f"{int(agree.sum())} of {len(tools)} views agree on one",
            hint="name the arm the session was recorded with, or use robot_model iid",
        )
    T_tool = mean_T(tools[agree])
    spread = tangent_difference(T_tool, tools[agree])
    rot_deg = float(np.degrees(np.max(np.linalg.norm(spread[:, :3], axis=1))))
    trans_mm = float(1e3 * np.max(np.linalg.norm(spread[:, 3:], axis=1)))
    disagree = tuple(v.view_id for v, ok in zip(views, agree, strict=False) if not ok)
    Ad = se3_adjoint(inv_T(T_tool))
    n = len(views)
    with_dh = kind == "kinematic"
    m = 4 * arm.n_joints if with_dh else 0
    J_dh = np.zeros((n, 6, m))
    B = np.zeros((n, 6, 6))
    ridge = float(cfg["encoder_ridge"])
    for i in range(n):
        Jq = Ad @ arm.jacobian_joints(q[i])
        B[i] = Jq @ Jq.T + ridge * np.eye(6)
        if with_dh:
            J_dh[i] = Ad @ arm.jacobian_dh(q[i])
    sig = np.tile([length_sigma, angle_sigma, length_sigma, angle_sigma], arm.n_joints)[:m]
    return KinematicRobotModel(
        kind=kind,
        arm=arm,
        joints=q,
        joints_source=source,
        J_dh=J_dh,
        B=B,
        dh_sigma=sig,
        encoder_sigma_rad=encoder_sigma,
        T_tool=T_tool,
        tool_spread=(rot_deg, trans_mm),
        joints_disagree=disagree,
    )


def kinematic_model_dict(
    km: KinematicRobotModel,
    *,
    ids: Sequence[str],
    encoder_sigma_rad: float,
    encoder_estimated: bool,
    encoder_resolved: Optional[bool],
) -> dict[str, Any]:
    """JSON-ready description of a kinematic / joint_space model (``ids``: its views' ids, in its order).

    Kind, arm and DH table, the model's formula, the encoder noise, where the joint angles came from, the
    tool offset and what was estimated; the DH offsets' estimate is :func:`describe_dh`'s.
    """
    return {
        "kind": km.kind,
        "arm": km.arm.name,
        "dh_convention": km.arm.convention,
        "dh_table": chain_to_dict(km.arm),
        "description": (
            "true pose = reported · Exp(J_dh · dh_offset + J_q · encoder_error): shared DH offsets "
            "(estimated with T_x where the views resolve them, held by their prior otherwise) and "
            "encoder noise per joint and view"
            if km.kind == "kinematic"
            else "true pose = reported · Exp(J_q · encoder_error): encoder noise per joint and view"
        ),
        "encoder_sigma_deg": float(np.degrees(encoder_sigma_rad)),
        "encoder_sigma_resolved": encoder_resolved,
        "joint_angles": (
            "recorded"
            if all(s == "recorded" for s in km.joints_source)
            else "inverse kinematics of the reported poses"
            if all(s != "recorded" for s in km.joints_source)
            else "recorded, inverse kinematics for views without them"
        ),
        "joint_angles_rad": {vid: km.joints[i] for i, vid in enumerate(ids)},
        "tool_offset_T_flange_reported": km.T_tool,
        "tool_offset_spread_deg_mm": list(km.tool_spread),
        "joints_disagree_view_ids": list(km.joints_disagree),
        # reported poses the arm cannot reach within its joint limits (their joints are the view's before)
        "unreachable_view_ids": [vid for vid, src in zip(ids, km.joints_source, strict=True) if src == "unreachable"],
        "estimated": (["dh_offset"] if km.m else []) + (["encoder_sigma_deg"] if encoder_estimated else []),
    }


def describe_dh(
    km: KinematicRobotModel,
    delta: np.ndarray,
    S_dd: np.ndarray,
    prior_cov: Optional[np.ndarray] = None,
    *,
    scale: float = 1.0,
    test: Optional[dict[str, Any]] = None,
    scale_dof: Optional[float] = None,
) -> dict[str, Any]:
    """JSON-ready estimate of the DH offsets per joint, with sigmas and prior shares.

    JSON-ready estimate of the DH offsets: per joint (a mm, alpha deg, d mm, theta_offset deg), their
    sigmas, and the share of each offset's prior variance the data removed (0: held by the prior alone,
    1: fixed by the data). ``prior_cov`` (m,m): the prior the offsets were estimated under when it is not the
    arm's own N(0, dh_sigma^2), e.g. an earlier calibration's estimate; the share is measured against it.
    ``dh_prior_sigma`` is the arm's own prior as used (``scale`` times the stated ``dh_prior_sigma_stated``,
    the scale estimated with ``scale_dof`` degrees of freedom when the views contradict the stated prior:
    ``test``, see :func:`handeye.refine.noise._dh_prior_test`); ``dh_prior`` says which prior was used.
    """
    if km.m == 0:
        return {}
    units = np.tile([1e3, np.degrees(1.0), 1e3, np.degrees(1.0)], km.arm.n_joints)
    sd = np.sqrt(np.clip(np.diag(S_dd), 0.0, None))
    prior_var = (scale * km.dh_sigma) ** 2 if prior_cov is None else np.clip(np.diag(prior_cov), 1e-300, None)
    share = 1.0 - np.clip(sd**2 / prior_var, 0.0, 1.0)
    shape = (km.arm.n_joints, 4)

    def sigmas(k: float) -> dict[str, float]:
        return {"length_mm": float(k * km.dh_sigma[0] * 1e3), "angle_deg": float(np.degrees(k * km.dh_sigma[1]))}

    return {
        "dh_columns": ["a_mm", "alpha_deg", "d_mm", "theta_offset_deg"],
        "dh_offset": (delta * units).reshape(shape),
        "dh_offset_sigma": (sd * units).reshape(shape),
        "dh_resolved_share": share.reshape(shape),
        "dh_prior": "the arm's error prior" if prior_cov is None else "an earlier calibration's estimate",
        "dh_prior_sigma": sigmas(scale),
        "dh_prior_sigma_stated": sigmas(1.0),
        "dh_prior_scale": float(scale),
        "dh_prior_test": dict(test or {}),
        "dh_prior_scale_dof": None if scale == 1.0 else scale_dof,
    }
