"""Importers for other tools' session layouts, each writing a native ``session.yaml``.

Its ``image_folder`` is the original folder (nothing is copied) and it states the pose format those
tools use.

- ``visp``: the layout :data:`VISP_LAYOUT` describes (ViSP's chessboard and single-AprilTag data); other
  ViSP target descriptions are refused by name.
- ``ical``: ROS-Industrial industrial_calibration (``cal_data.yaml`` + ``poses/N.yaml`` with
  x, y, z, qx, qy, qz, qw; ``static_camera`` decides the mode). Target finders: ChArUco
  (``CharucoGridTargetFinder``) and circle grids (``ModifiedCircleGridTargetFinder``: symmetric
  grid, ``spacing`` between dot centres, one double-size origin dot).

:func:`write_pose_only_session` is the pose-only session the samples importers write (easy_handeye2, MoveIt).
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path
from typing import Any, Optional

import numpy as np
import yaml

from ..errors import InputError
from ..output import atomic_write_text, read_text
from .fields import read_yaml

log = logging.getLogger(__name__)

#: what the importers write; an existing one is replaced only when asked (``force=True``, ``--force``)
SESSION_FILE = "session.yaml"


def _number(v, *, path: Path, field: str) -> float:
    """A finite number read from another tool's file; InputError naming the file and field."""
    import math

    try:
        x = float(v) if not isinstance(v, bool) else float("nan")
    except (TypeError, ValueError):
        x = float("nan")
    if not math.isfinite(x):
        raise InputError(f"{field} is not a number", path=path, received=repr(v)[:60], expected="a finite number")
    return x


def _mapping(v, *, path: Path, field: str, expected: str) -> dict:
    if not isinstance(v, dict):
        raise InputError(f"{field} must be a mapping", path=path, received=repr(v)[:60], expected=expected)
    return v


#: what ``handeye import visp`` reads, for its help and its messages
VISP_LAYOUT = (
    "ViSP's hand-eye data folders (apps/calibration/hand-eye/data-eye-in-hand and data-eye-to-hand): "
    "images [PREFIX_]image-N.png, robot poses [PREFIX_]pose_rPe_N.yaml or pose_fPe_N.yaml (vpPoseVector: "
    "metres + theta-u radians, the end in the base frame), and the target: chessboard-data.txt ('9 x 6' "
    "inner corners, 'square size: 0.0236 m') or apriltag-data.txt ('36h11' family, 'size: 0.048 m', one "
    "tag per image); optional *camera.xml"
)
_VISP_IMAGE = re.compile(r"^(?:.*_)?image-(\d+)\.png$")
_VISP_POSE = re.compile(r"^(?:.*_)?pose_[rf]Pe_(\d+)\.yaml$")
#: AprilTag families of ViSP's vpDetectorAprilTag that cv2.aruco also has
_VISP_TAG_FAMILIES = {
    "36h11": "DICT_APRILTAG_36h11",
    "25h9": "DICT_APRILTAG_25h9",
    "16h5": "DICT_APRILTAG_16h5",
    "36h10": "DICT_APRILTAG_36h10",
}


def _visp_other_target(src: Path) -> str | None:
    """The name of a ViSP target description handeye does not read (neither chessboard nor AprilTag data)."""
    for f in sorted(src.glob("*-data.txt")):
        if f.name not in ("chessboard-data.txt", "apriltag-data.txt"):
            return f.name
    return None


def _visp_description(src: Path, name: str, patterns: dict, expected: str) -> tuple[Path, dict]:
    """(file, {key: regex match}) of the target description ``name`` in ``src``; InputError when one is missing."""
    f = src / name
    txt = read_text(f, what=name)
    found = {k: re.search(p, txt) for k, p in patterns.items()}
    if not all(found.values()):
        raise InputError(f"{name} unreadable", path=f, expected=expected, hint=f"handeye reads {VISP_LAYOUT}")
    return f, found


def _visp_chessboard(src: Path) -> dict:
    _f, m = _visp_description(
        src,
        "chessboard-data.txt",
        {"size": r"(\d+)\s*x\s*(\d+)", "square": r"square size:\s*([0-9.eE+-]+)"},
        "'9 x 6' and 'square size: 0.0236 m'",
    )
    return {
        "type": "chessboard",
        "inner_corners": [int(m["size"].group(1)), int(m["size"].group(2))],
        "square_m": float(m["square"].group(1)),
    }


def _visp_apriltag(src: Path, images: list) -> dict:
    """The single-marker target of ViSP's AprilTag data.

    Family and size from apriltag-data.txt, the tag id from the first image that shows exactly one tag of
    that family (ViSP's tool assumes one tag per image).
    """
    import cv2

    f, m = _visp_description(
        src,
        "apriltag-data.txt",
        {"family": r"\b(\d+h\d+)\b", "size": r"size:\s*([0-9.eE+-]+)"},
        "a family such as '36h11' and 'size: 0.048 m'",
    )
    fam, size = m["family"], m["size"]
    if fam.group(1) not in _VISP_TAG_FAMILIES:
        raise InputError(
            f"unsupported AprilTag family {fam.group(1)!r}", path=f, expected=" | ".join(_VISP_TAG_FAMILIES)
        )
    dictionary = _VISP_TAG_FAMILIES[fam.group(1)]
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))
    for img in images:
        gray = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION) if img.is_file() else None
        if gray is None:
            continue
        _corners, ids, _ = detector.detectMarkers(gray)
        if ids is not None and len(ids) == 1:
            return {
                "type": "marker",
                "size_m": _number(size.group(1), path=f, field="size"),
                "dictionary": dictionary,
                "marker_id": int(ids[0][0]),
            }
    raise InputError(
        f"no image shows exactly one {fam.group(1)} tag",
        path=src,
        expected="one AprilTag in view, as ViSP's visp-compute-apriltag-poses assumes",
        hint="check the family in apriltag-data.txt",
    )


def visp_mode(src: Path, layout: str) -> tuple[str | None, str]:
    """(mounting mode, why) where the ViSP folder states it, else (None, why not).

    ViSP's two data folders are named for their mode (``data-eye-in-hand``, ``data-eye-to-hand``); a folder
    renamed keeps its layout, and ViSP's AprilTag layout is that of its eye-to-hand tutorial (the tag on the
    flange, the camera fixed). Its chessboard layout serves both tutorials: that mode is left to the data.
    """
    name = src.name.lower().replace("_", "-")
    for mode in ("eye-to-hand", "eye-in-hand"):
        if mode in name:
            return mode.replace("-", "_"), f"the folder name {src.name!r}"
    if layout == "apriltag":
        return "eye_to_hand", "ViSP's AprilTag layout is its eye-to-hand tutorial's (tag on the flange, camera fixed)"
    return None, "ViSP's chessboard layout serves both mounting modes"


def import_visp(
    src: str | Path,
    out: str | Path,
    *,
    use_given_intrinsics: bool = False,
    force: bool = False,
    mode: str | None = None,
) -> Path:
    """``out/session.yaml`` for a ViSP data folder of the layout :data:`VISP_LAYOUT`.

    An existing session in ``out`` is refused unless ``force``. The target is the chessboard of
    chessboard-data.txt or the single AprilTag of apriltag-data.txt (``source.layout`` in session.yaml says
    which). The mounting mode is ``mode`` when given, else the one the folder states (:func:`visp_mode`),
    written as ``mode:`` with its reason in ``source.mode``; otherwise left to the data.
    """
    src, out = Path(src).resolve(), Path(out)
    check_import_out(out, force=force)
    if not src.is_dir():
        raise InputError("not a folder", path=src, expected=VISP_LAYOUT)
    imgs = {int(m.group(1)): f for f in src.iterdir() if (m := _VISP_IMAGE.match(f.name))}
    poses = {int(m.group(1)): f for f in src.iterdir() if (m := _VISP_POSE.match(f.name))}
    if (src / "chessboard-data.txt").exists():
        layout, target = "chessboard", None
    elif (src / "apriltag-data.txt").exists():
        layout, target = "apriltag", None
    else:
        other = _visp_other_target(src)
        if other is not None:
            kind = other[: -len("-data.txt")]
            raise InputError(
                f"unsupported ViSP target {kind!r} ({other})",
                path=src / other,
                expected="chessboard-data.txt or apriltag-data.txt",
                hint="write session.yaml by hand for a target handeye supports, see docs/session_format.md",
            )
        raise InputError(
            "no ViSP target description (chessboard-data.txt or apriltag-data.txt)", path=src, expected=VISP_LAYOUT
        )
    if not imgs:
        raise InputError("no ViSP images ([PREFIX_]image-N.png) in the folder", path=src, expected=VISP_LAYOUT)
    target = _visp_chessboard(src) if layout == "chessboard" else _visp_apriltag(src, [imgs[k] for k in sorted(imgs)])
    views = []
    some = imgs[min(imgs)].name
    for k in sorted(set(imgs) | set(poses)):
        if k not in poses:
            raise InputError(
                f"image {imgs[k].name} has no pose file",
                path=src,
                expected=f"pose_rPe_{k}.yaml (or with the images' prefix)",
            )
        # a pose without its image stays a view: the session's loader drops it with its reason, as for any session
        image = imgs[k].name if k in imgs else re.sub(r"image-\d+\.png$", f"image-{k}.png", some)
        data = read_yaml(poses[k]).get("data")
        if not (isinstance(data, list) and len(data) == 6 and all(isinstance(v, list) and len(v) == 1 for v in data)):
            raise InputError(
                "not a ViSP vpPoseVector (data: 6 rows of one number)",
                path=poses[k],
                received=repr(data)[:60],
                expected="data: [[tx], [ty], [tz], [tux], [tuy], [tuz]]",
            )
        views.append(
            {
                "id": str(k),
                "image": image,
                "pose": [_number(v[0], path=poses[k], field=f"data[{i}]") for i, v in enumerate(data)],
            }
        )
    source: dict[str, object] = {"importer": "visp", "layout": layout, "path": str(src)}
    doc: dict[str, object] = {
        "handeye_session": 1,
        "target": target,
        "pose_format": {"rotation": "rotvec", "angle_unit": "rad", "translation_unit": "m"},
        "image_folder": str(src),
        "source": source,
        "views": views,
    }
    why = "--mode" if mode is not None else None
    if mode is None:
        mode, why = visp_mode(src, layout)
    if mode is not None:
        doc = {"handeye_session": 1, "mode": mode, **{k: v for k, v in doc.items() if k != "handeye_session"}}
    source["mode"] = why
    cam = next(iter(src.glob("*camera*.xml")), None)
    if use_given_intrinsics and cam is None:
        raise InputError(
            "--given-intrinsics: the folder has no ViSP camera file (*camera*.xml)",
            path=src,
            hint="remove --given-intrinsics to estimate the intrinsics from the images",
        )
    if use_given_intrinsics and cam is not None:
        t = read_text(cam, what="camera file")
        found = {k: re.search(rf"<{k}>\s*([0-9.eE+-]+)", t) for k in ("px", "py", "u0", "v0")}
        if not all(found.values()):
            raise InputError(
                "camera file without px, py, u0, v0",
                path=cam,
                expected="ViSP's camera XML with <px>, <py>, <u0>, <v0>",
                hint="remove --given-intrinsics to estimate the intrinsics",
            )
        vals = {k: _number(m.group(1), path=cam, field=k) for k, m in found.items() if m is not None}  # all found
        import cv2

        one = imgs[min(imgs)]
        first = cv2.imread(str(one), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION) if one.is_file() else None
        if first is None:
            raise InputError("cannot read the image for the image size", path=imgs[min(imgs)])
        h, w = first.shape
        doc["intrinsics"] = {
            "model": "opencv5",
            "fx": vals["px"],
            "fy": vals["py"],
            "cx": vals["u0"],
            "cy": vals["v0"],
            "dist": [0, 0, 0, 0, 0],
            "image_size": [w, h],
            "use": "fixed",
        }
    return _write(out, doc)


def import_ical(src: str | Path, out: str | Path, *, image_dir: str | None = None, force: bool = False) -> Path:
    """``out/session.yaml`` for an industrial_calibration data folder.

    ``out/session.yaml`` for an industrial_calibration data folder (an existing session in ``out`` is
    refused unless ``force``); every field is checked and named when missing or of the wrong type.
    """
    src, out = Path(src).resolve(), Path(out)
    check_import_out(out, force=force)
    cal_path = src / "cal_data.yaml"
    cal = read_yaml(cal_path)
    data = cal.get("data")
    if not isinstance(data, list) or not data:
        raise InputError(
            "cal_data.yaml has no data list",
            path=cal_path,
            expected="data: [{image: FILE, pose: FILE}, ...]",
            received=repr(data)[:60],
        )
    views = []
    for k, entry in enumerate(data):
        if not (isinstance(entry, dict) and isinstance(entry.get("image"), str) and isinstance(entry.get("pose"), str)):
            raise InputError(
                f"data[{k}] must name an image and a pose file",
                path=cal_path,
                expected="{image: FILE, pose: FILE}",
                received=repr(entry)[:60],
            )
        img = src / entry["image"]
        if image_dir is not None or not img.exists():
            alt = src / (image_dir or "images_gray") / Path(entry["image"]).name
            img = alt if alt.exists() else img
        pose_path = src / entry["pose"]
        p = read_yaml(pose_path)
        views.append(
            {
                "id": Path(entry["image"]).stem,
                "image": os.path.relpath(img, src),
                "pose": [_number(p.get(c), path=pose_path, field=c) for c in ("x", "y", "z", "qw", "qx", "qy", "qz")],
            }
        )
    tgt = _mapping(
        cal.get("target_finder", {}),
        path=cal_path,
        field="target_finder",
        expected="{type: CharucoGridTargetFinder | ModifiedCircleGridTargetFinder, ...}",
    )
    kind = str(tgt.get("type", ""))

    def num(key):
        return _number(tgt.get(key), path=cal_path, field=f"target_finder.{key}")

    def count(key):
        v = num(key)
        if not (v.is_integer() and 1 <= v <= 1000):
            raise InputError(
                f"target_finder.{key} is not a grid size",
                path=cal_path,
                received=repr(tgt.get(key)),
                expected="a whole number 1..1000",
            )
        return int(v)

    if kind.lower().startswith("charuco") or "CharucoGrid" in str(tgt):
        target = {
            "type": "charuco",
            "squares": [count("cols"), count("rows")],
            "square_m": num("chessboard_dim"),
            "marker_m": num("aruco_marker_dim"),
            "dictionary": _aruco_name(
                int(_number(tgt.get("dictionary", 10), path=cal_path, field="target_finder.dictionary"))
            ),
        }
    elif "circlegrid" in kind.lower():
        # ModifiedCircleGridTargetFinder: symmetric grid with one double-size origin dot
        target = {
            "type": "circlegrid",
            "grid": [count("cols"), count("rows")],
            "spacing_m": num("spacing"),
            "asymmetric": False,
            "origin_dot": kind.lower().startswith("modified"),
        }
    else:
        raise InputError(
            "unsupported industrial_calibration target finder",
            path=src / "cal_data.yaml",
            expected="CharucoGridTargetFinder | ModifiedCircleGridTargetFinder",
            received=str(tgt.get("type")),
        )
    mode = "eye_to_hand" if cal.get("static_camera", False) else "eye_in_hand"
    doc = {
        "handeye_session": 1,
        "mode": mode,
        "target": target,
        "pose_format": {"rotation": "quaternion", "quaternion_order": "wxyz", "translation_unit": "m"},
        "image_folder": str(src),
        "source": {"importer": "ical", "path": str(src)},
        "views": views,
    }
    return _write(out, doc)


_ARUCO = {
    0: "DICT_4X4_50",
    1: "DICT_4X4_100",
    2: "DICT_4X4_250",
    3: "DICT_4X4_1000",
    4: "DICT_5X5_50",
    5: "DICT_5X5_100",
    6: "DICT_5X5_250",
    7: "DICT_5X5_1000",
    8: "DICT_6X6_50",
    9: "DICT_6X6_100",
    10: "DICT_6X6_250",
    11: "DICT_6X6_1000",
    12: "DICT_7X7_50",
    13: "DICT_7X7_100",
    14: "DICT_7X7_250",
    15: "DICT_7X7_1000",
    16: "DICT_ARUCO_ORIGINAL",
}


def _aruco_name(code: int) -> str:
    return _ARUCO.get(code, "DICT_6X6_250")


def check_import_out(out: Path, *, force: bool, writes: tuple = ()) -> None:
    """The importer's output folder: a new or empty folder, or one whose session is to be replaced.

    The importer's output folder: a new or empty folder, or one whose session is to be replaced
    (``force``); a collected session (view_records/) or a vendor session is never overwritten silently.
    ``writes``: the folders in OUT the importer writes files into (rosbag: ``images``); with ``force`` they must
    be empty, or an earlier import's files would mix with the new ones.
    """
    from ..errors import OutputError
    from ..output import check_out_dir

    if out.exists() and not out.is_dir():
        check_out_dir(out, option="OUT")
    if out.is_dir() and not force:
        held = [n for n in (SESSION_FILE, "poses.txt", "view_records") if (out / n).exists()]
        if held:
            raise OutputError(
                "OUT already holds a session",
                path=out,
                received=held[0],
                expected="a new or empty folder",
                hint="choose another folder, or pass --force to replace its session.yaml",
            )
    for name in writes:
        if (out / name).is_dir() and any((out / name).iterdir()):
            raise OutputError(
                f"OUT/{name} holds the files of an earlier import; --force replaces session.yaml, not them",
                path=out / name,
                hint=f"remove {out / name}, or import into a new folder",
            )
    check_out_dir(out, option="OUT")


def _same(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether two (robot, tracker) pose pairs are the same sample (equal to round-off)."""
    return bool(np.allclose(a[0], b[0], rtol=0, atol=1e-12) and np.allclose(a[1], b[1], rtol=0, atol=1e-12))


def write_pose_only_session(
    out: str | Path,
    *,
    mode: Optional[str],
    source: dict[str, Any],
    pairs: list[tuple[np.ndarray, np.ndarray]],
    tracker_sigma: Optional[tuple] = None,
    force: bool = False,
) -> Path:
    """``out/session.yaml`` of a pose-only session: ``pairs`` of (``T_base_end``, ``T_cam_board``), views ``1``..``N``.

    ``mode`` None: left to the data (the mode gate decides). ``source``: where the poses came from (kept under
    ``source:``). ``tracker_sigma``: (mm, deg) of the tracker when known (else estimated at calibration). An
    ``out`` holding a session is refused unless ``force``.
    """
    from .fields import check_translation_units

    out = Path(out)
    for k, (T, C) in enumerate(pairs, start=1):  # millimetres written as metres: said here, naming the samples file
        check_translation_units(T, path=Path(source["file"]), line=None, unit="m", where=f"sample {k}")
        check_translation_units(C, path=Path(source["file"]), line=None, unit="m", where=f"sample {k}", tracked=True)
    kept: list[tuple[np.ndarray, np.ndarray]] = []
    repeats = []  # a sample saved twice is no second view: it would count its information twice
    for k, pair in enumerate(pairs, start=1):
        if any(_same(pair, earlier) for earlier in kept):
            repeats.append(str(k))
        else:
            kept.append(pair)
    if repeats:
        log.warning("%s: sample(s) %s repeat an earlier one exactly: left out", source["file"], ", ".join(repeats))
    if len(kept) < 3:
        raise InputError(
            f"{len(kept)} distinct sample(s); at least 3 are needed",
            path=Path(source["file"]),
            received=f"{len(pairs)} samples" + (f", {len(repeats)} of them repeats" if repeats else ""),
            hint="record at least 3 samples at different robot poses (15 or more for a good calibration)",
        )
    check_import_out(out, force=force)
    doc: dict[str, Any] = {
        "handeye_session": 1,
        **({"mode": mode} if mode else {}),
        "source": source,
        "pose_format": {"rotation": "matrix"},
        "target_pose_format": {"rotation": "matrix"},
    }
    if tracker_sigma is not None:
        doc["tracker_sigma"] = {"mm": float(tracker_sigma[0]), "deg": float(tracker_sigma[1])}
    doc["views"] = [
        {"id": str(k + 1), "pose": np.round(T, 15).tolist(), "target_pose": np.round(C, 15).tolist()}
        for k, (T, C) in enumerate(kept)
    ]
    return _write(out, doc)


def _write(out: Path, doc: dict) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / SESSION_FILE
    atomic_write_text(path, yaml.safe_dump(doc, sort_keys=False))
    return path
