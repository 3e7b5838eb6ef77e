"""The diagnostics sections: findings, how each diagnostics stage ended, the held-out validation."""

from __future__ import annotations

import re
from typing import Optional

from ..advice import STAGE_CHECKS, finding_advice

SEVERITY_ORDER = {"fail": 0, "warn": 1, "info": 2}


def _cap1(s) -> str:
    s = str(s or "")
    return s[:1].upper() + s[1:]


def _findings(diag: dict) -> list[dict]:
    out: list[dict] = []
    for f in (diag or {}).get("findings") or []:
        if not isinstance(f, dict):
            continue
        sev = str(f.get("severity", "info")).lower()
        sev = sev if sev in SEVERITY_ORDER else "info"
        out.append(
            {
                "code": str(f.get("code") or ""),
                "severity": sev,
                "title": str(f.get("title") or f.get("code") or "finding"),
                "evidence": _cap1(f.get("evidence", "")),
                "action": _cap1(f.get("action", "")),
                "view_ids": [str(v) for v in (f.get("view_ids") or [])],
                "details": f.get("details") if isinstance(f.get("details"), dict) else {},
                "advice": _unless_said(finding_advice(f), f.get("action", "")),
            }
        )
    out.sort(key=lambda f: SEVERITY_ORDER[f["severity"]])
    return out


def _stages(diag: dict) -> dict:
    """How each diagnostics stage ended.

    How each diagnostics stage ended (``diagnostics["stages"]``, ``["stage_errors"]``,
    ``["stages_skipped"]``, ``["crashed_stages"]``; see handeye/diagnose/findings.py):

    ``{"crashed": [{name, checks, error}], "skipped": [{name, checks, why}], "n_ok": int, "known": bool,
    "clean": bool}``. ``clean`` only when the stage record exists and every stage ran; a result
    written before stages were recorded is not ``known``, and its report does not claim that
    everything ran.
    """
    diag = diag or {}
    status = status if isinstance(status := diag.get("stages"), dict) else {}
    errors = errors if isinstance(errors := diag.get("stage_errors"), dict) else {}
    skipped = skipped if isinstance(skipped := diag.get("stages_skipped"), dict) else {}
    crashed_names = [n for n, st in status.items() if st == "crashed"]
    crashed_names += [n for n in errors if n not in crashed_names]  # an error always means a crash
    try:
        n_crashed = max(int(diag.get("crashed_stages") or 0), len(crashed_names))
    except (TypeError, ValueError):
        n_crashed = len(crashed_names)
    crashed = [
        {
            "name": str(n),
            "checks": STAGE_CHECKS.get(str(n), ""),
            "error": str(errors.get(n) or "no error message recorded"),
        }
        for n in crashed_names
    ]
    crashed += [
        {"name": "(unnamed)", "checks": "", "error": "counted as crashed without a name"}
        for _ in range(n_crashed - len(crashed))
    ]
    skipped_names = [n for n, st in status.items() if st == "skipped"]
    skipped_names += [n for n in skipped if n not in skipped_names and n not in crashed_names]
    skipped_rows = [
        {"name": str(n), "checks": STAGE_CHECKS.get(str(n), ""), "why": str(skipped.get(n) or "no reason recorded")}
        for n in skipped_names
    ]
    known = bool(status) or "crashed_stages" in diag
    return {
        "crashed": crashed,
        "skipped": skipped_rows,
        "n_ok": sum(st == "ok" for st in status.values()),
        "known": known,
        "clean": known and not crashed and not skipped_rows,
    }


def _col_title(key: str) -> str:
    """``held_out_rms_px`` -> ``Held out RMS [px]``."""
    k, unit = str(key), ""
    for suf in ("px", "mm", "deg", "m", "rad"):
        if k.endswith("_" + suf):
            k, unit = k[: -len(suf) - 1], f" [{suf}]"
            break
    k = k.replace("_", " ").replace("rms", "RMS")
    return k[:1].upper() + k[1:] + unit


def _unless_said(advice: str, action: str) -> str:
    """The advice of a finding's code, or "" when its own action says the same."""

    def norm(s):
        return re.sub(r"[^a-z0-9]+", " ", str(s).lower()).strip()

    return "" if norm(advice) == norm(action) else advice


def _cross_validation(cv) -> Optional[dict]:
    """The diagnostics' held-out validation: summary, spread against prediction, per-view table.

    Known keys (jackknife_sigma_*, predicted_sigma_*, per_view) get a dedicated layout; anything
    else is shown generically (scalars as items, lists of dicts as tables).
    """
    if not isinstance(cv, dict) or not cv:
        return None
    summary = str(cv.get("summary") or cv.get("conclusion") or "")
    ran = bool(cv.get("verdict")) or "jackknife_sigma_rot_deg" in cv
    out = {
        "summary": summary,
        "items": [],
        "tables": [],
        "not_run": not ran,
        "spread": None,
        "verdict": cv.get("verdict", ""),
    }
    used = {"summary", "conclusion", "verdict", "status"}
    if "jackknife_sigma_rot_deg" in cv or "jackknife_sigma_trans_mm" in cv:
        rows = [
            ("Held-out spread (jackknife, 1 σ)", cv.get("jackknife_sigma_rot_deg"), cv.get("jackknife_sigma_trans_mm"))
        ]
        if cv.get("predicted_sigma_rot_deg") is not None:
            rows.append(
                (
                    "Predicted by the covariance (1 σ)",
                    cv.get("predicted_sigma_rot_deg"),
                    cv.get("predicted_sigma_trans_mm"),
                )
            )
        out["spread"] = {
            "rows": [{"name": n, "rot": list(r or [None] * 3), "trans": list(t or [None] * 3)} for n, r, t in rows],
            "ratio_rot": cv.get("ratio_rot"),
            "ratio_trans": cv.get("ratio_trans"),
            "axes": cv.get("axes", ""),
        }
        used |= {
            "jackknife_sigma_rot_deg",
            "jackknife_sigma_trans_mm",
            "predicted_sigma_rot_deg",
            "predicted_sigma_trans_mm",
            "ratio_rot",
            "ratio_trans",
            "axes",
        }
    labels = {
        "method": "Refit",
        "scheme": "Scheme",
        "n_views": "Views",
        "n_folds": "Folds",
        "folds_solved": "Folds solved",
        "held_out_rms_px_median": "Held-out RMS, median [px]",
        "held_out_trans_mm_median": "Held-out pose residual, median [mm]",
        "held_out_rot_deg_median": "Held-out pose residual, median [deg]",
        "per_view": "Per view (the views held out together share their fold's shift of X)",
    }

    def num_text(x, d):
        return f"{x:.{d}f}" if isinstance(x, (int, float)) else "—"  # a NaN is stored as null

    def triple(v, d):
        return ", ".join(num_text(x, d) for x in v) if isinstance(v, list) else num_text(v, d)

    lim = cv.get("ratio_limits")
    if isinstance(lim, list) and len(lim) == 2:
        out["items"].append(
            {
                "name": "Range of the ratio by chance when the model holds",
                "value": f"{num_text(lim[0], 2)}-{num_text(lim[1], 2)}×",
            }
        )
    if cv.get("spread_p_value") is not None:
        out["items"].append(
            {"name": "p-value of the spread under the model covariance", "value": f"{float(cv['spread_p_value']):.2g}"}
        )
    if cv.get("verdict_sigma_rot_deg") is not None:
        out["items"].append(
            {
                "name": "Verdict covariance (1 σ): rotation [°] / translation [mm]",
                "value": f"{triple(cv['verdict_sigma_rot_deg'], 4)} / {triple(cv.get('verdict_sigma_trans_mm'), 3)}",
            }
        )
    if cv.get("ratio_rot_verdict") is not None:
        out["items"].append(
            {
                "name": "Held-out spread / verdict σ",
                "value": f"rotation {num_text(cv['ratio_rot_verdict'], 2)}×, translation "
                f"{num_text(cv.get('ratio_trans_verdict'), 2)}×"
                + (
                    ""
                    if cv.get("covered_by_verdict") is None
                    else "; the verdict covariance covers the spread"
                    if cv["covered_by_verdict"]
                    else "; the verdict covariance does not cover the spread"
                ),
            }
        )
    used |= {
        "ratio_limits",
        "ratio_limits_meaning",
        "spread_p_value",
        "verdict_sigma_rot_deg",
        "verdict_sigma_trans_mm",
        "ratio_rot_verdict",
        "ratio_trans_verdict",
        "covered_by_verdict",
    }
    for k, v in cv.items():
        if k in used:
            continue
        name = labels.get(k, k.replace("_", " "))
        if isinstance(v, (int, float, str, bool)) or v is None:
            out["items"].append({"name": name, "value": v})
        elif isinstance(v, list) and v and all(isinstance(r, dict) for r in v):
            cols = list(dict.fromkeys(c for r in v for c in r if not isinstance(r[c], (list, dict))))
            out["tables"].append(
                {"name": name, "cols": [_col_title(c) for c in cols], "rows": [[r.get(c) for c in cols] for r in v]}
            )
        elif isinstance(v, list) and v and all(isinstance(x, (int, float)) for x in v) and len(v) <= 6:
            out["items"].append({"name": name, "value": ", ".join(f"{x:.4g}" for x in v)})
        elif isinstance(v, dict):
            for kk, vv in v.items():
                if isinstance(vv, (int, float, str, bool)):
                    out["items"].append({"name": f"{name} {kk}".replace("_", " "), "value": vv})
    return out
