"""The ``target:`` section of a session file read into a target spec.

Chessboard, ChArUco, circle grid, one marker or an AprilGrid.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ..errors import ConfigError
from ..targets import AprilGridSpec, CharucoSpec, ChessboardSpec, CircleGridSpec, MarkerSpec, TargetSpec
from .fields import check_target_points, length_m, positive_number

TARGET_TYPES = ("chessboard", "charuco", "circlegrid", "marker", "aprilgrid")


def _int_pair(t: dict, key: str, meaning: str, *, path: Path, minimum: int) -> tuple[int, int]:
    """``target.<key>``: two integers > minimum, with a message naming the field."""
    v = t.get(key)
    if not (isinstance(v, (list, tuple)) and len(v) == 2):
        raise ConfigError(f"target.{key} must be {meaning}", path=path, received=repr(v))
    pair = tuple(
        positive_number(v[k], path=path, field=f"target.{key}[{k}]", integer=True, minimum=minimum) for k in range(2)
    )
    check_target_points(pair[0] * pair[1], path=path, field=f"target.{key}")
    return pair


def _flag(t: dict, name: str, *, path: Path) -> bool:
    v = t.get(name, False)
    if not isinstance(v, bool):
        raise ConfigError(f"invalid target.{name}", path=path, expected="true | false", received=repr(v))
    return v


def _chessboard(t: dict, path: Path) -> ChessboardSpec:
    cols, rows = _int_pair(t, "inner_corners", "[cols, rows]", path=path, minimum=1)
    return ChessboardSpec(cols, rows, length_m(t.get("square_m"), path=path, field="target.square_m"))


def _charuco(t: dict, path: Path) -> CharucoSpec:
    sx, sy = _int_pair(t, "squares", "[squares_x, squares_y]", path=path, minimum=2)
    square = length_m(t.get("square_m"), path=path, field="target.square_m")
    marker = positive_number(t.get("marker_m"), path=path, field="target.marker_m")
    if marker >= square:
        raise ConfigError(
            "target.marker_m must be smaller than square_m", path=path, received=f"marker {marker} >= square {square}"
        )
    dictionary = _dictionary(t, "DICT_6X6_250", path=path)
    return CharucoSpec(sx, sy, square, marker, dictionary, bool(t.get("legacy_pattern", False)))


def _dictionary(t: dict, default: str, *, path: Path) -> str:
    """``target.dictionary``: one of cv2.aruco's predefined dictionaries.

    ``target.dictionary``: one of cv2.aruco's predefined dictionaries (AprilTag families included, e.g.
    DICT_APRILTAG_36h11).
    """
    dictionary = str(t.get("dictionary", default))
    import cv2

    if not (dictionary.startswith("DICT_") and hasattr(cv2.aruco, dictionary)):
        raise ConfigError(
            "unknown ArUco dictionary",
            path=path,
            expected="e.g. DICT_6X6_250 or DICT_APRILTAG_36h11",
            received=repr(dictionary),
        )
    return dictionary


def _marker_id(t: dict, key: str, dictionary: str, *, path: Path, count: int = 1) -> int:
    """``target.<key>``: a marker id of ``dictionary`` (``count`` consecutive ids must exist)."""
    import cv2

    v = positive_number(t.get(key, 0), path=path, field=f"target.{key}", integer=True, minimum=-1)
    size = len(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)).bytesList)
    if v + count > size:
        raise ConfigError(
            f"target.{key} is beyond the dictionary",
            path=path,
            expected=f"ids 0..{size - 1} of {dictionary}",
            received=f"{v}..{v + count - 1}",
        )
    return int(v)


def _marker(t: dict, path: Path) -> MarkerSpec:
    size = length_m(t.get("size_m"), path=path, field="target.size_m")
    dictionary = _dictionary(t, "DICT_APRILTAG_36h11", path=path)
    return MarkerSpec(size, dictionary, _marker_id(t, "marker_id", dictionary, path=path))


def _aprilgrid(t: dict, path: Path) -> AprilGridSpec:
    cols, rows = _int_pair(t, "tags", "[cols, rows] (tags per row, rows of tags)", path=path, minimum=1)
    size = length_m(t.get("size_m"), path=path, field="target.size_m")
    spacing = positive_number(t.get("spacing", 0.3), path=path, field="target.spacing")
    dictionary = _dictionary(t, "DICT_APRILTAG_36h11", path=path)
    first = _marker_id(t, "first_id", dictionary, path=path, count=cols * rows)
    border = t.get("border_bits", 2)
    if border not in (1, 2) or isinstance(border, bool):
        raise ConfigError(
            "target.border_bits is not 1 or 2",
            path=path,
            expected="2 (Kalibr's AprilGrid) or 1 (tags made by OpenCV)",
            received=repr(border),
        )
    return AprilGridSpec(cols, rows, size, spacing, dictionary, first, int(border))


def _circlegrid(t: dict, path: Path) -> CircleGridSpec:
    cols, rows = _int_pair(t, "grid", "[cols, rows] (dots per row, dots per column)", path=path, minimum=1)
    spacing = length_m(t.get("spacing_m"), path=path, field="target.spacing_m")
    asymmetric, origin_dot = _flag(t, "asymmetric", path=path), _flag(t, "origin_dot", path=path)
    if asymmetric and origin_dot:
        raise ConfigError(
            "target.origin_dot is for symmetric grids only",
            path=path,
            received="asymmetric: true, origin_dot: true",
            hint="an asymmetric grid needs no origin dot; set one of them to false",
        )
    return CircleGridSpec(cols, rows, spacing, asymmetric=asymmetric, origin_dot=origin_dot)


_PARSERS: dict[str, Callable[[dict[str, Any], Path], TargetSpec]] = {
    "chessboard": _chessboard,
    "charuco": _charuco,
    "circlegrid": _circlegrid,
    "marker": _marker,
    "aprilgrid": _aprilgrid,
}


def parse_target(t: Any, *, path: Path) -> TargetSpec:
    """The spec a session's ``target:`` mapping describes; ConfigError naming the field otherwise."""
    if not isinstance(t, dict) or "type" not in t:
        raise ConfigError(
            "target is missing or has no type",
            path=path,
            expected="target: {type: chessboard, inner_corners: [11, 8], square_m: 0.03}",
        )
    parser = _PARSERS.get(t["type"]) if isinstance(t["type"], str) else None
    if parser is None:
        raise ConfigError("unknown target type", path=path, expected=" | ".join(TARGET_TYPES), received=repr(t["type"]))
    return parser(t, path)


def is_tracked(target) -> bool:
    """Whether a result.json ``target`` is a tracker's (a pose-only session: no images, no pixels)."""
    return isinstance(target, dict) and target.get("type") == "tracked"


def target_words(target) -> str:
    """A result.json ``target`` (the session field it was read from) in words, as its spec describes it.

    A tracker's target says so; a mapping no spec reads is given as written; anything else is an unknown board.
    """
    from ..errors import HandeyeError
    from ..targets import TrackedTargetSpec

    if not isinstance(target, dict):
        return "an unknown board"
    if is_tracked(target):
        return TrackedTargetSpec(str(target.get("name") or "")).describe()
    try:
        return parse_target(target, path=Path("result.json")).describe()
    except HandeyeError:
        return str(target)
