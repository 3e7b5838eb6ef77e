"""handeye's native ``session.yaml``: target, mode, pose format, optional intrinsics, and views.

Views come inline (``views:``) and/or as one YAML record per view in ``view_records/``, each with id,
image and pose (``pose:`` inline or ``pose_file:``), optionally the arm's joint angles (``joints:``).
:func:`read_native_document` is the only parser of this file; the strict loader
(:func:`load_native_session`) and the lenient reader of the diagnostics (:mod:`handeye.session.raw`)
both use it, and :func:`view_pose_values` / :func:`view_image_path` are the only readers of a view's
pose and image path. The rules are in docs/session_format.md.
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..camera import Intrinsics
from ..conventions import PoseFormat, T_from_pose_values
from ..errors import ConfigError, InputError
from ..output import read_text
from ..records import Session, View, view_id_key
from ..targets import TargetSpec, TrackedTargetSpec
from .fields import (
    ROBOT_ACCURACY_FORM,
    IdTextLoader,
    check_angle_units,
    check_finite,
    check_input_file,
    check_mode,
    check_translation_units,
    mm_deg,
    parse_pose_format,
    positive_number,
    read_yaml,
)
from .keys import unknown_session_keys
from .target_spec import parse_target

log = logging.getLogger(__name__)

INTRINSICS_USES = ("fixed", "prior", "initial")
#: ROS CameraInfo ``distortion_model`` names: plumb_bob is OpenCV's 5-coefficient model (D = k1, k2, p1,
#: p2, k3 in that order); the others are different models, which handeye does not have
DISTORTION_MODELS = ("plumb_bob",)
_OTHER_DISTORTION = {
    "rational_polynomial": "8 coefficients k1, k2, p1, p2, k3, k4, k5, k6",
    "equidistant": "the fisheye model, 4 coefficients k1..k4",
    "fisheye": "the fisheye model, 4 coefficients k1..k4",
}


@dataclass(frozen=True)
class ViewEntry:
    """One view as written: its mapping and the file it came from (session.yaml or a view record)."""

    data: dict
    source: Path


@dataclass(frozen=True)
class NativeDocument:
    """A parsed session.yaml: the stated mode (None when absent), target, pose format, intrinsics.

    A parsed session.yaml: the stated mode (None when absent), target, pose format, intrinsics
    (with their use: estimate | fixed | prior), the folder images are relative to, and the view
    entries (ids checked, not yet converted to poses).
    """

    path: Path
    data: dict
    mode: Optional[str]
    target: TargetSpec
    pose_format: PoseFormat
    intrinsics: Optional[Intrinsics]
    intrinsics_use: str
    entries: tuple  # tuple[ViewEntry, ...]
    image_folder: Optional[Path] = None  # ``image_folder:`` (resolved); None: the session folder
    # pose-only sessions (views with ``target_pose:``): how the target poses are written, and the
    # tracker's noise (rotation [rad], translation [m]) when stated
    target_pose_format: Optional[PoseFormat] = None
    tracker_sigma: Optional[tuple] = None


def read_native_document(path: Path) -> NativeDocument:
    """Parse session.yaml and its view records; ConfigError/InputError naming the field otherwise."""
    path = Path(path)
    d = read_yaml(path, loader=IdTextLoader)
    version = d.get("handeye_session", 1)
    if version != 1:
        raise ConfigError("unsupported handeye_session version", path=path, expected="1", received=repr(version))
    target: TargetSpec = (  # a pose-only session's target is a TrackedTargetSpec, outside the TargetSpec union
        parse_target(d.get("target"), path=path) if not _pose_only(d) or d.get("target") else TrackedTargetSpec()  # type: ignore[assignment]
    )
    fmt = parse_pose_format(d.get("pose_format"), path=path)
    intr, intr_use = parse_intrinsics(d.get("intrinsics"), path=path)
    image_folder = d.get("image_folder")
    if image_folder is not None:
        if not isinstance(image_folder, str) or not image_folder:
            raise ConfigError("image_folder must be a folder path", path=path, received=repr(image_folder))
        image_folder = Path(os.path.normpath(path.parent / image_folder))
    inline = d.get("views") or []
    if not isinstance(inline, list):
        raise ConfigError("views must be a list", path=path, received=type(inline).__name__)
    entries = [ViewEntry(e, path) for e in inline]
    rec_dir = d.get("view_records")
    if rec_dir is not None and not (isinstance(rec_dir, str) and rec_dir):
        raise ConfigError(
            "view_records must be a folder name",
            path=path,
            received=repr(rec_dir)[:60],
            expected="a folder inside the session folder, e.g. view_records",
        )
    if rec_dir:
        rec_dir = inside_folder(path.parent, rec_dir, vid="records", what="folder view_records", source=path)
    if rec_dir and rec_dir.is_dir():
        for f in sorted(rec_dir.iterdir()):
            if f.name.startswith(".") or f.suffix not in (".yaml", ".yml") or not f.is_file():
                continue
            entries.append(ViewEntry(read_yaml(f, loader=IdTextLoader), f))
    if not entries:
        raise InputError("the session has no views", path=path, hint="add a views: list or records in view_records/")
    for e in entries:
        if not isinstance(e.data, dict):
            raise ConfigError(
                "each view must be a mapping with id, image, pose", path=e.source, received=repr(e.data)[:60]
            )
        for key in ("id",) if "target_pose" in e.data else ("id", "image"):
            if key not in e.data:
                where = f"view {e.data['id']}" if isinstance(e.data.get("id"), str) else "a view"
                raise ConfigError(
                    f"{where} is missing {key!r}" + (" (or a tracker's target_pose)" if key == "image" else ""),
                    path=e.source,
                    received=repr(e.data)[:80],
                    expected="id, image, pose (or pose_file); a pose-only view: id, pose, target_pose",
                )
        vid = e.data["id"]
        if not isinstance(vid, str) or not vid.strip():
            raise ConfigError(
                "invalid view id", path=e.source, expected='a non-empty text such as "7" or "010"', received=repr(vid)
            )
        if _ID_FORBIDDEN.search(vid) or vid in (".", ".."):
            raise ConfigError(
                "invalid view id",
                path=e.source,
                received=repr(vid)[:60],
                expected="a text without /, \\ or control characters (it names the view's files)",
            )
        if "target_pose" in e.data:  # a pose-only view: no image (target_pose is read by view_target_pose)
            if "image" in e.data:
                raise ConfigError(f"view {vid} has both an image and a target_pose", path=e.source, hint="remove one")
        elif not isinstance(e.data["image"], str) or not e.data["image"].strip():
            raise ConfigError(
                f"view {vid}: image must be a file name",
                path=e.source,
                received=repr(e.data["image"])[:60],
                expected="a path relative to the session folder, e.g. images/7.png",
            )
        if ("pose" in e.data) == ("pose_file" in e.data):
            raise ConfigError(
                f"view {vid}: give either pose or pose_file",
                path=e.source,
                received="both" if "pose" in e.data else "neither",
                expected="pose: [numbers in pose_format] or pose_file: FILE",
            )
    po = _pose_only_fields(d, entries, path=path)
    _check_estimate_scale(d.get("estimate_scale"), pose_only=po[0] is not None, path=path)
    if d.get("robot_accuracy") is not None:  # the arm's stated accuracy (handeye.refine.arm_accuracy)
        mm_deg(d["robot_accuracy"], path=path, field="robot_accuracy", expected=ROBOT_ACCURACY_FORM)
    return NativeDocument(path, d, d.get("mode"), target, fmt, intr, intr_use, tuple(entries), image_folder, *po)


def _pose_only(d: dict) -> bool:
    """Whether session.yaml's inline views carry target poses.

    Whether session.yaml's inline views carry target poses (a pose-only session needs no target:; one that
    mixes them with image views is refused by :func:`_pose_only_fields`).
    """
    views = d.get("views")
    return isinstance(views, list) and any(isinstance(v, dict) and "target_pose" in v for v in views)


def _check_estimate_scale(value: object, *, pose_only: bool, path: Path) -> None:
    """``estimate_scale:`` is true or false, and true only in a pose-only session; ConfigError otherwise."""
    if value is None:
        return
    if not isinstance(value, bool):
        raise ConfigError(
            "estimate_scale must be true or false", path=path, received=repr(value)[:60], expected="true | false"
        )
    if value and not pose_only:
        raise ConfigError(
            "estimate_scale applies to pose-only sessions (views with target_pose): an image session's scale is "
            "the board's square size",
            path=path,
            received="estimate_scale: true in an image session",
            hint="remove estimate_scale; a wrong square size is named by the square_size finding",
        )


def session_kind(path: str | Path) -> Optional[str]:
    """``"pose_only"`` or ``"images"`` for the session at ``path``; None when it does not read (its loader says why)."""
    from ..errors import HandeyeError
    from .fields import locate_session

    try:
        kind, p = locate_session(path)
        return "pose_only" if kind == "native" and _pose_only(read_yaml(p, loader=IdTextLoader)) else "images"
    except HandeyeError:
        return None


def is_pose_only(path: str | Path) -> bool:
    """Whether the session at ``path`` (a folder, session.yaml or poses.txt) is pose-only.

    Pose-only: views with ``target_pose:``. False for an image session and for one that does not read (its
    loader says why).
    """
    from ..errors import HandeyeError
    from .fields import locate_session

    try:
        kind, p = locate_session(path)
        return kind == "native" and _pose_only(read_yaml(p, loader=IdTextLoader))
    except HandeyeError:
        return False


def _pose_only_fields(d: dict, entries: list, *, path: Path) -> tuple:
    """(target_pose_format, tracker_sigma) of a pose-only session.

    (target_pose_format, tracker_sigma) of a pose-only session ((None, None) for an image session);
    ConfigError when image and target-pose views are mixed or a field is malformed.
    """
    with_pose = [e for e in entries if "target_pose" in e.data]
    if not with_pose:
        return None, None
    if len(with_pose) != len(entries):
        e = next(e for e in entries if "target_pose" not in e.data)
        raise ConfigError(
            f"view {e.data['id']}: a session's views are either all images or all target poses",
            path=e.source,
            received="image views and target_pose views mixed",
            hint="split the session, or give every view a target_pose",
        )
    tfmt = d.get("target_pose_format")
    tfmt = (
        parse_pose_format(tfmt, path=path)
        if tfmt is not None
        else PoseFormat(rotation="matrix").validated(source=str(path))
    )
    if d.get("tracker_sigma") is None:
        return tfmt, None
    sig = mm_deg(
        d["tracker_sigma"],
        path=path,
        field="tracker_sigma",
        optional=("mm_along",),
        expected="the tracker's noise per axis, e.g. tracker_sigma: {mm: 0.5, deg: 0.2, mm_along: 2.0} (mm "
        "across the camera's optical axis, mm_along along it)",
    )
    along = sig.get("mm_along", sig["mm"])
    return tfmt, (float(np.radians(sig["deg"])), sig["mm"] / 1000.0, along / 1000.0)


def view_target_pose(doc: NativeDocument, e: ViewEntry) -> np.ndarray:
    """A pose-only view's ``target_pose``: ``T_cam_board`` (metres) read in ``target_pose_format``.

    A pose-only view's ``target_pose``: ``T_cam_board`` (metres) read in ``target_pose_format`` (4x4 by
    default), checked like a robot pose.
    """
    vid = e.data["id"]
    fmt = doc.target_pose_format
    assert fmt is not None, "a pose-only session has its target_pose_format"
    values = view_pose_values(
        ViewEntry({"id": vid, "pose": e.data["target_pose"]}, e.source), fmt, folder=files_folder(doc)
    )
    try:
        T = T_from_pose_values(values, fmt)
    except (ValueError, TypeError) as err:
        raise InputError(f"view {vid}: bad target_pose: {err}", path=e.source, expected=fmt.describe()) from None
    check_translation_units(T, path=e.source, line=None, unit=fmt.translation_unit, where=f"view {vid}", tracked=True)
    return T


#: characters a view id may not hold: it names files (thumbnails/<id>.jpg) and must stay one name
_ID_FORBIDDEN = re.compile(r"[/\\\x00-\x1f\x7f]")
_NUMBER_SEP = re.compile(r"[,;\s]+")


def _read_pose_file(f: Path, *, vid: str) -> list:
    """The rows of numbers in a pose file (``#`` comments and blank lines skipped)."""
    text = read_text(f, what=f"view {vid}: pose file")
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        try:
            rows.append([float(x) for x in _NUMBER_SEP.split(s) if x])
        except ValueError:
            raise InputError(
                f"view {vid}: pose file line is not numbers", path=f, line=lineno, received=repr(s[:60])
            ) from None
    return rows


def view_pose_values(e: ViewEntry, fmt: PoseFormat, *, folder: Path, allow_outside: bool = False) -> np.ndarray:
    """The pose numbers of one view as written.

    The pose numbers of one view as written (flat, row-major for a matrix), from ``pose:`` or
    ``pose_file:``; InputError/ConfigError naming the view and file when their shape does not fit ``fmt``.

    A matrix is a nested 4x4 list (rows) or 16 numbers row by row; a pose file (relative to ``folder``,
    the image folder) holds a 4x4 matrix as 4 lines of 4 numbers or one pose as one line of numbers,
    both read in ``fmt``.
    """
    vid = e.data["id"]
    if "pose_file" in e.data:
        written = e.data["pose_file"]
        if not isinstance(written, str) or not written:
            raise ConfigError(f"view {vid}: pose_file must be a file name", path=e.source, received=repr(written))
        f = inside_folder(folder, written, vid=vid, what="pose file", source=e.source, allow_outside=allow_outside)
        if not f.exists():
            raise InputError(f"view {vid}: pose file missing", path=f, hint="restore the file or remove the view")
        rows = _read_pose_file(f, vid=vid)
        shape = [len(r) for r in rows]
        if shape == [4, 4, 4, 4]:
            if fmt.rotation != "matrix":
                raise ConfigError(
                    f"view {vid}: the pose file holds a 4x4 matrix but pose_format.rotation is {fmt.rotation}",
                    path=f,
                    hint="set pose_format: {rotation: matrix} (all views of a session share one pose format)",
                )
            check_finite(rows, path=f, line=None, what=f"view {vid}: pose file")
            return np.asarray(rows, float).reshape(-1)
        if len(rows) == 1:
            check_finite(rows[0], path=f, line=None, what=f"view {vid}: pose file")
            return np.asarray(rows[0], float)
        raise InputError(
            f"view {vid}: pose file is neither one pose line nor a 4x4 matrix",
            path=f,
            expected="4 lines of 4 numbers, or one line such as x,y,z,rx,ry,rz",
            received=f"{len(rows)} lines of {shape} numbers",
        )
    pose = e.data["pose"]
    if not isinstance(pose, list) or not pose:
        raise InputError(
            f"view {vid}: pose must be a list of numbers",
            path=e.source,
            received=repr(pose)[:60],
            expected=fmt.describe(),
        )
    if any(isinstance(r, list) for r in pose):
        if fmt.rotation != "matrix" or len(pose) != 4 or any(not isinstance(r, list) or len(r) != 4 for r in pose):
            raise InputError(
                f"view {vid}: a nested pose must be a 4x4 matrix (4 rows of 4) with pose_format.rotation: matrix",
                path=e.source,
                received=repr(pose)[:80],
                expected=fmt.describe(),
            )
    if any(isinstance(x, (bool, str)) for x in (sum(pose, []) if isinstance(pose[0], list) else pose)):
        raise InputError(
            f"view {vid}: pose must be numbers", path=e.source, received=repr(pose)[:80], expected=fmt.describe()
        )
    try:
        values = np.asarray(pose, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(
            f"view {vid}: pose must be numbers", path=e.source, received=repr(pose)[:80], expected=fmt.describe()
        ) from None
    check_finite(values, path=e.source, line=None, what=f"view {vid}: pose")
    return values


def inside_folder(
    folder: Path, written: str, *, vid: str, what: str, source: Path, allow_outside: bool = False
) -> Path:
    """``folder / written`` with ``..`` resolved.

    ``folder / written`` with ``..`` resolved (symbolic links are not followed: a link placed in the
    folder is the user's choice); InputError when it leaves ``folder`` unless ``allow_outside``.
    """
    p = Path(os.path.normpath(Path(folder) / str(written)))
    base = Path(os.path.normpath(folder))
    if not allow_outside and base != p and base not in p.parents:
        raise InputError(
            f"view {vid}: {what} {written!r} is outside the session folder",
            path=source,
            expected=f"a path inside {base}",
            hint="copy the files into the session folder, or state image_folder: FOLDER in "
            "session.yaml for images kept elsewhere (their paths are then relative to it)",
        )
    return p


def files_folder(doc: NativeDocument) -> Path:
    """The folder a view's image and pose file are relative to: ``image_folder`` or the session folder."""
    return doc.image_folder or doc.path.parent


def view_image_path(doc: NativeDocument, e: ViewEntry, *, allow_outside: bool = False) -> Path:
    """The image of a view, relative to :func:`files_folder` and inside it (unless ``allow_outside``)."""
    return inside_folder(
        files_folder(doc), e.data["image"], vid=e.data["id"], what="image", source=e.source, allow_outside=allow_outside
    )


def view_joint_angles(e: ViewEntry) -> Optional[tuple]:
    """The optional ``joints:`` list of a view (radians) as a tuple of floats."""
    q = e.data.get("joints")
    if q is None:
        return None
    vid = e.data["id"]
    try:
        arr = np.asarray(q, dtype=float)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if not isinstance(q, list) or arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise InputError(
            f"view {vid}: joints must be a list of joint angles",
            path=e.source,
            expected="radians, one number per joint",
            received=repr(q)[:80],
        )
    try:
        check_angle_units(arr, path=e.source, line=None)
    except InputError as err:
        raise InputError(
            f"view {vid}: joint angle {np.abs(arr).max():.1f} is larger than 2*pi",
            path=e.source,
            expected=err.expected,
            hint=err.hint,
        ) from None
    return tuple(float(x) for x in arr)


def parse_intrinsics(d: Any, *, path: Path) -> tuple[Optional[Intrinsics], str]:
    """(intrinsics or None, use: estimate | fixed | prior) from the ``intrinsics:`` mapping."""
    if d is None:
        return None, "estimate"
    if not isinstance(d, dict):
        raise ConfigError("intrinsics must be a mapping", path=path, received=repr(d)[:60])
    model = d.get("model", "opencv5")
    if model not in ("opencv5", "pinhole"):
        raise ConfigError(
            "unsupported intrinsics model",
            path=path,
            expected="opencv5 (k1,k2,p1,p2,k3) | pinhole",
            received=repr(model),
        )
    dm = d.get("distortion_model", "plumb_bob")
    if dm not in DISTORTION_MODELS:
        raise ConfigError(
            "unsupported intrinsics.distortion_model",
            path=path,
            expected="plumb_bob (ROS CameraInfo's name for OpenCV's k1, k2, p1, p2, k3)",
            received=repr(dm) + (f" ({_OTHER_DISTORTION[dm]})" if dm in _OTHER_DISTORTION else ""),
            hint="handeye's camera model is OpenCV's 5-coefficient one; calibrate without "
            "intrinsics (remove the section) to estimate it",
        )
    vals = {k: positive_number(d.get(k), path=path, field=f"intrinsics.{k}") for k in ("fx", "fy", "cx", "cy")}
    dist = d.get("dist", [0, 0, 0, 0, 0]) if model == "opencv5" else [0, 0, 0, 0, 0]
    try:
        dist = np.asarray(dist, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        dist = np.array([np.nan])
    if dist.size == 8 and np.all(np.isfinite(dist)):
        raise ConfigError(
            "intrinsics.dist has 8 coefficients: ROS's rational_polynomial model, which handeye does not have",
            path=path,
            expected="4 or 5 numbers k1, k2, p1, p2[, k3] (plumb_bob)",
            received=repr(d.get("dist")),
        )
    if dist.size not in (4, 5) or not np.all(np.isfinite(dist)):
        raise ConfigError(
            "intrinsics.dist must be 4 or 5 finite numbers (k1, k2, p1, p2[, k3])",
            path=path,
            received=repr(d.get("dist")),
        )
    size = d.get("image_size")
    if not (isinstance(size, (list, tuple)) and len(size) == 2):
        raise ConfigError("intrinsics.image_size must be [width, height]", path=path, received=repr(size))
    w = positive_number(size[0], path=path, field="intrinsics.image_size[0]", integer=True)
    h = positive_number(size[1], path=path, field="intrinsics.image_size[1]", integer=True)
    use = d.get("use", "fixed")
    if use not in INTRINSICS_USES:
        raise ConfigError("invalid intrinsics.use", path=path, expected=" | ".join(INTRINSICS_USES), received=repr(use))
    K = np.array([[vals["fx"], 0, vals["cx"]], [0, vals["fy"], vals["cy"]], [0, 0, 1]])
    return Intrinsics.from_K(K, dist, w, h), str({"initial": "estimate"}.get(use, use))  # use: checked above


def load_native_session(path: str | Path, *, mode: str | None = None, allow_outside: bool = False) -> Session:
    """session.yaml, validated: poses converted to ``T_base_end`` (metres) and unit-checked.

    A view whose image file is missing is dropped with its pose (a warning, and ``missing_images`` /
    ``missing_image_files`` in the session's metadata), like a vendor pose line without its image; a
    session without any of its images is an error. ``allow_outside`` lets image and pose-file paths
    leave the session folder (by default they must stay inside it, or inside ``image_folder``).
    """
    path = Path(path)
    doc = read_native_document(path)
    for where, line in unknown_session_keys(doc.data, [(e.data, e.source) for e in doc.entries]):
        log.warning("%s: %s", where or path, line)
    source = "flag" if mode is not None else ("stated" if doc.mode is not None else "default")
    sess_mode = check_mode(mode if mode is not None else (doc.mode or "eye_in_hand"), path=path)
    fmt = doc.pose_format
    views = []
    missing: dict[str, Path] = {}
    seen: set[str] = set()
    files_read = [path, *(e.source for e in doc.entries if e.source != path)]
    for e in doc.entries:
        vid = e.data["id"]
        if vid in seen:
            raise ConfigError(f"duplicate view id {vid!r}", path=e.source, hint="give every view its own id")
        seen.add(vid)
        values = view_pose_values(e, fmt, folder=files_folder(doc), allow_outside=allow_outside)
        try:
            T = T_from_pose_values(values, fmt)
        except (ValueError, TypeError) as err:
            raise InputError(f"view {vid}: bad pose: {err}", path=e.source, expected=fmt.describe()) from None
        check_translation_units(T, path=e.source, line=None, unit=fmt.translation_unit, where=f"view {vid}")
        joints = view_joint_angles(e)
        t_image, t_pose = (_opt_time(e, k) for k in ("t_image", "t_pose"))
        if "pose_file" in e.data:
            files_read.append(files_folder(doc) / str(e.data["pose_file"]))
        if doc.target_pose_format is not None:  # a pose-only view: the tracker's T_cam_board, no image
            views.append(
                View(
                    view_id=vid,
                    image_path=None,  # type: ignore[arg-type]  # a pose-only view has no image
                    T_base_end=T,
                    t_image=t_image,
                    t_pose=t_pose,
                    joint_angles=joints,
                    T_cam_board=view_target_pose(doc, e),
                )
            )
            continue
        img = view_image_path(doc, e, allow_outside=allow_outside)
        if not os.path.lexists(img):
            missing[vid] = img
            continue
        files_read.append(check_input_file(img, what="image", vid=vid))
        views.append(
            View(view_id=vid, image_path=img, T_base_end=T, t_image=t_image, t_pose=t_pose, joint_angles=joints)
        )
    if not views:
        first = next(iter(missing.values()))
        raise InputError(
            f"none of the {len(missing)} views' images exists",
            path=first,
            hint="image paths are relative to the session folder (or image_folder); check them",
        )
    if missing:
        log.warning("%s: views without their image file (dropped with their poses): %s", path, sorted(missing))
    views.sort(key=lambda v: view_id_key(v.view_id))
    meta = {k: v for k, v in doc.data.items() if k not in ("views",)}
    meta.update(
        missing_images={v: None for v in missing},
        missing_image_files={v: str(f) for v, f in missing.items()},
        files_read=files_read,
    )
    if doc.target_pose_format is not None:
        meta.update(
            pose_only=True, tracker_sigma=doc.tracker_sigma, target_pose_format=doc.target_pose_format.describe()
        )
    return Session(
        path=path.parent,
        format="native",
        mode=sess_mode,
        target=doc.target,
        views=tuple(views),
        intrinsics=doc.intrinsics,
        intrinsics_prior=doc.intrinsics_use,
        pose_format=fmt.describe(),
        mode_source=source,
        meta=meta,
    )


def _opt_time(e: ViewEntry, key: str):
    """A view's optional time stamp (``t_image``, ``t_pose``): seconds as a finite number."""
    v = e.data.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ConfigError(
            f"view {e.data['id']}: invalid {key}",
            path=e.source,
            expected="a time stamp in seconds (a number)",
            received=repr(v)[:60],
            hint=f"write {key} as seconds, e.g. 1712345678.25, or remove it",
        )
    return float(v)
