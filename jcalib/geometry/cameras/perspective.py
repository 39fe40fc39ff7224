"""Perspective cameras with OpenCV's distortion model: the shared implementation of
:class:`~jcalib.geometry.cameras.pinhole.Pinhole` and the ``OpenCV4`` … ``OpenCV14`` models.

The projection is exactly OpenCV's ``projectPoints`` (``rvec = tvec = 0``): with ``x = X/Z``,
``y = Y/Z``, ``r² = x² + y²``::

    radial = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)
    x'' = x radial + 2 p1 x y + p2 (r² + 2x²) + s1 r² + s2 r⁴
    y'' = y radial + p1 (r² + 2y²) + 2 p2 x y + s3 r² + s4 r⁴
    (x', y') = tilt(x'', y'')          # computeTiltProjectionMatrix(tx, ty), a homography
    u = fx x' + skew y' + cx,   v = fy y' + cy

Coefficients a model does not have are zero. OpenCV's own ``projectPoints`` ignores ``K[0][1]``;
here the skew enters after distortion and tilt, as ``K`` multiplies it (``u = fx x' + skew y' + cx``).

**Valid region.** A point is valid when all of these hold:

1. it is in front of the camera, ``Z > MIN_DEPTH_M``;
2. ``r² < r²_max``: the point lies in the disc around the axis on which the distortion
   ``(x, y) ↦ (x'', y'')`` is provably one-to-one. Write it as ``R + T``: the radial map
   ``R(x) = x · radial(r²)`` and the tangential + thin-prism terms ``T``. ``r_max`` is the largest
   ``r₀`` such that ``D(r²) = 1 + k4 r² + k5 r⁴ + k6 r⁶ > 0`` and
   ``m = min(dρ/dr, ρ/r) > τ(r₀)`` for every ``r ≤ r₀``, where ``ρ(r) = r·radial(r²)`` and
   ``τ(r₀)`` bounds the norm of ``T``'s Jacobian on the disc ``r ≤ r₀`` (from ``|p1|, |p2|,
   |s1..s4|``). ``R`` is the gradient of a potential whose
   Hessian has eigenvalues ``dρ/dr`` and ``ρ/r``, so ``<R(a) - R(b), a - b> >= m |a - b|²``, while
   ``|T(a) - T(b)| <= τ |a - b|``: ``R + T`` cannot map two points of the disc to one. Without
   tangential terms ``r_max`` is exactly where ``dρ/dr`` first reaches zero (beyond it the image
   folds back: points farther from the axis land closer to the centre). The search covers view
   angles up to 89.9° (``r ≤ tan 89.9°``) at 512 samples, refined by two more levels of 512
   samples (to ~1e-8 rad); where nothing fails up to there, ``r_max = ∞``;
3. the tilt homography keeps the point in front (its third coordinate is positive).

Outside the valid region the projection is still computed (finite, with finite derivatives) but
means nothing; ``Z`` near zero is replaced by ``MIN_DEPTH_M`` first. Points behind the camera
(``Z < -MIN_DEPTH_M``) project like in OpenCV (mirrored through the centre).

``unproject`` removes ``K``, inverts the tilt homography in closed form and inverts the
distortion: first the radial map alone along the direction of the distorted point (a bracketed
1-D Newton solve on ``[0, r_max]``, which cannot diverge), then ``UNPROJECT_REFINE_ITERATIONS``
2-D Newton steps for the tangential and prism terms (steps leaving the disc ``r < r_max`` are
pulled back inside). A pixel is valid when the distortion residual is below
``UNPROJECT_TOLERANCE`` and the solution lies inside the valid region. Derivatives of the result are
those of the implicit function (one extra Newton step on the converged, gradient-stopped
solution), so they are exact at convergence.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.cameras.base import (
    concatenate_params,
    MIN_DEPTH_M,
    UNPROJECT_REFINE_ITERATIONS,
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

#: OpenCV's distortion coefficient names, in OpenCV's order.
OPENCV_DIST_NAMES = (
    "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty",
)  # fmt: skip

#: Largest view angle at which the fold radius ``r_max`` is searched (radians).
MAX_SEARCH_ANGLE = math.radians(89.9)

#: The tilt homography's third coordinate must exceed this for a valid point.
MIN_TILT_W = 1e-9


def _coefficients(distortion: jax.Array | None, n: int) -> dict[str, jax.Array]:
    """Split the distortion vector into named 0-d arrays (only the ones the model has)."""
    if n == 0 or distortion is None:
        return {}
    return {name: distortion[i] for i, name in enumerate(OPENCV_DIST_NAMES[:n])}


def _radial(c: dict[str, jax.Array], r2: jax.Array) -> jax.Array:
    """OpenCV's radial factor ``(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)``."""
    if "k3" in c:
        radial = 1.0 + r2 * (c["k1"] + r2 * (c["k2"] + r2 * c["k3"]))
    else:
        radial = 1.0 + r2 * (c["k1"] + r2 * c["k2"])
    if "k4" in c:
        radial = safe_divide(
            radial, 1.0 + r2 * (c["k4"] + r2 * (c["k5"] + r2 * c["k6"]))
        )
    return radial


def _distort(
    c: dict[str, jax.Array], x: jax.Array, y: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """OpenCV's radial, tangential and thin-prism distortion (not the tilt), normalised coordinates."""
    if not c:
        return x, y
    r2 = x * x + y * y
    radial = _radial(c, r2)
    xy2 = 2.0 * x * y
    xd = x * radial + c["p1"] * xy2 + c["p2"] * (r2 + 2.0 * x * x)
    yd = y * radial + c["p1"] * (r2 + 2.0 * y * y) + c["p2"] * xy2
    if "s1" in c:
        xd = xd + r2 * (c["s1"] + r2 * c["s2"])
        yd = yd + r2 * (c["s3"] + r2 * c["s4"])
    return xd, yd


def tilt_matrix(tx: jax.Array, ty: jax.Array) -> jax.Array:
    """OpenCV's ``computeTiltProjectionMatrix(tauX = tx, tauY = ty)``, shape ``(3, 3)``.

    Args:
        tx, ty: sensor tilt angles, radians (0-d).
    """
    ctx, stx, cty, sty = jnp.cos(tx), jnp.sin(tx), jnp.cos(ty), jnp.sin(ty)
    zero, one = jnp.zeros_like(tx), jnp.ones_like(tx)
    rot_x = jnp.stack([one, zero, zero, zero, ctx, stx, zero, -stx, ctx]).reshape(3, 3)
    rot_y = jnp.stack([cty, zero, -sty, zero, one, zero, sty, zero, cty]).reshape(3, 3)
    rot_xy = rot_y @ rot_x
    proj_z = jnp.stack(
        [
            rot_xy[2, 2],
            zero,
            -rot_xy[0, 2],
            zero,
            rot_xy[2, 2],
            -rot_xy[1, 2],
            zero,
            zero,
            one,
        ]
    ).reshape(3, 3)
    return proj_z @ rot_xy


def _apply_homography(h: jax.Array, x: jax.Array, y: jax.Array):
    """``(h @ [x, y, 1])``: returns the three coordinates (dehomogenise yourself)."""
    a = h[0, 0] * x + h[0, 1] * y + h[0, 2]
    b = h[1, 0] * x + h[1, 1] * y + h[1, 2]
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return a, b, w


# jitted: called outside a trace (e.g. projecting with a concrete model), the loop's body closes over
# the parameters and would be re-traced and re-compiled on every call, leaking compiled code
@jax.jit
def fold_radius2(c: dict[str, jax.Array]) -> jax.Array:
    """``r²_max``: the squared radius of the disc where the distortion is one-to-one (``inf`` if
    it is up to ``MAX_SEARCH_ANGLE``). See the module docstring for the definition. Not
    differentiated.
    """
    if not c:
        return jnp.asarray(jnp.inf)
    zero = jnp.zeros(())
    c = {k: jax.lax.stop_gradient(v) for k, v in c.items()}
    k1, k2 = c["k1"], c["k2"]
    k3 = c.get("k3", zero)
    k4, k5, k6 = c.get("k4", zero), c.get("k5", zero), c.get("k6", zero)
    p1, p2 = jnp.abs(c["p1"]), jnp.abs(c["p2"])
    s1, s2 = jnp.abs(c.get("s1", zero)), jnp.abs(c.get("s2", zero))
    s3, s4 = jnp.abs(c.get("s3", zero)), jnp.abs(c.get("s4", zero))

    def margin(theta):
        r = jnp.tan(theta)
        u = r * r
        num = 1.0 + u * (k1 + u * (k2 + u * k3))
        dnum = k1 + u * (2.0 * k2 + 3.0 * u * k3)
        den = 1.0 + u * (k4 + u * (k5 + u * k6))
        dden = k4 + u * (2.0 * k5 + 3.0 * u * k6)
        # Radial map ρ(r) = r N/D: dρ/dr = P / D² with P = N D + 2u (N' D - N D'), u = r².
        slope_num = num * den + 2.0 * u * (dnum * den - num * dden)
        den_ok = den > 0.0
        den_safe = jnp.where(den_ok, den, 1.0)
        h = jnp.where(
            den_ok, jnp.minimum(slope_num / (den_safe * den_safe), num / den_safe), -1.0
        )
        # Entry-wise bounds of the Jacobian of the tangential + thin-prism terms (|x|, |y| <= r).
        a = 2.0 * p1 + 6.0 * p2 + 2.0 * s1 + 4.0 * s2 * u
        b = 2.0 * p1 + 2.0 * p2 + 2.0 * s1 + 4.0 * s2 * u
        cc = 2.0 * p1 + 2.0 * p2 + 2.0 * s3 + 4.0 * s4 * u
        d = 6.0 * p1 + 2.0 * p2 + 2.0 * s3 + 4.0 * s4 * u
        return h, r * jnp.sqrt(a * a + b * b + cc * cc + d * d)

    theta_max = edge_of_valid_range(margin, MAX_SEARCH_ANGLE)
    tan_max = jnp.tan(jnp.where(jnp.isfinite(theta_max), theta_max, 0.0))
    return jnp.where(jnp.isfinite(theta_max), tan_max * tan_max, jnp.inf)


@jax.jit  # see fold_radius2
def _undistort(
    c: dict[str, jax.Array], xt: jax.Array, yt: jax.Array, r2_max: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Solve ``_distort(c, x, y) == (xt, yt)``. Returns ``(x, y, converged)``.

    First the radial part alone, ``r·radial(r²) = |(xt, yt)|`` for ``r`` in ``[0, r_max]`` (a
    bracketed 1-D Newton solve, which cannot diverge because the radial map is increasing there),
    then 2-D Newton steps from that start for the tangential and prism terms (small corrections).
    """
    c_ng = {k: jax.lax.stop_gradient(v) for k, v in c.items()}
    xt_ng, yt_ng = jax.lax.stop_gradient(xt), jax.lax.stop_gradient(yt)
    finite_max = jnp.isfinite(r2_max)
    r_lim = jnp.sqrt(jnp.where(finite_max, r2_max, 1.0))
    r_upper = jnp.where(finite_max, r_lim, math.tan(MAX_SEARCH_ANGLE))

    # 1-D radial solve along the direction of the target.
    rd2 = xt_ng * xt_ng + yt_ng * yt_ng
    on_axis = rd2 <= 1e-300
    rd = jnp.sqrt(jnp.where(on_axis, 1.0, rd2))
    r = bracketed_newton(lambda r: r * _radial(c_ng, r * r), rd, r_upper)
    scale = jnp.where(on_axis, 1.0, r / rd)
    x0, y0 = xt_ng * scale, yt_ng * scale

    def pull_inside(x, y, r_prev):
        # A step that leaves the disc r < r_max lands halfway between the old radius and r_max.
        r2 = x * x + y * y
        out = finite_max & (r2 >= r2_max)
        scale = (0.5 * (r_prev + r_lim)) / jnp.sqrt(jnp.where(out, r2, 1.0))
        return jnp.where(out, x * scale, x), jnp.where(out, y * scale, y)

    def newton_step(c, x, y, xt, yt):
        ones, zeros = jnp.ones_like(x), jnp.zeros_like(x)
        (fx, fy), (a, cc) = jax.jvp(
            lambda x, y: _distort(c, x, y), (x, y), (ones, zeros)
        )
        _, (b, d) = jax.jvp(lambda x, y: _distort(c, x, y), (x, y), (zeros, ones))
        ex, ey = fx - xt, fy - yt
        det = a * d - b * cc
        return (
            x - safe_divide(d * ex - b * ey, det),
            y - safe_divide(a * ey - cc * ex, det),
            ex,
            ey,
        )

    def body(_, xy):
        x, y = xy
        xn, yn, _, _ = newton_step(c_ng, x, y, xt_ng, yt_ng)
        return pull_inside(xn, yn, jnp.sqrt(x * x + y * y))

    xs, ys = jax.lax.fori_loop(0, UNPROJECT_REFINE_ITERATIONS, body, (x0, y0))
    xs, ys = jax.lax.stop_gradient(xs), jax.lax.stop_gradient(ys)
    # One differentiable Newton step from the solution gives the implicit derivatives.
    x, y, ex, ey = newton_step(c, xs, ys, xt, yt)
    tol = UNPROJECT_TOLERANCE * jnp.maximum(
        1.0, jnp.maximum(jnp.abs(xt_ng), jnp.abs(yt_ng))
    )
    residual = jnp.maximum(
        jnp.abs(jax.lax.stop_gradient(ex)), jnp.abs(jax.lax.stop_gradient(ey))
    )
    converged = (residual <= tol) & (xs * xs + ys * ys < r2_max)
    return x, y, converged


class AbstractPerspectiveModel(AbstractCameraModel):
    """A perspective camera with OpenCV's distortion model (see the module docstring).

    Attributes:
        image_size: ``(width, height)``, pixels (static).
        focal: ``(fx, fy)``, shape ``(2,)``, pixels.
        principal_point: ``(cx, cy)``, shape ``(2,)``, pixels (OpenCV convention).
        skew: ``K[0][1]``, shape ``()``, pixels, or None for a model without skew.
        distortion: OpenCV's distortion coefficients, shape ``(num_coeffs,)`` (``tx, ty`` in
            radians, the rest unitless), or None for the pinhole.
    """

    num_coeffs: eqx.AbstractClassVar[int]

    image_size: tuple[int, int] = eqx.field(static=True)
    focal: jax.Array
    principal_point: jax.Array
    skew: jax.Array | None
    distortion: jax.Array | None

    def __init__(self, image_size, focal, principal_point, distortion=None, skew=None):
        """Build the model (shapes are checked; values may be traced).

        Args:
            image_size: ``(width, height)``, two positive ints, pixels.
            focal: ``(fx, fy)``, pixels.
            principal_point: ``(cx, cy)``, pixels.
            distortion: ``(num_coeffs,)`` OpenCV coefficients; None (or empty) for the pinhole.
            skew: ``K[0][1]`` in pixels, or None for no skew parameter.
        """
        self.image_size = check_image_size(image_size)
        self.focal = check_vector(focal, (2,), "focal (fx, fy)")
        self.principal_point = check_vector(
            principal_point, (2,), "principal_point (cx, cy)"
        )
        self.skew = None if skew is None else check_vector(skew, (), "skew")
        n = self.num_coeffs
        if n == 0:
            if distortion is not None and np.size(distortion) != 0:
                raise BadInputError(
                    f"distortion for model {self.name!r} must be empty or None; got shape "
                    f"{np.shape(distortion)}"
                )
            self.distortion = None
        else:
            self.distortion = check_vector(
                distortion, (n,), f"distortion of model {self.name!r}"
            )

    # ---------------------------------------------------------------- parameters

    @property
    def has_skew(self) -> bool:
        return self.skew is not None

    @property
    def param_names(self) -> tuple[str, ...]:
        return (
            ("fx", "fy", "cx", "cy")
            + (("skew",) if self.has_skew else ())
            + OPENCV_DIST_NAMES[: self.num_coeffs]
        )

    @property
    def params(self) -> jax.Array:
        parts = [self.focal, self.principal_point]
        if self.skew is not None:
            parts.append(self.skew[None])
        if self.distortion is not None:
            parts.append(self.distortion)
        return concatenate_params(parts)

    @classmethod
    def from_params(cls, image_size, params, skew: bool = False):
        n_k = 5 if skew else 4
        names = (
            ("fx", "fy", "cx", "cy")
            + (("skew",) if skew else ())
            + OPENCV_DIST_NAMES[: cls.num_coeffs]
        )
        params = check_param_vector(params, n_k + cls.num_coeffs, cls.name, names)
        return cls(
            image_size,
            params[0:2],
            params[2:4],
            distortion=params[n_k:] if cls.num_coeffs else None,
            skew=params[4] if skew else None,
        )

    @property
    def K(self) -> jax.Array:
        zero, one = jnp.zeros(()), jnp.ones(())
        s = self.skew if self.skew is not None else zero
        fx, fy = self.focal[0], self.focal[1]
        cx, cy = self.principal_point[0], self.principal_point[1]
        return jnp.stack([fx, s, cx, zero, fy, cy, zero, zero, one]).reshape(3, 3)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray]:
        fx, fy = np.asarray(self.focal, dtype=np.float64)
        cx, cy = np.asarray(self.principal_point, dtype=np.float64)
        s = 0.0 if self.skew is None else float(np.asarray(self.skew))
        K = np.array([[fx, s, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        if self.distortion is None:
            return K, np.zeros(0, dtype=np.float64)
        return K, np.asarray(self.distortion, dtype=np.float64).copy()

    # ---------------------------------------------------------------- projection

    def project_valid(self, p_cam):
        p = as_float64(p_cam, "p_cam", 3)
        X, Y, Z = p[..., 0], p[..., 1], p[..., 2]
        # OpenCV divides by Z whatever its sign; only |Z| ~ 0 is replaced to stay finite.
        Z_safe = jnp.where(jnp.abs(Z) > MIN_DEPTH_M, Z, MIN_DEPTH_M)
        x, y = X / Z_safe, Y / Z_safe
        c = _coefficients(self.distortion, self.num_coeffs)
        xd, yd = _distort(c, x, y)
        valid = Z > MIN_DEPTH_M
        if c:
            valid = valid & (x * x + y * y < fold_radius2(c))
        if "tx" in c:
            a, b, w = _apply_homography(tilt_matrix(c["tx"], c["ty"]), xd, yd)
            valid = valid & (w > MIN_TILT_W)
            w_safe = jnp.where(jnp.abs(w) > MIN_TILT_W, w, MIN_TILT_W)
            xd, yd = a / w_safe, b / w_safe
        u = self.focal[0] * xd + self.principal_point[0]
        if self.skew is not None:
            u = u + self.skew * yd
        v = self.focal[1] * yd + self.principal_point[1]
        return jnp.stack([u, v], axis=-1), valid

    def unproject_valid(self, pixels):
        px = as_float64(pixels, "pixels", 2)
        yd = (px[..., 1] - self.principal_point[1]) / self.focal[1]
        xu = px[..., 0] - self.principal_point[0]
        if self.skew is not None:
            xu = xu - self.skew * yd
        xd = xu / self.focal[0]
        c = _coefficients(self.distortion, self.num_coeffs)
        valid = jnp.ones(xd.shape, dtype=bool)
        if "tx" in c:
            # (x'', y'', 1) ∝ tilt⁻¹ (x', y', 1); tilt = P_z R, so tilt⁻¹ = Rᵀ P_z⁻¹.
            a, b, w = _apply_homography(
                jnp.linalg.inv(tilt_matrix(c["tx"], c["ty"])), xd, yd
            )
            valid = valid & (w > MIN_TILT_W)
            w_safe = jnp.where(jnp.abs(w) > MIN_TILT_W, w, MIN_TILT_W)
            xd, yd = a / w_safe, b / w_safe
        if c:
            x, y, converged = _undistort(c, xd, yd, fold_radius2(c))
            valid = valid & converged
        else:
            x, y = xd, yd
        norm = jnp.sqrt(x * x + y * y + 1.0)
        rays = jnp.stack([x / norm, y / norm, 1.0 / norm], axis=-1)
        return rays, valid
