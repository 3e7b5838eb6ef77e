"""What to do about a failed run or a finding, keyed on codes, never on message text.

A failed run's result.json holds the structured error (:meth:`handeye.errors.HandeyeError.to_dict`:
code, what, file, line, expected, got, fix); the diagnostics' findings carry a ``code``. The advice
here complements the error's own ``fix`` with what a person should check, per code.
"""
from __future__ import annotations

#: error code -> what to check (in addition to the error's own ``fix``)
ERROR_ADVICE = {
    "target_not_found": "Count the inner corners (where four squares meet), not the squares, give the square size "
                        "in metres, and check in the thumbnails below that the board is whole, sharp and evenly lit.",
    "detection_failed": "Count the inner corners (where four squares meet), not the squares, give the square size "
                        "in metres, and check in the thumbnails below that the board is whole, sharp and evenly lit.",
    "too_few_views": "Collect 15-25 views with the board fully visible.",
    "motion_small_rotation": "Collect views tilted 20-45 deg against each other about two different axes.",
    "motion_one_axis": "Tilt the tool about the other axes as well, not only about one.",
    "degenerate_motion": "Collect views tilted 20-45 deg against each other about two different axes.",
    "refinement_failed": "Re-run with --no-refine to get the closed-form result, and check the per-view table for "
                         "views whose robot pose disagrees with the image.",
    "intrinsics_size_mismatch": "Fix the intrinsics' image size in the session or remove the given intrinsics.",
    "closed_form_failed": "Try another --method (e.g. park) and check the robot poses' units and rotation convention.",
    "unknown_method": "Use one of the methods handeye calibrate --help lists.",
    "camera_calibration_failed": "Give the camera intrinsics in the session, or add views that reach the image "
                                 "corners at different distances and tilts.",
    "pnp_failed": "Check the board description (inner corners, square size) against the thumbnails.",
}

#: advice for the error classes' default codes: only when nothing more precise is known
FALLBACK_ADVICE = {
    "input_error": "Fix what the message names (docs/session_format.md describes the session files) and re-run "
                   "handeye calibrate.",
    "config_error": "Fix the setting the message names and re-run handeye calibrate.",
}

#: finding code -> the QA metrics whose value that finding makes untrustworthy (the number is computed
#: from data the finding says is wrong, so a green card for it would mislead)
UNTRUSTED_METRICS = {
    "translation_units": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg",
                          "axis_spread_deg"),
    "angle_units": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "euler_order": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "quaternion_order": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg",
                         "axis_spread_deg"),
    "poses_inverted": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "mode_swapped": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    "board_moved": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    "intrinsics_mismatch": ("reprojection_rms_px", "predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    "uncertainty_underestimated": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
}

#: diagnostics stage name (handeye.diagnose, ``diagnostics["stages"]``) -> what that stage checks, for the
#: report's list of checks that crashed or did not run; an unknown stage is shown by its name alone
STAGE_CHECKS = {
    "observations": "gathering the detections and robot poses the other checks use",
    "lenient_read": "reading a session that did not load",
    "readings": "how the robot poses are read: units, Euler order, quaternion order, inversion, mounting mode",
    "pairing": "whether images and robot poses are paired in step",
    "board_moved": "whether the board moved during the collection",
    "robot_poses": "robot poses that disagree with what the camera saw",
    "motion": "rotation and view coverage of the robot motion",
    "detection": "corner detections that do not fit",
    "intrinsics": "the lens model and its distortion",
    "images": "image blur and exposure",
    "coverage": "how much of the image the corners reach",
    "cross_validation": "validation on held-out views",
}

MAX_ACTIONS = 3  # a short list is read; the findings section below has every finding's action

GENERIC_WITH_VIEWS = ("Read the per-view table for what was found in each image, fix the cause and re-run "
                      "handeye calibrate.")
GENERIC_WITHOUT_VIEWS = ("Fix what the message names (docs/session_format.md describes the session files) and "
                         "re-run handeye calibrate.")


def _sentence(s) -> str:
    s = str(s or "").strip()
    return (s[:1].upper() + s[1:]).rstrip(".") + "." if s else s


def error_record(res: dict) -> dict:
    """The structured error of a failed run; a result written before errors had codes gives its
    ``failure_reason`` as ``what`` and the code ``""``."""
    err = res.get("error")
    if isinstance(err, dict) and err.get("what"):
        return err
    return {"code": "", "what": res.get("failure_reason") or "the calibration failed (no reason recorded)"}


def failure_advice(res: dict, findings: list[dict], *, has_views: bool) -> dict:
    """Why a run failed and what to change: the error's own fix, the advice for its code, then the
    actions of the diagnostics' fail findings (up to :data:`MAX_ACTIONS` in all); generic advice only
    when none of these says anything."""
    err = error_record(res)
    parts = [str(err["what"])]
    if err.get("expected"):
        parts.append(f"expected {err['expected']}")
    if err.get("got"):
        parts.append(f"got {err['got']}")
    problem = _sentence("; ".join(parts))
    actions: list[str] = []

    def add(text: str) -> None:
        text = _sentence(text)
        if text and text not in actions:
            actions.append(text)

    code = str(err.get("code") or "")
    add(err.get("fix"))
    add(ERROR_ADVICE.get(code, ""))
    for f in findings:
        if f["severity"] == "fail" and len(actions) < MAX_ACTIONS:
            add(f.get("action"))
    if not actions:
        add(FALLBACK_ADVICE.get(code) or (GENERIC_WITH_VIEWS if has_views else GENERIC_WITHOUT_VIEWS))
    where = err.get("file") or ""
    if where and err.get("line") is not None:
        where = f"{where}:{err['line']}"
    return {"code": err.get("code") or "", "problem": problem, "short": problem, "where": where,
            "actions": actions}


def untrusted_metrics(findings: list[dict]) -> dict[str, str]:
    """metric key -> the title of the (fail or warn) finding that makes its value untrustworthy."""
    out: dict[str, str] = {}
    for f in findings:
        if f["severity"] not in ("fail", "warn"):
            continue
        for key in UNTRUSTED_METRICS.get(f.get("code", ""), ()):
            out.setdefault(key, f.get("title") or f.get("code"))
    return out
