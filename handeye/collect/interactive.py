"""The interactive capture loop: key ``s`` captures, ``q`` quits.

A preview window with the detected corners where a display and an OpenCV GUI exist
(:func:`gui_available`), a terminal prompt otherwise. :class:`InteractiveMode` is the part of
:class:`~handeye.collect.collector.Collector` that runs it.
"""

from __future__ import annotations

import os
import sys
from typing import Optional, TextIO

import cv2
import numpy as np

from ..errors import clip
from ..targets import ChessboardSpec, TargetSpec
from .camera import Camera
from .capture import Capture, _gray
from .robot import Robot


def gui_available() -> bool:
    """A display exists and this OpenCV build has a GUI backend (opencv-python-headless has none)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    info = cv2.getBuildInformation()
    gui = [ln for ln in info.splitlines() if ln.strip().startswith("GUI:")]
    if gui and gui[0].split(":", 1)[1].strip().upper() in ("NONE", ""):
        return False
    try:
        cv2.namedWindow("handeye-probe", cv2.WINDOW_AUTOSIZE)
        cv2.destroyWindow("handeye-probe")
    except cv2.error:
        return False
    return True


class InteractiveMode:
    """The interactive capture loop of a collector (its ``robot``, ``camera``, ``target``, ``kept``, ``capture``)."""

    robot: Robot
    camera: Camera
    target: TargetSpec
    kept: list[Capture]

    def capture(self, *, reference_T_cam_board: Optional[np.ndarray] = None) -> Capture:
        """Take one capture (the collector's)."""
        raise NotImplementedError

    def run_interactive(
        self, *, preview: Optional[bool] = None, stdin: Optional[TextIO] = None, max_views: Optional[int] = None
    ) -> int:
        """Capture on ``s``, quit on ``q``; returns the number of views kept."""
        use_gui = gui_available() if preview is None else preview
        if use_gui:
            return self._run_preview(max_views=max_views)
        stream = sys.stdin if stdin is None else stdin
        guided = hasattr(self.robot, "simulate_hand_guiding")
        print(
            "Move the arm so the camera sees the whole board, then press s + Enter to capture; "
            "q + Enter (or end of input) quits.",
            file=sys.stderr,
        )
        first = True
        while max_views is None or len(self.kept) < max_views:
            print(f"[{len(self.kept)} views] s = capture, q = quit > ", end="", file=sys.stderr, flush=True)
            line = stream.readline()
            if not line:
                break
            key = line.strip().lower()
            if key in ("q", "quit", "exit"):
                break
            if key not in ("s", ""):
                print("  keys: s (capture), q (quit)", file=sys.stderr)
                continue
            if guided and not first:
                self.robot.simulate_hand_guiding()  # type: ignore[attr-defined]  # hasattr above
            first = False
            cap = self.capture()
            print(f"  view {cap.view_id} saved" if cap.kept else f"  rejected: {cap.reason}", file=sys.stderr)
        return len(self.kept)

    def _run_preview(self, *, max_views: Optional[int]) -> int:
        win = "handeye collect: s = capture, q = quit"
        cv2.namedWindow(win, cv2.WINDOW_NORMAL)
        message = "s: capture   q: quit"
        guided = hasattr(self.robot, "simulate_hand_guiding")
        try:
            while max_views is None or len(self.kept) < max_views:
                image, _ = self.camera.grab()
                shown = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
                scale = min(1.0, 960.0 / shown.shape[1])
                small = cv2.resize(shown, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
                if isinstance(self.target, ChessboardSpec):
                    ok, corners = cv2.findChessboardCorners(
                        _gray(small), (self.target.cols, self.target.rows), flags=cv2.CALIB_CB_FAST_CHECK
                    )
                    if ok:
                        cv2.drawChessboardCorners(small, (self.target.cols, self.target.rows), corners, ok)
                cv2.putText(
                    small,
                    f"{len(self.kept)} views | {message}",
                    (10, 25),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.6,
                    (0, 255, 255),
                    2,
                )
                cv2.imshow(win, small)
                key = cv2.waitKey(30) & 0xFF
                if key in (ord("q"), 27):
                    break
                if key == ord("s"):
                    if guided and self.kept:
                        self.robot.simulate_hand_guiding()  # type: ignore[attr-defined]  # hasattr above
                    cap = self.capture()
                    message = f"view {cap.view_id} saved" if cap.kept else f"rejected: {clip(cap.reason, 70)}"
        finally:
            cv2.destroyWindow(win)
        return len(self.kept)
