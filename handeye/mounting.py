"""The one hand-eye model that serves both mounting modes.

Both modes are ``T_cam_board_i = A · M_i · B`` with a known robot motion ``M_i`` and two constant
unknowns: eye-in-hand ``A = T_cam_end``, ``M_i = T_end_base_i``, ``B = T_base_board``; eye-to-hand
``A = T_cam_base``, ``M_i = T_base_end_i``, ``B = T_end_board``. The reported unknown X is ``inv(A)``
(``T_end_cam`` or ``T_base_cam``). The two adapters below are the only place where the modes differ.

See docs/conventions.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ConfigError
from .frames import inv_T

MODES = ("eye_in_hand", "eye_to_hand")


@dataclass(frozen=True)
class MountingMode:
    name: str
    x_name: str  # name of the hand-eye unknown in results
    board_name: str  # name of the constant board transform
    fixed_frame: str  # frame the camera is rigid to
    board_frame: str  # frame the board is rigid to
    inverts_robot: bool  # M_i = inv(T_base_end_i) (eye-in-hand) rather than T_base_end_i
    camera_location: str  # words for messages: where the camera is
    board_location: str  # words for messages: where the board is

    @property
    def camera_moves(self) -> bool:
        """True when the camera rides on the robot (eye-in-hand): its base pose changes with every view."""
        return self.inverts_robot

    @property
    def other(self) -> "MountingMode":
        """The other mounting mode (for "the mode looks swapped" checks)."""
        return EYE_TO_HAND if self is EYE_IN_HAND else EYE_IN_HAND

    def M_from_T_base_end(self, T_base_end: np.ndarray) -> np.ndarray:
        """Robot motion M_i for (N,4,4) or (4,4) reported poses ``T_base_end``."""
        return inv_T(T_base_end) if self.inverts_robot else np.asarray(T_base_end, float)

    def T_base_end_from_M(self, M: np.ndarray) -> np.ndarray:
        return inv_T(M) if self.inverts_robot else np.asarray(M, float)

    @staticmethod
    def A_from_X(T_x: np.ndarray) -> np.ndarray:
        return inv_T(T_x)

    @staticmethod
    def X_from_A(A: np.ndarray) -> np.ndarray:
        return inv_T(A)

    def predict_T_cam_board(self, T_x: np.ndarray, T_board: np.ndarray, T_base_end: np.ndarray) -> np.ndarray:
        """``T_cam_board`` for each robot pose (N,4,4) under a hand-eye solution."""
        return inv_T(T_x) @ self.M_from_T_base_end(T_base_end) @ T_board

    def T_base_cam(self, T_x: np.ndarray, T_base_end: np.ndarray | None) -> np.ndarray:
        """Camera in the base frame at robot pose(s) ``T_base_end`` (4,4)/(N,4,4).

        Camera in the base frame at robot pose(s) ``T_base_end`` (4,4)/(N,4,4) (eye-to-hand: constant,
        the pose may be None). Eye-in-hand without a robot pose is a :class:`ConfigError`.
        """
        if not self.inverts_robot:
            return np.asarray(T_x, float)
        if T_base_end is None:
            raise ConfigError(
                "eye-in-hand needs the robot's end pose at the time the camera saw the point",
                hint="pass --end-pose x y z rx ry rz (metres, radians, R = Rz·Ry·Rx)",
            )
        return np.asarray(T_base_end, float) @ np.asarray(T_x, float)

    def T_base_board(self, T_board: np.ndarray, T_base_end: np.ndarray) -> np.ndarray:
        """Board in the base frame at robot pose(s) ``T_base_end`` (eye-in-hand: constant)."""
        if self.inverts_robot:
            return np.asarray(T_board, float)
        return np.asarray(T_base_end, float) @ np.asarray(T_board, float)


EYE_IN_HAND = MountingMode(
    "eye_in_hand",
    "T_end_cam",
    "T_base_board",
    "end",
    "base",
    inverts_robot=True,
    camera_location="on the robot's flange",
    board_location="on the table",
)
EYE_TO_HAND = MountingMode(
    "eye_to_hand",
    "T_base_cam",
    "T_end_board",
    "base",
    "end",
    inverts_robot=False,
    camera_location="beside the robot",
    board_location="in the gripper",
)


def mounting(mode: str) -> MountingMode:
    if mode == "eye_in_hand":
        return EYE_IN_HAND
    if mode == "eye_to_hand":
        return EYE_TO_HAND
    raise ConfigError(
        "unknown mounting mode",
        expected=" | ".join(MODES),
        received=repr(mode),
        hint="use --mode eye_in_hand or --mode eye_to_hand",
    )
