"""The result section: X (and the board pose) in every form with 95 % intervals, the prior, the sigmas."""

from __future__ import annotations

import re
from typing import Optional

import numpy as np

from ...conventions import pose_forms
from ...frames import quat_wxyz_from_R
from ...results import cov_source_words
from ..observations import as_T
from ..uncertainty import Z95


def matrix_text(T: np.ndarray) -> str:
    """A 4x4 as aligned plain text (ASCII minus, so that it can be copied)."""
    return "\n".join("   ".join(f"{x:+.6f}" for x in row) for row in np.asarray(T, float))


def _result_block(res, T_x, *, T_board, unc, pred, wd, x_name, b_name, parent, board_parent, tracked=False) -> dict:
    """The result section: ``T_x`` (named ``x_name``, child ``cam``, parent ``parent``) in every form.

    Rows of translation, quaternion, rotation vector and Euler angles with the 1-sigma of ``unc`` and
    95 % intervals; ``pred``: the predicted point error at ``wd`` metres; ``T_board`` (``b_name``, in
    ``board_parent``) when the board pose is known (``tracked``: a pose-only session's tracked target).
    """
    f = pose_forms(T_x)
    q = quat_wxyz_from_R(T_x[:3, :3])
    rows = []

    def add(group, comp, unit, val, sig, digits):
        lo = hi = None
        if sig is not None and np.isfinite(sig):
            lo, hi = val - Z95 * sig, val + Z95 * sig
        rows.append(
            {
                "group": group,
                "comp": comp,
                "unit": unit,
                "value": val,
                "sigma": sig,
                "lo": lo,
                "hi": hi,
                "digits": digits,
            }
        )

    t = T_x[:3, 3] * 1e3
    for k, c in enumerate("xyz"):
        add(f"Translation ({parent} frame)", c, "mm", t[k], unc["translation_mm"][k] if unc else None, 2)
    for k, c in enumerate("wxyz"):
        add("Quaternion (w, x, y, z)", c, "", q[k], unc["quaternion_wxyz"][k] if unc else None, 6)
    rv = np.asarray(f["rotvec_deg"], float)
    for k, c in enumerate("xyz"):
        add("Rotation vector (axis × angle)", c, "deg", rv[k], unc["rotvec_deg"][k] if unc else None, 3)
    eu = np.asarray(f["euler_vendor_deg"], float)
    for k, c in enumerate(("rx", "ry", "rz")):
        add("Euler, R = Rz·Ry·Rx (extrinsic x-y-z)", c, "deg", eu[k], unc["euler_vendor_deg"][k] if unc else None, 3)
    out = {
        "name": x_name,
        # the frame's words without result.json's equation: the line below the name states it once
        "meaning": re.sub(r";\s*p_\w+ = \w+ @ p_\w+\.?$", "", str((res.get("frames") or {}).get(x_name, ""))),
        "equation": f"p_{parent} = {x_name} · p_cam",
        "child": "cam",
        "parent": parent,
        "matrix_text": matrix_text(T_x),
        "translation_mm": t.tolist(),
        "quaternion_wxyz": q.tolist(),
        "euler_deg": eu.tolist(),
        "rows": rows,
        "rotvec_rad": list(map(float, f["rotvec_rad"])),
        "vendor_line": f["vendor_pose_line"],
        "quaternion_xyzw": [q[1], q[2], q[3], q[0]],
        "pred": pred,
        "working_distance_m": wd,
        "has_sigma": unc is not None,
    }
    if T_board is not None:
        bf = pose_forms(T_board)
        out["board"] = {
            "name": b_name,
            "noun": "Target" if tracked else "Board",
            "meaning": (
                f"pose of the tracked target in the {board_parent} frame; p_{board_parent} = {b_name} @ p_board"
                if tracked
                else (res.get("frames") or {}).get(b_name, "")
            ),
            "equation": f"p_{board_parent} = {b_name} · p_board",
            "matrix_text": matrix_text(T_board),
            "translation_mm": bf["translation_mm"],
            "euler_deg": bf["euler_vendor_deg"],
            "vendor_line": bf["vendor_pose_line"],
        }
    return out


def _change_rows(d: dict) -> list[dict]:
    """Per axis a change of X with its 1-sigma (a ``prior`` block's update or change)."""
    keys = ("d_trans_mm", "sigma_trans_mm", "d_rot_deg", "sigma_rot_deg")
    vals = [np.asarray(d.get(k) if d.get(k) is not None else [np.nan] * 3, float).reshape(-1)[:3] for k in keys]
    return [{"axis": ax, **{k: float(v[i]) for k, v in zip(keys, vals, strict=False)}} for i, ax in enumerate("xyz")]


def _prior_block(res, x_name) -> Optional[dict]:
    """A ``calibrate --prior`` run (result.json's ``prior``): the earlier result used as the prior.

    A ``calibrate --prior`` run (result.json's ``prior``): the earlier result used as the prior (source, X,
    sigmas), the update the new views made to it, whether they contradict it and which the result is.
    """
    p = res.get("prior")
    if not isinstance(p, dict):
        return None
    T0 = as_T(p.get(p.get("frame") or x_name))
    f = pose_forms(T0) if T0 is not None else None
    test, upd, change = p.get("test") or {}, p.get("update") or {}, p.get("change") or {}
    return {
        "source": p.get("source", ""),
        "frame": p.get("frame") or x_name,
        "covariance_used": cov_source_words(str(p["covariance_used"])) if p.get("covariance_used") else "",
        "intrinsics": p.get("intrinsics", ""),
        "translation_mm": f["translation_mm"] if f else None,
        "euler_deg": f["euler_vendor_deg"] if f else None,
        "sigma_trans_mm": p.get("sigma_trans_mm"),
        "sigma_rot_deg": p.get("sigma_rot_deg"),
        "update_rows": _change_rows(upd) if upd else None,
        "test": test or None,
        "alpha": p.get("alpha"),
        "contradicted": bool(p.get("contradicted")),
        "tested": p.get("tested", True) is not False,
        "used": p.get("used", ""),
        "summary": p.get("summary", ""),
        "change_rows": _change_rows(change) if change else None,
    }


SIGMA_SOURCE_TEXT = {
    "validated": "the validated covariance (the spread of the result over refits without some views), which "
    "exceeds the model's in every direction",
    "model+validated": "the larger of the model's and the validated covariance (the spread over refits without "
    "some views) in each direction",
    "model": "the refinement's model covariance (the refits without some views spread no more than it predicts, "
    "or by no more than chance)",
}


def _uncertainty_block(ref, unc, parent) -> dict:
    corr = ref.get("correlation_6x6")
    src = ref.get("sigma_source")
    val = val if isinstance(val := ref.get("validation"), dict) else {}
    rows = []
    for label, r, t in (
        ("model (refinement)", ref.get("sigma_rot_deg_model"), ref.get("sigma_trans_mm_model")),
        (
            "validated (the folds' spread, shrunk toward the model scaled to it)",
            ref.get("sigma_rot_deg_validated"),
            ref.get("sigma_trans_mm_validated"),
        ),
    ):
        if r is not None and t is not None:
            rows.append({"name": label, "rot": list(r), "trans": list(t)})
    text = (
        SIGMA_SOURCE_TEXT.get(src, SIGMA_SOURCE_TEXT["model"])
        if val.get("status") == "ok"
        else "the refinement's model covariance (not validated"
        + (f": {val['summary']})" if val.get("summary") else ")")
    )
    return {
        "source": src,
        "source_text": text,
        "rule": ref.get("sigma_rule", ""),
        "other_rows": rows,
        "validation_summary": val.get("summary"),
        "sigma_trans_mm": list(unc["translation_mm"]),
        "sigma_rot_deg": list(unc["rot_cam_deg"]),
        "trans_axes": ref.get("sigma_trans_axes", f"{parent} frame"),
        "rot_axes": ref.get("sigma_rot_axes", "camera frame"),
        "parametrisation": ref.get("cov_parametrisation", ""),
        "corr": np.asarray(corr, float).tolist() if corr is not None else None,
        "corr_names": ["ωx", "ωy", "ωz", "vx", "vy", "vz"],
    }
