"""MoveIt Calibration's saved samples (the Calibrate tab's "Save samples") as a pose-only session.

The file is a YAML list, one map per sample: ``effector_wrt_world`` (the end effector in the robot base
frame, ``T_base_end``) and ``object_wrt_sensor`` (the calibration board in the camera frame,
``T_cam_board``), each 16 numbers of a 4x4 matrix row by row, metres. The file does not say how the camera
is mounted (a setting of the tool): ``--mode`` says it, else the data decide at calibration.

See docs/session_format.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ..config import parse_yaml
from ..conventions import PoseFormat, T_from_pose_values
from ..errors import InputError
from ..output import read_text
from .fields import kind_of_file

KEYS = ("effector_wrt_world", "object_wrt_sensor")
_MATRIX = PoseFormat(rotation="matrix")


def read_moveit_samples(path: str | Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(T_base_end, T_cam_board), ...] of a MoveIt Calibration samples file, in its order."""
    path = Path(path)
    d = parse_yaml(read_text(path, what="samples file"), path=path)
    if not isinstance(d, list) or not all(isinstance(s, dict) for s in d):
        kind = kind_of_file(d)
        raise InputError(
            "not a MoveIt Calibration samples file: not a list of samples",
            path=path,
            expected="- {effector_wrt_world: [16 numbers], object_wrt_sensor: [16 numbers]} per sample",
            hint=f"this looks like {kind}" if kind else None,
        )
    if len(d) < 3:
        raise InputError(f"{len(d)} samples; at least 3 are needed", path=path)
    pairs = []
    for k, s in enumerate(d, start=1):
        Ts = []
        for key in KEYS:
            values = s.get(key)
            try:
                if not isinstance(values, list):
                    raise ValueError(f"expected a list of 16 numbers, got {type(values).__name__}")
                Ts.append(T_from_pose_values(values, _MATRIX))
            except (ValueError, TypeError) as e:
                raise InputError(
                    f"sample {k} {key}: {e}", path=path, expected="16 numbers, a 4x4 matrix row by row"
                ) from None
        pairs.append((Ts[0], Ts[1]))
    return pairs


def import_moveit_samples(
    src: str | Path,
    out: str | Path,
    *,
    mode: Optional[str] = None,
    tracker_sigma: Optional[tuple] = None,
    force: bool = False,
) -> Path:
    """``out/session.yaml``: the pose-only session of a MoveIt Calibration samples file.

    Views ``1``..``N`` in the file's order. ``mode``: the camera's mounting (None: decided from the data at
    calibration). ``tracker_sigma``: (mm, deg) of the board poses when known (else estimated at calibration).
    """
    from .importers import write_pose_only_session

    src = Path(src)
    pairs = read_moveit_samples(src)
    source = {"tool": "moveit_calibration", "file": str(src.resolve())}
    return write_pose_only_session(out, mode=mode, source=source, pairs=pairs, tracker_sigma=tracker_sigma, force=force)
