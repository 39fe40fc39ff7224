"""Calibration-target geometry: chessboards, ChArUco boards and circle grids (OpenCV semantics), and the
AprilTag targets of :mod:`jcalib.geometry.apriltags` (Kalibr's AprilGrid, a single AprilTag).

A target is a frozen, hashable description of a printed planar board. Its ``points`` are the
observable features (inner chessboard corners, circle centres) in the **target frame**: metres,
``z = 0`` on the printed face, ``x`` to the right and ``y`` down when the face is looked at (so ``z``
points into the board, away from a camera that sees it). Point ``k`` is the row ``points[k]``; the
vision layer reports detections as ``point_index`` into this array, in the order OpenCV's detectors
use for the same board, with the origin where OpenCV puts its first object point:

- :class:`Checkerboard` ``(cols, rows)`` inner corners (OpenCV ``patternSize``), point
  ``k = i * cols + j`` at ``(j * square, i * square, 0)``; the outer square next to point 0 is black.
- :class:`Charuco`: point ``k`` is OpenCV's ChArUco corner id ``k``, at the position
  ``cv2.aruco.CharucoBoard.getChessboardCorners()[k]`` (origin at the outer corner of the board,
  first inner corner at ``(square, square, 0)``).
- :class:`CircleGrid` ``(cols, rows)`` circles; symmetric: ``(j * spacing, i * spacing, 0)``;
  asymmetric: ``((2 * j + i % 2) * spacing, i * spacing, 0)`` (OpenCV's calibration sample), for
  ``k = i * cols + j``; a symmetric grid may carry a larger origin dot at one corner (``origin_dot``,
  ROS-Industrial's modified circle grid), which fixes its orientation.

This module uses numpy only (no OpenCV): marker bit patterns are drawn by :mod:`jcalib.sim.textures`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Union

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.apriltags import AprilGrid, AprilTag

__all__ = [
    "ARUCO_DICTIONARIES",
    "AprilGrid",
    "AprilTag",
    "Charuco",
    "Checkerboard",
    "CircleGrid",
    "Target",
    "target_from_spec",
    "warp_bow",
    "warped_points",
]

# OpenCV predefined dictionaries: name -> (marker side in bits, number of markers).
ARUCO_DICTIONARIES: dict[str, tuple[int, int]] = {
    **{f"DICT_{b}X{b}_{n}": (b, n) for b in (4, 5, 6, 7) for n in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": (5, 1024),
    "DICT_APRILTAG_16h5": (4, 30),
    "DICT_APRILTAG_25h9": (5, 35),
    "DICT_APRILTAG_36h10": (6, 2320),
    "DICT_APRILTAG_36h11": (6, 587),
    "DICT_ARUCO_MIP_36h12": (6, 250),
}


#: Corners of a circle grid that can carry the origin dot (:class:`CircleGrid`).
ORIGIN_CORNERS = ("top_left", "top_right", "bottom_left", "bottom_right")


def _check_count(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise BadInputError(f"target field {name!r}: got {value!r}, expected an integer >= {minimum}")
    return int(value)


def _check_length(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise BadInputError(f"target field {name!r}: got {value!r}, expected a positive length in metres")
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise BadInputError(f"target field {name!r}: got {value!r}, expected a positive length in metres")
    return v


def _grid(cols: int, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Row-major grid indices: (i, j) for k = i * cols + j, each (cols*rows,) int64."""
    i, j = np.divmod(np.arange(cols * rows, dtype=np.int64), cols)
    return i, j


def _points3(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.stack([x, y, np.zeros_like(x)], axis=-1).astype(np.float64)


@dataclass(frozen=True)
class Checkerboard:
    """Chessboard with ``cols x rows`` inner corners (OpenCV ``patternSize = (cols, rows)``).

    The printed board has ``(cols + 1) x (rows + 1)`` squares; the outer square touching point 0
    (the one at ``x, y < 0``) is black. A board with ``cols + rows`` even looks the same after a
    180° turn, so a detector cannot tell point 0 from point ``N - 1`` (see
    :func:`jcalib.vision.detect_target`).

    Attributes:
        cols: inner corners per row (along target x).
        rows: inner corners per column (along target y).
        square: side of a square, m.
    """

    cols: int
    rows: int
    square: float

    type = "checkerboard"

    def __post_init__(self):
        object.__setattr__(self, "cols", _check_count("cols", self.cols, 2))
        object.__setattr__(self, "rows", _check_count("rows", self.rows, 2))
        object.__setattr__(self, "square", _check_length("square", self.square))

    @property
    def num_points(self) -> int:
        return self.cols * self.rows

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 inner corners, m, target frame, row-major from the first corner."""
        i, j = _grid(self.cols, self.rows)
        return _points3(j * self.square, i * self.square)

    @property
    def ids(self) -> np.ndarray:
        """(N,) int64 point ids (= row index into ``points``)."""
        return np.arange(self.num_points, dtype=np.int64)

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(cols, rows) of the point grid."""
        return (self.cols, self.rows)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the printed pattern (outer squares), m, target frame."""
        s = self.square
        return (-s, -s, self.cols * s, self.rows * s)

    def to_spec(self) -> dict:
        """Cell-spec entry ``{type: checkerboard, cols, rows, square}`` (square in m)."""
        return {"type": self.type, **asdict(self)}


@dataclass(frozen=True)
class Charuco:
    """ChArUco board, as ``cv2.aruco.CharucoBoard((squares_x, squares_y), square, marker, dict)``.

    Attributes:
        squares_x: squares along target x.
        squares_y: squares along target y.
        square: side of a chessboard square, m.
        marker: side of an ArUco marker (black border included), m; ``marker < square``.
        dictionary: OpenCV predefined dictionary name, e.g. ``"DICT_5X5_100"``.
        legacy: OpenCV's pre-4.6 layout (``setLegacyPattern(True)``): with an even ``squares_y`` the
            top-left square is white and carries marker 0. Without it (or with odd ``squares_y``)
            the top-left square is black.
    """

    squares_x: int
    squares_y: int
    square: float
    marker: float
    dictionary: str = "DICT_5X5_100"
    legacy: bool = False

    type = "charuco"

    def __post_init__(self):
        object.__setattr__(self, "squares_x", _check_count("squares_x", self.squares_x, 2))
        object.__setattr__(self, "squares_y", _check_count("squares_y", self.squares_y, 2))
        object.__setattr__(self, "square", _check_length("square", self.square))
        object.__setattr__(self, "marker", _check_length("marker", self.marker))
        if self.marker >= self.square:
            raise BadInputError(
                f"target field 'marker': got {self.marker!r} m, expected less than square = {self.square!r} m"
            )
        if self.dictionary not in ARUCO_DICTIONARIES:
            raise BadInputError(
                f"target field 'dictionary': got {self.dictionary!r}, expected one of "
                f"{sorted(ARUCO_DICTIONARIES)}"
            )
        if not isinstance(self.legacy, (bool, np.bool_)):
            raise BadInputError(f"target field 'legacy': got {self.legacy!r}, expected true or false")
        object.__setattr__(self, "legacy", bool(self.legacy))
        available = ARUCO_DICTIONARIES[self.dictionary][1]
        if self.num_markers > available:
            raise BadInputError(
                f"target field 'dictionary': {self.dictionary} has {available} markers, the "
                f"{self.squares_x}x{self.squares_y} board needs {self.num_markers}"
            )

    @property
    def cols(self) -> int:
        """Inner corners per row (``squares_x - 1``)."""
        return self.squares_x - 1

    @property
    def rows(self) -> int:
        """Inner corners per column (``squares_y - 1``)."""
        return self.squares_y - 1

    @property
    def num_points(self) -> int:
        return self.cols * self.rows

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 chessboard corners, m, target frame; row k is OpenCV's ChArUco id k."""
        i, j = _grid(self.cols, self.rows)
        return _points3((j + 1) * self.square, (i + 1) * self.square)

    @property
    def ids(self) -> np.ndarray:
        """(N,) int64 ChArUco corner ids as OpenCV numbers them (= row index into ``points``)."""
        return np.arange(self.num_points, dtype=np.int64)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        return (0.0, 0.0, self.squares_x * self.square, self.squares_y * self.square)

    @property
    def first_square_black(self) -> bool:
        """Whether the square at the board origin (x, y in [0, square]) is black."""
        return not (self.legacy and self.squares_y % 2 == 0)

    @property
    def marker_squares(self) -> np.ndarray:
        """(M, 2) int64 (x, y) square index holding marker ``m`` (marker ids ``0..M-1``, row-major)."""
        y, x = np.divmod(np.arange(self.squares_x * self.squares_y, dtype=np.int64), self.squares_x)
        black = ((x + y) % 2 == 0) == self.first_square_black
        return np.stack([x[~black], y[~black]], axis=-1)

    @property
    def num_markers(self) -> int:
        return (self.squares_x * self.squares_y + (0 if self.first_square_black else 1)) // 2

    @property
    def marker_ids(self) -> np.ndarray:
        """(M,) int64 ArUco ids of the markers (OpenCV's default ``0..M-1``)."""
        return np.arange(self.num_markers, dtype=np.int64)

    @property
    def marker_corners(self) -> np.ndarray:
        """(M, 4, 3) float64 marker corners (top-left, top-right, bottom-right, bottom-left), m.

        Same as ``cv2.aruco.CharucoBoard.getObjPoints()``.
        """
        offset = 0.5 * (self.square - self.marker)
        tl = self.marker_squares.astype(np.float64) * self.square + offset
        d = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]) * self.marker
        xy = tl[:, None, :] + d[None, :, :]
        return np.concatenate([xy, np.zeros(xy.shape[:2] + (1,))], axis=-1)

    def to_spec(self) -> dict:
        """Cell-spec entry ``{type: charuco, squares_x, squares_y, square, marker, dictionary, legacy}``."""
        return {"type": self.type, **asdict(self)}


@dataclass(frozen=True)
class CircleGrid:
    """Grid of filled black circles on white, OpenCV ``findCirclesGrid`` semantics.

    Attributes:
        cols: circles per row (OpenCV ``patternSize[0]``).
        rows: rows of circles (OpenCV ``patternSize[1]``).
        spacing: symmetric: distance between neighbouring centres, m. Asymmetric: the vertical
            distance between consecutive rows, which is also their horizontal offset; centres in one
            row are ``2 * spacing`` apart (OpenCV's ``squareSize`` for ``ASYMMETRIC_GRID``).
        asymmetric: OpenCV's asymmetric (staggered) grid; ``rows`` must then be odd.
        diameter: printed circle diameter, m (optional, default ``spacing / 2``, or ``0.4 spacing`` with an
            origin dot); only the texture uses it.
        origin_dot: a *modified* circle grid (ROS-Industrial's ``ModifiedCircleGridTarget``): the circle at
            this corner of the grid is printed larger (twice the diameter), which fixes the board's
            orientation: ``"top_left"`` (point 0), ``"top_right"`` (point ``cols - 1``), ``"bottom_left"``
            (point ``(rows - 1) * cols``) or ``"bottom_right"`` (the last point), the printed face seen with
            target x to the right and y down. A ROS-Industrial print (large dot at the bottom left, x along
            the bottom row, y up) is ``"bottom_left"``, and jcalib's point k is then its point k. Symmetric
            grids only (an asymmetric grid's layout already fixes its orientation). None: a plain grid.
    """

    cols: int
    rows: int
    spacing: float
    asymmetric: bool = False
    diameter: float | None = None
    origin_dot: str | None = None

    type = "circles"

    def __post_init__(self):
        object.__setattr__(self, "cols", _check_count("cols", self.cols, 2))
        object.__setattr__(self, "rows", _check_count("rows", self.rows, 2))
        object.__setattr__(self, "spacing", _check_length("spacing", self.spacing))
        if not isinstance(self.asymmetric, (bool, np.bool_)):
            raise BadInputError(f"target field 'asymmetric': got {self.asymmetric!r}, expected true or false")
        object.__setattr__(self, "asymmetric", bool(self.asymmetric))
        if self.asymmetric and self.rows % 2 == 0:
            # Such a grid looks the same turned by 180°, and findCirclesGrid (4.14) then numbers its
            # rows in an order that fits no rigid placement of the grid: refuse it up front.
            raise BadInputError(
                f"target field 'rows': got {self.rows} for an asymmetric circle grid, expected an odd "
                "number (e.g. cols=4, rows=11, as OpenCV's acircles pattern)"
            )
        if self.origin_dot is not None:
            if self.origin_dot not in ORIGIN_CORNERS:
                raise BadInputError(f"target field 'origin_dot': got {self.origin_dot!r}, expected one of "
                                    f"{list(ORIGIN_CORNERS)} (the grid corner with the larger dot)")
            if self.asymmetric:
                raise BadInputError("target field 'origin_dot': an asymmetric circle grid's layout already fixes its "
                                    "orientation; an origin dot is for symmetric grids (asymmetric: false)")
        if self.diameter is None:
            object.__setattr__(self, "diameter", (0.4 if self.origin_dot else 0.5) * self.spacing)
        d = _check_length("diameter", self.diameter)
        nearest = self.spacing * (math.sqrt(2.0) if self.asymmetric else 1.0)
        if d >= nearest:
            raise BadInputError(
                f"target field 'diameter': got {d!r} m, expected less than the centre distance {nearest!r} m"
            )
        if self.origin_dot and 1.5 * d >= self.spacing:  # the origin dot (2 d) must not touch its neighbours
            raise BadInputError(f"target field 'diameter': got {d!r} m; with an origin dot (twice the diameter) it "
                                f"must be below {self.spacing / 1.5:.6g} m (2/3 of the spacing)")
        object.__setattr__(self, "diameter", d)

    @property
    def origin_index(self) -> int | None:
        """The point index of the origin dot (None without one)."""
        if self.origin_dot is None:
            return None
        n = self.cols * self.rows
        return {"top_left": 0, "top_right": self.cols - 1, "bottom_left": n - self.cols, "bottom_right": n - 1}[self.origin_dot]

    @property
    def origin_diameter(self) -> float | None:
        """Diameter of the origin dot, m (twice :attr:`diameter`; None without one)."""
        return None if self.origin_dot is None else 2.0 * self.diameter

    @property
    def num_points(self) -> int:
        return self.cols * self.rows

    @property
    def grid_shape(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 circle centres, m, target frame, in OpenCV's order."""
        i, j = _grid(self.cols, self.rows)
        x = (2 * j + i % 2) if self.asymmetric else j
        return _points3(x * self.spacing, i * self.spacing)

    @property
    def ids(self) -> np.ndarray:
        return np.arange(self.num_points, dtype=np.int64)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the printed circles, m."""
        p = self.points
        r = 0.5 * (self.origin_diameter or self.diameter)  # the origin dot (a corner) reaches furthest
        return (float(p[:, 0].min()) - r, float(p[:, 1].min()) - r, float(p[:, 0].max()) + r, float(p[:, 1].max()) + r)

    def to_spec(self) -> dict:
        """Cell-spec entry ``{type: circles, cols, rows, spacing, asymmetric, diameter[, origin_dot]}``."""
        spec = {"type": self.type, **asdict(self)}
        if spec["origin_dot"] is None:
            del spec["origin_dot"]
        return spec


Target = Union[Checkerboard, Charuco, CircleGrid, AprilGrid, AprilTag]

_SPEC_FIELDS: dict[str, tuple[type, tuple[str, ...], tuple[str, ...]]] = {
    "checkerboard": (Checkerboard, ("cols", "rows", "square"), ()),
    "charuco": (Charuco, ("squares_x", "squares_y", "square", "marker"), ("dictionary", "legacy")),
    "circles": (CircleGrid, ("cols", "rows", "spacing"), ("asymmetric", "diameter", "origin_dot")),
    # AprilTag targets: jcalib.geometry.apriltags
    "aprilgrid": (AprilGrid, ("cols", "rows", "tag_size", "tag_spacing"), ("family",)),
    "apriltag": (AprilTag, ("id", "size"), ("family", "border_bits")),
}
# Keys a cell-spec target entry may carry that are not geometry (used by the cell, not here).
_NON_GEOMETRY_KEYS = {"type", "mount", "pose"}


def target_from_spec(spec: dict) -> Target:
    """Build a target from a cell-spec entry (see docs/design.md), e.g. ``{type: checkerboard, ...}``.

    Args:
        spec: mapping with ``type`` (``checkerboard``, ``charuco``, ``circles``, ``aprilgrid`` or
            ``apriltag``) and the fields of
            that target (lengths in metres). ``mount`` and ``pose`` are allowed and ignored.

    Raises:
        BadInputError: unknown type, a missing, unknown or non-positive field (the message names it).
    """
    if not isinstance(spec, dict):
        raise BadInputError(f"target spec: got {type(spec).__name__} {spec!r}, expected a mapping")
    kind = spec.get("type")
    if kind not in _SPEC_FIELDS:
        raise BadInputError(f"target spec key 'type': got {kind!r}, expected one of {sorted(_SPEC_FIELDS)}")
    cls, required, optional = _SPEC_FIELDS[kind]
    for key in required:
        if key not in spec:
            raise BadInputError(f"target spec ({kind}): missing key {key!r}; required keys are {list(required)}")
    unknown = set(spec) - set(required) - set(optional) - _NON_GEOMETRY_KEYS
    if unknown:
        raise BadInputError(
            f"target spec ({kind}): unknown key(s) {sorted(unknown)}; allowed are {list(required + optional)}"
        )
    return cls(**{k: spec[k] for k in required + optional if k in spec and spec[k] is not None})


def warp_bow(points: np.ndarray, all_points: np.ndarray) -> np.ndarray:
    """``(n, 2)`` ``(1 − xr², 1 − yr²)`` of target ``points (n, 3)``: the shape functions of a board's
    warp (mrcal's parabolic ``calobject_warp``), ``z = c0 (1 − xr²) + c1 (1 − yr²)`` in the target frame.

    ``xr, yr`` are the points' x, y normalised to ``[−1, 1]`` over the extent of the target's
    ``all_points (N, 3)`` (for a grid board: its first and last corner, as mrcal). A direction without
    extent gets 0 (no warp along it).
    """
    points, all_points = np.asarray(points, np.float64), np.asarray(all_points, np.float64)
    lo, hi = all_points[:, :2].min(axis=0), all_points[:, :2].max(axis=0)
    span = hi - lo
    ok = span > 0.0
    r = np.where(ok, 2.0 * (points[:, :2] - lo) / np.where(ok, span, 1.0) - 1.0, 1.0)
    return 1.0 - r * r


def warped_points(points: np.ndarray, warp) -> np.ndarray:
    """``(N, 3)`` a target's ``points`` on a board bent by ``warp = (c0, c1)`` m (:func:`warp_bow`)."""
    points = np.asarray(points, np.float64)
    out = points.copy()
    out[:, 2] += warp_bow(points, points) @ np.asarray(warp, np.float64)
    return out
