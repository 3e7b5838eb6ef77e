"""The headline cards, and the verdict's checks on numbers a finding says are not to be trusted."""

from __future__ import annotations

from dataclasses import replace

from ..qa import STATUS_ORDER, Verdict


def _distrust(verdict: Verdict, untrusted: dict[str, str], *, fail_finding: bool = False) -> Verdict:
    """Checks on a number a finding says is wrong are shown as untrusted, not as passed or failed.

    The finding is the cause and counts towards the verdict itself (the label stays as judged), e.g. a board
    that moved inflates the validated sigmas past their limit, and the report leads with the move. A warn or
    fail check is marked so only when a fail finding already makes the verdict FAIL (``fail_finding``).
    """
    if not untrusted:
        return verdict
    checks = tuple(
        replace(
            c,
            status="untrusted",
            why=f"Not to be trusted: {untrusted[c.key]}",
            action="Fix what that finding names and re-run handeye calibrate",
        )
        if c.key in untrusted and (c.status == "pass" or (fail_finding and c.status in ("info", "warn", "fail")))
        else c
        for c in verdict.checks
    )
    counts = dict(
        verdict.counts, **{s: sum(c.status == s for c in checks) for s in ("pass", "info", "warn", "fail", "untrusted")}
    )
    return replace(verdict, checks=checks, counts=counts)


def _kpis(metrics, pred, wd, views, verdict: Verdict, ok: bool, untrusted: dict[str, str]) -> list[dict]:
    """The headline cards.

    A card whose number a finding says is not to be trusted is shown as such, never green.
    """
    status = {k: c.status for c in verdict.checks for k in c.key.split("+")}

    def card(label, value, sub, keys):
        st = max((status.get(k, "pass") for k in keys), key=lambda s: STATUS_ORDER.get(s, 0)) if keys else ""
        if not ok and st == "pass":  # no result: a number of the data is not a passed calibration
            st = "info"
        doubt = next((untrusted[k] for k in keys if k in untrusted), None)
        if doubt and value != "n/a":
            return {"label": label, "value": value, "sub": f"not to be trusted: {doubt}", "status": "untrusted"}
        return {"label": label, "value": value, "sub": sub, "status": st}

    out = []
    if pred is not None:
        out.append(
            card(
                f"Predicted error at {wd:.2f} m",
                f"{pred['rms_mm']:.2f} mm",
                f"1 σ RMS 3-D · 95 %: {pred['r95_mm']:.2f} mm",
                ["predicted_error_mm"],
            )
        )
    elif ok:
        out.append(card("Predicted error", "n/a", "no covariance (--no-refine)", ["predicted_error_mm"]))
    v = metrics.get("reprojection_rms_px")
    if v is not None:
        out.append(card("Reprojection RMS", f"{v:.2f} px", "detected vs predicted corners", ["reprojection_rms_px"]))
    n_used = sum(x["status"] == "used" for x in views)
    if views:
        n_flagged = sum(bool(x.get("flagged")) for x in views)
        n_corners = sum(bool(x.get("corner_flags")) for x in views)
        out.append(
            card(
                "Views used" if ok else "Views detected and paired",
                f"{n_used} / {len(views)}",
                f"{n_flagged} dropped" + (f"; {n_corners} used with outlier corners" if n_corners else ""),
                ["used_views"],
            )
        )
    mr, sp = metrics.get("max_rotation_deg"), metrics.get("axis_spread_deg")
    if mr is not None:
        out.append(
            card(
                "Rotation coverage",
                f"{mr:.0f}°",
                f"largest rotation; axis spread {sp:.0f}°" if sp is not None else "largest rotation",
                ["max_rotation_deg", "axis_spread_deg"],
            )
        )
    return out
