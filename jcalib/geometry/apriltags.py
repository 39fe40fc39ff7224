"""AprilTag targets: Kalibr's AprilGrid and a single AprilTag (geometry, numpy only).

**The printed tags.** A tag is the official AprilTag image of its family and id (the images of
``AprilRobotics/apriltag-imgs``; with OpenCV 4.x's ``cv2.aruco.DICT_APRILTAG_*`` dictionaries, whose
marker images are the official ones turned by 180°, measured for tag16h5, tag25h9 and tag36h11
against the families' published codes). Its size is the side of the outer black square (the black
border included). "Bottom", "left" etc. refer to the tag as the official image shows it (and as
Kalibr prints it).

**Frames.** Like every jcalib target (:mod:`jcalib.geometry.targets`): ``z = 0`` on the printed face,
``x`` to the right and ``y`` down when the face is looked at, ``z`` into the board (the printed face
is the target's ``-z`` side, the side the renderer and planners show to a camera).

- :class:`AprilTag` (one tag; ViSP's hand-eye tutorials, lab cells): origin at the tag's centre. This
  is the frame of the AprilTag library's pose estimate (x right, y down, z into the tag), so a
  ``T_cam_target`` compares with its ``pose_t / pose_R`` (and ViSP's ``cMo``) directly.
- :class:`AprilGrid` (Kalibr's ``kalibr_create_target_pdf --type apriltag``): tag 0 at the bottom left,
  tag ids along the rows (``+x``) and then upwards; each tag ``tag_size`` wide with a 2-bit black border,
  ``tag_spacing * tag_size`` of white between neighbouring tags and a black square of that side at
  every gap crossing (and at the grid's outer corners), which makes every tag corner an X-junction.
  The origin is Kalibr's: the bottom-left corner of tag 0. Kalibr's target frame has ``y`` up and ``z``
  out of the print; jcalib's is that frame turned by 180° about ``x``: a point ``(x, y, z)`` here is
  Kalibr's ``(x, -y, -z)``, and ``T_cam_target_kalibr = T_cam_target @ diag(1, -1, -1, 1)``. Tag rows
  therefore go up along ``-y``.

**Points.** Point ``4 * tag_id + corner`` (grid) or ``corner`` (single tag), corners in the AprilTag
library's and Kalibr's order: 0 bottom left, 1 bottom right, 2 top right, 3 top left of the printed
tag. On a grid with ``cols`` tags per row, tag ``t`` sits in column ``t % cols`` and row ``t // cols``
(from the bottom); its bottom-left corner is at ``x = col * (1 + tag_spacing) * tag_size``,
``y = -row * (1 + tag_spacing) * tag_size``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from jcalib.errors import BadInputError

__all__ = ["APRILTAG_FAMILIES", "AprilGrid", "AprilTag"]

#: AprilTag families jcalib draws and detects: name -> (OpenCV dictionary, data bits per side, number
#: of tags). Their orientation against OpenCV's marker images is pinned by a test (the published codes).
APRILTAG_FAMILIES: dict[str, tuple[str, int, int]] = {
    "tag16h5": ("DICT_APRILTAG_16h5", 4, 30),
    "tag25h9": ("DICT_APRILTAG_25h9", 5, 35),
    "tag36h11": ("DICT_APRILTAG_36h11", 6, 587),
}
#: A tag's corners in tag units (x right, y down, origin at the bottom-left corner), in point order:
#: bottom left, bottom right, top right, top left.
_UNIT_CORNERS = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, -1.0], [0.0, -1.0]])


def _integer(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise BadInputError(f"target field {name!r}: got {value!r}, expected an integer >= {minimum}")
    return int(value)


def _positive(name: str, value: Any, what: str = "a positive length in metres") -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise BadInputError(f"target field {name!r}: got {value!r}, expected {what}")
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise BadInputError(f"target field {name!r}: got {value!r}, expected {what}")
    return v


def _family(value: Any) -> str:
    if value not in APRILTAG_FAMILIES:
        raise BadInputError(f"target field 'family': got {value!r}, expected one of {sorted(APRILTAG_FAMILIES)}")
    return str(value)


def _points3(xy: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return np.column_stack([xy, np.zeros(len(xy))])


@dataclass(frozen=True)
class AprilGrid:
    """Kalibr's AprilGrid (module docstring): ``cols x rows`` tags of one family.

    Attributes:
        cols: tags per row (Kalibr's ``tagCols``), along target x.
        rows: tag rows (Kalibr's ``tagRows``), upwards (target -y).
        tag_size: side of a tag's outer black square, m (Kalibr's ``tagSize``).
        tag_spacing: white gap between neighbouring tags over ``tag_size`` (Kalibr's ``tagSpacing``),
            in (0, 1]; it is also the side of the black squares at the gap crossings, over ``tag_size``.
        family: AprilTag family (:data:`APRILTAG_FAMILIES`); Kalibr's grids are ``tag36h11``.
    """

    cols: int
    rows: int
    tag_size: float
    tag_spacing: float
    family: str = "tag36h11"

    type = "aprilgrid"
    #: black border of every tag, in bits (Kalibr prints 2)
    border_bits = 2

    def __post_init__(self):
        object.__setattr__(self, "cols", _integer("cols", self.cols, 1))
        object.__setattr__(self, "rows", _integer("rows", self.rows, 1))
        object.__setattr__(self, "tag_size", _positive("tag_size", self.tag_size))
        s = _positive("tag_spacing", self.tag_spacing, "the gap over the tag size, in (0, 1]")
        if s > 1.0:
            raise BadInputError(f"target field 'tag_spacing': got {self.tag_spacing!r}, expected the gap over the "
                                "tag size, in (0, 1] (Kalibr's tagSpacing, e.g. 0.3)")
        object.__setattr__(self, "tag_spacing", s)
        object.__setattr__(self, "family", _family(self.family))
        available = APRILTAG_FAMILIES[self.family][2]
        if self.num_tags > available:
            raise BadInputError(f"target field 'family': {self.family} has {available} tags, the {self.cols}x{self.rows} "
                                f"grid needs {self.num_tags}")

    @property
    def num_tags(self) -> int:
        return self.cols * self.rows

    @property
    def num_points(self) -> int:
        return 4 * self.num_tags

    @property
    def tag_ids(self) -> np.ndarray:
        """(M,) int64 the grid's tag ids, ``0..M-1``."""
        return np.arange(self.num_tags, dtype=np.int64)

    @property
    def pitch(self) -> float:
        """Distance between neighbouring tags' corners of the same kind, m: ``(1 + tag_spacing) * tag_size``."""
        return (1.0 + self.tag_spacing) * self.tag_size

    @property
    def gap(self) -> float:
        """White gap between neighbouring tags (and side of the crossing squares), m."""
        return self.tag_spacing * self.tag_size

    @property
    def tag_origins(self) -> np.ndarray:
        """(M, 2) float64 bottom-left corner (x, y) of each tag, m."""
        row, col = np.divmod(self.tag_ids, self.cols)
        return np.stack([col * self.pitch, -row * self.pitch], axis=-1).astype(np.float64)

    @property
    def tag_corners(self) -> np.ndarray:
        """(M, 4, 3) float64 corners of each tag in point order (bottom left, bottom right, top right,
        top left), m."""
        xy = self.tag_origins[:, None, :] + self.tag_size * _UNIT_CORNERS[None]
        return np.concatenate([xy, np.zeros(xy.shape[:2] + (1,))], axis=-1)

    @property
    def points(self) -> np.ndarray:
        """(4M, 3) float64 tag corners, m; row ``4 * tag_id + corner``."""
        return self.tag_corners.reshape(-1, 3)

    @property
    def ids(self) -> np.ndarray:
        return np.arange(self.num_points, dtype=np.int64)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the print, crossing squares at the outer corners included, m."""
        g = self.gap
        width = self.cols * self.tag_size + (self.cols - 1) * g
        height = self.rows * self.tag_size + (self.rows - 1) * g
        return (-g, -height - g, width + g, g)

    def to_spec(self) -> dict:
        """Cell-spec entry ``{type: aprilgrid, cols, rows, tag_size, tag_spacing, family}``."""
        return {"type": self.type, "cols": self.cols, "rows": self.rows, "tag_size": self.tag_size,
                "tag_spacing": self.tag_spacing, "family": self.family}


@dataclass(frozen=True)
class AprilTag:
    """One AprilTag (module docstring): 4 points, the outer corners of its black border.

    Attributes:
        id: the tag's id in its family.
        size: side of the outer black square, m (the AprilTag library's ``tag_size``).
        family: AprilTag family (:data:`APRILTAG_FAMILIES`).
        border_bits: width of the black border in bits: 1 for the official images, 2 for Kalibr-style tags.
    """

    id: int
    size: float
    family: str = "tag36h11"
    border_bits: int = 1

    type = "apriltag"

    def __post_init__(self):
        object.__setattr__(self, "family", _family(self.family))
        object.__setattr__(self, "id", _integer("id", self.id, 0))
        available = APRILTAG_FAMILIES[self.family][2]
        if self.id >= available:
            raise BadInputError(f"target field 'id': got {self.id}, {self.family} has ids 0..{available - 1}")
        object.__setattr__(self, "size", _positive("size", self.size))
        if isinstance(self.border_bits, bool) or self.border_bits not in (1, 2):
            raise BadInputError(f"target field 'border_bits': got {self.border_bits!r}, expected 1 (official tags) "
                                "or 2 (Kalibr-style tags)")
        object.__setattr__(self, "border_bits", int(self.border_bits))

    @property
    def num_points(self) -> int:
        return 4

    @property
    def num_tags(self) -> int:
        return 1

    @property
    def tag_ids(self) -> np.ndarray:
        return np.array([self.id], dtype=np.int64)

    @property
    def tag_size(self) -> float:
        return self.size

    @property
    def tag_corners(self) -> np.ndarray:
        """(1, 4, 3) float64 the corners in point order, m."""
        xy = self.size * (_UNIT_CORNERS + [-0.5, 0.5])
        return _points3(xy)[None]

    @property
    def points(self) -> np.ndarray:
        """(4, 3) float64 corners (bottom left, bottom right, top right, top left), m, origin at the centre."""
        return self.tag_corners[0]

    @property
    def ids(self) -> np.ndarray:
        return np.arange(4, dtype=np.int64)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        h = 0.5 * self.size
        return (-h, -h, h, h)

    def to_spec(self) -> dict:
        """Cell-spec entry ``{type: apriltag, id, size, family, border_bits}``."""
        return {"type": self.type, "id": self.id, "size": self.size, "family": self.family,
                "border_bits": self.border_bits}
