"""Chessboard corners: a cheap search on reduced images, then ``cornerSubPix`` + a saddle-point fit at full
resolution; every grid any attempt returns is checked before it is kept.

**Search** (:func:`find_chessboard`), cheapest first:

1. ``findChessboardCorners`` with ``CALIB_CB_FAST_CHECK`` on the pyramid level whose longer side is at
   most :data:`FAST_SIDE_PX` (a millisecond or two; finds most clean views);
2. the X-junction locator (:mod:`jcalib.vision.locate`) says whether a board plausibly is in view,
   where, and how large its squares are; when it is, the classic finder (then ``findChessboardCornersSB``
   when that finds nothing or a grid with a corner off it) runs on that region, on the pyramid level
   where the squares are about :data:`FINDER_SQUARE_PX` wide;
3. only then, and only with ``retry``, the attempts of :data:`jcalib.vision.attempts.GRID_ATTEMPTS`
   on the same region.

An image without a lattice of X-junctions gets no further than step 2 (a few milliseconds at
640x480). Whatever a step finds is refined level by level down to the full-resolution image.

**Checks**, the same for every step: :func:`grid_error` on the finder's grid and again on the refined
one (a corner a spacing off its neighbours' grid), and :func:`jcalib.vision.locate.x_junction_check`
on every refined corner: a grid with a corner that is not an X-junction is not the board (e.g. a
board with its last row covered, whose finder took the outer corners of the border squares for the
covered row and so numbered every real corner 180° off). The caller then checks every point
against the board's homography (:mod:`jcalib.vision.validate`).

**Accuracy** (the refinement):

Measured on clean synthetic homography warps of a 9x6 board (exact-coverage texture, 4x4
supersampled pixels, 640x480, 10-40 px squares; helpers in ``tests/vision/synth.py``): plain
``cornerSubPix`` (11x11) has a mean corner error of 0.04 px (its gradient model is biased on
1-px-sharp edges), ``findChessboardCornersSB`` (with ``CALIB_CB_ACCURACY``) 0.07-0.11 px. Smoothing the
image with a Gaussian of sigma ~ window/4 before ``cornerSubPix`` removes most of the mean bias, but
on rendered perspective views (``jcalib.sim``, 640x480, 8x6 board) every corner still carries a
deterministic error of 0.030 px RMS (0.034 px with lens distortion) that depends on the corner's
geometry: it does not average out over views and showed as 4-6σ errors in the demo cell.

The final step therefore fits the saddle point of the lightly smoothed image: an X-junction is
point-symmetric about the corner (180° rotation maps black squares to black squares, also under
perspective), a Gaussian blur keeps that symmetry, so the corner is a stationary point of the
smoothed image. A quadratic ``f = a x² + b xy + c y² + d x + e y + g`` is fitted (Gaussian-weighted
least squares) to a window resampled around the current estimate and the estimate moves to the
fit's stationary point until the step is below 1e-4 px; on a window centred on the corner the
symmetric terms leave no bias. Measured on rendered views (10 random poses, 8x6 board): 640x480,
17-37 px spacing: 0.0071 px RMS without noise, 0.0103 px with the renderer's sensor noise
(cornerSubPix: 0.030 / 0.031); 1600x1200 with distortion, 42-93 px: 0.0048 / 0.0095 px. On OpenCV's
real left images (13 views) the calibration RMS drops from 0.183 to 0.165 px (``cv2.calibrateCamera``,
fixed aspect ratio, same images).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.vision.image import GrayImage, from_level, image_stats, mosaic, to_level
from jcalib.vision.locate import BoardHint, Region, locate_board, x_junction_check
from jcalib.vision.validate import consistent_points

__all__ = ["GridFound", "find_chessboard", "find_partial_chessboard", "grid_error", "grid_errors", "plausible_lattice",
           "refine_corners", "windows"]

_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE


def windows(gray: GrayImage, corners: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """A mosaic of the float image's windows (2 half + 1 px) around the corners, and each corner's
    position in it: filters then cost the windows' area, not the image's."""
    c = np.asarray(corners, np.float64).reshape(-1, 2)
    centre = np.round(c).astype(np.int64)
    image, origins = mosaic(gray.tiles(centre, half))
    return image, c - centre + half + origins


def refine_corners(gray: GrayImage, corners: np.ndarray, spacing_px: float, accurate_start: bool = False) -> np.ndarray:
    """Sub-pixel X-junction positions from rough ones (``cornerSubPix``, then the saddle-point fit).

    Args:
        gray: the image.
        corners: (N, 2) rough corners, px.
        spacing_px: smallest distance between neighbouring corners in the image, px (sets the windows).
        accurate_start: the corners come from a finder on the full-resolution (or an enlarged) image:
            where the saddle fit settles from them (within a quarter spacing of the other result), that
            point is kept.

    Returns:
        (N, 2) float64 refined corners, px (OpenCV convention). A corner whose saddle fit does not
        converge within 1 px of the ``cornerSubPix`` result keeps that result.
    """
    half = int(np.clip(np.floor(0.35 * spacing_px), 2, 10))
    sigma = float(np.clip(0.25 * half + 0.75, 1.0, 2.5))
    start = np.asarray(corners, np.float64).reshape(-1, 2)
    image, local = windows(gray, start, half + int(np.ceil(4.0 * sigma)) + 8)
    smooth = cv2.GaussianBlur(image, (0, 0), sigma)
    c = np.ascontiguousarray(local, dtype=np.float32).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-5)
    moved = cv2.cornerSubPix(smooth, c, (half, half), (-1, -1), criteria).reshape(-1, 2).astype(np.float64) - local
    refined = start + np.where(np.linalg.norm(moved, axis=1, keepdims=True) < half, moved, 0.0)
    out = saddle_points(gray, refined, spacing_px)
    if not accurate_start:
        return out
    # cornerSubPix drags the skewed junctions of a steeply tilted board by 1-2 px (measured on rendered
    # 60-75° views, 11-14 px spacing), further than the saddle fit may move back: where the fit
    # converges from a full-resolution finder's own corner, that stationary point is kept
    # (on a blurred image the fit from a finder's corner 1-3 px off can settle there too: the more
    # point-symmetric of the two points is the junction)
    direct, ok = saddle_points(gray, start, spacing_px, converged=True)
    differ = ok & (np.linalg.norm(direct - out, axis=1) > 0.05)
    if np.any(differ):
        a = x_junction_check(gray, out[differ], spacing_px, asymmetry=True)
        b = x_junction_check(gray, direct[differ], spacing_px, asymmetry=True)
        out[np.flatnonzero(differ)[b < a]] = direct[differ][b < a]
    return out


#: Saddle fit window: half width ``round(_SADDLE_F * spacing)`` clipped to [2, _SADDLE_MAX] px and a
#: pre-smoothing σ of ``_SADDLE_S * half``: chosen on rendered 640x480 and 1600x1200 views (17-93 px
#: spacing); wider windows reach the curved part of the blurred junction and lose accuracy.
_SADDLE_F, _SADDLE_MAX, _SADDLE_S = 0.12, 4, 0.35


def _bilinear(img: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """``img`` at float positions (pixel centres at integers), bilinear, clamped at the border; float64."""
    h, w = img.shape
    xs = np.clip(xs, 0.0, w - 1.000001)
    ys = np.clip(ys, 0.0, h - 1.000001)
    x0, y0 = np.floor(xs).astype(np.intp), np.floor(ys).astype(np.intp)
    fx, fy = xs - x0, ys - y0
    f = img.astype(np.float64, copy=False)
    top = f[y0, x0] * (1.0 - fx) + f[y0, x0 + 1] * fx
    bottom = f[y0 + 1, x0] * (1.0 - fx) + f[y0 + 1, x0 + 1] * fx
    return top * (1.0 - fy) + bottom * fy


def saddle_points(gray: GrayImage, corners: np.ndarray, spacing_px: float, iterations: int = 12,
                  converged: bool = False):
    """Stationary points of a quadratic fitted around each corner (see the module docstring).

    Returns:
        (N, 2) px; a corner whose fit does not settle within 1 px of its start keeps the start. With
        ``converged``: also (N,) bool, which fits settled (a saddle, within 1 px).
    """
    half = int(np.clip(np.round(_SADDLE_F * spacing_px), 2, _SADDLE_MAX))
    start = np.asarray(corners, np.float64).reshape(-1, 2)
    # each corner's window: the fit's half width, the smoothing's reach and the 1 px it may move
    image, local = windows(gray, start, half + int(np.ceil(4.0 * _SADDLE_S * half)) + 8)
    smooth = cv2.GaussianBlur(image, (0, 0), _SADDLE_S * half)
    n = 2 * half + 1
    y, x = np.mgrid[-half:half + 1, -half:half + 1].astype(np.float64)
    A = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1).reshape(-1, 6)
    w = np.exp(-(x * x + y * y) / (2.0 * (half / 1.5) ** 2)).reshape(-1)
    P = np.linalg.pinv(A * w[:, None]) * w[None, :]  # (6, n*n): weighted least-squares fit
    cur = local.copy()
    active = np.ones(len(cur), bool)
    settled = np.zeros(len(cur), bool)  # the last fit was a saddle
    for _ in range(iterations):
        if not np.any(active):
            break
        idx = np.flatnonzero(active)
        # resample every active corner's window around its estimate, bilinear in float64 (cv2.remap
        # quantises the sub-pixel weights to 1/32 px, which alone biases the corners by ~0.01 px)
        patches = _bilinear(smooth, cur[idx, 0][:, None, None] + x[None], cur[idx, 1][:, None, None] + y[None])
        a, b, cc, d, e, _ = P @ patches.reshape(len(idx), n * n).T
        det = 4.0 * a * cc - b * b  # < 0 at a saddle
        ok = det < 0.0
        step = np.zeros((len(idx), 2))
        step[ok, 0] = -(2.0 * cc[ok] * d[ok] - b[ok] * e[ok]) / det[ok]
        step[ok, 1] = -(2.0 * a[ok] * e[ok] - b[ok] * d[ok]) / det[ok]
        step = np.clip(step, -0.5, 0.5)
        cur[idx] += step
        active[idx] = ok & (np.linalg.norm(step, axis=1) > 1e-4)
        settled[idx] = ok
    moved = cur - local
    far = (np.linalg.norm(moved, axis=1) > 1.0) | ~np.all(np.isfinite(moved), axis=1)
    out = np.where(far[:, None], start, start + moved)
    if converged:
        return out, ~far & ~active & settled
    return out


def _min_spacing(corners: np.ndarray, cols: int, rows: int) -> float:
    g = corners.reshape(rows, cols, 2)
    d = [np.linalg.norm(np.diff(g, axis=1), axis=-1).ravel(), np.linalg.norm(np.diff(g, axis=0), axis=-1).ravel()]
    return float(np.min(np.concatenate(d)))


#: The classic finder's grid is taken at once when :func:`grid_error` is at most this; above, the SB
#: finder runs too and the grid with the smaller error is kept. Measured (9x6 grids projected by OpenCV,
#: tilts to 70°, 0.2 px noise): 0.04 without distortion, up to 0.25 with k1 in [-0.45, 0.2], more where
#: such strong distortion folds the outer rows; a corner one spacing off (a border square's corner, a
#: neighbour's) scores 0.4-1.5.
GRID_RTOL = 0.3


def grid_error(corners: np.ndarray, cols: int, rows: int) -> float:
    """The largest of :func:`grid_errors` (0 for grids narrower than 3 corners; inf when not finite)."""
    if cols < 3 or rows < 3:
        return 0.0
    err = grid_errors(corners, cols, rows)
    return float(np.max(err)) if np.all(np.isfinite(err)) else float("inf")


def grid_errors(corners: np.ndarray, cols: int, rows: int, predictions: bool = False):
    """(N,) how far each corner of a ``cols x rows`` grid (OpenCV's order) sits from where its neighbours
    put it, in units of the local spacing (zeros for grids narrower than 3 corners; inf where not finite).

    Every corner's 3x3 block (shifted inwards at the border) gives 8 other corners: their homography from
    the lattice (a DLT per block, all blocks at once, in block-normalised pixels) predicts the corner.
    Perspective keeps a real corner on it; lens distortion bends the grid slowly over two squares.
    With ``predictions`` also (N, 2) the predicted positions, px.
    """
    if cols < 3 or rows < 3:
        zero = np.zeros(cols * rows)
        return (zero, np.asarray(corners, np.float64).reshape(-1, 2)) if predictions else zero
    g = np.asarray(corners, np.float64).reshape(rows, cols, 2)
    I, J = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    I, J = I.ravel(), J.ravel()
    i0, j0 = np.clip(I - 1, 0, rows - 3), np.clip(J - 1, 0, cols - 3)
    dr, dc = np.divmod(np.arange(9), 3)
    blocks = g[i0[:, None] + dr[None], j0[:, None] + dc[None]]  # (N, 9, 2)
    k = 3 * (I - i0) + (J - j0)  # the corner's place in its block
    b = blocks.reshape(-1, 3, 3, 2)
    down = np.linalg.norm(b[:, 1:] - b[:, :-1], axis=-1).reshape(len(I), -1)
    across = np.linalg.norm(b[:, :, 1:] - b[:, :, :-1], axis=-1).reshape(len(I), -1)
    spacing = np.median(np.concatenate([down, across], axis=1), axis=1)  # of the block's 12 neighbour steps
    if not np.all(np.isfinite(blocks)) or np.any(spacing <= 0.0):
        inf = np.full(cols * rows, np.inf)
        return (inf, np.asarray(corners, np.float64).reshape(-1, 2)) if predictions else inf
    u = (blocks - blocks.mean(axis=1, keepdims=True)) / spacing[:, None, None]  # pixels, block-normalised
    x, y = (dc - 1.0)[None], (dr - 1.0)[None]  # lattice, centred
    use = (np.arange(9)[None] != k[:, None]).astype(np.float64)
    one, zero = np.ones_like(u[..., 0]), np.zeros_like(u[..., 0])
    X, Y = np.broadcast_to(x, u[..., 0].shape), np.broadcast_to(y, u[..., 0].shape)
    ru = np.stack([X, Y, one, zero, zero, zero, -u[..., 0] * X, -u[..., 0] * Y, -u[..., 0]], axis=-1)
    rv = np.stack([zero, zero, zero, X, Y, one, -u[..., 1] * X, -u[..., 1] * Y, -u[..., 1]], axis=-1)
    A = np.concatenate([ru, rv], axis=1) * np.concatenate([use, use], axis=1)[..., None]  # (N, 18, 9)
    h = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)[1][..., 0].reshape(-1, 3, 3)
    n = np.arange(len(I))
    q = h @ np.stack([x[0, k], y[0, k], np.ones(len(I))], axis=-1)[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        pred = q[:, :2, 0] / q[:, 2:, 0]
        err = np.where(np.isfinite(pred).all(axis=1), np.linalg.norm(pred - u[n, k], axis=-1), np.inf)
    if predictions:
        return err, pred * spacing[:, None] + blocks.mean(axis=1)
    return err


#: The first, cheap pass runs on the pyramid level whose longer side is at most this, px.
FAST_SIDE_PX = 400
#: Regions of lattice junctions searched, largest first (a board, a screen showing one, a tiled floor...).
MAX_REGIONS = 3
#: A level image larger than this (px) is searched around the located junctions only.
CROP_PIXELS = 1_000_000
#: The located region is searched on the pyramid level where the squares are about this wide (px), then on
#: the level where they are twice as wide: the classic finder is fast on small squares and finds most boards
#: there (OpenCV's FAST_CHECK is not: it misses them), some hard ones only on the finer level.
FINDER_SQUARE_PX = 7.0
_FAST_FLAGS = _FIND_FLAGS | cv2.CALIB_CB_FAST_CHECK


@dataclass(frozen=True)
class GridFound:
    """What :func:`find_chessboard` found.

    Attributes:
        pixels: (cols * rows, 2) float64 refined corners in OpenCV's order, px, or None.
        method: the finder and level that found them, e.g. ``"findChessboardCorners@level1+cornerSubPix+saddle"``.
        attempts: the attempts run, in order (``"default"`` is the fast pass and the located region).
        rejected: why grids that attempts returned were not kept (``"<attempt>: <reason>"``).
        hint: the locator's :class:`~jcalib.vision.locate.BoardHint` (None when the fast pass sufficed).
        suspect: (cols * rows,) bool, the corners of ``pixels`` that failed a check (to be left out).
        partial: (cols, rows) of the largest chessboard seen when the board was not found (None: not
            looked for, or none); when it is cut by the image border the retries were skipped.
    """

    pixels: np.ndarray | None
    method: str
    attempts: tuple[str, ...]
    rejected: tuple[str, ...] = ()
    hint: BoardHint | None = None
    suspect: np.ndarray | None = None
    partial: tuple[int, int] | None = None

    @property
    def attempt(self) -> str:
        return self.attempts[-1] if self.attempts else "default"


def level_with_side(gray: GrayImage, side: float) -> int:
    """The first pyramid level whose longer side is at most ``side`` px."""
    k, longer = 0, max(gray.size)
    while longer / 2**k > side:
        k += 1
    return k


def _classic_then_sb(img: np.ndarray, cols: int, rows: int, flags: int, sb: bool) -> tuple[np.ndarray | None, str]:
    """The classic finder's grid, or SB's when the classic one is missing or has a corner off the grid and
    SB's fits better (the classic finder now and then returns a border square's outer corner for an inner
    one, a spacing away: seen on a rendered 8x5 board at 320x240, one corner 14 px off)."""
    ok, c = cv2.findChessboardCorners(img, (cols, rows), flags=flags)
    method = "findChessboardCorners"
    error = grid_error(c.reshape(-1, 2), cols, rows) if ok and c is not None else float("inf")
    if error > GRID_RTOL and sb:
        ok_sb, c_sb = cv2.findChessboardCornersSB(img, (cols, rows), flags=cv2.CALIB_CB_EXHAUSTIVE)
        error_sb = grid_error(c_sb.reshape(-1, 2), cols, rows) if ok_sb and c_sb is not None else float("inf")
        if error_sb < error:
            c, error, method = c_sb, error_sb, "findChessboardCornersSB"
    if not error <= GRID_RTOL:
        return None, method
    return c.reshape(-1, 2).astype(np.float64), method


def _to_full(gray: GrayImage, corners: np.ndarray, level: int, cols: int, rows: int) -> np.ndarray:
    """Corners on pyramid level ``level`` -> full resolution, with ``cornerSubPix`` on every level on the way
    (each halves the start error of the next). The windows stay small (a fifth of a spacing, 2-4 px): a
    wider one drifts on level 1 (measured on OpenCV's real right05: a border corner 1.3 px off)."""
    c = np.asarray(corners, np.float64)
    # a finder's corner off the grid of its neighbours (the classic finder's, up to 5 px on level 1 of
    # OpenCV's real left03) starts where they put it
    err, pred = grid_errors(c, cols, rows, predictions=True)
    c = np.where((np.isfinite(err) & (err > 0.2))[:, None], pred, c)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3)
    for k in range(level, 0, -1):
        half = int(np.clip(np.floor(0.2 * _min_spacing(c, cols, rows)), 2, 4))
        c32 = np.ascontiguousarray(c, np.float32).reshape(-1, 1, 2)
        moved = cv2.cornerSubPix(gray.level(k), c32, (half, half), (-1, -1), criteria).reshape(-1, 2) - c
        c = c + np.where(np.linalg.norm(moved, axis=1, keepdims=True) < 2 * half, moved, 0.0)
        c = (c + 0.5) * 2.0 - 0.5
    return c


#: A grid with more suspect corners than this fraction (or half of an outer row or column) is not the board.
MAX_SUSPECT = 0.1


def _checked(gray: GrayImage, corners: np.ndarray, cols: int, rows: int,
             accurate_start: bool = False) -> tuple[np.ndarray | None, np.ndarray, str]:
    """Refined full-resolution corners and which are suspect, or None and why the grid is not the board.

    A corner is suspect when, after refinement, it is off the grid of its neighbours (:func:`grid_errors`;
    :func:`jcalib.vision.validate.consistent_points`, which also catches a skipped row), not an X-junction
    (:func:`jcalib.vision.locate.x_junction_check`) or not surrounded by the four squares of a checker pattern
    (:func:`checker_squares`). Isolated suspects (glare over a square, a corner
    dragged by a reflection) are left for the caller to drop; when half of an outer row or column is
    suspect the finder has numbered a shifted grid (its outer row made of border squares' outer corners:
    every real corner then carries a wrong index), and when more than :data:`MAX_SUSPECT` of the corners
    are, the grid is not trusted either.
    """
    spacing = _min_spacing(corners, cols, rows)
    if not spacing > 1.0:
        return None, np.zeros(0, bool), "corners coincide"
    refined = refine_corners(gray, corners, spacing, accurate_start)
    local = _local_spacing(refined, cols, rows)
    not_x, _ = x_junction_check(gray, refined, local)
    lattice = np.stack(np.meshgrid(np.arange(cols), np.arange(rows)), axis=-1).reshape(-1, 2).astype(np.float64)
    suspect = ((grid_errors(refined, cols, rows) > GRID_RTOL) | not_x | ~checker_squares(gray, refined, cols, rows)
               | ~consistent_points(lattice, refined))  # fmt: skip
    grid = suspect.reshape(rows, cols)
    outer = [grid[0], grid[-1], grid[:, 0], grid[:, -1]]
    if any(2 * np.sum(line) >= len(line) for line in outer):
        return None, suspect, ("half of an outer row or column of corners are not inner corners of a checker pattern "
                               "(a border square's outer corners standing in for a covered row or column?)")  # fmt: skip
    if np.sum(suspect) > MAX_SUSPECT * len(suspect):
        return None, suspect, (f"{int(np.sum(suspect))} of {len(suspect)} corners are off the grid or not inner corners "
                               "of a checker pattern")  # fmt: skip
    return refined, suspect, ""


def checker_squares(gray: GrayImage, corners: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """(N,) bool: each inner corner has the four squares of a checker pattern around it.

    The printed board has a square on every side of every inner corner (the border squares beyond the
    outer corners too, though a trimmed print may cut them narrower: OpenCV's left/right sample board).
    Around each corner the grey level is sampled 0.4 of the way to the centre of each of its four
    squares (the outer squares' centres extrapolated one spacing), smoothed over a tenth of a spacing:
    the two diagonal pairs must each be of one shade and the pairs of opposite shades; a pair differing
    by more than the contrast between the pairs fails (an invented corner on the board's edge: twice).
    Samples outside the image, and corners whose four
    values differ by less than a quarter of the board's median contrast (glare, shadow: nothing
    measurable), pass.
    """
    g = np.asarray(corners, np.float64).reshape(rows, cols, 2)
    ext = np.empty((rows + 2, cols + 2, 2))
    ext[1:-1, 1:-1] = g
    ext[1:-1, 0] = 2.0 * g[:, 0] - g[:, 1]
    ext[1:-1, -1] = 2.0 * g[:, -1] - g[:, -2]
    ext[0] = 2.0 * ext[1] - ext[2]
    ext[-1] = 2.0 * ext[-2] - ext[-3]
    centres = 0.25 * (ext[:-1, :-1] + ext[:-1, 1:] + ext[1:, :-1] + ext[1:, 1:])  # (rows + 1, cols + 1, 2)
    # the four squares around corner (i, j): a (i, j), b (i, j + 1), c (i + 1, j + 1), d (i + 1, j) of centres
    quad = np.stack([centres[:-1, :-1], centres[:-1, 1:], centres[1:, 1:], centres[1:, :-1]], axis=2)
    at = g[:, :, None, :] + 0.4 * (quad - g[:, :, None, :])  # (rows, cols, 4, 2)
    spacing = _local_spacing(corners, cols, rows)
    sigma = float(np.clip(0.1 * np.median(spacing), 0.5, 4.0))  # averages the noise over a fifth of a spacing
    reach = np.max(np.linalg.norm(at - g[:, :, None, :], axis=-1))
    half = int(np.ceil(min(reach, 2.0 * np.max(spacing)) + 4.0 * sigma + 2.0))
    centre = np.round(g.reshape(-1, 2)).astype(np.int64)
    image, origins = mosaic(gray.tiles(centre, half))
    local = at.reshape(-1, 4, 2) - centre[:, None, :] + half + origins[:, None, :]
    w, h = gray.size
    flat_at = at.reshape(-1, 4, 2)
    inside = np.all((flat_at[..., 0] >= 0) & (flat_at[..., 0] <= w - 1) & (flat_at[..., 1] >= 0)
                    & (flat_at[..., 1] <= h - 1) & (np.abs(local - origins[:, None, :] - half) <= half - 4.0 * sigma).all(-1),
                    axis=1)  # fmt: skip
    smooth = cv2.GaussianBlur(image, (0, 0), sigma)
    value = cv2.remap(smooth, local[..., 0].astype(np.float32), local[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE).astype(np.float64)  # fmt: skip
    a, b, c, d = (value[:, k] for k in range(4))
    between = np.abs(0.5 * (a + c) - 0.5 * (b + d))
    within = np.maximum(np.abs(a - c), np.abs(b - d))
    contrast = np.median(between[inside]) if np.any(inside) else 0.0
    measurable = inside & (np.maximum(between, within) > 0.25 * contrast)
    return ~measurable | (within <= between)


def _local_spacing(corners: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """(N,) distance of each corner to its nearest grid neighbour, px."""
    g = np.asarray(corners, np.float64).reshape(rows, cols, 2)
    d = np.full((rows, cols), np.inf)
    across = np.linalg.norm(np.diff(g, axis=1), axis=-1)
    down = np.linalg.norm(np.diff(g, axis=0), axis=-1)
    d[:, :-1] = np.minimum(d[:, :-1], across)
    d[:, 1:] = np.minimum(d[:, 1:], across)
    d[:-1] = np.minimum(d[:-1], down)
    d[1:] = np.minimum(d[1:], down)
    return d.reshape(-1)


def find_chessboard(gray: GrayImage, cols: int, rows: int, *, retry: bool = True,
                    contrast: float | None = None) -> GridFound:
    """All ``cols x rows`` inner corners in OpenCV's order, refined and checked (module docstring).

    Args:
        gray: the image.
        cols, rows: inner corners of the board.
        retry: run the attempts of :data:`jcalib.vision.attempts.GRID_ATTEMPTS` on the located region when
            the default passes find nothing.
        contrast: the image's grey-level spread, 0..1 (default: measured here).

    Returns:
        :class:`GridFound` (``pixels`` None when no checked grid was found).
    """
    from jcalib.vision.attempts import GRID_ATTEMPTS, prepare, to_original

    rejected: list[str] = []
    suspects: list[np.ndarray] = []

    def keep(c_level: np.ndarray | None, level: int, name: str) -> np.ndarray | None:
        """The grid found on ``level`` by attempt ``name``, refined and checked (None: rejected, recorded)."""
        if c_level is None:
            return None
        full, suspect, why = _checked(gray, _to_full(gray, c_level, level, cols, rows), cols, rows, level == 0)
        if full is None:
            rejected.append(f"{name}: {why}")
        suspects.append(suspect)
        return full

    def found(pixels, method, level, attempts, hint=None) -> GridFound:
        return GridFound(pixels, f"{method}@level{level}+cornerSubPix+saddle", attempts, tuple(rejected), hint,
                         suspects[-1])

    # 1. the fast pass: the whole image, reduced, with the classic finder's quick rejection
    k1 = level_with_side(gray, FAST_SIDE_PX)
    c, method = _classic_then_sb(gray.level(k1), cols, rows, _FAST_FLAGS, sb=False)
    pixels = keep(c, k1, "default")
    if pixels is not None:
        return found(pixels, method, k1, ("default",))
    # 2. where is a board, and how large are its squares?
    if contrast is None:
        contrast = image_stats(gray)[0]
    hint = locate_board(gray, contrast)
    tried = ["default"]
    if hint.lattice < plausible_lattice(cols, rows):
        return GridFound(None, "", tuple(tried), tuple(rejected), hint)
    crops = []
    for region in _search_regions(hint, gray):
        for level in sorted({region.level_for(FINDER_SQUARE_PX), region.level_for(2.0 * FINDER_SQUARE_PX)}, reverse=True):
            (x0, y0), (x1, y1) = np.round(to_level(np.array([region.roi[:2], region.roi[2:]]), level)).astype(int)
            lvl = gray.level(level)
            x0, y0 = max(0, x0), max(0, y0)
            crop = np.ascontiguousarray(lvl[y0:min(lvl.shape[0], y1 + 1), x0:min(lvl.shape[1], x1 + 1)])
            crops.append((level, crop, np.array([x0, y0], np.float64)))
    attempts = GRID_ATTEMPTS if retry else GRID_ATTEMPTS[:1]
    partial = None
    for a, attempt in enumerate(attempts):
        if a == 1:  # the defaults found nothing: is the board cut by the image border?
            partial = find_partial_chessboard(gray, hint)
            if partial is not None and partial[2] and partial[0] * partial[1] < cols * rows:
                return GridFound(None, "", tuple(tried), tuple(rejected), hint, partial=partial[:2])
        if attempt.name not in tried:
            tried.append(attempt.name)
        for level, crop, origin in crops:
            img = prepare(crop, attempt)
            if min(img.shape) < 16:
                continue
            c, method = _classic_then_sb(img, cols, rows, _FIND_FLAGS, sb=True)
            if c is not None:
                c = to_original(c, attempt) + origin
            pixels = keep(c, level, attempt.name)
            if pixels is not None:
                return found(pixels, method, level, tuple(tried), hint)
    if len(attempts) == 1:
        partial = find_partial_chessboard(gray, hint)
    return GridFound(None, "", tuple(tried), tuple(rejected), hint, partial=None if partial is None else partial[:2])


def _search_regions(hint: BoardHint, gray: GrayImage) -> list[Region]:
    """Where to search, on the level each region's squares suggest: the whole level image when it has
    at most :data:`CROP_PIXELS` (a crop that cuts the board's white border stops the finders); else the
    box around each region of lattice junctions, largest first, then the box around all of them (a steep
    or blurred board's lattice breaks into pieces), each widened by two spacings."""
    w, h = gray.size
    regions = []
    for r in list(hint.regions[:MAX_REGIONS]) + ([_union(hint.regions)] if len(hint.regions) > 1 else []):
        s = 2.0 * r.spacing_px
        grown = Region(r.lattice, r.spacing_px, (max(0, int(r.roi[0] - s)), max(0, int(r.roi[1] - s)),
                                                 min(w, int(r.roi[2] + s)), min(h, int(r.roi[3] + s))))  # fmt: skip
        if w * h / 4 ** r.level_for(FINDER_SQUARE_PX) <= CROP_PIXELS:
            grown = Region(r.lattice, r.spacing_px, (0, 0, w, h))
        if all((g.roi, g.level_for(FINDER_SQUARE_PX)) != (grown.roi, grown.level_for(FINDER_SQUARE_PX)) for g in regions):
            regions.append(grown)
    return regions


def _union(regions) -> Region:
    x0, y0 = (min(r.roi[i] for r in regions) for i in (0, 1))
    x1, y1 = (max(r.roi[i] for r in regions) for i in (2, 3))
    return Region(sum(r.lattice for r in regions), min(r.spacing_px for r in regions), (x0, y0, x1, y1))


def plausible_lattice(cols: int, rows: int) -> int:
    """Lattice junctions (:func:`jcalib.vision.locate.locate_board`) that make a ``cols x rows`` board
    plausible enough to search for: a sixth of its inner-most corners, at least 4 (measured: board-free
    cluttered scenes show 0-3, steep views of a 9x6 board from 0 up, most views over 10)."""
    return max(4, int(np.ceil((max(cols - 2, 1) * max(rows - 2, 1)) / 6.0)))


def find_partial_chessboard(gray: GrayImage, hint: BoardHint | None = None) -> tuple[int, int, bool] | None:
    """The largest chessboard of at least 3x3 inner corners found: ``(cols, rows, at_border)``, or None;
    ``at_border``: its outer corners come within 1.5 spacings of the image border (cut by it).

    With a ``hint`` only its largest region is searched, on the pyramid level its squares suggest (at least
    10 px); without one the whole image at full resolution (slow on large images)."""
    img, level, origin = gray.u8, 0, np.zeros(2)
    if hint is not None:
        if not hint.regions:
            return None
        region = _search_regions(hint, gray)[0]
        level = region.level_for(10.0)
        (x0, y0), (x1, y1) = np.round(to_level(np.array([region.roi[:2], region.roi[2:]]), level)).astype(int)
        lvl = gray.level(level)
        x0, y0 = max(0, x0), max(0, y0)
        img, origin = np.ascontiguousarray(lvl[y0:y1 + 1, x0:x1 + 1]), np.array([x0, y0], np.float64)
    try:
        ok, c, meta = cv2.findChessboardCornersSBWithMeta(img, (3, 3), flags=cv2.CALIB_CB_LARGER | cv2.CALIB_CB_EXHAUSTIVE)
    except cv2.error:
        return None
    if not ok or meta is None or c is None:
        return None
    rows, cols = meta.shape[:2]
    pts = from_level(c.reshape(-1, 2).astype(np.float64) + origin, level)
    w, h = gray.size
    near = np.min(np.stack([pts[:, 0], pts[:, 1], w - 1 - pts[:, 0], h - 1 - pts[:, 1]]), axis=0)
    spacing = _min_spacing(pts, cols, rows) if len(pts) == rows * cols and rows > 1 and cols > 1 else 0.0
    return (int(cols), int(rows), bool(np.min(near) < 1.5 * spacing))
