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
from jcalib.vision.tooltip_edges import (
    BacklightLevels,
    Lens,
    backlight_image,
    estimate_backlight,
    extremum,
    fit_cone,
    fit_shaft,
    robust_line,
)

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
    lens = Lens(camera)
    if camera is not None and tuple(int(v) for v in getattr(camera, "image_size", (w, h))) != (w, h):
        raise BadInputError(
            f"{name}: camera.image_size is {tuple(camera.image_size)}, expected the image's size {(w, h)}"
        )
    warnings: list[str] = []

    # 1. levels, 2. silhouette, 3. coarse tip and axis
    sil = _silhouette(f, min_contrast, min_area_px, name)
    levels, blob = sil.levels, sil.blob
    tip0, axis, contour = _coarse_tip_and_axis(blob, name)
    if min(tip0[0], tip0[1], w - 1 - tip0[0], h - 1 - tip0[1]) < 0.5:
        raise _fail(
            name,
            f"the tool silhouette is cut by the image border at its tip (near pixel {tip0.round(1).tolist()}); "
            "move the tip into the image",
            "tip_outside_image",
        )
    tip0, axis = _refine_axis(blob, contour, tip0, axis, 4.0 * max_fit_length_px)
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
        return fit_cone(f, levels, lens, tip0, axis, normal, s_ok[:k], l_ok[:k], r_ok[:k], cone_slope, cone_end,
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
    extremum_px = extremum(f, levels, tip0, axis, sigma)
    diagnostics: dict[str, Any] = {
        "coarse_tip_px": tip0.tolist(),
        "extremum_px": extremum_px.tolist(),
        "contrast": sil.contrast,
        "threshold": float(0.5 * (levels.dark + sil.back_level)),
        "noise": sil.noise / 255.0,
        "blob_area_px": sil.area,
        "num_blobs": sil.num_blobs,
    }
    if result is None:
        visible_cone = cone_end
        if _near_border(tip0, w, h, border_margin_px + 2.0 * sigma + 2.0):
            raise _fail(name, "the tip is too close to the image border to be refined", "partially_visible")
        warnings.append("cone_too_small")
        tip = extremum_px
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
        shaft = fit_shaft(f, levels, lens, tip0, axis, normal, s_ok[k:], l_ok[k:], r_ok[k:], cone_end,
                          result["sigma"], max_fit_length_px, (w, h), border_margin_px)
        dvec = None if shaft is None else _vanishing_direction(shaft, lens, tip, axis)
        if dvec is not None:
            axis_dir, axis_method = dvec, "shaft_vanishing_point"
        diagnostics["axis_method"] = axis_method
    diagnostics["warnings"] = tuple(warnings)
    axis_dir = np.asarray(axis_dir, np.float64)
    axis_dir = axis_dir / float(np.linalg.norm(axis_dir))
    return ToolTipDetection(
        pixel=np.asarray(tip, np.float64), axis_direction=axis_dir, diagnostics=diagnostics, image_size=(w, h),
        name=name,
    )


@dataclass(frozen=True)
class _Silhouette:
    levels: BacklightLevels  # with the tool's grey level as ``dark``
    back_level: float  # median backlight, 0..255
    noise: float  # backlight pixel noise, 0..255
    contrast: float  # 0..1
    blob: np.ndarray  # (H, W) bool, the tool
    area: int  # px
    num_blobs: int


def _silhouette(f: np.ndarray, min_contrast: float, min_area_px: int, name: str) -> _Silhouette:
    """Steps 1 and 2: backlight and tool levels, then the tool's silhouette (one dark blob)."""
    h, w = f.shape
    levels, contrast = estimate_backlight(f, min_contrast, name)
    back = backlight_image(levels, w, h)
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
    mask = (f < 0.5 * (back + dark)).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    blob, area, num_blobs = _select_blob(mask, min_area_px, name)
    if area > 0.95 * h * w:
        raise _fail(name, "the whole image is dark: no backlight visible around the tool", "not_found")
    return _Silhouette(dataclasses.replace(levels, dark=dark), back_level, noise, contrast, blob, area, num_blobs)


def _refine_axis(
    blob: np.ndarray, contour: np.ndarray, tip0: np.ndarray, axis: np.ndarray, s_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """The axis as the mid-line of the cross-sections (skeleton of the symmetric silhouette), and the
    coarse tip moved onto the axis' extremum: ``(tip (2,), unit axis (2,))``."""
    for _ in range(2):
        s, left, right, ok = _cross_sections(blob, contour, tip0, axis, s_max)
        far = ok & (s >= 0.25 * s[ok].max()) if ok.any() else ok
        if far.sum() >= 5:
            mid = 0.5 * (left + right)
            normal = np.array([-axis[1], axis[0]])
            pts = tip0[None, :] + s[far, None] * axis[None, :] + mid[far, None] * normal[None, :]
            c, d, _, _ = robust_line(pts)
            d = d if d @ axis > 0 else -d
            axis = d
            rel = contour - c
            on_axis = np.abs(rel @ np.array([-d[1], d[0]])) <= 1.5
            if on_axis.any():
                tip0 = c + float(np.min(rel[on_axis] @ d)) * d
    return tip0, axis


def _vanishing_direction(shaft: list[np.ndarray], lens: Lens, tip: np.ndarray, axis: np.ndarray) -> np.ndarray | None:
    """Step 7: unit image direction at the tip towards the vanishing point of the shaft edges (into
    the tool), in the distorted image; None when the edges give no direction."""
    v = np.cross(shaft[0], shaft[1])  # vanishing point, homogeneous (undistorted pixels)
    tip_u = lens.undistort(tip[None, :])[0]
    dvec = v[:2] - v[2] * tip_u
    nrm = float(np.linalg.norm(dvec))
    if nrm <= 1e-12:
        return None
    dvec = dvec / nrm
    dvec = dvec if dvec @ axis > 0 else -dvec
    if lens.camera is not None:  # direction in the distorted image at the tip
        p2 = lens.distort(np.array([tip_u + 0.5 * dvec]))[0]
        dvec = (p2 - tip) / max(float(np.linalg.norm(p2 - tip)), 1e-12)
    return dvec


def _near_border(p: np.ndarray, w: int, h: int, margin: float) -> bool:
    return bool(min(p[0], p[1], w - 1 - p[0], h - 1 - p[1]) < margin)
