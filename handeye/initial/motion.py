"""Motion quality: whether the robot's relative rotations determine the hand-eye transform.

The hand-eye problem ``C_i = A · M_i · B`` is solvable only when the relative motions ``M_i M_j^-1``
include rotations about at least two different axes (Tsai and Lenz 1989). :func:`motion_quality` is
the one computation of that coverage, used by the pipeline (to stop), the diagnostics (to explain)
and the simulator/planner (to check a plan). Its thresholds live in configs/calibration.yaml
(``motion:``) and nowhere else.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from ..frames import inv_T, rotvec_from_R


@dataclass(frozen=True)
class MotionThresholds:
    """The degeneracy gates, from configs/calibration.yaml ``motion:`` (degrees)."""

    min_rotation_deg: float
    min_axis_spread_deg: float

    @staticmethod
    def from_config(cfg: dict[str, Any]) -> "MotionThresholds":
        m = cfg["motion"]
        return MotionThresholds(float(m["min_rotation_deg"]), float(m["min_axis_spread_deg"]))


@functools.lru_cache(maxsize=1)
def default_thresholds() -> MotionThresholds:
    """The shipped thresholds (configs/calibration.yaml), read once."""
    from ..config import load_preset

    return MotionThresholds.from_config(load_preset("calibration"))


@dataclass(frozen=True)
class MotionQuality:
    n_views: int
    max_rotation_deg: float
    axis_spread_deg: float  # how far the relative rotation axes leave their main direction
    main_axis: np.ndarray  # (3,) in the frame where M's rotations act
    weak_axes: np.ndarray  # (2, 3) directions with little rotation, weakest first
    status: str  # ok | degenerate
    reason: str
    code: str = ""  # "", too_few_views, motion_small_rotation, motion_one_axis (as the errors' codes)
    min_rotation_deg: float = float("nan")  # the thresholds this was judged with
    min_axis_spread_deg: float = float("nan")


def _rotation_axes(M: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Largest relative rotation (deg) and the eigen-decomposition.

    Largest relative rotation (deg) and the eigen-decomposition (ascending) of the weighted
    scatter of the relative rotation vectors over all pairs ``M_i M_j^-1``.
    """
    n = len(M)
    iu, ju = np.triu_indices(n, 1)
    rv = rotvec_from_R((M[iu] @ inv_T(M[ju]))[:, :3, :3])  # shape (P, 3)
    ang = np.linalg.norm(rv, axis=1)
    W = rv * np.minimum(ang, np.pi / 2)[:, None] / np.maximum(ang, 1e-12)[:, None]  # sin-like weights
    evals, evecs = np.linalg.eigh(W.T @ W)  # ascending
    return float(np.degrees(ang.max())), evals, evecs


def motion_quality(
    M: np.ndarray, *, frame: str, min_rotation_deg: Optional[float] = None, min_axis_spread_deg: Optional[float] = None
) -> MotionQuality:
    """Rotation coverage of the robot motions ``M`` (N,4,4) for the hand-eye problem.

    ``frame`` names the frame the axes are expressed in (for the message). A threshold left at None
    is the one in configs/calibration.yaml (``motion:``).
    """
    d = default_thresholds()
    min_rot = d.min_rotation_deg if min_rotation_deg is None else float(min_rotation_deg)
    min_spread = d.min_axis_spread_deg if min_axis_spread_deg is None else float(min_axis_spread_deg)
    M = np.asarray(M, float)
    n = len(M)
    gates = dict(min_rotation_deg=min_rot, min_axis_spread_deg=min_spread)
    if n < 3:
        return MotionQuality(
            n,
            0.0,
            0.0,
            np.zeros(3),
            np.eye(3)[:2],
            "degenerate",
            f"only {n} usable views; the hand-eye solution needs at least 3 (10-20 recommended)",
            "too_few_views",
            **gates,
        )
    max_deg, evals, evecs = _rotation_axes(M)
    main = evecs[:, 2]
    spread = float(np.degrees(np.arctan2(np.sqrt(max(evals[1], 0)), np.sqrt(max(evals[2], 1e-30)))))
    weak = evecs[:, :2].T
    if max_deg < min_rot:
        return MotionQuality(
            n,
            max_deg,
            spread,
            main,
            weak,
            "degenerate",
            f"the robot rotates at most {max_deg:.1f} deg between views (needs {min_rot:g}); add "
            f"views tilted by 20-45 deg about two different axes of the {frame} frame",
            "motion_small_rotation",
            **gates,
        )
    if spread < min_spread:
        return MotionQuality(
            n,
            max_deg,
            spread,
            main,
            weak,
            "degenerate",
            f"all rotations are about one axis ({_vec_text(main)} in the {frame} frame, spread "
            f"{spread:.1f} deg, needs {min_spread:g}); add views rotated 20-45 deg about "
            f"{_vec_text(weak[1])} and {_vec_text(weak[0])}",
            "motion_one_axis",
            **gates,
        )
    return MotionQuality(n, max_deg, spread, main, weak, "ok", "", "", **gates)


# ------------------------------------------------------------------------------ axis text
def _vec_text(a: np.ndarray) -> str:
    """A direction as ``[+0.00, +1.00, +0.00]``, signed so that its largest component is positive."""
    a = np.asarray(a, float) / max(float(np.linalg.norm(a)), 1e-12)
    a = a if a[np.argmax(np.abs(a))] >= 0 else -a
    return "[" + ", ".join(f"{x:+.2f}" for x in a) + "]"


def axis_text(a: np.ndarray, frame: str) -> str:
    """A direction in words: ``the base z axis [+0.00, +0.00, +1.00]`` when it is close to a frame axis.

    A direction in words: ``the base z axis [+0.00, +0.00, +1.00]`` when it is close to a frame
    axis (within ~25 deg), else ``[...] in the base frame``.
    """
    a = np.asarray(a, float) / max(float(np.linalg.norm(a)), 1e-12)
    a = a if a[np.argmax(np.abs(a))] >= 0 else -a
    k = int(np.argmax(np.abs(a)))
    if abs(a[k]) > 0.9:
        return f"the {frame} {'xyz'[k]} axis {_vec_text(a)}"
    return f"{_vec_text(a)} in the {frame} frame"


def rotations_to_add(M: np.ndarray, frame: str, *, R: Optional[np.ndarray] = None) -> str:
    """The axes the relative robot rotations lack, in words (``R`` maps them into another frame).

    When the two least-rotated directions are about equally weak (all rotations about one axis), any
    two axes across the main axis will do: name the frame's axes closest to that plane.
    """
    ev, V = _rotation_axes(np.asarray(M, float))[1:]
    if R is not None:
        V = R @ V
    weak1, weak2, main = V[:, 0], V[:, 1], V[:, 2]
    if ev[1] < 4.0 * max(ev[0], 1e-12 * max(ev[2], 1e-12)):  # a weak plane: rotations about one axis only
        k = int(np.argmax(np.abs(main)))
        if abs(main[k]) > 0.9:
            a, b = [name for m, name in enumerate("xyz") if m != k]
            return (
                f"the {frame} {a} axis and the {frame} {b} axis (across the {frame} {'xyz'[k]} axis, the only one used)"
            )
        return (
            f"two axes across {axis_text(main, frame)} (the only one used), e.g. {axis_text(weak1, frame)} and "
            f"{axis_text(weak2, frame)}"
        )
    return axis_text(weak1, frame)
