"""The keys of session files that handeye reads (or writes for the record), and a warning line for any other.

A key handeye does not read is ignored, but named with the nearest known key: a misspelt optional key
would otherwise leave its default in force without a word (``usage: prior`` holds the intrinsics fixed,
``legacy_patern: true`` draws another ChArUco board, ``mdoe: eye_to_hand`` leaves the mode to the data).
"""

from __future__ import annotations

import difflib
from pathlib import Path

#: config.yaml of the vendor layout, and its checkerboard_args
CONFIG_KEYS = ("checkerboard_args", "mode", "pose_format")
CHECKERBOARD_KEYS = ("XX", "YY", "L")

#: session.yaml: what the loader reads, then what handeye writes for the record (importers, collect)
SESSION_KEYS = (
    "handeye_session",
    "mode",
    "target",
    "pose_format",
    "target_pose_format",
    "image_folder",
    "robot",
    "intrinsics",
    "views",
    "view_records",
    "tracker_sigma",
    "estimate_scale",
    "robot_accuracy",
    "source",
    "collected",
    "pose_meaning",
)
#: a view (a ``views:`` entry or a record in view_records/): read, then written by ``handeye collect``
VIEW_KEYS = ("id", "image", "pose", "pose_file", "target_pose", "joints", "t_image", "t_pose")
VIEW_RECORD_KEYS = ("robot_state", "checks", "camera_frame")
#: ``intrinsics:`` (``source``: where ``handeye collect`` took them from)
INTRINSICS_KEYS = ("model", "distortion_model", "fx", "fy", "cx", "cy", "dist", "image_size", "use", "source")
#: cell.yaml, and its ``cell:``
CELL_KEYS = ("cell", "robot")
CELL_SECTION_KEYS = ("sessions",)
#: ``target:`` by its type (what each spec's ``to_dict`` writes and its parser reads)
TARGET_KEYS = {
    "chessboard": ("type", "inner_corners", "square_m"),
    "charuco": ("type", "squares", "square_m", "marker_m", "dictionary", "legacy_pattern"),
    "circlegrid": ("type", "grid", "spacing_m", "asymmetric", "origin_dot"),
    "marker": ("type", "size_m", "dictionary", "marker_id"),
    "aprilgrid": ("type", "tags", "size_m", "spacing", "dictionary", "first_id", "border_bits"),
    "tracked": ("type", "name"),
}


def nearest_key(key: object, known: tuple[str, ...]) -> str | None:
    """The known key ``key`` most likely misspells (case aside), or None."""
    by_lower = {k.lower(): k for k in known}
    close = difflib.get_close_matches(str(key).lower(), list(by_lower), n=1, cutoff=0.6)
    return by_lower[close[0]] if close else None


def unknown_keys(mapping: object, known: tuple[str, ...], *, prefix: str = "") -> list[str]:
    """One line per key of ``mapping`` (when it is a mapping) not in ``known``, naming the nearest known key."""
    if not isinstance(mapping, dict):
        return []
    lines = []
    for key in mapping:
        if key in known:
            continue
        near = nearest_key(key, known)
        lines.append(
            f"unknown key {prefix}{key} is ignored"
            + (f" (did you mean {prefix}{near}?)" if near else "")
            + f"; known keys: {', '.join(prefix + k for k in known)}"
        )
    return lines


def unknown_session_keys(doc: dict, views: list[tuple[dict, Path]]) -> list[tuple[Path | None, str]]:
    """(file or None for session.yaml, line) per unknown key of a session.yaml and of its ``views`` (mapping, file).

    A view's unknown keys are named once per key, with the first view that has it and how many do.
    """
    lines: list[tuple[Path | None, str]] = [(None, line) for line in unknown_keys(doc, SESSION_KEYS)]
    lines += [(None, line) for line in unknown_keys(doc.get("intrinsics"), INTRINSICS_KEYS, prefix="intrinsics.")]
    target = doc.get("target")
    if isinstance(target, dict) and target.get("type") in TARGET_KEYS:
        lines += [(None, line) for line in unknown_keys(target, TARGET_KEYS[target["type"]], prefix="target.")]
    seen: dict[str, list] = {}
    for data, source in views:
        for key in data if isinstance(data, dict) else ():
            if key not in VIEW_KEYS + VIEW_RECORD_KEYS:
                seen.setdefault(key, [data.get("id"), source, 0])[2] += 1
    for key, (vid, source, count) in seen.items():
        (line,) = unknown_keys({key: None}, VIEW_KEYS, prefix="")
        where = f"view {vid}" + (f" and {count - 1} other view{'s' if count > 2 else ''}" if count > 1 else "")
        lines.append((source, f"{where}: {line}"))
    return lines
