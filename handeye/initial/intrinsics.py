"""Camera intrinsics from the detected views: OpenCV's calibrateCamera (5-coefficient model)."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator, Sequence

import cv2
import numpy as np

from ..camera import Intrinsics
from ..errors import CalibrationError, DetectionError
from ..records import Detection

_SERIAL = threading.Lock()


@contextmanager
def opencv_serial() -> Iterator[None]:
    """OpenCV on one thread inside the block, its thread count restored after.

    calibrateCamera sums its normal equations over views in parallel chunks whose split follows the thread
    pool's timing, so with more than one thread the same corners give intrinsics that differ in their last
    bits from run to run; those bits reach X and every choice made on it (e.g. ``verify --plan``'s greedy
    pose choice). One thread makes the result a function of the input. The lock keeps concurrent callers
    from restoring each other's count.
    """
    with _SERIAL:
        n = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            yield
        finally:
            cv2.setNumThreads(n)


def calibrate_intrinsics(
    detections: Sequence[Detection], object_points: np.ndarray, *, fix_k3: bool = False
) -> tuple[Intrinsics, float]:
    """OpenCV calibrateCamera (5-coefficient model) on the detected views: (intrinsics, rms_px).

    ``object_points`` (M,3) are the target's points in the board frame, indexed by the detections'
    ``corner_ids``.
    """
    if len(detections) < 3:
        raise DetectionError(
            f"only {len(detections)} views with a detected target; calibrating the camera needs 3+",
            hint="capture more views with the whole board visible",
            code="target_not_found",
        )
    obj = [object_points[d.corner_ids].astype(np.float32) for d in detections]
    img = [d.image_points.astype(np.float32).reshape(-1, 1, 2) for d in detections]
    w, h = detections[0].image_size
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    with opencv_serial():  # reproducible to the bit (see opencv_serial)
        rms, K, dist, _, _ = cv2.calibrateCamera(
            obj,
            img,
            (int(w), int(h)),
            None,
            None,
            flags=flags,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12),
        )
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0:
        raise CalibrationError(
            "camera calibration failed",
            hint="check the board size in the config and the images",
            code="camera_calibration_failed",
        )
    return Intrinsics.from_K(K, dist, w, h), float(rms)
