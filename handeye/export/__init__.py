"""Export a calibration result where robot software reads it: ROS 2 (static transform launch file and
tf2 YAML), URDF / xacro, MoveIt 2 Calibration's launch file, easy_handeye2's calibration file, plain
YAML / JSON (``handeye export``, ``handeye calibrate --export``).

- :mod:`.frames`   ROS's conventions (tf2 parent -> child, quaternion x y z w, URDF rpy), the optical
  and body camera frames, the default frame names, :class:`ExportTransform`;
- :mod:`.writers`  the text of each format.

Only a usable result is exported: ``status: ok`` and a verdict other than FAIL or REFUSED (``force``
exports a FAIL anyway; a result without a matrix never).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from ..errors import InputError
from .frames import CAMERA_FRAMES, DEFAULT_FRAMES, ExportTransform, camera_transform

#: format -> (the files it writes, from the base name; the one-line description)
FORMATS = {
    "ros2": ((".launch.py", ".tf_static.yaml"), "ROS 2 launch file (static_transform_publisher) + tf2 YAML"),
    "urdf": ((".urdf", ".urdf.xacro"), "URDF fixed joint + xacro macro"),
    "moveit": (
        (".moveit.launch.py", ".moveit.launch"),
        "MoveIt 2 and MoveIt (ROS 1) Calibration's camera pose launch files",
    ),
    "easy_handeye2": ((".calib",), "easy_handeye2's saved calibration"),
    "yaml": ((".yaml",), "frames, matrix, quaternion, rpy, sigmas"),
    "json": ((".json",), "frames, matrix, quaternion, rpy, sigmas"),
}

DEFAULT_BASENAME = "hand_eye"

_UNUSABLE_VERDICTS = ("FAIL", "REFUSED")


def export_transform(
    result,
    *,
    parent: Optional[str] = None,
    child: Optional[str] = None,
    camera_frame: str = "optical",
    force: bool = False,
) -> ExportTransform:
    """The transform to export from a result folder, result.json path or loaded dict.

    Raises :class:`~handeye.errors.InputError` (code ``result_not_usable``) for a result without a
    matrix, and for a FAIL or REFUSED verdict unless ``force``.
    """
    from ..recal.loaded import load_result

    r = load_result(result)
    verdict = str(r.raw.get("verdict") or "none")
    if not r.ok:
        why = r.raw.get("failure_reason") or f"status {r.status}"
        raise InputError(
            f"the result has no usable transform ({why})",
            path=r.source,
            code="result_not_usable",
            hint="export a result whose status is ok",
        )
    if verdict.upper() in _UNUSABLE_VERDICTS and not force:
        head = r.raw.get("verdict_headline") or ""
        raise InputError(
            f"the result's verdict is {verdict}" + (f" ({head})" if head else ""),
            path=r.source,
            code="result_not_usable",
            hint="fix the calibration (see its report), or pass --force to export it anyway",
        )
    if camera_frame not in CAMERA_FRAMES:
        raise InputError(f"unknown camera frame {camera_frame!r}", expected=" | ".join(CAMERA_FRAMES))
    for flag, name in (("--parent", parent), ("--child", child)):
        if name is not None and (not name.strip() or any(c.isspace() or c in "<>\"'&" for c in name)):
            raise InputError(
                f"{flag} {name!r} is not a TF frame name",
                expected="a name without spaces or quotes, e.g. tool0 or camera_color_optical_frame",
            )
    if child is not None:  # ROS names optical frames *_optical_frame (REP 103): a rotation under the other
        optical_name = "optical" in child.lower()  # convention's name is 90 degrees off for every consumer
        if (
            camera_frame == "body"
            and optical_name
            or camera_frame == "optical"
            and not optical_name
            and child.lower().endswith(("_link", "_frame"))
        ):
            other = "optical" if camera_frame == "body" else "body"
            raise InputError(
                f"--child {child} names {'an optical' if optical_name else 'a body'} frame but "
                f"--camera-frame is {camera_frame}",
                expected="the rotation of the frame the name "
                "stands for (ROS: *_optical_frame is x right, y down, z forward)",
                hint=f"use --camera-frame {other}, or a child name of the {camera_frame} frame",
            )
    assert r.T_x is not None, "an ok result has X"
    T, cov = camera_transform(r.T_x, r.cov_x, camera_frame)
    return ExportTransform(
        parent=parent or DEFAULT_FRAMES[r.mode if r.mode in DEFAULT_FRAMES else "eye_in_hand"],
        child=child or DEFAULT_FRAMES["camera_" + camera_frame],
        T_parent_child=T,
        camera_frame=camera_frame,
        mode=r.mode,
        x_name=r.x_name,
        cov_6x6=cov,
        cov_source=r.cov_source,
        source=r.source,
        verdict=verdict,
    )


def export_paths(fmt: str, out: Optional[Path], result_dir: Path) -> list[Path]:
    """The files format ``fmt`` writes (``out`` names the first, or their folder).

    The files format ``fmt`` writes: ``out`` names the first (its companions share its base name),
    or the folder for them; default ``result_dir/hand_eye<suffix>``.
    """
    if fmt not in FORMATS:
        raise InputError(f"unknown export format {fmt!r}", expected=" | ".join(FORMATS))
    suffixes = FORMATS[fmt][0]
    if out is None or Path(out).is_dir():
        base = (result_dir if out is None else Path(out)) / DEFAULT_BASENAME
    else:
        out = Path(out)
        name = out.name
        ending = max((s for s in suffixes if name.endswith(s) and len(name) > len(s)), key=len, default=None)
        if ending is not None:  # one of the format's files named: each file takes its own ending on that name
            base = out.with_name(name[: -len(ending)])
        elif out.suffix:  # another extension than the format's: the first file as named, companions on its stem
            stem = name.split(".", 1)[0] or name
            return [out] + [out.with_name(stem + s) for s in suffixes[1:]]
        else:
            base = out
    return [base.with_name(base.name + s) for s in suffixes]


def render(
    fmt: str,
    e: ExportTransform,
    paths: list[Path],
    *,
    base_frame: Optional[str] = None,
    effector_frame: Optional[str] = None,
) -> list[str]:
    """The text of each file of format ``fmt`` (in the order of ``paths``)."""
    from . import writers as w

    if fmt == "ros2":
        return [w.ros2_launch(e), w.tf_static_yaml(e)]
    if fmt == "urdf":
        return [w.urdf(e), w.xacro(e)]
    if fmt == "moveit":
        return [w.ros2_launch(e, moveit_layout=True), w.moveit1_launch(e)]
    if fmt == "easy_handeye2":
        eye_in_hand = e.mode == "eye_in_hand"
        base = base_frame or (DEFAULT_FRAMES["eye_to_hand"] if eye_in_hand else e.parent)
        effector = effector_frame or (e.parent if eye_in_hand else DEFAULT_FRAMES["eye_in_hand"])
        name = paths[0].name[: -len(".calib")] if paths[0].name.endswith(".calib") else paths[0].stem
        return [w.easy_handeye2_calib(e, name=name, base=base, effector=effector)]
    if fmt == "yaml":
        return [w.plain_yaml(e)]
    return [w.plain_json(e)]


def export_result(
    result,
    fmt: str,
    *,
    out: Optional[Path] = None,
    parent: Optional[str] = None,
    child: Optional[str] = None,
    camera_frame: str = "optical",
    force: bool = False,
    base_frame: Optional[str] = None,
    effector_frame: Optional[str] = None,
) -> list[Path]:
    """Write the export ``fmt`` of ``result`` (a result folder or result.json path); returns the files."""
    from ..output import atomic_write_text

    e = export_transform(result, parent=parent, child=child, camera_frame=camera_frame, force=force)
    for flag, name, mode in (
        ("--base-frame", base_frame, "eye_in_hand"),
        ("--effector-frame", effector_frame, "eye_to_hand"),
    ):
        if name is None:
            continue
        if fmt != "easy_handeye2":
            raise InputError(f"{flag} applies to --to easy_handeye2 only", hint=f"drop {flag}, or use --parent")
        if e.mode != mode:  # the frame the camera hangs from: it is --parent's
            raise InputError(
                f"{flag} names the robot frame of an {mode} calibration, this one is {e.mode}",
                hint=f"the camera's parent frame is --parent (here {e.parent}): use --parent {name}",
            )
    src = Path(e.source)
    paths = export_paths(fmt, out, src.parent)
    texts = render(fmt, e, paths, base_frame=base_frame, effector_frame=effector_frame)
    return [atomic_write_text(p, t) for p, t in zip(paths, texts, strict=False)]
