"""Render realistic grey images of planar calibration targets seen through a (distorted) camera.

The renderer is a ray caster with pixel-area integration, run once per image:

1. every pixel centre (plus a one-pixel border) is unprojected to a ray by the camera model (one
   ``jit``-compiled call per camera structure and image size, cached per camera parameters);
2. each pixel is split into ``supersample x supersample`` sub-pixel samples; a sample's ray is the
   bilinear interpolation of the rays of the four surrounding pixel centres (the map is smooth: the
   position error this adds is below 1e-3 px even for strong distortion, see the tests);
3. the ray is intersected with the target plane ``z = 0`` of the target frame; the printed face is
   the target's ``-z`` side (OpenCV board convention: ``T_cam_target = [I | (0, 0, d)]`` looks
   straight at the face), so a camera on the ``+z`` side sees the board's back, i.e. background;
4. the hit point is mapped to texture coordinates (:class:`~jcalib.sim.textures.TargetTexture`) and
   the texture is sampled bilinearly with ``cv2.remap``; the board's extent is the texture's extent,
   rays that miss it, miss the plane, see the back face or leave the lens's valid region see the
   background; the samples of a pixel are averaged (pixel area integration);
5. defocus blur (Gaussian or disk PSF), vignetting (``cos(theta)**p`` of the field angle), a linear
   illumination gradient, then the sensor model of :mod:`jcalib.sim.noise` (shot noise, full well,
   read noise, gain, black level, quantisation to 8..16 bits).

Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.sim.noise import check_sensor_settings, sensor_response
from jcalib.sim.textures import TargetTexture

PSFS = ("gaussian", "disk", "none")
#: Names accepted by :meth:`RenderOptions.preset`.
RENDER_PRESETS = ("clean", "realistic")
#: Photo-electrons on white paper at the image centre of the ``"realistic"`` preset.
REALISTIC_WHITE_ELECTRONS = 120.0
#: Its analogue gain: white paper at ~70 % of the 8-bit range, DN per electron.
REALISTIC_GAIN_DN_PER_E = 255.0 / (1.4 * REALISTIC_WHITE_ELECTRONS)
_MAX_REMAP_SIZE = 32767  # cv2.remap takes source images up to SHRT_MAX pixels per side


@dataclass(frozen=True)
class RenderOptions:
    """How an image is formed. The defaults describe a realistic industrial capture: a well-exposed
    8-bit monochrome CMOS camera (10 000 e- full well, 3 e- read noise), a lens slightly out of focus
    and natural vignetting, a printed board (matte paper, black ink) in front of a darker background.

    Attributes:
        supersample: samples per pixel along each axis (``supersample**2`` per pixel), >= 1.
        psf: defocus point spread function: ``"gaussian"`` (``blur_sigma_px``), ``"disk"``
            (``blur_radius_px``, uniform disk, the geometric defocus of a circular aperture) or ``"none"``.
        blur_sigma_px: standard deviation of the Gaussian PSF, pixels.
        blur_radius_px: radius of the disk PSF, pixels.
        vignetting_power: irradiance falls as ``cos(theta)**vignetting_power``, theta the angle between a
            pixel's ray and the optical axis (4 = natural cos^4 law of a simple lens, 0 = none).
        illumination_gradient: (gx, gy) relative change of the illumination across the image width and
            height (e.g. (0.2, 0) = 20 % brighter at the right edge than at the left), unitless.
        white_electrons: photo-electrons collected at the image centre from a surface of reflectance 1
            (the exposure), electrons.
        paper_reflectance: reflectance of the board's white (texture value 1), in [0, 1].
        ink_reflectance: reflectance of the board's black ink (texture value 0), in [0, 1].
        background_reflectance: reflectance seen by rays that miss the board, in [0, 1].
        bit_depth: output bits: 8 gives ``uint8``, 10/12/14/16 give ``uint16`` (LSB-aligned).
        full_well_e: pixel saturation capacity, electrons.
        read_noise_e: Gaussian read noise standard deviation, electrons.
        gain_dn_per_e: system gain, DN per electron; None maps a full well to the top DN.
        black_level_dn: offset added to every pixel, DN.
        shot_noise: draw Poisson photo-electrons (physical) or use the mean (noise-free signal).
        fast_noise: draw shot and read noise together by the normal approximation N(mean, mean + read²)
            in float32 at every pixel (about 5x faster than the exact Poisson draw at 1280x960; for
            live simulated cameras, ``jcalib simulate --fast-noise``). Off: the exact model.
        glare: specular highlights, each ``(u, v, radius, peak)``: a Gaussian spot of light added to
            the image irradiance at ``(u, v)`` (fractions of the image width and height), standard
            deviation ``radius`` (fraction of the image width), ``peak`` times a white surface's
            irradiance at its centre (saturates where the sum exceeds the full well); () = none.
    """

    supersample: int = 3
    psf: str = "gaussian"
    blur_sigma_px: float = 0.7
    blur_radius_px: float = 1.5
    vignetting_power: float = 4.0
    illumination_gradient: tuple[float, float] = (0.0, 0.0)
    white_electrons: float = 7000.0
    paper_reflectance: float = 0.9
    ink_reflectance: float = 0.05
    background_reflectance: float = 0.25
    bit_depth: int = 8
    full_well_e: float = 10000.0
    read_noise_e: float = 3.0
    gain_dn_per_e: float | None = None
    black_level_dn: float = 0.0
    shot_noise: bool = True
    glare: tuple[tuple[float, float, float, float], ...] = ()
    fast_noise: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.supersample, int | np.integer) or not 1 <= self.supersample <= 16:
            raise BadInputError(f"RenderOptions.supersample: got {self.supersample!r}, expected an int in 1..16")
        if self.psf not in PSFS:
            raise BadInputError(f"RenderOptions.psf: got {self.psf!r}, expected one of {PSFS}")
        for name in ("blur_sigma_px", "blur_radius_px", "vignetting_power", "white_electrons"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise BadInputError(f"RenderOptions.{name}: got {value!r}, expected a finite number >= 0")
        for name in ("paper_reflectance", "ink_reflectance", "background_reflectance"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 <= value <= 1.0):
                raise BadInputError(f"RenderOptions.{name}: got {value!r}, expected a reflectance in [0, 1]")
        grad = np.asarray(self.illumination_gradient, dtype=np.float64)
        if grad.shape != (2,) or not np.all(np.isfinite(grad)):
            raise BadInputError(
                f"RenderOptions.illumination_gradient: got {self.illumination_gradient!r}, expected (gx, gy)"
            )
        check_sensor_settings(
            self.bit_depth, self.full_well_e, self.read_noise_e, self.gain_dn_per_e, self.black_level_dn
        )
        try:
            spots = np.asarray(self.glare, dtype=np.float64).reshape(-1, 4)
        except (TypeError, ValueError):
            spots = np.full((1, 4), np.nan)
        if not np.all(np.isfinite(spots)) or np.any(spots[:, 2] <= 0) or np.any(spots[:, 3] < 0):
            raise BadInputError(
                f"RenderOptions.glare: got {self.glare!r}, expected ((u, v, radius, peak), ...) with finite values, "
                "radius > 0 and peak >= 0"
            )
        object.__setattr__(self, "glare", tuple(tuple(float(x) for x in row) for row in spots))

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> RenderOptions:
        """Named image-formation settings (:data:`RENDER_PRESETS`), with ``overrides`` replacing fields.

        - ``"clean"``: the defaults: a bright (7000 e- on white), nearly focused (0.7 px) exposure.
          Detected chessboard corners are ~0.01 px precise: far better than real captures, so the
          detector's own ~0.007 px deterministic errors show as several σ in a calibration.
        - ``"realistic"``: a short exposure in a dim cell: 120 e- on white paper at the image centre,
          raised to ~70 % of the 8-bit range by analogue gain (:data:`REALISTIC_GAIN_DN_PER_E`), 6 e-
          read noise, a Gaussian defocus of 1.4 px. Shot noise dominates (SNR ~10 on white); corners
          carry ~0.1 px of random error per axis (0.08-0.16 px depending on the square size in the
          image: ``benchmarks/bench_demo_consistency.py`` prints the a-posteriori σ of every run),
          the scale of real calibration residuals, and a backlit tool silhouette stays above the
          tool-tip detector's contrast threshold.

        Raises:
            BadInputError: an unknown name or an invalid override.
        """
        if name not in RENDER_PRESETS:
            raise BadInputError(f"RenderOptions.preset: got {name!r}, expected one of {RENDER_PRESETS}")
        base: dict[str, Any] = {}
        if name == "realistic":
            base = dict(
                white_electrons=REALISTIC_WHITE_ELECTRONS,
                read_noise_e=6.0,
                blur_sigma_px=1.4,
                gain_dn_per_e=REALISTIC_GAIN_DN_PER_E,
            )
        try:
            return cls(**{**base, **overrides})
        except TypeError as e:
            raise BadInputError(f"RenderOptions.preset({name!r}): {e}") from None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary of every setting (units in the names)."""
        d = dataclasses.asdict(self)
        d["illumination_gradient"] = [float(g) for g in self.illumination_gradient]
        d["glare"] = [list(g) for g in self.glare]
        return d


# --------------------------------------------------------------------------------------------------
# Input checks


def check_transform(T: Any, name: str) -> np.ndarray:
    """A validated (4, 4) float64 rigid transform from an array or an object with ``as_matrix()``."""
    if hasattr(T, "as_matrix"):
        T = T.as_matrix()
    try:
        M = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise BadInputError(f"{name}: got {type(T).__name__}, expected a (4, 4) rigid transform") from e
    if M.shape != (4, 4):
        raise BadInputError(f"{name}: got shape {M.shape}, expected a (4, 4) rigid transform (metres)")
    if not np.all(np.isfinite(M)):
        raise BadInputError(f"{name}: contains non-finite values, expected a finite (4, 4) transform")
    R = M[:3, :3]
    if not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or (
        np.linalg.det(R) < 0
    ):
        raise BadInputError(
            f"{name}: not a rigid transform (rotation block must be orthonormal with det +1, last row "
            f"[0, 0, 0, 1]); got\n{M}"
        )
    return M


def check_texture(texture: Any, name: str = "texture") -> TargetTexture:
    """``texture`` if it is a usable :class:`~jcalib.sim.textures.TargetTexture`, else a BadInputError naming ``name``."""
    if not all(hasattr(texture, a) for a in ("image", "metres_per_pixel", "origin_m")):
        raise BadInputError(f"{name}: got {type(texture).__name__}, expected a jcalib.sim.textures.TargetTexture")
    image = np.asarray(texture.image)
    if image.ndim != 2 or min(image.shape) < 2:
        raise BadInputError(f"{name}.image: got shape {image.shape}, expected (H, W) with H, W >= 2")
    if max(image.shape) > _MAX_REMAP_SIZE:
        raise BadInputError(
            f"{name}.image: got shape {image.shape}, expected at most {_MAX_REMAP_SIZE} pixels per side "
            "(use a coarser metres_per_pixel)"
        )
    if not np.all(np.isfinite(image)) or image.min() < -1e-6 or image.max() > 1 + 1e-6:
        raise BadInputError(f"{name}.image: expected finite reflectances in [0, 1]")
    mpp = float(texture.metres_per_pixel)
    if not (np.isfinite(mpp) and mpp > 0):
        raise BadInputError(f"{name}.metres_per_pixel: got {mpp!r}, expected a positive length (m)")
    origin = np.asarray(texture.origin_m, dtype=np.float64)
    if origin.shape != (2,) or not np.all(np.isfinite(origin)):
        raise BadInputError(f"{name}.origin_m: got {texture.origin_m!r}, expected a finite (2,) position (m)")
    return texture


def camera_image_size(camera: Any) -> tuple[int, int]:
    """(width, height) of a camera model, validated."""
    size = getattr(camera, "image_size", None)
    try:
        w, h = (int(s) for s in size)  # type: ignore[union-attr]
    except (TypeError, ValueError) as e:
        raise BadInputError(
            f"camera: image_size is {size!r}, expected (width, height); is it a jcalib camera model?"
        ) from e
    if w < 1 or h < 1:
        raise BadInputError(f"camera.image_size: got {(w, h)}, expected positive (width, height)")
    return w, h


# --------------------------------------------------------------------------------------------------
# Rays of the pixel grid (JAX, jit-compiled once per camera structure and image size)


def _unproject_padded_grid(camera: Any, width: int, height: int) -> tuple[jax.Array, jax.Array]:
    """Unit rays (camera frame) of pixel centres u = -1..width, v = -1..height: (H+2, W+2, 3), valid."""
    u = jnp.arange(-1, width + 1, dtype=jnp.float64)
    v = jnp.arange(-1, height + 1, dtype=jnp.float64)
    uu, vv = jnp.meshgrid(u, v)
    pixels = jnp.stack([uu.ravel(), vv.ravel()], axis=-1)
    if hasattr(camera, "unproject_valid"):
        rays, valid = camera.unproject_valid(pixels)
    else:
        rays = camera.unproject(pixels)
        valid = jnp.ones(rays.shape[:-1], dtype=bool)
    valid = valid & jnp.all(jnp.isfinite(rays), axis=-1)
    return rays.reshape(height + 2, width + 2, 3), valid.reshape(height + 2, width + 2)


_unproject_padded_grid_jit = eqx.filter_jit(_unproject_padded_grid)
_RAY_CACHE: OrderedDict[Any, tuple[np.ndarray, np.ndarray, np.ndarray]] = OrderedDict()
_RAY_CACHE_SIZE = 2


def _camera_key(camera: Any, width: int, height: int) -> Any:
    try:
        leaves, treedef = jax.tree_util.tree_flatten(camera)
        arrays = tuple(np.asarray(leaf).tobytes() + str(np.asarray(leaf).dtype).encode() for leaf in leaves)
        key = (type(camera), treedef, arrays, width, height)
        hash(key)
    except Exception:  # not a pytree of arrays: no caching
        return None
    return key


def ray_grid(camera: Any, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays of the padded pixel grid, cached per camera parameters and image size.

    Returns:
        rays: (3, H+2, W+2) float32 unit rays (camera frame) of pixel centres u = -1..W, v = -1..H,
            one contiguous plane per component; (0, 0, 1) where invalid.
        valid: (H+2, W+2) bool, the pixel centre unprojects to a valid ray.
        cos_theta: (H, W) float32 cosine of the field angle of each image pixel centre.
    """
    key = _camera_key(camera, width, height)
    if key is not None and key in _RAY_CACHE:
        _RAY_CACHE.move_to_end(key)
        return _RAY_CACHE[key]
    try:
        rays, valid = _unproject_padded_grid_jit(camera, width, height)
    except AttributeError as e:
        raise BadInputError(
            f"camera: got {type(camera).__name__}, expected a jcalib camera model with unproject_valid()"
        ) from e
    rays = np.asarray(rays, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    rays = np.where(valid[..., None], rays, np.array([0.0, 0.0, 1.0]))
    cos_theta = (rays[1:-1, 1:-1, 2] / np.linalg.norm(rays[1:-1, 1:-1], axis=-1)).astype(np.float32)
    planar = np.ascontiguousarray(np.moveaxis(rays, -1, 0), dtype=np.float32)
    entry = (planar, valid, cos_theta)
    if key is not None:
        _RAY_CACHE[key] = entry
        while len(_RAY_CACHE) > _RAY_CACHE_SIZE:
            _RAY_CACHE.popitem(last=False)
    return entry


# --------------------------------------------------------------------------------------------------
# Texture pyramid (anti-aliasing for far or grazing boards)

_PYRAMID_CACHE: OrderedDict[Any, tuple[TargetTexture, list[np.ndarray]]] = OrderedDict()


def _reflectance_pyramid(texture: TargetTexture, paper: float, ink: float, level: int) -> np.ndarray:
    """Texture reflectance at pyramid ``level`` (each level halves the resolution with cv2.pyrDown:
    level-L texel i is centred on level-0 texel ``2**L * i``)."""
    key = (id(texture), paper, ink)
    entry = _PYRAMID_CACHE.get(key)
    if entry is None or entry[0] is not texture:
        base = ink + (paper - ink) * np.clip(np.asarray(texture.image, dtype=np.float32), 0.0, 1.0)
        entry = (texture, [base.astype(np.float32)])
        _PYRAMID_CACHE[key] = entry
        while len(_PYRAMID_CACHE) > 8:
            _PYRAMID_CACHE.popitem(last=False)
    levels = entry[1]
    while len(levels) <= level and min(levels[-1].shape) >= 4:
        levels.append(cv2.pyrDown(levels[-1], borderType=cv2.BORDER_REPLICATE))
    return levels[min(level, len(levels) - 1)]


# --------------------------------------------------------------------------------------------------
# Rendering


def _plane_matrix(T_cam_target: np.ndarray, texture: TargetTexture) -> tuple[np.ndarray, float] | None:
    """3x3 A with A @ d = (u * s, v * s, s) for a camera ray d, (u, v) the texture pixel it hits and
    s = (target z axis) . d > 0 on the printed face; and c_z, the camera centre's target-frame z.
    None when the camera is behind (or in) the board plane: only the back face is visible."""
    R = T_cam_target[:3, :3]
    t = T_cam_target[:3, 3]
    c = -R.T @ t  # camera centre in the target frame
    if not c[2] < 0.0:
        return None
    a_x = c[0] * R[:, 2] - c[2] * R[:, 0]
    a_y = c[1] * R[:, 2] - c[2] * R[:, 1]
    a_d = R[:, 2]
    ox, oy = (float(o) for o in texture.origin_m)
    mpp = float(texture.metres_per_pixel)
    A = np.stack([(a_x - ox * a_d) / mpp, (a_y - oy * a_d) / mpp, a_d])
    return A, float(c[2])


def _interp_weights(offset: float) -> tuple[int, float]:
    """Padded-grid start index of the lower neighbour and the weight of the upper one for a sample
    at ``pixel + offset`` (offset in (-0.5, 0.5))."""
    f = math.floor(offset)
    return 1 + f, offset - f


def _pyramid_level(G: list[np.ndarray], supersample: int) -> int:
    """Texture pyramid level for which one sub-pixel sample covers about 1..2 texels (median)."""
    step = 8 if min(G[0].shape) > 32 else 1
    g = [Gk[1:-1:step, 1:-1:step].astype(np.float64) for Gk in G]
    s = g[2]
    ok = s > 1e-12
    u = np.where(ok, g[0] / np.where(ok, s, 1.0), 0.0)
    v = np.where(ok, g[1] / np.where(ok, s, 1.0), 0.0)
    du_x, dv_x = np.diff(u, axis=1)[:-1, :], np.diff(v, axis=1)[:-1, :]
    du_y, dv_y = np.diff(u, axis=0)[:, :-1], np.diff(v, axis=0)[:, :-1]
    area = np.abs(du_x * dv_y - du_y * dv_x) / (step * step)  # texels^2 per pixel
    ok4 = ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & np.isfinite(area)
    if not np.any(ok4):
        return 0
    texels_per_sample = math.sqrt(float(np.median(area[ok4]))) / supersample
    return max(0, int(math.floor(math.log2(texels_per_sample)))) if texels_per_sample >= 2.0 else 0


def _psf_blur(image: np.ndarray, options: RenderOptions) -> np.ndarray:
    if options.psf == "gaussian" and options.blur_sigma_px > 0:
        return cv2.GaussianBlur(image, (0, 0), sigmaX=options.blur_sigma_px, borderType=cv2.BORDER_REFLECT)
    if options.psf == "disk" and options.blur_radius_px > 0:
        r = options.blur_radius_px
        n = int(math.ceil(r))
        sub = 8  # the kernel integrates the disk over each pixel with 8x8 samples
        o = (np.arange(sub) + 0.5) / sub - 0.5
        x = np.arange(-n, n + 1)[:, None] + o[None, :]
        inside = (x.reshape(-1)[None, :] ** 2 + x.reshape(-1)[:, None] ** 2) <= r * r
        kernel = inside.reshape(2 * n + 1, sub, 2 * n + 1, sub).mean(axis=(1, 3))
        kernel = (kernel / kernel.sum()).astype(np.float32)
        return cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REFLECT)
    return image


def render_reflectance(
    camera: Any,
    targets: Sequence[tuple[Any, TargetTexture]],
    options: RenderOptions | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The noise-free, unblurred scene reflectance seen by each pixel (area-averaged).

    Args:
        camera: camera model (``image_size``, ``unproject_valid``).
        targets: ``(T_cam_target, texture)`` pairs; T_cam_target (4, 4) maps target to camera frame, m.
            Where boards overlap, the nearest one along the ray is seen.
        options: only ``supersample`` and the reflectances are used here.

    Returns:
        reflectance: (H, W) float32 in [0, 1].
        cos_theta: (H, W) cosine of the angle between each pixel-centre ray and the optical axis.
        lens_valid: (H, W) bool, the pixel centre unprojects to a valid ray.
    """
    options = RenderOptions() if options is None else options
    width, height = camera_image_size(camera)
    checked = []
    for k, (T, texture) in enumerate(targets):
        name = "T_cam_target" if len(targets) == 1 else f"targets[{k}].T_cam_target"
        checked.append((check_transform(T, name), check_texture(texture)))
    rays, valid, cos_theta = ray_grid(camera, width, height)
    all_valid = bool(valid.all())
    lens_valid = valid[1:-1, 1:-1]

    s = int(options.supersample)
    offsets = [(k + 0.5) / s - 0.5 for k in range(s)]
    background = float(options.background_reflectance)
    total = np.zeros((height, width), dtype=np.float32)

    planes = []
    for T, texture in checked:
        plane = _plane_matrix(T, texture)
        if plane is None:  # back face: the board is invisible
            continue
        A, c_z = plane
        # G_k = A[k] . ray on the padded grid: (u s, v s, s), three contiguous float32 planes. float32
        # is enough: cv2.remap resolves texture coordinates to 1/32 texel anyway.
        A32 = A.astype(np.float32)
        G = [A32[k, 0] * rays[0] + A32[k, 1] * rays[1] + A32[k, 2] * rays[2] for k in range(3)]
        level = _pyramid_level(G, s)
        tex = _reflectance_pyramid(texture, options.paper_reflectance, options.ink_reflectance, level)
        planes.append((G, tex, level, c_z))

    if not planes:
        return np.full((height, width), background, np.float32), cos_theta, lens_valid

    def lerp(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
        return a if w == 0.0 else cv2.addWeighted(a, 1.0 - w, b, w, 0.0)

    for oy in offsets:
        r0, wy = _interp_weights(oy)
        rows = [
            ([lerp(Gk[r0 : r0 + height], Gk[r0 + 1 : r0 + 1 + height], wy) for Gk in G], tex, level, c_z)
            for G, tex, level, c_z in planes
        ]
        vrow = None if all_valid else valid[r0 : r0 + height] & valid[r0 + 1 : r0 + 1 + height]
        for ox in offsets:
            c0, wx = _interp_weights(ox)
            vsample = None if vrow is None else vrow[:, c0 : c0 + width] & vrow[:, c0 + 1 : c0 + 1 + width]
            best_depth = None
            sample = None
            for Gr, tex, level, c_z in rows:
                gu, gv, den = (lerp(Gk[:, c0 : c0 + width], Gk[:, c0 + 1 : c0 + 1 + width], wx) for Gk in Gr)
                miss = den <= 1e-9
                if vsample is not None:
                    miss |= ~vsample
                scale = 0.5**level
                th, tw = tex.shape
                maps = []
                for num, size in ((gu, tw), (gv, th)):
                    m = cv2.divide(num, den, scale=scale)
                    np.copyto(m, np.float32(-8.0), where=miss)
                    maps.append(np.clip(m, -8.0, size + 8.0, out=m))
                value = cv2.remap(
                    tex, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background
                )
                if len(rows) == 1:
                    sample = value
                    break
                mapx, mapy = maps
                on_board = ~miss & (mapx > -1.0) & (mapx < tw) & (mapy > -1.0) & (mapy < th)
                depth = np.where(on_board, -c_z / np.where(miss, np.float32(1.0), den), np.inf)
                if best_depth is None:
                    best_depth, sample = depth, np.where(on_board, value, np.float32(background))
                else:
                    closer = depth < best_depth
                    sample = np.where(closer, value, sample)
                    best_depth = np.minimum(depth, best_depth)
            total += sample
    return total / np.float32(s * s), cos_theta, lens_valid


def render_targets_image(
    camera: Any,
    targets: Sequence[tuple[Any, TargetTexture]],
    options: RenderOptions | None = None,
    rng: np.random.Generator | int = 0,
) -> np.ndarray:
    """Render one camera image of several planar targets (the nearest board wins where they overlap).

    Args:
        camera: camera model with ``image_size`` (width, height) and ``unproject_valid(pixels)``.
        targets: ``(T_cam_target, texture)`` pairs; T_cam_target (4, 4), target frame -> camera frame, m.
        options: image formation settings; None = :class:`RenderOptions` defaults.
        rng: seed or generator of the sensor noise (same seed, same image).

    Returns:
        (H, W) ``uint8`` (8-bit) or ``uint16`` grey image.
    """
    options = RenderOptions() if options is None else options
    if not isinstance(options, RenderOptions):
        raise BadInputError(f"options: got {type(options).__name__}, expected RenderOptions or None")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    reflectance, cos_theta, lens_valid = render_reflectance(camera, targets, options)
    return form_image(reflectance, cos_theta, lens_valid, options, gen)


def form_image(
    radiance: np.ndarray,
    cos_theta: np.ndarray,
    lens_valid: np.ndarray,
    options: RenderOptions,
    rng: np.random.Generator,
) -> np.ndarray:
    """The sensor side of image formation: PSF blur, vignetting, illumination gradient, noise, ADC.

    Args:
        radiance: (H, W) relative scene radiance in [0, 1] (1 = white paper / backlight).
        cos_theta: (H, W) cosine of each pixel's ray with the optical axis (vignetting).
        lens_valid: (H, W) bool, pixels the lens maps (others stay black).
        options: image formation settings.
        rng: noise generator.

    Returns:
        (H, W) ``uint8`` (8-bit) or ``uint16`` image.
    """
    return expose(exposure_electrons(radiance, cos_theta, lens_valid, options), options, rng)


def exposure_electrons(
    radiance: np.ndarray, cos_theta: np.ndarray, lens_valid: np.ndarray, options: RenderOptions
) -> np.ndarray:
    """The noise-free part of :func:`form_image`: mean photo-electrons per pixel after PSF blur, glare,
    vignetting and the illumination gradient, (H, W) float64 (arguments as :func:`form_image`)."""
    height, width = radiance.shape
    irradiance = _psf_blur(radiance, options)
    if options.glare:
        u = np.arange(width, dtype=np.float32)[None, :]
        v = np.arange(height, dtype=np.float32)[:, None]
        irradiance = irradiance.astype(np.float32, copy=True)
        for gu, gv, radius, peak in options.glare:
            r = np.float32(radius * width)
            irradiance += np.float32(peak) * np.exp(
                -((u - np.float32(gu * (width - 1))) ** 2 + (v - np.float32(gv * (height - 1))) ** 2) / (2 * r * r)
            )
    gain = np.where(lens_valid, np.maximum(cos_theta, 0.0), 0.0).astype(np.float64)
    if options.vignetting_power != 1.0:
        gain = gain ** float(options.vignetting_power)
    gx, gy = (float(g) for g in options.illumination_gradient)
    if gx != 0.0 or gy != 0.0:
        u = (np.arange(width) - (width - 1) / 2.0) / width
        v = (np.arange(height) - (height - 1) / 2.0) / height
        gain = gain * np.maximum(1.0 + gx * u[None, :] + gy * v[:, None], 0.0)
    return options.white_electrons * irradiance.astype(np.float64) * np.where(lens_valid, gain, 0.0)


def expose(electrons: np.ndarray, options: RenderOptions, rng: np.random.Generator) -> np.ndarray:
    """The sensor of :func:`form_image`: mean electrons (H, W) -> noisy digital image (``options``' sensor)."""
    return sensor_response(
        electrons,
        rng,
        bit_depth=options.bit_depth,
        full_well_e=options.full_well_e,
        read_noise_e=options.read_noise_e,
        gain_dn_per_e=options.gain_dn_per_e,
        black_level_dn=options.black_level_dn,
        shot_noise=options.shot_noise,
        approximate=options.fast_noise,
    )


def render_target_image(
    camera: Any,
    T_cam_target: Any,
    texture: TargetTexture,
    options: RenderOptions | None = None,
    rng: np.random.Generator | int = 0,
) -> np.ndarray:
    """Render a grey image of one planar target seen through ``camera``.

    Args:
        camera: camera model (any lens model of ``jcalib.geometry.cameras``): ``image_size``
            (width, height) and ``unproject_valid(pixels (..., 2)) -> (rays (..., 3), valid)``.
        T_cam_target: (4, 4) pose of the target in the camera frame (maps target points to camera
            points), metres; a jaxlie ``SE3`` is accepted too. The printed face is the target's -z side.
        texture: the target's printed face.
        options: image formation settings; None = :class:`RenderOptions` defaults.
        rng: seed or ``np.random.Generator`` of the sensor noise; the same seed gives the same image.

    Returns:
        (H, W) ``uint8`` (``bit_depth`` 8) or ``uint16`` image, pixel (0, 0) centred at (0, 0).
    """
    return render_targets_image(camera, [(T_cam_target, texture)], options, rng)
