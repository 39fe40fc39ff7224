"""Sub-pixel corners of dark squares on white from their edges (the outer corners of AprilTags).

A tag's outer corner is an L-junction: one dark quadrant on white. A blur rounds such a corner, which
moves any fit of the corner itself, but leaves a straight edge where it is: a symmetric blur of a
step keeps its 50 % level on the step. So each side of the square is located by sub-pixel edge points
along its middle part, a curve is fitted to them, and a corner is where two adjacent sides' curves
meet. Everything is vectorised over all sides of all squares of an image.

- **Edge points.** Across each side, a profile of the (lightly smoothed) image is sampled from inside
  to outside; an edge point is where it rises through the mean of its two ends' levels, the crossing
  nearest the previous estimate (the levels are fitted along the side as a line: less noise, and
  illumination changes slowly along it). A first pass, from corners that may be half a cell off, takes
  the steepest dark-to-light step of a wider profile instead.
- **Curves.** A parabola per side (least squares, points more than 4 robust σ off a line dropped): lens
  distortion bends a straight edge, and a line's corner is off by up to the bend's sagitta (measured on
  rendered 4x3 grids through k1 = -0.3: 0.084 px RMS for lines, 0.032 px for parabolas; on single
  100-150 px tags through k1 = -0.1, the hand-eye of ``tests/problems/test_apriltag_handeye.py`` was off
  by up to 31 in Mahalanobis² with lines, at most 13 with parabolas, χ²(6) 99.73 %: 20). A parabola
  extrapolated to the corner is noisier (0.13 against 0.09 px σ̂ there), so a rough start takes lines.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np

from jcalib.vision.image import GrayImage

__all__ = ["refine_square_corners"]

#: Edge points per side, spread over this middle part of it.
_POINTS = 32
_SPAN = (0.1, 0.9)
#: Samples of a profile across a side.
_SAMPLES = 25
#: Smallest step between the levels inside and outside (grey levels of 0..255) of a usable edge point.
_MIN_STEP = 8.0


def _bilinear(img: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """``img`` at float positions (pixel centres at integers), bilinear in float64 weights (``cv2.remap``
    quantises them to 1/32 px), clamped at the border."""
    h, w = img.shape
    xs = np.clip(xs, 0.0, w - 1.000001)
    ys = np.clip(ys, 0.0, h - 1.000001)
    x0, y0 = xs.astype(np.intp), ys.astype(np.intp)  # floor: non-negative
    fx, fy = xs - x0, ys - y0
    i = y0 * w + x0
    flat = img.reshape(-1)
    top = flat[i] + fx * (flat[i + 1] - flat[i])
    bottom = flat[i + w] + fx * (flat[i + w + 1] - flat[i + w])
    return top + fy * (bottom - top)


def _weighted_fit(x: np.ndarray, y: np.ndarray, w: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-row polynomial fits ``y ≈ Σ c_k x^k`` (rows of (S, P) arrays, weights ``w``): ``(c (S, degree+1),
    standard errors (S, degree+1))``."""
    A = np.stack([x**k for k in range(degree + 1)], axis=-1)  # (S, P, d+1)
    Aw = A * w[..., None]
    N = np.swapaxes(Aw, 1, 2) @ A + 1e-12 * np.eye(degree + 1)
    c = np.linalg.solve(N, (Aw * y[..., None]).sum(axis=1)[..., None])[..., 0]
    r = y - (A @ c[..., None])[..., 0]
    dof = np.maximum(w.sum(axis=1) - degree - 1, 1.0)
    var = (w * r * r).sum(axis=1) / dof
    se = np.sqrt(np.maximum(var[:, None] * np.diagonal(np.linalg.inv(N), axis1=1, axis2=2), 0.0))
    return c, se


def _edges(smooth: np.ndarray, p0: np.ndarray, p1: np.ndarray, outward: np.ndarray, half: np.ndarray,
           steepest: bool, curved: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edge curves of sides p0 -> p1 ((S, 2) each, ``outward`` unit normals, profiles ``half`` px each
    way): ``(d (S, 2) unit directions, c (S, 3) offset polynomial in tau (px from p0), ok (S,))``; a
    parabola with ``curved`` (and not ``steepest``), else a line."""
    length = np.linalg.norm(p1 - p0, axis=1)
    d = (p1 - p0) / np.maximum(length, 1e-9)[:, None]
    t = np.linspace(*_SPAN, _POINTS)
    tau = length[:, None] * t[None, :]  # (S, P)
    s = half[:, None] * np.linspace(-1.0, 1.0, _SAMPLES)[None, :]  # (S, Q)
    xy = (p0[:, None, None, :] + tau[:, :, None, None] * d[:, None, None, :]
          + s[:, None, :, None] * outward[:, None, None, :])  # (S, P, Q, 2)
    prof = _bilinear(smooth, xy[..., 0], xy[..., 1])  # (S, P, Q): dark inside -> light outside
    step_px = s[:, 1] - s[:, 0]
    if steepest:
        jump = np.diff(prof, axis=2)
        i = np.argmax(jump, axis=2)
        offset = np.take_along_axis(s, i, axis=1) + 0.5 * step_px[:, None]
        best = np.take_along_axis(jump, i[..., None], axis=2)[..., 0]
        good = best > 0.5 * np.median(best, axis=1, keepdims=True)
    else:
        ends = np.stack([prof[..., 0], prof[..., -1]], axis=-1)  # (S, P, 2)
        V = np.stack([np.ones_like(t), t], axis=-1)
        lo, hi = np.moveaxis(V @ (np.linalg.pinv(V) @ ends), -1, 0)  # levels fitted along each side
        level = 0.5 * (lo + hi)
        # the rising crossing of the mid level nearest the profile's centre (the previous estimate). An
        # area (integral) estimate would be pulled by any error of the levels times the window's length:
        # measured on rendered single tags, 0.03-0.06 px outward on average against 0.01-0.03 px here
        above = prof >= level[..., None]
        rising = ~above[..., :-1] & above[..., 1:]  # (S, P, Q-1): a crossing between samples q and q+1
        centre = 0.5 * (s[:, :-1] + s[:, 1:])  # (S, Q-1)
        dist = np.where(rising, np.abs(centre)[:, None, :], np.inf)
        i = np.argmin(dist, axis=2)
        good = ((hi - lo) > _MIN_STEP) & np.isfinite(np.take_along_axis(dist, i[..., None], axis=2)[..., 0])
        a = np.take_along_axis(prof, i[..., None], axis=2)[..., 0]
        b = np.take_along_axis(prof, (i + 1)[..., None], axis=2)[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.clip(np.where(b > a, (level - a) / (b - a), 0.5), 0.0, 1.0)
        offset = np.take_along_axis(s, i, axis=1) + frac * step_px[:, None]
    w = good.astype(np.float64)
    for _ in range(2):  # fit, then once more without the points far off the line (a speck, a bit)
        c, _ = _weighted_fit(tau, offset, w, 1)
        r = offset - c[:, :1] - c[:, 1:2] * tau
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a side without edge points: all NaN
            mad = 1.4826 * np.nanmedian(np.where(w > 0, np.abs(r), np.nan), axis=1) + 0.02
        w = w * (np.abs(r) <= 4.0 * np.nan_to_num(mad, nan=np.inf)[:, None])
    ok = w.sum(axis=1) >= 8
    c = np.concatenate([c, np.zeros((len(c), 1))], axis=1)
    if curved and not steepest:
        mid, scale = tau.mean(axis=1, keepdims=True), np.maximum(tau.std(axis=1, keepdims=True), 1e-9)
        q, _ = _weighted_fit((tau - mid) / scale, offset, w, 2)  # normalised: well conditioned
        m, k = mid[:, 0], scale[:, 0]
        c = np.stack([q[:, 0] - q[:, 1] * m / k + q[:, 2] * m * m / (k * k),
                      q[:, 1] / k - 2.0 * q[:, 2] * m / (k * k), q[:, 2] / (k * k)], axis=1)  # back to tau
    return d, c, ok


def _meet(pa, da, na, ca, la, pb, db, nb, cb) -> np.ndarray:
    """(C, 2) where the end of curve a (length ``la``) meets the start of curve b (Newton, vectorised)."""
    ta, tb = la.copy(), np.zeros_like(la)

    def at(p, d, n, c, t):
        return p + t[:, None] * d + (c[:, 0] + c[:, 1] * t + c[:, 2] * t * t)[:, None] * n

    def slope(d, n, c, t):
        return d + (c[:, 1] + 2.0 * c[:, 2] * t)[:, None] * n

    for _ in range(8):
        f = at(pb, db, nb, cb, tb) - at(pa, da, na, ca, ta)
        J = np.stack([slope(da, na, ca, ta), -slope(db, nb, cb, tb)], axis=-1)  # (C, 2, 2)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        safe = np.abs(det) > 1e-9
        step = np.linalg.solve(np.where(safe[:, None, None], J, np.eye(2)), f[..., None])[..., 0]
        step = np.where(safe[:, None], step, np.nan)
        ta, tb = ta + step[:, 0], tb + step[:, 1]
        if np.all(~np.isfinite(step) | (np.abs(step) < 1e-7)):
            break
    return at(pa, da, na, ca, ta)


def refine_square_corners(gray: GrayImage, corners: np.ndarray, border: float, passes: int = 3,
                          curved: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The outer corners of dark squares from their sides' edges (module docstring).

    Args:
        gray: the image.
        corners: (M, 4, 2) rough corners of each square, in order around it, px.
        border: width of the squares' dark border over their side (how far an edge is looked for: a whole
            width each way in the first pass, half of it in the others; across each side, the square's
            width there is its area over that side's length: a foreshortened square is narrow across
            its long sides).
        passes: fits, each around the corners of the previous one.
        curved: fit the edges as parabolas (module docstring), else as lines.

    Returns:
        ``(pixels (M, 4, 2), ok (M, 4))``: refined corners, and whether both sides meeting there were fitted.
    """
    smooth = cv2.GaussianBlur(gray.f32, (0, 0), 0.7)
    cur = np.asarray(corners, np.float64).copy()
    m = len(cur)
    ok = np.zeros((m, 4), bool)
    if m == 0:
        return cur, ok
    for npass in range(passes):
        p0 = cur.reshape(-1, 2)
        p1 = np.roll(cur, -1, axis=1).reshape(-1, 2)  # side k: corner k -> corner k+1
        d = p1 - p0
        out = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)[:, None]
        mid = 0.5 * (p0 + p1) - np.repeat(cur.mean(axis=1), 4, axis=0)
        out *= np.where(np.sum(mid * out, axis=1) < 0, -1.0, 1.0)[:, None]  # pointing away from the centre
        x, y = cur[..., 0], cur[..., 1]
        area = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))  # (M,)
        across = np.repeat(area, 4) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)  # width across each side
        half = border * across * (1.0 if npass == 0 else 0.5)
        dirs, coef, fitted = _edges(smooth, p0, p1, out, half, steepest=npass == 0, curved=curved)
        a = (np.arange(4 * m).reshape(m, 4) + 3) % 4 + 4 * np.arange(m)[:, None]  # side k-1 ends at corner k
        a, b = a.reshape(-1), np.arange(4 * m)
        la = np.linalg.norm(p1 - p0, axis=1)[a]
        new = _meet(p0[a], dirs[a], out[a], coef[a], la, p0[b], dirs[b], out[b], coef[b]).reshape(m, 4, 2)
        ok = (fitted[a] & fitted[b]).reshape(m, 4) & np.all(np.isfinite(new), axis=-1)
        cur = np.where(ok[..., None], new, cur)
    return cur, ok
