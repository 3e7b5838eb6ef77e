"""Calibration targets: chessboard, ChArUco, circle-grid, single-marker and AprilGrid specs.

Each spec is a frozen dataclass with ``object_points()`` (the board-frame corner positions, metres,
in OpenCV's numbering), ``symmetries()`` (the corner permutations a detector cannot tell apart),
``to_dict()`` (the session/result form; :func:`handeye.session.target_spec.parse_target` reads it
back with validation) and ``describe()`` (one line for messages).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Union

import numpy as np


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
    kind: Literal["chessboard"] = "chessboard"

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
        such a board from the other end is corrected in detection, see handeye.detect.chessboard.board_order.)
        """
        if (self.cols + self.rows) % 2 == 1:
            return [np.arange(self.n_corners)]
        return grid_turns(self.cols, self.rows)

    def to_dict(self) -> dict:
        return {"type": "chessboard", "inner_corners": [self.cols, self.rows], "square_m": self.square_m}

    def describe(self) -> str:
        return f"chessboard {self.cols}x{self.rows} inner corners, {self.square_m * 1000:g} mm"


@dataclass(frozen=True)
class CharucoSpec:
    """ChArUco board of ``squares_x`` x ``squares_y`` squares; corner ids are OpenCV's."""

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_6X6_250"
    legacy_pattern: bool = False
    kind: Literal["charuco"] = "charuco"

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
        return {
            "type": "charuco",
            "squares": [self.squares_x, self.squares_y],
            "square_m": self.square_m,
            "marker_m": self.marker_m,
            "dictionary": self.dictionary,
            "legacy_pattern": self.legacy_pattern,
        }

    def describe(self) -> str:
        return (
            f"ChArUco {self.squares_x}x{self.squares_y} squares, {self.square_m * 1000:g} mm squares, "
            f"{self.marker_m * 1000:g} mm markers, {self.dictionary}"
        )


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
    kind: Literal["circlegrid"] = "circlegrid"

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
        return {
            "type": "circlegrid",
            "grid": [self.cols, self.rows],
            "spacing_m": self.spacing_m,
            "asymmetric": self.asymmetric,
            "origin_dot": self.origin_dot,
        }

    def describe(self) -> str:
        layout = "asymmetric " if self.asymmetric else ""
        dot = ", origin dot" if self.origin_dot else ""
        return f"{layout}circle grid {self.cols}x{self.rows} dots, {self.spacing_m * 1000:g} mm spacing{dot}"


#: the corners of one square marker in its own frame, as a detector returns them (cv2.aruco's order):
#: top-left, top-right, bottom-right, bottom-left of the printed marker, x to the right, y down the
#: print (z into the board, as for every target here), in units of the marker's side
MARKER_CORNERS = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class MarkerSpec:
    """One square fiducial marker.

    One square fiducial marker (ArUco or AprilTag through cv2.aruco's dictionaries), ``size_m`` the side of
    its black square (AprilTag's "tag size"). Corner ids 0-3: top-left, top-right, bottom-right, bottom-left
    (:data:`MARKER_CORNERS`); the board frame's origin is the top-left corner.

    Four coplanar points fix the pose only up to the planar ambiguity (two poses that explain the corners
    almost equally well when the marker is small or seen head-on); :attr:`pose_ambiguous` tells the board-pose
    step to keep both solutions and let the robot motion choose (:mod:`handeye.initial.board_poses`).
    """

    size_m: float
    dictionary: str = "DICT_APRILTAG_36h11"
    marker_id: int = 0
    kind: Literal["marker"] = "marker"
    pose_ambiguous: bool = True

    @property
    def n_corners(self) -> int:
        return 4

    @property
    def square_m(self) -> float:
        """The length that sets the target's scale (the marker side), for code that sizes things by it."""
        return self.size_m

    def object_points(self) -> np.ndarray:  # shape (4, 3)
        return MARKER_CORNERS * self.size_m

    def symmetries(self) -> list[np.ndarray]:
        return [np.arange(4)]  # the marker's code fixes its orientation

    def to_dict(self) -> dict:
        return {"type": "marker", "size_m": self.size_m, "dictionary": self.dictionary, "marker_id": self.marker_id}

    def describe(self) -> str:
        return f"marker {self.dictionary} id {self.marker_id}, {self.size_m * 1000:g} mm"


@dataclass(frozen=True)
class AprilGridSpec:
    """Kalibr's AprilGrid: ``cols`` x ``rows`` tags of side ``size_m`` with gaps between them.

    Kalibr's AprilGrid: ``cols`` x ``rows`` tags of side ``size_m``, ``spacing`` (a ratio of the tag side)
    between neighbouring tags, small black squares in the gaps at the tags' corners. Kalibr prints each tag with
    a black border of ``border_bits`` = 2 cells (its side is 10 cells for 36h11) and the code as AprilTag lays it
    out, which OpenCV's dictionary holds turned by a half turn: the detector reads the turn off the grid.

    Tag ids as Kalibr numbers them: ``first_id`` at the bottom left of the print, increasing along a row to
    the right, then row by row upwards. Frame (handeye's, as for every target): x to the right and y down
    the print, z into the board, origin at the top-left corner of the top-left tag. Corner id
    ``4 * k + c`` is corner c (:data:`MARKER_CORNERS` order) of the k-th tag (tag id ``first_id + k``).
    """

    cols: int
    rows: int
    size_m: float
    spacing: float = 0.3
    dictionary: str = "DICT_APRILTAG_36h11"
    first_id: int = 0
    border_bits: int = 2  # black border cells of each tag: Kalibr prints 2 (its tag is 10 cells); 1: OpenCV's markers
    kind: Literal["aprilgrid"] = "aprilgrid"
    pose_ambiguous: bool = False

    @property
    def n_tags(self) -> int:
        return self.cols * self.rows

    @property
    def n_corners(self) -> int:
        return 4 * self.n_tags

    @property
    def square_m(self) -> float:
        return self.size_m

    @property
    def pitch_m(self) -> float:
        """Distance between the top-left corners of neighbouring tags."""
        return self.size_m * (1.0 + self.spacing)

    def tag_origins(self) -> np.ndarray:
        """(n_tags, 3): top-left corner of each tag, in tag order."""
        k = np.arange(self.n_tags)
        row_up, col = np.divmod(k, self.cols)
        return np.stack([col * self.pitch_m, (self.rows - 1 - row_up) * self.pitch_m, np.zeros(self.n_tags)], axis=1)

    def object_points(self) -> np.ndarray:  # shape (4 * n_tags, 3)
        return (self.tag_origins()[:, None, :] + MARKER_CORNERS[None] * self.size_m).reshape(-1, 3)

    def symmetries(self) -> list[np.ndarray]:
        return [np.arange(self.n_corners)]  # tag ids fix the orientation

    def to_dict(self) -> dict:
        return {
            "type": "aprilgrid",
            "tags": [self.cols, self.rows],
            "size_m": self.size_m,
            "spacing": self.spacing,
            "dictionary": self.dictionary,
            "first_id": self.first_id,
            "border_bits": self.border_bits,
        }

    def describe(self) -> str:
        border = "" if self.border_bits == 2 else f", {self.border_bits}-cell tag border"
        return (
            f"AprilGrid {self.cols}x{self.rows} tags, {self.size_m * 1000:g} mm, spacing {self.spacing:g}, "
            f"{self.dictionary}{border}"
        )


TargetSpec = Union[ChessboardSpec, CharucoSpec, CircleGridSpec, MarkerSpec, AprilGridSpec]


@dataclass(frozen=True)
class TrackedTargetSpec:
    """The target of a pose-only session: a frame whose pose an external tracker reports.

    The target of a pose-only session: a frame whose pose an external tracker reports (no points are
    detected). ``object_points`` are its origin and the tips of its x and y axes at ``axis_m``, for
    drawings and for code that sizes things by the target.
    """

    name: str = ""
    axis_m: float = 0.1
    kind: Literal["tracked"] = "tracked"
    pose_ambiguous: bool = False

    @property
    def n_corners(self) -> int:
        return 3

    @property
    def square_m(self) -> float:
        return self.axis_m

    def object_points(self) -> np.ndarray:  # shape (3, 3)
        return np.array([[0.0, 0.0, 0.0], [self.axis_m, 0.0, 0.0], [0.0, self.axis_m, 0.0]])

    def symmetries(self) -> list[np.ndarray]:
        return [np.arange(3)]

    def to_dict(self) -> dict:
        return {"type": "tracked", "name": self.name}

    def describe(self) -> str:
        return f"tracked target {self.name}".rstrip() + " (poses from an external tracker)"
