"""Importers for other tools' session layouts: each writes a native ``session.yaml`` whose
``image_folder`` is the original folder (nothing is copied) and states the pose format those tools use.

- ``visp``: the layout :data:`VISP_LAYOUT` describes (ViSP's eye-in-hand chessboard data); other ViSP
  targets (AprilTag's ``apriltag-data.txt``, ...) are refused by name.
- ``ical``: ROS-Industrial industrial_calibration (``cal_data.yaml`` + ``poses/N.yaml`` with
  x, y, z, qx, qy, qz, qw; ``static_camera`` decides the mode). Target finders: ChArUco
  (``CharucoGridTargetFinder``) and circle grids (``ModifiedCircleGridTargetFinder``: symmetric
  grid, ``spacing`` between dot centres, one double-size origin dot).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import yaml

from ..errors import InputError
from ..output import atomic_write_text
from .fields import read_yaml


#: what ``handeye import visp`` reads, for its help and its messages
VISP_LAYOUT = ("ViSP's eye-in-hand chessboard data (apps/calibration/hand-eye/data-eye-in-hand): images "
               "[PREFIX_]image-N.png, robot poses [PREFIX_]pose_rPe_N.yaml or pose_fPe_N.yaml (vpPoseVector: "
               "metres + theta-u radians, the end in the base frame), chessboard-data.txt ('9 x 6' inner corners, "
               "'square size: 0.0236 m'), optional *camera.xml")
_VISP_IMAGE = re.compile(r"^(?:.*_)?image-(\d+)\.png$")
_VISP_POSE = re.compile(r"^(?:.*_)?pose_[rf]Pe_(\d+)\.yaml$")


def _visp_other_target(src: Path) -> str | None:
    """The name of a ViSP target description that is not a chessboard's (e.g. apriltag-data.txt)."""
    for f in sorted(src.glob("*-data.txt")):
        if f.name != "chessboard-data.txt":
            return f.name
    return None


def import_visp(src: str | Path, out: str | Path, *, use_given_intrinsics: bool = False) -> Path:
    """``out/session.yaml`` for a ViSP data folder of the layout :data:`VISP_LAYOUT`."""
    src, out = Path(src).resolve(), Path(out)
    if not src.is_dir():
        raise InputError("not a folder", path=src, expected=VISP_LAYOUT)
    other = _visp_other_target(src)
    if other is not None and not (src / "chessboard-data.txt").exists():
        kind = other[: -len("-data.txt")]
        raise InputError(f"unsupported ViSP target {kind!r} ({other})", path=src / other,
                         expected="a chessboard (chessboard-data.txt)",
                         hint=f"handeye reads ViSP's chessboard data only; write session.yaml by hand for a "
                              "target handeye supports (chessboard, charuco, circlegrid), see "
                              "docs/session_format.md")
    imgs = {int(m.group(1)): f for f in src.iterdir() if (m := _VISP_IMAGE.match(f.name))}
    poses = {int(m.group(1)): f for f in src.iterdir() if (m := _VISP_POSE.match(f.name))}
    if not imgs:
        raise InputError("no ViSP images ([PREFIX_]image-N.png) in the folder", path=src, expected=VISP_LAYOUT)
    txt = (src / "chessboard-data.txt").read_text() if (src / "chessboard-data.txt").exists() else ""
    m = re.search(r"(\d+)\s*x\s*(\d+)", txt)
    s = re.search(r"square size:\s*([0-9.eE+-]+)", txt)
    if not (m and s):
        raise InputError("chessboard-data.txt missing or unreadable", path=src / "chessboard-data.txt",
                         expected="'9 x 6' and 'square size: 0.0236 m'", hint=f"handeye reads {VISP_LAYOUT}")
    views = []
    for k in sorted(imgs):
        if k not in poses:
            raise InputError(f"image {imgs[k].name} has no pose file", path=src,
                             expected=f"pose_rPe_{k}.yaml (or with the images' prefix)")
        data = read_yaml(poses[k]).get("data")
        if not (isinstance(data, list) and len(data) == 6):
            raise InputError("not a ViSP vpPoseVector (data: 6 rows)", path=poses[k], received=repr(data)[:60])
        views.append({"id": str(k), "image": imgs[k].name, "pose": [float(v[0]) for v in data]})
    doc = {"handeye_session": 1, "mode": "eye_in_hand",
           "target": {"type": "chessboard", "inner_corners": [int(m.group(1)), int(m.group(2))],
                      "square_m": float(s.group(1))},
           "pose_format": {"rotation": "rotvec", "angle_unit": "rad", "translation_unit": "m"},
           "image_folder": str(src), "source": {"importer": "visp", "path": str(src)}, "views": views}
    cam = next(iter(src.glob("*camera*.xml")), None)
    if use_given_intrinsics and cam is not None:
        t = cam.read_text()
        vals = {k: float(re.search(rf"<{k}>\s*([0-9.eE+-]+)", t).group(1)) for k in ("px", "py", "u0", "v0")}
        import cv2

        h, w = cv2.imread(str(imgs[min(imgs)]), cv2.IMREAD_GRAYSCALE).shape
        doc["intrinsics"] = {"model": "opencv5", "fx": vals["px"], "fy": vals["py"], "cx": vals["u0"],
                             "cy": vals["v0"], "dist": [0, 0, 0, 0, 0], "image_size": [w, h], "use": "fixed"}
    return _write(out, doc)


def import_ical(src: str | Path, out: str | Path, *, image_dir: str | None = None) -> Path:
    src, out = Path(src).resolve(), Path(out)
    cal = read_yaml(src / "cal_data.yaml")
    if not isinstance(cal, dict) or "data" not in cal:
        raise InputError("cal_data.yaml has no data list", path=src / "cal_data.yaml")
    views = []
    for k, entry in enumerate(cal["data"]):
        img = src / entry["image"]
        if image_dir is not None or not img.exists():
            alt = src / (image_dir or "images_gray") / Path(entry["image"]).name
            img = alt if alt.exists() else img
        p = read_yaml(src / entry["pose"])
        views.append({"id": Path(entry["image"]).stem, "image": os.path.relpath(img, src),
                      "pose": [p["x"], p["y"], p["z"], p["qw"], p["qx"], p["qy"], p["qz"]]})
    tgt = cal.get("target_finder", {})
    if tgt.get("type", "").lower().startswith("charuco") or "CharucoGrid" in str(tgt):
        target = {"type": "charuco", "squares": [int(tgt["cols"]), int(tgt["rows"])],
                  "square_m": float(tgt["chessboard_dim"]), "marker_m": float(tgt["aruco_marker_dim"]),
                  "dictionary": _aruco_name(int(tgt.get("dictionary", 10)))}
    elif "circlegrid" in str(tgt.get("type", "")).lower():
        # ModifiedCircleGridTargetFinder: symmetric grid with one double-size origin dot
        target = {"type": "circlegrid", "grid": [int(tgt["cols"]), int(tgt["rows"])],
                  "spacing_m": float(tgt["spacing"]), "asymmetric": False,
                  "origin_dot": str(tgt.get("type", "")).lower().startswith("modified")}
    else:
        raise InputError("unsupported industrial_calibration target finder", path=src / "cal_data.yaml",
                         expected="CharucoGridTargetFinder | ModifiedCircleGridTargetFinder",
                         received=str(tgt.get("type")))
    mode = "eye_to_hand" if cal.get("static_camera", False) else "eye_in_hand"
    doc = {"handeye_session": 1, "mode": mode, "target": target,
           "pose_format": {"rotation": "quaternion", "quaternion_order": "wxyz", "translation_unit": "m"},
           "image_folder": str(src), "source": {"importer": "ical", "path": str(src)}, "views": views}
    return _write(out, doc)


_ARUCO = {0: "DICT_4X4_50", 1: "DICT_4X4_100", 2: "DICT_4X4_250", 3: "DICT_4X4_1000", 4: "DICT_5X5_50",
          5: "DICT_5X5_100", 6: "DICT_5X5_250", 7: "DICT_5X5_1000", 8: "DICT_6X6_50", 9: "DICT_6X6_100",
          10: "DICT_6X6_250", 11: "DICT_6X6_1000", 12: "DICT_7X7_50", 13: "DICT_7X7_100", 14: "DICT_7X7_250",
          15: "DICT_7X7_1000", 16: "DICT_ARUCO_ORIGINAL"}


def _aruco_name(code: int) -> str:
    return _ARUCO.get(code, "DICT_6X6_250")


def _write(out: Path, doc: dict) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "session.yaml"
    atomic_write_text(path, yaml.safe_dump(doc, sort_keys=False))
    return path
