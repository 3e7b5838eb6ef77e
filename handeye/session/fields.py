"""Reading and validating the fields of session files.

YAML documents, numbers, lengths, the mode and the plausibility of robot positions and angles. Every
message names the file, the field, what was expected and what was received. The plausibility limits
are in ``configs/detection.yaml`` (``session:``).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import yaml

from ..config import load_preset, parse_yaml
from ..conventions import PoseFormat
from ..errors import ConfigError, InputError
from ..mounting import MODES
from ..output import file_kind, read_text


@functools.lru_cache(maxsize=None)
def session_limits() -> dict:
    """The plausibility limits of session values (configs/detection.yaml ``session``: reach, angles, lengths)."""
    return load_preset("detection")["session"]


class IdTextLoader(yaml.SafeLoader):
    """YAML's safe loader, except that the value of every ``id:`` key is kept as the text written.

    An unquoted ``010`` stays "010" (YAML 1.1 reads it as the octal number 8), ``7`` is "7",
    ``1.50`` is "1.50". A null id stays None (the loader refuses it).
    """

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if (
                    isinstance(k, yaml.ScalarNode)
                    and k.value == "id"
                    and isinstance(v, yaml.ScalarNode)
                    and v.tag != "tag:yaml.org,2002:null"
                ):
                    v.tag = "tag:yaml.org,2002:str"
        return super().construct_mapping(node, deep=deep)


def read_yaml(path: Path, *, loader=yaml.SafeLoader) -> dict:
    """The top-level mapping of a YAML file (empty file: ``{}``); InputError naming the file and line.

    ``loader``: :class:`IdTextLoader` for session files (view ids kept as written).
    """
    data = parse_yaml(read_text(path, what="YAML file"), path=path, loader=loader)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InputError("expected a mapping at the top level", path=path, received=type(data).__name__)
    return data


def kind_of_file(doc) -> "str | None":
    """What a parsed YAML/JSON document looks like, said as a hint for a reader that was given the wrong kind.

    A MoveIt Calibration samples file, an easy_handeye2 ``.samples`` file, a handeye session or result; None
    when it is none of these.
    """
    if isinstance(doc, list) and doc and all(isinstance(x, dict) for x in doc):
        if "effector_wrt_world" in doc[0] or "object_wrt_sensor" in doc[0]:
            return "a MoveIt Calibration samples file: handeye import moveit FILE"
    if isinstance(doc, dict):
        if isinstance(doc.get("samples"), list):
            return "an easy_handeye2 samples file: handeye import easy_handeye2 FILE"
        if "handeye_session" in doc:
            return "a handeye session: handeye calibrate its folder"
        if "handeye_result" in doc:
            return "a handeye result: handeye export, report or compare its folder"
    return None


@functools.lru_cache(maxsize=None)
def input_limits() -> dict:
    """``configs/input_limits.yaml``: the sizes an input file may state."""
    return load_preset("input_limits")


def check_target_points(n_points: int, *, path: Path, field: str) -> None:
    """A target with more points than :func:`input_limits` allows is refused before allocating them."""
    limit = input_limits()["max_target_points"]
    if n_points > limit:
        raise ConfigError(
            f"{field} describes a target of {n_points} points",
            path=path,
            expected=f"at most {limit} points (configs/input_limits.yaml)",
            hint="check the board size (inner corners, not millimetres)",
        )


def check_input_file(path: Path, *, what: str, source: Path | None = None, vid: str | None = None) -> Path:
    """``path`` as an input file that may be opened: a readable regular file.

    ``path`` as an input file that may be opened: a regular file (a folder, a device such as
    /dev/zero or a named pipe is never opened) that can be read; InputError naming the view and file.
    """
    import os
    import stat

    prefix = f"view {vid}: " if vid is not None else ""
    try:
        st = os.stat(path)
    except OSError as e:
        raise InputError(f"{prefix}cannot read {what} ({e.strerror})", path=path) from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(
            f"{prefix}{what} is not a regular file",
            path=path,
            received=file_kind(st.st_mode),
            expected="an image file",
            hint="point the view at its image file, or remove the view",
        )
    try:
        with open(path, "rb"):
            pass
    except OSError as e:
        raise InputError(
            f"{prefix}cannot read {what} ({e.strerror})", path=path, hint="fix the file's permissions"
        ) from None
    return path


def check_finite(
    values, *, path: Path, line: int | None, what: str, hint: str = "fix this pose, or remove the view"
) -> None:
    """Numbers read from a file must be finite and of a size a pose can have.

    Numbers read from a file must be finite and of a size a pose can have (|x| < 1e6): NaN, inf and
    1e308 are refused at load, naming the file and line, with ``hint`` (a vendor pose line's own: its
    line pairs with an image by number).
    """
    a = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(a)) or np.any(np.abs(a) > 1e6):
        bad = a[~np.isfinite(a) | (np.abs(np.nan_to_num(a, nan=np.inf)) > 1e6)][0]
        raise InputError(
            f"{what} holds a value that is not a usable number",
            path=path,
            line=line,
            expected="finite numbers (|x| < 1e6)",
            received=repr(float(bad)),
            hint=hint,
        )


def check_mode(mode, *, path: Path, field: str = "mode") -> str:
    if mode not in MODES:
        raise ConfigError(f"invalid {field}", path=path, expected=" | ".join(MODES), received=repr(mode))
    return mode


#: what ``robot_accuracy`` holds (session.yaml; ``--robot-accuracy MM DEG``)
ROBOT_ACCURACY_FORM = (
    "the arm's flange pose error per axis, common to the workspace, e.g. robot_accuracy: {mm: 0.5, deg: 0.05}"
)


def mm_deg(value, *, path: Path, field: str, expected: str, optional: tuple = ()) -> dict:
    """``{mm: NUMBER, deg: NUMBER}`` (and the ``optional`` keys) of positive numbers, as floats; ConfigError else.

    The form of a session's stated sigmas (``tracker_sigma``) and accuracies (``robot_accuracy``).
    """
    keys = ("mm", "deg", *optional)
    if not isinstance(value, dict) or not {"mm", "deg"} <= set(value) <= set(keys):
        extra = " (and optionally " + ", ".join(f"{k}: NUMBER" for k in optional) + ")" if optional else ""
        raise ConfigError(
            f"{field} must be {{mm: NUMBER, deg: NUMBER}}{extra}",
            path=path,
            received=repr(value)[:60],
            expected=expected,
        )
    return {k: positive_number(value[k], path=path, field=f"{field}.{k}") for k in keys if k in value}


def positive_number(value, *, path: Path, field: str, integer: bool = False, minimum: float = 0.0):
    """``value`` as a finite number > ``minimum`` (an int when ``integer``); ConfigError naming ``field``.

    A number written in quotes (``L: "0.03"``) is read as the number.
    """
    if isinstance(value, str):
        try:
            value = float(value.strip()) if not integer else int(value.strip())
        except ValueError:
            kind = "an integer" if integer else "a number"
            raise ConfigError(
                f"invalid {field}",
                path=path,
                expected=f"{kind} > {minimum:g}",
                received=repr(value),
                hint="write the bare number, without a unit"
                + (" (metres)" if field.endswith(".L") or "_m" in field else ""),
            ) from None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if not ok or value <= minimum:
        kind = "an integer" if integer else "a number"
        raise ConfigError(
            f"invalid {field}",
            path=path,
            expected=f"{kind} > {minimum:g}",
            received=repr(value),
            hint="fix the value in this file",
        )
    return int(value) if integer else float(value)


def length_m(value, *, path: Path, field: str, strict: bool = True) -> float:
    """A board length (square size, dot spacing) in metres; ``strict`` also rejects millimetre-sized values."""
    L = positive_number(value, path=path, field=field)
    if not strict:
        return L
    lim = session_limits()
    if L > lim["max_board_length_m"]:
        raise ConfigError(
            f"{field} looks like millimetres",
            path=path,
            expected="the square size in metres (e.g. 0.03)",
            received=repr(value),
            hint=f"write {L / 1000:g} if the squares are {L:g} mm",
        )
    if L < lim["min_board_length_m"]:
        raise ConfigError(
            f"{field} is implausibly small",
            path=path,
            expected="the square size in metres (e.g. 0.03)",
            received=repr(value),
        )
    return L


def check_translation_units(
    T_base_end: np.ndarray,
    *,
    path: Path,
    line: int | None,
    unit: str,
    or_state: str = "",
    where: str = "",
    tracked: bool = False,
) -> None:
    """A robot position farther from the base than an arm reaches means the unit is wrong.

    ``or_state``: where the file's format could say so instead (a vendor config.yaml). ``where``: the view or
    sample, said first. ``tracked``: ``T_base_end`` is a tracker's camera -> target pose (a pose-only view's
    ``target_pose``), checked against the same distance.
    """
    dist = float(np.linalg.norm(T_base_end[:3, 3]))
    reach = session_limits()["max_reach_m"]
    if dist > reach:
        hint = (
            "the translation is not in metres (millimetres or centimetres?); convert to metres"
            + (f" or {or_state}" if or_state else "")
            if unit == "m"
            else "check translation_unit"
        )
        what = (
            f"target position {dist:.1f} m from the camera" if tracked else f"robot position {dist:.1f} m from the base"
        )
        raise InputError(
            f"{where + ': ' if where else ''}{what} is not plausible",
            path=path,
            line=line,
            expected=f"metres ({'a tracked target is' if tracked else 'an arm reaches'} < {reach:g} m away)",
            hint=hint,
        )


def check_angle_units(angles_rad, *, path: Path, line: int | None, or_state: str = "") -> None:
    """Angles stated in radians larger than a full turn are degrees (``or_state``: as above)."""
    a = np.abs(np.asarray(angles_rad, float))
    if np.any(a > session_limits()["max_angle_rad"]):
        raise InputError(
            f"rotation angle {a.max():.1f} is larger than 2*pi",
            path=path,
            line=line,
            expected="radians",
            hint="the angles look like degrees; convert them to radians" + (f" or {or_state}" if or_state else ""),
        )


#: the file that makes a folder a cell of cameras (several sessions of one arm, handeye calibrate CELL_DIR)
CELL_FILE = "cell.yaml"
#: what a collection that kept no view leaves in its folder instead of a session (handeye.collect.session_writer)
EMPTY_COLLECTION_FILE = "collect_run.yaml"


def is_cell_folder(path: str | Path) -> bool:
    """True for a folder holding a cell.yaml."""
    return (Path(path) / CELL_FILE).is_file()


def locate_session(path: str | Path) -> tuple[str, Path]:
    """("native", session.yaml) or ("vendor", folder) for a session folder, session.yaml or poses.txt."""
    p = Path(path)
    if not p.exists():
        raise InputError("session not found", path=p, hint="pass the folder that holds the images and poses")
    if p.is_file():
        if p.name.endswith((".yaml", ".yml")):
            return "native", p
        if p.name == "poses.txt":
            return "vendor", p.parent
        raise InputError("not a session file", path=p, expected="a folder, session.yaml or poses.txt")
    if (p / "session.yaml").exists():
        return "native", p / "session.yaml"
    if (p / "poses.txt").exists():
        return "vendor", p
    if (p / EMPTY_COLLECTION_FILE).is_file():
        raise InputError(
            "no session.yaml or poses.txt in the folder",
            path=p,
            hint=f"its {EMPTY_COLLECTION_FILE} records a collection that kept no view (its why: says what went "
            "wrong); collect again into the folder",
        )
    near = sorted(
        f.name for f in p.iterdir() if f.is_file() and "pose" in f.stem.lower() and f.suffix.lower() in (".txt", ".csv")
    )
    raise InputError(
        "no session.yaml or poses.txt in the folder",
        path=p,
        hint=f"rename {near[0]} to poses.txt if it holds the vendor's pose lines"
        if near
        else "a vendor session needs poses.txt, N.jpg and config.yaml; see docs/session_format.md",
    )


def parse_pose_format(fmt_d, *, path: Path) -> PoseFormat:
    """The ``pose_format:`` mapping of a session file (session.yaml, or a vendor config.yaml), validated."""
    if fmt_d is None:
        raise ConfigError(
            "pose_format is missing",
            path=path,
            expected="pose_format: {rotation: euler | quaternion | rotvec | matrix, ...}",
            hint="state how the poses are written; the vendor's x,y,z,rx,ry,rz lines are "
            "pose_format: {rotation: euler, euler_order: xyz, euler_kind: extrinsic, "
            "angle_unit: rad, translation_unit: m}",
        )
    if not isinstance(fmt_d, dict):
        raise ConfigError("pose_format must be a mapping", path=path, received=repr(fmt_d))
    unknown = set(fmt_d) - set(PoseFormat.__dataclass_fields__)
    if unknown:
        raise ConfigError(
            f"unknown pose_format field {sorted(unknown)[0]!r}",
            path=path,
            expected=", ".join(f for f in PoseFormat.__dataclass_fields__),
        )
    if "rotation" not in fmt_d:
        raise ConfigError("pose_format.rotation is missing", path=path, expected="euler | quaternion | rotvec | matrix")
    return PoseFormat(**{k: (str(v).lower() if isinstance(v, str) else v) for k, v in fmt_d.items()}).validated(
        source=str(path)
    )
