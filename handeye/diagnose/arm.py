"""Findings about the arm's kinematic model: the DH table the views reject, and poses the arm cannot reach."""

from __future__ import annotations

from typing import Optional

import numpy as np

from .findings import Finding


def arm_table_findings(model: Optional[dict]) -> list:
    """An info finding when the views put the arm further from its DH table than its stated prior allows.

    An info finding when the views put the arm further from its DH table than its stated prior allows
    (the kinematic model widened the prior: :func:`handeye.refine.noise._dh_prior_test`), with the offsets
    most beyond their sigma: the arm's own kinematic calibration is off, which the hand-eye result has taken into
    account.
    """
    if not model or model.get("kind") != "kinematic" or float(model.get("dh_prior_scale") or 1.0) <= 1.0:
        return []
    test, stated = model.get("dh_prior_test") or {}, model.get("dh_prior_sigma_stated") or {}
    off = np.asarray(model.get("dh_offset") if model.get("dh_offset") is not None else [], float)
    sd = np.asarray(model.get("dh_offset_sigma") if model.get("dh_offset_sigma") is not None else [], float)
    cols = list(model.get("dh_columns") or [])
    largest = ""
    if off.ndim == 2 and off.shape == sd.shape and off.size and len(cols) == off.shape[1]:
        z = np.abs(off) / np.where(sd > 0, sd, np.inf)
        top = [np.unravel_index(k, off.shape) for k in np.argsort(-z, axis=None)[:3]]
        largest = "; the offsets most beyond their sigma: " + ", ".join(
            f"{cols[c].split('_')[0]} of joint {j + 1} {off[j, c]:+.2f} {cols[c].rsplit('_', 1)[-1]} "
            f"({z[j, c]:.1f} sigma)"
            for j, c in top
        )
    return [
        Finding(
            "arm_beyond_table",
            "info",
            f"The arm is further from its DH table than its stated tolerance: the robot error model's DH "
            f"prior was widened {float(model['dh_prior_scale']):.2f}x",
            f"the DH offsets the views resolve reject the stated {stated.get('length_mm', float('nan')):.2g} "
            f"mm / {stated.get('angle_deg', float('nan')):.2g} deg (p = {float(test.get('p_value', float('nan'))):.2g}"
            f" at alpha {test.get('alpha', '?')}){largest}; the result's covariance includes the widened prior",
            "nothing for this calibration; if the arm's absolute accuracy matters elsewhere, have its "
            "kinematics calibrated (or give its calibrated DH table with --robot FILE)",
        )
    ]


def unreachable_pose_findings(model: Optional[dict], per_view: Optional[dict]) -> list:
    """A finding for the reported poses the named arm cannot reach within its joint limits.

    Such a pose is wrong, or the arm named is not the one that reported it (its joints were taken from the
    view before, so its error model is not the arm's). Left out of the result by the robot-pose test, the views
    are named (warn); any of them still in the result makes it rest on joints the arm cannot have (fail).
    """
    ids = list((model or {}).get("unreachable_view_ids") or [])
    if not ids:
        return []
    used = [v for v in ids if str(((per_view or {}).get(v) or {}).get("status", "used")) in ("used", "ok")]
    arm = (model or {}).get("arm", "the arm")
    return [
        Finding(
            "arm_cannot_reach",
            "fail" if used else "warn",
            f"The {arm} cannot reach the reported pose of view(s) {', '.join(ids[:12])}",
            f"{len(ids)} reported pose(s) lie beyond the {arm}'s reach or joint limits"
            + (f"; view(s) {', '.join(used[:12])} are still in the result" if used else "; left out of the result"),
            f"check that the session was recorded with the {arm} (--robot, or robot: in the session), and these "
            "views' poses",
            view_ids=tuple(ids),
        )
    ]
