"""Flat textures of calibration targets, the input of the renderer (contract shared by sim and vision).

A texture is an image of the target's printed face. Target-frame point ``(x, y, 0)`` (metres) lies at
texture pixel ``u = (x - origin_m[0]) / metres_per_pixel``, ``v = (y - origin_m[1]) / metres_per_pixel``
(pixel centres at integer coordinates, OpenCV convention). Outside the texture is white paper.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TargetTexture:
    """Printed face of a target.

    Attributes:
        image: (H, W) float64 reflectance in [0, 1] (0 black ink, 1 white paper).
        metres_per_pixel: texture resolution, m.
        origin_m: (2,) target-frame (x, y) of the centre of texture pixel (0, 0), m.
    """

    image: np.ndarray
    metres_per_pixel: float
    origin_m: np.ndarray


def target_texture(target, metres_per_pixel: float, margin_m: float | None = None) -> TargetTexture:
    """Render the printed face of a calibration target, anti-aliased by exact area coverage.

    Every texture pixel holds the exact fraction of its square footprint covered by white paper
    (box filter), so an edge or a circle lies where the geometry puts it to floating-point accuracy:
    chessboard squares and marker bits are axis-aligned rectangles (separable overlaps), circles use
    the closed-form area of a disc inside a rectangle.

    Args:
        target: a :mod:`jcalib.geometry.targets` target (``Checkerboard``, ``Charuco``, ``CircleGrid``,
            ``AprilGrid`` or ``AprilTag``). The chessboard's outer square next to point 0 is black; a
            ChArUco board is drawn as ``cv2.aruco.CharucoBoard.generateImage`` draws it (markers with a
            1-bit black border); AprilTags as their official images (Kalibr's print for a grid: 2-bit
            borders and black squares at the gap crossings; :mod:`jcalib.geometry.apriltags`).
        metres_per_pixel: texture resolution, m per pixel (> 0).
        margin_m: white border around the pattern, m (>= 0). Default: one square (chessboards), one
            spacing (circle grids), one gap (AprilGrid) or two bits (AprilTag), the quiet zone detectors want.

    Returns:
        :class:`TargetTexture` whose pixel ``(u, v)`` centre is target point
        ``origin_m + metres_per_pixel * (u, v)``; the pattern's outer edges fall on pixel boundaries
        when ``margin_m`` and the pattern size are multiples of ``metres_per_pixel``.

    Raises:
        BadInputError: non-positive resolution, negative margin, an image over 100 megapixels, or an
            object that is not a target.
    """
    from jcalib.errors import BadInputError
    from jcalib.geometry.targets import AprilGrid, AprilTag, Charuco, Checkerboard, CircleGrid

    if not isinstance(target, (Checkerboard, Charuco, CircleGrid, AprilGrid, AprilTag)):
        raise BadInputError(f"target_texture: argument 'target' got {type(target).__name__}, expected a target")
    mpp = float(metres_per_pixel)
    if not (np.isfinite(mpp) and mpp > 0.0):
        raise BadInputError(f"target_texture: 'metres_per_pixel' got {metres_per_pixel!r}, expected > 0")
    if margin_m is None:
        if isinstance(target, AprilGrid):
            margin_m = target.gap
        elif isinstance(target, AprilTag):
            margin_m = 2.0 * target.size / (APRILTAG_BITS[target.family] + 2 * target.border_bits)
        else:
            margin_m = target.spacing if isinstance(target, CircleGrid) else target.square
    margin = float(margin_m)
    if not (np.isfinite(margin) and margin >= 0.0):
        raise BadInputError(f"target_texture: 'margin_m' got {margin_m!r}, expected >= 0")

    x_min, y_min, x_max, y_max = target.extent_m
    x0, y0 = x_min - margin, y_min - margin
    # Round the size so that an extent that is a multiple of the resolution is not padded by a pixel.
    width = int(np.ceil((x_max + margin - x0) / mpp - 1e-9))
    height = int(np.ceil((y_max + margin - y0) / mpp - 1e-9))
    if width * height > 100_000_000:
        raise BadInputError(
            f"target_texture: {width}x{height} pixels at metres_per_pixel={mpp!r}; expected at most "
            "100 megapixels (use a coarser resolution)"
        )
    # Pixel u covers [x0 + u * mpp, x0 + (u + 1) * mpp]; work in pixel units from (x0, y0).
    ink = np.zeros((height, width), dtype=np.float64)

    def to_px(x, y):
        return (x - x0) / mpp, (y - y0) / mpp

    if isinstance(target, CircleGrid):
        r = 0.5 * target.diameter / mpp
        for k, (cx, cy) in enumerate(zip(*to_px(target.points[:, 0], target.points[:, 1]))):
            _add_disc(ink, cx, cy, r if k != target.origin_index else 0.5 * target.origin_diameter / mpp)
    else:
        rects = _tag_rectangles(target) if isinstance(target, (AprilGrid, AprilTag)) else _black_rectangles(target)
        for rx0, ry0, rx1, ry1 in rects:
            (a0, b0), (a1, b1) = to_px(rx0, ry0), to_px(rx1, ry1)
            _add_rectangle(ink, a0, b0, a1, b1)
    image = np.clip(1.0 - ink, 0.0, 1.0)
    return TargetTexture(image=image, metres_per_pixel=mpp, origin_m=np.array([x0 + 0.5 * mpp, y0 + 0.5 * mpp]))


def _black_rectangles(target) -> list[tuple[float, float, float, float]]:
    """Disjoint black axis-aligned rectangles (x0, y0, x1, y1), m, of a chessboard or ChArUco board."""
    from jcalib.geometry.targets import Checkerboard

    s = target.square
    rects = []
    if isinstance(target, Checkerboard):
        for b in range(target.rows + 1):
            for a in range(target.cols + 1):
                if (a + b) % 2 == 0:
                    rects.append(((a - 1) * s, (b - 1) * s, a * s, (b - 1) * s + s))
        return rects
    # ChArUco: black squares, then the black cells of each marker (border included).
    for y in range(target.squares_y):
        for x in range(target.squares_x):
            if ((x + y) % 2 == 0) == target.first_square_black:
                rects.append((x * s, y * s, (x + 1) * s, (y + 1) * s))
    bits = _marker_bits(target.dictionary, target.num_markers)
    n = bits.shape[1]
    cell = target.marker / n
    for m, corners in enumerate(target.marker_corners):
        mx, my = corners[0, 0], corners[0, 1]
        for i in range(n):
            row = bits[m, i]
            j = 0
            while j < n:  # merge runs of black cells in a row into one rectangle
                if row[j]:
                    k = j
                    while k < n and row[k]:
                        k += 1
                    rects.append((mx + j * cell, my + i * cell, mx + k * cell, my + (i + 1) * cell))
                    j = k
                else:
                    j += 1
    return rects


#: Data bits per side of each AprilTag family.
APRILTAG_BITS = {"tag16h5": 4, "tag25h9": 5, "tag36h11": 6}


def apriltag_image(family: str, tag_id: int, border_bits: int) -> np.ndarray:
    """``(n, n)`` bool, True where the official image of AprilTag ``tag_id`` is black, one cell per bit
    (``n = bits + 2 * border_bits``, rows from the top of the printed tag): OpenCV 4.x's marker image of
    ``DICT_APRILTAG_<family>`` turned by 180° (:mod:`jcalib.geometry.apriltags`)."""
    import cv2

    from jcalib.geometry.apriltags import APRILTAG_FAMILIES

    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, APRILTAG_FAMILIES[family][0]))
    n = d.markerSize + 2 * border_bits
    return np.rot90(d.generateImageMarker(int(tag_id), n, borderBits=border_bits) < 128, 2)


def _tag_rectangles(target) -> list[tuple[float, float, float, float]]:
    """Disjoint black rectangles (x0, y0, x1, y1), m, of an AprilGrid or AprilTag: each tag's cells
    (runs of black cells per row merged), and a grid's squares at the gap crossings."""
    from jcalib.geometry.targets import AprilGrid

    border = target.border_bits
    rects = []
    for tag_id, corners in zip(target.tag_ids, target.tag_corners):
        cells = apriltag_image(target.family, int(tag_id), border)
        n = cells.shape[0]
        cell = target.tag_size / n
        x0, y0 = corners[:, 0].min(), corners[:, 1].min()  # top-left corner of the printed tag
        for i in range(n):
            j = 0
            while j < n:
                if cells[i, j]:
                    k = j
                    while k < n and cells[i, k]:
                        k += 1
                    rects.append((x0 + j * cell, y0 + i * cell, x0 + k * cell, y0 + (i + 1) * cell))
                    j = k
                else:
                    j += 1
    if isinstance(target, AprilGrid):
        g, p = target.gap, target.pitch
        for r in range(target.rows + 1):  # crossing squares: below row r's tags (r = rows: above the top row)
            for c in range(target.cols + 1):
                x, y = c * p - g, -r * p + g  # the square's bottom-left corner (Kalibr's print)
                rects.append((x, y - g, x + g, y))
    return rects


def _marker_bits(dictionary: str, count: int) -> np.ndarray:
    """(count, n, n) bool: True where marker ``m`` of an OpenCV dictionary is black (1-bit border)."""
    import cv2

    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = d.markerSize + 2
    return np.stack([d.generateImageMarker(m, n, borderBits=1) < 128 for m in range(count)])


def _add_rectangle(ink: np.ndarray, a0: float, b0: float, a1: float, b1: float) -> None:
    """Add the exact coverage of the rectangle [a0, a1] x [b0, b1] (pixel-edge units) to ``ink``."""
    h, w = ink.shape
    u0, u1 = max(int(np.floor(a0)), 0), min(int(np.ceil(a1)), w)
    v0, v1 = max(int(np.floor(b0)), 0), min(int(np.ceil(b1)), h)
    if u1 <= u0 or v1 <= v0:
        return
    u = np.arange(u0, u1, dtype=np.float64)
    v = np.arange(v0, v1, dtype=np.float64)
    cx = np.clip(np.minimum(u + 1.0, a1) - np.maximum(u, a0), 0.0, 1.0)
    cy = np.clip(np.minimum(v + 1.0, b1) - np.maximum(v, b0), 0.0, 1.0)
    ink[v0:v1, u0:u1] += cy[:, None] * cx[None, :]


def _disc_quadrant_area(a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """Area of the disc of radius r at the origin intersected with {x < a, y < b} (closed form)."""

    def f(x):  # antiderivative of sqrt(r^2 - x^2), well conditioned near x = +-r (atan2, not asin)
        x = np.clip(x, -r, r)
        h = np.sqrt(np.maximum((r - x) * (r + x), 0.0))
        return 0.5 * (x * h + r * r * np.arctan2(x, h))

    a = np.clip(a, -r, r)
    xb = np.sqrt(np.maximum((r - b) * (r + b), 0.0))  # where the chord y = b meets the circle
    ac = np.clip(a, -xb, xb)
    middle = np.where(np.abs(b) < r, b * (ac + xb) + f(ac) - f(-xb), 0.0)
    outer = 2.0 * (f(np.minimum(a, -xb)) - f(-r)) + 2.0 * (f(np.maximum(a, xb)) - f(xb))
    return middle + np.where(b >= 0.0, outer, 0.0)


def _add_disc(ink: np.ndarray, cx: float, cy: float, r: float) -> None:
    """Add the exact coverage of the disc (centre (cx, cy), radius r; pixel-edge units) to ``ink``."""
    h, w = ink.shape
    u0, u1 = max(int(np.floor(cx - r)), 0), min(int(np.ceil(cx + r)), w)
    v0, v1 = max(int(np.floor(cy - r)), 0), min(int(np.ceil(cy + r)), h)
    if u1 <= u0 or v1 <= v0:
        return
    ex = np.arange(u0, u1 + 1, dtype=np.float64) - cx  # pixel edges relative to the centre
    ey = np.arange(v0, v1 + 1, dtype=np.float64) - cy
    q = _disc_quadrant_area(ex[None, :], ey[:, None], r)
    ink[v0:v1, u0:u1] += q[1:, 1:] - q[:-1, 1:] - q[1:, :-1] + q[:-1, :-1]
