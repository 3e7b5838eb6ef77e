"""``handeye import rosbag``: a native session from a ROS 1 or ROS 2 bag, read with ``rosbags``.

The TF chain from ``base`` to ``end`` is interpolated in time; the periods in which it stands still
(:class:`Stillness`, ``configs/rosbag.yaml``) get one image each, paired with base -> end at the image's
stamp; CameraInfo gives the intrinsics. It writes ``OUT/session.yaml`` (``T_base_end`` as 4x4 matrices,
metres) and ``OUT/images/<id>.png``.

See docs/session_format.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..errors import InputError
from ..frames import R_from_quat_wxyz, inv_T, make_T, rotation_angle_rad

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Stillness:
    """When the robot counts as still (units in the names; defaults from ``configs/rosbag.yaml``)."""

    still_trans_mm_s: float = 2.0
    still_rot_deg_s: float = 0.2
    speed_window_s: float = 0.1
    min_still_s: float = 0.3
    margin_s: float = 0.05

    @classmethod
    def from_preset(cls, **override) -> "Stillness":
        from ..config import check_section, load_preset

        d = check_section(cls, load_preset("rosbag").get("stillness"), name="stillness", source="configs/rosbag.yaml")
        d.update({k: v for k, v in override.items() if v is not None})
        for k, v in d.items():
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"{k} must be a number > 0", received=repr(v))
        return cls(**{k: float(v) for k, v in d.items()})


@dataclass(frozen=True)
class RosbagImport:
    """What :func:`import_rosbag` did."""

    session_path: Path
    n_views: int
    n_still_periods: int
    periods_without_image: int
    max_offset_ms: float  # largest |image stamp - nearest TF sample|
    max_motion_mm: float  # largest motion of base -> end over a still period that gave a view
    max_motion_deg: float
    intrinsics: str  # "camera_info" | "none (...)"
    views: list = field(default_factory=list)  # per view: id, t_image, offset_ms, period [start, end]

    def summary_lines(self) -> list[str]:
        return [
            f"{self.n_views} views from {self.n_still_periods} still periods"
            + (
                f" ({self.periods_without_image} without an image inside their margins)"
                if self.periods_without_image
                else ""
            ),
            f"time offset image -> nearest TF sample: at most {self.max_offset_ms:.1f} ms; the pose moved at most "
            f"{self.max_motion_mm:.3f} mm / {self.max_motion_deg:.4f} deg over a still period",
            f"intrinsics: {self.intrinsics}",
            f"session: {self.session_path}",
        ]


# ------------------------------------------------------------------------------ TF
@dataclass
class _Edge:
    """One TF edge parent -> child: stamps (N,), translations (N,3), quaternions wxyz (N,4)."""

    t: np.ndarray
    xyz: np.ndarray
    q: np.ndarray
    static: bool

    def at(self, times: np.ndarray) -> np.ndarray:
        """T_parent_child (M,4,4) at ``times`` (held constant outside the samples)."""
        times = np.atleast_1d(np.asarray(times, float))
        if self.static or len(self.t) == 1:
            return np.broadcast_to(make_T(R_from_quat_wxyz(self.q[-1]), self.xyz[-1]), (len(times), 4, 4)).copy()
        i = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, len(self.t) - 2)
        t0, t1 = self.t[i], self.t[i + 1]
        a = np.clip((times - t0) / np.where(t1 > t0, t1 - t0, 1.0), 0.0, 1.0)
        xyz = self.xyz[i] + a[:, None] * (self.xyz[i + 1] - self.xyz[i])
        q = _slerp(self.q[i], self.q[i + 1], a)
        T = np.zeros((len(times), 4, 4))
        T[:, :3, :3] = R_from_quat_wxyz(q)
        T[:, :3, 3] = xyz
        T[:, 3, 3] = 1.0
        return T


def _slerp(q0: np.ndarray, q1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Spherical interpolation of quaternions (N,4) at fractions ``a`` (N,)."""
    d = np.sum(q0 * q1, axis=-1)
    q1 = np.where(d[:, None] < 0, -q1, q1)
    d = np.abs(d)
    th = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(th)
    small = s < 1e-9
    w0 = np.where(small, 1.0 - a, np.sin((1.0 - a) * th) / np.where(small, 1.0, s))
    w1 = np.where(small, a, np.sin(a * th) / np.where(small, 1.0, s))
    q = w0[:, None] * q0 + w1[:, None] * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _frame(name: str) -> str:
    return str(name).lstrip("/")


def _stamp(msg) -> float:
    s = msg.header.stamp
    return float(s.sec) + 1e-9 * float(s.nanosec)


def _raw_header_stamp(raw: bytes, *, ros2: bool) -> float:
    """The header stamp of a serialized message that starts with a std_msgs/Header.

    The header stamp of a serialized message that starts with a std_msgs/Header (Image,
    CompressedImage), read from its first bytes: ROS 2 CDR (4-byte encapsulation, then int32 sec,
    uint32 nanosec; byte 1 says the byte order), ROS 1 (uint32 seq, uint32 secs, uint32 nsecs, little endian).
    """
    b = memoryview(raw)
    if ros2:
        order = "<" if b[1] == 1 else ">"
        sec = int(np.frombuffer(b[4:8], dtype=f"{order}i4")[0])
        nsec = int(np.frombuffer(b[8:12], dtype=f"{order}u4")[0])
    else:
        sec, nsec = (int(v) for v in np.frombuffer(b[4:12], dtype=np.dtype("<u4")))
    return sec + 1e-9 * nsec


def _chain(edges: dict, base: str, end: str, *, bag: Path) -> list[tuple[tuple[str, str], bool]]:
    """The edges from ``base`` to ``end``: ((parent, child), forward) in order (forward False: inverted)."""
    nbrs: dict[str, list] = {}
    for p, c in edges:
        nbrs.setdefault(p, []).append((c, (p, c), True))
        nbrs.setdefault(c, []).append((p, (p, c), False))
    for name in (base, end):
        if name not in nbrs:
            raise InputError(
                f"frame {name!r} is not in the bag's TF",
                path=bag,
                expected="one of " + ", ".join(sorted(nbrs)[:12]) if nbrs else "a TF stream (/tf)",
                hint="pass --base and --end as the frames the robot publishes (e.g. base_link, tool0)",
            )
    prev: dict[str, Optional[tuple[str, Any, bool]]] = {base: None}
    queue = [base]
    while queue:
        f = queue.pop(0)
        for g, e, fwd in nbrs[f]:
            if g not in prev:
                prev[g] = (f, e, fwd)
                queue.append(g)
    if end not in prev:
        raise InputError(
            f"no TF chain from {base!r} to {end!r} in the bag",
            path=bag,
            hint="the two frames are in separate TF trees; record the robot's whole TF",
        )
    out, f = [], end
    while (link := prev[f]) is not None:
        f0, e, fwd = link
        out.append((e, fwd))
        f = f0
    return out[::-1]


def _compose(edges: dict, chain, times: np.ndarray) -> np.ndarray:
    """T_base_end (M,4,4) at ``times`` along ``chain``."""
    T = np.broadcast_to(np.eye(4), (len(times), 4, 4)).copy()
    for e, fwd in chain:
        Te = edges[e].at(times)
        T = T @ (Te if fwd else inv_T(Te))
    return T


# ------------------------------------------------------------------------------ stillness
def still_periods(times: np.ndarray, T_base_end: np.ndarray, st: Stillness) -> list[tuple[float, float]]:
    """[start, end] of each period in which the pose stays still for at least ``min_still_s``.

    [start, end] of each period in which the pose moves slower than the thresholds for at least
    ``min_still_s``; ``times`` (N,) sorted, ``T_base_end`` (N,4,4).
    """
    n = len(times)
    if n < 2:
        return []
    half = 0.5 * st.speed_window_s
    idx = np.arange(n)
    lo = np.searchsorted(times, times - half, side="left")
    hi = np.clip(np.searchsorted(times, times + half, side="right") - 1, 0, n - 1)
    lo, hi = np.minimum(lo, np.maximum(idx - 1, 0)), np.maximum(hi, np.minimum(idx + 1, n - 1))  # a slow TF
    dt = times[hi] - times[lo]
    ok_dt = dt > 0
    d_mm = np.linalg.norm(T_base_end[hi, :3, 3] - T_base_end[lo, :3, 3], axis=-1) * 1e3
    R_rel = np.einsum("nji,njk->nik", T_base_end[lo, :3, :3], T_base_end[hi, :3, :3])
    d_deg = np.degrees(rotation_angle_rad(R_rel))
    with np.errstate(divide="ignore", invalid="ignore"):
        still = (
            ok_dt
            & (d_mm / np.where(ok_dt, dt, 1.0) < st.still_trans_mm_s)
            & (d_deg / np.where(ok_dt, dt, 1.0) < st.still_rot_deg_s)
        )
    periods = []
    k = 0
    while k < n:
        if not still[k]:
            k += 1
            continue
        j = k
        while j + 1 < n and still[j + 1]:
            j += 1
        if times[j] - times[k] >= st.min_still_s:
            periods.append((float(times[k]), float(times[j])))
        k = j + 1
    return periods


# ------------------------------------------------------------------------------ images and camera info
_EXT = {"jpeg": ".jpg", "jpg": ".jpg", "png": ".png"}


def _image_file(msg, msgtype: str) -> tuple[bytes, str]:
    """(file bytes, extension) of an Image (written as PNG) or CompressedImage (its own bytes)."""
    import cv2

    if msgtype.endswith("CompressedImage"):
        fmt = str(msg.format).lower()
        ext = next((e for k, e in _EXT.items() if k in fmt), None)
        if ext is None:
            raise InputError(f"compressed image format {msg.format!r} is not JPEG or PNG")
        return bytes(msg.data), ext
    enc = str(msg.encoding).lower()
    h, w = int(msg.height), int(msg.width)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint16 if enc in ("mono16", "16uc1") else np.uint8)
    if enc in ("mono16", "16uc1") and bool(msg.is_bigendian):
        data = data.byteswap()
    step_items = int(msg.step) // data.itemsize
    channels = {"mono8": 1, "8uc1": 1, "mono16": 1, "16uc1": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}
    if enc not in channels:
        raise InputError(
            f"image encoding {msg.encoding!r} is not read",
            expected="mono8, mono16, rgb8, bgr8, rgba8 or bgra8 (or a CompressedImage topic)",
        )
    c = channels[enc]
    img: np.ndarray = (
        data.reshape(h, step_items)[:, : w * c].reshape(h, w, c) if c > 1 else data.reshape(h, step_items)[:, :w]
    )
    if enc == "rgb8":
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    elif enc == "rgba8":
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    elif enc == "bgra8":
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:  # pragma: no cover - OpenCV failure
        raise InputError("an image could not be encoded as PNG")
    return buf.tobytes(), ".png"


def _intrinsics(msg, *, use: str) -> tuple[Optional[dict], str]:
    """The session's ``intrinsics:`` from a CameraInfo (ROS 1 K/D or ROS 2 k/d), or None and why."""
    K = np.asarray(getattr(msg, "k", getattr(msg, "K", None)), float).reshape(-1)
    D = [float(v) for v in np.asarray(getattr(msg, "d", getattr(msg, "D", [])), float).reshape(-1)]
    model = str(msg.distortion_model or "plumb_bob")
    if K.size != 9 or K[0] <= 0 or K[4] <= 0:
        return None, "none (CameraInfo has no calibration: K is zero); estimated from the images"
    if model != "plumb_bob" or len(D) not in (0, 4, 5):
        return None, (
            f"none (CameraInfo's {model} with {len(D)} coefficients is not handeye's 5-coefficient "
            "model); estimated from the images"
        )
    dist = (D + [0.0] * 5)[:5]
    return (
        {
            "model": "opencv5",
            "distortion_model": "plumb_bob",
            "fx": float(K[0]),
            "fy": float(K[4]),
            "cx": float(K[2]),
            "cy": float(K[5]),
            "dist": dist,
            "image_size": [int(msg.width), int(msg.height)],
            "use": use,
        },
        f"from CameraInfo (use: {use})",
    )


# ------------------------------------------------------------------------------ the importer
def _open_reader(bag: Path):
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    if not bag.exists():
        raise InputError("bag not found", path=bag, expected="a ROS 1 .bag file or a ROS 2 bag folder (metadata.yaml)")
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as e:
        raise InputError(
            f"not a readable ROS bag ({e})",
            path=bag,
            expected="a ROS 1 .bag file or a ROS 2 bag folder (sqlite3 or MCAP)",
        ) from None
    return reader


def _connections(reader, bag: Path, image_topic: str, camera_info_topic: Optional[str]):
    """(image connection, CameraInfo connection or None, TF connections).

    A missing topic is named with the ones the bag has.
    """
    conns = {c.topic: c for c in reader.connections}
    kinds = {t: c.msgtype.split("/")[-1] for t, c in conns.items()}
    if kinds.get(image_topic) not in ("Image", "CompressedImage"):
        images = sorted(t for t, k in kinds.items() if k in ("Image", "CompressedImage"))
        raise InputError(
            f"no image topic {image_topic!r} in the bag",
            path=bag,
            expected="one of " + (", ".join(images) or "(no image topics)"),
        )
    if camera_info_topic is None:
        guess = image_topic.rsplit("/", 1)[0] + "/camera_info"
        camera_info_topic = guess if kinds.get(guess) == "CameraInfo" else None
    elif kinds.get(camera_info_topic) != "CameraInfo":
        raise InputError(
            f"no camera info topic {camera_info_topic!r} in the bag",
            path=bag,
            expected="one of "
            + (", ".join(sorted(t for t, k in kinds.items() if k == "CameraInfo")) or "(no CameraInfo topics)"),
        )
    tf_conns = [c for c in reader.connections if kinds[c.topic] == "TFMessage"]
    if not tf_conns:
        raise InputError(
            "the bag has no TF (tf2_msgs/TFMessage) topic", path=bag, hint="record /tf and /tf_static with the images"
        )
    return conns[image_topic], (conns[camera_info_topic] if camera_info_topic else None), tf_conns


def _read_tf(reader, tf_conns, info_conn) -> tuple[dict, object]:
    """({(parent, child): _Edge}, the first CameraInfo or None) in one pass over those topics."""
    samples: dict = {}
    info = None
    for conn, t_bag, raw in reader.messages(connections=tf_conns + ([info_conn] if info_conn else [])):
        msg = reader.deserialize(raw, conn.msgtype)
        if conn is info_conn:
            info = msg if info is None else info
            continue
        static = conn.topic.endswith("tf_static")
        for tr in msg.transforms:
            s = samples.setdefault((_frame(tr.header.frame_id), _frame(tr.child_frame_id)), ([], [], [], static))
            tt, r = tr.transform.translation, tr.transform.rotation
            s[0].append(_stamp(tr) or t_bag * 1e-9)
            s[1].append((tt.x, tt.y, tt.z))
            s[2].append((r.w, r.x, r.y, r.z))
    edges = {}
    for key, (tt, xyz, q, static) in samples.items():
        order = np.argsort(tt, kind="stable")
        edges[key] = _Edge(np.asarray(tt)[order], np.asarray(xyz, float)[order], np.asarray(q, float)[order], static)
    return edges, info


def pick_images(periods, stamps: np.ndarray, *, margin_s: float) -> tuple[list[tuple[int, float, float]], int]:
    """One image per still period.

    One image per still period: (index into ``stamps``, period start, end) of the image nearest the
    period's middle among those at least ``margin_s`` inside it, and how many periods had none.
    """
    picked, without = [], 0
    for a, b in periods:
        inside = np.flatnonzero((stamps >= a + margin_s) & (stamps <= b - margin_s))
        if inside.size == 0:
            without += 1
            continue
        picked.append((int(inside[np.argmin(np.abs(stamps[inside] - 0.5 * (a + b)))]), a, b))
    return picked, without


def _pose_at(edges, chain, times: np.ndarray, T_all: np.ndarray, t_img: float, a: float, b: float):
    """(T_base_end at ``t_img``, ms to the nearest TF sample, mm and deg the pose moved over [a, b])."""
    T = _compose(edges, chain, np.array([t_img]))[0]
    near = times[np.clip(np.searchsorted(times, t_img), 1, len(times) - 1) - np.array([1, 0])]
    Tp = T_all[(times >= a) & (times <= b)]
    mm = float(np.max(np.linalg.norm(Tp[:, :3, 3] - T[:3, 3], axis=-1)) * 1e3)
    deg = float(np.degrees(np.max(rotation_angle_rad(np.einsum("ji,njk->nik", T[:3, :3], Tp[:, :3, :3])))))
    return T, float(np.min(np.abs(near - t_img)) * 1e3), mm, deg


def import_rosbag(
    bag: str | Path,
    out: str | Path,
    *,
    image_topic: str,
    base_frame: str,
    end_frame: str,
    target: dict,
    camera_info_topic: Optional[str] = None,
    mode: Optional[str] = None,
    stillness: Optional[Stillness] = None,
    intrinsics_use: str = "prior",
    force: bool = False,
) -> RosbagImport:
    """Write ``out/session.yaml`` and ``out/images/`` from the bag (see the module's description).

    ``target`` is the session's ``target:`` mapping (the bag does not say which board was seen);
    ``camera_info_topic`` defaults to ``camera_info`` beside the image topic when the bag has it. An ``out``
    already holding a session is refused, unless ``force`` (then its images/ must be empty).
    """
    import yaml

    from ..output import atomic_write_bytes, atomic_write_text
    from .importers import check_import_out
    from .target_spec import parse_target

    bag, out = Path(bag), Path(out)
    check_import_out(out, force=force, writes=("images",))
    st = stillness or Stillness.from_preset()
    parse_target(target, path=Path("--target"))  # a wrong target is said now, not after the import
    reader = _open_reader(bag)
    try:
        img_conn, info_conn, tf_conns = _connections(reader, bag, image_topic, camera_info_topic)
        edges, info = _read_tf(reader, tf_conns, info_conn)
        chain = _chain(edges, _frame(base_frame), _frame(end_frame), bag=bag)
        dyn = [edges[e].t for e, _ in chain if not edges[e].static]
        if not dyn:
            raise InputError(
                f"{base_frame} -> {end_frame} is static in the bag's TF",
                path=bag,
                hint="pass the robot's base and flange frames, whose transform the robot publishes",
            )
        times = np.unique(np.concatenate(dyn))
        T_all = _compose(edges, chain, times)
        periods = still_periods(times, T_all, st)
        if not periods:
            raise InputError(
                f"no still periods in the bag: {base_frame} -> {end_frame} never stood still for {st.min_still_s:g} s "
                f"(speed under {st.still_trans_mm_s:g} mm/s and {st.still_rot_deg_s:g} deg/s over "
                f"{st.speed_window_s:g} s)",
                path=bag,
                code="no_still_periods",
                hint="check --base/--end, or loosen --still-trans-mm-s / --still-rot-deg-s / --min-still-s if the "
                "arm's TF jitters at rest",
            )
        img_stamps = [
            (_raw_header_stamp(raw, ros2=reader.is2) or t_bag * 1e-9, t_bag)  # stamps only, no pixels
            for _, t_bag, raw in reader.messages(connections=[img_conn])
        ]
        stamps = np.array([s for s, _ in img_stamps], float)
        picked, without = pick_images(periods, stamps, margin_s=st.margin_s)
        if not picked:
            raise InputError(
                f"no image inside any of the {len(periods)} still periods (margin {st.margin_s:g} s)",
                path=bag,
                code="no_images_at_rest",
                hint=f"check that {image_topic} was recorded while the robot stood still, and the clocks",
            )
        wanted = {img_stamps[k][1]: k for k, _, _ in picked}
        files: dict[int, tuple[bytes, str]] = {}
        for conn, t_bag, raw in reader.messages(connections=[img_conn]):
            k = wanted.get(t_bag)
            if k is not None and k not in files:
                files[k] = _image_file(reader.deserialize(raw, conn.msgtype), conn.msgtype)
    finally:
        reader.close()

    views, report_views = [], []
    width = max(3, len(str(len(picked))))
    for n, (k, a, b) in enumerate(picked, start=1):
        t_img = float(stamps[k])
        T, off_ms, mm, deg = _pose_at(edges, chain, times, T_all, t_img, a, b)
        vid = str(n).zfill(width)
        data, ext = files[k]
        rel = f"images/{vid}{ext}"
        atomic_write_bytes(out / rel, data, durable=False)
        views.append(
            {"id": vid, "image": rel, "pose": [[float(x) for x in row] for row in T], "t_image": t_img, "t_pose": t_img}
        )
        report_views.append(
            {
                "id": vid,
                "t_image": t_img,
                "offset_ms": off_ms,
                "still_period_s": [a, b],
                "motion_mm": mm,
                "motion_deg": deg,
            }
        )
    intr, intr_text = (None, "none (no CameraInfo topic); estimated from the images")
    if info is not None:
        intr, intr_text = _intrinsics(info, use=intrinsics_use)
    doc = {
        "handeye_session": 1,
        **({"mode": mode} if mode else {}),
        "target": target,
        "pose_format": {"rotation": "matrix", "translation_unit": "m"},
        **({"intrinsics": intr} if intr else {}),
    }
    max_off = max(v["offset_ms"] for v in report_views)
    doc["source"] = {
        "importer": "rosbag",
        "path": str(bag.resolve()),
        "image_topic": image_topic,
        "camera_info_topic": info_conn.topic if info_conn else None,
        "base_frame": base_frame,
        "end_frame": end_frame,
        "tf_chain": [f"{p} -> {c}" if fwd else f"inverse of {p} -> {c}" for (p, c), fwd in chain],
        "stillness": {f.name: getattr(st, f.name) for f in fields(st)},
        "still_periods": len(periods),
        "periods_without_image": without,
        "max_offset_ms": max_off,
        "views": report_views,
    }
    doc["views"] = views
    path = atomic_write_text(out / "session.yaml", yaml.safe_dump(doc, sort_keys=False))
    log.info("rosbag %s: %d still periods, %d views", bag, len(periods), len(views))
    return RosbagImport(
        path,
        len(views),
        len(periods),
        without,
        max_off,
        max(v["motion_mm"] for v in report_views),
        max(v["motion_deg"] for v in report_views),
        intr_text,
        report_views,
    )


def read_target_file(path: Path) -> tuple[dict, Optional[str]]:
    """(the ``target:`` mapping, the mode it states or None) from a YAML file.

    (the ``target:`` mapping, the mode it states or None) from a YAML holding a session.yaml-like
    ``target:`` (and optional ``mode:``) or a vendor config.yaml (``checkerboard_args``).
    """
    from .fields import read_yaml

    path = Path(path)
    d = read_yaml(path)
    if isinstance(d, dict) and isinstance(d.get("target"), dict):
        return dict(d["target"]), d.get("mode")
    if isinstance(d, dict) and isinstance(d.get("checkerboard_args"), dict):
        cb = d["checkerboard_args"]
        return {"type": "chessboard", "inner_corners": [cb.get("XX"), cb.get("YY")], "square_m": cb.get("L")}, d.get(
            "mode"
        )
    raise InputError(
        "no target in the file",
        path=path,
        expected="target: {type: chessboard, inner_corners: [11, 8], square_m: 0.03}, or a vendor "
        "config.yaml with checkerboard_args",
    )
