"""The camera interface the capture loop talks to.

A camera returns frames as numpy arrays (8-bit BGR or grayscale, exactly as delivered: the saved
image is the camera frame, never a preview) with the UNIX time each frame was received, and the
factory intrinsics where the device knows them.
"""

from __future__ import annotations

import abc

import numpy as np

from ..camera import Intrinsics


class Camera(abc.ABC):
    #: short description for the session header, e.g. "realsense D435 #123456"
    name: str = "camera"
    #: details of the last grabbed frame (device frame number, device timestamp), recorded per view
    last_frame_info: dict = {}

    def intrinsics(self) -> Intrinsics | None:
        """Factory intrinsics (OpenCV 5-coefficient model) or None when the device has none."""
        return None

    def intrinsics_source(self) -> dict:
        """Where the intrinsics come from (device, original distortion model, exactness of the mapping)."""
        return {}

    @abc.abstractmethod
    def grab(self) -> tuple[np.ndarray, float]:
        """A fresh frame (H, W[, 3]) uint8 and the UNIX time it was received; HardwareError on failure."""

    def close(self) -> None:  # noqa: B027 - optional hook: a device with nothing to release keeps it
        """Release the device (idempotent)."""

    def describe(self) -> dict:
        return {"backend": self.name}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
