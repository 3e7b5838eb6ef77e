"""PASS / WARN / FAIL against the QA thresholds of ``configs/qa.yaml`` (site-overridable).

:func:`evaluate` takes plain numbers (``metrics``) and returns a :class:`Verdict`; every check that
does not pass says why, with the number, and what to do about it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

from ..config import load_preset, load_with_override
from ..errors import ConfigError

STATUS_ORDER = {"pass": 0, "info": 1, "warn": 2, "fail": 3}
VERDICT_TEXT = {"pass": "PASS", "warn": "WARN", "fail": "FAIL", "info": "PASS"}
#: what a crashed diagnostics stage may count as (configs/qa.yaml ``crashed_stage``): never less than warn
CRASHED_STAGE_STATUSES = ("warn", "fail")


@dataclass(frozen=True)
class Check:
    key: str
    title: str
    status: str  # pass | warn | fail | info
    value: Optional[float]
    value_text: str
    limit_text: str
    why: str = ""  # set when the check does not pass
    action: str = ""
    source: str = ""  # where the number comes from
    short: str = ""  # a few words for the headline when the check does not pass


@dataclass(frozen=True)
class Verdict:
    status: str  # pass | warn | fail
    headline: str
    checks: tuple = ()  # Check
    findings: tuple = ()  # diagnostics findings that count (dicts)
    thresholds_source: str = "configs/qa.yaml (shipped)"
    counts: dict = field(default_factory=dict)
    #: the root cause that leads a failed run's headline (:func:`handeye.report.advice.root_cause`'s text), or ""
    cause: str = ""

    @property
    def label(self) -> str:
        return VERDICT_TEXT[self.status]


def load_qa(path: str | Path | None = None) -> dict:
    """Shipped QA thresholds, deep-merged with a site file when given; validated once."""
    cfg = load_with_override("qa", path) if path is not None else load_preset("qa")
    src = str(path) if path is not None else "configs/qa.yaml"
    if cfg.get("crashed_stage", "warn") not in CRASHED_STAGE_STATUSES:
        raise ConfigError(
            "crashed_stage must be warn or fail (a crashed check never passes)",
            path=src,
            expected=" | ".join(CRASHED_STAGE_STATUSES),
            received=repr(cfg.get("crashed_stage")),
        )
    if cfg.get("missing_value", "warn") not in STATUS_ORDER:
        raise ConfigError(
            "missing_value must be one of pass | info | warn | fail", path=src, received=repr(cfg.get("missing_value"))
        )
    wd = cfg.get("working_distance_m")
    if wd is not None and not (isinstance(wd, (int, float)) and wd > 0):
        raise ConfigError("working_distance_m must be a positive number of metres or null", path=src, received=repr(wd))
    cells = cfg.get("coverage_grid_cells_x", 16)
    if not (isinstance(cells, int) and not isinstance(cells, bool) and cells >= 1):
        raise ConfigError(
            "coverage_grid_cells_x must be a positive whole number of cells", path=src, received=repr(cells)
        )
    for name, lim in (cfg.get("checks") or {}).items():
        if not isinstance(lim, dict):
            raise ConfigError(f"checks.{name} must be a mapping of limits", path=src, received=repr(lim))
        for k, v in lim.items():
            if k not in ("warn_above", "fail_above", "warn_below", "fail_below"):
                raise ConfigError(
                    f"checks.{name}: unknown limit {k!r}",
                    path=src,
                    expected="warn_above, fail_above, warn_below, fail_below",
                )
            if v is not None and not isinstance(v, (int, float)):
                raise ConfigError(f"checks.{name}.{k} must be a number or null", path=src, received=repr(v))
    return cfg


# ------------------------------------------------------------------------------ check texts
def _or_arm(c: dict, action: str, share_key: str = "arm_share") -> str:
    """``action``, unless most of X's uncertainty is the arm's stated accuracy, which more views cannot reduce.

    ``share_key``: the translation's share (``arm_share``) or the rotation's (``arm_share_rot``).
    """
    share = float(c.get(share_key, 0.0))
    if share < 0.5:
        return action
    return (
        f"{share:.0%} of this uncertainty is the arm's stated accuracy (robot_accuracy), which more views cannot "
        "reduce: calibrate with the arm's kinematic model (--robot ARM, its DH table), or take the arm's accuracy "
        "as the limit of this installation"
    )


_SPEC = {
    # key: (title, unit, format, why(value, limit, ctx), action(ctx))
    "reprojection_rms_px": (
        "Reprojection RMS",
        "px",
        "{:.3f}",
        lambda v, lim, c: (
            f"detected corners sit {v:.2f} px RMS from where the model puts them ({c.get('rms_source', '')}); "
            f"the limit is {lim:g} px, so the camera model or the corner detections do not fit the images"
        ),
        lambda c: (
            "check focus and motion blur, that the board is flat and its square size is right, and that the lens "
            "did not move; recalibrate the intrinsics with views that reach the image corners"
        ),
    ),
    "predicted_error_mm": (
        "Predicted position error",
        "mm",
        "{:.2f}",
        lambda v, lim, c: (
            f"a point {c.get('wd_m', float('nan')):.2f} m in front of the camera is placed with "
            f"{v:.2f} mm RMS 3-D error (1 σ), above the limit of {lim:g} mm"
        ),
        lambda c: _or_arm(
            c,
            "add views with larger rotations (20-45 deg) about different axes, hold the board near the working "
            "distance, make sure the robot is at rest when each image is taken; the error shrinks about "
            "with 1/sqrt(number of views)",
        ),
    ),
    "sigma_trans_mm": (
        "Translation uncertainty (largest axis, 1 σ)",
        "mm",
        "{:.3f}",
        lambda v, lim, c: (
            f"the hand-eye translation is known to {v:.2f} mm (1 σ, {c.get('sigma_t_axis', '')}), "
            f"the limit is {lim:g} mm"
        ),
        lambda c: _or_arm(
            c,
            "add views that rotate the camera about axes perpendicular to the weak direction and vary the "
            "distance to the board; check the robot's repeatability",
        ),
    ),
    "sigma_rot_deg": (
        "Rotation uncertainty (largest axis, 1 σ)",
        "deg",
        "{:.3f}",
        lambda v, lim, c: (
            f"the hand-eye rotation is known to {v:.3f} deg (1 σ, about camera {c.get('sigma_r_axis', '')}), "
            f"the limit is {lim:g} deg"
        ),
        lambda c: _or_arm(
            c,
            "add views with larger rotations between them and views where the board fills more of the image",
            "arm_share_rot",
        ),
    ),
    "max_rotation_deg": (
        "Largest rotation between views",
        "deg",
        "{:.1f}",
        lambda v, lim, c: (
            f"the robot turns at most {v:.1f} deg between two views (limit {lim:g} deg); small rotations "
            "leave the hand-eye translation poorly determined"
        ),
        lambda c: "add views tilted 20-45 deg (or more) against each other about two different axes",
    ),
    "axis_spread_deg": (
        "Spread of rotation axes",
        "deg",
        "{:.1f}",
        lambda v, lim, c: (
            f"the rotations between views are mostly about one axis ({c.get('main_axis', '?')}); "
            f"spread {v:.1f} deg, limit {lim:g} deg"
        ),
        lambda c: f"add views rotated 20-45 deg about {c.get('weak_axes', 'the other two axes')}",
    ),
    "dropped_share": (
        "Views dropped",
        "",
        "{:.0%}",
        lambda v, lim, c: (
            f"{c.get('n_bad', '?')} of {c.get('n_total', '?')} views were dropped "
            f"({v:.0%}, limit {lim:.0%}): {c.get('bad_reasons', '')}"
        ),
        lambda c: (
            "read the reasons in the per-view table; fix the cause (board partly outside the image, blur, robot "
            "still moving, poses and images out of step) and retake those views"
        ),
    ),
    "used_views": (
        "Views used",
        "",
        "{:.0f}",
        lambda v, lim, c: f"only {v:.0f} views constrain the hand-eye transform (limit {lim:g})",
        lambda c: "collect 10-20 views with the board fully visible and varied orientations",
    ),
    "image_coverage": (
        "Image area reached by corners",
        "",
        "{:.0%}",
        lambda v, lim, c: (
            f"detected corners reach {v:.0%} of the image (limit {lim:.0%}); "
            + (
                "the given intrinsics are then checked against the image only where the target was"
                if c.get("intrinsics_fixed")
                else "the lens distortion is then only known where the target was"
            )
        ),
        lambda c: "add views with the board near the image edges and corners",
    ),
}


def _fmt_limit(lim: dict, fmt: str, unit: str) -> str:
    def f(x):
        return fmt.format(x) + (f" {unit}" if unit else "")

    parts = []
    if lim.get("warn_above") is not None:
        parts.append(f"warn > {f(lim['warn_above'])}")
    if lim.get("fail_above") is not None:
        parts.append(f"fail > {f(lim['fail_above'])}")
    if lim.get("warn_below") is not None:
        parts.append(f"warn < {f(lim['warn_below'])}")
    if lim.get("fail_below") is not None:
        parts.append(f"fail < {f(lim['fail_below'])}")
    return ", ".join(parts) if parts else "not checked"


class _ShownApart(float):
    """A checked value that formats with enough decimals to read otherwise than its limit.

    A checked value that formats with as many more decimals (up to 3) as it takes to read otherwise than the
    limit it crossed: 29.97 against 30 shows as "29.97", not "30.0 < 30.0".
    """

    limit: Optional[float]

    def __new__(cls, value: float, limit: Optional[float]):
        obj = super().__new__(cls, value)
        obj.limit = limit
        return obj

    def __format__(self, spec: str) -> str:
        m = re.fullmatch(r"(.*\.)(\d+)([ef%])", spec)
        if m is None or self.limit is None:
            return float.__format__(self, spec)
        for d in range(int(m[2]), int(m[2]) + 4):
            out = float.__format__(self, f"{m[1]}{d}{m[3]}")
            if out != float.__format__(float(self.limit), f"{m[1]}{d}{m[3]}"):
                return out
        return float.__format__(self, spec)


def _level(value: float, lim: dict) -> tuple[str, Optional[float]]:
    fa, wa, fb, wb = (lim.get(k) for k in ("fail_above", "warn_above", "fail_below", "warn_below"))
    if fa is not None and value > fa:
        return "fail", fa
    if fb is not None and value < fb:
        return "fail", fb
    if wa is not None and value > wa:
        return "warn", wa
    if wb is not None and value < wb:
        return "warn", wb
    return "pass", None


def evaluate(
    metrics: dict,
    cfg: dict,
    *,
    context: dict | None = None,
    failure: dict | None = None,
    findings: list | None = None,
    crashed_stages: list | None = None,
    thresholds_source: str = "configs/qa.yaml (shipped)",
) -> Verdict:
    """Verdict from ``metrics`` (check key -> number or None), thresholds ``cfg`` (see configs/qa.yaml).

    ``failure``: ``{"problem": ..., "action": ...}`` when the calibration itself failed (always FAIL).
    ``findings``: diagnostics findings (dicts with severity fail|warn|info) that count when
    ``cfg["include_diagnostics"]``. ``crashed_stages``: diagnostics stages that crashed (dicts with
    ``name``, ``checks`` (what the stage looks at) and ``error``); they count as ``cfg["crashed_stage"]``
    (warn or fail) in one check. Checks that cannot be evaluated for the same reason are merged.
    """
    ctx = context or {}
    checks: list[Check] = []
    if failure:
        checks.append(
            Check(
                "calibration",
                "Calibration",
                "fail",
                None,
                "failed",
                "must succeed",
                why=failure.get("problem", failure.get("reason", "")),
                action=failure.get("action", ""),
                short="the calibration failed",
            )
        )
    if crashed_stages:
        checks.append(_crashed_check(crashed_stages, cfg.get("crashed_stage", "warn")))
    missing_status = cfg.get("missing_value", "warn")
    missing: dict[str, list] = {}  # why -> keys not evaluated for that reason
    for key, lim in (cfg.get("checks") or {}).items():
        if key not in _SPEC or (key not in metrics and not failure):
            continue
        if all(lim.get(k) is None for k in ("warn_above", "fail_above", "warn_below", "fail_below")):
            continue
        title, unit, fmt, why_f, act_f = _SPEC[key]
        limit_text = _fmt_limit(lim, fmt, unit)
        v = metrics.get(key)
        if v is None:
            if not failure:  # a failed run only shows the checks that have a number
                missing.setdefault(ctx.get(f"{key}_missing", "not available for this run"), []).append(
                    (key, title, limit_text)
                )
            continue
        status, hit = _level(float(v), lim)
        shown = _ShownApart(float(v), hit)  # a value that crossed its limit never reads as the limit
        val_text = fmt.format(shown) + (f" {unit}" if unit else "")
        why = act = short = ""
        if status != "pass":
            why, act = why_f(shown, hit, ctx), act_f(ctx)
            rel = ">" if hit == lim.get("warn_above") or hit == lim.get("fail_above") else "<"
            short = f"{title.split(' (')[0].lower()} {val_text} {rel} {fmt.format(hit)}{' ' + unit if unit else ''}"
        checks.append(
            Check(
                key,
                title,
                status,
                float(v),
                val_text,
                limit_text,
                why=why,
                action=act,
                source=ctx.get(f"{key}_source", ""),
                short=short,
            )
        )
    for why, items in missing.items():
        keys = [k for k, _, _ in items]
        titles = [t.split(" (")[0] for _, t, _ in items]
        title = _join([titles[0]] + [t[:1].lower() + t[1:] for t in titles[1:]])
        act = ctx.get(f"{keys[0]}_missing_action", "")
        quiet = missing_status == "pass"
        checks.append(
            Check(
                "+".join(keys),
                title,
                missing_status,
                None,
                "n/a",
                "; ".join(lt for _, _, lt in items),
                why="" if quiet else why,
                action="" if quiet else act,
                short=f"{title[:1].lower() + title[1:]} not available",
            )
        )
    counted = []
    if cfg.get("include_diagnostics", True):
        counted = [f for f in (findings or []) if str(f.get("severity", "")).lower() in ("fail", "warn")]
    worst = max(
        [STATUS_ORDER[c.status] for c in checks] + [STATUS_ORDER[str(f["severity"]).lower()] for f in counted] + [0]
    )
    status = {0: "pass", 1: "pass", 2: "warn", 3: "fail"}[worst]
    checks = [replace(c, why=_cap(c.why), action=_cap(c.action)) for c in checks]
    counts = {s: sum(c.status == s for c in checks) for s in ("pass", "warn", "fail", "info")}
    counts["findings_fail"] = sum(str(f["severity"]).lower() == "fail" for f in counted)
    counts["findings_warn"] = sum(str(f["severity"]).lower() == "warn" for f in counted)
    cause = ctx.get("root_cause")
    return Verdict(
        status,
        _headline(status, checks, counted, ctx, failure),
        tuple(checks),
        tuple(counted),
        thresholds_source,
        counts,
        cause=str(cause["text"]) if (failure and cause) else "",
    )


def _crashed_check(crashed: list, status: str) -> Check:
    """One check for every diagnostics stage that crashed: which, its error and what did not run."""
    names = [str(c["name"]) for c in crashed]
    n = len(names)
    why = "; ".join(
        f"the {c['name']} stage ({c['checks']}) crashed with {c['error']}"
        if c.get("checks")
        else f"the {c['name']} stage crashed with {c['error']}"
        for c in crashed
    )
    why += (
        ", so its checks did not run" if n == 1 else ", so their checks did not run"
    ) + " and the dataset was not fully examined"
    action = (
        "rebuild the result with handeye --debug calibrate to see the traceback and report it as a bug; "
        "until then, check by hand what the crashed stage looks at"
    )
    short = f"diagnostics stage {names[0]} crashed" if n == 1 else f"diagnostics stages {_join(names)} crashed"
    return Check(
        "diagnostics_stages",
        "Diagnostics stages",
        status,
        float(n),
        f"{n} crashed",
        "every stage must run",
        why=why,
        action=action,
        short=short,
    )


def _cap(s: str) -> str:
    s = (s or "").strip().rstrip(".")
    return s[:1].upper() + s[1:]


def _lower1(s: str) -> str:
    return s[:1].lower() + s[1:]


def _headline(status: str, checks: list, findings: list, ctx: dict, failure: dict | None) -> str:
    cause = ctx.get("root_cause")  # {"code", "text", "fix", "refused"} (report.advice.root_cause)
    if failure:
        if cause:
            fix = f" Fix: {_lower1(cause['fix'])}." if cause.get("fix") else ""
            end = " No result is given." if cause.get("refused") else " The session could not be calibrated."
            return f"{cause['text']}.{fix}{end}"
        return "The session could not be calibrated. " + (failure.get("short") or "")
    if cause and cause.get("severity") != status:
        cause = None  # a warning does not explain a failed verdict
    named = [c for c in checks if c.status == status and c.short and c.key not in ctx.get("headline_skips", ())]
    items = [c.short for c in named]
    items += [
        _lower1(str(f.get("title") or f.get("code") or "").rstrip("."))
        for f in findings
        if str(f.get("severity")).lower() == status and not (cause and f.get("code") == cause["code"])
    ]
    lead = f"{cause['text']}. " if cause and status != "pass" else ""
    name = ctx.get("x_name", "The hand-eye transform")
    pe = ctx.get("predicted_text")
    said = any(c.key == "predicted_error_mm" for c in named)  # the headline names it already
    tail = f" Predicted position error {pe}." if pe and not said else ""
    if status == "pass":
        return f"{name} meets every QA threshold.{tail}"
    if len(items) > 3:
        items = items[:3] + [f"{len(items) - 3} more"]
    if status == "warn":
        return f"{lead}{name} passes with warnings{': ' + _join(items) if items else ''}.{tail}"
    return f"{lead}{name} fails QA{': ' + _join(items) if items else ''}.{tail}"


def _join(items: list) -> str:
    items = [i for i in items if i]
    if len(items) <= 2:
        return " and ".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]
