"""The closed-form methods beside the result, and where the result lies against them and each half."""

from __future__ import annotations

from typing import Optional

import numpy as np

from ...conventions import vendor_euler_from_R
from ...stats import chi2_ppf
from ..observations import as_T
from .values import _num


def _methods(res, T_x, x_name) -> list[dict]:
    rows = []
    ref = ref if isinstance(ref := res.get("refinement"), dict) else {}
    start = ref.get("start_method")  # the closed form the refinement started from, when not the seed
    for m, e in (res.get("closed_form") or {}).items():
        T = as_T(e.get(x_name))
        row = {
            "name": m,
            "status": e.get("status", "?"),
            "reason": e.get("failure_reason", ""),
            "is_seed": m == res.get("method"),
            "is_start": m == start and m != res.get("method"),
            "is_result": False,
            "cons_mm": None,
            "cons_deg": None,
        }
        if T is not None:
            row["t_mm"] = (T[:3, 3] * 1e3).tolist()
            row["euler_deg"] = np.degrees(vendor_euler_from_R(T[:3, :3])).tolist()
            if T_x is not None:
                row["d_deg"], row["d_mm"], _ = _stored_difference(e)
                row["offset_mm"] = ((T[:3, 3] - T_x[:3, 3]) * 1e3).tolist()
            row["cons_mm"], row["cons_deg"] = e.get("board_consistency_mm"), e.get("board_consistency_deg")
        rows.append(row)
    if T_x is not None and res.get("refined"):
        rows.append(
            {
                "name": "joint refinement (result)",
                "status": "ok",
                "reason": "",
                "is_result": True,
                "is_seed": False,
                "is_start": False,
                "cons_mm": None,
                "cons_deg": None,
                "t_mm": (T_x[:3, 3] * 1e3).tolist(),
                "euler_deg": np.degrees(vendor_euler_from_R(T_x[:3, :3])).tolist(),
                "d_deg": 0.0,
                "d_mm": 0.0,
                "offset_mm": [0.0, 0.0, 0.0],
            }
        )
    elif T_x is not None:
        for r in rows:
            if r.get("is_seed"):
                r["is_result"] = True
    return rows


def methods_views(res: dict) -> str:
    """Which views the closed forms solved, for the method comparison's first sentence."""
    kept = res.get("closed_form_views")
    if not kept:
        return "on the same views"
    per_view = ((res.get("refinement") or {}).get("per_view")) or {}
    out = [str(v) for v, d in per_view.items() if isinstance(d, dict) and d.get("status") != "used"]
    left = f" (without view{'s' * (len(out) > 1)} {', '.join(out)}, left out by the refinement)" if out else ""
    return f"on the {len(kept)} views the result used{left}"


def _stored_difference(e: dict) -> tuple[float, float, float]:
    """(deg, mm, verdict sigmas) of a closed form or a refitted half against the result.

    (deg, mm, verdict sigmas) of a closed form or a refitted half against the result, as result.json
    stores them (``diff_to_result_deg``, ``_mm``, ``_sigma``; NaN where it does not).
    """
    return _num(e.get("diff_to_result_deg")), _num(e.get("diff_to_result_mm")), _num(e.get("diff_to_result_sigma"))


def _offsets(res, ref, T_x, cov, x_name, *, tracked: bool = False) -> Optional[dict]:
    """Where the result lies against each closed form and each half of the views.

    Where the result lies against each closed form and each half of the views (refitted alone), in mm,
    degrees and verdict sigmas, with the sentences that explain a departure. ``tracked``: a pose-only session
    (its views' noise is the tracker's).
    """
    from ...config import load_preset
    from ..uncertainty import offset_explanation

    if T_x is None or cov is None or not ref:
        return None
    alpha = float(load_preset("diagnostics")["validation"]["offset_alpha"])
    limit = float(np.sqrt(chi2_ppf(1.0 - alpha, 6)))
    rows = []
    for m, e in (res.get("closed_form") or {}).items():
        T = as_T(e.get(x_name))
        if T is not None:
            rows.append({"name": m, "kind": "closed_form", "T": T, "stored": e})
    val = val if isinstance(val := ref.get("validation"), dict) else {}
    halves = val.get("halves") or {}
    n_used = sum(len((halves.get(h) or {}).get("used_view_ids") or []) for h in ("odd", "even"))
    for h, which in (("odd", "1st"), ("even", "2nd")):
        T = as_T((halves.get(h) or {}).get(x_name))
        if T is not None:
            ids = [str(v) for v in halves[h].get("used_view_ids") or halves[h].get("view_ids") or []]
            shown = ", ".join(ids[:4]) + (f", …, {ids[-1]}" if len(ids) > 5 else "".join(f", {v}" for v in ids[4:]))
            rows.append(
                {
                    "name": f"every other used view from the {which} ({len(ids)}"
                    + (f" of {n_used}" if n_used else "")
                    + f": views {shown}), refitted alone",
                    "kind": "half",
                    "T": T,
                    "stored": halves[h],
                }
            )
    if not rows:
        return None
    for r in rows:
        T = r.pop("T")
        r["d_deg"], r["d_mm"], r["sigma"] = _stored_difference(r.pop("stored"))
        r["offset_mm"] = ((T[:3, 3] - T_x[:3, 3]) * 1e3).tolist()
        r["far"] = bool(r["sigma"] > limit)
    split = (halves.get("odd_vs_even") or {}).get("mahalanobis2")
    model = model if isinstance(model := ref.get("robot_model"), dict) else {}
    text = offset_explanation(
        rows,
        limit_sigma=limit,
        halves_m2=None if split is None else float(split),
        halves_m2_limit=chi2_ppf(1.0 - alpha, 6),
        robot_mm=_num(ref.get("robot_sigma_mm")),
        robot_deg=_num(ref.get("robot_sigma_deg")),
        robot_model=str(model.get("kind") or ref.get("robot_noise_model") or ""),
        tracked=tracked,
    )
    for r in rows:  # a closed form past the limit is usually its own error: only a half is marked
        r["bold"] = r["far"] and r["kind"] == "half"
    return {
        "rows": rows,
        "limit_sigma": limit,
        "intro": offsets_intro(limit, ref.get("sigma_source") or "model"),
        "explanation": text,
        "halves_split_m2": split,
        "sigma_source": ref.get("sigma_source") or "model",
    }


def offsets_intro(limit_sigma: float, sigma_source: str) -> str:
    """What the "Where the result lies" table measures, in words (its limit ``limit_sigma`` in verdict sigmas)."""
    return (
        "How far the refined result lies from each closed form and from each half of the views refitted alone (odd "
        "and even positions in view order), in mm, degrees and σ, the result's own uncertainty (its verdict "
        f"covariance, {sigma_source}). Past {limit_sigma:.1f} σ, where 99 % of chance offsets stay below, an offset "
        "is more than the result's uncertainty explains: for a closed form that is usually the closed form's own "
        "error (it ignores the noise), not the result's; for a half of the views (in bold), that the half lies "
        "further from the whole than chance allows. The sentences below the table say what the offsets show here."
    )
