"""A small stand-in for a RealMan controller's JSON port, for tests and dry runs.

It listens on 127.0.0.1 (an ephemeral port by default), answers the commands
:class:`handeye.collect.realman.RealmanArm` uses, and can misbehave on request (``faults``) the
ways a real link does: answers split into pieces, several answers in one packet, bytes that are
not JSON, truncated answers, silence, dropped connections, error codes, refused or failed motions.
Every loop is bounded and the server stops by itself after ``lifetime_s``.

    with RealmanEmulator(faults=["split", "drop"]) as emu:
        arm = RealmanArm(*emu.address)
"""

from __future__ import annotations

import json
import logging
import socket
import threading
import time
from collections import deque

import numpy as np

from ..collect.realman import JsonStreamDecoder, T_base_end_from_realman_pose, realman_pose_from_T

log = logging.getLogger(__name__)

#: fault names understood by the emulator; each is consumed by one reply (in order)
FAULTS = ("split", "merge", "garbage", "truncate", "silent", "drop", "refuse", "fail_motion", "malformed")


class RealmanEmulator:
    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        T_base_end: np.ndarray | None = None,
        faults=(),
        errors=(),
        err_format: str = "list",
        motion_time_s: float = 0.02,
        lifetime_s: float = 30.0,
        split_delay_s: float = 0.01,
    ):
        for f in faults:
            if f not in FAULTS:
                raise ValueError(f"unknown fault {f!r}; expected one of {FAULTS}")
        if T_base_end is None:
            T_base_end = T_base_end_from_realman_pose([300000, 0, 400000, 3141, 0, 0])
        self.pose_units = realman_pose_from_T(T_base_end)  # quantised like the real controller
        self.faults: deque[str] = deque(faults)
        self.errors = list(errors)
        self.err_format = err_format
        self.motion_time_s = motion_time_s
        self.lifetime_s = lifetime_s
        self.split_delay_s = split_delay_s
        self.received: list[dict] = []  # every command, in order
        self.connections = 0
        self.work_frame = "World"
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._srv.bind((host, port))
        self._srv.listen(8)
        self._srv.settimeout(0.05)
        self.address = self._srv.getsockname()[:2]
        self._threads: list[threading.Thread] = []
        self._t0 = time.monotonic()
        self._accept_thread = threading.Thread(target=self._accept_loop, name="realman-emulator", daemon=True)

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> "RealmanEmulator":
        self._accept_thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._accept_thread.join(timeout=2.0)
        for t in self._threads:
            t.join(timeout=2.0)
        try:
            self._srv.close()
        except OSError:
            pass

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False

    def _alive(self) -> bool:
        return not self._stop.is_set() and time.monotonic() - self._t0 < self.lifetime_s

    @property
    def T_base_end(self) -> np.ndarray:
        return T_base_end_from_realman_pose(self.pose_units)

    def _next_fault(self) -> str | None:
        with self._lock:
            return self.faults.popleft() if self.faults else None

    # -- server --------------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        while self._alive():
            try:
                conn, _ = self._srv.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            self.connections += 1
            t = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            self._threads.append(t)
            t.start()

    def _serve(self, conn: socket.socket) -> None:
        dec = JsonStreamDecoder()
        conn.settimeout(0.05)
        try:
            while self._alive():
                try:
                    data = conn.recv(4096)
                except socket.timeout:
                    continue
                except OSError:
                    return
                if not data:
                    return
                for cmd in dec.feed(data):
                    with self._lock:
                        self.received.append(cmd)
                    if not self._answer(conn, cmd):
                        return
        finally:
            try:
                conn.close()
            except OSError:
                pass

    def _send(self, conn: socket.socket, obj: dict, fault: str | None) -> bool:
        """Send one reply, applying ``fault``; False when the connection was dropped."""
        data = (json.dumps(obj, separators=(",", ":")) + "\r\n").encode()
        if fault == "silent":
            return True
        if fault == "drop":
            conn.close()
            return False
        if fault == "garbage":
            data = b"\x00\xff#?garbage}\r\n" + data
        if fault == "truncate":  # a cut-off answer, then the full one again on the next line
            data = data[: len(data) // 2] + b"\r\n" + data
        if fault == "merge":  # an unsolicited extra object glued in front, same packet
            extra = json.dumps({"state": "current_trajectory_state", "trajectory_state": True, "device": 1})
            data = extra.encode() + data
        if fault == "malformed":
            data = b'{"state":"current_arm_state","arm_state":{"pose":"oops"}}\r\n'
        try:
            if fault == "split":
                for i in range(0, len(data), 7):
                    conn.sendall(data[i : i + 7])
                    time.sleep(self.split_delay_s)
            else:
                conn.sendall(data)
        except OSError:
            return False
        return True

    def _joint_units(self) -> list | None:
        """The RM65-B's joint angles (0.001 deg) at the current pose.

        The RM65-B's joint angles (0.001 deg) at the current pose (nominal DH, cached per pose), or None
        when the arm cannot reach it (then the state has no ``joint`` field).
        """
        key = tuple(self.pose_units)
        if getattr(self, "_joints_for", (None,))[0] != key:
            from ..collect.realman import T_base_end_from_realman_pose
            from ..kinematics import default_ik_seeds, load_arm, solve_ik

            arm = load_arm("rm65")
            T = T_base_end_from_realman_pose(list(key))
            q = solve_ik(arm, T, seeds=default_ik_seeds(arm, T))
            self._joints_for = (key, None if q is None else [int(round(v)) for v in np.degrees(q) * 1000.0])
        return self._joints_for[1]

    def _arm_state(self) -> dict:
        err = {
            "list": self.errors or [0],
            "int": self.errors[0] if self.errors else 0,
            "dict": {"err_len": len(self.errors), "err": self.errors},
        }[self.err_format]
        state = {"pose": list(self.pose_units), "err": err}
        joints = self._joint_units()
        if joints is not None:
            state = {"joint": joints, **state}
        return {"state": "current_arm_state", "arm_state": state}

    def _answer(self, conn: socket.socket, cmd: dict) -> bool:
        name = cmd.get("command")
        fault = self._next_fault()
        if name == "get_current_arm_state":
            return self._send(conn, self._arm_state(), fault)
        if name == "set_change_work_frame":
            self.work_frame = str(cmd.get("frame_name"))
            return self._send(conn, {"command": name, "change_work_frame": True}, fault)
        if name == "get_current_tool_frame":
            return self._send(
                conn,
                {
                    "state": "current_tool_frame",
                    "tool_name": "Arm_Tip",
                    "pose": [0, 0, 0, 0, 0, 0],
                    "payload": 0,
                    "position": [0, 0, 0],
                },
                fault,
            )
        if name == "set_arm_stop":
            return self._send(conn, {"command": name, "arm_stop": True}, fault)
        if name in ("movel", "movej_p"):
            pose = cmd.get("pose")
            ok = isinstance(pose, list) and len(pose) == 6 and fault != "refuse" and not self.errors
            if name == "movej_p":
                ack = {
                    "state": "pose_state",
                    "pose": list(self.pose_units),
                    "joint": [0] * 6,
                    "arm_err": 0 if ok else 0x1003,
                }
            else:
                ack = {"command": name, "receive_state": ok}
            if not self._send(conn, ack, fault if fault not in ("refuse", "fail_motion") else None):
                return False
            if not ok:
                return True
            time.sleep(self.motion_time_s)
            success = fault != "fail_motion"
            if success:
                assert isinstance(pose, list), "ok: a pose list"
                with self._lock:
                    self.pose_units = [int(v) for v in pose]
            return self._send(
                conn,
                {
                    "state": "current_trajectory_state",
                    "trajectory_state": success,
                    "device": 0,
                    "trajectory_connect": 0,
                },
                None,
            )
        return self._send(conn, {"command": name, "error": "unknown command"}, fault)
