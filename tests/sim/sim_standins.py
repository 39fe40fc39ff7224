"""Local stand-ins for contracts other engineers are writing, used by the sim tests until they land.

- ``StandInOpenCV5`` / ``StandInFisheye``: camera models with the ``jcalib.geometry.cameras`` contract
  (``project``, ``project_valid``, ``unproject``, ``unproject_valid``, ``to_opencv``, ``image_size``),
  written here in JAX from the OpenCV formulas; tests cross-check their projection against ``cv2``.
- ``checkerboard_texture``: a checkerboard drawn in the ``TargetTexture`` format.
- ``detect_checkerboard``: ``cv2.findChessboardCornersSB`` + ``cornerSubPix``.

``make_camera`` / ``make_checkerboard_texture`` / ``make_checkerboard`` switch to the real
implementations when they exist.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.sim.textures import TargetTexture


class StandInOpenCV5(eqx.Module):
    """OpenCV 5-coefficient model (k1, k2, p1, p2, k3)."""

    K: jax.Array
    dist: jax.Array
    image_size: tuple[int, int] = eqx.field(static=True)

    def _distort(self, x: jax.Array) -> jax.Array:
        k1, k2, p1, p2, k3 = (self.dist[i] for i in range(5))
        a, b = x[..., 0], x[..., 1]
        r2 = a * a + b * b
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
        yd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
        return jnp.stack([xd, yd], axis=-1)

    def project_valid(self, p: jax.Array) -> tuple[jax.Array, jax.Array]:
        z = p[..., 2]
        valid = z > 1e-12
        zs = jnp.where(valid, z, 1.0)
        x = p[..., :2] / zs[..., None]
        xd = self._distort(x)
        u = self.K[0, 0] * xd[..., 0] + self.K[0, 1] * xd[..., 1] + self.K[0, 2]
        v = self.K[1, 1] * xd[..., 1] + self.K[1, 2]
        return jnp.stack([u, v], axis=-1), valid

    def project(self, p: jax.Array) -> jax.Array:
        return self.project_valid(p)[0]

    def unproject_valid(self, pixels: jax.Array) -> tuple[jax.Array, jax.Array]:
        yd = (pixels[..., 1] - self.K[1, 2]) / self.K[1, 1]
        xd = (pixels[..., 0] - self.K[0, 2] - self.K[0, 1] * yd) / self.K[0, 0]
        target = jnp.stack([xd, yd], axis=-1)
        flat = target.reshape(-1, 2)
        jac = jax.vmap(jax.jacfwd(self._distort))

        def step(x, _):
            r = jax.vmap(self._distort)(x) - flat
            J = jac(x)
            dx = jnp.linalg.solve(J, r[..., None])[..., 0]
            return x - dx, None

        x, _ = jax.lax.scan(step, flat, None, length=12)
        err = jnp.linalg.norm(jax.vmap(self._distort)(x) - flat, axis=-1)
        x = x.reshape(target.shape)
        rays = jnp.concatenate([x, jnp.ones_like(x[..., :1])], axis=-1)
        rays = rays / jnp.linalg.norm(rays, axis=-1, keepdims=True)
        return rays, (err < 1e-9).reshape(target.shape[:-1])

    def unproject(self, pixels: jax.Array) -> jax.Array:
        return self.unproject_valid(pixels)[0]

    def to_opencv(self):
        return np.asarray(self.K), np.asarray(self.dist)


class StandInFisheye(eqx.Module):
    """OpenCV fisheye (Kannala-Brandt, k1..k4) with theta = atan2(r, z), valid up to theta_max."""

    K: jax.Array
    dist: jax.Array
    image_size: tuple[int, int] = eqx.field(static=True)
    theta_max: float = eqx.field(static=True, default=float(np.deg2rad(100.0)))

    def _theta_d(self, theta):
        t2 = theta * theta
        k = self.dist
        return theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))

    def project_valid(self, p):
        r = jnp.linalg.norm(p[..., :2], axis=-1)
        theta = jnp.arctan2(r, p[..., 2])
        rs = jnp.where(r > 1e-15, r, 1.0)
        scale = jnp.where(r > 1e-15, self._theta_d(theta) / rs, 1.0 / jnp.where(p[..., 2] > 0, p[..., 2], 1.0))
        x = p[..., :2] * scale[..., None]
        u = self.K[0, 0] * x[..., 0] + self.K[0, 2]
        v = self.K[1, 1] * x[..., 1] + self.K[1, 2]
        return jnp.stack([u, v], axis=-1), theta < self.theta_max

    def project(self, p):
        return self.project_valid(p)[0]

    def unproject_valid(self, pixels):
        x = (pixels[..., 0] - self.K[0, 2]) / self.K[0, 0]
        y = (pixels[..., 1] - self.K[1, 2]) / self.K[1, 1]
        td = jnp.sqrt(x * x + y * y)
        theta = jnp.minimum(td, self.theta_max)
        dtd = jax.grad(lambda t: jnp.sum(self._theta_d(t)))
        for _ in range(10):
            theta = theta - (self._theta_d(theta) - td) / dtd(theta)
        valid = (theta < self.theta_max) & (jnp.abs(self._theta_d(theta) - td) < 1e-9)
        tds = jnp.where(td > 1e-15, td, 1.0)
        s = jnp.where(td > 1e-15, jnp.sin(theta) / tds, 1.0)
        rays = jnp.stack([x * s, y * s, jnp.cos(theta)], axis=-1)
        return rays, valid

    def unproject(self, pixels):
        return self.unproject_valid(pixels)[0]

    def to_opencv(self):
        return np.asarray(self.K), np.asarray(self.dist)


def make_camera(K, dist, image_size, fisheye=False):
    """The real ``camera_from_opencv`` when it exists, else a stand-in."""
    try:
        from jcalib.geometry.cameras import camera_from_opencv  # type: ignore[attr-defined]
    except ImportError:
        K = jnp.asarray(K, dtype=jnp.float64)
        dist = jnp.asarray(dist, dtype=jnp.float64)
        cls = StandInFisheye if fisheye else StandInOpenCV5
        return cls(K, dist, (int(image_size[0]), int(image_size[1])))
    K = np.asarray(K, np.float64)
    return camera_from_opencv(K, np.asarray(dist, np.float64), tuple(image_size), fisheye=fisheye)


@dataclass(frozen=True)
class StandInCheckerboard:
    """Checkerboard geometry: inner corners (i * square, j * square, 0), row-major, i fastest."""

    cols: int
    rows: int
    square: float

    @property
    def points(self) -> np.ndarray:
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        return np.stack([i.ravel() * self.square, j.ravel() * self.square, np.zeros(i.size)], axis=-1)

    @property
    def ids(self) -> np.ndarray:
        return np.arange(self.cols * self.rows)


def make_checkerboard(cols, rows, square):
    try:
        from jcalib.geometry.targets import Checkerboard  # type: ignore[attr-defined]
    except ImportError:
        return StandInCheckerboard(cols, rows, square)
    return Checkerboard(cols, rows, square)


def checkerboard_texture(cols, rows, square, metres_per_pixel, margin_m) -> TargetTexture:
    """Checkerboard with ``cols x rows`` inner corners at (i*square, j*square); squares from -square
    to cols*square; white margin around. Square edges fall between texel centres."""
    x0 = -square - margin_m
    y0 = -square - margin_m
    w = int(round(((cols + 1) * square + 2 * margin_m) / metres_per_pixel))
    h = int(round(((rows + 1) * square + 2 * margin_m) / metres_per_pixel))
    origin = np.array([x0 + metres_per_pixel / 2, y0 + metres_per_pixel / 2])
    xs = origin[0] + np.arange(w) * metres_per_pixel
    ys = origin[1] + np.arange(h) * metres_per_pixel
    ci = np.floor(xs / square).astype(np.int64)  # square column index, -1..cols
    rj = np.floor(ys / square).astype(np.int64)
    in_x = (ci >= -1) & (ci <= cols - 1)
    in_y = (rj >= -1) & (rj <= rows - 1)
    black = ((ci[None, :] + rj[:, None]) % 2 == 0) & in_x[None, :] & in_y[:, None]
    image = np.where(black, 0.0, 1.0)
    return TargetTexture(image=image, metres_per_pixel=float(metres_per_pixel), origin_m=origin)


def make_checkerboard_texture(board, metres_per_pixel, margin_m) -> TargetTexture:
    try:
        from jcalib.sim.textures import target_texture  # type: ignore[attr-defined]
    except ImportError:
        return checkerboard_texture(board.cols, board.rows, board.square, metres_per_pixel, margin_m)
    return target_texture(board, metres_per_pixel, margin_m)


def detect_checkerboard(image: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """(N, 2) sub-pixel corners (OpenCV order) or None. 16-bit images are scaled to 8 bits."""
    img = image
    if img.dtype != np.uint8:
        img = np.clip(np.rint(img.astype(np.float64) / img.max() * 255.0), 0, 255).astype(np.uint8)
    ok, corners = cv2.findChessboardCornersSB(img, (cols, rows), flags=cv2.CALIB_CB_ACCURACY)
    if not ok:
        return None
    corners = cv2.cornerSubPix(
        img, corners.astype(np.float32), (5, 5), (-1, -1),
        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4),
    )
    return corners.reshape(-1, 2).astype(np.float64)
