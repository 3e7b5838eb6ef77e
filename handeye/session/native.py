"""handeye's native ``session.yaml``: target, mode, pose format, optional intrinsics, and views
(``views:`` inline and/or one YAML record per view in ``view_records/``), each with id, image and pose.

:func:`read_native_document` is the only parser of this file; the strict loader
(:func:`load_native_session`) and the lenient reader of the diagnostics (:mod:`handeye.session.raw`)
both use it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..camera import Intrinsics
from ..conventions import PoseFormat, T_from_pose_values
from ..errors import ConfigError, InputError
from ..records import Session, View, view_id_key
from ..targets import TargetSpec
from .fields import check_mode, check_translation_units, positive_number, read_yaml
from .target_spec import parse_target

INTRINSICS_USES = ("fixed", "prior", "initial")


@dataclass(frozen=True)
class ViewEntry:
    """One view as written: its mapping and the file it came from (session.yaml or a view record)."""

    data: dict
    source: Path


@dataclass(frozen=True)
class NativeDocument:
    """A parsed session.yaml: the stated mode (None when absent), target, pose format, intrinsics
    (with their use: estimate | fixed | prior) and the view entries, not yet converted to poses."""

    path: Path
    data: dict
    mode: Optional[str]
    target: TargetSpec
    pose_format: PoseFormat
    intrinsics: Optional[Intrinsics]
    intrinsics_use: str
    entries: tuple  # tuple[ViewEntry, ...]


def read_native_document(path: Path) -> NativeDocument:
    """Parse session.yaml and its view records; ConfigError/InputError naming the field otherwise."""
    path = Path(path)
    d = read_yaml(path)
    version = d.get("handeye_session", 1)
    if version != 1:
        raise ConfigError("unsupported handeye_session version", path=path, expected="1", received=repr(version))
    target = parse_target(d.get("target"), path=path)
    fmt = _parse_pose_format(d.get("pose_format"), path=path)
    intr, intr_use = parse_intrinsics(d.get("intrinsics"), path=path)
    inline = d.get("views") or []
    if not isinstance(inline, list):
        raise ConfigError("views must be a list", path=path, received=type(inline).__name__)
    entries = [ViewEntry(e, path) for e in inline]
    rec_dir = d.get("view_records")
    if rec_dir and (path.parent / str(rec_dir)).is_dir():
        for f in sorted((path.parent / str(rec_dir)).iterdir()):
            if f.name.startswith(".") or f.suffix not in (".yaml", ".yml"):
                continue
            entries.append(ViewEntry(read_yaml(f), f))
    if not entries:
        raise InputError("the session has no views", path=path, hint="add a views: list or records in view_records/")
    for e in entries:
        if not isinstance(e.data, dict):
            raise ConfigError("each view must be a mapping with id, image, pose", path=e.source,
                              received=repr(e.data)[:60])
        for key in ("id", "image", "pose"):
            if key not in e.data:
                raise ConfigError(f"view is missing {key!r}", path=e.source, received=repr(e.data)[:80],
                                  expected="id, image, pose")
    return NativeDocument(path, d, d.get("mode"), target, fmt, intr, intr_use, tuple(entries))


def _parse_pose_format(fmt_d, *, path: Path) -> PoseFormat:
    fmt_d = fmt_d or {}
    if not isinstance(fmt_d, dict):
        raise ConfigError("pose_format must be a mapping", path=path, received=repr(fmt_d))
    unknown = set(fmt_d) - set(PoseFormat.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"unknown pose_format field {sorted(unknown)[0]!r}", path=path,
                          expected=", ".join(f for f in PoseFormat.__dataclass_fields__))
    return PoseFormat(**{k: (str(v).lower() if isinstance(v, str) else v) for k, v in fmt_d.items()}).validated(
        source=str(path))


def parse_intrinsics(d, *, path: Path) -> tuple[Optional[Intrinsics], str]:
    """(intrinsics or None, use: estimate | fixed | prior) from the ``intrinsics:`` mapping."""
    if d is None:
        return None, "estimate"
    if not isinstance(d, dict):
        raise ConfigError("intrinsics must be a mapping", path=path, received=repr(d)[:60])
    model = d.get("model", "opencv5")
    if model not in ("opencv5", "pinhole"):
        raise ConfigError("unsupported intrinsics model", path=path, expected="opencv5 (k1,k2,p1,p2,k3) | pinhole",
                          received=repr(model))
    vals = {k: positive_number(d.get(k), path=path, field=f"intrinsics.{k}") for k in ("fx", "fy", "cx", "cy")}
    dist = d.get("dist", [0, 0, 0, 0, 0]) if model == "opencv5" else [0, 0, 0, 0, 0]
    try:
        dist = np.asarray(dist, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        dist = np.array([np.nan])
    if dist.size not in (4, 5) or not np.all(np.isfinite(dist)):
        raise ConfigError("intrinsics.dist must be 4 or 5 finite numbers (k1, k2, p1, p2[, k3])", path=path,
                          received=repr(d.get("dist")))
    size = d.get("image_size")
    if not (isinstance(size, (list, tuple)) and len(size) == 2):
        raise ConfigError("intrinsics.image_size must be [width, height]", path=path, received=repr(size))
    w = positive_number(size[0], path=path, field="intrinsics.image_size[0]", integer=True)
    h = positive_number(size[1], path=path, field="intrinsics.image_size[1]", integer=True)
    use = d.get("use", "fixed")
    if use not in INTRINSICS_USES:
        raise ConfigError("invalid intrinsics.use", path=path, expected=" | ".join(INTRINSICS_USES), received=repr(use))
    K = np.array([[vals["fx"], 0, vals["cx"]], [0, vals["fy"], vals["cy"]], [0, 0, 1]])
    return Intrinsics.from_K(K, dist, w, h), {"initial": "estimate"}.get(use, use)


def load_native_session(path: str | Path, *, mode: str | None = None) -> Session:
    """session.yaml, validated: poses converted to ``T_base_end`` (metres) and unit-checked, images present."""
    path = Path(path)
    doc = read_native_document(path)
    sess_mode = check_mode(mode if mode is not None else doc.mode, path=path)
    fmt = doc.pose_format
    views = []
    seen: set[str] = set()
    for e in doc.entries:
        vid = str(e.data["id"])
        if vid in seen:
            raise ConfigError(f"duplicate view id {vid!r}", path=e.source, hint="give every view its own id")
        seen.add(vid)
        try:
            T = T_from_pose_values(np.asarray(e.data["pose"], dtype=float), fmt)
        except (ValueError, TypeError) as err:
            raise InputError(f"view {vid}: bad pose: {err}", path=e.source, expected=fmt.describe()) from None
        check_translation_units(T, path=e.source, line=None, unit=fmt.translation_unit)
        img = path.parent / str(e.data["image"])
        if not img.exists():
            raise InputError(f"view {vid}: image file missing", path=img, hint="restore the image or remove the view")
        views.append(View(view_id=vid, image_path=img, T_base_end=T,
                          t_image=_opt_float(e.data.get("t_image")), t_pose=_opt_float(e.data.get("t_pose"))))
    views.sort(key=lambda v: view_id_key(v.view_id))
    return Session(path=path.parent, format="native", mode=sess_mode, target=doc.target, views=tuple(views),
                   intrinsics=doc.intrinsics, intrinsics_prior=doc.intrinsics_use, pose_format=fmt.describe(),
                   meta={k: v for k, v in doc.data.items() if k not in ("views",)})


def _opt_float(v):
    return None if v is None else float(v)
