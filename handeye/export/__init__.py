"""Export a calibration result where robot software reads it (``handeye export``, ``calibrate --export``).

Formats: ROS 2 (static transform launch file and tf2 YAML), URDF / xacro, MoveIt 2 Calibration's
launch file, easy_handeye2's calibration file, plain YAML / JSON.

- :mod:`.frames`   ROS's conventions (tf2 parent -> child, quaternion x y z w, URDF rpy), the optical
  and body camera frames, the default frame names, :class:`ExportTransform`;
- :mod:`.writers`  the text of each format.

Only a usable result is exported: ``status: ok`` and a verdict other than FAIL or REFUSED (``force``
exports a FAIL anyway; a result without a matrix never). See docs/export.md.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Optional

from ..errors import InputError
from .frames import (
    CAMERA_FRAMES,
    CELL_CAMERA_FRAMES,
    DEFAULT_FRAMES,
    ExportTransform,
    camera_transform,
    check_frame_name,
)

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
    camera: Optional[str] = None,
) -> ExportTransform:
    """The transform to export from a result folder, result.json path or loaded dict (a cell: camera ``camera``).

    Raises :class:`~handeye.errors.InputError` (code ``result_not_usable``) for a result without a
    matrix, and for a FAIL or REFUSED verdict unless ``force``. A cell's camera is named in the messages and its
    frame is by default ``<camera>_optical_frame`` (``<camera>_link`` with the body frame).
    """
    from ..recal.loaded import load_result

    r = load_result(result, camera=camera, absolute=True)
    verdict = str(r.raw.get("verdict") or "none")
    if not r.ok:
        why = r.raw.get("failure_reason") or f"status {r.status}"
        raise InputError(
            f"the result has no usable transform ({why})",
            path=r.label,
            code="result_not_usable",
            hint="export a result whose status is ok",
        )
    if verdict.upper() in _UNUSABLE_VERDICTS and not force:
        head = r.raw.get("verdict_headline") or ""
        raise InputError(
            f"the result's verdict is {verdict}" + (f" ({head})" if head else ""),
            path=r.label,
            code="result_not_usable",
            hint="fix the calibration (see its report), or pass --force to export it anyway",
        )
    if r.mode not in ("eye_in_hand", "eye_to_hand"):  # the parent frame and every file's words depend on it
        raise InputError(
            f"the result's mode {r.mode!r} is not a mounting mode",
            path=r.label,
            expected="eye_in_hand | eye_to_hand",
            hint="calibrate the session again, or restore result.json",
        )
    if camera_frame not in CAMERA_FRAMES:
        raise InputError(f"unknown camera frame {camera_frame!r}", expected=" | ".join(CAMERA_FRAMES))
    for flag, name in (("--parent", parent), ("--child", child)):
        if name is not None:
            check_frame_name(name, flag)
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
    own = DEFAULT_FRAMES["camera_" + camera_frame]
    if r.camera is not None:
        own = CELL_CAMERA_FRAMES[camera_frame].format(camera=r.camera)
    parent, child = parent or DEFAULT_FRAMES[r.mode if r.mode in DEFAULT_FRAMES else "eye_in_hand"], child or own
    if parent == child:  # a frame is not its own parent (tf2 and URDF refuse it)
        raise InputError(
            f"--parent and --child name the same frame {parent!r}",
            hint="give the robot frame as --parent and the camera frame as --child",
        )
    return ExportTransform(
        parent=parent,
        child=child,
        T_parent_child=T,
        camera_frame=camera_frame,
        mode=r.mode,
        x_name=r.x_name,
        cov_6x6=cov,
        cov_source=r.cov_source,
        source=r.source,
        verdict=verdict,
        camera=r.camera,
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
) -> list[tuple[str, str, dict]]:
    """Each file of format ``fmt`` (in the order of ``paths``): ``(text, kind, fields)``.

    ``kind`` names its reader in :data:`.readback.READERS`, ``fields`` what that reader must find in it
    besides the frames and the transform.
    """
    from . import writers as w

    launch_fields = {"node_name": w.node_name(e), w.PROVENANCE_NAME: w.provenance_constant(e)}
    if fmt == "ros2":
        return [(w.ros2_launch(e), "launch.py", launch_fields), (w.tf_static_yaml(e), "tf_static", {})]
    if fmt == "urdf":
        return [(w.urdf(e), "urdf", {"joint_name": w.joint_name(e)}), (w.xacro(e), "xacro", {})]
    if fmt == "moveit":
        return [
            (w.ros2_launch(e, moveit_layout=True), "launch.py", launch_fields),
            (w.moveit1_launch(e), "ros1_launch", {}),
        ]
    if fmt == "easy_handeye2":
        eye_in_hand = e.mode == "eye_in_hand"
        base = base_frame or (DEFAULT_FRAMES["eye_to_hand"] if eye_in_hand else e.parent)
        effector = effector_frame or (e.parent if eye_in_hand else DEFAULT_FRAMES["eye_in_hand"])
        name = paths[0].name[: -len(".calib")] if paths[0].name.endswith(".calib") else paths[0].stem
        fields = {"name": name, "robot_base_frame": base, "robot_effector_frame": effector}
        return [(w.easy_handeye2_calib(e, name=name, base=base, effector=effector), "calib", fields)]
    d = w.plain_dict(e)
    fields = {"mode": e.mode, "verdict": e.verdict, "source": e.source, "camera_frame": e.camera_frame}
    fields["result_name"] = e.x_name
    if fmt == "yaml":
        return [(w.plain_yaml(e, d), "plain_yaml", fields)]
    return [(w.plain_json(e, d), "plain_json", fields)]


#: the files of a result folder (and of verify's and batch's output folders) an export never replaces
RESULT_FOLDER_FILES = (
    "result.json",
    "result.previous.json",
    "result.last-good.json",
    "observations.json",
    "report.html",
    "report.md",
    "verify.json",
    "verify.html",
    "verify.md",
    "plan.json",
    "batch.json",
    "batch.log",
    "fleet.csv",
    "fleet.parquet",
    "index.html",
    "index.md",
    ".handeye.lock",
)
#: a result folder's subfolders an export never writes into
RESULT_FOLDER_DIRS = ("thumbnails", "report_files", "index_files")
#: what makes a folder a result folder (or verify's or batch's output)
_RESULT_MARKS = ("result.json", "verify.json", "batch.json")


def _result_folder_file(path: Path, result_dir: Path) -> Optional[str]:
    """The reason ``path`` is one of a result folder's own files (None: it is not).

    A name of :data:`RESULT_FOLDER_FILES` in the exported result's folder or in any folder holding a result,
    or a file under one of their :data:`RESULT_FOLDER_DIRS`.
    """
    import os

    where = Path(os.path.realpath(path.parent))  # the folder entry the export would replace (not a link's target)

    def is_result_folder(folder: Path) -> bool:
        return folder == Path(os.path.realpath(result_dir)) or any((folder / m).is_file() for m in _RESULT_MARKS)

    if path.name in RESULT_FOLDER_FILES and is_result_folder(where):
        return f"{path.name} is the result folder's own file"
    for up in [where, *where.parents]:
        if up.name in RESULT_FOLDER_DIRS and is_result_folder(up.parent):
            return f"{up.name}/ belongs to the result folder"
    return None


def _same_entry(a: Path, b: Path) -> bool:
    """``a`` and ``b`` name the same file (or ``a`` would replace the folder entry of ``b``)."""
    import os

    if Path(os.path.realpath(a.parent)) / a.name == Path(os.path.realpath(b.parent)) / b.name:
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # a does not exist yet
        return False


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
    camera: Optional[str] = None,
) -> list[Path]:
    """Write the export ``fmt`` of ``result`` (a result folder or result.json path); returns the files.

    Refused before anything is written (:class:`~handeye.errors.InputError`): a file that would replace one of
    a result folder's own (:data:`RESULT_FOLDER_FILES`). Every file is parsed back by its own language's
    reader and must hold the frames and the transform meant (:mod:`.readback`) before any is written; each is
    written atomically (a reader sees the old file or the new one). A cell: camera ``camera``, or without it
    every camera (:func:`export_cell`).
    """
    from .readback import check, read_back

    if camera is None and _cell_cameras(result):
        return export_cell(
            result,
            fmt,
            out=out,
            parent=parent,
            child=child,
            camera_frame=camera_frame,
            force=force,
            base_frame=base_frame,
            effector_frame=effector_frame,
        )
    e = export_transform(result, parent=parent, child=child, camera_frame=camera_frame, force=force, camera=camera)
    for flag, name, mode in (
        ("--base-frame", base_frame, "eye_in_hand"),
        ("--effector-frame", effector_frame, "eye_to_hand"),
    ):
        if name is None:
            continue
        check_frame_name(name, flag)
        if fmt != "easy_handeye2":
            raise InputError(f"{flag} applies to --to easy_handeye2 only", hint=f"drop {flag}, or use --parent")
        if e.mode != mode:  # the frame the camera hangs from: it is --parent's
            raise InputError(
                f"{flag} names the robot frame of an {mode} calibration, this one is {e.mode}",
                hint=f"the camera's parent frame is --parent (here {e.parent}): use --parent {name}",
            )
    src = Path(e.source)
    paths = export_paths(fmt, out, src.parent)
    _check_targets(paths, src, fmt)
    files = render(fmt, e, paths, base_frame=base_frame, effector_frame=effector_frame)
    data = [text.encode("utf-8") for text, _, _ in files]
    for p, b, (_, kind, fields) in zip(paths, data, files, strict=True):
        got = read_back(kind, b, name=p.name)
        check(got, parent=e.parent, child=e.child, T_parent_child=e.T_parent_child, fields=fields, name=p.name)
    return _write_together(paths, data)


#: what the first bytes of every file an export writes hold: the header line of one camera's export
#: (``hand-eye calibration by handeye``, ``hand-eye calibration of camera cam1 of a cell by handeye``) or a cell's
#: (``hand-eye calibration of a cell of 3 cameras by handeye``), or the JSON format's own key
EXPORT_MARK = re.compile(rb'hand-eye calibration[^\n]* by handeye |"handeye_export"')


def written_by_export(path: Path) -> bool:
    """Whether the file ``path`` is one an export wrote (its header says so)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return False
    return EXPORT_MARK.search(head) is not None


def exports_of(result_json: Path) -> list[Path]:
    """The exports written beside ``result_json`` by default whose source it is.

    Files ``hand_eye.*`` of :data:`FORMATS` in its folder that an export wrote (:func:`written_by_export`) and that
    name that result.json as their source.
    """
    import json

    folder = result_json.parent
    ends = tuple(e for exts, _ in FORMATS.values() for e in exts)
    src = str(result_json.resolve())
    marks = {src, json.dumps(src)[1:-1]}  # as text, and as a JSON string escapes it
    found = []
    for p in sorted(folder.glob(f"{DEFAULT_BASENAME}*")):
        if not (p.is_file() and p.name.endswith(ends) and written_by_export(p)):
            continue
        try:
            text = p.read_text(encoding="utf-8", errors="replace")
        except OSError:
            continue
        if any(m in text for m in marks):
            found.append(p)
    return found


def _check_targets(paths: list[Path], src: Path, fmt: str) -> None:
    """Refuse a target that would replace what an export must not.

    A result folder's own file or the result itself (``export_over_result``), or an existing file an export did
    not write (``export_over_file``: a session.yaml, a launch file of the user's).
    """
    for p in paths:
        why, code = _result_folder_file(p, src.parent), "export_over_result"
        if why is None and _same_entry(p, src):
            why = "it is the result being exported"
        if why is None and (p.is_file() or p.is_symlink()) and not written_by_export(p):
            why, code = "it exists and is not a file handeye export wrote", "export_over_file"
        if why is not None:
            raise InputError(
                f"will not write {fmt} over {p}: {why}",
                code=code,
                hint=f"name another file or folder with --out (e.g. {p.parent / DEFAULT_BASENAME}{FORMATS[fmt][0][0]})"
                + (", or remove that file first" if code == "export_over_file" else ""),
            )


def _cell_cameras(result) -> list[str]:
    """The cameras of ``result`` when it is a cell of more than one camera, else []."""
    from ..contract import read_result, validate_result
    from ..output import plain

    if isinstance(result, dict):
        m = validate_result(plain(result), require_version=False)
    else:
        m = read_result(Path(result))
    return m.camera_names if m.is_cell and len(m.camera_names) > 1 else []


def camera_paths(paths: list[Path], fmt: str, camera: str) -> list[Path]:
    """A format's files for one camera of a cell: the camera's name after the base name (``hand_eye_wrist.calib``)."""
    out = []
    for p, suffix in zip(paths, FORMATS[fmt][0], strict=True):
        n = p.name
        if n.endswith(suffix) and len(n) > len(suffix):
            stem, rest = n[: -len(suffix)], suffix
        else:  # a name with another extension: the camera before its first dot
            stem, dot, ext = n.partition(".")
            rest = dot + ext
        out.append(p.with_name(f"{stem}_{camera}{rest}"))
    return out


def export_cell(
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
    """Write every camera of a cell: one file set holding all (:data:`.cell.CELL_FORMATS`), else one per camera.

    Each camera is checked as a one-camera export is (status, verdict unless ``force``); ``--parent`` and
    ``--child`` name one frame and are refused (one camera: ``camera=``). MoveIt's and easy_handeye2's
    files hold one camera each: ``<base>_<camera><suffix>``, ``base_frame`` going to the eye-in-hand
    cameras, ``effector_frame`` to the eye-to-hand ones.
    """
    from . import cell
    from .readback import check_all, read_back_all

    names = _cell_cameras(result)
    for flag, v in (("--parent", parent), ("--child", child)):
        if v is not None:
            raise InputError(
                f"{flag} names one frame, the result is a cell of {len(names)} cameras ({', '.join(names)})",
                hint=f"export one camera with --camera NAME {flag} {v}, or leave out {flag}",
            )
    es = [export_transform(result, camera_frame=camera_frame, force=force, camera=n) for n in names]
    src = Path(es[0].source)
    if fmt not in cell.CELL_FORMATS:
        written: list[Path] = []
        paths = export_paths(fmt, out, src.parent)
        for e in es:
            written += export_result(
                result,
                fmt,
                out=camera_paths(paths, fmt, str(e.camera))[0],
                camera_frame=camera_frame,
                force=force,
                base_frame=base_frame if e.mode == "eye_in_hand" else None,
                effector_frame=effector_frame if e.mode == "eye_to_hand" else None,
                camera=e.camera,
            )
        return written
    for flag, v in (("--base-frame", base_frame), ("--effector-frame", effector_frame)):
        if v is not None:
            raise InputError(f"{flag} applies to --to easy_handeye2 only", hint=f"drop {flag}")
    paths = export_paths(fmt, out, src.parent)
    _check_targets(paths, src, fmt)
    files = cell.render(fmt, es)
    data = [text.encode("utf-8") for text, _, _ in files]
    for p, b, (_, kind, want) in zip(paths, data, files, strict=True):
        check_all(read_back_all(kind, b, name=p.name), want, name=p.name)
    return _write_together(paths, data)


def _write_together(paths: list[Path], data: list[bytes]) -> list[Path]:
    """Write a format's files so that they change together.

    Each is written whole beside its target first (:func:`~handeye.output.atomic_write_bytes` into a temporary
    name), and only when all are on disk are they renamed into place. A refused write (disk full,
    permissions) leaves every target as it was.
    """
    import os
    import tempfile

    from ..output import TEMP_SUFFIX, atomic_write_bytes, writing

    staged: list[tuple[Path, Path]] = []
    try:
        for p, b in zip(paths, data, strict=True):
            with writing(p):
                p.parent.mkdir(parents=True, exist_ok=True)
                fd, name = tempfile.mkstemp(prefix="." + p.name + ".", suffix=TEMP_SUFFIX, dir=p.parent)
                os.close(fd)
            staged.append((Path(name), p))
            atomic_write_bytes(name, b)  # the bytes flushed to the disk under the temporary name
        for tmp, p in staged:
            with writing(p):
                os.replace(tmp, p)
    finally:
        for tmp, _ in staged:
            if tmp.exists():
                tmp.unlink()
    return list(paths)
