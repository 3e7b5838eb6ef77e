"""Synthetic pose-only (tracker) sessions with ground truth.

The camera -> target poses of a corner-level session (:func:`handeye.sim.corners.make_corner_session`),
perturbed by the tracker's noise, and the reported robot poses (gross errors on ``outlier_views`` as
there). The tracker's noise is right-multiplied: ``T_cam_board_measured = T_cam_board_true · Exp(n)``,
``n ~ N(0, diag(s_rot^2 I3, s_trans^2 I3))`` (:mod:`handeye.factors.pose`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np
import yaml

from ..frames import se3_exp
from .corners import make_corner_session


@dataclass(frozen=True)
class TrackerSession:
    """A pose-only session: per view (order of ``view_ids``) the measured ``T_cam_board``.

    A pose-only session: per view (order of ``view_ids``) the measured ``T_cam_board`` (N,4,4) and the
    reported ``T_base_end`` (N,4,4), with the corner session it came from (its ground truth).
    """

    truth: Any  # CornerSession, or another truth with mode, T_x_true, T_board_true, outlier_view_ids
    view_ids: tuple
    T_cam_board: np.ndarray
    T_base_end: np.ndarray
    sigma_mm: float
    sigma_deg: float
    sigma_mm_along: Optional[float] = None  # the translation noise along the optical axis, when not sigma_mm

    @property
    def mode(self) -> str:
        return self.truth.mode

    def write(self, folder: Union[str, Path], *, state_sigma: bool = True) -> Path:
        """A native pose-only session.yaml in ``folder`` (4x4 matrices); ``state_sigma`` writes ``tracker_sigma``."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        d = {
            "handeye_session": 1,
            "mode": self.mode,
            "pose_format": {"rotation": "matrix"},
            "target_pose_format": {"rotation": "matrix"},
            "views": [
                {"id": vid, "pose": self.T_base_end[k].tolist(), "target_pose": self.T_cam_board[k].tolist()}
                for k, vid in enumerate(self.view_ids)
            ],
        }
        if state_sigma:
            sigma: dict[str, float] = {"mm": self.sigma_mm, "deg": self.sigma_deg}
            if self.sigma_mm_along is not None:
                sigma["mm_along"] = self.sigma_mm_along
            d["tracker_sigma"] = sigma
        path = folder / "session.yaml"
        path.write_text(yaml.safe_dump(d, sort_keys=False))
        return path


def make_tracker_session(
    *,
    mode: str = "eye_in_hand",
    n_views: int = 20,
    seed: int = 0,
    sigma_mm: float = 0.5,
    sigma_deg: float = 0.2,
    outlier_views: Union[int, Sequence[str]] = 0,
    **corner_options,
) -> TrackerSession:
    """A tracker session: ``n_views`` views of the corner session of ``seed``.

    A tracker session: ``n_views`` views of the corner session of ``seed`` (noiseless corners, exact robot
    poses unless ``corner_options`` say otherwise), target poses perturbed by the tracker's noise
    (``sigma_mm`` per axis, ``sigma_deg`` per axis) drawn from ``default_rng(seed + 7919)``.
    """
    cs = make_corner_session(
        mode=mode, n_views=n_views, seed=seed, noise_px=0.0, outlier_views=outlier_views, **corner_options
    )
    rng = np.random.default_rng(seed + 7919)
    n = rng.standard_normal((len(cs.view_ids), 6)) * np.r_[[np.radians(sigma_deg)] * 3, [sigma_mm / 1000.0] * 3]
    C = cs.T_cam_board_true @ se3_exp(n)
    return TrackerSession(
        cs, tuple(cs.view_ids), C, np.asarray(cs.T_base_end_reported, float), float(sigma_mm), float(sigma_deg)
    )
