"""ROS's transform conventions, translated once, and the exported transform with its frames.

- A ROS transform ``parent -> child`` (tf2, URDF joint, static_transform_publisher) is handeye's
  ``T_parent_child``: the pose of the child in the parent frame, ``p_parent = T @ p_child``.
- Quaternions in ROS are written ``x, y, z, w``; handeye's are ``w, x, y, z`` inside (w >= 0 here).
- URDF ``rpy`` (and static_transform_publisher's ``--roll --pitch --yaw``) are fixed-axis
  roll-pitch-yaw: ``R = Rz(yaw) · Ry(pitch) · Rx(roll)``, the same convention as the vendor's rx, ry, rz
  (:func:`handeye.conventions.vendor_euler_from_R`).
- handeye's ``cam`` is the camera's optical frame (x right, y down, z forward), ROS's
  ``*_optical_frame``. The body frame of REP 103 (x forward, y left, z up; the RealSense driver's
  ``camera_color_frame``) has the same origin and is turned by the fixed rotation
  :data:`R_OPTICAL_BODY`: ``T_parent_body = T_parent_optical @ T_optical_body``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..conventions import vendor_euler_from_R
from ..errors import InputError
from ..frames import make_T, quat_wxyz_from_R, se3_adjoint

#: the body frame's axes in the optical frame (columns): body x = optical z (forward), body y = -optical x
#: (left), body z = -optical y (up); ``p_optical = R_OPTICAL_BODY @ p_body``
R_OPTICAL_BODY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
T_OPTICAL_BODY = make_T(R_OPTICAL_BODY, np.zeros(3))

CAMERA_FRAMES = ("optical", "body")

#: default frame names: the RealSense ROS 2 driver's colour camera, and the flange / base of the
#: common arm descriptions (ROS-Industrial's ``tool0`` and ``base_link``)
DEFAULT_FRAMES = {
    "camera_optical": "camera_color_optical_frame",
    "camera_body": "camera_color_frame",
    "eye_in_hand": "tool0",
    "eye_to_hand": "base_link",
}

#: a cell camera's default frame names: its name (result.json's ``cameras`` key) with ROS's frame suffixes
CELL_CAMERA_FRAMES = {"optical": "{camera}_optical_frame", "body": "{camera}_link"}

#: what the exported files say about the camera frame
CAMERA_FRAME_TEXT = {
    "optical": "optical frame (x right, y down, z forward; ROS *_optical_frame), handeye's camera frame",
    "body": "body frame (REP 103: x forward, y left, z up), the optical frame turned by the fixed rotation "
    "T_optical_body (quaternion x, y, z, w = 0.5, -0.5, 0.5, 0.5; the RealSense driver's "
    "camera_color_frame -> camera_color_optical_frame is its inverse) at the same origin",
}

#: a frame name every exported format carries as it is: ASCII letters, digits and ``_ . / -``, starting with a
#: letter, digit or ``_`` (tf2 refuses a leading ``/``; a leading ``-`` reads as an option to
#: static_transform_publisher; spaces split ROS 1's ``args``; ``$ { }`` are xacro expressions; quotes and
#: ``< > &`` are markup)
FRAME_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_./-]*")
FRAME_NAME_TEXT = (
    "letters, digits and _ . / - (starting with a letter, digit or _), e.g. tool0 or camera_color_optical_frame"
)


def check_frame_name(name, option: str) -> str:
    """``name`` if it is a frame name (:data:`FRAME_NAME`).

    Else :class:`~handeye.errors.InputError` naming ``option`` (the command-line flag or the field it came from).
    """
    if not isinstance(name, str) or FRAME_NAME.fullmatch(name) is None:
        raise InputError(f"{option} {name!r} is not a TF frame name", expected=FRAME_NAME_TEXT)
    return name


RPY_TEXT = "roll, pitch, yaw [rad], fixed axes: R = Rz(yaw) * Ry(pitch) * Rx(roll) (URDF, tf2)"


def quat_xyzw_from_R(R: np.ndarray) -> np.ndarray:
    """ROS's quaternion order (x, y, z, w) of a rotation, w >= 0."""
    q = quat_wxyz_from_R(R)
    return np.array([q[1], q[2], q[3], q[0]])


def rpy_from_R(R: np.ndarray) -> np.ndarray:
    """URDF ``rpy`` (roll, pitch, yaw) with ``R = Rz(yaw) · Ry(pitch) · Rx(roll)``."""
    return np.asarray(vendor_euler_from_R(R), float)


@dataclass(frozen=True)
class ExportTransform:
    """The transform to export, ``T_parent_child``, with its frames and covariance.

    The transform to export: ``T_parent_child`` (4x4) with its frame names, the camera frame kind,
    the mounting mode and, when the result has one, its covariance ``cov_6x6`` in handeye's tangent
    (right perturbation of ``T_parent_child``, rotation first, radians and metres, child axes).
    """

    parent: str
    child: str
    T_parent_child: np.ndarray
    camera_frame: str  # optical | body
    mode: str
    x_name: str  # the result's own name for the optical transform (T_end_cam | T_base_cam)
    cov_6x6: Optional[np.ndarray]
    cov_source: str
    source: str  # the result.json it came from
    verdict: str
    camera: Optional[str] = None  # the camera of a cell (its name in result.json's cameras)

    def __post_init__(self):
        """Frames and the transform checked once: every writer can put the names into its file as they are."""
        check_frame_name(self.parent, "parent frame")
        check_frame_name(self.child, "child frame")
        if self.camera_frame not in CAMERA_FRAMES:
            raise InputError(f"unknown camera frame {self.camera_frame!r}", expected=" | ".join(CAMERA_FRAMES))
        T = np.asarray(self.T_parent_child, float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError("the transform to export is not a finite 4x4 matrix", received=f"shape {T.shape}")

    @property
    def translation_m(self) -> np.ndarray:
        return self.T_parent_child[:3, 3]

    @property
    def quat_xyzw(self) -> np.ndarray:
        return quat_xyzw_from_R(self.T_parent_child[:3, :3])

    @property
    def rpy_rad(self) -> np.ndarray:
        return rpy_from_R(self.T_parent_child[:3, :3])

    def sigmas(self) -> Optional[dict]:
        """1-sigma of the translation, of roll/pitch/yaw and of the rotation, from ``cov_6x6``.

        1-sigma of the translation (mm, parent axes), of roll/pitch/yaw (deg) and of the rotation
        about the child's axes (deg), propagated from ``cov_6x6``; None without a covariance.
        """
        if self.cov_6x6 is None:
            return None
        from ..report.uncertainty import form_sigmas

        s = form_sigmas(self.T_parent_child, self.cov_6x6)
        return {
            "translation_mm": s["translation_mm"],
            "rpy_deg": s["euler_vendor_deg"],
            "rotation_child_axes_deg": s["rot_cam_deg"],
        }


def camera_transform(T_x_optical: np.ndarray, cov_optical: Optional[np.ndarray], camera_frame: str):
    """``(T_parent_camera, cov)`` for the chosen camera frame.

    The optical one as it is, or the body one ``T_parent_optical @ T_optical_body`` with the
    covariance moved to the body axes (``T·Exp(xi)·C = T·C·Exp(Ad(C^-1) xi)``).
    """
    if camera_frame not in CAMERA_FRAMES:
        raise InputError(f"unknown camera frame {camera_frame!r}", expected=" | ".join(CAMERA_FRAMES))
    T = np.asarray(T_x_optical, float)
    if camera_frame == "optical":
        return T.copy(), None if cov_optical is None else np.asarray(cov_optical, float).copy()
    Ad = se3_adjoint(T_OPTICAL_BODY.T)  # Ad(inv(T_optical_body)); a pure rotation: its inverse is its transpose
    cov = None if cov_optical is None else Ad @ np.asarray(cov_optical, float) @ Ad.T
    return T @ T_OPTICAL_BODY, cov
