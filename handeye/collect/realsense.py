"""Intel RealSense colour camera, live (``realsense``) or from a recording (``bag:FILE``).

pyrealsense2 is imported only when one of these backends is used; a missing package or a missing
libusb gives a one-line HardwareError that says what to install.

Distortion models (librealsense ``rsutil.h``, ``rs2_project_point_to_pixel``): ``brown_conrady``
is OpenCV's (k1, k2, p1, p2, k3) exactly. ``modified_brown_conrady`` and ``inverse_brown_conrady``
(the D400 colour sensor's model) apply the tangential terms after the radial scaling; with p1 = p2
= 0 that is OpenCV's model exactly, otherwise it is close but not equal and is recorded as
``approximate`` (the intrinsics are written with ``use: initial``, so they are refined anyway).
Other models (fisheye) are not representable and are recorded without distortion. The original
model name and coefficients are always recorded.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import weakref
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..camera import Intrinsics
from ..errors import ConfigError, HardwareError
from .camera import Camera

log = logging.getLogger(__name__)


def import_pyrealsense2():
    """``pyrealsense2`` or a HardwareError naming what to install."""
    try:
        import pyrealsense2 as rs  # noqa: PLC0415 (lazy on purpose: optional hardware dependency)
    except ImportError as e:
        text = str(e)
        if "libusb" in text:
            raise HardwareError(
                f"pyrealsense2 is installed but cannot load libusb ({text})",
                hint="install it: apt-get install libusb-1.0-0 (Debian/Ubuntu)",
            ) from None
        raise HardwareError(
            f"pyrealsense2 is not available ({text})",
            hint="pip install pyrealsense2 (x86-64 Linux/Windows wheels), or build librealsense "
            "with its Python bindings",
        ) from None
    return rs


def opencv5_from_realsense(model: str, coeffs) -> tuple[tuple, str]:
    """(k1, k2, p1, p2, k3) for OpenCV and how exact that is: "exact" | "approximate" | "not representable"."""
    name = str(model).lower().replace(" ", "_").replace("distortion.", "")
    c = [float(x) for x in list(coeffs)[:5]] + [0.0] * max(0, 5 - len(list(coeffs)))
    if name in ("none",):
        return (0.0,) * 5, "exact"
    if name == "brown_conrady":
        return tuple(c), "exact"
    if name in ("inverse_brown_conrady", "modified_brown_conrady"):
        return tuple(c), ("exact" if c[2] == 0.0 and c[3] == 0.0 else "approximate")
    return (0.0,) * 5, "not representable"


def intrinsics_from_realsense(
    *, fx: float, fy: float, ppx: float, ppy: float, width: int, height: int, model: str, coeffs
) -> tuple[Intrinsics, dict]:
    """Intrinsics in handeye's OpenCV form plus a record of the original RealSense values."""
    dist, exactness = opencv5_from_realsense(model, coeffs)
    if exactness != "exact":
        log.warning(
            "RealSense distortion model %s maps to OpenCV's %s; the intrinsics are only a starting value",
            model,
            exactness,
        )
    intr = Intrinsics(float(fx), float(fy), float(ppx), float(ppy), dist, int(width), int(height))
    source = {
        "kind": "factory (RealSense)",
        "original_model": str(model).replace("distortion.", ""),
        "original_coeffs": [float(x) for x in coeffs],
        "mapping_to_opencv5": exactness,
    }
    return intr, source


def _bgr_from_frame(rs, frame) -> np.ndarray:
    fmt = frame.get_profile().format()
    data = np.asanyarray(frame.get_data())
    if fmt == rs.format.bgr8:
        return np.ascontiguousarray(data).copy()
    if fmt == rs.format.rgb8:
        return cv2.cvtColor(data, cv2.COLOR_RGB2BGR)
    if fmt == rs.format.bgra8:
        return cv2.cvtColor(data, cv2.COLOR_BGRA2BGR)
    if fmt == rs.format.rgba8:
        return cv2.cvtColor(data, cv2.COLOR_RGBA2BGR)
    if fmt == rs.format.yuyv:
        return cv2.cvtColor(data.reshape(frame.get_height(), frame.get_width(), 2), cv2.COLOR_YUV2BGR_YUYV)
    if fmt == rs.format.y8:
        return np.ascontiguousarray(data).copy()
    raise HardwareError(f"unsupported RealSense colour format {fmt}", expected="bgr8, rgb8, bgra8, rgba8, yuyv or y8")


def _frame_info(rs, frame) -> dict:
    return {
        "frame_number": int(frame.get_frame_number()),
        "device_timestamp_ms": float(frame.get_timestamp()),
        "timestamp_domain": str(frame.get_frame_timestamp_domain()).replace("timestamp_domain.", ""),
    }


class _RealSenseBase(Camera):
    def __init__(self) -> None:
        self._rs = import_pyrealsense2()
        self._pipe: Any = None
        self._intr: Intrinsics | None = None
        self._intr_source: dict = {}
        self._device_info: dict = {}

    def _read_profile(self, profile) -> None:
        """Intrinsics and device description from a started pipeline's profile."""
        self._read_stream(profile.get_stream(self._rs.stream.color).as_video_stream_profile(), profile.get_device())

    def _read_stream(self, vsp, dev) -> None:
        """Intrinsics (OpenCV form plus the original model) and device description of a colour stream."""
        rs = self._rs
        ii = vsp.get_intrinsics()
        self._intr, self._intr_source = intrinsics_from_realsense(
            fx=ii.fx,
            fy=ii.fy,
            ppx=ii.ppx,
            ppy=ii.ppy,
            width=ii.width,
            height=ii.height,
            model=str(ii.model),
            coeffs=ii.coeffs,
        )
        info = {}
        for key in ("name", "serial_number", "firmware_version", "product_line"):
            field = getattr(rs.camera_info, key)
            if dev.supports(field):
                info[key] = dev.get_info(field)
        info["stream"] = f"colour {ii.width}x{ii.height} {vsp.format()} @ {vsp.fps()} fps"
        self._device_info = info
        self._intr_source["device"] = {k: v for k, v in info.items() if k in ("name", "serial_number")}

    def intrinsics(self) -> Intrinsics | None:
        return self._intr

    def intrinsics_source(self) -> dict:
        return dict(self._intr_source)

    def describe(self) -> dict:
        return {"backend": self.name, **self._device_info}

    def close(self) -> None:
        if self._pipe is not None:
            try:
                self._pipe.stop()
            except RuntimeError:
                pass
            self._pipe = None


class RealSenseCamera(_RealSenseBase):
    """A live RealSense camera's colour stream at ``width`` x ``height``, ``fps``."""

    def __init__(
        self,
        *,
        width: int = 1280,
        height: int = 720,
        fps: int = 30,
        serial: str | None = None,
        settle_frames: int = 30,
        timeout_s: float = 5.0,
    ):
        super().__init__()
        rs = self._rs
        self.name = "realsense"
        self.timeout_ms = int(timeout_s * 1000)
        self._waiting = threading.Lock()  # held while a frame wait runs: close never stops the pipeline under it
        try:
            devices = rs.context().query_devices()
            n_dev = len(devices)
        except RuntimeError as e:
            raise HardwareError(
                f"cannot enumerate RealSense devices ({e})",
                hint="check USB permissions (udev rules) and that libusb is installed",
            ) from None
        if n_dev == 0:
            raise HardwareError("no RealSense camera found", hint="plug it into a USB3 port and check the cable")
        cfg = rs.config()
        if serial:
            cfg.enable_device(str(serial))
        cfg.enable_stream(rs.stream.color, int(width), int(height), rs.format.bgr8, int(fps))
        self._pipe = rs.pipeline()
        try:
            profile = self._pipe.start(cfg)
        except RuntimeError as e:
            self._pipe = None
            raise HardwareError(
                f"the RealSense camera cannot stream colour {width}x{height} at {fps} fps ({e})",
                hint="pick a supported mode, e.g. --resolution 1280x720 --fps 30",
            ) from None
        self._read_profile(profile)
        self.name = f"realsense {self._device_info.get('name', '')} #{self._device_info.get('serial_number', '?')}"
        # Auto exposure and white balance need a moment after the stream starts.
        for _ in range(int(settle_frames)):
            self._wait()

    def _wait(self):
        try:
            return self._pipe.wait_for_frames(self.timeout_ms)
        except RuntimeError as e:
            raise HardwareError(
                f"no frame from the RealSense camera within {self.timeout_ms / 1000:g} s ({e})",
                hint="the camera may be unplugged or on a USB2 port; reconnect it",
            ) from None

    def grab(self) -> tuple[np.ndarray, float]:
        with self._waiting:
            if self._pipe is None:
                raise HardwareError("the RealSense camera is closed")
            # Frames queued before this call may predate the robot's stillness check: drop them.
            for _ in range(16):
                if not self._pipe.poll_for_frames():
                    break
            fs = self._wait()
            t = time.time()
            color = fs.get_color_frame()
            if not color:
                raise HardwareError(
                    "the RealSense camera delivered a frame set without colour", hint="reconnect the camera"
                )
            self.last_frame_info = _frame_info(self._rs, color)
            return _bgr_from_frame(self._rs, color), t  # the frame's memory is copied before close may run

    def close(self) -> None:
        """Stop the pipeline once no frame wait runs (one on another thread ends within its timeout)."""
        with self._waiting:
            super().close()


class BagCamera(_RealSenseBase):
    """Frames from a RealSense recording (``.bag``, or ``.db3`` of librealsense >= 2.56), one per grab, in order.

    The recording is played through its playback device's colour sensor, not a pipeline: the device
    is switched to non-real-time playback *before* it starts, and each frame is handed over through a
    small blocking queue, so the player waits for the reader and no frame is ever dropped. (A pipeline
    starts playing in real time the moment it starts; a reader that is late by one frame interval
    before it can switch real time off - a loaded machine - loses the first frames.)

    The end of the recording is what the player says (its status turns to stopped once it has handed
    over its last frame), never a timeout: on a loaded machine the next frame may take seconds, and a
    short wait that was read as "no more frames" cut recordings short. ``timeout_s`` only bounds a
    player that stalls (a distinct error).
    """

    _QUEUE_FRAMES = 2  # frames decoded ahead of the reader (bounded memory; the player waits)

    def __init__(self, path: str | Path, *, timeout_s: float = 60.0):
        super().__init__()
        rs = self._rs
        self.path = Path(path)
        if not self.path.is_file():
            raise ConfigError("RealSense recording not found", path=self.path, hint="give --camera bag:FILE")
        self.name = f"realsense recording {self.path.name}"
        self.timeout_s = float(timeout_s)
        self.n_frames = 0
        self._frames: queue.Queue = queue.Queue(maxsize=self._QUEUE_FRAMES)
        self._closing = threading.Event()
        self._idle = threading.Event()  # no frame callback is running (close waits for a running one)
        self._idle.set()
        self._played = threading.Event()  # the player has reported that it plays
        self._stopped = threading.Event()  # ... and then that it stopped: the whole recording was handed over
        self._sensor = None
        self._playback = None
        self._player: list = []  # [sensor, playback, rs] once started, released in order by close
        # a camera left open is closed before the interpreter exits (a player thread blocked in a
        # Python callback during interpreter shutdown aborts the process)
        self._finalizer = weakref.finalize(self, _stop_player, self._closing, self._idle, self._player)
        try:
            self._playback = rs.context().load_device(str(self.path)).as_playback()
            self._playback.set_real_time(False)  # before anything plays: every frame, in order
            sensor, vsp = self._colour_stream()
            self._read_stream(vsp, self._playback)
            sensor.open(vsp)
            self._sensor = sensor
            self._player[:] = [sensor, self._playback, rs]
            self._playback.set_status_changed_callback(_status_recorder(rs, self._played, self._stopped))
            sensor.start(self._on_frame)
        except RuntimeError as e:
            self.close()
            raise HardwareError(
                f"cannot play the RealSense recording ({e})",
                path=self.path,
                hint="it needs a colour stream; check the file with realsense-viewer",
            ) from None

    def _colour_stream(self):
        rs = self._rs
        for sensor in self._playback.query_sensors():
            for p in sensor.get_stream_profiles():
                if p.stream_type() == rs.stream.color:
                    return sensor, p.as_video_stream_profile()
        raise HardwareError(
            "the recording has no colour stream",
            path=self.path,
            hint="record the colour stream (realsense-viewer: RGB camera on)",
        )

    def _ended(self) -> bool:
        """The player has played the whole recording (it reports stopped after handing over its last frame)."""
        return self._stopped.is_set()

    def _on_frame(self, frame) -> None:
        """Player thread: convert the frame and wait for room in the queue (the player waits with it).

        Marked busy while it runs: stopping the sensor under a running callback crashed librealsense (a
        segmentation fault when a reader gave up on a slow player and closed it).
        """
        self._idle.clear()
        try:
            if self._closing.is_set():
                return
            try:
                item: Any = (_bgr_from_frame(self._rs, frame), _frame_info(self._rs, frame))
            except HardwareError as e:  # raised to the reader by the next grab
                item = e
            while not self._closing.is_set():
                try:
                    self._frames.put(item, timeout=0.05)
                    return
                except queue.Full:
                    continue
        finally:
            self._idle.set()

    def grab(self) -> tuple[np.ndarray, float]:
        if self._sensor is None:
            raise HardwareError("the recording is closed", path=self.path)
        deadline = time.monotonic() + self.timeout_s
        while True:
            try:
                item = self._frames.get(timeout=0.02)
                break
            except queue.Empty:
                # the player puts its last frame before it reports the end, so an empty queue after
                # the end means no frame is left
                if self._ended() and self._frames.empty():
                    raise HardwareError(
                        f"the recording has no more colour frames (after {self.n_frames})",
                        path=self.path,
                        hint="record a longer sequence or capture fewer views",
                    ) from None
                if time.monotonic() > deadline:
                    raise HardwareError(
                        f"the recording's player stalled: no colour frame within {self.timeout_s:g} s "
                        f"and no end of the recording (after {self.n_frames} frames)",
                        path=self.path,
                        hint="check the file with realsense-viewer; on a very busy machine pass a longer timeout",
                    ) from None
        if isinstance(item, HardwareError):
            raise item
        image, info = item
        self.n_frames += 1
        self.last_frame_info = info
        return image, time.time()

    def close(self) -> None:
        """Stop the player and release the recording."""
        self._sensor = self._playback = None
        self._finalizer()


def _status_recorder(rs, played: threading.Event, stopped: threading.Event):
    """The player's status callback: sets ``played`` when it plays and ``stopped`` when it stops after that.

    A closure, not a method: the player must not keep the camera alive.
    """

    def on_status(status) -> None:
        if status == rs.playback_status.playing:
            played.set()
        elif status == rs.playback_status.stopped and played.is_set():
            stopped.set()

    return on_status


#: longest wait for a running frame callback to return before the sensor is stopped anyway [s] (a conversion
#: takes milliseconds; the bound only keeps a wedged callback from blocking close forever)
_CALLBACK_WAIT_S = 10.0


def _stop_player(closing: threading.Event, idle: threading.Event, player: list) -> None:
    """Shut the player down in order, each step after the one before has finished.

    1. let a frame callback waiting for room in the queue return, and wait for a running one;
    2. stop and close the sensor, then release it while its playback device still exists;
    3. wait until the playback device reports that it stopped, then release the device.

    ``player`` is ``[sensor, playback, rs]``. Releasing the device while its player thread was still
    stopping (or the sensor after its device) crashed librealsense: a segmentation fault in about one
    close in 25 when readers closed recordings at random moments (during a stall, mid-recording).
    """
    closing.set()
    if not idle.wait(_CALLBACK_WAIT_S):
        log.warning("a frame callback still runs after %g s; stopping the player anyway", _CALLBACK_WAIT_S)
    if not player:
        return
    for step in ("stop", "close"):
        try:
            getattr(player[0], step)()
        except RuntimeError:  # pyrealsense2 raises when the sensor is already stopped or closed
            pass
    del player[0]  # the sensor's last reference
    playback, rs = player
    t_end = time.monotonic() + _CALLBACK_WAIT_S
    while True:
        try:
            if playback.current_status() == rs.playback_status.stopped:
                break
        except RuntimeError:  # a device that cannot say has nothing left running
            break
        if time.monotonic() > t_end:
            log.warning("the recording's player did not stop within %g s; releasing it anyway", _CALLBACK_WAIT_S)
            break
        time.sleep(0.01)
    del playback
    player.clear()  # the playback device's last reference
