"""AprilTag targets in images: Kalibr's AprilGrid and single tags (:mod:`jcalib.geometry.apriltags`).

Tags are found with OpenCV's ArUco module (its AprilTag dictionaries), and every candidate
quadrilateral is decoded by jcalib on the original image:

1. **Candidates.** ``cv2.aruco.ArucoDetector`` (black border of ``border_bits``) runs on the attempts
   of :data:`TAG_ATTEMPTS` (the image as it is, smoothed, with the dark regions shrunk by a pixel, ...)
   until every tag the found ones predict inside the image is found; its accepted markers and the
   quadrilaterals it rejected are candidates. On an AprilGrid every tag touches the black squares at
   its four corners, so a thresholded tag and its squares can form one blob whose outline is no
   quadrilateral (measured on rendered 5x4 grids: 1-6 of 20 tags found by the detector alone under the
   renderer's realistic noise and blur); shrinking the dark regions separates them, and the candidates
   are decoded on the original image, whose cells the shrinking would corrupt.
2. **Decoding.** A candidate is sampled on a grid of cells (means over each cell's inner pixels);
   Otsu's threshold between the cell means splits black from white (the two classes well apart), the
   border cells must be black, and the data bits are identified in the family's dictionary
   (``cv2.aruco.Dictionary.identify``, OpenCV's error correction) in the 4 rotations, which order the
   corners. Ids the target does not have are ignored (other tags, clutter); an id decoded at two
   places is dropped (a second copy of the tag in view); two reads of one tag keep the better.
3. **Board** (grids). Every tag must sit where its neighbours put it (:func:`_consistent_tags`, as
   :func:`jcalib.vision.validate.consistent_markers`: a wrong id or rotation is a tag away), and the
   missing neighbours of found tags are read where the board predicts them, as the tag expected there
   (with the family's full error correction: blurred small bits read grey), until none is added.
4. **Corners.** A tag's sides are fitted to sub-pixel edge points (:mod:`jcalib.vision.tag_edges`):
   the decoded corners of a grid's tags are 1-4 px off (measured on rendered grids: the outline bends
   into the crossing squares; OpenCV's own corners likewise), a large single tag's half a cell. On a
   grid every tag corner is an X-junction (the tag and a crossing square meet there, white gaps on the
   other two sides): from the edges' corner it is refined like a chessboard corner
   (:func:`jcalib.vision.chessboard.refine_corners`, ``cornerSubPix`` then a saddle-point fit) in
   windows inside the pure X around it (radius ``min(gap, 2 cells)``), which an ink spread or a
   blur leaves in place; where that fit strays from the edges' corner (strong noise) the edges' corner
   is kept. A single tag's corners are its edges' corners (L-junctions).
5. **Checks.** Only tags wholly in view (with room for the refinement windows) and with cells of at
   least 1.5 px give corners; a grid corner that its neighbour tags' corners do not predict
   (:func:`_consistent_corners`), or that cannot be checked (a grid tag found alone), is dropped.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.geometry.apriltags import APRILTAG_FAMILIES, AprilGrid
from jcalib.vision.chessboard import refine_corners
from jcalib.vision.image import GrayImage
from jcalib.vision.tag_edges import refine_square_corners
from jcalib.vision.validate import MARKER_TOLERANCE

__all__ = ["OPENCV_TO_POINT", "TAG_ATTEMPTS", "TagAttempt", "TagsFound", "find_apriltags"]

#: Corner ``k`` of OpenCV's marker order (top left, top right, bottom right, bottom left of its marker
#: image) is tag corner ``OPENCV_TO_POINT[k]`` of :mod:`jcalib.geometry.apriltags` (bottom left, bottom
#: right, top right, top left of the official image, which is OpenCV's turned by 180°).
OPENCV_TO_POINT = np.array([1, 0, 3, 2])
#: Pixels per cell when a candidate is sampled for decoding.
_CELL_PX = 6
#: Largest fraction of a tag's border cells that may read white.
_MAX_BORDER_ERRORS = 0.15
#: OpenCV's error correction rate (``DetectorParameters.errorCorrectionRate``'s default).
_CORRECTION_RATE = 0.6
#: Smallest difference between the mean grey of a tag's dark and light cells, grey levels (0..255), and
#: (a candidate the board does not predict) in units of the classes' spreads: a quadrilateral a cell
#: off the tag's outline (an inner contour) reads mixed cells, and now and then a tag after correction.
_MIN_CONTRAST = 8.0
_MIN_SEPARATION = 2.0
#: Smallest cell (side of a tag over its cells) of a tag whose corners are measured, px, along its
#: shortest side: smaller cells decode by luck and their corners are off by a pixel (measured on rendered
#: grids seen at 70°).
_MIN_CELL_PX = 1.5
#: A grid corner is kept where its X-junction fit and its edges' corner agree within this, px; the kept
#: corner is the X-junction fit's. Each check alone lets wrong corners through (measured on rendered
#: grids, ``benchmarks/bench_apriltag.py``): an X-junction fit strays 1-2 px now and then, even on
#: clean views, and one that jumps to the next junction (a gap away) in a whole region at once fools
#: the neighbours' check; the edges' corner is off by 0.3 px (median) under the renderer's realistic
#: noise and by up to 0.7 px at 70° of tilt, where the X-junction fit is good to 0.02 px. Agreement
#: within 1 gap in 3 (up to 1.5 px) kept 10-58 corners more than 1 px off per 1152; within 0.5 px none,
#: at the price of a quarter of the corners under the realistic noise at 640x480.
_X_AGREE_PX = 0.5


@dataclass(frozen=True)
class TagAttempt:
    """One way of looking for tag candidates.

    Attributes:
        name: how detections refer to it.
        separate_px: radius of the grey dilation that shrinks dark regions (0 = none).
        smooth_sigma_px: Gaussian pre-smoothing, px (0 = none).
        wide_thresholds: wider adaptive-threshold windows (3-53 px) and looser candidate filters.
    """

    name: str
    separate_px: int = 0
    smooth_sigma_px: float = 0.0
    wide_thresholds: bool = False


#: Attempts, in order; the search stops when every tag the found ones predict inside the image is found.
TAG_ATTEMPTS = (
    TagAttempt("default"),
    TagAttempt("smooth", smooth_sigma_px=1.0),
    TagAttempt("separate", separate_px=1),
    TagAttempt("smooth+separate", separate_px=1, smooth_sigma_px=1.0),
    TagAttempt("wide+separate", separate_px=1, smooth_sigma_px=1.0, wide_thresholds=True),
    TagAttempt("smooth+separate_2px", separate_px=2, smooth_sigma_px=1.5),
)


@dataclass(frozen=True)
class TagsFound:
    """What :func:`find_apriltags` found.

    Attributes:
        point_index: (n,) int64 target point indices (``4 * tag_id + corner`` on a grid), ascending.
        pixels: (n, 2) float64 refined corners, px.
        raw_pixels: (n, 2) float64 the same corners before refinement (the decoded quadrilaterals'), px.
        tags: (m,) int64 ids of the tags kept.
        attempts: names of the attempts run, in order (``"board"``: tags decoded where the board
            predicts them).
        contributing: names of the attempts whose tags were kept.
        dropped_tags: tags decoded but left out (inconsistent with the board, a duplicate id, too close
            to the image border).
        dropped_corners: corners of kept tags left out (refinement failed or moved them too far, or
            they disagree with their neighbours).
    """

    point_index: np.ndarray
    pixels: np.ndarray
    raw_pixels: np.ndarray
    tags: np.ndarray
    attempts: tuple[str, ...]
    contributing: tuple[str, ...]
    dropped_tags: int = 0
    dropped_corners: int = 0


@functools.lru_cache(maxsize=8)
def _dictionary(family: str) -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, APRILTAG_FAMILIES[family][0]))


def _parameters(attempt: TagAttempt, border_bits: int) -> cv2.aruco.DetectorParameters:
    p = cv2.aruco.DetectorParameters()
    p.markerBorderBits = border_bits
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    p.minMarkerDistanceRate = 0.01  # near duplicates are sorted out after decoding
    if attempt.wide_thresholds:
        p.adaptiveThreshWinSizeMin = 3
        p.adaptiveThreshWinSizeMax = 53
        p.adaptiveThreshWinSizeStep = 10
        p.adaptiveThreshConstant = 5.0
        p.polygonalApproxAccuracyRate = 0.05
    return p


def _prepare(u8: np.ndarray, attempt: TagAttempt) -> np.ndarray:
    img = u8
    if attempt.smooth_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), attempt.smooth_sigma_px)
    if attempt.separate_px > 0:
        k = 2 * attempt.separate_px + 1
        img = cv2.dilate(img, np.ones((k, k), np.uint8))
    return np.ascontiguousarray(img)


def _clockwise(q: np.ndarray) -> np.ndarray:
    """The quadrilateral's corners in clockwise order on the image (y down), same first corner."""
    (a, b), (c, d) = q[2] - q[0], q[3] - q[1]
    return q if a * d - b * c > 0 else q[[0, 3, 2, 1]]


def _candidates(u8: np.ndarray, target, attempt: TagAttempt) -> list[np.ndarray]:
    """(4, 2) float64 quadrilaterals (clockwise) from OpenCV's marker detector on an attempt's image."""
    det = cv2.aruco.ArucoDetector(_dictionary(target.family), _parameters(attempt, target.border_bits))
    corners, _, rejected = det.detectMarkers(_prepare(u8, attempt))
    if not len(corners) + len(rejected):
        return []
    quads = np.concatenate([np.asarray(c, np.float64).reshape(-1, 4, 2) for c in list(corners) + list(rejected)])
    n = _dictionary(target.family).markerSize + 2 * target.border_bits
    keep = np.all(np.isfinite(quads), axis=(1, 2)) & (_side_px(quads) >= 2.0 * n)  # 2 px per cell at least
    return [_clockwise(q) for q in quads[keep]]


def _decode(f32: np.ndarray, quad: np.ndarray, target, expect: int | None = None) -> tuple[int, np.ndarray, int] | None:
    """Read a clockwise quadrilateral as a tag: ``(id, (4, 2) corners in OpenCV's order, bit errors)``
    or None (no tag: no dark border, no contrast, bits of no tag of the family).

    With ``expect`` (a tag the board predicts there, corners in OpenCV's order) only that tag in that
    rotation is read, with the family's full error correction (half its minimum distance, where
    OpenCV's default corrects 60 % of that): a blurred tag's isolated bits read grey."""
    d = _dictionary(target.family)
    bits, border = d.markerSize, target.border_bits
    n = bits + 2 * border
    size = n * _CELL_PX
    # corners are pixel-centre coordinates of the outer corners: the patch's outer pixel edges
    dst = np.array([[-0.5, -0.5], [size - 0.5, -0.5], [size - 0.5, size - 0.5], [-0.5, size - 0.5]], np.float32)
    H = cv2.getPerspectiveTransform(dst, quad.astype(np.float32))
    patch = cv2.warpPerspective(f32, H, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
    cells = patch.reshape(n, _CELL_PX, n, _CELL_PX)[:, 1:-1, :, 1:-1].mean(axis=(1, 3))
    v = np.sort(cells.ravel())
    # Otsu's split between the sorted cell means
    k = np.arange(1, v.size)
    c0 = np.cumsum(v)[:-1]
    between = (c0 / k - (v.sum() - c0) / (v.size - k)) ** 2 * k * (v.size - k)
    split = int(np.argmax(between)) + 1
    dark, light = v[:split], v[split:]
    spread = 0.0 if expect is not None else _MIN_SEPARATION * (dark.std() + light.std())
    if light.mean() - dark.mean() < max(_MIN_CONTRAST, spread):
        return None
    white = cells > 0.5 * (dark[-1] + light[0])
    ring = np.ones((n, n), bool)
    ring[border:-border, border:-border] = False
    if np.sum(white & ring) > _MAX_BORDER_ERRORS * np.sum(ring):
        return None
    data = white[border:-border, border:-border].astype(np.uint8)
    if expect is not None:
        errors = int(d.getDistanceToId(data, int(expect), False))
        return (int(expect), quad, errors) if errors <= d.maxCorrectionBits else None
    ok, idx, rotation = d.identify(data, _CORRECTION_RATE)
    if not ok:
        return None
    errors = int(d.getDistanceToId(data, int(idx), True))
    corners = quad[(np.arange(4) - int(rotation)) % 4]
    return int(idx), corners, errors


def _tag_xy(target, tag_ids) -> np.ndarray:
    """(M, 4, 2) board (x, y) of the tags' corners in point order, m."""
    k = np.searchsorted(target.tag_ids, np.asarray(tag_ids, np.int64))
    return target.tag_corners[k][:, :, :2]


def _homographies(src: np.ndarray, dst: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(B, 3, 3) homographies mapping ``src`` to ``dst`` ((B, K, 2) each) fitted to the points where
    ``use`` (B, K) holds (a DLT per batch member, in normalised coordinates); NaN where fewer than 4."""
    w = use.astype(np.float64)
    n = np.maximum(w.sum(axis=1), 1.0)[:, None]

    def normalise(p):
        c = (p * w[..., None]).sum(axis=1) / n
        r = np.sqrt(((p - c[:, None]) ** 2).sum(axis=-1) * w).sum(axis=1) / n[:, 0]
        s = np.sqrt(2.0) / np.maximum(r, 1e-12)
        T = np.zeros((len(p), 3, 3))
        T[:, 0, 0] = T[:, 1, 1] = s
        T[:, :2, 2] = -s[:, None] * c
        T[:, 2, 2] = 1.0
        return (p - c[:, None]) * s[:, None, None], T

    (x, Ts), (u, Td) = normalise(src), normalise(dst)
    one, zero = np.ones_like(x[..., 0]), np.zeros_like(x[..., 0])
    X, Y, U, V = x[..., 0], x[..., 1], u[..., 0], u[..., 1]
    ru = np.stack([X, Y, one, zero, zero, zero, -U * X, -U * Y, -U], axis=-1)
    rv = np.stack([zero, zero, zero, X, Y, one, -V * X, -V * Y, -V], axis=-1)
    A = np.concatenate([ru, rv], axis=1) * np.concatenate([w, w], axis=1)[..., None]
    h = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)[1][..., 0].reshape(-1, 3, 3)
    H = np.linalg.inv(Td) @ h @ Ts
    H[use.sum(axis=1) < 4] = np.nan
    return H


def _project(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(B, K, 2) points ``xy`` (B, K, 2) through homographies H (B, 3, 3)."""
    p = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1) @ np.swapaxes(H, 1, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[..., :2] / p[..., 2:]


def _consistent_tags(xy: np.ndarray, px: np.ndarray, tolerance: float = MARKER_TOLERANCE) -> np.ndarray:
    """(M,) bool: tags (board corners ``xy``, image corners ``px``, (M, 4, 2) each) that the homography
    of the nearest (up to 4) other tags puts within ``tolerance`` tag sides: a wrong id or rotation is
    a tag away. The worst offender is dropped and the check repeated; dropped tags that the kept ones
    then predict are re-admitted (as :func:`jcalib.vision.validate.consistent_markers`, vectorised)."""
    m = len(xy)
    if m < 2:
        return np.zeros(m, bool)
    centres = xy.mean(axis=1)
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    near = np.argsort(d, axis=1)[:, :min(4, m - 1)]

    def errors(ok):
        use = np.repeat(ok[near], 4, axis=1)
        H = _homographies(xy[near].reshape(m, -1, 2), px[near].reshape(m, -1, 2), use)
        pred = _project(H, xy)
        err = np.max(np.linalg.norm(pred - px, axis=-1), axis=1) / np.maximum(_side_px(pred), 1e-9)
        return np.where(np.isfinite(err), err, np.inf)

    ok = np.ones(m, bool)
    while ok.sum() >= 2:
        err = np.where(ok, errors(ok), 0.0)
        worst = int(np.argmax(err))
        if not err[worst] > tolerance:
            back = ~ok & (errors(ok) <= tolerance)
            return ok | back
        ok[worst] = False
    return np.zeros(m, bool)


def _area(quad: np.ndarray) -> float:
    """Area of a quadrilateral (4, 2), px²."""
    x, y = quad[:, 0], quad[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def _side_px(quads: np.ndarray) -> np.ndarray:
    """(M,) mean side length of quadrilaterals (M, 4, 2), px."""
    return np.mean(np.linalg.norm(quads - np.roll(quads, 1, axis=-2), axis=-1), axis=-1)


class _Search:
    """The tags found so far in one image, their corners and what the search did."""

    def __init__(self, gray: GrayImage, target):
        self.gray, self.target = gray, target
        self.grid = isinstance(target, AprilGrid)
        self.quads: dict[int, np.ndarray] = {}  # id -> (4, 2) decoded corners, point order (raw)
        self.errors: dict[int, int] = {}  # id -> bit errors of the decoding kept
        self.fine: dict[int, np.ndarray] = {}  # id -> (4, 2) refined corners, point order
        self.ok: dict[int, np.ndarray] = {}  # id -> (4,) refined corner accepted
        self.room: dict[int, bool] = {}  # id -> wholly in view, with room for the refinement windows
        self.duplicates: set[int] = set()
        self.tried: list[str] = []
        self.contributing: list[str] = []
        self.dropped = 0

    def corners(self, ids) -> np.ndarray:
        """(M, 4, 2) the best corners known of tags ``ids`` (refined where accepted), point order."""
        return np.stack([np.where(self.ok[i][:, None], self.fine[i], self.quads[i]) for i in ids])

    def add(self, quads, name: str, expected: dict[int, np.ndarray] | None = None) -> None:
        """Decode quadrilaterals (clockwise; ``expected``: id -> quad in OpenCV's order, decoded there only
        as that id); refine and check the new tags."""
        wanted = {int(t) for t in self.target.tag_ids}
        new = set()
        if self.quads and len(quads):  # candidates where a tag is already known: skipped
            known = self.corners(sorted(self.quads))
            centres, sides = known.mean(axis=1), _side_px(known)
            at = np.stack([q.mean(axis=0) for q in quads])
            near = np.min(np.linalg.norm(at[:, None] - centres[None], axis=-1) / sides[None], axis=1) <= 0.35
            quads = [q for q, n in zip(quads, near) if not n]
        items = [(None, q) for q in quads] + [(t, q) for t, q in (expected or {}).items()]
        for want, q in items:
            r = _decode(self.gray.f32, q, self.target, expect=want)
            if r is None or r[0] not in wanted or r[0] in self.duplicates:
                continue
            tid, corners, errors = r
            raw = np.empty_like(corners)
            raw[OPENCV_TO_POINT] = corners
            if np.min(np.linalg.norm(raw - np.roll(raw, 1, axis=0), axis=1)) < _MIN_CELL_PX * _bit_cells(self.target):
                continue  # too small (or too foreshortened) to measure: cells under 1.5 px
            if tid in self.quads:
                old = self.quads[tid]
                if np.linalg.norm(old.mean(axis=0) - raw.mean(axis=0)) > 0.3 * _side_px(old[None])[0]:
                    self.duplicates.add(tid)  # the same tag at two places: trust neither
                    for d in (self.quads, self.errors, self.fine, self.ok, self.room):
                        d.pop(tid, None)
                    new.discard(tid)
                elif tid in new and (errors, -_area(raw)) < (self.errors[tid], -_area(old)):
                    # the same tag twice in this batch (an outline and an inner one, read with a bit error
                    # or two): the better read, then the larger outline, is the tag's
                    self.quads[tid], self.errors[tid] = raw, errors
                continue
            self.quads[tid], self.errors[tid] = raw, errors
            new.add(tid)
        if not new:
            return
        ids = np.array(sorted(new), np.int64)
        raw = np.stack([self.quads[int(i)] for i in ids])
        fine, ok, room = (_refine_x(self.gray, self.target, ids, raw) if self.grid
                          else _refine_l(self.gray, self.target, raw))
        for k, i in enumerate(ids):
            self.fine[int(i)], self.ok[int(i)], self.room[int(i)] = fine[k], ok[k], bool(room[k].all())
        bad = self.check_board()
        if any(int(i) in self.quads for i in ids):
            self.contributing.append(name)
        self.dropped += bad

    def check_board(self) -> int:
        """Drop tags inconsistent with their neighbours on the board (grids with >= 2 tags)."""
        if not self.grid or len(self.quads) < 2:
            return 0
        ids = sorted(self.quads)
        good = _consistent_tags(_tag_xy(self.target, ids), self.corners(ids))
        for i, keep in zip(ids, good):
            if not keep:
                for d in (self.quads, self.errors, self.fine, self.ok, self.room):
                    d.pop(i, None)
        return int(np.sum(~good))

    def predict(self, tag_ids: np.ndarray, margin: float = 0.5) -> dict[int, np.ndarray]:
        """Tags ``tag_ids`` as the nearest found tags (up to 4, local homography) put them: id -> (4, 2)
        corners in OpenCV's order, for those inside the image with ``margin`` tag sides to spare."""
        if not self.grid or not self.quads or len(tag_ids) == 0:
            return {}
        ids = np.array(sorted(self.quads), np.int64)
        xy, px = _tag_xy(self.target, ids), self.corners(ids)
        centres = xy.mean(axis=1)
        want = _tag_xy(self.target, tag_ids)
        near = np.argsort(np.linalg.norm(want.mean(axis=1)[:, None] - centres[None], axis=-1), axis=1)[:, :4]
        src, dst = xy[near].reshape(len(want), -1, 2), px[near].reshape(len(want), -1, 2)
        p = _project(_homographies(src, dst, np.ones(src.shape[:2], bool)), want)
        m = margin * _side_px(p)[:, None]
        w, h = self.gray.size
        inside = np.all(np.isfinite(p), axis=(1, 2)) & np.all(
            (p[..., 0] > m) & (p[..., 0] < w - 1 - m) & (p[..., 1] > m) & (p[..., 1] < h - 1 - m), axis=1)
        inv = np.argsort(OPENCV_TO_POINT)  # point order -> OpenCV's order
        return {int(t): p[k][inv] for k, t in enumerate(tag_ids) if inside[k]}

    def missing(self) -> np.ndarray:
        return np.array([t for t in self.target.tag_ids if int(t) not in self.quads and int(t) not in self.duplicates],
                        np.int64)

    def grow(self) -> None:
        """Decode the missing neighbours of found tags where the board predicts them, until none is added."""
        if not self.grid:
            return
        cols = self.target.cols
        tried: set[int] = set()
        while True:
            found = np.array(sorted(self.quads), np.int64)
            if len(found) == 0:
                return
            r, c = np.divmod(found, cols)
            ring = {int(rr * cols + cc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)
                    for rr, cc in zip(r + dr, c + dc) if 0 <= rr < self.target.rows and 0 <= cc < cols}
            todo = np.array(sorted(ring - {int(t) for t in found} - tried - self.duplicates), np.int64)
            if len(todo) == 0:
                return
            tried |= {int(t) for t in todo}
            before = len(self.quads)
            expected = self.predict(todo)
            if expected:
                self.add([], "board", expected)
            if len(self.quads) == before:
                return

    def complete(self) -> bool:
        """Whether every tag the found ones put inside the image is found (single tags: found)."""
        if not self.grid:
            return bool(self.quads)
        return bool(self.quads) and not self.predict(self.missing())


def find_apriltags(gray: GrayImage, target, *, retry: bool = True) -> TagsFound:
    """The corners of an AprilGrid's or an AprilTag's tags seen in an image (module docstring).

    Args:
        gray: the image.
        target: :class:`jcalib.geometry.apriltags.AprilGrid` or :class:`~jcalib.geometry.apriltags.AprilTag`.
        retry: run the further attempts of :data:`TAG_ATTEMPTS` while tags the found ones predict inside
            the image are missing (False: the default attempt and the board's predictions only).

    Returns:
        :class:`TagsFound`; ``point_index`` may be empty.
    """
    s = _Search(gray, target)
    for attempt in TAG_ATTEMPTS if retry else TAG_ATTEMPTS[:1]:
        s.tried.append(attempt.name)
        s.add(_candidates(gray.u8, target, attempt), attempt.name)
        s.grow()
        if s.complete():
            break
    return _result(s)


def _result(s: _Search) -> TagsFound:
    """The kept corners (step 5 of the module docstring)."""
    target = s.target
    ids = np.array([i for i in sorted(s.quads) if s.room[i]], np.int64)
    dropped = s.dropped + len(s.duplicates) + (len(s.quads) - len(ids))
    if len(ids) == 0:
        return TagsFound(np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), ids, tuple(s.tried),
                         tuple(dict.fromkeys(s.contributing)), dropped)
    fine = np.stack([s.fine[int(i)] for i in ids])
    raw = np.stack([s.quads[int(i)] for i in ids])
    ok = np.stack([s.ok[int(i)] for i in ids])
    if s.grid:
        ok &= _consistent_corners(target, ids, fine, ok)
        point_index = 4 * ids[:, None] + np.arange(4)[None, :]
    else:
        point_index = np.tile(np.arange(4, dtype=np.int64), (len(ids), 1))
    keep = ok.reshape(-1)
    point_index, pixels, raw = point_index.reshape(-1)[keep], fine.reshape(-1, 2)[keep], raw.reshape(-1, 2)[keep]
    order = np.argsort(point_index, kind="stable")
    return TagsFound(point_index[order], pixels[order], raw[order], ids, tuple(s.tried),
                     tuple(dict.fromkeys(s.contributing)), dropped, int(np.sum(~keep)))


#: A grid corner may miss the prediction of its neighbour tags' corners by this fraction of the local
#: gap width, and by at least :data:`MIN_CORNER_TOLERANCE_PX`: a corner that converged onto the next
#: X-junction is a gap away.
CORNER_TOLERANCE = 0.15
MIN_CORNER_TOLERANCE_PX = 1.0


def _consistent_corners(target: AprilGrid, ids: np.ndarray, fine: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(M, 4) bool: refined corners that the homography of the (up to 4) nearest other tags' accepted
    corners predicts within the tolerance; the worst offender is dropped and the check repeated. A
    corner that cannot be checked (a tag found alone) is not kept: an unverifiable detection is not
    accepted (as :mod:`jcalib.vision.validate`)."""
    ok = ok.copy()
    xy = _tag_xy(target, ids)
    centres = xy.mean(axis=1)
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    near = np.argsort(d, axis=1)[:, :4]
    near_ok = np.isfinite(np.take_along_axis(d, near, axis=1))
    gap = target.gap
    while True:
        use = (ok[near] & near_ok[..., None]).reshape(len(ids), -1)
        src, dst = xy[near].reshape(len(ids), -1, 2), fine[near].reshape(len(ids), -1, 2)
        H = _homographies(src, dst, use)
        pred = _project(H, xy)
        step = _project(H, xy + [gap, 0.0]) - pred, _project(H, xy + [0.0, gap]) - pred
        gap_px = np.minimum(np.linalg.norm(step[0], axis=-1), np.linalg.norm(step[1], axis=-1))
        err = np.linalg.norm(pred - fine, axis=-1) / np.maximum(CORNER_TOLERANCE * gap_px, MIN_CORNER_TOLERANCE_PX)
        err = np.where(ok, np.where(np.isfinite(err), err, np.inf), 0.0)  # unverifiable: dropped
        worst = np.unravel_index(int(np.argmax(err)), err.shape)
        if not err[worst] > 1.0:
            return ok
        ok[worst] = False


def _local_scale(target, tag_ids: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """(M, 4) image length per board length (px/m) at each corner, the smaller of the two board axes,
    from the homography of the corner's own tag (corners ``raw`` (M, 4, 2) in point order)."""
    xy = _tag_xy(target, tag_ids)
    H = _homographies(xy, raw, np.ones(raw.shape[:2], bool))
    d = 1e-3 * target.tag_size
    p0 = _project(H, xy)
    dx = np.linalg.norm(_project(H, xy + [d, 0.0]) - p0, axis=-1)
    dy = np.linalg.norm(_project(H, xy + [0.0, d]) - p0, axis=-1)
    return np.minimum(dx, dy) / d


def _bit_cells(target) -> int:
    """Cells along a tag's side (data bits and both borders)."""
    return APRILTAG_FAMILIES[target.family][1] + 2 * target.border_bits


def _bit_size(target) -> float:
    """Side of one cell of a tag, m."""
    return target.tag_size / (APRILTAG_FAMILIES[target.family][1] + 2 * target.border_bits)


def _refine_x(gray: GrayImage, target: AprilGrid, tag_ids: np.ndarray, raw: np.ndarray):
    """X-junction refinement of a grid's corners ``raw`` (M, 4, 2): ``(pixels (M, 4, 2), ok (M, 4),
    room (M, 4))``. Starts from the tags' edges (:func:`_refine_l`: the decoded corners of large tags are
    up to half a cell off), then ``refine_corners`` in crops of the image around the tags (the
    smoothing stays local). A corner is kept where the edges were fitted and the X-junction's fit agrees
    with the edges' corner (:data:`_X_AGREE_PX`): neither is trusted alone."""
    # the start: lines (less noisy than parabolas); the decoded corners can be a crossing square off
    lines, fitted, _ = _refine_l(gray, target, raw, curved=False, passes=2, max_move_cells=0.5 * _bit_cells(target))
    raw = np.where(fitted[..., None], lines, raw)
    radius_m = min(target.gap, target.border_bits * _bit_size(target))
    radius = _local_scale(target, tag_ids, raw) * radius_m  # px, the pure X around each corner
    half = np.floor(0.6 * np.nan_to_num(radius, nan=0.0)).min(axis=1)  # cornerSubPix half window per tag
    w, h = gray.size
    reach = (1.35 * half + 3.0)[:, None]  # window, smoothing and the saddle fit's window
    room = ((raw[..., 0] >= reach) & (raw[..., 0] <= w - 1 - reach) & (raw[..., 1] >= reach)
            & (raw[..., 1] <= h - 1 - reach) & (half[:, None] >= 2))
    pixels = raw.copy()
    tags = room.all(axis=1)
    for hw in np.unique(half[tags]):  # one crop per window size: the smoothing stays local
        sel = tags & (half == hw)
        pts = raw[sel].reshape(-1, 2)
        pad = 1.35 * hw + 11.0
        x0, y0 = (max(int(np.floor(pts[:, k].min() - pad)), 0) for k in (0, 1))
        x1, y1 = min(int(np.ceil(pts[:, 0].max() + pad)) + 1, w), min(int(np.ceil(pts[:, 1].max() + pad)) + 1, h)
        crop = GrayImage(u8=gray.u8[y0:y1, x0:x1], f32=gray.f32[y0:y1, x0:x1], name=gray.name)
        origin = np.array([x0, y0], np.float64)
        fine = refine_corners(crop, pts - origin, spacing_px=(hw + 0.5) / 0.35) + origin
        pixels[sel] = fine.reshape(-1, 4, 2)
    xok = room & (np.linalg.norm(pixels - raw, axis=-1) <= _X_AGREE_PX)
    return pixels, room & fitted & xok, room


def _refine_l(gray: GrayImage, target, raw: np.ndarray, curved: bool = True, passes: int = 3,
              max_move_cells: float = 1.0):
    """Edge refinement of tags' outer corners (:func:`jcalib.vision.tag_edges.refine_square_corners`):
    ``(pixels, ok, room)``, each (M, 4[, 2]); a corner may move at most ``max_move_cells`` cells (and
    2 px) from ``raw``: the decoded corners of large single tags are half a cell off (the detector's
    threshold windows are smaller than their border), a grid's up to the size of a crossing square
    (the tag's outline bends into the squares)."""
    n_cells = APRILTAG_FAMILIES[target.family][1] + 2 * target.border_bits
    cell = _side_px(raw) / n_cells  # (M,)
    pixels, ok = refine_square_corners(gray, raw, target.border_bits / n_cells, passes=passes, curved=curved)
    w, h = gray.size
    reach = (0.25 * target.border_bits * cell + 3.0)[:, None]
    room = (raw[..., 0] >= reach) & (raw[..., 0] <= w - 1 - reach) & (raw[..., 1] >= reach) & (raw[..., 1] <= h - 1 - reach)
    ok &= room & (np.linalg.norm(pixels - raw, axis=-1) <= np.maximum(max_move_cells * cell, 2.0)[:, None])
    return np.where(ok[..., None], pixels, raw), ok, room
