"""Where a chessboard plausibly is, cheaply: X-junctions on a reduced image and the lattice they form.

A chessboard's inner corners are X-junctions: two dark and two bright sectors meeting at a point,
point-symmetric about it (a half turn maps dark to dark, also under perspective). Such a point is a
saddle of the smoothed image (``-det(Hessian) > 0``) and a ring of samples around it varies
point-symmetrically (even angular harmonics only) with one dark-bright alternation per half turn.
Lines, edges, blobs and the corners of shapes fail one of these tests; crossings of two lines and the
odd stray junction of a cluttered scene pass them, but do not form a lattice: on a board, most
junctions have two pairs of opposite neighbours (``p ± v``, ``p ± w``) among their nearest.

:func:`locate_board` runs on the pyramid level whose longer side is at most :data:`LOCATE_SIDE_PX`,
the next coarser one and, for small boards, the next finer one (when small enough); it costs a few milliseconds and gives
the number of lattice junctions, their spacing (which pyramid level suits a finder) and their
bounding box (where to look). :func:`x_junction_check` tests corners a finder returned, at full
resolution: a grid with a corner that is not an X-junction is not the board (e.g. the outer corner of a
border square standing in for a covered row).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.vision.image import GrayImage, from_level, mosaic

__all__ = ["BoardHint", "LOCATE_SIDE_PX", "Region", "lattice_points", "locate_board", "x_junction_check"]

#: The locator works on the first pyramid level whose longer side is at most this, px.
LOCATE_SIDE_PX = 700
#: ... and also on the level below it when that has at most this many pixels (small boards).
LOCATE_FINE_PIXELS = 1_600_000
_RING = 16
_ANG = np.arange(_RING) * (2.0 * np.pi / _RING)
_COS, _SIN = np.cos(_ANG).astype(np.float32), np.sin(_ANG).astype(np.float32)
#: Candidates (strongest saddles) tested per scale: many more than any board has corners.
_MAX_CANDIDATES = 400


@dataclass(frozen=True)
class Region:
    """One cluster of lattice junctions: a board, or another chessboard-like pattern.

    Attributes:
        lattice: its lattice junctions.
        spacing_px: median distance between lattice neighbours, full-resolution px.
        roi: (x0, y0, x1, y1) full-resolution box around its junctions plus two spacings, clipped to the
            image.
    """

    lattice: int
    spacing_px: float
    roi: tuple[int, int, int, int]

    def level_for(self, min_square_px: float = 14.0) -> int:
        """The coarsest pyramid level whose squares are still at least ``min_square_px`` wide."""
        if not np.isfinite(self.spacing_px) or self.spacing_px < 2.0 * min_square_px:
            return 0
        return int(np.floor(np.log2(self.spacing_px / min_square_px)))


@dataclass(frozen=True)
class BoardHint:
    """What :func:`locate_board` found.

    Attributes:
        junctions: X-junctions found (at the best level).
        regions: clusters of lattice junctions (neighbours at most two spacings apart), largest first.
    """

    junctions: int
    regions: tuple[Region, ...]

    @property
    def lattice(self) -> int:
        """Lattice junctions in all regions."""
        return sum(r.lattice for r in self.regions)


def _x_candidates(f: np.ndarray, sigma: float, min_amplitude: float) -> np.ndarray:
    """(M, 2) X-junction-like points of a float image at smoothing ``sigma`` (px of that image)."""
    g = cv2.GaussianBlur(f, (0, 0), sigma)
    dxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    dyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    dxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    # -det(Hessian) (Sobel's second derivatives are 4x, its mixed one 16x the true ones)
    r = cv2.subtract(cv2.multiply(dxy, dxy, scale=0.0625), cv2.multiply(dxx, dyy))
    peak = cv2.bitwise_and(cv2.compare(r, cv2.dilate(r, None), cv2.CMP_GE), cv2.compare(r, 1e-3, cv2.CMP_GT))
    pts = cv2.findNonZero(peak)
    if pts is None:
        return np.zeros((0, 2))
    pts = pts.reshape(-1, 2)
    if len(pts) > _MAX_CANDIDATES:
        vals = r[pts[:, 1], pts[:, 0]]
        pts = pts[np.argpartition(-vals, _MAX_CANDIDATES)[:_MAX_CANDIDATES]]
    start = np.clip(pts.astype(np.float64) + _peak_offset(r, pts), 0.0, np.array(r.shape[::-1]) - 1.0)
    rho = np.float32(2.5 * sigma)
    ring = _ring(g, start, rho)
    start = start[ring.max(axis=1) - ring.min(axis=1) > min_amplitude]
    if len(start) == 0:
        return np.zeros((0, 2))
    # the saddle response peaks off a skewed junction (a steeply tilted board): cornerSubPix moves the
    # candidate onto the junction before the ring is laid around it
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 10, 0.05)
    sub = cv2.cornerSubPix(g, start.astype(np.float32).reshape(-1, 1, 2), (2, 2), (-1, -1), criteria)
    sub = sub.reshape(-1, 2).astype(np.float64)
    sub = np.where(np.linalg.norm(sub - start, axis=1, keepdims=True) < 2.0, sub, start)
    ring = _ring(g, sub, rho)
    keep = _is_x_ring(ring, min_amplitude)
    return sub[keep]


def _ring(g: np.ndarray, centres: np.ndarray, rho: float) -> np.ndarray:
    """(M, 16) samples of ``g`` on circles of radius ``rho`` around ``centres`` (M, 2)."""
    px = centres[:, 0:1].astype(np.float32) + np.float32(rho) * _COS[None]
    py = centres[:, 1:2].astype(np.float32) + np.float32(rho) * _SIN[None]
    return cv2.remap(g, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)


def _peak_offset(r: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(M, 2) sub-pixel offsets of integer peaks of ``r`` (a quadratic through their 3x3 neighbourhood,
    at most half a pixel): the ring test needs the ring centred on the junction."""
    h, w = r.shape
    x = np.clip(pts[:, 0], 1, w - 2)
    y = np.clip(pts[:, 1], 1, h - 2)
    c = r[y, x].astype(np.float64)
    dx = 0.5 * (r[y, x + 1] - r[y, x - 1])
    dy = 0.5 * (r[y + 1, x] - r[y - 1, x])
    dxx = r[y, x + 1] + r[y, x - 1] - 2.0 * c
    dyy = r[y + 1, x] + r[y - 1, x] - 2.0 * c
    dxy = 0.25 * (r[y + 1, x + 1] - r[y + 1, x - 1] - r[y - 1, x + 1] + r[y - 1, x - 1])
    det = dxx * dyy - dxy * dxy
    with np.errstate(divide="ignore", invalid="ignore"):
        ox = np.where(det > 0, -(dyy * dx - dxy * dy) / det, 0.0)
        oy = np.where(det > 0, -(dxx * dy - dxy * dx) / det, 0.0)
    return np.clip(np.stack([ox, oy], axis=1), -0.5, 0.5)


def _is_x_ring(ring: np.ndarray, min_amplitude: float) -> np.ndarray:
    """(M,) bool: rings of samples (M, n) around X-junctions: point-symmetric, one dark-bright alternation
    per half turn (also for the skewed junctions of a steeply tilted board), enough contrast."""
    n = ring.shape[1]
    amp = ring.max(axis=1) - ring.min(axis=1)
    z = ring - ring.mean(axis=1, keepdims=True)
    half = z[:, : n // 2] + z[:, n // 2 :]  # even part (x2); the odd part is z - even
    odd = z[:, : n // 2] - z[:, n // 2 :]
    even_energy, odd_energy = np.sum(half**2, axis=1), np.sum(odd**2, axis=1)
    sign = half > 0.0
    changes = np.sum(sign != np.roll(sign, 1, axis=1), axis=1)  # sign changes around the half ring
    return (amp > min_amplitude) & (even_energy > 4.0 * odd_energy) & (changes == 2)


#: Above this many points :func:`lattice_points` finds neighbours with a k-d tree (an (m, m) distance
#: matrix of 10 000 blobs of a noise image is 800 MB and seconds).
DENSE_POINTS = 2000


def lattice_points(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M,) bool: points with two non-parallel pairs of opposite neighbours among their 6 nearest; and
    (M,) the shorter of those neighbour distances (NaN where not on a lattice)."""
    m = len(p)
    spacing = np.full(m, np.nan)
    if m < 5:
        return np.zeros(m, bool), spacing
    k = min(6, m - 1)
    if m > DENSE_POINTS:  # noise or clutter: a k-d tree, not an (m, m) distance matrix (memory, time)
        from scipy.spatial import cKDTree

        nn = cKDTree(p).query(p, k + 1)[1][:, 1:]
    else:
        d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
        np.fill_diagonal(d, np.inf)
        nn = np.argpartition(d, k - 1, axis=1)[:, :k]
    v = p[nn] - p[:, None, :]  # (m, k, 2)
    length = np.linalg.norm(v, axis=-1)
    ia, ib = np.triu_indices(k, 1)
    s = np.linalg.norm(v[:, ia] + v[:, ib], axis=-1)  # (m, pairs)
    opposite = s < 0.35 * np.minimum(length[:, ia], length[:, ib])
    unit = v[:, ia] / length[:, ia, None]
    cos = np.abs(np.einsum("mpc,mqc->mpq", unit, unit))
    two = np.any(opposite[:, :, None] & opposite[:, None, :] & (cos < 0.87), axis=(1, 2))
    pair_len = np.where(opposite, np.minimum(length[:, ia], length[:, ib]), np.inf)
    spacing[two] = np.min(pair_len[two], axis=1)
    return two, spacing


def locate_board(gray: GrayImage, contrast: float) -> BoardHint:
    """X-junctions and their lattice on a reduced image (see the module docstring).

    Args:
        gray: the image.
        contrast: the image's grey-level spread, 0..1 (:func:`jcalib.vision.image.image_stats`): junctions
            fainter than a twentieth of it (or 4 grey levels) are ignored.

    Returns:
        :class:`BoardHint` of the level and scale with the most lattice junctions.
    """
    w, h = gray.size
    k0 = 0
    while max(w, h) / 2**k0 > LOCATE_SIDE_PX:
        k0 += 1
    # sigma 1 px on three levels: squares of ~5 to ~80 px on the locator's level
    levels = [k0, k0 + 1] + ([k0 - 1] if k0 > 0 and w * h / 4 ** (k0 - 1) <= LOCATE_FINE_PIXELS else [])
    min_amp = max(4.0, 0.05 * 255.0 * contrast)
    best = None
    for k in levels:
        pts = _x_candidates(gray.level(k).astype(np.float32), 1.0, min_amp)
        on, spacing = lattice_points(pts)
        score = int(np.sum(on))
        if best is None or score > best[1]:
            best = (len(pts), score, k, pts, on, spacing)
    n, score, k, all_pts, on, spacing = best
    return BoardHint(n, _regions(from_level(all_pts, k), on, spacing * 2**k, (w, h)))


def _components(adjacent: np.ndarray) -> np.ndarray:
    """(M,) connected-component labels 0..C-1 of a symmetric (M, M) adjacency (label propagation)."""
    m = len(adjacent)
    label = np.arange(m)
    big = np.where(adjacent | np.eye(m, dtype=bool), 0, m)
    while True:
        new = np.min(big + label[None, :], axis=1)
        new = new[new]  # jump along chains
        if np.array_equal(new, label):
            break
        label = new
    return np.unique(label, return_inverse=True)[1]


def _regions(points: np.ndarray, on: np.ndarray, spacing: np.ndarray, size: tuple[int, int]) -> tuple[Region, ...]:
    """Clusters of lattice junctions (full-resolution px; junctions closer than twice the larger of their
    spacings are neighbours), each grown by the other junctions within 1.5 spacings of it (the board's
    outermost corners have no opposite neighbours), its box widened by 2.5 spacings (the border
    squares and the quiet zone the finders need)."""
    lat, sp = points[on], spacing[on]
    if len(lat) == 0:
        return ()
    d = np.linalg.norm(lat[:, None, :] - lat[None, :, :], axis=-1)
    label = _components(d <= 2.0 * np.maximum(sp[:, None], sp[None, :]))
    count = int(label.max()) + 1
    others = points[~on]
    out = []
    for c in range(count):
        idx = np.flatnonzero(label == c)
        s = float(np.median(sp[idx]))
        member = lat[idx]
        for _ in range(2):
            if len(others) == 0:
                break
            near = np.min(np.linalg.norm(others[:, None, :] - member[None, :, :], axis=-1), axis=1) <= 1.5 * s
            member = np.concatenate([lat[idx], others[near]])
        big = float(np.percentile(sp[idx], 90))
        x0, y0 = member.min(axis=0) - 2.5 * big
        x1, y1 = member.max(axis=0) + 2.5 * big
        roi = (max(0, int(x0)), max(0, int(y0)), min(size[0], int(np.ceil(x1)) + 1), min(size[1], int(np.ceil(y1)) + 1))
        out.append(Region(len(idx), s, roi))
    return tuple(sorted(out, key=lambda r: -r.lattice))


#: A corner whose ring has less even (point-symmetric) than odd energy is not an X-junction: an L corner
#: (a border square's outer corner) has a ratio of 1/2, an edge 0, an X-junction far above 1 (measured
#: on OpenCV's real left/right images: at least 16, 1 % below 130).
X_MIN_EVEN_ODD = 1.0


def x_junction_check(gray: GrayImage, corners: np.ndarray, spacing_px: np.ndarray | float, asymmetry: bool = False):
    """Which corners are X-junctions, at full resolution.

    Rings of radius 0.25 and 0.4 spacings (at least 2 px) around each corner, on the image smoothed by an
    eighth of a spacing, averaged: an X-junction varies point-symmetrically around them (even angular
    harmonics), the corners of shapes and edges do not (:data:`X_MIN_EVEN_ODD`).

    Args:
        gray: the image.
        corners: (N, 2) px.
        spacing_px: (N,) or scalar local corner spacing, px.

    Returns:
        ``(not_x, flat)``: (N,) bool each; ``not_x`` marks corners with clearly more odd than even
        structure; ``flat`` marks corners whose ring has less than a quarter of the median ring
        contrast of all corners (nothing measurable there: glare, shadow), which are neither confirmed
        nor refuted. With ``asymmetry``: (N,) the odd share of the rings' energy instead (0 at a perfect
        X-junction, the point-symmetric centre; the lower the better).
    """
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    sp = np.broadcast_to(np.asarray(spacing_px, np.float64), (len(c),))
    sigma = float(np.clip(0.125 * np.median(sp), 0.5, 4.0))
    radii = np.maximum(np.stack([0.25 * sp, 0.4 * sp], axis=1), 2.0)  # (N, 2)
    half = int(np.ceil(radii.max() + 4.0 * sigma + 2.0))
    centre = np.round(c).astype(np.int64)
    image, origins = mosaic(gray.tiles(centre, half))
    g = cv2.GaussianBlur(image, (0, 0), sigma)
    local = c - centre + half + origins
    n = 32
    ang = np.arange(n) * (2.0 * np.pi / n)
    ring = 0.0
    for j in range(2):
        px = (local[:, 0:1] + radii[:, j:j + 1] * np.cos(ang)[None]).astype(np.float32)
        py = (local[:, 1:2] + radii[:, j:j + 1] * np.sin(ang)[None]).astype(np.float32)
        ring = ring + cv2.remap(g, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    amp = ring.max(axis=1) - ring.min(axis=1)
    flat = amp < 0.25 * np.median(amp)
    z = ring - ring.mean(axis=1, keepdims=True)
    even = np.sum((z[:, : n // 2] + z[:, n // 2 :]) ** 2, axis=1)
    odd = np.sum((z[:, : n // 2] - z[:, n // 2 :]) ** 2, axis=1)
    if asymmetry:
        return odd / np.maximum(even + odd, 1e-12)
    return (even < X_MIN_EVEN_ODD * odd) & ~flat, flat
