"""The calibration options from a namespace of command-line flags, shared by calibrate and batch.

:func:`options_from_args` builds :class:`handeye.pipeline.CalibrateOptions` from the preset, the site
``--config`` (checked by :func:`check_site_config`) and the flags; :func:`refuse_pose_only_flags`
refuses the flags a pose-only session would ignore, and ``--estimate-scale`` on an image session.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: site config keys of configs/calibration.yaml checked beyond their type (null presets, ranges) -> check
_SITE_CHECKS = {
    "motion.min_rotation_deg": ("a number of degrees >= 0", lambda v: _pos(v) or v == 0),
    "motion.min_axis_spread_deg": ("a number of degrees >= 0", lambda v: _pos(v) or v == 0),
    "min_corners": (
        "a whole number >= 4, or null",
        lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 4,
    ),
    "refine_options.robot_noise": ("estimate | fixed | none", lambda v: v in ("estimate", "fixed", "none")),
    "refine_options.robot_sigma_mm": ("a number > 0 (mm)", lambda v: _pos(v)),
    "refine_options.robot_sigma_deg": ("a number > 0 (degrees)", lambda v: _pos(v)),
    "refine_options.loss": ("huber | cauchy | none", lambda v: v in ("huber", "cauchy", "none")),
    "refine_options.outlier_loop": ("true | false", lambda v: isinstance(v, bool)),
}


def _pos(v) -> bool:
    import math

    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def check_site_config(cfg: dict, *, source) -> dict:
    """The calibration settings whose preset value is null.

    The calibration settings whose preset value is null (any type merges over it) checked by type, and
    the motion gates by range; ConfigError naming the setting and the file.
    """
    from .errors import ConfigError

    for key, (expected, ok) in _SITE_CHECKS.items():
        v: Any = cfg
        for part in key.split("."):
            v = v.get(part) if isinstance(v, dict) else None
        if v is not None and not ok(v):
            raise ConfigError(
                f"invalid setting {key}",
                path=source,
                expected=expected,
                received=repr(v)[:60],
                hint="fix the value in this file",
            )
    return cfg


def options_from_args(args):
    """CalibrateOptions from the preset, the site --config and the command-line flags."""
    from .config import load_with_override
    from .pipeline import CalibrateOptions

    cfg = check_site_config(
        load_with_override("calibration", getattr(args, "config", None)),
        source=getattr(args, "config", None) or "configs/calibration.yaml",
    )
    ro = {}
    if getattr(args, "robot_noise", None):
        ro["robot_noise"] = args.robot_noise
    if getattr(args, "robot_sigma", None):
        ro["robot_sigma_mm"], ro["robot_sigma_deg"] = args.robot_sigma
    if getattr(args, "fix", None):
        ro["fix"] = tuple(args.fix)
    if getattr(args, "robot", None):
        from .kinematics import load_arm

        load_arm(args.robot)  # a wrong name or file is one error line before any work
        ro["arm"] = str(Path(args.robot).resolve()) if Path(args.robot).is_file() else args.robot
    return CalibrateOptions.from_config(
        cfg,
        method=args.method,
        refine=False if args.no_refine else None,
        fix_k3=True if args.fix_k3 else None,
        workers=args.workers,
        shift_poses=getattr(args, "shift_poses", 0) or None,
        estimate_scale=True if getattr(args, "estimate_scale", False) else None,
        robot_accuracy=tuple(args.robot_accuracy) if getattr(args, "robot_accuracy", None) else None,
        refine_options=ro,
    )


#: calibrate's flags that a pose-only session (views with target_pose) has no use for: flag -> why
#: (``--robot`` applies: the arm's kinematic model enters the pose graph, handeye.refine.poseonly_robot)
POSE_ONLY_REFUSED = {
    "robot_noise": (
        "--robot-noise",
        "a pose-only session estimates one noise of the tracker and the robot together (with --robot, the "
        "encoder noise is held at the arm's prior: poses alone cannot tell it from the tracker's)",
    ),
    "robot_sigma": (
        "--robot-sigma",
        "a pose-only session estimates one noise of the tracker and the robot together (state it as "
        "tracker_sigma in session.yaml; --robot models the arm's errors)",
    ),
    "fix": ("--fix", "a pose-only session has no camera intrinsics to hold"),
    "fix_k3": ("--fix-k3", "a pose-only session has no camera intrinsics to hold"),
    "shift_poses": ("--shift-poses", "each view of session.yaml holds its tracker pose and its robot pose together"),
    "prior": (
        "--prior",
        "the prior's test (handeye verify's) works on detected corners, which a pose-only session has not",
    ),
    "board_unmoved": ("--board-unmoved", "it goes with --prior"),
}


def refuse_pose_only_flags(args) -> None:
    """InputError (one line, exit 2) naming every flag given that a pose-only session would ignore, and why.

    Also ``--estimate-scale`` on an image session (its scale is the board's square size).
    """
    from .errors import InputError
    from .session.native import session_kind

    given = [k for k in POSE_ONLY_REFUSED if getattr(args, k, None)]
    scale = bool(getattr(args, "estimate_scale", False))
    if not given and not scale:
        return
    kind = session_kind(args.session)
    if kind != "pose_only":
        if scale and kind == "images":
            raise InputError(
                "--estimate-scale applies to pose-only sessions (views with target_pose): an image session's "
                "scale is the board's square size",
                path=args.session,
                hint="drop --estimate-scale; a wrong square size is named by the square_size finding",
                code="flag_not_applicable",
            )
        return
    if scale and getattr(args, "robot", None):
        raise InputError(
            "--estimate-scale and --robot are not estimated together on a pose-only session",
            path=args.session,
            hint="calibrate with one of them: the scale first (then fix the marker size), then --robot",
            code="flag_not_applicable",
        )
    if not given:
        return

    flags = ", ".join(POSE_ONLY_REFUSED[k][0] for k in given)
    why = (
        POSE_ONLY_REFUSED[given[0]][1]
        if len(given) == 1
        else "; ".join(f"{POSE_ONLY_REFUSED[k][0]}: {POSE_ONLY_REFUSED[k][1]}" for k in given)
    )
    raise InputError(
        f"{flags} {'does' if len(given) == 1 else 'do'} not apply to a pose-only session (views with target_pose): "
        + why,
        path=args.session,
        hint=f"drop {flags}",
        code="flag_not_applicable",
    )
