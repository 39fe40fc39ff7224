"""Assigning target point indices to a detected grid: handedness, printed colours and symmetric boards.

OpenCV's grid finders return the points of a chessboard or circle grid row by row, but which corner
comes first is only defined up to the symmetries of the pattern. jcalib fixes it as follows:

1. A labelling must be *proper*: seen from the camera, target x then y turn the same way as image
   u then v (the camera looks at the printed face). A mirrored order is mirrored back.
2. Chessboards: the printed squares must match (the outer square next to point 0 is black, so the
   inner square between points 0, 1, cols, cols+1 is black). For ``cols + rows`` odd this leaves
   exactly one labelling.
3. Circle grids with an origin dot (``CircleGrid.origin_dot``, ROS-Industrial's modified grid): the
   labelling whose origin point is the corner with the clearly larger dot, whatever the roll.
4. When several labellings remain (a chessboard with ``cols + rows`` even, any symmetric circle
   grid without a seen origin dot, an asymmetric grid with an even number of rows, square grids), the one whose target
   +x axis points closest to image +u (left to right) is chosen, and the detection carries the
   warning ``"orientation_ambiguous"``: point indices of such a board can swap between views that
   turn it by 180°. Use a board with ``cols + rows`` odd (or ChArUco) when that matters.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["assign_grid_indices", "point_symmetries"]


def point_symmetries(points_xy: np.ndarray, proper: bool = True) -> list[np.ndarray]:
    """Permutations ``perm`` with ``points[perm] == A @ points + t`` for a grid isometry ``A``.

    Args:
        points_xy: (N, 2) target points, m.
        proper: rotations (0°, 90°, 180°, 270°) when True, reflections when False.

    Returns:
        list of (N,) int64 permutations (the identity first when ``proper``).
    """
    p = np.asarray(points_xy, dtype=np.float64)
    scale = float(np.max(np.ptp(p, axis=0)))
    centred = (p - p.mean(axis=0)) / scale
    rotations = [np.array([[c, -s], [s, c]], dtype=np.float64) for c, s in ((1, 0), (0, 1), (-1, 0), (0, -1))]
    mats = rotations if proper else [r @ np.diag([1.0, -1.0]) for r in rotations]
    perms = []
    for A in mats:
        moved = centred @ A.T
        dist = np.linalg.norm(moved[:, None, :] - centred[None, :, :], axis=-1)
        idx = np.argmin(dist, axis=1)
        if np.all(dist[np.arange(len(idx)), idx] < 1e-9) and len(np.unique(idx)) == len(idx):
            perms.append(idx.astype(np.int64))
    return perms


def _orientation_sign(points_xy: np.ndarray, pixels: np.ndarray) -> float:
    """+1 when the labelling maps target (x, y) to image (u, v) without a mirror, else -1."""
    H, _ = cv2.findHomography(points_xy, pixels, 0)
    if H is None:
        return 1.0
    c = points_xy.mean(axis=0)
    w = H[2, 0] * c[0] + H[2, 1] * c[1] + H[2, 2]
    # Jacobian of the homography at the centroid: (H[:2,:2] * w - h_xy * H[2,:2]) / w^2.
    h_xy = H[:2, :2] @ c + H[:2, 2]
    J = (H[:2, :2] * w - np.outer(h_xy, H[2, :2])) / (w * w)
    return 1.0 if np.linalg.det(J) > 0.0 else -1.0


def _checker_score(gray, target, pixels_of_point: np.ndarray) -> float:
    """Mean grey of inner squares that should be white minus those that should be black (> 0: right)."""
    cols, rows = target.cols, target.rows
    P = pixels_of_point.reshape(rows, cols, 2)
    centres = 0.25 * (P[:-1, :-1] + P[:-1, 1:] + P[1:, :-1] + P[1:, 1:])
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    black = (i + j) % 2 == 0
    vals = gray.sample(centres.reshape(-1, 2)).reshape(black.shape)
    return float(vals[~black].mean() - vals[black].mean())


#: The origin dot's disc must be darker than every other candidate corner's by this fraction of dark pixels.
ORIGIN_DOT_MARGIN = 0.25


def _origin_dot(gray, target, pixels: np.ndarray, candidates: list[np.ndarray]) -> np.ndarray | None:
    """The labelling whose origin point is the grid corner with the larger dot, or None when no corner is
    clearly larger (the dot not printed, washed out, or out of the image).

    Around each candidate origin a disc of 0.4 local spacings is sampled: the fraction of it darker than
    half way between the dots' ink (their centres) and the paper (the middle of each square of four dots)
    is ~0.25 for a dot of 0.4 spacings and ~1 for the origin dot of twice that diameter."""
    p = np.asarray(pixels, np.float64)
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    spacing = d.min(axis=1)
    g = p.reshape(target.rows, target.cols, 2)
    ink = float(np.median(gray.sample(p)))
    paper = float(np.median(gray.sample((0.25 * (g[:-1, :-1] + g[:-1, 1:] + g[1:, :-1] + g[1:, 1:])).reshape(-1, 2))))
    if not paper - ink > 8.0:
        return None
    u = np.linspace(-1.0, 1.0, 9)
    disc = np.array([(a, b) for a in u for b in u if a * a + b * b <= 1.0])
    fractions = []
    for c in candidates:
        k = int(np.flatnonzero(c == target.origin_index)[0])
        values = gray.sample(p[k] + 0.4 * spacing[k] * disc)
        fractions.append(float(np.mean(values < 0.5 * (ink + paper))))
    order = np.argsort(fractions)[::-1]
    if fractions[order[0]] - fractions[order[1]] < ORIGIN_DOT_MARGIN:
        return None
    return candidates[int(order[0])]


def assign_grid_indices(target, pixels: np.ndarray, gray=None):
    """Point indices for a grid detection in OpenCV's row-major order.

    Args:
        target: ``Checkerboard`` or ``CircleGrid``.
        pixels: (N, 2) detected pixels, OpenCV's order (row-major, ``cols`` per row), px.
        gray: the :class:`~jcalib.vision.image.GrayImage` (checks the printed colours of a chessboard).

    Returns:
        (point_index, ambiguous): (N,) int64 with ``pixels[k]`` the image of
        ``target.points[point_index[k]]``, and whether the printed board left a choice (rule 4 above).
    """
    xy = target.points[:, :2]
    n = len(xy)
    base = np.arange(n, dtype=np.int64)
    # Candidate labellings: point_index = perm (detection k is point perm[k]).
    if _orientation_sign(xy, pixels) < 0.0:
        candidates = [base[r] for r in point_symmetries(xy, proper=False)]
    else:
        candidates = [base[r] for r in point_symmetries(xy, proper=True)]
    candidates = [c for c in candidates if _orientation_sign(xy[c], pixels) > 0.0] or candidates
    if gray is not None and getattr(target, "type", "") == "checkerboard" and len(candidates) > 1:
        scored = []
        for c in candidates:
            pix = np.empty_like(pixels)
            pix[c] = pixels
            scored.append(_checker_score(gray, target, pix))
        good = [c for c, s in zip(candidates, scored) if s > 0.0]
        candidates = good or [candidates[int(np.argmax(scored))]]
    if gray is not None and getattr(target, "origin_index", None) is not None and len(candidates) > 1:
        picked = _origin_dot(gray, target, pixels, candidates)
        if picked is not None:
            return picked, False
    if len(candidates) == 1:
        return candidates[0], False
    # Rule 4: target +x axis (point 0 -> point cols-1) closest to image +u.
    cols = target.cols
    best, best_cos = candidates[0], -np.inf
    for c in candidates:
        pix = np.empty_like(pixels)
        pix[c] = pixels
        d = pix[cols - 1] - pix[0]
        cos = d[0] / (np.linalg.norm(d) + 1e-12) - 1e-6 * d[1] / (np.linalg.norm(d) + 1e-12)
        if cos > best_cos:
            best, best_cos = c, cos
    return best, True
