"""Reading sessions from disk: the vendor folder as it is, and handeye's native session.yaml.

Everything is validated here, once; errors name the file (and line) and what to do. Poses are
converted to ``T_base_end`` (metres) at this boundary. See docs/session_format.md.
"""
from __future__ import annotations

import logging
import math
import re
from pathlib import Path

import numpy as np
import yaml

from ..conventions import VENDOR_POSE_FORMAT, PoseFormat, T_from_pose_values
from ..errors import ConfigError, InputError
from ..mounting import MODES
from ..targets import CharucoSpec, ChessboardSpec, CircleGridSpec
from ..camera import Intrinsics
from ..records import Session, View, view_id_key

log = logging.getLogger(__name__)

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
_NUMBERED = re.compile(r"^(\d+)$")


def load_session(path: str | Path, *, mode: str | None = None) -> Session:
    """Load a session folder (native ``session.yaml`` or vendor ``poses.txt``), or a session.yaml path.

    ``mode`` overrides the mode stated in the session (the CLI's ``--mode``).
    """
    p = Path(path)
    if not p.exists():
        raise InputError("session not found", path=p, hint="pass the folder that holds the images and poses")
    if p.is_file():
        if p.name.endswith((".yaml", ".yml")):
            return load_native_session(p, mode=mode)
        if p.name == "poses.txt":
            return load_vendor_session(p.parent, mode=mode)
        raise InputError("not a session file", path=p, expected="a folder, session.yaml or poses.txt")
    if (p / "session.yaml").exists():
        return load_native_session(p / "session.yaml", mode=mode)
    if (p / "poses.txt").exists():
        return load_vendor_session(p, mode=mode)
    raise InputError("no session.yaml or poses.txt in the folder", path=p,
                     hint="a vendor session needs poses.txt, N.jpg and config.yaml; see docs/session_format.md")


def _read_yaml(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read file ({e.strerror})", path=path) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        raise InputError("not valid YAML", path=path, line=None if line is None else line + 1,
                         hint="fix the syntax of this file") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InputError("expected a mapping at the top level", path=path, received=type(data).__name__)
    return data


def _check_mode(mode, *, path: Path, field: str = "mode") -> str:
    if mode not in MODES:
        raise ConfigError(f"invalid {field}", path=path, expected=" | ".join(MODES), received=repr(mode))
    return mode


def _positive_number(value, *, path: Path, field: str, integer: bool = False, minimum: float = 0.0):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if not ok or value <= minimum:
        kind = "an integer" if integer else "a number"
        raise ConfigError(f"invalid {field}", path=path, expected=f"{kind} > {minimum:g}", received=repr(value),
                          hint="fix the value in this file")
    return int(value) if integer else float(value)


def _square_size_m(value, *, path: Path, field: str) -> float:
    L = _positive_number(value, path=path, field=field)
    if L > 0.5:
        raise ConfigError(f"{field} looks like millimetres", path=path, expected="the square size in metres (e.g. 0.03)",
                          received=repr(value), hint=f"write {L / 1000:g} if the squares are {L:g} mm")
    if L < 1e-3:
        raise ConfigError(f"{field} is implausibly small", path=path, expected="the square size in metres (e.g. 0.03)",
                          received=repr(value))
    return L


# ----------------------------------------------------------------------------------------- vendor
def load_vendor_session(folder: str | Path, *, mode: str | None = None) -> Session:
    folder = Path(folder)
    cfg_path = folder / "config.yaml"
    if not cfg_path.exists():
        raise InputError("config.yaml is missing", path=cfg_path,
                         hint="add config.yaml with checkerboard_args: {XX: 11, YY: 8, L: 0.03}")
    cfg = _read_yaml(cfg_path)
    cb = cfg.get("checkerboard_args")
    if not isinstance(cb, dict):
        raise ConfigError("checkerboard_args is missing or not a mapping", path=cfg_path,
                          expected="checkerboard_args: {XX: 11, YY: 8, L: 0.03}", received=repr(cb))
    for key in ("XX", "YY", "L"):
        if key not in cb:
            raise ConfigError(f"checkerboard_args.{key} is missing", path=cfg_path,
                              expected="XX (inner corners, long side), YY (short side), L (square, metres)")
    xx = _positive_number(cb["XX"], path=cfg_path, field="checkerboard_args.XX", integer=True, minimum=1)
    yy = _positive_number(cb["YY"], path=cfg_path, field="checkerboard_args.YY", integer=True, minimum=1)
    L = _square_size_m(cb["L"], path=cfg_path, field="checkerboard_args.L")
    target = ChessboardSpec(cols=xx, rows=yy, square_m=L)
    sess_mode = _check_mode(mode if mode is not None else cfg.get("mode", "eye_in_hand"), path=cfg_path)

    poses_path = folder / "poses.txt"
    try:
        raw_lines = poses_path.read_text(encoding="utf-8", errors="strict").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read poses.txt ({e})", path=poses_path) from None
    poses: list[tuple[int, np.ndarray]] = []  # (line number, T)
    for lineno, line in enumerate(raw_lines, start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f for f in re.split(r"[,\s]+", s) if f]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise InputError("malformed pose line", path=poses_path, line=lineno,
                             expected="x,y,z,rx,ry,rz (metres, radians)", received=repr(s[:80])) from None
        try:
            T = T_from_pose_values(values, VENDOR_POSE_FORMAT)
        except ValueError as e:
            raise InputError(f"bad pose: {e}", path=poses_path, line=lineno,
                             expected="x,y,z,rx,ry,rz (metres, radians)") from None
        _check_translation_units(T, path=poses_path, line=lineno, unit="m")
        _check_angle_units(values[3:], path=poses_path, line=lineno)
        poses.append((lineno, T))
    if not poses:
        raise InputError("poses.txt has no pose lines", path=poses_path, expected="one line x,y,z,rx,ry,rz per image")

    images = _numbered_images(folder)
    n_pose = len(poses)
    missing = [k for k in images if k > n_pose]
    if missing:
        raise InputError(f"{len(images)} images but {n_pose} pose lines: image {images[missing[0]].name} has no pose line",
                         path=poses_path, hint="line k of poses.txt belongs to k.jpg; add the missing poses or remove the extra images")
    # Gaps are allowed: a pose line whose image was deleted stays in the session as a dropped view.
    without_image = [k for k in range(1, n_pose + 1) if k not in images]
    if without_image:
        log.warning("%s: pose lines without an image (views dropped): %s", poses_path, without_image)
    views = []
    for k in sorted(images):
        lineno, T = poses[k - 1]
        views.append(View(view_id=str(k), image_path=images[k], T_base_end=T, source_line=lineno))
    return Session(path=folder, format="vendor", mode=sess_mode, target=target, views=tuple(views),
                   pose_format=VENDOR_POSE_FORMAT.describe(),
                   meta={"config": cfg, "missing_images": {str(k): poses[k - 1][0] for k in without_image}})


def _numbered_images(folder: Path) -> dict[int, Path]:
    found: dict[int, Path] = {}
    for f in folder.iterdir():
        if f.suffix.lower() in IMAGE_EXTS and _NUMBERED.match(f.stem):
            k = int(f.stem)
            if k in found:
                raise InputError(f"two images for view {k}: {found[k].name} and {f.name}", path=folder,
                                 hint="keep one image per number")
            if k < 1:
                raise InputError("image numbering starts at 1", path=f, hint="rename 0.jpg to 1.jpg etc.")
            found[k] = f
    if not found:
        raise InputError("no numbered images (1.jpg, 2.jpg, ...) in the folder", path=folder)
    return found


def _check_translation_units(T: np.ndarray, *, path: Path, line: int | None, unit: str) -> None:
    dist = float(np.linalg.norm(T[:3, 3]))
    if dist > 5.0:
        hint = ("the translation looks like millimetres; convert to metres" if unit == "m"
                else "check translation_unit")
        raise InputError(f"robot position {dist:.1f} m from the base is not plausible", path=path, line=line,
                         expected="metres (an arm reaches < 5 m)", hint=hint)


def _check_angle_units(angles, *, path: Path, line: int | None) -> None:
    a = np.abs(np.asarray(angles, float))
    if np.any(a > 2 * np.pi + 1e-6):
        raise InputError(f"rotation angle {a.max():.1f} is larger than 2*pi", path=path, line=line,
                         expected="radians", hint="the angles look like degrees; convert them to radians")


# ----------------------------------------------------------------------------------------- native
def load_native_session(path: str | Path, *, mode: str | None = None) -> Session:
    path = Path(path)
    folder = path.parent
    d = _read_yaml(path)
    version = d.get("handeye_session", 1)
    if version != 1:
        raise ConfigError("unsupported handeye_session version", path=path, expected="1", received=repr(version))
    sess_mode = _check_mode(mode if mode is not None else d.get("mode"), path=path)
    target = parse_target(d.get("target"), path=path)
    fmt_d = d.get("pose_format") or {}
    if not isinstance(fmt_d, dict):
        raise ConfigError("pose_format must be a mapping", path=path, received=repr(fmt_d))
    unknown = set(fmt_d) - set(PoseFormat.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"unknown pose_format field {sorted(unknown)[0]!r}", path=path,
                          expected=", ".join(f for f in PoseFormat.__dataclass_fields__))
    fmt = PoseFormat(**{k: (str(v).lower() if isinstance(v, str) else v) for k, v in fmt_d.items()}).validated(
        source=str(path))
    intr, intr_use = _parse_intrinsics(d.get("intrinsics"), path=path)

    entries: list[tuple[dict, Path, int | None]] = []
    inline = d.get("views") or []
    if not isinstance(inline, list):
        raise ConfigError("views must be a list", path=path, received=type(inline).__name__)
    for i, e in enumerate(inline):
        entries.append((e, path, None))
    rec_dir = d.get("view_records")
    if rec_dir:
        rd = folder / str(rec_dir)
        if rd.is_dir():
            for f in sorted(rd.iterdir()):
                if f.name.startswith(".") or f.suffix not in (".yaml", ".yml"):
                    continue
                entries.append((_read_yaml(f), f, None))
    if not entries:
        raise InputError("the session has no views", path=path, hint="add a views: list or records in view_records/")
    views = []
    seen: set[str] = set()
    for e, src, _ in entries:
        if not isinstance(e, dict):
            raise ConfigError("each view must be a mapping with id, image, pose", path=src, received=repr(e)[:60])
        for key in ("id", "image", "pose"):
            if key not in e:
                raise ConfigError(f"view is missing {key!r}", path=src, received=repr(e)[:80],
                                  expected="id, image, pose")
        vid = str(e["id"])
        if vid in seen:
            raise ConfigError(f"duplicate view id {vid!r}", path=src, hint="give every view its own id")
        seen.add(vid)
        try:
            T = T_from_pose_values(np.asarray(e["pose"], dtype=float), fmt)
        except (ValueError, TypeError) as err:
            raise InputError(f"view {vid}: bad pose: {err}", path=src, expected=fmt.describe()) from None
        _check_translation_units(T, path=src, line=None, unit=fmt.translation_unit)
        img = folder / str(e["image"])
        if not img.exists():
            raise InputError(f"view {vid}: image file missing", path=img, hint="restore the image or remove the view")
        views.append(View(view_id=vid, image_path=img, T_base_end=T,
                          t_image=_opt_float(e.get("t_image")), t_pose=_opt_float(e.get("t_pose"))))
    views.sort(key=lambda v: view_id_key(v.view_id))
    return Session(path=folder, format="native", mode=sess_mode, target=target, views=tuple(views),
                   intrinsics=intr, intrinsics_prior=intr_use, pose_format=fmt.describe(),
                   meta={k: v for k, v in d.items() if k not in ("views",)})


def _opt_float(v):
    return None if v is None else float(v)


def _int_pair(t: dict, key: str, meaning: str, *, path: Path, minimum: int) -> tuple[int, int]:
    """``target.<key>``: two integers > minimum, with a message naming the field."""
    v = t.get(key)
    if not (isinstance(v, (list, tuple)) and len(v) == 2):
        raise ConfigError(f"target.{key} must be {meaning}", path=path, received=repr(v))
    return tuple(_positive_number(v[k], path=path, field=f"target.{key}[{k}]", integer=True, minimum=minimum)
                 for k in range(2))


def parse_target(t, *, path: Path):
    if not isinstance(t, dict) or "type" not in t:
        raise ConfigError("target is missing or has no type", path=path,
                          expected="target: {type: chessboard, inner_corners: [11, 8], square_m: 0.03}")
    kind = t["type"]
    if kind == "chessboard":
        cols, rows = _int_pair(t, "inner_corners", "[cols, rows]", path=path, minimum=1)
        return ChessboardSpec(cols, rows, _square_size_m(t.get("square_m"), path=path, field="target.square_m"))
    if kind == "charuco":
        sx, sy = _int_pair(t, "squares", "[squares_x, squares_y]", path=path, minimum=2)
        square = _square_size_m(t.get("square_m"), path=path, field="target.square_m")
        marker = _positive_number(t.get("marker_m"), path=path, field="target.marker_m")
        if marker >= square:
            raise ConfigError("target.marker_m must be smaller than square_m", path=path,
                              received=f"marker {marker} >= square {square}")
        dictionary = str(t.get("dictionary", "DICT_6X6_250"))
        import cv2

        if not hasattr(cv2.aruco, dictionary):
            raise ConfigError("unknown ArUco dictionary", path=path, expected="e.g. DICT_6X6_250",
                              received=repr(dictionary))
        return CharucoSpec(sx, sy, square, marker, dictionary, bool(t.get("legacy_pattern", False)))
    if kind == "circlegrid":
        cols, rows = _int_pair(t, "grid", "[cols, rows] (dots per row, dots per column)", path=path, minimum=1)
        spacing = _square_size_m(t.get("spacing_m"), path=path, field="target.spacing_m")
        flags = {}
        for name in ("asymmetric", "origin_dot"):
            v = t.get(name, False)
            if not isinstance(v, bool):
                raise ConfigError(f"invalid target.{name}", path=path, expected="true | false", received=repr(v))
            flags[name] = v
        if flags["asymmetric"] and flags["origin_dot"]:
            raise ConfigError("target.origin_dot is for symmetric grids only", path=path,
                              received="asymmetric: true, origin_dot: true",
                              hint="an asymmetric grid needs no origin dot; set one of them to false")
        return CircleGridSpec(cols, rows, spacing, **flags)
    raise ConfigError("unknown target type", path=path, expected="chessboard | charuco | circlegrid",
                      received=repr(kind))


def _parse_intrinsics(d, *, path: Path):
    if d is None:
        return None, "estimate"
    if not isinstance(d, dict):
        raise ConfigError("intrinsics must be a mapping", path=path, received=repr(d)[:60])
    model = d.get("model", "opencv5")
    if model not in ("opencv5", "pinhole"):
        raise ConfigError("unsupported intrinsics model", path=path, expected="opencv5 (k1,k2,p1,p2,k3) | pinhole",
                          received=repr(model))
    vals = {k: _positive_number(d.get(k), path=path, field=f"intrinsics.{k}") for k in ("fx", "fy", "cx", "cy")}
    dist = d.get("dist", [0, 0, 0, 0, 0]) if model == "opencv5" else [0, 0, 0, 0, 0]
    dist = np.asarray(dist, dtype=float).reshape(-1)
    if dist.size not in (4, 5) or not np.all(np.isfinite(dist)):
        raise ConfigError("intrinsics.dist must be 4 or 5 finite numbers (k1, k2, p1, p2[, k3])", path=path,
                          received=repr(d.get("dist")))
    size = d.get("image_size")
    if not (isinstance(size, (list, tuple)) and len(size) == 2):
        raise ConfigError("intrinsics.image_size must be [width, height]", path=path, received=repr(size))
    w = _positive_number(size[0], path=path, field="intrinsics.image_size[0]", integer=True)
    h = _positive_number(size[1], path=path, field="intrinsics.image_size[1]", integer=True)
    use = d.get("use", "fixed")
    if use not in ("fixed", "prior", "initial"):
        raise ConfigError("invalid intrinsics.use", path=path, expected="fixed | prior | initial", received=repr(use))
    K = np.array([[vals["fx"], 0, vals["cx"]], [0, vals["fy"], vals["cy"]], [0, 0, 1]])
    return Intrinsics.from_K(K, dist, w, h), {"initial": "estimate"}.get(use, use)
