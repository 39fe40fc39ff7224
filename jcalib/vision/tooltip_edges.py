"""Sub-pixel edges of a dark tool on a backlight: the grey-level steps of
:func:`jcalib.vision.tooltip.detect_tool_tip`.

- **Levels** (:func:`estimate_backlight`): the backlight as a smooth polynomial surface fitted to a
  downsampled image (it absorbs vignetting and uneven illumination), so every pixel gets a
  normalised brightness ``n = (I - dark) / (backlight(x, y) - dark)``.
- **Edge points**: grey-level profiles perpendicular to an edge (bilinear sampling) give the
  position where ``n`` crosses 0.5 (a local linear fit of the transition); under a symmetric PSF the
  half-level crossing of a straight edge is unbiased.
- **Lines**: robust total-least-squares lines through the edge points (:func:`robust_line`), in
  undistorted pixels when a camera model is given (:class:`Lens`), so they are exact for any lens.
- **Cone and shaft** (:func:`fit_cone`, :func:`fit_shaft`): the two cone edges meet at the image of
  the apex, with a covariance from the line fits; the two shaft edges meet at the vanishing point of
  the tool axis.

Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from jcalib.errors import BadInputError, DetectionError

__all__ = ["BacklightLevels", "Lens", "backlight_image", "estimate_backlight", "extremum", "fit_cone", "fit_shaft",
           "robust_line"]


# --------------------------------------------------------------------------------------------------
# Levels: backlight surface and tool level


def _poly_terms(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    return np.stack([x**i * y**j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=-1)


@dataclass(frozen=True)
class BacklightLevels:
    """The backlight as a polynomial surface in normalised image coordinates, and the tool's grey level ``dark``."""

    dark: float
    coeffs: np.ndarray  # polynomial of the backlight in normalised coordinates
    degree: int
    size: tuple[int, int]
    bright_range: tuple[float, float]

    def backlight(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        w, h = self.size
        xn = (np.asarray(x, np.float64) - 0.5 * (w - 1)) / (0.5 * w)
        yn = (np.asarray(y, np.float64) - 0.5 * (h - 1)) / (0.5 * h)
        b = _poly_terms(xn, yn, self.degree) @ self.coeffs
        return np.clip(b, *self.bright_range)


def _lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations (A is small and well conditioned here)."""
    return np.linalg.solve(A.T @ A + 1e-12 * np.eye(A.shape[1]), A.T @ b)


def estimate_backlight(f: np.ndarray, min_contrast: float, name: str) -> tuple[BacklightLevels, float]:
    """The backlight as a smooth surface fitted to a downsampled image, rejecting dark samples (the
    tool) iteratively; raises ``not_found`` when the image is flat. The tool level is set later."""
    h, w = f.shape
    step = max(1, int(math.ceil(max(h, w) / 256)))
    small = cv2.resize(f, (max(1, w // step), max(1, h // step)), interpolation=cv2.INTER_AREA)
    lo, hi = (float(v) for v in np.percentile(small, [0.5, 99.5]))
    contrast = (float(f.max()) - float(f.min())) / 255.0
    if max(contrast, (hi - lo) / 255.0) < min_contrast or hi <= lo:
        raise DetectionError(
            f"{name}: no tool silhouette: the image is flat (contrast {(hi - lo) / 255.0:.3f}, expected >= "
            f"{min_contrast}); is the backlight on and the tool in view?",
            "not_found",
        )
    sh, sw = small.shape
    ys, xs = np.mgrid[0:sh, 0:sw]
    # small pixel (i, j) covers full-resolution pixels j*step .. (j+1)*step - 1
    xf = (xs * step + 0.5 * (step - 1)).ravel()
    yf = (ys * step + 0.5 * (step - 1)).ravel()
    vals = small.ravel().astype(np.float64)
    if vals.size > 6000:  # a smooth surface: a few thousand samples are plenty
        pick = np.linspace(0, vals.size - 1, 6000).astype(np.int64)
        xf, yf, vals = xf[pick], yf[pick], vals[pick]
    # start from Otsu's bright class when the histogram is clearly bimodal (a large tool), else all
    u8 = np.clip(np.round((vals - lo) * (255.0 / (hi - lo))), 0, 255).astype(np.uint8)
    otsu, _ = cv2.threshold(u8.reshape(1, -1), 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    thr = lo + (otsu + 0.5) * (hi - lo) / 255.0
    upper, lower = vals[vals > thr], vals[vals <= thr]
    keep = vals > thr if lower.size and upper.size and np.median(lower) < 0.5 * np.median(upper) else vals > -1.0
    xn = (xf - 0.5 * (w - 1)) / (0.5 * w)
    yn = (yf - 0.5 * (h - 1)) / (0.5 * h)
    degree = 0
    for _ in range(4):
        frac = keep.mean()
        degree = 4 if frac > 0.3 and keep.sum() > 200 else (2 if frac > 0.1 and keep.sum() > 50 else 0)
        A = _poly_terms(xn, yn, degree)
        coeffs = _lstsq(A[keep], vals[keep])
        fit = A @ coeffs
        res = vals - fit
        mad = 1.4826 * float(np.median(np.abs(res[keep] - np.median(res[keep])))) + 1e-3
        new = res > -np.maximum(4.0 * mad, 0.05 * np.abs(fit))
        if np.array_equal(new, keep) or new.sum() < 10:
            break
        keep = new
    bright = vals[keep]
    bmin, bmax = float(np.percentile(bright, 0.5)), float(bright.max())
    levels = BacklightLevels(dark=0.0, coeffs=coeffs, degree=degree, size=(w, h), bright_range=(bmin, bmax))
    return levels, contrast


# --------------------------------------------------------------------------------------------------
# Lines


def _fit_line_tls(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Total least squares line: (centroid (2,), unit direction (2,), rms orthogonal residual)."""
    wts = np.ones(len(points)) if weights is None else weights
    c = (wts[:, None] * points).sum(0) / wts.sum()
    d = points - c
    cov = (wts[:, None, None] * d[:, :, None] * d[:, None, :]).sum(0) / wts.sum()
    evals, evecs = np.linalg.eigh(cov)
    direction = evecs[:, 1]
    rms = math.sqrt(max(float(evals[0]), 0.0))
    return c, direction, rms


def robust_line(points: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """TLS line with iterative rejection of points beyond 3 robust sigmas. Returns centroid,
    direction, rms of inliers, inlier mask."""
    keep = np.ones(len(points), dtype=bool)
    c, d, rms = _fit_line_tls(points)
    for _ in range(iterations):
        normal = np.array([-d[1], d[0]])
        r = (points - c) @ normal
        sigma = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep])))) + 1e-4
        new = np.abs(r - np.median(r[keep])) <= 3.0 * sigma
        if new.sum() < 4 or np.array_equal(new, keep):
            break
        keep = new
        c, d, rms = _fit_line_tls(points[keep])
    return c, d, rms, keep


def _line_cov(points: np.ndarray, c: np.ndarray, d: np.ndarray, rms: float) -> np.ndarray:
    """Covariance of the line parameters (offset along the normal at c, angle) from point scatter."""
    s = (points - c) @ d
    n = len(points)
    var = max(rms, 1e-6) ** 2 * n / max(n - 2, 1)
    return np.diag([var / n, var / max(float((s**2).sum()), 1e-9)])


def _intersect(c1: np.ndarray, d1: np.ndarray, c2: np.ndarray, d2: np.ndarray) -> np.ndarray | None:
    """Intersection of lines c1 + s d1 and c2 + t d2, None when (nearly) parallel."""
    M = np.column_stack([d1, -d2])
    det = float(np.linalg.det(M))
    if abs(det) < 1e-6:
        return None
    st = np.linalg.solve(M, c2 - c1)
    return c1 + st[0] * d1


# --------------------------------------------------------------------------------------------------
# Sub-pixel edge points


def _edge_points(
    f: np.ndarray,
    levels: BacklightLevels,
    anchors: np.ndarray,
    normal: np.ndarray,
    half_window: float,
    sigma: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Half-level crossings of profiles through ``anchors`` (N, 2) along ``normal`` (2,) (pointing
    from the tool to the backlight). Returns the edge points (M, 2) and the profile slopes (M,) in
    normalised brightness per px."""
    if len(anchors) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    step = 0.25
    q = np.arange(-half_window, half_window + 1e-9, step)
    pts = anchors[:, None, :] + q[None, :, None] * normal[None, None, :]
    mapx = pts[..., 0].astype(np.float32)
    mapy = pts[..., 1].astype(np.float32)
    prof = cv2.remap(f, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    back = levels.backlight(pts[..., 0], pts[..., 1])
    n = (prof - levels.dark) / np.maximum(back - levels.dark, 1e-6)
    above = n >= 0.5
    change = above[:, 1:] != above[:, :-1]
    idx = np.arange(len(q) - 1)
    # the crossing nearest to the anchor
    dist = np.where(change, np.abs(idx + 0.5 - (len(q) - 1) / 2.0), np.inf)
    k = np.argmin(dist, axis=1)
    ok = np.isfinite(dist[np.arange(len(k)), k])
    # local linear fit of n(q) over +-0.75 px around the crossing
    half = 3  # +-0.75 px: the transition of an edge blurred by >= 0.5 px is nearly linear there
    rows = np.nonzero(ok)[0]
    if rows.size == 0:
        return np.zeros((0, 2)), np.zeros(0)
    j = k[rows, None] + np.arange(-half + 1, half + 1)[None, :]
    wts = ((j >= 0) & (j < len(q))).astype(np.float64)
    j = np.clip(j, 0, len(q) - 1)
    qq = q[j]
    nn = n[rows[:, None], j]
    sw = wts.sum(1)
    mq = (wts * qq).sum(1) / sw
    mn = (wts * nn).sum(1) / sw
    sqq = (wts * (qq - mq[:, None]) ** 2).sum(1)
    sqn = (wts * (qq - mq[:, None]) * (nn - mn[:, None])).sum(1)
    slope = sqn / np.maximum(sqq, 1e-12)
    qc = mq + (0.5 - mn) / np.where(slope > 1e-3, slope, 1.0)
    good = (slope > 1e-3) & (qc >= qq.min(1) - step) & (qc <= qq.max(1) + step)
    pts_out = anchors[rows[good]] + qc[good, None] * normal[None, :]
    return pts_out, slope[good]


# --------------------------------------------------------------------------------------------------
# Lens (optional): edge lines are straight in undistorted pixels


class Lens:
    """Undistorts edge points (and distorts results back) with a camera model's OpenCV parameters; the
    identity without one."""

    def __init__(self, camera: Any):
        self.camera = camera
        if camera is None:
            return
        if not hasattr(camera, "to_opencv"):
            raise BadInputError(f"camera: got {type(camera).__name__}, expected a jcalib camera model or None")
        K, dist = camera.to_opencv()
        self.K = np.asarray(K, np.float64)
        self.dist = np.asarray(dist, np.float64)
        self.fisheye = getattr(camera, "name", "") == "fisheye"

    def undistort(self, pts: np.ndarray) -> np.ndarray:
        if self.camera is None or len(pts) == 0:
            return pts
        p = np.ascontiguousarray(pts, np.float64).reshape(-1, 1, 2)
        if self.fisheye:
            u = cv2.fisheye.undistortPoints(p, self.K, self.dist, P=self.K)
        else:
            u = cv2.undistortPointsIter(
                p, self.K, self.dist, np.eye(3), self.K, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
            )
        return u.reshape(-1, 2)

    def distort(self, pts: np.ndarray) -> np.ndarray:
        if self.camera is None or len(pts) == 0:
            return pts
        Kinv = np.linalg.inv(self.K)
        h = np.column_stack([pts, np.ones(len(pts))]) @ Kinv.T
        obj = h.reshape(-1, 1, 3)
        zero = np.zeros(3)
        if self.fisheye:
            out, _ = cv2.fisheye.projectPoints(obj, zero, zero, self.K, self.dist)
        else:
            out, _ = cv2.projectPoints(obj, zero, zero, self.K, self.dist)
        return out.reshape(-1, 2)


# --------------------------------------------------------------------------------------------------
# Cone and shaft


def backlight_image(levels: BacklightLevels, w: int, h: int) -> np.ndarray:
    """Backlight surface on the full grid, float32 (evaluated on a coarse grid and resized)."""
    step = 8
    xs = np.arange(0, w + step, step, dtype=np.float64)
    ys = np.arange(0, h + step, step, dtype=np.float64)
    X, Y = np.meshgrid(xs, ys)
    coarse = levels.backlight(X, Y).astype(np.float32)
    mapx = (np.arange(w, dtype=np.float32) / step)[None, :].repeat(h, 0)
    mapy = (np.arange(h, dtype=np.float32) / step)[:, None].repeat(w, 1)
    return cv2.remap(coarse, mapx, mapy, cv2.INTER_LINEAR)


def extremum(f: np.ndarray, levels: BacklightLevels, tip0: np.ndarray, axis: np.ndarray, sigma: float) -> np.ndarray:
    """Sub-pixel half-level crossing along the axis through the coarse tip."""
    pts, _ = _edge_points(f, levels, tip0[None, :], -axis, 3.0 * sigma + 3.0, sigma)
    return pts[0] if len(pts) else tip0.copy()


def _edge_anchor_points(
    tip0: np.ndarray, axis: np.ndarray, normal: np.ndarray, s: np.ndarray, t: np.ndarray, s_lo: float, s_hi: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Anchors every 0.5 px along a coarse edge line (fitted to the mask contour between s_lo and s_hi),
    and the edge's outward normal."""
    sel = (s >= s_lo) & (s <= s_hi)
    if sel.sum() < 3:
        return None
    pts = tip0[None, :] + s[sel, None] * axis[None, :] + t[sel, None] * normal[None, :]
    c, d, _, _ = robust_line(pts)
    d = d if d @ axis > 0 else -d
    a0 = (tip0 + s_lo * axis - c) @ d
    a1 = (tip0 + s_hi * axis - c) @ d
    u = np.arange(a0, a1 + 1e-9, 0.5)
    anchors = c[None, :] + u[:, None] * d[None, :]
    out = np.array([-d[1], d[0]])
    if out @ (c - tip0 - ((c - tip0) @ axis) * axis) < 0:
        out = -out
    return anchors, out


def _fit_edges(
    f: np.ndarray,
    levels: BacklightLevels,
    lens: Lens,
    anchors_normals: list[tuple[np.ndarray, np.ndarray]],
    sigma: float,
    size: tuple[int, int],
    margin: float,
) -> list[dict] | None:
    w, h = size
    out = []
    half_window = 3.0 * sigma + 2.0
    for anchors, nrm in anchors_normals:
        inside = (
            (anchors[:, 0] >= margin + half_window)
            & (anchors[:, 1] >= margin + half_window)
            & (anchors[:, 0] <= w - 1 - margin - half_window)
            & (anchors[:, 1] <= h - 1 - margin - half_window)
        )
        pts, slopes = _edge_points(f, levels, anchors[inside], nrm, half_window, sigma)
        if len(pts) < 6:
            return None
        und = lens.undistort(pts)
        c, d, rms, keep = robust_line(und)
        if keep.sum() < 6:
            return None
        out.append({"c": c, "d": d, "rms": rms, "pts": und[keep], "slopes": slopes[keep], "n": int(keep.sum())})
    return out


def fit_cone(f, levels, lens, tip0, axis, normal, s, left, right, cone_slope, cone_end, sigma, clear, max_len,
             size, margin) -> dict | None:
    """Steps 5 and 6: sub-pixel edge lines of the cone and their intersection, the tip.

    Profiles are kept where the cone is at least ``clear`` px wide on each side of the axis and as
    far from the cone/shaft corner, over at most ``max_len`` px. Returns None when the cone is too
    small or its edges are (nearly) parallel; else a dict with ``tip`` (2,) px, ``tip_std`` px (from
    the line fits), ``sigma`` (the measured edge blur), ``n_points``, ``rms``, ``angle_deg`` (between
    the edges), ``bisector`` (unit image direction into the tool) and ``warnings``.
    """
    # keep profiles where the cone is at least ``clear`` px wide on each side of the axis (with
    # 1.5 sigma the other edge shifts the half-level crossing by < 0.01 sigma), and away from the
    # cone/shaft corner by the same amount
    if cone_slope <= 1e-3:
        return None
    s_lo = max(2.0 * clear / cone_slope, 1.0)
    s_hi = min(cone_end - clear - 0.5, s_lo + max_len)
    if s_hi - s_lo < 3.0:
        return None
    sides = []
    for t in (left, right):
        a = _edge_anchor_points(tip0, axis, normal, s, t, s_lo, s_hi)
        if a is None:
            return None
        sides.append(a)
    fits = _fit_edges(f, levels, lens, sides, sigma, size, margin)
    if fits is None:
        return None
    l1, l2 = fits
    tip_u = _intersect(l1["c"], l1["d"], l2["c"], l2["d"])
    if tip_u is None:
        return None
    tip = lens.distort(tip_u[None, :])[0]
    warnings: list[str] = []
    if np.linalg.norm(tip - tip0) > 3.0 * sigma + 5.0:  # (nearly) parallel edges: not a cone tip
        return None
    # tip covariance by propagating the line-parameter covariances (numerical Jacobian)
    covs = [_line_cov(L["pts"], L["c"], L["d"], L["rms"]) for L in fits]

    def tip_of(p: np.ndarray) -> np.ndarray:
        lines = []
        for L, (off, ang) in zip(fits, (p[:2], p[2:])):
            ca, sa = math.cos(ang), math.sin(ang)
            d = np.array([ca * L["d"][0] - sa * L["d"][1], sa * L["d"][0] + ca * L["d"][1]])
            n = np.array([-L["d"][1], L["d"][0]])
            lines.append((L["c"] + off * n, d))
        x = _intersect(lines[0][0], lines[0][1], lines[1][0], lines[1][1])
        return tip_u if x is None else x

    J = np.zeros((2, 4))
    for i in range(4):
        e = np.zeros(4)
        e[i] = 1e-6
        J[:, i] = (tip_of(e) - tip_of(-e)) / 2e-6
    P = np.zeros((4, 4))
    P[:2, :2] = covs[0]
    P[2:, 2:] = covs[1]
    C = J @ P @ J.T
    tip_std = float(math.sqrt(max(np.trace(C), 0.0) / 2.0))
    # blur: a Gaussian-blurred unit step rises with slope 1 / (sqrt(2 pi) sigma) at its middle
    slope = float(np.median(np.concatenate([L["slopes"] for L in fits])))
    sigma_new = float(np.clip(1.0 / (math.sqrt(2.0 * math.pi) * max(slope, 1e-3)), 0.5, 20.0))
    d1 = fits[0]["d"] if fits[0]["d"] @ axis > 0 else -fits[0]["d"]
    d2 = fits[1]["d"] if fits[1]["d"] @ axis > 0 else -fits[1]["d"]
    bis = d1 + d2
    bis = bis / float(np.linalg.norm(bis))
    if lens.camera is not None:
        p2 = lens.distort(np.array([tip_u + 0.5 * bis]))[0]
        bis = (p2 - tip) / max(float(np.linalg.norm(p2 - tip)), 1e-12)
    angle = math.degrees(math.acos(float(np.clip(d1 @ d2, -1.0, 1.0))))
    return {
        "tip": tip,
        "tip_std": tip_std,
        "sigma": sigma_new,
        "n_points": [fits[0]["n"], fits[1]["n"]],
        "rms": [fits[0]["rms"], fits[1]["rms"]],
        "angle_deg": angle,
        "bisector": bis,
        "warnings": warnings,
    }


def fit_shaft(f, levels, lens, tip0, axis, normal, s, left, right, cone_end, sigma, max_len, size,
              margin) -> list[np.ndarray] | None:
    """Homogeneous lines (undistorted pixels) of the two shaft edges, or None when not visible enough."""
    if len(s) < 10:
        return None
    clear = 2.0 * sigma + 2.0
    s_lo = cone_end + clear
    s_hi = min(float(s[-1]) - clear, s_lo + max_len)
    if s_hi - s_lo < 10.0:
        return None
    sides = []
    for t in (left, right):
        a = _edge_anchor_points(tip0, axis, normal, s, t, s_lo, s_hi)
        if a is None:
            return None
        sides.append(a)
    fits = _fit_edges(f, levels, lens, sides, sigma, size, margin)
    if fits is None:
        return None
    lines = []
    for L in fits:
        n = np.array([-L["d"][1], L["d"][0]])
        lines.append(np.array([n[0], n[1], -float(n @ L["c"])]))
    return lines
