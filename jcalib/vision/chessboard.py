"""Chessboard corners: ``cv2.findChessboardCorners`` + ``cornerSubPix`` + a saddle-point fit, SB as fallback
(also when a corner of the classic finder's grid is off the grid its neighbours define).

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

import cv2
import numpy as np

from jcalib.vision.image import GrayImage

__all__ = ["find_chessboard", "refine_corners", "find_partial_chessboard", "grid_error"]

_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE


def refine_corners(gray: GrayImage, corners: np.ndarray, spacing_px: float) -> np.ndarray:
    """Sub-pixel X-junction positions from rough ones (``cornerSubPix``, then the saddle-point fit).

    Args:
        gray: the image.
        corners: (N, 2) rough corners, px.
        spacing_px: smallest distance between neighbouring corners in the image, px (sets the windows).

    Returns:
        (N, 2) float64 refined corners, px (OpenCV convention). A corner whose saddle fit does not
        converge within 1 px of the ``cornerSubPix`` result keeps that result.
    """
    half = int(np.clip(np.floor(0.35 * spacing_px), 2, 10))
    sigma = float(np.clip(0.25 * half + 0.75, 1.0, 2.5))
    smooth = cv2.GaussianBlur(gray.f32, (0, 0), sigma)
    c = np.ascontiguousarray(corners, dtype=np.float32).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-5)
    refined = cv2.cornerSubPix(smooth, c, (half, half), (-1, -1), criteria).reshape(-1, 2).astype(np.float64)
    return saddle_points(gray, refined, spacing_px)


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


def saddle_points(gray: GrayImage, corners: np.ndarray, spacing_px: float, iterations: int = 12) -> np.ndarray:
    """Stationary points of a quadratic fitted around each corner (see the module docstring)."""
    half = int(np.clip(np.round(_SADDLE_F * spacing_px), 2, _SADDLE_MAX))
    smooth = cv2.GaussianBlur(gray.f32, (0, 0), _SADDLE_S * half)
    n = 2 * half + 1
    y, x = np.mgrid[-half:half + 1, -half:half + 1].astype(np.float64)
    A = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1).reshape(-1, 6)
    w = np.exp(-(x * x + y * y) / (2.0 * (half / 1.5) ** 2)).reshape(-1)
    P = np.linalg.pinv(A * w[:, None]) * w[None, :]  # (6, n*n): weighted least-squares fit
    start = np.asarray(corners, np.float64)
    cur = start.copy()
    active = np.ones(len(cur), bool)
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
    far = np.linalg.norm(cur - start, axis=1) > 1.0
    return np.where(far[:, None] | ~np.isfinite(cur), start, cur)


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
    """How far the worst corner of a ``cols x rows`` grid (OpenCV's order) sits from where its neighbours
    put it, in units of the local spacing (0 for grids narrower than 3 corners; inf when not finite).

    Every corner's 3x3 block (shifted inwards at the border) gives 8 other corners: their homography from
    the lattice (a DLT per block, all blocks at once, in block-normalised pixels) predicts the corner.
    Perspective keeps a real corner on it; lens distortion bends the grid slowly over two squares.
    """
    if cols < 3 or rows < 3:
        return 0.0
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
        return float("inf")
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
        err = np.linalg.norm(q[:, :2, 0] / q[:, 2:, 0] - u[n, k], axis=-1)
    return float(np.max(err)) if np.all(np.isfinite(err)) else float("inf")


def find_chessboard(gray: GrayImage, cols: int, rows: int, *, retry: bool = True) -> tuple[np.ndarray | None, str, tuple[str, ...]]:
    """All ``cols x rows`` inner corners in OpenCV's order, refined, or None.

    Each attempt of :data:`jcalib.vision.attempts.GRID_ATTEMPTS` (only the first unless ``retry``)
    runs ``findChessboardCorners`` on its prepared image, and ``findChessboardCornersSB`` when that finds
    nothing or a grid with a corner off it (:func:`grid_error` above :data:`GRID_RTOL`; the grid that fits
    better is kept); the first board found is mapped back to the original pixels and refined there.

    Returns:
        ((cols*rows, 2) float64 px or None, name of the finder that succeeded, names of the attempts run).
    """
    from jcalib.vision.attempts import GRID_ATTEMPTS, prepare, to_original

    tried: list[str] = []
    for attempt in GRID_ATTEMPTS if retry else GRID_ATTEMPTS[:1]:
        tried.append(attempt.name)
        img = prepare(gray.u8, attempt)
        ok, c = cv2.findChessboardCorners(img, (cols, rows), flags=_FIND_FLAGS)
        method = "findChessboardCorners"
        error = grid_error(c.reshape(-1, 2), cols, rows) if ok and c is not None else float("inf")
        if error > GRID_RTOL:
            # not found, or a corner off the grid: the classic finder now and then returns a border
            # square's outer corner for an inner one, a spacing away (seen: a rendered 8x5 board at
            # 320x240, one corner 14 px off); the SB finder's grid replaces it when it fits better
            ok_sb, c_sb = cv2.findChessboardCornersSB(img, (cols, rows), flags=cv2.CALIB_CB_EXHAUSTIVE)
            if ok_sb and c_sb is not None and grid_error(c_sb.reshape(-1, 2), cols, rows) < error:
                ok, c, method = True, c_sb, "findChessboardCornersSB"
        if not ok or c is None:
            continue
        c = to_original(c.reshape(-1, 2).astype(np.float64), attempt)
        return refine_corners(gray, c, _min_spacing(c, cols, rows)), method + "+cornerSubPix+saddle", tuple(tried)
    return None, "", tuple(tried)


def find_partial_chessboard(gray: GrayImage) -> tuple[int, int] | None:
    """Size (cols, rows) of the largest chessboard of at least 3x3 inner corners found, or None."""
    try:
        ok, c, meta = cv2.findChessboardCornersSBWithMeta(
            gray.u8, (3, 3), flags=cv2.CALIB_CB_LARGER | cv2.CALIB_CB_EXHAUSTIVE
        )
    except cv2.error:
        return None
    if not ok or meta is None:
        return None
    return (int(meta.shape[1]), int(meta.shape[0]))
