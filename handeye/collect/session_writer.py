"""Writes a native handeye session (docs/session_format.md) so that a crash never corrupts it.

``OUT/session.yaml`` (header), ``OUT/images/<id>.png`` (the frame as grabbed) and one
``OUT/views/<id>.yaml`` record per capture, each written atomically
(:func:`handeye.output.atomic_write_bytes`), the image before its record, so a kill loses at most the
capture in flight. Poses are written as ``T_base_end`` 4x4 matrices in metres. No session file is written
before the first view: a collection that keeps none leaves only ``OUT/collect_run.yaml`` (its settings, seed and
why no view was kept), which no command takes for a session and which a collection into OUT replaces.

See docs/collect.md.
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
from pathlib import Path

import cv2
import numpy as np
import yaml

from .. import __version__
from ..camera import Intrinsics
from ..errors import HardwareError, InputError
from ..output import atomic_write_bytes, command_line, plain, to_json
from ..session.fields import EMPTY_COLLECTION_FILE
from ..targets import TargetSpec

log = logging.getLogger(__name__)

SESSION_VERSION = 1
POSE_FORMAT = {"rotation": "matrix", "translation_unit": "m"}
RECORDS_DIR = "views"
IMAGES_DIR = "images"
#: the version of OUT/collect_run.yaml (:data:`EMPTY_COLLECTION_FILE`), the record of a collection that kept no view
EMPTY_RUN_VERSION = 1
#: session.yaml's keys that make a folder a session: left out of the empty run's record
_SESSION_KEYS = ("handeye_session", "pose_format", "pose_meaning", "view_records")


def unused_folder(out: str | Path) -> bool:
    """Whether a collection may write into ``out``: missing, empty, or holding only an empty run's record."""
    out = Path(out)
    return not out.exists() or (out.is_dir() and all(f.name == EMPTY_COLLECTION_FILE for f in out.iterdir()))


def _fsync_dir(folder: Path) -> None:
    if os.name != "posix":
        return
    fd = os.open(str(folder), os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_durably(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically.

    Write ``data`` to ``path`` atomically (a reader sees the old file or the whole new one), then
    fsync the folder so that the new name is on disk too.
    """
    atomic_write_bytes(path, data)
    _fsync_dir(Path(path).parent)


def dump_yaml(data: dict) -> bytes:
    return yaml.safe_dump(plain(data), sort_keys=False, default_flow_style=None, width=120).encode("utf-8")


def intrinsics_header(intr: Intrinsics, *, use: str = "initial", source: dict | None = None) -> dict:
    """The ``intrinsics:`` block of session.yaml (dist as a list k1, k2, p1, p2, k3)."""
    block = {
        "model": "opencv5",
        "fx": float(intr.fx),
        "fy": float(intr.fy),
        "cx": float(intr.cx),
        "cy": float(intr.cy),
        "dist": [float(x) for x in intr.dist],
        "image_size": [intr.width, intr.height],
        "use": use,
    }
    if source:
        block["source"] = plain(source)
    return block


class SessionWriter:
    """Checks ``out_dir``, then writes one capture at a time; the folder and its header with the first."""

    def __init__(
        self,
        out_dir: str | Path,
        *,
        mode: str,
        target: TargetSpec,
        intrinsics: Intrinsics | None = None,
        intrinsics_source: dict | None = None,
        collected: dict | None = None,
    ):
        self.out = Path(out_dir)
        if not unused_folder(self.out):
            raise InputError(
                "output folder is not empty",
                path=self.out,
                hint="collect into a new folder; an existing session is never overwritten",
            )
        self.mode = mode
        self.target = target
        self.n_written = 0
        header = {
            "handeye_session": SESSION_VERSION,
            "mode": mode,
            "target": target.to_dict(),
            "pose_format": dict(POSE_FORMAT),
            "pose_meaning": "T_base_end: pose of the end (flange/tool) in the robot base frame, 4x4, metres",
        }
        if intrinsics is not None:
            header["intrinsics"] = intrinsics_header(intrinsics, use="initial", source=intrinsics_source)
        header["view_records"] = RECORDS_DIR
        self._collected: dict = {  # header's, typed: the empty run's record adds its end
            "handeye_version": __version__,
            "command_line": command_line(),
            "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            **(collected or {}),
        }
        header["collected"] = self._collected
        self._header_doc = header
        self._header = dump_yaml(header)
        self._truth: bytes | None = None  # ground_truth.json, held until the session is started
        self.started = False

    def _start(self) -> None:
        """Create the folders and write session.yaml (and ground_truth.json when given): at the first view."""
        if self.started:
            return
        try:
            (self.out / IMAGES_DIR).mkdir(parents=True, exist_ok=True)
            (self.out / RECORDS_DIR).mkdir(exist_ok=True)
        except OSError as e:
            raise InputError(f"cannot create the session folder ({e.strerror})", path=self.out) from None
        self._write(self.out / "session.yaml", self._header)
        if self._truth is not None:
            self._write(self.out / "ground_truth.json", self._truth)
        self.started = True
        try:  # an earlier run's, that kept no view: session.yaml records this one
            (self.out / EMPTY_COLLECTION_FILE).unlink(missing_ok=True)
        except OSError as e:
            log.warning("%s: the record of an earlier run that kept no view stays (%s)", self.out, e.strerror)

    def record_empty_run(self, why: str, *, rejected: list[str], error: dict | None = None) -> Path:
        """Write ``OUT/collect_run.yaml`` for a run that ends before its first view: returns its path.

        Session.yaml's header without what makes a folder a session (its mode, target, intrinsics and
        ``collected``: version, command line, devices, seed), with ``why`` no view was kept, the reasons of the
        ``rejected`` captures in the order taken, and ``error`` (:meth:`HandeyeError.to_dict`) when one ended it.
        """
        assert not self.started, "a run with a view has its session.yaml"
        head = {k: v for k, v in self._header_doc.items() if k not in _SESSION_KEYS}
        now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        record = {
            "handeye_collect_run": EMPTY_RUN_VERSION,
            "outcome": "no view kept",
            "why": why,
            "note": "no session was written: this folder holds no session until a collection into it keeps a view",
            **head,
            "collected": {**self._collected, "finished": now},
            "rejected": list(rejected),
            **({"error": error} if error else {}),
        }
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise InputError(f"cannot create the session folder ({e.strerror})", path=self.out) from None
        path = self.out / EMPTY_COLLECTION_FILE
        self._write(path, dump_yaml(record))
        return path

    def _write(self, path: Path, data: bytes) -> None:
        try:
            write_durably(path, data)
        except OSError as e:
            raise HardwareError(
                f"cannot write {path.name} ({e.strerror})",
                path=path,
                hint="check free disk space; the views already saved are intact",
            ) from None

    def write_view(
        self,
        view_id: str,
        image: np.ndarray,
        T_base_end: np.ndarray,
        *,
        t_image: float,
        t_pose: float,
        robot_state: dict | None = None,
        extra: dict | None = None,
    ) -> Path:
        """Write ``images/<id>.png`` then ``views/<id>.yaml``; returns the record path."""
        vid = str(view_id)
        rec_path = self.out / RECORDS_DIR / f"{vid}.yaml"
        if rec_path.exists():
            raise InputError(f"view {vid} already exists", path=rec_path, hint="view ids must be unique")
        T = np.asarray(T_base_end, float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_base_end must be a finite 4x4 matrix, got shape {T.shape}")
        ok, png = cv2.imencode(".png", image)
        if not ok:
            raise HardwareError(
                f"view {vid}: the camera frame could not be encoded as PNG",
                received=f"array {image.shape} {image.dtype}",
            )
        self._start()
        img_rel = f"{IMAGES_DIR}/{vid}.png"
        self._write(self.out / img_rel, png.tobytes())
        record = {
            "id": vid,
            "image": img_rel,
            "pose": T.tolist(),
            "t_image": float(t_image),
            "t_pose": float(t_pose),
            "robot_state": robot_state or {},
        }
        if extra:
            record.update(extra)
        self._write(rec_path, dump_yaml(record))
        self.n_written += 1
        return rec_path

    def write_ground_truth(self, truth: dict) -> None:
        """``ground_truth.json`` for simulated sessions (rewritten atomically as it grows; from the first view on)."""
        self._truth = to_json(truth, indent=1).encode("utf-8")
        if self.started:
            self._write(self.out / "ground_truth.json", self._truth)
