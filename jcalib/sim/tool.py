"""Render silhouette images of a rotationally symmetric tool (pin, needle, torch) on a backlight.

The tool is a solid of revolution in the ``tcp`` frame (metres):

- the tool axis is the tcp ``+z`` axis, pointing from the tip *into* the tool (towards the flange);
- the tip (the TCP) is the origin: the tool's foremost point on the axis;
- a cone of half-angle ``cone_half_angle_deg`` widens from the tip until it reaches the shaft
  radius, then a cylinder of radius ``shaft_radius_m`` runs up to ``z = length_m`` (flat end);
- with ``tip_radius_m > 0`` the cone ends in a sphere of that radius tangent to the cone (a worn or
  rounded tip) whose foremost point is still the origin.

The solid is convex, so a ray hits it iff the intersection of the ray's parameter intervals inside
the slab ``0 <= z <= length``, the cylinder and the cone's upper nappe is not empty (or it hits the
tip sphere). Each pixel is integrated with ``supersample x supersample`` rays (pixel-area
anti-aliasing), cast only for the pixels whose centre ray passes within the tool's bounding cylinder
plus a footprint margin (all other pixels see the backlight). Sub-pixel rays are the bilinear
interpolation of the rays of the surrounding pixel centres, exactly as in :mod:`jcalib.sim.render`,
so any lens model (distortion, fisheye) is supported.

Image formation reuses :class:`jcalib.sim.render.RenderOptions` (supersample, PSF blur, vignetting,
illumination gradient, sensor noise and quantisation); the backlight's and the tool's radiance
replace the board's reflectances (``backlight`` and ``tool_reflectance`` below, in units of a
perfectly white surface at ``white_electrons``).

Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.sim.render import RenderOptions, camera_image_size, check_transform, form_image, ray_grid

__all__ = ["SymmetricTool", "ToolImage", "render_tool_image", "tool_rays_hit"]


@dataclass(frozen=True)
class SymmetricTool:
    """Geometry of a rotationally symmetric tool in its ``tcp`` frame (see the module docstring).

    Attributes:
        shaft_radius_m: radius of the cylindrical shaft, m (> 0).
        cone_half_angle_deg: half opening angle of the conical point, degrees, in (0, 90).
        length_m: the tool ends (flat) at ``z = length_m``, m; > the cone's length.
        tip_radius_m: radius of the rounded tip, m (0 = sharp point); smaller than the shaft radius.
    """

    shaft_radius_m: float = 0.003
    cone_half_angle_deg: float = 20.0
    length_m: float = 0.15
    tip_radius_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("shaft_radius_m", "length_m"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise BadInputError(f"SymmetricTool.{name}: got {value!r}, expected a positive length (m)")
        a = self.cone_half_angle_deg
        if not (np.isfinite(a) and 0.5 <= a <= 80.0):
            raise BadInputError(f"SymmetricTool.cone_half_angle_deg: got {a!r}, expected degrees in [0.5, 80]")
        rho = self.tip_radius_m
        if not (np.isfinite(rho) and 0.0 <= rho < self.shaft_radius_m):
            raise BadInputError(
                f"SymmetricTool.tip_radius_m: got {rho!r}, expected 0 <= tip radius < shaft radius "
                f"({self.shaft_radius_m} m)"
            )
        if self.cone_end_z_m >= self.length_m:
            raise BadInputError(
                f"SymmetricTool.length_m: got {self.length_m!r}, expected more than the cone's length "
                f"{self.cone_end_z_m:.6g} m"
            )

    @property
    def apex_z_m(self) -> float:
        """z of the (virtual) apex of the cone, m: 0 for a sharp tip, < 0 for a rounded one."""
        alpha = math.radians(self.cone_half_angle_deg)
        return self.tip_radius_m - self.tip_radius_m / math.sin(alpha)

    @property
    def sphere_end_z_m(self) -> float:
        """z where the tip sphere meets the cone (tangent circle), m; 0 for a sharp tip."""
        alpha = math.radians(self.cone_half_angle_deg)
        return self.apex_z_m + self.tip_radius_m * math.cos(alpha) ** 2 / math.sin(alpha)

    @property
    def cone_end_z_m(self) -> float:
        """z where the cone reaches the shaft radius, m."""
        return self.apex_z_m + self.shaft_radius_m / math.tan(math.radians(self.cone_half_angle_deg))


@dataclass(frozen=True)
class ToolImage:
    """A rendered tool image and its ground truth.

    Attributes:
        image: (H, W) ``uint8`` or ``uint16`` grey image (dark tool on a bright backlight).
        tip_px: (2,) float64 projection of the TCP origin, px (OpenCV convention).
        axis_direction: (2,) float64 unit vector, the image direction of the tool axis at the tip
            (derivative of the projection along tcp +z: from the tip into the tool); (0, 0) when the
            axis points straight at (or away from) the camera.
        tip_in_image: the tip projects validly inside the image rectangle [-0.5, W - 0.5] x [-0.5, H - 0.5].
        coverage: (H, W) float32 fraction of each pixel's area covered by the tool, in [0, 1]
            (noise-free, before blur).
    """

    image: np.ndarray
    tip_px: np.ndarray
    axis_direction: np.ndarray
    tip_in_image: bool
    coverage: np.ndarray


def _interval_slab(o: float, d: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters t with lo <= o + t d <= hi: (t_min, t_max), empty when t_min > t_max."""
    parallel = np.abs(d) < 1e-15
    safe = np.where(parallel, 1.0, d)
    t1 = (lo - o) / safe
    t2 = (hi - o) / safe
    inside = lo <= o <= hi
    t_min = np.where(parallel, -np.inf if inside else np.inf, np.minimum(t1, t2))
    t_max = np.where(parallel, np.inf if inside else -np.inf, np.maximum(t1, t2))
    return t_min, t_max


def tool_rays_hit(tool: SymmetricTool, origin_tcp: np.ndarray, dirs_tcp: np.ndarray) -> np.ndarray:
    """Whether rays from one origin hit the tool (forward of the origin).

    Args:
        tool: the tool geometry.
        origin_tcp: (3,) ray origin in the tcp frame, m (outside the tool).
        dirs_tcp: (N, 3) ray directions in the tcp frame (any non-zero length).

    Returns:
        (N,) bool.
    """
    o = np.asarray(origin_tcp, dtype=np.float64)
    d = np.asarray(dirs_tcp, dtype=np.float64)
    dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
    ox, oy, oz = (float(v) for v in o)
    r = float(tool.shaft_radius_m)
    k2 = math.tan(math.radians(tool.cone_half_angle_deg)) ** 2
    rho = float(tool.tip_radius_m)
    z_start = tool.sphere_end_z_m if rho > 0 else 0.0

    # slab
    t_lo, t_hi = _interval_slab(oz, dz, z_start, float(tool.length_m))

    # cylinder x^2 + y^2 <= r^2
    a = dx * dx + dy * dy
    b = 2.0 * (ox * dx + oy * dy)
    c = ox * ox + oy * oy - r * r
    disc = b * b - 4.0 * a * c
    along = a < 1e-30
    sq = np.sqrt(np.maximum(disc, 0.0))
    a_safe = np.where(along, 1.0, a)
    c_lo = np.where(along, -np.inf if c <= 0 else np.inf, (-b - sq) / (2.0 * a_safe))
    c_hi = np.where(along, np.inf if c <= 0 else -np.inf, (-b + sq) / (2.0 * a_safe))
    c_hi = np.where(~along & (disc < 0.0), -np.inf, c_hi)
    t_lo = np.maximum(t_lo, c_lo)
    t_hi = np.minimum(t_hi, c_hi)

    # cone's upper nappe: x^2 + y^2 <= k^2 (z - z_a)^2, z >= z_a
    ozp = oz - tool.apex_z_m
    A = dx * dx + dy * dy - k2 * dz * dz
    B = 2.0 * (ox * dx + oy * dy - k2 * ozp * dz)
    C = ox * ox + oy * oy - k2 * ozp * ozp
    A = np.where(np.abs(A) < 1e-18, -1e-18, A)  # parallel to a generator: treat as just inside
    disc = B * B - 4.0 * A * C
    sq = np.sqrt(np.maximum(disc, 0.0))
    r1 = (-B - sq) / (2.0 * A)
    r2 = (-B + sq) / (2.0 * A)
    root_lo, root_hi = np.minimum(r1, r2), np.maximum(r1, r2)
    outside_dir = A > 0.0  # bounded chord within one nappe
    mid_zp = ozp + 0.5 * (root_lo + root_hi) * dz
    chord_ok = (disc >= 0.0) & (mid_zp >= 0.0)
    k_lo = np.where(outside_dir, np.where(chord_ok, root_lo, np.inf), np.where(dz > 0.0, root_hi, -np.inf))
    k_hi = np.where(outside_dir, np.where(chord_ok, root_hi, -np.inf), np.where(dz > 0.0, np.inf, root_lo))
    t_lo = np.maximum(t_lo, k_lo)
    t_hi = np.minimum(t_hi, k_hi)
    hit = (t_lo <= t_hi) & (t_hi > 0.0)

    if rho > 0:
        oc = o - np.array([0.0, 0.0, rho])
        a = np.sum(d * d, axis=1)
        b = 2.0 * (d @ oc)
        c = float(oc @ oc) - rho * rho
        disc = b * b - 4.0 * a * c
        t2 = (-b + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a)
        hit |= (disc >= 0.0) & (t2 > 0.0)
    return hit


def _inside_tool(tool: SymmetricTool, p: np.ndarray) -> bool:
    """Whether a point (tcp frame, m) lies inside the solid."""
    x, y, z = (float(v) for v in p)
    rr = math.hypot(x, y)
    if tool.tip_radius_m > 0 and math.dist((x, y, z), (0.0, 0.0, tool.tip_radius_m)) <= tool.tip_radius_m:
        return True
    z0 = tool.sphere_end_z_m if tool.tip_radius_m > 0 else 0.0
    cone_r = math.tan(math.radians(tool.cone_half_angle_deg)) * (z - tool.apex_z_m)
    return z0 <= z <= tool.length_m and rr <= tool.shaft_radius_m and rr <= cone_r


def _candidate_pixels(
    rays: np.ndarray, origin: np.ndarray, R_tcp_cam: np.ndarray, tool: SymmetricTool, pitch: float
) -> np.ndarray:
    """(H, W) bool: pixel-centre rays passing close enough to the tool axis that some part of the
    pixel may see the tool (a conservative bound: bounding cylinder + twice the pixel footprint)."""
    d = [rays[k, 1:-1, 1:-1] for k in range(3)]
    # ray directions in the tcp frame (float32 is ample for a bound)
    R = R_tcp_cam.astype(np.float32)
    e = [R[i, 0] * d[0] + R[i, 1] * d[1] + R[i, 2] * d[2] for i in range(3)]
    z_min = min(tool.apex_z_m, 0.0)
    z_max = float(tool.length_m)
    reach = float(np.linalg.norm(origin)) + z_max + tool.shaft_radius_m + abs(z_min)
    margin = 2.0 * pitch * reach
    bound = tool.shaft_radius_m + margin
    # exact distance from the ray {o + t e, t >= 0} to the segment {(0, 0, z), z in [z_min, z_max]}:
    # a convex problem in (t, z); its minimum is the interior stationary point when feasible, else
    # on one of the edges t = 0, z = z_min, z = z_max.
    ox, oy, oz = (float(v) for v in origin)
    ex, ey, ez = e
    a = ex * ex + ey * ey
    t_line = -(ox * ex + oy * ey) / np.maximum(a, np.float32(1e-12))
    z_line = oz + t_line * ez
    interior = (a > 1e-12) & (t_line >= 0.0) & (z_line >= z_min) & (z_line <= z_max)
    d2 = np.where(interior, (ox + t_line * ex) ** 2 + (oy + t_line * ey) ** 2, np.inf)
    d2 = np.minimum(d2, ox * ox + oy * oy + (oz - min(max(oz, z_min), z_max)) ** 2)  # t = 0
    for zc in (z_min, z_max):
        t = np.maximum(-(ox * ex + oy * ey + (oz - zc) * ez), 0.0)
        d2 = np.minimum(d2, (ox + t * ex) ** 2 + (oy + t * ey) ** 2 + (oz - zc + t * ez) ** 2)
    dist = np.sqrt(d2)
    out = dist <= bound
    return out


def _pixel_coverage(
    tool: SymmetricTool,
    origin: np.ndarray,
    R_tcp_cam: np.ndarray,
    rays: np.ndarray,
    valid: np.ndarray,
    iy: np.ndarray,
    ix: np.ndarray,
    s: int,
) -> np.ndarray:
    """Covered fraction of pixels (iy, ix) from s x s rays each (bilinear rays of the padded grid)."""
    offsets = [(k + 0.5) / s - 0.5 for k in range(s)]
    count = np.zeros(iy.size, dtype=np.float64)
    for oy in offsets:
        fy = math.floor(oy)
        wy = oy - fy
        r0 = iy + 1 + fy
        for ox in offsets:
            fx = math.floor(ox)
            wx = ox - fx
            c0 = ix + 1 + fx
            d = (
                (1 - wy) * (1 - wx) * rays[:, r0, c0].astype(np.float64)
                + (1 - wy) * wx * rays[:, r0, c0 + 1]
                + wy * (1 - wx) * rays[:, r0 + 1, c0]
                + wy * wx * rays[:, r0 + 1, c0 + 1]
            )  # (3, n), camera frame
            sample_ok = valid[r0, c0] & valid[r0, c0 + 1] & valid[r0 + 1, c0] & valid[r0 + 1, c0 + 1]
            hit = tool_rays_hit(tool, origin, (R_tcp_cam @ d).T)
            count += hit & sample_ok
    return (count / (s * s)).astype(np.float32)


def _coverage(
    camera: Any, T_cam_tcp: np.ndarray, tool: SymmetricTool, supersample: int, edge_supersample: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel covered area fraction (H, W) float32, cos(field angle) (H, W), lens validity (H, W)."""
    width, height = camera_image_size(camera)
    rays, valid, cos_theta = ray_grid(camera, width, height)
    lens_valid = valid[1:-1, 1:-1]
    R_tcp_cam = T_cam_tcp[:3, :3].T
    origin = -R_tcp_cam @ T_cam_tcp[:3, 3]  # camera centre in the tcp frame
    if _inside_tool(tool, origin):
        raise BadInputError("T_cam_tcp: the camera centre lies inside the tool; expected a camera outside it")
    # angular pixel pitch: largest angle between neighbouring pixel-centre rays
    du = np.sqrt(np.sum((rays[:, :, 1:] - rays[:, :, :-1]) ** 2, axis=0))
    dv = np.sqrt(np.sum((rays[:, 1:, :] - rays[:, :-1, :]) ** 2, axis=0))
    ok_u = valid[:, 1:] & valid[:, :-1]
    ok_v = valid[1:, :] & valid[:-1, :]
    pitch = max(float(du[ok_u].max(initial=0.0)), float(dv[ok_v].max(initial=0.0)), 1e-9)
    cand = _candidate_pixels(rays, origin, R_tcp_cam, tool, pitch) & lens_valid
    coverage = np.zeros((height, width), dtype=np.float32)
    iy, ix = np.nonzero(cand)
    if iy.size == 0:
        return coverage, cos_theta, lens_valid
    coverage[iy, ix] = _pixel_coverage(tool, origin, R_tcp_cam, rays, valid, iy, ix, int(supersample))
    # pixels on the silhouette's boundary (and their neighbours, for sub-sample-thin features such
    # as a sharp tip) are integrated again with edge_supersample**2 samples
    if edge_supersample > supersample:
        part = (coverage > 0.0) & (coverage < 1.0)
        part = cv2.dilate(part.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & cand
        ey, ex = np.nonzero(part)
        if ey.size:
            coverage[ey, ex] = _pixel_coverage(tool, origin, R_tcp_cam, rays, valid, ey, ex, int(edge_supersample))
    return coverage, cos_theta, lens_valid


def _tip_ground_truth(camera: Any, T_cam_tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    p = jnp.asarray(T_cam_tcp[:3, 3], dtype=jnp.float64)
    axis = jnp.asarray(T_cam_tcp[:3, 2], dtype=jnp.float64)
    (pix, valid), (dpix, _) = jax.jvp(camera.project_valid, (p,), (axis,))
    pix = np.asarray(pix, dtype=np.float64)
    dpix = np.asarray(dpix, dtype=np.float64)
    n = float(np.linalg.norm(dpix))
    direction = dpix / n if n > 1e-9 * max(1.0, float(np.linalg.norm(pix))) else np.zeros(2)
    width, height = camera_image_size(camera)
    inside = bool(valid) and -0.5 <= pix[0] <= width - 0.5 and -0.5 <= pix[1] <= height - 0.5
    return pix, direction, inside


def render_tool_image(
    camera: Any,
    T_cam_tcp: Any,
    tool: SymmetricTool | None = None,
    options: RenderOptions | None = None,
    rng: np.random.Generator | int = 0,
    *,
    backlight: float = 0.9,
    tool_reflectance: float = 0.03,
    edge_supersample: int = 16,
) -> ToolImage:
    """Render a dark tool silhouette on a bright backlight, seen through ``camera``.

    Args:
        camera: camera model of ``jcalib.geometry.cameras`` (``image_size``, ``unproject_valid``,
            ``project_valid``); any lens model.
        T_cam_tcp: (4, 4) pose of the tool's tcp frame in the camera frame (maps tcp points to
            camera points), m; a jaxlie ``SE3`` is accepted too.
        tool: the tool geometry; None = :class:`SymmetricTool` defaults (3 mm shaft, 20° cone, sharp).
        options: image formation (supersample, PSF, vignetting, gradient, sensor); the board
            reflectances of :class:`RenderOptions` are not used. None = defaults.
        rng: seed or generator of the sensor noise (same seed, same image).
        backlight: radiance of the backlight, relative to a white surface at ``white_electrons``, in [0, 1].
        tool_reflectance: radiance of the tool's (unlit) surface, same unit, in [0, 1].
        edge_supersample: pixels on the silhouette's boundary are integrated again with
            ``edge_supersample**2`` rays (exact-looking edges at little cost); <= supersample = off.

    Returns:
        :class:`ToolImage`: the image, the projected tip and axis direction, the coverage map.
    """
    options = RenderOptions() if options is None else options
    if not isinstance(options, RenderOptions):
        raise BadInputError(f"options: got {type(options).__name__}, expected RenderOptions or None")
    tool = SymmetricTool() if tool is None else tool
    if not isinstance(tool, SymmetricTool):
        raise BadInputError(f"tool: got {type(tool).__name__}, expected SymmetricTool or None")
    for name, value in (("backlight", backlight), ("tool_reflectance", tool_reflectance)):
        if not (np.isfinite(value) and 0.0 <= value <= 1.0):
            raise BadInputError(f"{name}: got {value!r}, expected a relative radiance in [0, 1]")
    if not isinstance(edge_supersample, int | np.integer) or not 1 <= edge_supersample <= 64:
        raise BadInputError(f"edge_supersample: got {edge_supersample!r}, expected an int in 1..64")
    T = check_transform(T_cam_tcp, "T_cam_tcp")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    radiance, cos_theta, lens_valid, coverage = tool_radiance(camera, T, tool, options, backlight=backlight,
                                                              tool_reflectance=tool_reflectance,
                                                              edge_supersample=edge_supersample)  # fmt: skip
    image = form_image(radiance, cos_theta, lens_valid, options, gen)
    tip, direction, inside = _tip_ground_truth(camera, T)
    return ToolImage(image=image, tip_px=tip, axis_direction=direction, tip_in_image=inside, coverage=coverage)


def tool_radiance(
    camera: Any,
    T_cam_tcp: np.ndarray,
    tool: SymmetricTool,
    options: RenderOptions,
    *,
    backlight: float = 0.9,
    tool_reflectance: float = 0.03,
    edge_supersample: int = 16,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The noise-free scene of :func:`render_tool_image` (checked arguments, same meaning):
    ``(radiance, cos_theta, lens_valid, coverage)``, each (H, W), for
    :func:`jcalib.sim.render.form_image`."""
    coverage, cos_theta, lens_valid = _coverage(camera, T_cam_tcp, tool, options.supersample, edge_supersample)
    radiance = (backlight + (tool_reflectance - backlight) * coverage).astype(np.float32)
    return radiance, cos_theta, lens_valid, coverage
