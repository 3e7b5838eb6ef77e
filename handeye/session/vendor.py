"""The vendor session folder as it is: ``config.yaml``, ``poses.txt`` and numbered images.

``config.yaml`` gives the board, ``poses.txt`` one pose line per image (``x,y,z,rx,ry,rz`` in metres and
radians), images ``1.jpg, 2.jpg, ...`` pair with lines 1, 2, ...; images numbered from 0 pair image k
with line k+1. A first line of column names is skipped like a ``#`` comment. config.yaml may state
another line format (``pose_format:``, as in session.yaml: :func:`vendor_pose_format`).

:func:`read_pose_lines`, :func:`read_vendor_config` and :func:`numbered_images` are the only parsers of
these files; the strict loader (:func:`load_vendor_session`) and the lenient reader of the diagnostics
(:mod:`handeye.session.raw`) both use them.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..conventions import VENDOR_POSE_FORMAT, PoseFormat, T_from_pose_values
from ..errors import ConfigError, InputError
from ..output import read_text
from ..records import Session, View
from ..targets import ChessboardSpec
from .fields import (
    check_angle_units,
    check_finite,
    check_input_file,
    check_mode,
    check_target_points,
    check_translation_units,
    length_m,
    parse_pose_format,
    positive_number,
    read_yaml,
    session_limits,
)
from .keys import CHECKERBOARD_KEYS, CONFIG_KEYS, nearest_key, unknown_keys

log = logging.getLogger(__name__)

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
_NUMBERED = re.compile(r"^(\d+)$")
_PREFIXED = re.compile(r"^(\D+)(\d+)$")  # image_1, img-01: a number behind a name
_NOT_NAMES = {"none", "null", "nil", "na", "n/a", "undefined", "error"}  # a value that failed, not a column name
_NAME = re.compile(r"^[A-Za-z_][\w()\[\]/.-]*$")  # a column name: x, rx, rx(rad), x[m]
_POSE_EXPECTED = "x,y,z,rx,ry,rz (metres, radians)"
#: the mode of a vendor session whose config.yaml states none (the vendor's rig is eye-in-hand)
VENDOR_DEFAULT_MODE = "eye_in_hand"


@dataclass(frozen=True)
class PoseLine:
    """One pose line of poses.txt: its image's number, line number and numbers as written.

    One pose line of poses.txt: its image's number (the pose lines counted from the first image's
    number), the line number in the file and the numbers as written.
    """

    index: int
    lineno: int
    values: np.ndarray  # (n,) as written, no unit conversion


def read_pose_lines(poses_path: Path, *, first: int = 1) -> list[PoseLine]:
    """The pose lines of poses.txt.

    The pose lines of poses.txt (blank lines, ``#`` comments and a first line of column names skipped),
    numbered from ``first`` (the number of the first image: :func:`first_image_number`); InputError on a
    line that is not numbers. Counts and units are not checked here.
    """
    raw_lines = read_text(poses_path, what="poses.txt").splitlines()
    out: list[PoseLine] = []
    header = None  # (line number, fields, text) of a first line of column names
    for lineno, line in enumerate(raw_lines, start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        fields = [f for f in re.split(r"[,\s]+", s) if f]
        if not out and header is None and _is_header(fields):
            header = (lineno, fields, s)
            continue
        try:  # a line printed as a list or tuple ([x, y, z, rx, ry, rz]) holds the same numbers
            if _decimal_commas(s):  # 0,512 -0,2 (tabs or spaces): each comma would split a number in two
                raise ValueError(s)
            values = np.array([float(f) for f in (f.strip("[]()") for f in fields) if f])
        except ValueError:
            raise InputError(
                "malformed pose line",
                path=poses_path,
                line=lineno,
                expected=_POSE_EXPECTED,
                received=repr(s[:80]),
                hint=_malformed_hint(s),
            ) from None
        if not out and header is not None:
            if len(header[1]) != values.size:  # not the names of these columns: a pose line gone wrong
                raise InputError(
                    "malformed pose line",
                    path=poses_path,
                    line=header[0],
                    expected=_POSE_EXPECTED,
                    received=repr(header[2][:80]),
                    hint=f"as column names it names {len(header[1])} columns, the lines hold {values.size}",
                )
            log.debug("%s:%d: column names skipped: %s", poses_path, header[0], header[2][:80])
        check_finite(
            values,
            path=poses_path,
            line=lineno,
            what="pose line",
            hint=f"fix line {lineno} (lines pair with images by number: removing only the line puts every later "
            "image out of step; to drop the view, remove the line and its image together and renumber the later "
            "images)",
        )
        out.append(PoseLine(len(out) + first, lineno, values))
    if not out:
        raise InputError("poses.txt has no pose lines", path=poses_path, expected="one line x,y,z,rx,ry,rz per image")
    return out


def _decimal_commas(line: str) -> bool:
    """Numbers separated by white space (tabs, spaces) whose decimal mark is a comma (``0,512  -0,2``).

    Read with commas as separators too, such a line gives twice the numbers, or fractions read as integers
    (``0,692010593`` as 0 and 692010593); it is malformed, with the decimal-comma hint.
    """
    tokens = line.split()
    return (
        len(tokens) >= 2
        and all(re.fullmatch(r"[-+]?\d+(,\d+)?", tok) for tok in tokens)
        and any("," in tok for tok in tokens)
    )


def _malformed_hint(line: str) -> str:
    """What a pose line that does not read as numbers most likely holds, and what to do."""
    decimal_commas = re.search(r"\d,\d", line) and not re.search(r"\d\.\d", line)
    if decimal_commas:
        return "write decimal points, not decimal commas (a locale's export), e.g. 0.512 not 0,512" + (
            ", and separate the numbers with commas or spaces" if ";" in line else ""
        )
    if ";" in line:
        return "separate the numbers with commas or spaces, not semicolons"
    if "#" in line:
        return "put a comment on a line of its own (starting with #)"
    return "write six numbers x,y,z,rx,ry,rz (metres and radians) per line"


def _is_header(fields: list[str]) -> bool:
    """A line of column names: every field a name (a letter first, no ``=``), none a number.

    A line of column names: every field a name (a letter first, no ``=``), none a number (``nan`` and ``inf``
    are numbers here, so a pose line holding them is still refused as not finite).
    """

    def number(f: str) -> bool:
        try:
            float(f)
            return True
        except ValueError:
            return False

    return bool(fields) and all(_NAME.match(f) and not number(f) and f.lower() not in _NOT_NAMES for f in fields)


def read_vendor_config(folder: Path, *, strict: bool = True) -> tuple[ChessboardSpec, str | None, dict]:
    """(board, mode stated in config.yaml or None, the whole config) from ``folder/config.yaml``.

    ``strict=False`` skips the plausibility of the square size (the lenient reader re-reads sessions
    written in the wrong units).
    """
    cfg_path = folder / "config.yaml"
    if not cfg_path.exists():
        raise InputError(
            "config.yaml is missing",
            path=cfg_path,
            hint="rename config.yml to config.yaml"
            if (folder / "config.yml").exists()
            else "add config.yaml with checkerboard_args: {XX: 11, YY: 8, L: 0.03}",
        )
    cfg = read_yaml(cfg_path)
    cb = cfg.get("checkerboard_args")
    if not isinstance(cb, dict):
        raise ConfigError(
            "checkerboard_args is missing or not a mapping",
            path=cfg_path,
            expected="checkerboard_args: {XX: 11, YY: 8, L: 0.03}",
            received=repr(cb),
        )
    for key in CHECKERBOARD_KEYS:
        if key not in cb:
            near = [str(k) for k in cb if nearest_key(k, CHECKERBOARD_KEYS) == key]
            raise ConfigError(
                f"checkerboard_args.{key} is missing",
                path=cfg_path,
                expected="XX (inner corners, long side), YY (short side), L (square, metres)",
                hint=f"rename {near[0]} to {key} (the keys are case-sensitive)" if near else None,
            )
    xx = positive_number(cb["XX"], path=cfg_path, field="checkerboard_args.XX", integer=True, minimum=1)
    yy = positive_number(cb["YY"], path=cfg_path, field="checkerboard_args.YY", integer=True, minimum=1)
    check_target_points(xx * yy, path=cfg_path, field="checkerboard_args XX x YY")
    L = length_m(cb["L"], path=cfg_path, field="checkerboard_args.L", strict=strict)
    return ChessboardSpec(cols=xx, rows=yy, square_m=L), cfg.get("mode"), cfg


def unknown_config_keys(cfg: dict) -> list[str]:
    """One line per key of config.yaml that handeye does not read, naming the nearest known key.

    Unknown keys are ignored, as in session.yaml, but named: a misspelt ``mdoe: eye_to_hand`` would
    otherwise leave the mode to the data and ``l: 0.025`` the square size to ``L`` or an error.
    """
    cb = cfg.get("checkerboard_args")
    return unknown_keys(cfg, CONFIG_KEYS) + unknown_keys(cb, CHECKERBOARD_KEYS, prefix="checkerboard_args.")


def numbered_images(folder: Path) -> dict[int, Path]:
    """Image number -> file of the numbered images (``7.jpg`` is view 7) in ``folder``."""
    found: dict[int, Path] = {}
    for f in folder.iterdir():
        if f.suffix.lower() in IMAGE_EXTS and _NUMBERED.match(f.stem):
            k = int(f.stem)
            if k in found:
                raise InputError(
                    f"two images for view {k}: {found[k].name} and {f.name}",
                    path=folder,
                    hint="keep one image per number",
                )
            found[k] = f
    if not found:
        inside = sorted(
            d.name
            for d in folder.iterdir()
            if d.is_dir() and any(f.suffix.lower() in IMAGE_EXTS and _NUMBERED.match(f.stem) for f in d.iterdir())
        )
        prefixed = sorted(
            (f.name for f in folder.iterdir() if f.suffix.lower() in IMAGE_EXTS and _PREFIXED.match(f.stem)),
            key=lambda n: int(_PREFIXED.match(Path(n).stem)[2]),  # type: ignore[index]  # the names matched above
        )
        hint = (
            f"the numbered images are in {inside[0]}/: move them next to poses.txt"
            if inside
            else f"the images are named {prefixed[0]}, ...: rename them to the number alone (1.jpg, 2.jpg, ...)"
            if prefixed
            else None
        )
        raise InputError("no numbered images (1.jpg, 2.jpg, ...) in the folder", path=folder, hint=hint)
    return found


def vendor_pose_format(cfg: dict, cfg_path: Path) -> PoseFormat:
    """How poses.txt's lines are written: config.yaml's optional ``pose_format:``.

    How poses.txt's lines are written: config.yaml's optional ``pose_format:`` (the fields and defaults of
    session.yaml's), else the vendor's ``x,y,z,rx,ry,rz`` in metres and radians, R = Rz·Ry·Rx.
    """
    if cfg.get("pose_format") is None:
        return VENDOR_POSE_FORMAT
    return parse_pose_format(cfg["pose_format"], path=cfg_path)


def _count_hint(n: int, lines: list[PoseLine]) -> str:
    """What a pose line of ``n`` numbers (not 6) may be, and how to say so."""
    first = np.array([pl.values[0] if pl.values.size else np.nan for pl in lines])
    if (
        n == 7
        and all(pl.values.size == 7 for pl in lines)
        and len(lines) > 1
        and (np.array_equal(first, np.arange(len(lines))) or np.array_equal(first, np.arange(1, len(lines) + 1)))
    ):
        return "the first number of every line counts the lines (a view number): remove that column"
    guess = {
        7: "x,y,z and a quaternion: add to config.yaml pose_format: {rotation: quaternion, "
        "quaternion_order: wxyz} (or xyzw)",
        16: "a 4x4 matrix row by row: add to config.yaml pose_format: {rotation: matrix}",
    }.get(n)
    return f"{n} numbers may be {guess}" if guess else "write one pose per line: x,y,z,rx,ry,rz"


def _check_mixed_units(lines: list[PoseLine], fmt: PoseFormat, poses_path: Path) -> None:
    """A few pose lines in other units than the rest.

    A few pose lines in other units than the rest (angles beyond a full turn, positions beyond an arm's reach
    on fewer than half of the lines: those lines were written in degrees or millimetres, the others not): an
    InputError naming them, whose fix is to convert those lines (stating a unit for the whole file would
    misread the others). A whole file in other units is left to the per-line checks, which say how to state it.
    """
    lim = session_limits()
    rows = [pl for pl in lines if pl.values.size == fmt.n_values and np.all(np.isfinite(pl.values))]
    checks = []
    if fmt.rotation in ("euler", "rotvec") and fmt.angle_unit == "rad":
        checks.append(
            (
                "rotation angles beyond 2*pi",
                "degrees",
                "radians",
                [pl for pl in rows if np.any(np.abs(pl.values[3:6]) > lim["max_angle_rad"])],
            )
        )
    if fmt.rotation != "matrix" and fmt.translation_unit == "m":
        checks.append(
            (
                f"positions beyond an arm's reach ({lim['max_reach_m']:g} m)",
                "millimetres",
                "metres",
                [pl for pl in rows if np.linalg.norm(pl.values[:3]) > lim["max_reach_m"]],
            )
        )
    for what, unit, stated, bad in checks:
        if bad and 2 * len(bad) < len(rows):
            named = ", ".join(str(pl.lineno) for pl in bad[:8]) + (", ..." if len(bad) > 8 else "")
            raise InputError(
                f"{what} on {len(bad)} of {len(rows)} pose lines (line{'s' if len(bad) > 1 else ''} {named})",
                path=poses_path,
                line=bad[0].lineno,
                expected=f"every line in {stated}",
                hint=f"those lines look like {unit} while the others fit {stated}: convert those lines "
                f"to {stated} (or re-export the poses in one unit)",
            )


def first_image_number(images: dict[int, Path]) -> int:
    """The number of the first pose line's image: 0 when the images are numbered from 0, else 1."""
    return 0 if 0 in images else 1


def load_vendor_session(folder: str | Path, *, mode: str | None = None) -> Session:
    """The vendor folder, validated: units checked, every image paired with its pose line."""
    folder = Path(folder)
    target, cfg_mode, cfg = read_vendor_config(folder)
    for line in unknown_config_keys(cfg):
        log.warning("%s: %s", folder / "config.yaml", line)
    sess_mode = check_mode(mode if mode is not None else (cfg_mode or VENDOR_DEFAULT_MODE), path=folder / "config.yaml")

    poses_path = folder / "poses.txt"
    fmt = vendor_pose_format(cfg, folder / "config.yaml")
    stated = fmt is not VENDOR_POSE_FORMAT
    pose_lines = read_pose_lines(poses_path)
    images = numbered_images(folder)
    first = first_image_number(images)
    if first == 0:
        log.info("%s: images numbered from 0: image k is paired with pose line k+1", folder)
    _check_mixed_units(pose_lines, fmt, poses_path)
    poses: list[tuple[int, np.ndarray]] = []  # (line number, T)
    for pl in pose_lines:
        try:
            T = T_from_pose_values(pl.values, fmt)
        except ValueError as e:
            hint = (
                "the lines do not match config.yaml's pose_format: fix one of the two"
                if stated
                else None
                if pl.values.size == fmt.n_values
                else _count_hint(pl.values.size, pose_lines)
            )
            raise InputError(
                f"bad pose: {e}",
                path=poses_path,
                line=pl.lineno,
                expected=fmt.describe() if stated else _POSE_EXPECTED,
                hint=hint,
            ) from None
        check_translation_units(
            T,
            path=poses_path,
            line=pl.lineno,
            unit=fmt.translation_unit,
            or_state=""
            if stated
            else "add to config.yaml pose_format: {rotation: euler, translation_unit: mm} (or cm)",
        )
        if fmt.rotation in ("euler", "rotvec") and fmt.angle_unit == "rad":
            check_angle_units(
                pl.values[3:],
                path=poses_path,
                line=pl.lineno,
                or_state="" if stated else "add to config.yaml pose_format: {rotation: euler, angle_unit: deg}",
            )
        poses.append((pl.lineno, T))

    n_pose = len(poses)
    missing = [k for k in sorted(images) if k - first >= n_pose]
    if missing:
        belongs = (
            "line k of poses.txt belongs to k.jpg"
            if first
            else "line k+1 of poses.txt belongs to k.jpg (images numbered from 0)"
        )
        gaps = [k for k in range(first, max(images)) if k not in images]  # numbers with no image below the last
        without = (
            f"; the images run to {images[max(images)].name} without "
            + ", ".join(f"{k}{images[max(images)].suffix}" for k in gaps[:5])
            + (" ..." if len(gaps) > 5 else "")
            if gaps
            else ""
        )
        hint = (
            f"{belongs}: an image deleted with its pose line puts every later image out of step; put a line back "
            f"in its place (any pose: a line without its image is a dropped view), or renumber the later images"
            if gaps
            else f"{belongs}; add the missing poses (a pose missing in between puts every later image out of step: "
            "the report names where) or remove the extra images"
        )
        what = (
            f"image {images[missing[0]].name} has no pose line: poses.txt has {n_pose} lines{without}"
            if gaps
            else f"{len(images)} images but {n_pose} pose lines: image {images[missing[0]].name} has no pose line"
        )
        raise InputError(what, path=poses_path, hint=hint)
    # Gaps are allowed: a pose line whose image was deleted stays in the session as a dropped view.
    without_image = [k for k in range(first, first + n_pose) if k not in images]
    if without_image:
        log.warning(
            "%s: pose lines without an image (views dropped): %s", poses_path, [k + 1 - first for k in without_image]
        )
    views = []
    for k in sorted(images):
        lineno, T = poses[k - first]
        check_input_file(images[k], what="image", vid=str(k))
        views.append(View(view_id=str(k), image_path=images[k], T_base_end=T, source_line=lineno))
    return Session(
        path=folder,
        format="vendor",
        mode=sess_mode,
        target=target,
        views=tuple(views),
        pose_format=fmt.describe(),
        mode_source="flag" if mode is not None else ("stated" if cfg_mode else "default"),
        meta={
            "config": cfg,
            "missing_images": {str(k): k - first + 1 for k in without_image},  # pose line k
            "files_read": [folder / "config.yaml", poses_path, *(images[k] for k in sorted(images))],
        },
    )
