"""A splined stereographic lens model for wide-angle and fisheye lenses (in the spirit of mrcal's
``LENSMODEL_SPLINED_STEREOGRAPHIC``).

For a point ``p = (X, Y, Z)`` in the camera frame, ``r = |p|``:

    u = 2 (X, Y) / (r + Z)                    (stereographic: |u| = 2 tan(θ/2), θ from the axis)
    u' = u + Δ(u)                             (Δ: a cubic B-spline surface, two values per control point)
    pixel = (fx u'x + cx, fy u'y + cy)

The spline's control points lie on a regular grid of :data:`GRID` = ``(nx, ny)`` points in the
stereographic plane, spacing ``h = 2 U / (nx − 3)`` in both directions, ``U = 2 tan(fov_x / 4)``: the
spline is defined for ``|ux| ≤ U`` and ``|uy| ≤ V = h (ny − 3) / 2`` (a horizontal field of view of
``fov_x`` around the axis, and ``V / U = 10/13`` of it vertically, enough for 4:3 images). A point
outside that domain, or at ``θ = π``, is not valid. ``Δ`` is in the stereographic plane's (unitless)
units: ``Δ = 0`` is an ideal stereographic lens.

Parameters (:attr:`param_names`): ``fx, fy, cx, cy``, then ``fov_x_deg`` (the spline's horizontal
extent, degrees; configuration, held by the calibration), then ``su{j}_{i}, sv{j}_{i}``: the two
values of control point ``(i, j)`` (column ``i`` along x, row ``j`` along y), row-major. A result file
stores them in ``dist`` (this is not an OpenCV model: exports refuse it; convert it first).

``unproject`` solves ``u + Δ(u) = w`` by Newton's method (2 x 2, from ``u = w``), then inverts the
stereographic projection: ``ray = (4 u, 4 − |u|²) / (4 + |u|²)``. Its derivatives are the
implicit-function ones (one differentiable Newton step on the solution).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.cameras.base import (
    MIN_DEPTH_M,
    AbstractCameraModel,
    as_float64,
    check_image_size,
    check_param_vector,
    check_vector,
    concatenate_params,
)

#: Control points ``(nx, ny)`` of the spline (cubic: ``nx − 3`` spans across the field of view).
GRID = (16, 13)

#: Newton iterations of ``unproject`` (the spline is a small correction: a few reach 1e-14).
UNPROJECT_ITERATIONS = 12

#: ``unproject`` has converged when ``|u + Δ(u) − w|`` is below this (stereographic units).
UNPROJECT_TOLERANCE = 1e-10

#: The spline's coefficient names (after ``fx, fy, cx, cy``), in :attr:`SplinedStereographic.params` order.
SPLINED_DIST_NAMES = ("fov_x_deg",) + tuple(
    f"s{ax}{j}_{i}" for j in range(GRID[1]) for i in range(GRID[0]) for ax in ("u", "v"))


def _basis(t):
    """Uniform cubic B-spline weights of the 4 control points around a span, ``t ∈ [0, 1]`` -> ``(..., 4)``."""
    t2, t3 = t * t, t * t * t
    return jnp.stack([(1.0 - t) ** 3, 3.0 * t3 - 6.0 * t2 + 4.0, -3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0, t3],
                     axis=-1) / 6.0


def _solve2(J, b):
    """``J⁻¹ b`` for ``J (..., 2, 2)``, ``b (..., 2)`` in closed form (no batched LAPACK call)."""
    det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
    det = jnp.where(jnp.abs(det) > 1e-300, det, 1e-300)
    x = (J[..., 1, 1] * b[..., 0] - J[..., 0, 1] * b[..., 1]) / det
    y = (J[..., 0, 0] * b[..., 1] - J[..., 1, 0] * b[..., 0]) / det
    return jnp.stack([x, y], axis=-1)


def spline_extent(fov_x_deg) -> tuple:
    """``(U, V, h)``: the half-widths of the spline's domain in the stereographic plane and its knot spacing."""
    nx, ny = GRID
    U = 2.0 * jnp.tan(jnp.radians(fov_x_deg) / 4.0)
    h = 2.0 * U / (nx - 3)
    return U, h * (ny - 3) / 2.0, h


def fov_covering(focal, principal_point, image_size, margin: float = 1.25) -> float:
    """The ``fov_x_deg`` whose spline domain covers the whole image for a stereographic lens with this
    focal length and principal point (``margin`` more), at most 350°."""
    w, h = image_size
    fx, fy = (float(v) for v in np.asarray(focal))
    cx, cy = (float(v) for v in np.asarray(principal_point))
    ux = max(abs(-0.5 - cx), abs(w - 0.5 - cx)) / fx
    uy = max(abs(-0.5 - cy), abs(h - 0.5 - cy)) / fy
    nx, ny = GRID
    U = margin * max(ux, uy * (nx - 3) / (ny - 3))
    return float(min(math.degrees(4.0 * math.atan(U / 2.0)), 350.0))


class SplinedStereographic(AbstractCameraModel):
    """Stereographic core plus a cubic B-spline correction (see the module docstring).

    Attributes:
        image_size: ``(width, height)``, pixels (static).
        focal: ``(fx, fy)``, pixels.  principal_point: ``(cx, cy)``, pixels.
        fov_x_deg: the spline's horizontal extent, degrees, shape ``()``.
        control: ``(ny, nx, 2)`` spline values (stereographic units).
    """

    name: ClassVar[str] = "splined"
    mrcal_name: ClassVar[str | None] = None

    image_size: tuple[int, int] = eqx.field(static=True)
    focal: jax.Array
    principal_point: jax.Array
    fov_x_deg: jax.Array
    control: jax.Array

    def __init__(self, image_size, focal, principal_point, fov_x_deg, control=None):
        self.image_size = check_image_size(image_size)
        self.focal = check_vector(focal, (2,), "focal (fx, fy)")
        self.principal_point = check_vector(principal_point, (2,), "principal_point (cx, cy)")
        self.fov_x_deg = check_vector(fov_x_deg, (), "fov_x_deg")
        nx, ny = GRID
        self.control = (jnp.zeros((ny, nx, 2)) if control is None
                        else check_vector(control, (ny, nx, 2), f"control ({ny}, {nx}, 2) of 'splined'"))

    # ---------------------------------------------------------------- parameters

    @property
    def has_skew(self) -> bool:
        return False

    @property
    def param_names(self) -> tuple[str, ...]:
        return ("fx", "fy", "cx", "cy") + SPLINED_DIST_NAMES

    @property
    def params(self) -> jax.Array:
        return concatenate_params([self.focal, self.principal_point, self.fov_x_deg[None], self.control.reshape(-1)])

    @classmethod
    def from_params(cls, image_size, params, skew: bool = False):
        if skew:
            raise BadInputError("model 'splined' has no skew parameter; remove skew: true")
        names = ("fx", "fy", "cx", "cy") + SPLINED_DIST_NAMES
        params = check_param_vector(params, len(names), cls.name, names)
        nx, ny = GRID
        return cls(image_size, params[0:2], params[2:4], params[4], params[5:].reshape(ny, nx, 2))

    @property
    def K(self) -> jax.Array:
        zero, one = jnp.zeros(()), jnp.ones(())
        fx, fy = self.focal[0], self.focal[1]
        cx, cy = self.principal_point[0], self.principal_point[1]
        return jnp.stack([fx, zero, cx, zero, fy, cy, zero, zero, one]).reshape(3, 3)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K, dist)`` as a result file stores them: ``dist`` is ``fov_x_deg`` and the spline values
        (:data:`SPLINED_DIST_NAMES`), not OpenCV coefficients."""
        params = np.asarray(self.params, np.float64)
        return np.asarray(self.K, np.float64), params[4:].copy()

    # ---------------------------------------------------------------- the spline

    def correction(self, u: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(Δ(u) (..., 2), inside (...))``: the spline at stereographic points ``u (..., 2)``."""
        nx, ny = GRID
        U, V, h = spline_extent(self.fov_x_deg)
        sx, sy = (u[..., 0] + U) / h, (u[..., 1] + V) / h
        inside = (sx >= 0.0) & (sx <= nx - 3) & (sy >= 0.0) & (sy <= ny - 3)
        return _spline(jnp.asarray(self.control), self.fov_x_deg, u) - u, inside

    # ---------------------------------------------------------------- projection

    def project_valid(self, p_cam):
        p = as_float64(p_cam, "p_cam", 3)
        r = jnp.sqrt(jnp.sum(p * p, axis=-1))
        den = r + p[..., 2]
        ok = (den > MIN_DEPTH_M * 1e-3) & (r > MIN_DEPTH_M)
        u = 2.0 * p[..., :2] / jnp.where(ok, den, 1.0)[..., None]
        d, inside = self.correction(u)
        v = u + d
        pixel = jnp.stack([self.focal[0] * v[..., 0] + self.principal_point[0],
                           self.focal[1] * v[..., 1] + self.principal_point[1]], axis=-1)
        return pixel, ok & inside

    def unproject_valid(self, pixels):
        px = as_float64(pixels, "pixels", 2)
        w = jnp.stack([(px[..., 0] - self.principal_point[0]) / self.focal[0],
                       (px[..., 1] - self.principal_point[1]) / self.focal[1]], axis=-1)
        control, fov = jnp.asarray(self.control), jnp.asarray(self.fov_x_deg)
        u_s, residual = _solve_u(jax.lax.stop_gradient(control), jax.lax.stop_gradient(fov), jax.lax.stop_gradient(w))
        # one differentiable Newton step from the solution: the implicit-function derivatives
        J = _correction_jacobian(jax.lax.stop_gradient(control), jax.lax.stop_gradient(fov), u_s)
        u = u_s - _solve2(J, u_s + self.correction(u_s)[0] - w)
        s = jnp.sum(u * u, axis=-1)
        ray = jnp.concatenate([4.0 * u, (4.0 - s)[..., None]], axis=-1) / (4.0 + s)[..., None]
        _, inside = self.correction(u_s)
        valid = (residual <= UNPROJECT_TOLERANCE) & inside & jnp.all(jnp.isfinite(u_s), axis=-1)
        return ray, valid


def _spline(control, fov_x_deg, u):
    """``u + Δ(u)`` of a spline given by its arrays (the model's correction, for the module-level solves)."""
    nx, ny = GRID
    U, V, h = spline_extent(fov_x_deg)
    flat = u.reshape(-1, 2)
    sx, sy = (flat[:, 0] + U) / h, (flat[:, 1] + V) / h
    ix = jnp.clip(jnp.floor(sx), 0, nx - 4).astype(jnp.int32)
    iy = jnp.clip(jnp.floor(sy), 0, ny - 4).astype(jnp.int32)
    bx = _basis(jnp.clip(sx - ix.astype(sx.dtype), 0.0, 1.0))
    by = _basis(jnp.clip(sy - iy.astype(sy.dtype), 0.0, 1.0))
    k = jnp.arange(4, dtype=jnp.int32)[None, :]
    rows, cols = iy[:, None] + k, ix[:, None] + k  # (n, 4)
    block = control[rows[:, :, None], cols[:, None, :]]  # (n, 4, 4, 2)
    return u + jnp.einsum("na,nb,nabc->nc", by, bx, block).reshape(u.shape)


def _correction_jacobian(control, fov_x_deg, u):
    """``∂(u + Δ(u))/∂u``, ``(..., 2, 2)``."""
    flat = u.reshape(-1, 2)
    J = jax.vmap(jax.jacfwd(lambda x: _spline(control, fov_x_deg, x)))(flat)
    return J.reshape(u.shape + (2,))


# jitted at module level: outside a trace, a loop over a closure would be compiled again on every call
@jax.jit
def _solve_u(control, fov_x_deg, w):
    """``(u, |u + Δ(u) − w|)``: Newton's method from ``u = w`` (not differentiated)."""

    def step(u, _):
        return u - _solve2(_correction_jacobian(control, fov_x_deg, u), _spline(control, fov_x_deg, u) - w), None

    u, _ = jax.lax.scan(step, w, None, length=UNPROJECT_ITERATIONS)
    return u, jnp.sqrt(jnp.sum((_spline(control, fov_x_deg, u) - w) ** 2, axis=-1))
