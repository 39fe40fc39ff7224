"""Tool-tip detection: the tip of a rotationally symmetric tool (pin, needle, torch) on a backlight.

The pipeline follows camera-based TCP calibration (Toffano 2015), with a sub-pixel refinement that
uses the geometry of a cone's silhouette:

1. **Levels.** The image is converted to grey (:func:`jcalib.vision.image.to_gray`). A first Otsu
   threshold splits backlight from tool; the backlight is then modelled by a smooth polynomial
   surface (it absorbs vignetting and uneven illumination) and the tool by its median grey level, so
   every pixel gets a normalised brightness ``n = (I - dark) / (backlight(x, y) - dark)``.
2. **Silhouette.** ``n < 0.5`` with a morphological opening and closing, then connected components:
   no component → ``not_found``; two or more comparable components → ``ambiguous``.
3. **Axis and coarse tip.** The silhouette of a convex tool is convex. When it leaves the image (the
   shaft usually does), the coarse tip is the silhouette point farthest from where it crosses the
   border; otherwise it is the narrower end of the principal (PCA) axis. The axis is refined as the
   line through the mid-points of the silhouette's cross-sections (the skeleton of a symmetric
   silhouette). A coarse tip on the image border → ``tip_outside_image``.
4. **Cone and shaft.** The silhouette width along the axis is split into the cone (width growing
   linearly from the tip) and the shaft by a two-segment least-squares fit.
5. **Sub-pixel edges.** Grey-level profiles perpendicular to each cone edge (bilinear sampling, every
   half pixel along the edge) give the position where ``n`` crosses 0.5 (a local linear fit of the
   transition). Under a symmetric PSF the half-level crossing of a straight edge is unbiased. Profiles
   too close to the apex (where the two edges blur into each other) or to the cone/shaft corner are
   left out.
6. **Tip.** The silhouette edges of a cone seen by a central camera are straight lines (the traces of
   the two planes through the camera centre tangent to the cone) that meet at the image of the apex.
   A robust total-least-squares line is fitted to each edge and the two lines are intersected. With
   ``camera`` given, edge points are undistorted first (OpenCV), so the lines are exact for any lens.
7. **Axis direction.** The silhouette edges of the cylindrical shaft meet at the vanishing point of
   the tool axis, so the projected axis is the line from the tip to that point (exact for a central
   camera); without a visible shaft, the bisector of the two cone edges is used.

For a rounded tip the edge lines meet at the virtual apex of the cone, beyond the physical tip by
``tip_radius * (1 / sin(half_angle) - 1)`` along the axis; the diagnostics give the silhouette's
extremum too.

Limits (measured, see ``benchmarks/bench_tooltip.py``): the cone must be wider than about
``2 * (1.5 * blur_sigma + 0.75)`` px somewhere before it meets the shaft. Thinner cones (needles a
few pixels wide) fall back to the half-level extremum of the silhouette along the axis (warning
``cone_too_small``), which lies 1-3 px inside the tool because blur rounds the point. When the whole
tool is in view (no border crossing) the tip is taken as the narrower end, which can pick a rounded
shaft end; a tool held by a robot leaves the image and does not have this ambiguity.

Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from jcalib.errors import BadInputError, DetectionError
from jcalib.vision.image import to_gray

__all__ = ["TOOLTIP_FAILURE_REASONS", "ToolTipDetection", "detect_tool_tip"]

#: Values of ``DetectionError.reason`` raised by :func:`detect_tool_tip`.
TOOLTIP_FAILURE_REASONS = ("not_found", "tip_outside_image", "partially_visible", "ambiguous")


@dataclass(frozen=True)
class ToolTipDetection:
    """The tool tip found in one image.

    Attributes:
        pixel: (2,) float64 tip position, px (OpenCV convention: centre of the top-left pixel is (0, 0)).
        axis_direction: (2,) float64 unit vector in the image, along the projected tool axis, pointing
            from the tip into the tool.
        diagnostics: how the tip was found: ``method`` (``"cone_edges"`` or ``"silhouette_extremum"``),
            ``axis_method`` (``"shaft_vanishing_point"``, ``"cone_bisector"`` or ``"silhouette_midline"``),
            ``tip_std_px`` (standard deviation of the tip from the edge-line fits: noise only, not
            model error), ``coarse_tip_px``, ``extremum_px`` (sub-pixel silhouette extremum along the
            axis), ``edge_points`` (per cone edge), ``edge_rms_px`` (per cone edge), ``edge_blur_px``
            (Gaussian-equivalent edge blur), ``cone_angle_deg`` (image angle between the cone edges),
            ``contrast`` (0..1), ``threshold`` (grey level of the silhouette, 0..255 scale),
            ``blob_area_px``, ``num_blobs``, ``warnings``.
        image_size: (width, height), px.
        name: the image path or ``"<array>"``.
    """

    pixel: np.ndarray
    axis_direction: np.ndarray
    diagnostics: dict[str, Any] = field(default_factory=dict)
    image_size: tuple[int, int] = (0, 0)
    name: str = "<array>"

    def to_json(self) -> dict[str, Any]:
        """``{"pixel": [u, v]}``, a tool-tip detection of ``observations.json`` (without its ids)."""
        return {"pixel": [float(self.pixel[0]), float(self.pixel[1])]}


# --------------------------------------------------------------------------------------------------
# Levels: backlight surface and tool level


def _poly_terms(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    return np.stack([x**i * y**j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=-1)


@dataclass(frozen=True)
class _Levels:
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


def _estimate_backlight(f: np.ndarray, min_contrast: float, name: str) -> tuple[_Levels, float]:
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
    levels = _Levels(dark=0.0, coeffs=coeffs, degree=degree, size=(w, h), bright_range=(bmin, bmax))
    return levels, contrast


# --------------------------------------------------------------------------------------------------
# Geometry helpers


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


def _robust_line(points: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
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
    levels: _Levels,
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


class _Lens:
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
# The detector


def _fail(name: str, message: str, reason: str) -> DetectionError:
    return DetectionError(f"{name}: {message}", reason)


def _select_blob(mask: np.ndarray, min_area_px: int, name: str) -> tuple[np.ndarray, int, int]:
    num, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    big = np.nonzero(areas >= min_area_px)[0]
    if big.size == 0:
        raise _fail(name, f"no tool silhouette of at least {min_area_px} px found on the backlight", "not_found")
    order = big[np.argsort(areas[big])[::-1]]
    largest = int(areas[order[0]])
    rivals = [int(areas[i]) for i in order[1:] if areas[i] >= 0.25 * largest]
    if rivals:
        raise _fail(
            name,
            f"{1 + len(rivals)} dark silhouettes of comparable size ({largest} px and {rivals} px); expected "
            "one tool in front of the backlight",
            "ambiguous",
        )
    label = int(order[0]) + 1
    return labels == label, largest, int(big.size)


def _coarse_tip_and_axis(blob: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coarse tip (2,), axis (2,) unit from tip into the tool, contour points (N, 2)."""
    h, w = blob.shape
    contours, _ = cv2.findContours(blob.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    mom = cv2.moments(blob.astype(np.uint8), binaryImage=True)
    centroid = np.array([mom["m10"] / mom["m00"], mom["m01"] / mom["m00"]])
    on_border = (contour[:, 0] <= 0) | (contour[:, 1] <= 0) | (contour[:, 0] >= w - 1) | (contour[:, 1] >= h - 1)
    if on_border.any():
        anchor = contour[on_border].mean(0)
        far = contour[np.argmax(np.linalg.norm(contour - anchor, axis=1))]
        tip = far
        axis = centroid - tip
        if np.linalg.norm(axis) < 1e-6:
            axis = anchor - tip
    else:
        cov = np.array([[mom["mu20"], mom["mu11"]], [mom["mu11"], mom["mu02"]]]) / mom["m00"]
        evals, evecs = np.linalg.eigh(cov)
        major = evecs[:, 1]
        s = (contour - centroid) @ major
        wdt = (contour - centroid) @ np.array([-major[1], major[0]])
        s_min, s_max = float(s.min()), float(s.max())

        # the tip end narrows (cone), the other end is cut flat: compare the widths a little way in
        typical = float(np.median(np.abs(wdt))) * 2.0
        delta = max(1.0, 0.15 * typical)

        def width_near(s0: float) -> float:
            sel = np.abs(s - s0) <= max(0.5, 0.1 * delta)
            return float(np.ptp(wdt[sel])) if sel.any() else 0.0

        if width_near(s_min + delta) <= width_near(s_max - delta):
            tip, axis = contour[np.argmin(s)], major
        else:
            tip, axis = contour[np.argmax(s)], -major
    axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
    return tip, axis, contour


def _cross_sections(blob: np.ndarray, contour: np.ndarray, tip: np.ndarray, axis: np.ndarray, s_max: float):
    """The silhouette straightened along the axis: per 1-px station s = 0, 1, ... from the tip, the
    signed left/right extent (px, along the normal ``(-axis_y, axis_x)``) of the blob's run that
    contains the axis (nearest-neighbour samples every 0.5 px across), and whether there is one."""
    normal = np.array([-axis[1], axis[0]])
    rel = contour - tip
    s_c = rel @ axis
    t_c = rel @ normal
    n = int(min(max(float(s_c.max()), 0.0), s_max)) + 1
    t_max = float(np.abs(t_c).max()) + 2.0
    t = np.arange(-t_max, t_max + 1e-9, 0.5)
    s = np.arange(n, dtype=np.float64)
    pts = tip[None, None, :] + s[:, None, None] * axis[None, None, :] + t[None, :, None] * normal[None, None, :]
    m = cv2.remap(
        blob.astype(np.uint8), pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32), cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0,
    ).astype(bool)
    any_in = m.any(axis=1)
    first = np.where(any_in, np.argmax(m, axis=1), 0)
    last = np.where(any_in, len(t) - 1 - np.argmax(m[:, ::-1], axis=1), 0)
    left = t[first] - 0.25
    right = t[last] + 0.25
    # a cross-section is measured only if both its ends (plus a sample) lie inside the image
    h, w = blob.shape
    ok = any_in.copy()
    for tt in (left - 1.0, right + 1.0):
        x = tip[0] + s * axis[0] + tt * normal[0]
        y = tip[1] + s * axis[1] + tt * normal[1]
        ok &= (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    # keep the first contiguous stretch from the tip
    bad = np.nonzero(~ok)[0]
    bad = bad[bad > 0]
    if bad.size:
        ok[bad[0]:] = False
    return s, left, right, ok


def _two_segment_break(s: np.ndarray, wdt: np.ndarray) -> int:
    """Index that best splits width(s) into two straight segments (least squares), >= 3 points each."""
    n = len(s)
    if n < 8:
        return n
    best, best_k = np.inf, n
    # cumulative sums for O(1) segment fits
    cs = np.cumsum(np.column_stack([np.ones(n), s, s * s, wdt, s * wdt, wdt * wdt]), axis=0)
    cs = np.vstack([np.zeros(6), cs])

    def sse(a: int, b: int) -> float:
        m, sx, sxx, sy, sxy, syy = cs[b] - cs[a]
        den = m * sxx - sx * sx
        if m < 2 or den <= 1e-12:
            return 0.0
        beta = (m * sxy - sx * sy) / den
        alpha = (sy - beta * sx) / m
        return float(syy - 2 * alpha * sy - 2 * beta * sxy + alpha * alpha * m + 2 * alpha * beta * sx + beta * beta * sxx)

    for k in range(4, n - 3):
        e = sse(0, k) + sse(k, n)
        if e < best:
            best, best_k = e, k
    whole = sse(0, n)
    if whole <= best * 1.5 + n * 0.05:  # no real break: all cone
        return n
    return best_k


def detect_tool_tip(
    image: Any,
    *,
    camera: Any = None,
    name: str = "<array>",
    min_contrast: float = 0.02,
    min_area_px: int = 30,
    max_fit_length_px: float = 400.0,
    border_margin_px: float = 2.0,
) -> ToolTipDetection:
    """Find the tip of a rotationally symmetric tool seen dark against a backlight.

    Args:
        image: (H, W) / (H, W, 3|4) uint8, uint16 or float-in-[0, 1] image (BGR for colour).
        camera: optional camera model of ``jcalib.geometry.cameras`` (``to_opencv()``); the edge
            points are then undistorted before the line fits, which makes them exact for any lens.
            Without it the edges are fitted as straight lines in the distorted image.
        name: how messages and the result refer to the image.
        min_contrast: smallest backlight-to-tool difference accepted, 0..1 of the full grey range;
            it must also exceed 8 times the backlight's pixel noise.
        min_area_px: silhouettes smaller than this are ignored (dust), px.
        max_fit_length_px: at most this length of each cone (and shaft) edge is fitted, px.
        border_margin_px: a tip or fitted edge closer than this to the image border counts as cut.

    Returns:
        :class:`ToolTipDetection`.

    Raises:
        BadInputError: ``image`` has the wrong shape or dtype.
        DetectionError: reason ``"not_found"`` (no silhouette: blank, dark or flat image),
            ``"ambiguous"`` (several tool-sized silhouettes), ``"tip_outside_image"`` (the
            silhouette is cut by the image border at the tip), ``"partially_visible"`` (the tip is
            inside but too close to the border, or too little of the cone is visible, to refine it).
    """
    gray = to_gray(image, name)
    f = gray.f32
    h, w = f.shape
    lens = _Lens(camera)
    if camera is not None and tuple(int(v) for v in getattr(camera, "image_size", (w, h))) != (w, h):
        raise BadInputError(
            f"{name}: camera.image_size is {tuple(camera.image_size)}, expected the image's size {(w, h)}"
        )
    warnings: list[str] = []

    # 1. levels, 2. silhouette
    levels, contrast = _estimate_backlight(f, min_contrast, name)
    back = _backlight_image(levels, w, h)
    dark_px = f[f < 0.5 * back]
    if dark_px.size < min_area_px:
        raise _fail(name, f"no tool silhouette: {dark_px.size} px darker than half the backlight", "not_found")
    if dark_px.size > 200_000:
        dark_px = dark_px[:: dark_px.size // 100_000]
    dark = float(np.percentile(dark_px, 10))
    back_level = float(np.median(back[::16, ::16]))
    # noise of the backlight (robust, from horizontal pixel differences of a band of rows)
    rows = f[h // 4 : h - h // 4 : max(1, h // 64)]
    brows = back[h // 4 : h - h // 4 : max(1, h // 64)]
    diff = np.diff(rows, axis=1)[(rows[:, 1:] > 0.75 * brows[:, 1:]) & (rows[:, :-1] > 0.75 * brows[:, :-1])]
    noise = 1.4826 * float(np.median(np.abs(diff))) / math.sqrt(2.0) if diff.size > 50 else 0.0
    if back_level - dark < max(min_contrast * 255.0, 8.0 * noise):
        raise _fail(
            name,
            f"no tool silhouette: backlight and tool differ by {(back_level - dark) / 255.0:.3f} of the grey range "
            f"(noise {noise / 255.0:.4f}; expected >= {min_contrast} and >= 8 noise sigmas)",
            "not_found",
        )
    levels = dataclasses.replace(levels, dark=dark)
    mask = (f < 0.5 * (back + dark)).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    blob, area, num_blobs = _select_blob(mask, min_area_px, name)
    if area > 0.95 * h * w:
        raise _fail(name, "the whole image is dark: no backlight visible around the tool", "not_found")

    # 3. coarse tip and axis
    tip0, axis, contour = _coarse_tip_and_axis(blob, name)
    if min(tip0[0], tip0[1], w - 1 - tip0[0], h - 1 - tip0[1]) < 0.5:
        raise _fail(
            name,
            f"the tool silhouette is cut by the image border at its tip (near pixel {tip0.round(1).tolist()}); "
            "move the tip into the image",
            "tip_outside_image",
        )
    # refine the axis with the mid-line of the cross-sections (skeleton of the symmetric silhouette)
    for _ in range(2):
        s, left, right, ok = _cross_sections(blob, contour, tip0, axis, 4.0 * max_fit_length_px)
        far = ok & (s >= 0.25 * s[ok].max()) if ok.any() else ok
        if far.sum() >= 5:
            mid = 0.5 * (left + right)
            normal = np.array([-axis[1], axis[0]])
            pts = tip0[None, :] + s[far, None] * axis[None, :] + mid[far, None] * normal[None, :]
            c, d, _, _ = _robust_line(pts)
            d = d if d @ axis > 0 else -d
            axis = d
            # move the coarse tip onto the axis' extremum
            rel = contour - c
            on_axis = np.abs(rel @ np.array([-d[1], d[0]])) <= 1.5
            if on_axis.any():
                tip0 = c + float(np.min(rel[on_axis] @ d)) * d
    normal = np.array([-axis[1], axis[0]])

    # 4. cone / shaft split of the silhouette width
    s, left, right, ok = _cross_sections(blob, contour, tip0, axis, 4.0 * max_fit_length_px)
    s_ok, l_ok, r_ok = s[ok], left[ok], right[ok]
    widths = r_ok - l_ok
    k = _two_segment_break(s_ok, widths)
    cone_end = float(s_ok[k - 1]) if k < len(s_ok) else float(s_ok[-1]) + 1.0
    cone_slope = float(np.polyfit(s_ok[:k], widths[:k], 1)[0]) if k >= 3 else 0.0

    # 5./6. sub-pixel cone edges: a first pass measures the edge blur, the second keeps the profiles
    # clear of the apex and of the cone/shaft corner by 1.5 blur sigmas (or less for a short cone)
    def fit(sig: float, clear: float) -> dict | None:
        return _fit_cone(f, levels, lens, tip0, axis, normal, s_ok[:k], l_ok[:k], r_ok[:k], cone_slope, cone_end,
                         sig, clear, max_fit_length_px, (w, h), border_margin_px)

    sigma = 1.0
    result = fit(sigma, 1.5 * sigma + 0.75) or fit(sigma, 0.75 * sigma + 0.5)
    if result is not None:
        sigma = result["sigma"]
        final = fit(sigma, 1.5 * sigma + 0.75)
        if final is None:
            final = fit(sigma, 0.75 * sigma + 0.5)
            warnings.append("short_cone")
        if final is not None:
            result = final
    extremum = _extremum(f, levels, tip0, axis, sigma)
    diagnostics: dict[str, Any] = {
        "coarse_tip_px": tip0.tolist(),
        "extremum_px": extremum.tolist(),
        "contrast": contrast,
        "threshold": float(0.5 * (levels.dark + back_level)),
        "noise": noise / 255.0,
        "blob_area_px": area,
        "num_blobs": num_blobs,
    }
    if result is None:
        visible_cone = cone_end
        if _near_border(tip0, w, h, border_margin_px + 2.0 * sigma + 2.0):
            raise _fail(name, "the tip is too close to the image border to be refined", "partially_visible")
        warnings.append("cone_too_small")
        tip = extremum
        axis_dir = axis
        diagnostics.update(method="silhouette_extremum", axis_method="silhouette_midline",
                           visible_cone_px=visible_cone, tip_std_px=float("nan"), edge_blur_px=sigma)
    else:
        tip = result["tip"]
        if _near_border(tip, w, h, border_margin_px):
            raise _fail(name, f"the tip {tip.round(1).tolist()} is at the image border", "partially_visible")
        diagnostics.update(
            method="cone_edges",
            tip_std_px=result["tip_std"],
            edge_points=result["n_points"],
            edge_rms_px=result["rms"],
            edge_blur_px=result["sigma"],
            cone_angle_deg=result["angle_deg"],
        )
        warnings.extend(result["warnings"])
        # 7. axis direction
        axis_dir, axis_method = result["bisector"], "cone_bisector"
        shaft = _fit_shaft(f, levels, lens, tip0, axis, normal, s_ok[k:], l_ok[k:], r_ok[k:], cone_end,
                           result["sigma"], max_fit_length_px, (w, h), border_margin_px)
        if shaft is not None:
            v = np.cross(shaft[0], shaft[1])  # vanishing point, homogeneous (undistorted pixels)
            tip_u = lens.undistort(tip[None, :])[0]
            dvec = v[:2] - v[2] * tip_u
            nrm = float(np.linalg.norm(dvec))
            if nrm > 1e-12:
                dvec = dvec / nrm
                dvec = dvec if dvec @ axis > 0 else -dvec
                if lens.camera is not None:  # direction in the distorted image at the tip
                    p2 = lens.distort(np.array([tip_u + 0.5 * dvec]))[0]
                    dvec = (p2 - tip) / max(float(np.linalg.norm(p2 - tip)), 1e-12)
                axis_dir, axis_method = dvec, "shaft_vanishing_point"
        diagnostics["axis_method"] = axis_method
    diagnostics["warnings"] = tuple(warnings)
    axis_dir = np.asarray(axis_dir, np.float64)
    axis_dir = axis_dir / float(np.linalg.norm(axis_dir))
    return ToolTipDetection(
        pixel=np.asarray(tip, np.float64), axis_direction=axis_dir, diagnostics=diagnostics, image_size=(w, h),
        name=name,
    )


def _near_border(p: np.ndarray, w: int, h: int, margin: float) -> bool:
    return bool(min(p[0], p[1], w - 1 - p[0], h - 1 - p[1]) < margin)


def _backlight_image(levels: _Levels, w: int, h: int) -> np.ndarray:
    """Backlight surface on the full grid, float32 (evaluated on a coarse grid and resized)."""
    step = 8
    xs = np.arange(0, w + step, step, dtype=np.float64)
    ys = np.arange(0, h + step, step, dtype=np.float64)
    X, Y = np.meshgrid(xs, ys)
    coarse = levels.backlight(X, Y).astype(np.float32)
    mapx = (np.arange(w, dtype=np.float32) / step)[None, :].repeat(h, 0)
    mapy = (np.arange(h, dtype=np.float32) / step)[:, None].repeat(w, 1)
    return cv2.remap(coarse, mapx, mapy, cv2.INTER_LINEAR)


def _extremum(f: np.ndarray, levels: _Levels, tip0: np.ndarray, axis: np.ndarray, sigma: float) -> np.ndarray:
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
    c, d, _, _ = _robust_line(pts)
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
    levels: _Levels,
    lens: _Lens,
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
        c, d, rms, keep = _robust_line(und)
        if keep.sum() < 6:
            return None
        out.append({"c": c, "d": d, "rms": rms, "pts": und[keep], "slopes": slopes[keep], "n": int(keep.sum())})
    return out


def _fit_cone(f, levels, lens, tip0, axis, normal, s, left, right, cone_slope, cone_end, sigma, clear, max_len,
              size, margin) -> dict | None:
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


def _fit_shaft(f, levels, lens, tip0, axis, normal, s, left, right, cone_end, sigma, max_len, size,
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
