"""Geometric consistency of a detection with the board model: the guard against accepting a wrong board.

A detector can return a board that is not there, or not there in that order: a ChArUco marker decoded
with a wrong id or rotation (clutter that happens to decode, a bit error the dictionary corrects
wrongly), a chessboard corner that the sub-pixel step dragged onto the next edge, a grid found with
a skipped row. Each of these puts a point far from where its neighbours say it must be. Locally a
planar board is seen through a smooth lens as a homography, so every point is predicted from a
homography fitted to its neighbours *on the board* (never including itself, nor, for a marker, its own
other corners), and a point whose prediction misses by more than a fraction of the local spacing is
inconsistent. The check removes the worst inconsistent point and repeats, so one wrong point does not
condemn its neighbours.

Thresholds are fractions of the local spacing in the image (the distance between neighbouring board
points), not pixels: a wrong id or a skipped row moves a point by at least one spacing; detection
noise and the lens's departure from a homography over a few squares stay far below a tenth of one.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRID_TOLERANCE", "MARKER_TOLERANCE", "batched_homographies", "consistent_markers", "consistent_points", "homography_steps"]

#: Largest distance of a grid point from its neighbours' prediction, in local spacings (but at least
#: :data:`MIN_TOLERANCE_PX`). 0.2 let a block of corners dragged 5-7 px by glare through (35 px squares).
GRID_TOLERANCE = 0.1
#: Floor of the grid tolerance, px: noisy corners of small squares (σ up to ~0.5 px) stay inside it.
MIN_TOLERANCE_PX = 1.5
#: Largest distance of a marker corner from its neighbour markers' prediction, in marker sides.
MARKER_TOLERANCE = 0.3


def batched_homographies(src: np.ndarray, dst: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """(B, 3, 3) least-squares homographies (normalised DLT) mapping ``src`` (B, K, 2) to ``dst`` (B, K, 2),
    all at once; ``weight`` (B, K) in {0, 1} leaves points out. NaN where a set is degenerate."""
    w = np.ones(src.shape[:2]) if weight is None else np.asarray(weight, np.float64)
    count = np.maximum(w.sum(axis=1, keepdims=True), 1.0)

    def normalise(p):
        mean = (p * w[..., None]).sum(axis=1) / count
        d = np.sqrt(((p - mean[:, None, :]) ** 2).sum(axis=-1))
        scale = np.sqrt(2.0) / np.maximum((d * w).sum(axis=1) / count[:, 0], 1e-300)
        T = np.zeros((len(p), 3, 3))
        T[:, 0, 0] = T[:, 1, 1] = scale
        T[:, :2, 2] = -scale[:, None] * mean
        T[:, 2, 2] = 1.0
        return (p - mean[:, None, :]) * scale[:, None, None], T

    s, Ts = normalise(np.asarray(src, np.float64))
    d, Td = normalise(np.asarray(dst, np.float64))
    x, y, u, v = s[..., 0], s[..., 1], d[..., 0], d[..., 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    ru = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], axis=-1)
    rv = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], axis=-1)
    A = np.concatenate([ru, rv], axis=1) * np.concatenate([w, w], axis=1)[..., None]
    with np.errstate(invalid="ignore"):
        vals, vecs = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)
    h = vecs[..., 0].reshape(-1, 3, 3)
    H = np.linalg.solve(Td, h) @ Ts
    bad = ~np.all(np.isfinite(H), axis=(1, 2)) | (np.abs(H[:, 2, 2]) < 1e-300) | (vals[:, 1] <= 1e-12 * vals[:, -1])
    H = H / np.where(np.abs(H[:, 2:3, 2:3]) > 1e-300, H[:, 2:3, 2:3], 1.0)
    H[bad] = np.nan
    return H


def homography_steps(H: np.ndarray, xy: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """(B, 2) ``H[b]`` applied to ``xy[b]`` and (B,) the image length of a board step there (smaller axis)."""
    def apply(p):
        q = np.einsum("bij,bj->bi", H, np.concatenate([p, np.ones((len(p), 1))], axis=1))
        with np.errstate(divide="ignore", invalid="ignore"):
            return q[:, :2] / q[:, 2:]

    p0 = apply(xy)
    dx = np.linalg.norm(apply(xy + [step, 0.0]) - p0, axis=1)
    dy = np.linalg.norm(apply(xy + [0.0, step]) - p0, axis=1)
    return p0, np.minimum(dx, dy)


def consistent_points(
    board_xy: np.ndarray,
    pixels: np.ndarray,
    *,
    neighbours: int = 8,
    tolerance: float = GRID_TOLERANCE,
) -> np.ndarray:
    """Which detected points agree with their board neighbours (see the module docstring).

    Args:
        board_xy: (N, 2) board coordinates of the detected points, m.
        pixels: (N, 2) their detected image positions, px.
        neighbours: how many nearest board points predict each point (>= 4).
        tolerance: largest prediction error, in local spacings (distance to the nearest board
            neighbour), at least :data:`MIN_TOLERANCE_PX`.

    Returns:
        (N,) bool: True for consistent points. Points that cannot be checked (fewer than 5 points in
        all) are all False: an unverifiable detection is not accepted.
    """
    xy = np.asarray(board_xy, dtype=np.float64)
    px = np.asarray(pixels, dtype=np.float64)
    n = len(xy)
    ok = np.isfinite(px).all(axis=1)
    if n < 5:
        return np.zeros(n, dtype=bool)
    d_board = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=-1)
    np.fill_diagonal(d_board, np.inf)
    spacing_m = float(np.min(d_board))
    k = max(4, neighbours)
    safe_px = np.where(np.isfinite(px), px, 0.0)

    def errors(points: np.ndarray, members: np.ndarray) -> np.ndarray:
        """Prediction errors (local spacings) of ``points`` from their nearest ``members`` (never themselves)."""
        d = d_board[np.ix_(points, members)]
        order = np.argsort(d, axis=1, kind="stable")[:, : min(k, len(members))]
        near = members[order]  # (P, K)
        use = np.isfinite(np.take_along_axis(d, order, axis=1))
        H = batched_homographies(xy[near], safe_px[near], use)
        pred, scale = homography_steps(H, xy[points], spacing_m)
        err = np.linalg.norm(pred - px[points], axis=1) / np.maximum(scale, max(MIN_TOLERANCE_PX / tolerance, 1e-9))
        return np.where(np.isfinite(err) & (use.sum(axis=1) >= 4), err, np.inf)

    return _prune_batched(ok, errors, tolerance, minimum=5)


def consistent_markers(
    marker_xy: np.ndarray,
    marker_pixels: np.ndarray,
    *,
    neighbours: int = 4,
    tolerance: float = MARKER_TOLERANCE,
) -> np.ndarray:
    """Which detected markers sit where their neighbour markers say (ids and rotations consistent).

    Args:
        marker_xy: (M, 4, 2) board coordinates of each detected marker's corners, in the order the
            detector reports image corners, m.
        marker_pixels: (M, 4, 2) the detected corners, px.
        neighbours: how many nearest markers (by board distance of the centres) predict each marker.
        tolerance: largest corner prediction error, in marker sides (image length of the marker's side).

    Returns:
        (M,) bool. With fewer than 2 markers nothing can be checked: all False.
    """
    xy = np.asarray(marker_xy, dtype=np.float64)
    px = np.asarray(marker_pixels, dtype=np.float64)
    m = len(xy)
    ok = np.isfinite(px).reshape(m, -1).all(axis=1)
    if m < 2:
        return np.zeros(m, dtype=bool)
    centres = xy.mean(axis=1)
    d_board = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=-1)
    np.fill_diagonal(d_board, np.inf)
    side_m = float(np.median(np.linalg.norm(xy[:, 1] - xy[:, 0], axis=1)))
    safe_px = np.where(np.isfinite(px), px, 0.0)

    def errors(points: np.ndarray, members: np.ndarray) -> np.ndarray:
        """Corner prediction errors (marker sides) of ``points`` from their nearest ``members``."""
        d = d_board[np.ix_(points, members)]
        order = np.argsort(d, axis=1, kind="stable")[:, : min(neighbours, len(members))]
        near = members[order]  # (P, K)
        use = np.repeat(np.isfinite(np.take_along_axis(d, order, axis=1)), 4, axis=1)
        H = batched_homographies(xy[near].reshape(len(points), -1, 2), safe_px[near].reshape(len(points), -1, 2), use)
        Hc = np.repeat(H, 4, axis=0)
        pred, scale = homography_steps(Hc, xy[points].reshape(-1, 2), side_m)
        side_px = np.maximum(scale.reshape(-1, 4).mean(axis=1), 1e-9)
        err = np.max(np.linalg.norm(pred.reshape(-1, 4, 2) - px[points], axis=-1), axis=1) / side_px
        return np.where(np.isfinite(err) & (use.sum(axis=1) >= 4), err, np.inf)

    return _prune_batched(ok, errors, tolerance, minimum=2)


def _prune_batched(ok: np.ndarray, errors, tolerance: float, minimum: int) -> np.ndarray:
    """Drop the worst point while any error exceeds ``tolerance``; then re-admit dropped points that
    the kept ones predict within it (a good point can look bad while a wrong neighbour is still in).
    ``errors(points, members)`` gives the errors of ``points`` predicted from ``members`` (all at once)."""
    finite = ok.copy()
    ok = ok.copy()
    while True:
        idx = np.flatnonzero(ok)
        if len(idx) < minimum:
            return np.zeros(len(ok), dtype=bool)
        err = errors(idx, idx)
        worst = int(np.argmax(err))
        if not err[worst] > tolerance:
            break
        ok[idx[worst]] = False
    out = np.flatnonzero(~ok & finite)
    if len(out):
        ok[out[errors(out, np.flatnonzero(ok)) <= tolerance]] = True
    return ok
