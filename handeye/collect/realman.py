r"""RealMan arm client speaking the controller's JSON protocol over TCP (what the vendor tool uses).

One compact JSON object per command, terminated by ``\r\n``, on port 8080 by default; answers are
framed by braces (several may share a packet, one may be split). Poses come in 0.001 mm and
0.001 rad in the vendor convention (:data:`handeye.conventions.VENDOR_POSE_FORMAT`). Reads are
retried on a fresh connection; a motion command is sent once and never resent.

See docs/collect.md for the commands used and their sources.
"""

from __future__ import annotations

import json
import logging
import re
import socket
import time
from collections import deque
from typing import Callable

import numpy as np

from ..conventions import VENDOR_POSE_FORMAT, T_from_pose_values, pose_values_from_T
from ..errors import ConfigError, HardwareError
from .robot import PoseReading, Robot, poses_agree

log = logging.getLogger(__name__)

REALMAN_DEFAULT_PORT = 8080
#: pose units on the wire
POSITION_UNIT_M = 1e-6  # 0.001 mm
ANGLE_UNIT_RAD = 1e-3  # 0.001 rad

#: system error codes (RealMan JSON protocol / rm_driver error table)
SYSTEM_ERRORS = {
    0x1001: "abnormal joint communication",
    0x1002: "target angle out of joint limit",
    0x1003: "point unreachable (singularity)",
    0x1004: "real-time kernel communication error",
    0x1005: "joint communication bus error",
    0x1006: "planning layer kernel error",
    0x1007: "joint overspeed",
    0x1008: "end interface board disconnected",
    0x1009: "speed out of limit",
    0x100A: "acceleration out of limit",
    0x100B: "joint brake not released",
    0x100C: "overspeed during drag teaching",
    0x100D: "collision detected",
    0x100E: "no such work frame",
    0x100F: "no such tool frame",
    0x1010: "joint disabled",
    0x1011: "circular planning error",
    0x1012: "self-collision",
    0x1013: "electronic fence collision",
    0x5001: "base tilted",
    0x5003: "controller over-temperature",
    0x5005: "controller overcurrent",
    0x5006: "controller undercurrent",
    0x5007: "controller overvoltage",
    0x5008: "controller undervoltage",
    0x5009: "real-time layer not answering",
}

MOTION_COMMANDS = ("movej_p", "movel")


def describe_error_codes(codes) -> str:
    return ", ".join(f"0x{c:04X} ({SYSTEM_ERRORS.get(c, 'see the RealMan error table')})" for c in codes)


def parse_robot_address(spec: str, *, default_port: int = REALMAN_DEFAULT_PORT) -> tuple[str, int]:
    """``"IP[:PORT]"`` (or ``"[IPv6]:PORT"``) -> (host, port). The host is never defaulted."""
    s = (spec or "").strip()
    m = re.fullmatch(r"\[([^\]]+)\](?::(\d+))?", s) or re.fullmatch(r"([^:\s]+)(?::(\d+))?", s)
    if not m or not m.group(1):
        raise ConfigError(
            "the RealMan arm's address is missing or malformed",
            expected="IP[:PORT], e.g. 192.168.1.18",
            received=repr(spec),
            hint="give it as --robot realman:192.168.1.18 (port 8080 by default)",
        )
    port = int(m.group(2)) if m.group(2) else default_port
    if not 0 < port < 65536:
        raise ConfigError("invalid TCP port for the RealMan arm", expected="1..65535", received=str(port))
    return m.group(1), port


# ------------------------------------------------------------------------------ wire conversions
def T_base_end_from_realman_pose(pose_units) -> np.ndarray:
    """4x4 ``T_base_end`` (metres) from ``[x, y, z, rx, ry, rz]`` in 0.001 mm / 0.001 rad."""
    v = np.asarray(pose_units, dtype=float).reshape(-1)
    if v.size != 6 or not np.all(np.isfinite(v)):
        raise ValueError(f"expected 6 finite pose numbers, got {list(pose_units)!r}")
    values = np.concatenate([v[:3] * POSITION_UNIT_M, v[3:] * ANGLE_UNIT_RAD])
    return T_from_pose_values(values, VENDOR_POSE_FORMAT)


def realman_pose_from_T(T_base_end: np.ndarray) -> list[int]:
    """``[x, y, z, rx, ry, rz]`` integers in 0.001 mm / 0.001 rad for a motion command."""
    v = pose_values_from_T(np.asarray(T_base_end, float), VENDOR_POSE_FORMAT)
    return [int(round(x / POSITION_UNIT_M)) for x in v[:3]] + [int(round(a / ANGLE_UNIT_RAD)) for a in v[3:]]


def realman_error_codes(err) -> list[int]:
    """Non-zero error codes from ``arm_state.err`` in any of the firmware's shapes."""
    if err is None:
        return []
    if isinstance(err, dict):
        err = err.get("err", [])
    if isinstance(err, bool):
        raise ValueError(f"unexpected error field {err!r}")
    if isinstance(err, (int, float)):
        err = [err]
    if not isinstance(err, list):
        raise ValueError(f"unexpected error field {err!r}")
    out = []
    for e in err:
        if isinstance(e, str):
            e = int(e, 0)
        if isinstance(e, bool) or not isinstance(e, (int, float)):
            raise ValueError(f"unexpected error code {e!r}")
        if int(e) != 0:
            out.append(int(e))
    return out


# ------------------------------------------------------------------------------ stream framing
class JsonStreamDecoder:
    """Splits a TCP byte stream into JSON objects.

    Handles objects split across packets, several objects in one packet (with or without line
    breaks between them), bytes that are not JSON, and truncated objects. The controller writes one
    compact object per line, so a line break inside an unfinished object marks the object as
    truncated: it is discarded and reading resumes after the line break. Anything discarded is
    counted in ``discarded_bytes``. The buffer is bounded by ``max_buffer_bytes``.
    """

    def __init__(self, *, max_buffer_bytes: int = 1 << 20):
        self._buf = bytearray()
        self.max_buffer_bytes = int(max_buffer_bytes)
        self.discarded_bytes = 0

    def reset(self) -> None:
        self._buf.clear()

    def _discard(self, n: int) -> None:
        junk = bytes(self._buf[:n])
        del self._buf[:n]
        if junk.strip():
            self.discarded_bytes += len(junk)
            log.debug("discarded %d bytes that are not JSON: %r", len(junk), junk[:60])

    def feed(self, data: bytes) -> list[dict]:
        self._buf.extend(data)
        out: list[dict] = []
        while self._buf:
            start = self._buf.find(b"{")
            if start < 0:
                self._discard(len(self._buf))
                break
            if start > 0:
                self._discard(start)
            status, end = _scan_object(self._buf)
            if status == "incomplete":
                if len(self._buf) > self.max_buffer_bytes:
                    self._discard(len(self._buf))
                break
            if status == "truncated":
                self._discard(end + 1)
                continue
            chunk = bytes(self._buf[: end + 1])
            try:
                obj = json.loads(chunk.decode("utf-8"))
            except (UnicodeDecodeError, ValueError):
                self._discard(end + 1)
                continue
            del self._buf[: end + 1]
            if isinstance(obj, dict):
                out.append(obj)
            else:
                self.discarded_bytes += len(chunk)
        return out


def _scan_object(buf: bytearray) -> tuple[str, int]:
    """Whether the JSON object at the start of ``buf`` is complete, truncated or incomplete.

    For ``buf`` starting with '{': ("complete", index of the closing brace), ("truncated",
    index of the line break that cut it) or ("incomplete", -1).
    """
    depth = 0
    in_str = False
    esc = False
    for i, b in enumerate(buf):
        if b in (0x0A, 0x0D):  # a raw line break never occurs inside one compact message
            return "truncated", i
        if in_str:
            if esc:
                esc = False
            elif b == 0x5C:  # backslash
                esc = True
            elif b == 0x22:
                in_str = False
            continue
        if b == 0x22:
            in_str = True
        elif b == 0x7B:
            depth += 1
        elif b == 0x7D:
            depth -= 1
            if depth == 0:
                return "complete", i
    return "incomplete", -1


# ------------------------------------------------------------------------------ the client
class _LinkError(Exception):
    """The connection failed or the reply did not come in time (transient for reads)."""


class RealmanArm(Robot):
    """A RealMan arm over its JSON port.

    ``motion`` chooses ``movej_p`` (joint-space path to a Cartesian target, the default: it cannot
    hit a singularity on the way) or ``movel`` (straight line). ``max_speed_fraction`` caps every
    motion whatever the caller asks for.
    """

    is_real = True

    def __init__(
        self,
        host: str,
        port: int = REALMAN_DEFAULT_PORT,
        *,
        timeout_s: float = 2.0,
        read_retries: int = 2,
        motion_timeout_s: float = 120.0,
        motion: str = "movej_p",
        max_speed_fraction: float = 0.3,
        work_frame: str | None = "Base",
        arrive_tol_mm: float = 2.0,
        arrive_tol_deg: float = 0.5,
    ):
        if not host:
            raise ConfigError("the RealMan arm's address is missing", hint="use --robot realman:IP[:PORT]")
        if motion not in MOTION_COMMANDS:
            raise ConfigError(
                "unknown RealMan motion command", expected=" | ".join(MOTION_COMMANDS), received=repr(motion)
            )
        if not 0 < max_speed_fraction <= 1:
            raise ConfigError(
                "invalid maximum speed fraction", expected="0 < value <= 1", received=repr(max_speed_fraction)
            )
        self.host, self.port = host, int(port)
        self.name = f"realman {host}:{self.port}"
        self.timeout_s = float(timeout_s)
        self.read_retries = int(read_retries)
        self.motion_timeout_s = float(motion_timeout_s)
        self.motion = motion
        self.max_speed_fraction = float(max_speed_fraction)
        self.work_frame = work_frame
        self.arrive_tol_mm, self.arrive_tol_deg = float(arrive_tol_mm), float(arrive_tol_deg)
        self.tool_frame: str | None = None
        self._sock: socket.socket | None = None
        self._decoder = JsonStreamDecoder()
        self._pending: deque[dict] = deque()
        self.reconnects = 0
        self._connect()
        if work_frame:
            self._set_work_frame(work_frame)
        self.tool_frame = self._query_tool_frame()

    # -- connection ----------------------------------------------------------------------------
    def _where(self) -> str:
        return f"RealMan arm at {self.host}:{self.port}"

    def _connect(self) -> None:
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as e:
            self._sock = None
            raise HardwareError(
                f"cannot reach the {self._where()} ({e.strerror or e})",
                hint="check the address, the cable and that the controller is on; "
                "close the teach pendant's JSON session",
            ) from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._decoder.reset()
        self._pending.clear()

    def _disconnect(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
        self._sock = None
        self._decoder.reset()
        self._pending.clear()

    def close(self) -> None:
        self._disconnect()

    # -- exchange ------------------------------------------------------------------------------
    def _send(self, command: dict) -> None:
        if self._sock is None:
            raise _LinkError("not connected")
        data = (json.dumps(command, separators=(",", ":")) + "\r\n").encode("utf-8")
        try:
            self._sock.sendall(data)
        except OSError as e:
            raise _LinkError(f"send failed ({e.strerror or e})") from None

    def _await(self, match: Callable[[dict], bool], *, timeout_s: float, what: str) -> dict:
        deadline = time.monotonic() + timeout_s
        while True:
            while self._pending:
                msg = self._pending.popleft()
                if match(msg):
                    return msg
                log.debug("%s: ignored message while waiting for %s: %s", self._where(), what, str(msg)[:120])
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise _LinkError(f"no answer to {what} within {timeout_s:g} s")
            if self._sock is None:
                raise _LinkError("not connected")
            try:
                self._sock.settimeout(remaining)
                data = self._sock.recv(65536)
            except socket.timeout:
                raise _LinkError(f"no answer to {what} within {timeout_s:g} s") from None
            except OSError as e:
                raise _LinkError(f"connection error ({e.strerror or e})") from None
            if not data:
                raise _LinkError("the arm closed the connection")
            self._pending.extend(self._decoder.feed(data))

    def _request(
        self, command: dict, match: Callable[[dict], bool], *, retries: int, timeout_s: float | None = None
    ) -> dict:
        """Send ``command`` and return the first matching reply; reconnect and resend up to ``retries`` times.

        Send ``command`` and return the first matching reply; reconnect and resend up to
        ``retries`` times (only for commands without side effects).
        """
        what = command.get("command", "?")
        last = ""
        for attempt in range(retries + 1):
            try:
                if self._sock is None:
                    self._connect()
                    self.reconnects += 1
                self._send(command)
                return self._await(match, timeout_s=timeout_s or self.timeout_s, what=what)
            except _LinkError as e:
                last = str(e)
                self._disconnect()
                if attempt < retries:
                    log.warning(
                        "%s: %s; reconnecting and asking again (%d/%d)", self._where(), last, attempt + 1, retries
                    )
                    time.sleep(min(0.2 * (attempt + 1), 1.0))
        raise HardwareError(
            f"the {self._where()} did not answer {what!r} ({last}) after {retries + 1} attempts",
            hint="check the network link and that no other program holds the arm's JSON port",
        )

    # -- setup ---------------------------------------------------------------------------------
    def _set_work_frame(self, frame: str) -> None:
        reply = self._request(
            {"command": "set_change_work_frame", "frame_name": frame},
            lambda m: m.get("command") == "set_change_work_frame",
            retries=self.read_retries,
        )
        if reply.get("change_work_frame") is not True:
            raise HardwareError(
                f"the {self._where()} refused to switch its work frame to {frame!r}",
                received=json.dumps(reply),
                hint="check the frame exists on the controller",
            )

    def _query_tool_frame(self) -> str | None:
        try:
            reply = self._request(
                {"command": "get_current_tool_frame"},
                lambda m: m.get("state") == "current_tool_frame" or m.get("command") == "get_current_tool_frame",
                retries=0,
            )
        except HardwareError as e:
            log.warning("could not read the active tool frame (%s); poses are of whatever tool is active", e)
            if self._sock is None:
                self._connect()
            return None
        return reply.get("tool_name")

    def describe(self) -> dict:
        return {
            "backend": "realman",
            "address": f"{self.host}:{self.port}",
            "protocol": "RealMan JSON over TCP",
            "work_frame": self.work_frame,
            "tool_frame": self.tool_frame,
            "motion_command": self.motion,
            "max_speed_fraction": self.max_speed_fraction,
            "pose_resolution": "0.001 mm, 0.001 rad (as reported by get_current_arm_state)",
        }

    # -- Robot ---------------------------------------------------------------------------------
    def read_pose(self) -> PoseReading:
        last = ""
        for _attempt in range(self.read_retries + 1):
            reply = self._request(
                {"command": "get_current_arm_state"},
                lambda m: m.get("state") == "current_arm_state" or "arm_state" in m,
                retries=self.read_retries,
            )
            t = time.time()
            try:
                return self._parse_arm_state(reply, t)
            except ValueError as e:
                log.warning("%s: malformed arm state (%s); asking again", self._where(), e)
                last = str(e)
                self._disconnect()
        raise HardwareError(
            f"the {self._where()} keeps sending a malformed arm state",
            received=last,
            hint="check the controller firmware version",
        )

    def _parse_arm_state(self, reply: dict, t: float) -> PoseReading:
        st = reply.get("arm_state")
        if not isinstance(st, dict):
            raise ValueError(f"arm_state is {type(st).__name__}, not a mapping")
        pose = st.get("pose")
        if not isinstance(pose, list) or len(pose) != 6:
            raise ValueError(f"arm_state.pose is {pose!r}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in pose):
            raise ValueError(f"arm_state.pose is {pose!r}")
        T = T_base_end_from_realman_pose(pose)
        errors = realman_error_codes(st.get("err", st.get("arm_err")))
        state = {
            "raw_pose": [v for v in pose],
            "pose_units": "0.001 mm, 0.001 rad (x,y,z,rx,ry,rz; R=Rz@Ry@Rx)",
            "errors": errors,
            "work_frame": self.work_frame,
            "tool_frame": self.tool_frame,
        }
        joints = None
        if isinstance(st.get("joint"), list):
            state["joint_mdeg"] = list(st["joint"])
            if st["joint"] and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in st["joint"]):
                joints = tuple(float(np.radians(v / 1000.0)) for v in st["joint"])  # 0.001 deg -> rad
        return PoseReading(T, t, state, joints)

    def stop(self) -> bool:
        """Best-effort trajectory stop on a fresh connection; True when the arm confirmed."""
        try:
            self._disconnect()
            self._connect()
            reply = self._request({"command": "set_arm_stop"}, lambda m: m.get("command") == "set_arm_stop", retries=0)
            return reply.get("arm_stop") is True
        except HardwareError as e:
            log.error("could not send the stop command: %s", e)
            return False

    def move_to(self, T_base_end: np.ndarray, *, speed_fraction: float) -> None:
        if not 0 < speed_fraction <= 1:
            raise ConfigError("invalid speed fraction", expected="0 < value <= 1", received=repr(speed_fraction))
        now = self.read_pose()
        if now.errors:
            raise HardwareError(
                f"the {self._where()} reports {describe_error_codes(now.errors)}",
                hint="clear the error on the teach pendant (or clear_system_err) before moving",
            )
        v = int(np.clip(round(100 * min(speed_fraction, self.max_speed_fraction)), 1, 100))
        pose = realman_pose_from_T(T_base_end)
        cmd = {"command": self.motion, "pose": pose, "v": v, "r": 0, "trajectory_connect": 0}
        unknown = (
            "the arm may still be moving; the motion was not resent. Check the arm, then "
            "re-run collect into a new folder (views already saved are kept)"
        )
        try:
            if self._sock is None:
                self._connect()
                self.reconnects += 1
            self._send(cmd)
            ack = self._await(
                lambda m: (
                    m.get("command") == self.motion or m.get("state") in ("pose_state", "current_trajectory_state")
                ),
                timeout_s=self.timeout_s,
                what=self.motion,
            )
            if ack.get("state") != "current_trajectory_state":
                refused = ack.get("receive_state") is False or realman_error_codes(ack.get("arm_err"))
                if refused:
                    raise HardwareError(
                        f"the {self._where()} refused {self.motion} to {pose}",
                        received=json.dumps(ack),
                        hint="the target is probably unreachable; plan a smaller motion",
                    )
                done = self._await(
                    lambda m: m.get("state") == "current_trajectory_state" and int(m.get("device", 0)) == 0,
                    timeout_s=self.motion_timeout_s,
                    what=f"{self.motion} completion",
                )
            else:
                done = ack
        except _LinkError as e:
            self._disconnect()
            if "no answer" in str(e):
                stopped = self.stop()
                raise HardwareError(
                    f"{self.motion} to {pose} on the {self._where()}: {e}; "
                    f"stop command {'confirmed' if stopped else 'NOT confirmed'}",
                    hint=unknown,
                ) from None
            raise HardwareError(
                f"lost the link to the {self._where()} during {self.motion} ({e})", hint=unknown
            ) from None
        if done.get("trajectory_state") is not True:
            raise HardwareError(
                f"the {self._where()} reports that {self.motion} to {pose} failed",
                received=json.dumps(done),
                hint="check the arm for errors and obstacles",
            )
        reached = self.read_pose()
        ok, rot_deg, trans_mm = poses_agree(
            reached.T_base_end, T_base_end, tol_mm=self.arrive_tol_mm, tol_deg=self.arrive_tol_deg
        )
        if not ok:
            raise HardwareError(
                f"the {self._where()} stopped {trans_mm:.1f} mm / {rot_deg:.2f} deg away from "
                f"the target of {self.motion}",
                hint="check the arm for errors and obstacles",
            )
