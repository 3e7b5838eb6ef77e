"""Given intrinsics against the images: zero_distortion_given, intrinsics_mismatch.

The given intrinsics are compared with calibrateCamera on the same corners (only focal length and
centre refitted without distortion, then the full 5-coefficient model).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from ..camera import Intrinsics, pixels_from_board_points, pixels_from_cam_points
from ..errors import HandeyeError
from ..frames import T_from_rotvec
from .findings import Finding
from .thresholds import thresholds

log = logging.getLogger(__name__)


def distortion_findings(run) -> list:
    """Given intrinsics without distortion (or that do not fit) against calibrateCamera on the same corners."""
    import cv2

    from ..initial import calibrate_intrinsics
    from ..initial.intrinsics import opencv_serial

    s = run.session
    given = s.intrinsics
    if given is None or s.intrinsics_prior not in ("fixed", "prior") or len(run.detections or {}) < 3:
        return []
    obj = s.target.object_points()
    ids = [v for v in run.detections if v in (run.board_poses or {})]
    if len(ids) < 3:
        return []
    th = thresholds().intrinsics
    dets = [replace(run.detections[v], corner_ids=run.board_poses[v].corner_ids) for v in ids]
    n_pts = np.array([len(d.corner_ids) for d in dets])
    rms_given = float(np.sqrt(np.sum(n_pts * np.array([run.board_poses[v].rms_px for v in ids]) ** 2) / n_pts.sum()))
    W, H = given.width, given.height
    objs = [obj[d.corner_ids].astype(np.float32) for d in dets]
    imgs = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in dets]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    flags0 = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_FIX_K1
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
        | cv2.CALIB_ZERO_TANGENT_DIST
    )
    try:
        with opencv_serial():
            rms_pin, K_pin, _, rv, tv = cv2.calibrateCamera(
                objs, imgs, (W, H), given.K.copy(), np.zeros(5), flags=flags0, criteria=crit
            )
        fit, rms_full = calibrate_intrinsics(dets, obj, fix_k3=len(dets) < 10)
    except (cv2.error, HandeyeError) as e:  # a fit that cannot be made only means no finding
        log.info("distortion check: calibrateCamera failed: %s", e)
        return []
    pinhole = Intrinsics.from_K(K_pin, np.zeros(5), W, H)
    fit_vec = fit.as_vector()
    fit_undistorted = np.concatenate([fit_vec[:4], np.zeros(5)])
    zero_dist = bool(np.all(np.abs(given.dist_array) < 1e-12))
    effect = float(np.sqrt(max(rms_pin**2 - rms_full**2, 0.0)))
    # how far the fitted lens moves the detected corners, and how radial the pinhole fit's residuals are
    shifts, radial_e, tot_e = [], 0.0, 0.0
    for o, im, r, t in zip(objs, imgs, rv, tv, strict=False):
        p_pin = pixels_from_board_points(T_from_rotvec(r.reshape(3), t.reshape(3)), o, pinhole)
        res = im.reshape(-1, 2) - p_pin
        d = p_pin - np.array([K_pin[0, 2], K_pin[1, 2]])
        er = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
        radial_e += float(np.sum(np.einsum("ni,ni->n", res, er) ** 2))
        tot_e += float(np.sum(res**2))
        xn = cv2.undistortPoints(im, fit.K, fit.dist_array).reshape(-1, 2)  # the lens model's inverse
        rays = np.c_[xn, np.ones(len(xn))]
        p_d = pixels_from_cam_points(fit_vec, rays, jacobians=False)[0]
        p_u = pixels_from_cam_points(fit_undistorted, rays, jacobians=False)[0]
        shifts.append(np.linalg.norm(p_d - p_u, axis=1))
    shift95 = float(np.percentile(np.concatenate(shifts), 95))
    radial_share = radial_e / max(tot_e, 1e-12)
    details = {
        "rms_given_px": rms_given,
        "rms_pinhole_fit_px": float(rms_pin),
        "rms_full_fit_px": float(rms_full),
        "distortion_effect_px": effect,
        "corner_shift_p95_px": shift95,
        "radial_share": radial_share,
        "fitted": fit.to_dict(),
    }
    dist_txt = ", ".join(f"{n}={v:+.4f}" for n, v in zip(("k1", "k2", "p1", "p2", "k3"), fit.dist, strict=False))
    if zero_dist:
        ratio = rms_full / max(rms_given, 1e-12)
        if effect < th.dist_info_px or ratio > th.dist_rms_ratio:
            return []
        warn = effect >= th.dist_warn_px and shift95 >= th.dist_warn_shift_px
        ev = (
            f"with the given intrinsics (no distortion) the corners fit to {rms_given:.2f} px RMS, refitting only "
            f"the focal length and centre to {rms_pin:.2f} px, adding distortion ({dist_txt}) to {rms_full:.2f} px; "
            f"the distortion explains {effect:.2f} px RMS, moves the detected corners by up to {shift95:.1f} px "
            f"(95th percentile), and {100 * radial_share:.0f}% of the distortion-free residual points radially"
        )
        return [
            Finding(
                "zero_distortion_given",
                "warn" if warn else "info",
                "The given intrinsics have no lens distortion, but the images show distortion"
                if warn
                else "The given intrinsics have no lens distortion; the images show a little",
                ev,
                "estimate the intrinsics from the images (drop the intrinsics section or set use: "
                "initial), or give the lens's distortion coefficients",
                details=details,
            )
        ]
    if rms_given > th.mismatch_ratio * rms_full and rms_given > rms_full + th.mismatch_px:
        return [
            Finding(
                "intrinsics_mismatch",
                "warn",
                "The given intrinsics do not fit the images",
                f"with the given intrinsics the corners fit to {rms_given:.2f} px RMS, with intrinsics fitted "
                f"to the same corners to {rms_full:.2f} px",
                "check that the intrinsics belong to this camera and resolution, or let handeye estimate them",
                details=details,
            )
        ]
    return []
