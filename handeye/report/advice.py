"""What to do about a failed run or a finding, keyed on codes, never on message text.

A failed run's result.json holds the structured error (:meth:`handeye.errors.HandeyeError.to_dict`:
code, what, file, line, expected, got, fix); the diagnostics' findings carry a ``code``. The advice
here complements the error's own ``fix`` with what a person should check, per code.
"""

from __future__ import annotations

from typing import Optional

from ..diagnose.findings import PAIRS_OUT_OF_STEP, ROOT_CAUSE_LABELS, is_out_of_step  # noqa: F401 (re-exported)

#: error code -> what to check (in addition to the error's own ``fix``)
ERROR_ADVICE = {
    "target_not_found": "Count the inner corners (where four squares meet), not the squares, give the square size "
    "in metres, and check in the thumbnails below that the board is whole, sharp and evenly lit.",
    "detection_failed": "Count the inner corners (where four squares meet), not the squares, give the square size "
    "in metres, and check in the thumbnails below that the board is whole, sharp and evenly lit.",
    "too_few_views": "Collect 10-20 views with the board fully visible.",
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
    "mode_swapped": "Check where the camera is mounted: on the flange it is eye_in_hand, on a stand eye_to_hand; "
    "state that mode with --mode or mode: in config.yaml or session.yaml.",
    "pairs_shifted": "Check whether the pose file has an extra or a missing line at the start; if the shift is "
    "certain, re-run with --shift-poses N (image k takes the pose written for image k + N), else re-capture images "
    "and poses together, by view id.",
    "pairs_shuffled": "Re-pair images and poses by view id (the recording lost the order); re-capture if unsure.",
    "session_refused": "Read the finding that refused the run below; fix its cause and re-run handeye calibrate.",
}

#: finding code -> what to check (the findings' own ``action`` comes first; this adds what a person checks)
FINDING_ADVICE = {
    "square_size": "Measure a printed square with a caliper and state that size in metres; a printer's 'fit to "
    "page' shrinks a board by a few per cent.",
    "images_mirrored": "Turn off the camera's or its driver's mirror / flip setting and capture again, or flip every "
    "image back; no square size fixes a mirrored image.",
    "scale_unexplained": "Check the unit of the robot translations (m, cm or mm) and that each pose is the flange's "
    "pose in the robot's base frame.",
    "poses_do_not_fit": "Check that each image is paired with the pose recorded at that moment, the pose format "
    "(units, Euler order), the mounting mode and that the board stayed put; re-capture if "
    "unsure.",
    "mode_undecided": "State the mounting mode (--mode eye_in_hand or eye_to_hand, or mode: in config.yaml or "
    "session.yaml); the "
    "data did not decide it, so the default was used.",
    "mode_swapped": ERROR_ADVICE["mode_swapped"],
    "pairs_shifted": ERROR_ADVICE["pairs_shifted"],
    "pairs_shuffled": ERROR_ADVICE["pairs_shuffled"],
}

#: codes whose fail or warn finding (or refusal) explains the verdict: the banner leads with the first found
ROOT_CAUSE_CODES = (
    "mode_swapped",
    "poses_inverted",
    "pairs_shifted",
    "pairs_shuffled",
    "translation_units",
    "angle_units",
    "euler_order",
    "rotation_kind",
    "quaternion_order",
    "images_mirrored",
    "scale_unexplained",
    "square_size",
    "tracker_scale",
    "board_moved",
    "target_drift",
    "poses_do_not_fit",
    "mode_undecided",
)

#: advice for the error classes' default codes: only when nothing more precise is known
FALLBACK_ADVICE = {
    "input_error": "Fix what the message names (docs/session_format.md describes the session files) and re-run "
    "handeye calibrate.",
    "config_error": "Fix the setting the message names and re-run handeye calibrate.",
}

#: finding code -> the QA metrics whose value that finding makes untrustworthy (the number is computed
#: from data the finding says is wrong, so a green card for it would mislead)
UNTRUSTED_METRICS = {
    "translation_units": (
        "predicted_error_mm",
        "sigma_trans_mm",
        "sigma_rot_deg",
        "max_rotation_deg",
        "axis_spread_deg",
    ),
    "angle_units": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "euler_order": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "rotation_kind": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "quaternion_order": (
        "predicted_error_mm",
        "sigma_trans_mm",
        "sigma_rot_deg",
        "max_rotation_deg",
        "axis_spread_deg",
    ),
    "poses_inverted": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg", "max_rotation_deg", "axis_spread_deg"),
    "mode_swapped": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    "board_moved": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    "target_drift": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    # a wrong square size scales every camera translation: X's translation and its uncertainty are off with it
    "square_size": ("predicted_error_mm", "sigma_trans_mm"),
    "tracker_scale": ("predicted_error_mm", "sigma_trans_mm"),
    # a mirrored image fits the board seen from behind: every camera pose, and X with it, is wrong
    "images_mirrored": ("predicted_error_mm", "sigma_trans_mm", "sigma_rot_deg"),
    "scale_unexplained": ("predicted_error_mm", "sigma_trans_mm"),
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

GENERIC_WITH_VIEWS = (
    "Read the per-view table for what was found in each image, fix the cause and re-run handeye calibrate."
)
GENERIC_WITHOUT_VIEWS = (
    "Fix what the message names (docs/session_format.md describes the session files) and re-run handeye calibrate."
)


def _sentence(s) -> str:
    s = str(s or "").strip()
    return (s[:1].upper() + s[1:]).rstrip(".") + "." if s else s


def error_record(res: dict) -> dict:
    """The structured error of a failed run.

    A result written before errors had codes gives its ``failure_reason`` as ``what`` and the code
    ``""``.
    """
    err = res.get("error")
    if isinstance(err, dict) and err.get("what"):
        return err
    return {"code": "", "what": res.get("failure_reason") or "the calibration failed (no reason recorded)"}


def failure_advice(res: dict, findings: list[dict], *, has_views: bool) -> dict:
    """Why a run failed and what to change.

    The error's own fix, the advice for its code, then the actions of the diagnostics' fail findings
    (up to :data:`MAX_ACTIONS` in all); generic advice only when none of these says anything.
    """
    err = error_record(res)
    parts = [str(err["what"])]
    if err.get("expected"):
        parts.append(f"expected {err['expected']}")
    if err.get("got"):
        parts.append(f"got {err['got']}")
    problem = _sentence("; ".join(parts))
    actions: list[str] = []

    def add(text: Optional[str]) -> None:
        text = _sentence(text)
        if text and text not in actions:
            actions.append(text)

    code = str(err.get("code") or "")
    add(err.get("fix"))
    if not (code == "pairs_shuffled" and any(is_out_of_step(f) for f in findings)):  # that one has its own fix
        add(ERROR_ADVICE.get(code, ""))
    for f in findings:
        if f["severity"] == "fail" and len(actions) < MAX_ACTIONS:
            add(f.get("action"))
    if not actions:
        add(FALLBACK_ADVICE.get(code) or (GENERIC_WITH_VIEWS if has_views else GENERIC_WITHOUT_VIEWS))
    where = err.get("file") or ""
    if where and err.get("line") is not None:
        where = f"{where}:{err['line']}"
    return {"code": err.get("code") or "", "problem": problem, "short": problem, "where": where, "actions": actions}


def finding_advice(f: dict) -> str:
    """What to check for a finding, by its code, beyond its own action.

    What to check for a finding, by its code, beyond its own action ("" when nothing more is known; a pairing
    out of step from one image on has its own fix, the order was not lost).
    """
    if is_out_of_step(f):
        return ""
    return _sentence(FINDING_ADVICE.get(str(f.get("code") or ""), ""))


def untrusted_metrics(findings: list[dict]) -> dict[str, str]:
    """Metric key -> the title of the (fail or warn) finding that makes its value untrustworthy."""
    out: dict[str, str] = {}
    for f in findings:
        if f["severity"] not in ("fail", "warn"):
            continue
        for key in UNTRUSTED_METRICS.get(f.get("code", ""), ()):
            out.setdefault(key, str(f.get("title") or f.get("code")))  # a finding has a code
    return out


def _shift_label(shift) -> str:
    """``Pairs shifted by one line`` for a shift of +-1, ``by 2 lines`` for +-2."""
    try:
        n = abs(int(shift))
    except (TypeError, ValueError):
        return "Pairs shifted"
    return "Pairs shifted by one line" if n == 1 else f"Pairs shifted by {n} lines"


def _cause_of_finding(f: dict) -> str:
    """The root cause a finding names: its label and title (``Mode swapped: the data are ...``)."""
    code, title = str(f.get("code") or ""), str(f.get("title") or "").rstrip(".")
    details = details if isinstance(details := f.get("details"), dict) else {}
    if code == "square_size" and title.startswith("The board's "):  # its digits tell the two sizes apart
        label = title[len("The board's ") :]
        return label[:1].upper() + label[1:]
    said = "images and robot poses are shuffled: "  # the label says it already
    if code == "pairs_shuffled" and title.lower().startswith(said):
        title = title[len(said) :]
    if code == "pairs_shifted":
        label = _shift_label(details["shift"]) if "shift" in details else ROOT_CAUSE_LABELS["pairs_shuffled"]
    elif is_out_of_step(f):
        label = PAIRS_OUT_OF_STEP  # from one image on: the title says where
    else:
        label = ROOT_CAUSE_LABELS.get(code, "")
    if not label:
        return _sentence(title).rstrip(".")
    return f"{label}: {title[:1].lower() + title[1:]}" if title else label


def root_cause(res: dict, findings: list[dict]) -> dict | None:
    """The root cause that explains the verdict, for the start of the banner, or None.

    A failed run whose error code names a cause (a refusal: mode_swapped, pairs_shifted, pairs_shuffled, or a
    refusing finding's code) gives ``{"code", "text", "fix", "refused": True}`` with the error's own fix; else
    the first fail, then warn finding with a code of :data:`ROOT_CAUSE_CODES` gives ``{"code", "text", "fix",
    "refused": False}`` with its action. Keyed on codes, never on message text.
    """
    err = err if isinstance(err := res.get("error"), dict) else {}
    code = str(err.get("code") or "")
    refused = res.get("verdict") == "REFUSED" or err.get("type") == "SessionRefused"
    if res.get("status") != "ok" and (refused or code in ROOT_CAUSE_CODES):
        same = [
            f
            for f in findings
            if f.get("code") == code or (code == "pairs_shuffled" and f.get("code") == "pairs_shifted")
        ]
        if same:
            text = _cause_of_finding(same[0])
            if code == "pairs_shuffled" and not text.startswith(
                (ROOT_CAUSE_LABELS["pairs_shuffled"], PAIRS_OUT_OF_STEP)
            ):
                text = ROOT_CAUSE_LABELS["pairs_shuffled"]
        elif code == "pairs_shifted":
            text = _shift_label(None)
        else:
            label = ROOT_CAUSE_LABELS.get(code, "")
            what = str(err.get("what") or "").rstrip(".")
            text = f"{label}: {what[:1].lower() + what[1:]}" if label and what else (label or _sentence(what))
        fix = err.get("fix") or ERROR_ADVICE.get(code) or (same[0].get("action") if same else "")
        if text:
            return {
                "code": code,
                "text": text.rstrip("."),
                "fix": _sentence(fix).rstrip("."),
                "refused": refused,
                "severity": "fail",
            }
    for severity in ("fail", "warn"):
        for f in findings:
            if f.get("severity") == severity and f.get("code") in ROOT_CAUSE_CODES:
                return {
                    "code": f["code"],
                    "text": _cause_of_finding(f),
                    "severity": severity,
                    "fix": _sentence(f.get("action") or FINDING_ADVICE.get(f["code"], "")).rstrip("."),
                    "refused": False,
                }
    return None
