"""The robot interface the capture loop talks to.

A robot reports the pose of its end (flange or active tool frame) in its base frame as a 4x4
``T_base_end`` in metres, and can be asked to move there. Every backend converts its own pose
convention once, at its boundary, through :mod:`handeye.conventions`.
"""

from __future__ import annotations

import abc
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..frames import pose_error


@dataclass(frozen=True)
class PoseReading:
    """One pose read: ``T_base_end`` (metres), the UNIX time it was read, and the backend's state.

    ``state`` is YAML-friendly (numbers, strings, lists): raw values as the robot sent them, error
    codes under ``errors`` (list of ints, empty when healthy), tool/work frame names. ``joints``: the
    joint angles (radians, encoder readings) when the arm reports them, else None; the session
    writer records them as the view's ``joints``.
    """

    T_base_end: np.ndarray  # (4, 4)
    t_pose: float
    state: dict = field(default_factory=dict)
    joints: Optional[tuple] = None

    @property
    def errors(self) -> list:
        return list(self.state.get("errors", []))


@dataclass(frozen=True)
class StillCheck:
    """Result of two pose reads taken a moment apart; true when they agree."""

    still: bool
    first: PoseReading
    second: PoseReading
    rot_diff_deg: float
    trans_diff_mm: float

    def __bool__(self) -> bool:
        return self.still


def poses_agree(T_a: np.ndarray, T_b: np.ndarray, *, tol_mm: float, tol_deg: float) -> tuple[bool, float, float]:
    """(agree, rotation difference in degrees, translation difference in mm) of two ``T_base_end``."""
    rot_deg, trans_mm = pose_error(np.asarray(T_a, float), np.asarray(T_b, float))
    return (rot_deg <= tol_deg and trans_mm <= tol_mm), rot_deg, trans_mm


class Robot(abc.ABC):
    """What the collector needs from an arm."""

    #: short description for the session header, e.g. "realman 192.168.1.18:8080"
    name: str = "robot"
    #: True for hardware that moves in the real world (its motion needs the user's confirmation)
    is_real: bool = True

    @abc.abstractmethod
    def read_pose(self) -> PoseReading:
        """Current reported pose. Safe to retry; raises HardwareError when the arm cannot answer."""

    @abc.abstractmethod
    def move_to(self, T_base_end: np.ndarray, *, speed_fraction: float) -> None:
        """Move to ``T_base_end`` and return once the motion has finished.

        ``speed_fraction`` in (0, 1] of the arm's maximum speed. Raises HardwareError when the motion
        is refused, fails, or its outcome is unknown; a motion command is never resent blindly.
        """

    def close(self) -> None:  # noqa: B027 - optional hook: a robot with nothing to release keeps it
        """Release the connection (idempotent)."""

    def describe(self) -> dict:
        """What the session header records about this robot."""
        return {"backend": self.name}

    def is_still(self, *, interval_s: float = 0.15, tol_mm: float = 0.2, tol_deg: float = 0.1) -> StillCheck:
        """Two pose reads ``interval_s`` apart agree within tolerance (truthy when still)."""
        first = self.read_pose()
        if interval_s > 0:
            time.sleep(interval_s)
        second = self.read_pose()
        ok, rot_deg, trans_mm = poses_agree(first.T_base_end, second.T_base_end, tol_mm=tol_mm, tol_deg=tol_deg)
        return StillCheck(ok, first, second, rot_deg, trans_mm)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
