"""Frozen dataclasses for the data that flows through handeye.

Views are identified by ``view_id`` (a string such as "7" for ``7.jpg``), never by list position.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

import numpy as np

MODES = ("eye_in_hand", "eye_to_hand")


def view_id_key(view_id) -> tuple:
    """Sort key for view ids: numeric ids in numeric order ("2" before "10"), then the others by name."""
    vid = str(view_id)
    return (0, int(vid), "") if vid.isdigit() else (1, 0, vid)
#: OpenCV's closed-form solvers by handeye name (hand-eye AX=XB ones, then robot-world AX=ZB ones)
METHOD_NAMES = ("tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li")


def grid_turns(cols: int, rows: int) -> list[np.ndarray]:
    """Row-major id permutations of a cols x rows grid under turns of 0, 180 (and, square, 90, 270) degrees."""
    ident = np.arange(cols * rows)
    out = [ident, ident[::-1].copy()]
    if cols == rows:
        grid = ident.reshape(rows, cols)
        out += [np.rot90(grid, 1).reshape(-1).copy(), np.rot90(grid, 3).reshape(-1).copy()]
    return out


@dataclass(frozen=True)
class ChessboardSpec:
    """Chessboard with ``cols`` x ``rows`` inner corners (cols along the long side), square in metres.

    Corner id ``r * cols + c`` sits at board point ``(c * square_m, r * square_m, 0)``.
    """

    cols: int
    rows: int
    square_m: float
    kind: str = "chessboard"

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:  # shape (cols*rows, 3)
        r, c = np.divmod(np.arange(self.n_corners), self.cols)
        return np.stack([c * self.square_m, r * self.square_m, np.zeros(self.n_corners)], axis=1)

    def symmetries(self) -> list[np.ndarray]:
        """Corner-id permutations under which a detector cannot tell the board's orientation.

        Each entry ``perm`` maps a detected corner index to the id it may really have. The identity
        is always first, then the 180-degree turn, then (square grids) the 90 and 270-degree turns.
        With (cols+1) x (rows+1) squares, a half turn maps the colour pattern onto itself when
        cols + rows is even. (On an asymmetric board the colours decide; a detector that numbers
        such a board from the other end is corrected in detection, see detect.normalize_chessboard_order.)
        """
        if (self.cols + self.rows) % 2 == 1:
            return [np.arange(self.n_corners)]
        return grid_turns(self.cols, self.rows)

    def to_dict(self) -> dict:
        return {"type": "chessboard", "inner_corners": [self.cols, self.rows], "square_m": self.square_m}


@dataclass(frozen=True)
class CharucoSpec:
    """ChArUco board of ``squares_x`` x ``squares_y`` squares; corner ids are OpenCV's."""

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_6X6_250"
    legacy_pattern: bool = False
    kind: str = "charuco"

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    def object_points(self) -> np.ndarray:  # shape (n_corners, 3)
        cols = self.squares_x - 1
        r, c = np.divmod(np.arange(self.n_corners), cols)
        return np.stack([(c + 1) * self.square_m, (r + 1) * self.square_m, np.zeros(self.n_corners)], axis=1)

    def symmetries(self) -> list[np.ndarray]:
        return [np.arange(self.n_corners)]  # marker ids make the orientation unique

    def to_dict(self) -> dict:
        return {"type": "charuco", "squares": [self.squares_x, self.squares_y], "square_m": self.square_m,
                "marker_m": self.marker_m, "dictionary": self.dictionary,
                "legacy_pattern": self.legacy_pattern}


@dataclass(frozen=True)
class CircleGridSpec:
    """Grid of ``cols`` x ``rows`` dots (cols = dots per row), centre spacing in metres.

    Symmetric grid: dot id ``r * cols + c`` sits at board point ``(c * spacing_m, r * spacing_m, 0)``.
    Asymmetric grid (OpenCV's layout, rows staggered): at ``((2 * c + r % 2) * spacing_m, r * spacing_m, 0)``.
    The board frame is OpenCV's: z points into the board (away from a camera that sees its front).
    ``origin_dot``: one corner dot is larger (ROS-Industrial's "modified circle grid"); the detector then
    numbers the grid from that dot (id 0). Seen from the front with the dot at the bottom left, x runs
    up from the dot and y to the right (ROS-Industrial's own frame has z out of the page instead).
    """

    cols: int
    rows: int
    spacing_m: float
    asymmetric: bool = False
    origin_dot: bool = False
    kind: str = "circlegrid"

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def square_m(self) -> float:
        """Grid pitch (distance between neighbouring rows), for code that sizes things by the square."""
        return self.spacing_m

    def object_points(self) -> np.ndarray:  # shape (cols*rows, 3)
        r, c = np.divmod(np.arange(self.n_corners), self.cols)
        x = (2 * c + r % 2) if self.asymmetric else c
        return np.stack([x * self.spacing_m, r * self.spacing_m, np.zeros(self.n_corners)], axis=1).astype(float)

    def symmetries(self) -> list[np.ndarray]:
        """Dot-id permutations under which the grid looks the same (see ``ChessboardSpec.symmetries``).

        The detector already orders every view as seen from the board's front (no mirror orderings),
        so only in-plane turns remain: symmetric grid: identity, half turn, and for a square grid the
        90 and 270-degree turns (in that order); an asymmetric grid is unique unless it has an even
        number of rows (then the half turn). With ``origin_dot`` the detector puts the big dot at id 0
        when it can tell it apart; the turns stay candidates so a view where it cannot is resolved by
        the robot motion.
        """
        if self.asymmetric:
            ident = np.arange(self.n_corners)
            return [ident, ident[::-1].copy()] if self.rows % 2 == 0 else [ident]
        return grid_turns(self.cols, self.rows)

    def to_dict(self) -> dict:
        return {"type": "circlegrid", "grid": [self.cols, self.rows], "spacing_m": self.spacing_m,
                "asymmetric": self.asymmetric, "origin_dot": self.origin_dot}


TargetSpec = Union[ChessboardSpec, CharucoSpec, CircleGridSpec]

DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera with OpenCV's 5-coefficient distortion (k1, k2, p1, p2, k3)."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)
    width: int = 0
    height: int = 0
    model: str = "opencv5"

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> np.ndarray:
        return np.asarray(self.dist, dtype=float)

    @property
    def image_size(self) -> tuple[int, int]:
        return (self.width, self.height)

    def as_vector(self) -> np.ndarray:
        """(fx, fy, cx, cy, k1, k2, p1, p2, k3)."""
        return np.concatenate([[self.fx, self.fy, self.cx, self.cy], self.dist_array])

    @staticmethod
    def from_vector(v, width: int, height: int) -> "Intrinsics":
        v = np.asarray(v, float)
        return Intrinsics(float(v[0]), float(v[1]), float(v[2]), float(v[3]), tuple(float(x) for x in v[4:9]),
                          int(width), int(height))

    @staticmethod
    def from_K(K, dist, width: int, height: int) -> "Intrinsics":
        d = np.zeros(5)
        dd = np.asarray(dist, float).reshape(-1)[:5]
        d[: dd.size] = dd
        return Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                          tuple(float(x) for x in d), int(width), int(height))

    def to_dict(self) -> dict:
        return {"model": self.model, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "dist": dict(zip(DIST_NAMES, map(float, self.dist))),
                "dist_order": "k1, k2, p1, p2, k3 (OpenCV)",
                "image_size": [self.width, self.height]}


@dataclass(frozen=True)
class View:
    """One capture: an image and the reported robot pose ``T_base_end`` (metres)."""

    view_id: str
    image_path: Path
    T_base_end: np.ndarray  # (4, 4)
    source_line: Optional[int] = None  # line in poses.txt, for messages
    t_image: Optional[float] = None
    t_pose: Optional[float] = None


@dataclass(frozen=True)
class Session:
    """A calibration session as read from disk, converted to handeye conventions."""

    path: Path
    format: str  # "vendor" | "native"
    mode: str
    target: TargetSpec
    views: tuple  # tuple[View, ...]
    intrinsics: Optional[Intrinsics] = None
    intrinsics_prior: str = "estimate"  # estimate | fixed | prior
    pose_format: str = ""
    meta: dict = field(default_factory=dict)

    def view(self, view_id: str) -> View:
        for v in self.views:
            if v.view_id == view_id:
                return v
        raise KeyError(view_id)


@dataclass(frozen=True)
class Detection:
    """Target corners found in one view. ``corner_ids`` index ``target.object_points()``."""

    view_id: str
    corner_ids: np.ndarray  # (N,) int
    image_points: np.ndarray  # (N, 2) float64 pixels
    image_size: tuple  # (width, height)
    sharpness: float = float("nan")  # variance of the Laplacian around the target
    order_cue: float = float("nan")  # chessboard: grey of the first inner square minus the last one
    seconds: float = 0.0


@dataclass(frozen=True)
class ViewOutcome:
    """What happened to one view: used or dropped, and why."""

    view_id: str
    image: str
    used: bool
    reason: str = ""
    n_corners: int = 0
    rms_px: Optional[float] = None
    max_px: Optional[float] = None
    orientation: int = 0  # index into target.symmetries() chosen for this view
    flags: tuple = ()  # reasons of outlier decisions (corner- or view-level)


@dataclass(frozen=True)
class HandEyeEstimate:
    """A hand-eye solution in the generic form ``T_cam_board_i = A · M_i · B``, named per mode."""

    mode: str
    method: str
    T_x: np.ndarray  # T_end_cam (eye-in-hand) or T_base_cam (eye-to-hand)
    T_board: np.ndarray  # T_base_board (eye-in-hand) or T_end_board (eye-to-hand)
    status: str = "ok"
    failure_reason: str = ""
