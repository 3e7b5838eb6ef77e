"""Views dropped by detection: target_not_found and partial_target.

target_not_found says where the board would have been, from the robot pose and the hand-eye model.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from ..camera import pixels_from_board_points
from ..frames import transform_points
from ..mounting import mounting
from ..records import FAILS_GRID_CHECK, IMAGE_MISSING_REASON, SHIFT_UNPAIRED_REASON
from .findings import Finding
from .thresholds import thresholds


def _image_r2_max(intr) -> float:
    """Largest squared undistorted normalized radius inside the image (the lens model's valid range)."""
    import cv2

    W, H = intr.width, intr.height
    t = np.linspace(0.0, 1.0, 17)
    border = np.concatenate(
        [
            np.c_[t * (W - 1), np.zeros_like(t)],
            np.c_[t * (W - 1), np.full_like(t, H - 1)],
            np.c_[np.zeros_like(t), t * (H - 1)],
            np.c_[np.full_like(t, W - 1), t * (H - 1)],
        ]
    )
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    xy = cv2.undistortPointsIter(  # type: ignore[call-overload]  # OpenCV's stubs: None for R and P
        border.reshape(-1, 1, 2), intr.K, intr.dist_array, None, None, crit
    ).reshape(-1, 2)
    return float(np.max(np.sum(xy**2, axis=1)))


def board_visibility(target, intr, T_cam_board: np.ndarray) -> float:
    """Share (0..1) of the board's corners that project inside the image, in front of the camera.

    Points beyond the image's undistorted radius do not count even if the distortion polynomial folds
    them back into the image.
    """
    obj = target.object_points()
    p_cam = transform_points(T_cam_board, obj)
    front = p_cam[:, 2] > thresholds().detection.min_depth_m
    if not front.any():
        return 0.0
    x = p_cam[front, :2] / p_cam[front, 2:3]
    in_lens = np.sum(x**2, axis=1) <= 1.02 * _image_r2_max(intr)
    uv = pixels_from_board_points(T_cam_board, obj[front], intr)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= intr.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= intr.height - 1)
    return float((inside & in_lens).sum()) / len(obj)


def _why_not_found(run, vid: str, C_pred: np.ndarray) -> str:
    """Look where the board should be in an image whose target was not found: blur, exposure."""
    from ..detect import read_gray
    from ..detect.quality import view_blur, view_exposure
    from ..errors import HandeyeError

    s = run.session
    try:
        gray = read_gray(s.view(vid).image_path)
    except (HandeyeError, KeyError, OSError):
        return " (image unreadable)"
    th = thresholds()
    obj = s.target.object_points()
    uv = pixels_from_board_points(C_pred, obj, run.intrinsics)
    b = view_blur(gray, uv, np.arange(len(obj)), obj, s.target.square_m, charuco=s.target.kind == "charuco")
    e = view_exposure(gray, uv)
    why = []
    if np.isfinite(b["blur_sigma_px"]) and b["blur_sigma_px"] > th.images.blur_warn_px:
        why.append(f"the image is blurred there (edges about {b['blur_sigma_px']:.1f} px)")
    if e["saturated_share"] > th.images.overexposed_warn_share:
        why.append(f"{100 * e['saturated_share']:.0f}% of that region is saturated")
    if np.isfinite(b.get("contrast", np.nan)) and b["contrast"] < th.detection.low_contrast_grey:
        why.append(f"there is little contrast there ({b['contrast']:.0f} grey levels)")
    return (": " + ", ".join(why)) if why else " (blur, exposure, glare or something in front of it?)"


def another_board_size(run):
    """The images' survey (:class:`handeye.detect.board_size.SizeSurvey`) when they show another board size.

    None when the target is no chessboard or the images show no other size than the stated one.
    """
    from ..detect import size_survey

    t = run.session.target
    if t.kind != "chessboard":
        return None
    survey = size_survey({**(run.failures or {}), **(run.detections or {})}, (t.cols, t.rows))
    return survey if survey is not None and survey.likely_size is not None else None


def detection_findings(
    run, *, A: Optional[np.ndarray] = None, B: Optional[np.ndarray] = None, invert_poses: bool = False
) -> list:
    """Dropped views (target not found, too few corners) with where the board would have been.

    ``A``, ``B``: the model ``C_i = A M_i B`` to predict the board with; ``invert_poses`` when the robot
    poses fit only inverted.
    """
    from ..frames import inv_T

    s = run.session
    mount = mounting(s.mode)
    th = thresholds()
    dropped = [o for o in run.outcomes if not o.used and not str(o.reason).startswith("outlier")]
    not_found = [o for o in dropped if o.view_id not in (run.detections or {})]
    n_total = len(run.outcomes) or len(s.views)
    n_found = len(run.detections or {})
    out = []
    intr = run.intrinsics
    can_predict = A is not None and B is not None and intr is not None and intr.width > 0
    few = [o for o in not_found if "corners" in str(o.reason) and "only" in str(o.reason)]
    absent = [o for o in not_found if str(o.reason).startswith(IMAGE_MISSING_REASON)]  # a pose without its image
    unpaired = [o for o in not_found if str(o.reason).startswith(SHIFT_UNPAIRED_REASON)]  # an image without one
    missing = [o for o in not_found if o not in few and o not in absent and o not in unpaired]
    n_total -= len(absent) + len(unpaired)  # images looked at
    notes, cut = {}, {}
    rejected = {o.view_id for o in missing if FAILS_GRID_CHECK in str(o.reason)}  # found, its corners not kept
    for o in missing:
        note = f"view {o.view_id}: {o.reason}"
        if o.view_id in rejected:
            notes[o.view_id] = note + " - the board was found, but a corner lies off its neighbours' grid"
            continue
        try:
            T = s.view(o.view_id).T_base_end
        except KeyError:
            T = None
        if can_predict and T is not None:
            C_pred = A @ mount.M_from_T_base_end(inv_T(T) if invert_poses else T) @ B
            vis = board_visibility(s.target, intr, C_pred)
            if 0.0 < vis < 0.999:
                cut[o.view_id] = (
                    f"not found; at this robot pose only {100 * vis:.0f}% of the board's corners are in the image"
                )
                continue
            if vis == 0.0:
                note += " - at this robot pose the board is outside the image"
            else:
                note += " - at this robot pose the whole board should be in the image" + _why_not_found(
                    run, o.view_id, C_pred
                )
        notes[o.view_id] = note
    missing = [o for o in missing if o.view_id in notes]
    warn_share = th.detection.warn_share
    if missing:
        share = len(missing) / max(n_total, 1)
        failed = n_found < th.views.min_fail
        sev = "fail" if failed else ("warn" if share > warn_share else "info")
        title = (
            f"The target was found in only {n_found} of {n_total} images"
            if failed or share > warn_share
            else f"Target not found in {len(missing)} of {n_total} images (dropped with their poses)"
        )
        action = (
            "check the board size in the session (inner corners, not squares), lighting and focus, and that "
            "the whole board is in every image"
            if failed or share > warn_share
            else "nothing to do if few; otherwise keep the whole board in the image at every robot pose"
        )
        if rejected and len(rejected) == len(missing) and not failed:
            title = f"Board corners rejected in {len(missing)} of {n_total} images (dropped with their poses)"
            action = (
                "nothing to do if few; otherwise look at those images where the corner named lies: a corner on the "
                "wrong point (glare, a pattern or edge behind the board) or a board that is not flat"
            )
        evidence, details = "; ".join(notes[o.view_id] for o in missing), {}
        survey = another_board_size(run) if failed else None
        if survey is not None:  # the images show another board: that is what to fix
            (c, r), (c0, r0) = survey.likely_size, survey.stated
            title = f"The board has {c}x{r} inner corners, not {c0}x{r0} as stated: the target was found in {n_found}"
            title += f" of {n_total} images"
            evidence, action, details = survey.text(), survey.fix(), {"board_size": [c, r]}
        out.append(
            Finding(
                "target_not_found",
                sev,
                title,
                evidence,
                action,
                view_ids=tuple(o.view_id for o in missing),
                details=details,
            )
        )
    if absent:
        out.append(
            Finding(
                "image_missing",
                "info",
                f"{len(absent)} pose line(s) without an image (dropped)",
                "; ".join(f"view {o.view_id}: {o.reason}" for o in absent),
                "nothing to do if those images were deleted on purpose; if the images were renumbered "
                "after a deletion, the later images carry the wrong poses (the pairing check names them)",
                view_ids=tuple(o.view_id for o in absent),
            )
        )
    if unpaired:
        out.append(
            Finding(
                "shift_unpaired",
                "info",
                f"{len(unpaired)} image(s) left without a pose by --shift-poses (dropped)",
                "; ".join(f"view {o.view_id}: {o.reason}" for o in unpaired),
                "nothing to do: with the shift, these images' poses would be past the last line of the pose file",
                view_ids=tuple(o.view_id for o in unpaired),
            )
        )
    partial = [(o.view_id, str(o.reason)) for o in few] + list(cut.items())
    n_board = s.target.n_corners
    for vid, det in (run.detections or {}).items():
        if s.target.kind == "charuco" and len(det.corner_ids) < th.detection.partial_share * n_board:
            partial.append((vid, f"{len(det.corner_ids)} of {n_board} corners"))
    if partial:
        sev = "warn" if len(partial) > warn_share * max(n_total, 1) else "info"
        out.append(
            Finding(
                "partial_target",
                sev,
                f"Board only partly visible in {len(partial)} view(s)",
                "; ".join(f"view {v}: {r}" for v, r in partial),
                "keep the whole board inside the image; partial views add little and corners near the "
                "board's edge constrain the pose poorly",
                view_ids=tuple(v for v, _ in partial),
            )
        )
    return out
