"""The models behind the result: the camera intrinsics, the pixel, tracker and robot noise, the robot error model."""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..formatting import num
from .result import SIGMA_SOURCE_TEXT
from .values import _num


def _intrinsics_rows(intr, sig, res, *, model_sigma=None) -> Optional[dict]:
    """The intrinsics with their (verdict) sigma ``sig`` and the model's ``model_sigma`` beside it."""
    if not intr:
        return None
    sig = sig or {}
    model_sigma = model_sigma or {}
    rows = []
    for k, unit in (("fx", "px"), ("fy", "px"), ("cx", "px"), ("cy", "px")):
        if k in intr:
            rows.append(
                {"name": k, "unit": unit, "value": intr[k], "sigma": sig.get(k), "sigma_model": model_sigma.get(k)}
            )
    d = intr.get("dist") or {}
    if isinstance(d, dict):
        for k in ("k1", "k2", "p1", "p2", "k3"):
            if k in d:
                rows.append(
                    {"name": k, "unit": "", "value": d[k], "sigma": sig.get(k), "sigma_model": model_sigma.get(k)}
                )
    given = res.get("intrinsics") or {}
    ref = ref if isinstance(ref := res.get("refinement"), dict) else {}
    return {
        "rows": rows,
        "source": given.get("source", ""),
        "rms": given.get("calibrate_camera_rms_px"),
        "size": intr.get("image_size"),
        "refined": bool(sig),
        "sigma_source": ref.get("intrinsics_sigma_source") if ref.get("intrinsics_sigma_verdict") else None,
        "sigma_source_text": SIGMA_SOURCE_TEXT.get(ref.get("intrinsics_sigma_source"), ""),  # type: ignore[arg-type]
    }


def _plain_text(v) -> str:
    """A parameter of the robot model as one short line (numbers to 4 significant digits)."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, (int, float)):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        if len(v) > 8 and all(isinstance(x, (int, float)) for x in v):
            return f"{len(v)} values, largest magnitude {max(abs(float(x)) for x in v):.4g}"
        return ", ".join(_plain_text(x) for x in v)
    if isinstance(v, dict):
        return "; ".join(f"{a}: {_plain_text(b)}" for a, b in v.items())
    return str(v)


def _robot_model(ref) -> Optional[dict]:
    """The refinement's robot error model.

    The refinement's robot error model (``refinement.robot_model``: kind and its parameters), else the
    robot noise model's name with its estimated sigmas.
    """
    if not ref:
        return None
    rm = ref.get("robot_model")
    if isinstance(rm, dict) and rm.get("kind") in ("kinematic", "joint_space"):
        return {"kind": str(rm["kind"]), "items": _kinematic_items(rm)}
    acc = ref.get("robot_accuracy")
    stated = (
        [
            {
                "name": "stated accuracy",
                "value": f"{_num(acc.get('sigma_mm')):.3f} mm / {_num(acc.get('sigma_deg')):.4f} deg per axis of "
                "the flange pose, the same over the workspace: an error the data cannot show, in the verdict "
                f"covariance ({_plain_text(acc.get('frame', ''))})",
            }
        ]
        if isinstance(acc, dict)
        else []
    )
    if isinstance(rm, dict) and rm:
        items = []
        said = {"kind", "sigma_mm", "sigma_deg", "estimated", "resolved"}
        if "sigma_mm" in rm or "sigma_deg" in rm:  # an iid model's two sigmas, in words
            est = set(rm.get("estimated") or [])
            how = "estimated from the data" if {"sigma_mm", "sigma_deg"} <= est else "as given" if not est else ""
            got = rm.get("resolved")
            res: dict = got if isinstance(got, dict) else {}
            unresolved = [w for k, w in (("rot", "rotation"), ("trans", "translation")) if res.get(k) is False]
            items.append(
                {
                    "name": "sigma per axis and view",
                    "value": f"{num(_num(rm.get('sigma_mm')), 3)} mm / {num(_num(rm.get('sigma_deg')), 4)} deg"
                    + (f", {how}" if how else "")
                    + (
                        f" (the camera cannot resolve the {' and the '.join(unresolved)} sigma: it is held)"
                        if unresolved
                        else ""
                    ),
                }
            )
        for k, v in rm.items():
            if k in said:
                continue
            items.append({"name": str(k).replace("_", " "), "value": _plain_text(v)})
        return {"kind": str(rm.get("kind", "?")), "items": items + stated}
    return {
        "kind": str(ref.get("robot_noise_model") or "iid"),
        "items": [
            {
                "name": "robot sigma",
                "value": f"{_num(ref.get('robot_sigma_mm')):.3f} mm / "
                f"{_num(ref.get('robot_sigma_deg')):.4f} deg per view",
            }
        ]
        + stated,
    }


def _tracker(ref) -> Optional[dict]:
    """A pose-only result's tracker model as short lines: its noise, the sigmas' degrees of freedom, its scale."""
    tn = ref.get("tracker_noise") if ref else None
    if not isinstance(tn, dict):
        return None
    items = []  # the tracker's noise itself is in the noise table (:func:`_noise`)
    dof = ref.get("tracker_noise_dof")
    nu, k = ref.get("cov_x_noise_dof"), _num(ref.get("cov_x_dof_factor"))
    if isinstance(dof, dict) and dof and nu is not None:
        per = ", ".join(f"{name.replace('_', ' ')} {_num(v):.0f}" for name, v in dof.items())
        items.append(
            {
                "name": "degrees of freedom",
                "value": f"{per}; X's covariance is the plug-in one times {k:.3f} "
                + (
                    "(the estimation repeated on noise drawn at these sigmas: the sigmas' spread and the weights "
                    "they gave)"
                    if ref.get("cov_x_dof_method") == "resampled"
                    else f"(Satterthwaite's {_num(nu):.0f} degrees of freedom over the sigmas' shares)"
                )
                + f": its 95 % region is that of 6 × F(6, {_num(nu):.0f}), not chi-square(6)'s",
            }
        )
    sc = ref.get("tracker_scale")
    if isinstance(sc, dict) and sc.get("value") is not None:
        items.append(
            {
                "name": "translation scale",
                "value": f"{_num(sc['value']):.5f} ± {_num(sc.get('sigma')):.2g} (estimated jointly with X, "
                "--estimate-scale; X's covariance includes its uncertainty)",
            }
        )
    return {"items": items} if items else None


def _kinematic_items(rm: dict) -> list:
    """The kinematic robot models' parameters as short lines.

    The arm, where the joint angles came from, the encoder noise, the DH prior (stated, as used, its test) and
    the largest DH offsets, the tool offset. The DH table and the joint angles of every view stay in
    result.json.
    """
    items = [{"name": "model", "value": str(rm.get("description", ""))}]
    items.append({"name": "arm", "value": f"{rm.get('arm', '?')} ({rm.get('dh_convention', '?')} DH)"})
    items.append({"name": "joint angles", "value": str(rm.get("joint_angles", "?"))})
    enc = _num(rm.get("encoder_sigma_deg"))
    items.append(
        {
            "name": "encoder noise",
            "value": f"{enc:.4f} deg per joint and view, "
            + ("estimated" if "encoder_sigma_deg" in (rm.get("estimated") or []) else "stated")
            + ("" if rm.get("encoder_sigma_resolved") is not False else " (not resolved by the views)"),
        }
    )
    stated, used = rm.get("dh_prior_sigma_stated") or {}, rm.get("dh_prior_sigma") or {}
    if used:
        test = rm.get("dh_prior_test") or {}
        line = f"{_num(used.get('length_mm')):.3g} mm / {_num(used.get('angle_deg')):.3g} deg per DH parameter"
        if rm.get("dh_prior") and rm["dh_prior"] != "the arm's error prior":
            line = f"{rm['dh_prior']} (the arm's own: {line})"
        elif test.get("contradicted"):
            line += (
                f": the views contradict the arm's stated {_num(stated.get('length_mm')):.3g} mm / "
                f"{_num(stated.get('angle_deg')):.3g} deg (chi-square {_num(test.get('statistic')):.1f} with "
                f"{_num(test.get('redundancy')):.1f} offsets resolved, p = {_num(test.get('p_value')):.2g}), so "
                f"its scale was estimated: x{_num(rm.get('dh_prior_scale')):.2f}"
            )
        elif test.get("resolved"):
            line += (
                f", the arm's stated prior (not rejected at {100 * _num(test.get('alpha')):g} %: "
                f"p = {_num(test.get('p_value')):.2g})"
            )
        else:
            line += ", the arm's stated prior"
        items.append({"name": "DH prior", "value": line})
    off, sd = rm.get("dh_offset"), rm.get("dh_offset_sigma")
    if isinstance(off, list) and isinstance(sd, list) and off:
        o, e = np.asarray(off, float), np.asarray(sd, float)
        names = ["a", "alpha", "d", "theta_offset"]
        parts = []
        for cols, unit in (((0, 2), "mm"), ((1, 3), "deg")):
            sub = np.abs(o[:, cols])
            j, c = np.unravel_index(int(np.argmax(sub)), sub.shape)
            parts.append(f"{o[j, cols[c]]:+.3g} ± {e[j, cols[c]]:.2g} {unit} ({names[cols[c]]} of joint {j + 1})")
        share = np.asarray(rm.get("dh_resolved_share") or [], float)
        resolved = (
            f" ({int(np.sum(share > 0.5))} of {share.size} known more from the views than from the prior)"
            if share.size
            else ""
        )
        items.append({"name": "DH offsets", "value": "largest " + ", ".join(parts) + resolved})
    spread = rm.get("tool_offset_spread_deg_mm")
    T = rm.get("tool_offset_T_flange_reported")
    if isinstance(T, list) and isinstance(spread, list) and len(spread) == 2:
        t = np.asarray(T, float)[:3, 3] * 1000.0
        items.append(
            {
                "name": "tool offset",
                "value": f"{np.linalg.norm(t):.1f} mm from the flange (spread over the "
                f"views {_num(spread[1]):.2g} mm / {_num(spread[0]):.2g} deg)",
            }
        )
    bad = rm.get("joints_disagree_view_ids") or []
    if bad:
        items.append({"name": "joints disagree with the pose", "value": ", ".join(str(v) for v in bad)})
    po = rm.get("pose_only")
    if isinstance(po, dict):  # a tracker session: what its poses cannot tell apart
        held = po.get("dh_held_by_prior") or []
        text = (
            "the encoder noise is held at the arm's stated sigma (a tracker's pose carries it and the tracker's "
            "noise together; poses alone cannot tell them apart)"
        )
        if isinstance(held, list) and "dh_resolved" in po:
            n = len(held) + len(po.get("dh_resolved") or [])
            text += (
                f"; {len(held)} of {n} DH offsets stay near their prior (they act as a change of the base, the "
                "tool, X or the target does): their uncertainty is in X's covariance"
            )
        items.append({"name": "from poses alone", "value": text})
    return items


def _noise(ref, *, tracked: bool = False) -> Optional[dict]:
    """The noise table: the pixel and robot noise of an image result, the tracker's and the robot's of a pose-only one.

    ``tracked``: the result's target is a tracker's (a pose-only session): no pixel rows; the tracker's noise as
    ``refinement.tracker_noise`` holds it (:func:`_tracker_noise`) instead.
    """
    if not ref:
        return None
    resolved = ref.get("robot_sigma_resolved") or {}
    tracker = _tracker_noise(ref.get("tracker_noise")) if tracked else None
    return {
        "pixels": not tracked,
        "tracker": tracker,
        "estimated": not tracked or bool(tracker and tracker["estimated"]),
        "sigma_px": ref.get("sigma_px"),
        "robot_mm": ref.get("robot_sigma_mm"),
        "robot_deg": ref.get("robot_sigma_deg"),
        "resolved_rot": resolved.get("rot"),
        "resolved_trans": resolved.get("trans"),
        "model": ref.get("robot_noise_model", ""),
        "rms_before": ref.get("rms_px_before"),
        "rms_after": ref.get("rms_px_after"),
        "iterations": ref.get("iterations"),
        # X's covariance widened for the estimated robot noise levels' degrees of freedom (image results)
        "x_dof": ref.get("cov_x_noise_dof") if not ref.get("tracker_noise_dof") else None,
        "x_dof_factor": ref.get("cov_x_dof_factor"),
    }


#: how a pose-only result's tracker sigmas were had (``refinement.tracker_noise.source``)
TRACKER_SOURCE_TEXT = {"stated": "stated with the session", "estimated": "estimated from the views"}


def _tracker_noise(tn) -> Optional[dict]:
    """The tracker's noise of a pose-only result (``refinement.tracker_noise``) as rows of the noise table.

    Rotation per axis, translation per axis across the optical axis (x, y) and along it (z), each with its
    unit and whether the views resolved it (an estimated sigma they cannot resolve is held at its start), how
    the sigmas were had (stated or estimated) and, for a heavy-tailed tracker, its Student-t degrees of freedom.
    """
    if not isinstance(tn, dict):
        return None
    got = tn.get("resolved")
    resolved: dict = got if isinstance(got, dict) else {}
    rows = [
        {"name": name, "value": tn.get(key), "unit": unit, "held": resolved.get(group) is False}
        for name, key, unit, group in (
            ("rotation, per axis", "sigma_deg", "deg", "rot"),
            ("translation across the optical axis (x, y), per axis", "sigma_mm", "mm", "trans"),
            ("translation along the optical axis (z)", "sigma_mm_along", "mm", "trans_along"),
        )
    ]
    source = str(tn.get("source") or "")
    tail = tn.get("tail_dof")
    return {
        "rows": rows,
        "source": TRACKER_SOURCE_TEXT.get(source, source),
        "estimated": source == "estimated",
        "tail_dof": tail if isinstance(tail, (int, float)) and not isinstance(tail, bool) else None,
    }
