"""Simulated arm and camera that know the ground truth, for dry runs and tests.

The simulated arm keeps a *true* pose and a *reported* pose. Moving to ``T_cmd`` reports exactly
``T_cmd`` (as a controller reports what it believes) while the flange really sits at
``T_true = T_cmd @ inv(dT)``, i.e. ``reported = true @ dT`` with ``dT`` a fresh small transform in
the end frame per motion (the robot-noise convention of :mod:`handeye.sim.scenarios`). The simulated
camera renders the board from the *true* pose through :func:`handeye.sim.render.render_view`, so a
calibration from the reported poses meets the same errors a real one does.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from ..camera import Intrinsics
from ..collect.camera import Camera
from ..collect.robot import PoseReading, Robot
from ..errors import ConfigError, HardwareError
from ..frames import inv_T
from ..kinematics import default_ik_seeds, solve_ik
from ..mounting import mounting
from ..targets import TargetSpec
from .render import render_view
from .robot_error import KinematicRobotError, OneConfiguration, reachable
from .scenarios import (
    DEFAULT_INTRINSICS,
    DEFAULT_TARGET,
    REACH_M,
    arm_workspace,
    perturb_T_base_end,
    plausible_robot_pose,
    sample_setup,
    sample_view_poses,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimRig:
    """Ground truth of a simulated set-up: the hand-eye and board transforms, camera and start pose."""

    mode: str
    T_x: np.ndarray  # T_end_cam (eye_in_hand) or T_base_cam (eye_to_hand)
    T_board: np.ndarray  # T_base_board (eye_in_hand) or T_end_board (eye_to_hand)
    target: TargetSpec
    intrinsics: Intrinsics
    T_base_end_start: np.ndarray  # a pose where the camera sees the whole board, roughly face on

    @staticmethod
    def sample(
        *,
        mode: str,
        rng: np.random.Generator,
        target: TargetSpec = DEFAULT_TARGET,
        intrinsics: Optional[Intrinsics] = None,
        kinematic: Optional[KinematicRobotError] = None,
    ) -> "SimRig":
        """A rig; with ``kinematic`` one sized for that arm whose start pose the arm reaches."""
        intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
        scale, pose_ok = 1.0, None
        extra: dict[str, Any] = {}
        if kinematic is not None:
            scale, extra = arm_workspace(kinematic.arm, mode=mode, target=target)
            pose_ok = lambda T: reachable(kinematic, T) is not None  # noqa: E731
        setup = sample_setup(mode=mode, rng=rng, target=target, workspace_scale=scale)
        T0 = sample_view_poses(
            mode=mode,
            n_views=1,
            rng=rng,
            T_x=setup["T_x"],
            T_board=setup["T_board"],
            target=target,
            intrinsics=intrinsics,
            tilt_deg=(0.0, 8.0),
            roll_deg=10.0,
            aim_deg=2.0,
            pose_ok=pose_ok,
            **extra,
        )[0]
        return SimRig(mode, setup["T_x"], setup["T_board"], target, intrinsics, T0)

    def truth(self) -> dict:
        m = mounting(self.mode)
        return {
            "mode": self.mode,
            m.x_name: self.T_x.tolist(),
            m.board_name: self.T_board.tolist(),
            "intrinsics": self.intrinsics.to_dict(),
            "target": self.target.to_dict(),
            "convention": "T_a_b maps points of frame b into frame a (p_a = T_a_b @ p_b); metres",
        }


class SimRobot(Robot):
    """A simulated arm with pose noise between reported and true poses.

    Without ``kinematic``: per-axis noise in the end frame (``pose_noise_mm``, ``pose_noise_deg``).
    With a :class:`handeye.sim.robot_error.KinematicRobotError`: the controller solves the commanded
    pose on the nominal arm and drives until its encoders read those angles, so it reports the
    commanded pose and those joint angles (``PoseReading.joints``), while the true joints differ by
    the encoder noise and the flange sits where the TRUE arm puts them. Poses the arm cannot reach
    are refused like a real controller refuses them (HardwareError).
    """

    is_real = False

    def __init__(
        self,
        rig: SimRig,
        *,
        pose_noise_mm: float = 0.1,
        pose_noise_deg: float = 0.02,
        rng: Optional[np.random.Generator] = None,
        reach_m: tuple = REACH_M,
        kinematic: Optional[KinematicRobotError] = None,
    ):
        if pose_noise_mm < 0 or pose_noise_deg < 0:
            raise ConfigError(
                "negative simulated pose noise", expected=">= 0", received=f"{pose_noise_mm} mm, {pose_noise_deg} deg"
            )
        self.rig = rig
        self.name = "sim"
        self.pose_noise_mm, self.pose_noise_deg = float(pose_noise_mm), float(pose_noise_deg)
        self.rng = np.random.default_rng() if rng is None else rng
        self.reach_m = reach_m
        self.kinematic = kinematic
        self.joints = None
        self.n_moves = 0
        self._set(rig.T_base_end_start)
        # the poses the planner may ask for: those the arm reaches without flipping over from its start
        self._configuration = None if kinematic is None else OneConfiguration(kinematic)
        if self._configuration is not None:
            self._configuration.joints(self.T_true)

    def _set(self, T_cmd: np.ndarray) -> None:
        if self.kinematic is not None:
            k = self.kinematic
            near = [np.asarray(self.joints, float)] if self.joints is not None else []  # the controller's choice:
            q_enc = solve_ik(k.nominal, T_cmd, seeds=near + default_ik_seeds(k.nominal, T_cmd))  # nearest solution
            if q_enc is None:
                raise HardwareError(
                    "the simulated arm cannot reach the commanded pose",
                    received=f"flange at {np.round(np.asarray(T_cmd)[:3, 3], 3).tolist()} m",
                    hint="plan poses within the arm's reach",
                )
            q_true = q_enc - self.rng.normal(0.0, k.encoder_sigma_rad, size=q_enc.shape)
            self.joints = tuple(float(v) for v in q_enc)
            self.T_reported = k.nominal.T_base_end(q_enc)
            self.T_true = k.true.T_base_end(q_true)
            return
        dT = perturb_T_base_end(np.eye(4), rng=self.rng, sigma_mm=self.pose_noise_mm, sigma_deg=self.pose_noise_deg)[0]
        self.T_reported = np.array(T_cmd, float)
        self.T_true = self.T_reported @ inv_T(dT)

    def describe(self) -> dict:
        if self.kinematic is not None:
            return {"backend": "sim", "robot_error": self.kinematic.describe()}
        return {
            "backend": "sim",
            "pose_noise_mm": self.pose_noise_mm,
            "pose_noise_deg": self.pose_noise_deg,
            "noise_convention": "reported = true @ dT, dT per motion in the end frame, per-axis sigma",
        }

    def read_pose(self) -> PoseReading:
        return PoseReading(self.T_reported.copy(), time.time(), {"errors": [], "backend": "sim"}, self.joints)

    def move_to(self, T_base_end: np.ndarray, *, speed_fraction: float) -> None:
        if not 0 < speed_fraction <= 1:
            raise ConfigError("invalid speed fraction", expected="0 < value <= 1", received=repr(speed_fraction))
        self._set(T_base_end)
        self.n_moves += 1

    def pose_ok(self, T_base_end: np.ndarray) -> bool:
        """Within reach and above the table (used by the planner)."""
        return plausible_robot_pose(T_base_end, self.reach_m) and (
            self._configuration is None or self._configuration(T_base_end)
        )  # the cheap test first

    def T_cam_board_true(self) -> np.ndarray:
        return mounting(self.rig.mode).predict_T_cam_board(self.rig.T_x, self.rig.T_board, self.T_true)

    def simulate_hand_guiding(self) -> None:
        """Interactive sessions: a simulated operator drags the arm to a new pose showing the board."""
        r = self.rig
        pose_ok = None if self.kinematic is None else self.pose_ok
        T = sample_view_poses(
            mode=r.mode,
            n_views=1,
            rng=self.rng,
            T_x=r.T_x,
            T_board=r.T_board,
            target=r.target,
            intrinsics=r.intrinsics,
            pose_ok=pose_ok,
        )[0]
        self._set(T)
        self.n_moves += 1


class SimCamera(Camera):
    """Renders the board as the simulated arm's true pose shows it (8-bit grey, like a mono frame)."""

    def __init__(
        self,
        robot: SimRobot,
        *,
        supersample: int = 2,
        blur_sigma_px: float = 0.0,
        noise_sigma: float = 2.0,
        rng: Optional[np.random.Generator] = None,
    ):
        self.robot = robot
        self.name = "sim"
        self.supersample = int(supersample)
        self.blur_sigma_px = float(blur_sigma_px)
        self.noise_sigma = float(noise_sigma)
        self.rng = np.random.default_rng() if rng is None else rng
        self.n_frames = 0

    def intrinsics(self) -> Intrinsics:
        return self.robot.rig.intrinsics

    def intrinsics_source(self) -> dict:
        return {"kind": "simulated camera (exact)"}

    def describe(self) -> dict:
        return {
            "backend": "sim",
            "supersample": self.supersample,
            "blur_sigma_px": self.blur_sigma_px,
            "noise_sigma_grey": self.noise_sigma,
        }

    def grab(self) -> tuple[np.ndarray, float]:
        r = self.robot.rig
        img = render_view(
            r.target,
            r.intrinsics,
            self.robot.T_cam_board_true(),
            supersample=self.supersample,
            blur_sigma_px=self.blur_sigma_px,
            noise_sigma=self.noise_sigma,
            rng=self.rng,
        )
        self.n_frames += 1
        self.last_frame_info = {"frame_number": self.n_frames}
        return img, time.time()
