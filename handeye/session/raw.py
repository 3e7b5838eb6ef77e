"""Sessions read leniently, for the diagnostics: the robot pose numbers exactly as written.

Also what is needed to look at the images. The same parsers as the strict loaders (:mod:`.vendor`,
:mod:`.native`) read the files; only the plausibility checks (units of poses and board lengths) are
skipped, so a session written in millimetres or degrees can still be re-read every plausible way.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..camera import Intrinsics
from ..conventions import VENDOR_POSE_FORMAT, PoseFormat, T_from_pose_values, pose_values_from_T
from ..errors import HandeyeError
from ..records import Session, view_id_key
from ..targets import TargetSpec
from .fields import check_mode, locate_session
from .native import files_folder, read_native_document, view_image_path, view_pose_values
from .vendor import (
    VENDOR_DEFAULT_MODE,
    first_image_number,
    numbered_images,
    read_pose_lines,
    read_vendor_config,
    vendor_pose_format,
)

log = logging.getLogger(__name__)

#: what a session file can throw at a lenient reader (the files are user input)
_UNREADABLE = (HandeyeError, OSError, ValueError, TypeError, KeyError)


@dataclass(frozen=True)
class RawPoses:
    """The robot pose numbers exactly as written in the session, before any reading.

    ``values``: view id -> numbers; ``order``: view ids in file order (the sequence in which
    images and poses are paired); ``fmt``: the format the session states; ``source``: the file.
    """

    fmt: PoseFormat
    values: dict
    order: tuple
    source: str


@dataclass(frozen=True)
class LenientSession:
    """A session read without unit checks.

    Target, mode, raw poses, images by view id, and the given intrinsics when the session says to
    use them (fixed or prior), else None.
    """

    target: TargetSpec
    mode: str
    raw: RawPoses
    images_by_id: dict
    intrinsics: Optional[Intrinsics]


def read_raw_poses(path: str | Path) -> Optional[RawPoses]:
    """Raw pose values of a vendor (poses.txt) or native (session.yaml) session; None if unreadable.

    No plausibility checks: this is what the diagnostics re-read in other units and conventions.
    """
    try:
        kind, p = locate_session(path)
        return _raw_native(p) if kind == "native" else _raw_vendor(p)
    except _UNREADABLE as e:
        log.debug("raw poses of %s unreadable: %s", path, e)
    return None


def _raw_vendor(folder: Path, *, cfg: Optional[dict] = None, images: Optional[dict] = None) -> RawPoses:
    """poses.txt's numbers, keyed by the images' numbering, in config.yaml's stated format.

    poses.txt's numbers, keyed by the images' numbering, in config.yaml's stated format (else the vendor's).
    ``cfg`` (config.yaml's mapping) and ``images`` (:func:`numbered_images`): when the caller has read them.
    """
    if images is None:
        try:
            images = numbered_images(folder)
        except HandeyeError:  # no numbered images: the poses keep the vendor's numbering
            images = {}
    if cfg is None:
        try:
            cfg = read_vendor_config(folder, strict=False)[2]
        except HandeyeError:  # no readable config.yaml: the vendor's own line
            cfg = {}
    try:
        fmt = vendor_pose_format(cfg, folder / "config.yaml")
    except HandeyeError:  # a pose_format that cannot be read: the vendor's own line
        fmt = VENDOR_POSE_FORMAT
    lines = read_pose_lines(folder / "poses.txt", first=first_image_number(images))
    values = {str(pl.index): pl.values for pl in lines}
    return RawPoses(fmt, values, tuple(values), str(folder / "poses.txt"))


def _raw_native(path: Path, *, doc=None) -> RawPoses:
    """The views' pose numbers of session.yaml (``doc``: its document, when the caller has read it)."""
    doc = read_native_document(path) if doc is None else doc
    values = {e.data["id"]: view_pose_values(e, doc.pose_format, folder=files_folder(doc)) for e in doc.entries}
    return RawPoses(doc.pose_format, values, tuple(sorted(values, key=view_id_key)), str(path))


def raw_poses_of(session: Session) -> RawPoses:
    """The raw pose numbers behind a loaded session.

    Re-read from its file when the file still holds the same views and poses, else regenerated from
    the loaded poses in the vendor format.
    """
    raw = read_raw_poses(session.path) if session.format in ("vendor", "native") else None
    if raw is not None:
        try:
            same = all(
                v.view_id in raw.values
                and np.allclose(T_from_pose_values(raw.values[v.view_id], raw.fmt), v.T_base_end, atol=1e-9)
                for v in session.views
            )
        except ValueError:
            same = False
        if same:
            return raw
    fmt = VENDOR_POSE_FORMAT
    values = {v.view_id: pose_values_from_T(v.T_base_end, fmt) for v in session.views}
    return RawPoses(fmt, values, tuple(sorted(values, key=view_id_key)), "loaded poses")


def read_session_lenient(path: str | Path, *, mode: Optional[str] = None) -> Optional[LenientSession]:
    """The session at ``path`` without unit checks, or None when even that cannot be read.

    ``mode`` overrides the mode the session states; a session that states none is read in the vendor's
    default mode (the strict native loader requires one).
    """
    try:
        kind, p = locate_session(path)
        if kind == "native":
            doc = read_native_document(p)
            raw = _raw_native(p, doc=doc)
            images = {}
            for e in doc.entries:
                try:
                    images[e.data["id"]] = view_image_path(doc, e)
                except HandeyeError:  # outside the session folder: not read here either
                    continue
            images = {v: f for v, f in images.items() if f.is_file()}  # never a folder, device or pipe
            intr = doc.intrinsics if doc.intrinsics_use in ("fixed", "prior") else None
            return LenientSession(
                doc.target, check_mode(mode or doc.mode or VENDOR_DEFAULT_MODE, path=p), raw, images, intr
            )
        target, cfg_mode, cfg = read_vendor_config(p, strict=False)
        numbered = numbered_images(p)
        raw = _raw_vendor(p, cfg=cfg, images=numbered)
        images = {str(k): f for k, f in numbered.items() if f.is_file()}
        return LenientSession(
            target, check_mode(mode or cfg_mode or VENDOR_DEFAULT_MODE, path=p / "config.yaml"), raw, images, None
        )
    except _UNREADABLE as e:
        log.debug("session %s unreadable even leniently: %s", path, e)
        return None
