"""The fisheye (Kannala–Brandt, 4 coefficients) model exactly as ``cv2.fisheye``.

For a point ``(X, Y, Z)`` in the camera frame, with ``ρ = √(X² + Y²)`` and the angle from the
optical axis ``θ = atan2(ρ, Z)``::

    θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
    x' = θd X / ρ,   y' = θd Y / ρ          (x' = X/Z, y' = Y/Z on the axis, as OpenCV)
    u = fx (x' + alpha y') + cx,   v = fy y' + cy

For ``Z > 0`` this is ``cv2.fisheye.projectPoints`` (which computes ``θ = atan(√(x² + y²))`` with
``x = X/Z``). For ``Z ≤ 0`` OpenCV mirrors the point into the front half-space; here ``θ`` is the
true angle (up to π), so lenses with more than 180° field of view are represented.
``alpha`` is cv2.fisheye's skew: ``K[0][1] = alpha · fx``.

**Valid region.** A point is valid when it is farther than ``MIN_DEPTH_M`` from the camera centre
and ``θ < θ_max``, where ``θ_max`` is the smallest angle in ``(0, π]`` at which
``dθd/dθ = 1 + 3 k1 θ² + 5 k2 θ⁴ + 7 k3 θ⁶ + 9 k4 θ⁸`` reaches zero (``π`` if it never does),
found by sampling 512 angles, refined by two more levels of 512 samples (~1e-8 rad). Beyond
``θ_max`` the image radius decreases again (the image folds back).

``unproject`` solves ``θd(θ) = √(x'² + y'²)`` for ``θ ∈ [0, θ_max]`` with ``UNPROJECT_ITERATIONS``
bracketed Newton steps (bisection where Newton would leave the bracket, so it cannot diverge);
a pixel is valid when the residual is below ``UNPROJECT_TOLERANCE`` and ``θ < θ_max``. The
result's derivatives are the implicit-function ones (one Newton step on the solution).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.geometry.cameras.base import (
    concatenate_params,
    MIN_DEPTH_M,
    UNPROJECT_TOLERANCE,
    AbstractCameraModel,
    as_float64,
    bracketed_newton,
    check_image_size,
    check_param_vector,
    check_vector,
    edge_of_valid_range,
    safe_divide,
)

FISHEYE_DIST_NAMES = ("k1", "k2", "k3", "k4")

# cv2.fisheye treats a point as on the axis when √(x² + y²) <= 1e-8 (x = X/Z).
_AXIS_RATIO2 = 1e-16


def _theta_d(k: jax.Array, theta: jax.Array) -> jax.Array:
    """``θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``."""
    t2 = theta * theta
    return theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))


def _theta_d_slope(k: jax.Array, theta: jax.Array) -> jax.Array:
    """``dθd/dθ = 1 + 3 k1 θ² + 5 k2 θ⁴ + 7 k3 θ⁶ + 9 k4 θ⁸``."""
    t2 = theta * theta
    return 1.0 + t2 * (
        3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3]))
    )


# jitted: called outside a trace the loop body (a closure over k) would be re-compiled on every call
@jax.jit
def max_theta(k: jax.Array) -> jax.Array:
    """``θ_max`` (radians): the end of the monotonic range of ``θd(θ)``, at most π. Not differentiated."""
    k = jax.lax.stop_gradient(k)
    theta_max = edge_of_valid_range(
        lambda t: (_theta_d_slope(k, t), jnp.zeros_like(t)), math.pi
    )
    return jnp.minimum(theta_max, math.pi)


@jax.jit  # see max_theta
def _solve_theta(k: jax.Array, theta_d: jax.Array, theta_max: jax.Array) -> jax.Array:
    """``θ`` with ``θd(θ) = theta_d`` on ``[0, θ_max]`` (bracketed Newton; not differentiated)."""
    return bracketed_newton(lambda t: _theta_d(k, t), theta_d, theta_max)


class Fisheye(AbstractCameraModel):
    """Kannala–Brandt fisheye with 4 coefficients, as ``cv2.fisheye`` (see the module docstring).

    Attributes:
        image_size: ``(width, height)``, pixels (static).
        focal: ``(fx, fy)``, shape ``(2,)``, pixels.
        principal_point: ``(cx, cy)``, shape ``(2,)``, pixels.
        alpha: cv2.fisheye skew (unitless, ``K[0][1] / fx``), shape ``()``, or None.
        distortion: ``(k1, k2, k3, k4)``, shape ``(4,)``, unitless (θ in radians).
    """

    name: ClassVar[str] = "fisheye"
    mrcal_name: ClassVar[str | None] = None

    image_size: tuple[int, int] = eqx.field(static=True)
    focal: jax.Array
    principal_point: jax.Array
    alpha: jax.Array | None
    distortion: jax.Array

    def __init__(self, image_size, focal, principal_point, distortion, alpha=None):
        """Build the model (shapes are checked; values may be traced).

        Args:
            image_size: ``(width, height)``, two positive ints, pixels.
            focal: ``(fx, fy)``, pixels.
            principal_point: ``(cx, cy)``, pixels.
            distortion: ``(k1, k2, k3, k4)``.
            alpha: cv2.fisheye skew (``K[0][1] / fx``), or None for no skew parameter.
        """
        self.image_size = check_image_size(image_size)
        self.focal = check_vector(focal, (2,), "focal (fx, fy)")
        self.principal_point = check_vector(
            principal_point, (2,), "principal_point (cx, cy)"
        )
        self.alpha = None if alpha is None else check_vector(alpha, (), "alpha")
        self.distortion = check_vector(
            distortion, (4,), "distortion (k1, k2, k3, k4) of 'fisheye'"
        )

    # ---------------------------------------------------------------- parameters

    @property
    def has_skew(self) -> bool:
        return self.alpha is not None

    @property
    def param_names(self) -> tuple[str, ...]:
        return (
            ("fx", "fy", "cx", "cy")
            + (("alpha",) if self.has_skew else ())
            + FISHEYE_DIST_NAMES
        )

    @property
    def params(self) -> jax.Array:
        parts = [self.focal, self.principal_point]
        if self.alpha is not None:
            parts.append(self.alpha[None])
        parts.append(self.distortion)
        return concatenate_params(parts)

    @classmethod
    def from_params(cls, image_size, params, skew: bool = False):
        n_k = 5 if skew else 4
        names = (
            ("fx", "fy", "cx", "cy") + (("alpha",) if skew else ()) + FISHEYE_DIST_NAMES
        )
        params = check_param_vector(params, n_k + 4, cls.name, names)
        return cls(
            image_size,
            params[0:2],
            params[2:4],
            params[n_k:],
            alpha=params[4] if skew else None,
        )

    @property
    def K(self) -> jax.Array:
        zero, one = jnp.zeros(()), jnp.ones(())
        fx, fy = self.focal[0], self.focal[1]
        s = self.alpha * fx if self.alpha is not None else zero
        cx, cy = self.principal_point[0], self.principal_point[1]
        return jnp.stack([fx, s, cx, zero, fy, cy, zero, zero, one]).reshape(3, 3)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray]:
        fx, fy = np.asarray(self.focal, dtype=np.float64)
        cx, cy = np.asarray(self.principal_point, dtype=np.float64)
        s = 0.0 if self.alpha is None else float(np.asarray(self.alpha)) * fx
        K = np.array([[fx, s, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return K, np.asarray(self.distortion, np.float64).copy()

    # ---------------------------------------------------------------- projection

    def project_valid(self, p_cam):
        p = as_float64(p_cam, "p_cam", 3)
        X, Y, Z = p[..., 0], p[..., 1], p[..., 2]
        k = self.distortion
        rho2 = X * X + Y * Y
        on_axis = rho2 <= _AXIS_RATIO2 * (Z * Z)
        rho = jnp.sqrt(jnp.where(on_axis, 1.0, rho2))
        theta_off = jnp.arctan2(rho, Z)
        scale_off = _theta_d(k, theta_off) / rho
        # On the axis θd/ρ -> 1/Z (OpenCV: x' = x); Z is kept away from 0 so this stays finite.
        scale_on = 1.0 / jnp.where(Z > MIN_DEPTH_M, Z, MIN_DEPTH_M)
        scale = jnp.where(on_axis, scale_on, scale_off)
        xd, yd = X * scale, Y * scale
        if self.alpha is not None:
            xd = xd + self.alpha * yd
        u = self.focal[0] * xd + self.principal_point[0]
        v = self.focal[1] * (Y * scale) + self.principal_point[1]
        theta = jnp.where(on_axis, jnp.where(Z > 0.0, 0.0, math.pi), theta_off)
        valid = (theta < max_theta(k)) & (rho2 + Z * Z > MIN_DEPTH_M * MIN_DEPTH_M)
        return jnp.stack([u, v], axis=-1), valid

    def unproject_valid(self, pixels):
        px = as_float64(pixels, "pixels", 2)
        k = self.distortion
        yd = (px[..., 1] - self.principal_point[1]) / self.focal[1]
        xd = (px[..., 0] - self.principal_point[0]) / self.focal[0]
        if self.alpha is not None:
            xd = xd - self.alpha * yd
        r2d = xd * xd + yd * yd
        on_axis = r2d <= 1e-32
        theta_d = jnp.sqrt(jnp.where(on_axis, 1.0, r2d))

        theta_max = max_theta(k)
        k_ng, td_ng = jax.lax.stop_gradient(k), jax.lax.stop_gradient(theta_d)

        theta_s = _solve_theta(k_ng, td_ng, theta_max)
        # One differentiable Newton step from the solution gives the implicit derivatives.
        g = _theta_d(k, theta_s) - theta_d
        theta = theta_s - safe_divide(g, _theta_d_slope(k, theta_s))
        residual = jnp.abs(jax.lax.stop_gradient(g))
        converged = (residual <= UNPROJECT_TOLERANCE * jnp.maximum(1.0, td_ng)) & (
            theta_s < theta_max
        )

        s = jnp.sin(theta) / theta_d
        norm_axis = jnp.sqrt(r2d + 1.0)
        rx = jnp.where(on_axis, xd / norm_axis, s * xd)
        ry = jnp.where(on_axis, yd / norm_axis, s * yd)
        rz = jnp.where(on_axis, 1.0 / norm_axis, jnp.cos(theta))
        valid = on_axis | converged
        return jnp.stack([rx, ry, rz], axis=-1), valid
