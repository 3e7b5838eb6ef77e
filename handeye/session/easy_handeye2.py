"""easy_handeye2's saved samples (``~/.ros2/easy_handeye2/calibrations/NAME.samples``) as a pose-only session.

Each sample is a ``robot`` and a ``tracking`` transform (tf2 lookups, metres and unit quaternions):
the robot one is ``T_base_end`` eye-in-hand and ``T_end_base`` (inverted here) eye-on-base, the
tracking one ``T_cam_board``. The camera is the tracker's base frame and the board the marker frame;
the session holds 4x4 matrices and its ``source`` block keeps the frame names.

See docs/session_format.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..config import parse_yaml
from ..errors import ConfigError, InputError
from ..frames import R_from_quat_wxyz, inv_T, make_T
from ..output import read_text
from .fields import kind_of_file

#: easy_handeye2's calibration_type -> handeye's mode
MODES = {"eye_in_hand": "eye_in_hand", "eye_on_base": "eye_to_hand"}


def _transform(t, *, path: Path, where: str) -> np.ndarray:
    """A geometry_msgs/Transform mapping as a 4x4 matrix; InputError naming the sample otherwise."""
    try:
        tr, rot = t["translation"], t["rotation"]
        xyz = np.array([float(tr[k]) for k in "xyz"])
        q = np.array([float(rot[k]) for k in "wxyz"])
    except (TypeError, KeyError, ValueError):
        raise InputError(
            f"{where} is not a transform",
            path=path,
            received=repr(t)[:80],
            expected="{translation: {x, y, z}, rotation: {x, y, z, w}}",
        ) from None
    if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(q))):
        raise InputError(f"{where} holds a number that is not finite", path=path, received=repr(t)[:80])
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > 1e-3:
        raise InputError(
            f"{where}: the rotation quaternion's norm is {n:.4g}, not 1",
            path=path,
            expected="a unit quaternion x, y, z, w",
        )
    return make_T(R_from_quat_wxyz(q / n), xyz)


def read_samples(
    path: str | Path, *, mode: Optional[str] = None
) -> tuple[Optional[str], dict[str, Any], list[tuple[np.ndarray, np.ndarray]]]:
    """(mode, parameters, pose pairs) of an easy_handeye2 ``.samples`` file.

    (mode, parameters, [(T_base_end, T_cam_board), ...]) of a ``.samples`` file. ``mode`` (handeye's name)
    is needed when the file's ``calibration_type`` is empty, and must agree with it otherwise.
    """
    path = Path(path)
    d = parse_yaml(read_text(path, what="samples file"), path=path)
    if not isinstance(d, dict) or not isinstance(d.get("samples"), list):
        kind = kind_of_file(d)
        raise InputError(
            "not an easy_handeye2 samples file: no samples list",
            path=path,
            expected="parameters: {...} and samples: [{robot: ..., tracking: ...}, ...]",
            hint=f"this looks like {kind}" if kind else None,
        )
    params = d.get("parameters") or {}
    if not isinstance(params, dict):
        raise InputError("parameters must be a mapping", path=path, received=repr(params)[:60])
    ctype = params.get("calibration_type") or ""
    if ctype and ctype not in MODES:
        raise InputError("unknown calibration_type", path=path, expected=" | ".join(MODES), received=repr(ctype))
    stated = MODES.get(ctype)
    if mode is None and stated is None:
        raise ConfigError(
            "the samples do not say the calibration type (calibration_type is empty)",
            path=path,
            expected="eye_in_hand or eye_on_base",
            hint="give --mode eye_in_hand or --mode eye_to_hand: "
            "it also says how easy_handeye2 stored the robot poses (T_base_end or T_end_base)",
        )
    if mode is not None and stated is not None and mode != stated:
        raise ConfigError(
            f"--mode {mode} but the samples are {ctype}", path=path, hint=f"leave --mode out, or give --mode {stated}"
        )
    mode = mode or stated
    if len(d["samples"]) < 3:
        raise InputError(f"{len(d['samples'])} samples; at least 3 are needed", path=path)
    pairs = []
    for k, s in enumerate(d["samples"], start=1):  # sample k is view k of the session, as MoveIt's are
        if not isinstance(s, dict) or "robot" not in s or not ("tracking" in s or "optical" in s):
            raise InputError(f"sample {k}: needs robot and tracking transforms", path=path, received=repr(s)[:80])
        robot = _transform(s["robot"], path=path, where=f"sample {k} robot")
        tracking = _transform(s.get("tracking", s.get("optical")), path=path, where=f"sample {k} tracking")
        pairs.append((robot if mode == "eye_in_hand" else inv_T(robot), tracking))
    return mode, params, pairs


def import_easy_handeye2(
    src: str | Path,
    out: str | Path,
    *,
    mode: Optional[str] = None,
    tracker_sigma: Optional[tuple] = None,
    force: bool = False,
) -> Path:
    """``out/session.yaml``: the pose-only session of an easy_handeye2 ``.samples`` file.

    ``out/session.yaml``: the pose-only session of an easy_handeye2 ``.samples`` file (views ``1``..``N`` in
    the file's order). ``tracker_sigma``: (mm, deg) of the tracker when known (else estimated at calibration).
    """
    src = Path(src)
    mode, params, pairs = read_samples(src, mode=mode)
    frames = (
        "name",
        "calibration_type",
        "robot_base_frame",
        "robot_effector_frame",
        "tracking_base_frame",
        "tracking_marker_frame",
    )
    named = {k: params.get(k) for k in frames if params.get(k)}
    source = {"tool": "easy_handeye2", "file": str(src.resolve()), **named}
    from .importers import write_pose_only_session

    return write_pose_only_session(out, mode=mode, source=source, pairs=pairs, tracker_sigma=tracker_sigma, force=force)
