"""Convert a calibrated camera model into another lens model over the image region a user needs.

A rich model (a fisheye, OpenCV's rational or thin-prism terms) often has to run where only a simpler
one is understood: a vision library that reads pinhole + 5 coefficients, a robot controller, a ROS
driver. :func:`convert_camera` fits the target model to the source model's rays over a grid of pixels
in a region (default: the whole image), by the one solve path, and reports how well it can: the RMS
and largest difference in pixels over the region, and where the largest lies. The camera frame is the
same for both models (the fit has no rotation): a calibration's transforms stay valid.

The converted intrinsics' covariance is the source's propagated through the fit: with the sampled rays
``d(ψ) = unproject_ψ(q)`` and the fit ``θ* = argmin c(θ, ψ)``, ``c = ½ Σ |project_θ(d(ψ)) − q|²``, the
implicit-function theorem gives ``A = ∂θ*/∂ψ = −(∇²θθ c)⁻¹ ∇²θψ c`` (exact Hessians: an approximation
leaves residuals, so Gauss–Newton's ``JᵀJ`` would be off by their curvature terms), and
``Σ_θ = A Σ_ψ Aᵀ``. It contains the source's sampling noise, not the approximation error: the
report's RMS / max difference is that error, and it is systematic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.cameras.splined import GRID as SPLINE_GRID
from jcalib.problems.build import SPLINE_PRIOR_SIGMA
from jcalib.solve import Euclidean, FactorGroup, Problem, SolveOptions, Variable, solve

__all__ = ["Conversion", "convert_camera"]

#: Default sampling grid over the region, ``(nx, ny)`` pixels (edges included).
GRID = (40, 30)

#: Perspective (OpenCV) models cannot represent rays at or beyond 90° from the axis; rays farther
#: than this from the axis are left out of a fit to one (and counted).
MAX_PERSPECTIVE_ANGLE_DEG = 85.0


@dataclass(frozen=True)
class Conversion:
    """A camera model converted to another lens model.

    Attributes:
        model: the fitted camera model (target class, same image size).
        covariance: ``(p, p)`` covariance of ``model.params`` propagated from the source's, or None
            when the source had none.
        region: ``(x0, y0, x1, y1)`` pixels the fit covers.
        rms_px, max_px: RMS and largest length of ``project_target(ray) − pixel`` over the compared
            pixels (the approximation error); ``worst_pixel``: where the largest is.
        num_pixels: pixels compared; ``num_left_out``: grid pixels the source does not unproject, or
            whose rays the target cannot represent (beyond :data:`MAX_PERSPECTIVE_ANGLE_DEG` for a
            perspective model).
        source_model: the source model's name.
    """

    model: object
    covariance: np.ndarray | None
    region: tuple[float, float, float, float]
    rms_px: float
    max_px: float
    worst_pixel: tuple[float, float]
    num_pixels: int
    num_left_out: int
    source_model: str

    def summary(self) -> dict:
        """JSON-ready facts of the conversion (written next to the converted camera)."""
        return {"from_model": self.source_model, "region_px": [float(v) for v in self.region],
                "rms_px": self.rms_px, "max_px": self.max_px, "worst_pixel": [float(v) for v in self.worst_pixel],
                "num_pixels": self.num_pixels, "num_left_out": self.num_left_out}


def _region(source, region) -> tuple[float, float, float, float]:
    w, h = source.image_size
    if region is None:
        return (0.0, 0.0, float(w - 1), float(h - 1))
    try:
        x0, y0, x1, y1 = (float(v) for v in region)
    except (TypeError, ValueError):
        raise BadInputError(f"region: expected x0, y0, x1, y1 in pixels, got {region!r}") from None
    if not (0.0 <= x0 < x1 <= w - 1 and 0.0 <= y0 < y1 <= h - 1):
        raise BadInputError(f"region: got ({x0:g}, {y0:g}, {x1:g}, {y1:g}); expected 0 <= x0 < x1 <= {w - 1} and "
                            f"0 <= y0 < y1 <= {h - 1} (pixels of the {w}x{h} image)")
    return (x0, y0, x1, y1)


def _start(source, target_name: str, skew: bool, rays: np.ndarray):
    """The target's parameter names and start: the source's ``fx, fy, cx, cy``, no distortion; a splined
    target's extent (``fov_x_deg``) covers the stereographic image of ``rays`` ``(n, 3)`` with a margin."""
    K = np.asarray(source.K, np.float64)
    names = camera_model_from_name(target_name, source.image_size, skew=skew).param_names
    start = np.zeros(len(names))
    start[:4] = [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    if "fov_x_deg" in names:
        u = 2.0 * rays[:, :2] / (np.linalg.norm(rays, axis=1) + rays[:, 2])[:, None]
        U = 1.25 * max(np.max(np.abs(u[:, 0])), np.max(np.abs(u[:, 1])) * (SPLINE_GRID[0] - 3) / (SPLINE_GRID[1] - 3))
        start[names.index("fov_x_deg")] = min(np.degrees(4.0 * np.arctan(U / 2.0)), 350.0)
    return names, start


def _spline_prior(names, start) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A splined target's prior (the calibration's, :data:`~jcalib.problems.build.SPLINE_PRIOR_SIGMA` on
    each spline value, towards 0) as ``(mean (p,), sqrt_info (p, p), held (p,))``: it decides the control
    points no sample ray reaches and the spline's trade-off with the core; ``fov_x_deg`` (configuration)
    is held. Without a spline: no prior, nothing held."""
    p = len(names)
    if "fov_x_deg" not in names:
        return start, np.zeros((p, p)), np.zeros(p, bool)
    spline = np.arange(p) > names.index("fov_x_deg")
    return np.where(spline, 0.0, start), np.diag(np.where(spline, 1.0 / SPLINE_PRIOR_SIGMA, 0.0)), \
        np.arange(p) == names.index("fov_x_deg")


def convert_camera(source, to: str, covariance: np.ndarray | None = None, region=None,
                   grid: tuple[int, int] = GRID, fix: Sequence[str] = ()) -> Conversion:
    """Fit the lens model ``to`` to the camera model ``source`` over ``region``.

    Args:
        source: a calibrated camera model (:mod:`jcalib.geometry.cameras`).
        to: the target model's name (``pinhole``, ``opencv4`` ... ``opencv14``, ``fisheye``).
        covariance: ``(p, p)`` covariance of ``source.params``, or None.
        region: ``(x0, y0, x1, y1)`` pixels to fit over (default: the whole image).
        grid: ``(nx, ny)`` sample pixels across the region.
        fix: the target's coefficients held at 0 (e.g. ``k4, k5, k6`` of ``opencv8``, which a moderate
            field of view does not separate from ``k1, k2``).

    Raises:
        BadInputError: an unknown model, a region outside the image, too few representable rays.
        NotObservableError: the region does not determine some of the target's coefficients (names them
            and says to fix them or choose a simpler model).
    """
    x0, y0, x1, y1 = _region(source, region)
    nx, ny = (int(v) for v in grid)
    if nx < 2 or ny < 2:
        raise BadInputError(f"grid: got {grid!r}; expected at least 2 x 2 sample pixels")
    skew = bool(source.has_skew)
    camera_model_from_name(to, source.image_size, skew=skew)  # an unknown model is refused first
    u, v = np.meshgrid(np.linspace(x0, x1, nx), np.linspace(y0, y1, ny))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1)
    rays, ok = source.unproject_valid(jnp.asarray(pixels))
    rays, ok = np.array(rays), np.array(ok)
    if to not in ("fisheye", "splined"):
        ok &= rays[:, 2] > np.cos(np.radians(MAX_PERSPECTIVE_ANGLE_DEG)) * np.linalg.norm(rays, axis=1)
    names, start = _start(source, to, skew, rays[ok] if ok.any() else np.array([[0.0, 0.0, 1.0]]))
    target = camera_model_from_name(to, source.image_size, start, skew=skew)
    prior_mean, prior_S, config = _spline_prior(names, start)
    n = int(ok.sum())
    if n < 2 * len(names):
        raise BadInputError(
            f"to {to}: only {n} of the region's {len(pixels)} sample pixels give rays the {to} model can represent "
            f"(a perspective model needs rays within {MAX_PERSPECTIVE_ANGLE_DEG:g}° of the axis); choose a smaller "
            "region or a fisheye target")
    model_cls, size = type(target), tuple(int(s) for s in source.image_size)

    def residual(params, obs):
        ray, pixel = obs
        return model_cls.from_params(size, params, skew=skew).project(ray) - pixel

    residual.__jcalib_key__ = repr(("convert", to, size, skew))
    unknown = sorted(set(fix) - set(names[4:]))
    if unknown:
        raise BadInputError(f"fix: {', '.join(unknown)} are not coefficients of {to} (its coefficients: "
                            f"{', '.join(names[4:]) or 'none'})")
    held = np.array([n in set(fix) for n in names]) | config
    prior = {"prior_mean": prior_mean[None, :], "prior_sqrt_info": prior_S} if prior_S.any() else {}
    problem = Problem(
        [Variable("intrinsics", Euclidean(len(names)), start[None, :], fixed=held[None, :], coord_names=list(names),
                  entry_label=to, **prior)],
        [FactorGroup(f"rays of {source.name}", residual, ("intrinsics",), (np.zeros(n, np.int32),),
                     (rays[ok], pixels[ok]))])
    try:
        sol = solve(problem, options=SolveOptions(max_iterations=200))
    except NotObservableError as err:
        raise NotObservableError(
            f"to {to}: over this region the model's coefficients are not determined by its projection: {err} "
            f"Hold some at 0 (fix, e.g. the higher-order ones) or convert to a simpler model.") from None
    params = np.asarray(sol.values["intrinsics"][0])
    model = model_cls.from_params(size, params, skew=skew)
    diff = np.asarray(jax.vmap(lambda r: model.project(r))(jnp.asarray(rays[ok]))) - pixels[ok]
    length = np.linalg.norm(diff, axis=1)
    worst = int(np.argmax(length))

    cov = None
    if covariance is not None:
        covariance = np.asarray(covariance, np.float64)
        p = len(source.params)
        if covariance.shape != (p, p):
            raise BadInputError(f"covariance: expected shape ({p}, {p}) for the source's intrinsics, got "
                                f"{covariance.shape}")
        source_cls = type(source)

        def fit_residuals(theta, psi):
            src = source_cls.from_params(size, psi, skew=skew)
            d = src.unproject(jnp.asarray(pixels[ok]))
            return (jax.vmap(model_cls.from_params(size, theta, skew=skew).project)(d) - pixels[ok]).ravel()

        def cost(theta, psi):  # the fit's cost, with a splined target's prior
            r = fit_residuals(theta, psi)
            e = jnp.asarray(prior_S) @ (theta - jnp.asarray(prior_mean))
            return 0.5 * jnp.dot(r, r) + 0.5 * jnp.dot(e, e)

        psi = jnp.asarray(source.params)
        # the fit's stationarity ∇θ c(θ*, ψ) = 0, differentiated: the exact Hessian (not Gauss–Newton's
        # JᵀJ), since the residuals of an approximation are not zero at the fit
        H_tt, H_tp = (np.asarray(H) for H in jax.jit(
            lambda t, p: (jax.hessian(cost, 0)(t, p), jax.jacfwd(jax.grad(cost, 0), 1)(t, p)))(jnp.asarray(params), psi))
        free = ~held
        A = np.zeros((len(names), len(psi)))
        A[free] = -np.linalg.solve(H_tt[np.ix_(free, free)], H_tp[free])
        cov = A @ covariance @ A.T
        cov = 0.5 * (cov + cov.T)
    return Conversion(model, cov, (x0, y0, x1, y1), float(np.sqrt(np.mean(length**2))), float(length[worst]),
                      (float(pixels[ok][worst, 0]), float(pixels[ok][worst, 1])), n, len(pixels) - n, source.name)
