"""What new views share with the install, and the drift test that takes it apart.

:func:`installed_robot_model` rebuilds the install's robot error model, :func:`with_installed_dh` gives
the new views the install's DH offsets as their prior and :func:`shares_dh` says when it does;
:func:`test_refined` tests ``X = X0`` on the refined views, jointly with the intrinsics (and DH offsets)
they share with the install when both results carry the joint covariance.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..camera import INTRINSIC_NAMES
from ..stats import wald_p_value
from .drift import JOINT_DH_KIND, DriftTest, drift_test, joint_drift_test
from .loaded import LoadedResult

log = logging.getLogger(__name__)


def installed_robot_model(installed: LoadedResult) -> dict:
    """RefineOptions for the robot error model of the installed result when it names an arm.

    RefineOptions for the robot error model of the installed result when it names an arm (``calibrate
    --robot`` or session.yaml's ``robot:``): the arm's kinematic model (DH offsets held by the prior the
    install used, encoder noise fixed at the installed value) from the DH table result.json records (or, in
    results written before it did, the shipped preset or DH file it names); {} (the iid model at the
    installed sigmas) otherwise.
    """
    ref = installed.raw.get("refinement") or {}
    rm = ref.get("robot_model") or {}
    if rm.get("kind") != "kinematic" or not rm.get("arm"):
        return {}
    from ..kinematics import PRESETS, chain_from_dict, load_arm

    name = (ref.get("options") or {}).get("arm")  # the preset or DH file the install named, when it named one
    if isinstance(rm.get("dh_table"), dict):
        arm = chain_from_dict(rm["dh_table"], source=f"{installed.source} refinement.robot_model.dh_table")
    elif name in PRESETS or (isinstance(name, str) and Path(name).is_file()):
        arm = load_arm(name)  # type: ignore[arg-type]  # a preset name or a file path here
    else:
        log.warning(
            "the installed result's arm %s is neither recorded as a table nor a shipped preset or DH file "
            "that still exists: verifying with the iid robot model",
            rm["arm"],
        )
        return {}
    out = {"robot_model": "kinematic", "arm": arm}
    if rm.get("encoder_sigma_deg"):
        out["encoder_sigma_deg"] = float(rm["encoder_sigma_deg"])
    prior_sd = rm.get("dh_prior_sigma") or {}
    if prior_sd.get("length_mm") and prior_sd.get("angle_deg"):
        out.update(dh_sigma_mm=float(prior_sd["length_mm"]), dh_sigma_deg=float(prior_sd["angle_deg"]))
    return out


def with_installed_dh(prior, installed: LoadedResult, robot: dict, views: Sequence = ()):
    """``prior`` with the installed arm's estimated DH offsets and their covariance.

    ``prior`` with the installed arm's estimated DH offsets and their covariance (the install's posterior)
    as the new views' DH prior, when the install modelled the same arm kinematically
    (:func:`installed_robot_model`) and recorded them; the arm's own prior otherwise. The arm's systematic
    error is then the install's, not a fresh unknown: the new views see X as precisely as that allows, and
    the test takes the shared offsets apart like the shared intrinsics. Only when the install's views and
    ``views`` carry recorded joint angles: joints from inverse kinematics of a reported pose may be another
    arm configuration than the one that took the view, for which the shared offsets are wrong. Not when the
    session brings its own intrinsics (``prior`` without them): the joint test, which takes shared
    parameters apart, then does not run.
    """
    if prior.intrinsics is None or not shares_dh(installed, robot):
        return prior
    if any(getattr(v, "joint_angles", None) is None for v in views):
        return prior
    dh = installed.dh_joint
    assert dh is not None, "shares_dh: the install recorded its DH offsets"
    return replace(prior, dh_offsets=dh[0], cov_dh=dh[3])


def shares_dh(installed: LoadedResult, robot: Optional[dict] = None) -> bool:
    """Whether a verification with recorded joint angles shares the install's DH offsets.

    Whether a verification with recorded joint angles shares the install's DH offsets
    (:func:`with_installed_dh`): the install recorded them for an arm verify can rebuild
    (``robot``, default :func:`installed_robot_model`) with as many offsets, from recorded joint angles.
    ``verify --plan`` asks the same question, so that it plans against the uncertainty verify will face.
    """
    robot = installed_robot_model(installed) if robot is None else robot
    dh, arm = installed.dh_joint, robot.get("arm")
    return (
        dh is not None
        and robot.get("robot_model") == "kinematic"
        and arm is not None
        and len(dh[0]) == 4 * arm.n_joints
        and installed.joints_recorded
    )


def test_refined(installed: LoadedResult, r, prior, *, min_variance_share: float) -> DriftTest:
    """The test of ``X = X0`` on new views refined (``r``) with X free under ``prior``.

    The test of ``X = X0`` on new views refined (``r``) with X free under ``prior``
    (:func:`handeye.recal.loaded.installed_prior`): :func:`joint_drift_test` when the new views share the
    installed intrinsics (and DH offsets, :func:`with_installed_dh`) and both results carry the joint
    covariance of X and the intrinsics, else :func:`drift_test` (the session's own intrinsics: nothing shared;
    an older result: the installed X covariance added whole, a conservative test).
    """
    assert installed.T_x is not None and installed.cov_x is not None, "installed_prior checked both"
    t = _joint_test(installed, r, prior, min_variance_share) if prior.intrinsics is not None else None
    if t is None:
        t = drift_test(
            cov_installed=installed.cov_x,
            T_x_installed=installed.T_x,
            T_x_new=r.T_x,
            cov_new=r.cov_x_6x6,
            min_variance_share=min_variance_share,
        )
    nu = installed.robot_noise_dof  # the new views' robot noise is the installed estimate too
    return replace(t, p_value=wald_p_value(t.statistic, t.dof, nu), noise_dof=nu) if nu is not None else t


def _joint_test(installed: LoadedResult, r, prior, min_variance_share: float) -> Optional[DriftTest]:
    """:func:`joint_drift_test` of the refinement ``r``.

    :func:`joint_drift_test` of the refinement ``r`` (made under ``prior``), or None when the installed
    result or the refinement lacks the joint covariance of X and the intrinsics, or their free intrinsics
    differ.
    """
    j, jr = installed.cov_x_intrinsics, r.cov_x_intrinsics
    if j is None or jr is None or tuple(jr["intrinsics"]) != j[0] or prior.cov_intrinsics is None:
        return None
    idx = [INTRINSIC_NAMES.index(n) for n in j[0]]
    C_k, K_k = np.asarray(jr["cross_6xk"], float), np.asarray(jr["intrinsics_kxk"], float)
    assert installed.intrinsics is not None, "a joint covariance comes with the intrinsics"
    assert installed.T_x is not None and installed.cov_x is not None, "installed_prior checked both"
    dk = r.intrinsics.as_vector()[idx] - installed.intrinsics.as_vector()[idx]
    cov_xk, cov_kk, cov_k_prior = j[1], j[2], np.asarray(prior.cov_intrinsics)[np.ix_(idx, idx)]
    dh = installed.dh_joint
    shared_dh = prior.dh_offsets is not None and dh is not None and "dh_offsets" in jr
    if shared_dh:
        assert dh is not None, "shared_dh"
        # the arm's DH offsets are shared too (with_installed_dh): appended to the shared parameters
        m = len(dh[0])
        C_k = np.hstack([C_k, np.asarray(jr["cross_6xm"], float)])
        K_k = np.block(
            [
                [K_k, np.asarray(jr["cross_kxm"], float)],
                [np.asarray(jr["cross_kxm"], float).T, np.asarray(jr["dh_mxm"], float)],
            ]
        )
        dk = np.r_[dk, np.asarray(jr["dh_offsets"], float) - dh[0]]
        cov_xk = np.hstack([cov_xk, dh[1]])
        cov_kk = np.block([[cov_kk, dh[2]], [dh[2].T, dh[3]]])
        cov_k_prior = np.block(
            [[cov_k_prior, np.zeros((len(idx), m))], [np.zeros((m, len(idx))), np.asarray(prior.cov_dh, float)]]
        )
    nk = len(dk)
    cov_new = np.zeros((6 + nk, 6 + nk))
    cov_new[:6, :6], cov_new[:6, 6:], cov_new[6:, 6:] = r.cov_x_6x6, C_k, K_k
    cov_new[6:, :6] = cov_new[:6, 6:].T
    try:
        t = joint_drift_test(
            T_x_installed=installed.T_x,
            cov_installed=installed.cov_x,
            cov_xk_installed=cov_xk,
            cov_kk_installed=cov_kk,
            T_x_new=r.T_x,
            dk_new=dk,
            cov_new=cov_new,
            cov_k_prior=cov_k_prior,
            cov_x_prior=prior.cov_x,
            min_variance_share=min_variance_share,
        )
        return replace(t, kind=JOINT_DH_KIND) if shared_dh else t
    except np.linalg.LinAlgError as e:
        log.warning("the joint test of X and the intrinsics failed (%s); testing X alone", e)
        return None
