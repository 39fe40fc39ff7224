"""Compare two calibrations of one camera: where they project differently, and whether that is more than
their uncertainties predict (mrcal's "projection diff", with the difference's own covariance and a χ² verdict).

How the difference is defined. A grid of pixels ``q`` spans the image (edges included). Camera A
unprojects each to a unit ray ``v_a`` in its frame ``cam_a``; the rotation ``R_b_a`` (``cam_a`` ->
``cam_b``) that best maps A's rays into B's frame is fitted; B projects the rotated ray::

    d(q) = project_B(R_b_a · unproject_A(q)) − q        (pixels, "where B sees what A sees at q")

Two calibrations of one camera share no physical camera frame: a small rotation of the frame trades
off against the principal point and the distortion centre, so a rotation is not a difference of the
lens (mrcal, "Differencing"). ``R_b_a`` minimises ``Σ |d(q)|²`` over the compared grid points (a
Gauss-Newton fit from the closed-form alignment of the two models' rays). With ``fit_rotation=False``
``R_b_a`` is the identity.

How the prediction is defined. To first order, ``d ≈ J_a δθ_a + J_b δθ_b`` where ``δθ`` are the
errors of the two intrinsic vectors, assumed independent (two calibrations from different data),
with the covariances the calibrations reported. ``J`` is computed by JAX (``jacfwd``, float64) through
the whole chain: A's unprojection (its implicit derivative), the fitted rotation (its derivative
through one Newton step of the fit, exact at convergence: the rotation moves with the parameters and
absorbs part of their error) and B's projection. The predicted covariance of ``d`` at each grid point
is ``Σ = J_a C_a J_aᵀ + J_b C_b J_bᵀ (2x2, px²)``; at each point ``χ² = dᵀ (Σ + f² I)⁻¹ d`` with 2
degrees of freedom, ``f = SIGMA_FLOOR_PX`` (differences below a thousandth of a pixel are not
resolved: unprojection tolerance and second-order terms). Checked by Monte Carlo (tests/report/
test_compare.py, benchmarks/bench_compare.py): with parameter errors drawn from the covariances the mean χ²
is 2; with whole 10-view calibrations, whose σ reach pixels at the corners, the first-order prediction is a
little pessimistic there (mean χ² ≈ 1.9).

The verdict. Two tests of "the differences are what the σ predict", each at level
``ALPHA / 2`` (false alarms ≤ ``ALPHA`` = 1 % when the covariances are right):

- local: the largest per-point χ² against the 2-dof χ² quantile with Bonferroni's correction for the
  number of grid points compared (a difference concentrated in one region, e.g. the corners);
- global: the sum of the per-point χ² against its exact null distribution (a weighted sum of 1-dof
  χ², the weights the eigenvalues of the whitened difference covariance; its saddlepoint approximation): a
  difference spread over the image, or covariances too small everywhere.

"consistent" when both pass, "differ" otherwise. What the σ include: the noise of the two
calibrations' observations as their solves reported it (sampling noise). What they exclude: model
error. A "differ" between two calibrations of the same camera therefore means model error, a camera
that changed, or reported σ too small (mrcal's cross-validation argument).

Distance. Both lens models are central and the fitted transformation is a rotation, so
``project_B(R_b_a · s v)`` is the same for every range ``s``: the comparison at a finite
``distance_m`` is the comparison at infinity. A translation between the two frames (mrcal's fit at
finite range) is not fitted; ``distance_m`` is recorded with the result.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.result import CameraResult, ResultFile, load_result

if TYPE_CHECKING:
    from jcalib.problems.crossval import SplitHalves

__all__ = [
    "ALPHA",
    "CHI2_99_2DOF",
    "DEFAULT_GRID",
    "SIGMA_FLOOR_PX",
    "Comparison",
    "SplitHalfComparison",
    "comparison_table",
    "compare_cameras",
    "compare_results",
    "image_region_name",
    "print_comparisons",
    "quadratic_form_sf",
    "split_half_comparison",
    "write_comparisons",
]

#: Grid points across the image ``(nx, ny)`` (edges and corners included).
DEFAULT_GRID = (24, 18)

#: False-alarm rate of the verdict "differ" when the covariances are right (split over its two tests).
ALPHA = 0.01

#: 99 % quantile of the χ² distribution with 2 degrees of freedom: ``-2 ln 0.01``.
CHI2_99_2DOF = -2.0 * math.log(0.01)

#: Per-coordinate floor (px) added to the predicted σ of each difference.
SIGMA_FLOOR_PX = 1e-3

#: Gauss-Newton iterations of the rotation fit (after the closed-form start; converges in 2-3).
ROTATION_ITERATIONS = 8

_REGIONS = (("top-left corner", "top edge", "top-right corner"),
            ("left edge", "centre", "right edge"),
            ("bottom-left corner", "bottom edge", "bottom-right corner"))


# ------------------------------------------------------------------------------------------ inputs


@dataclass(frozen=True)
class _Camera:
    """One side of a comparison: lens model class, configuration, parameters and covariance."""

    name: str
    cls: type
    image_size: tuple[int, int]
    skew: bool
    params: np.ndarray
    covariance: np.ndarray | None
    param_names: tuple[str, ...]


def _camera(cam: Any, which: str) -> _Camera:
    """A :class:`CameraResult`, or ``(model, covariance)`` (covariance None: known exactly)."""
    from jcalib.geometry.cameras import CAMERA_MODELS, AbstractCameraModel

    if isinstance(cam, CameraResult):
        if cam.covariance is None:
            raise BadInputError(
                f"compare: camera {which} ({cam.model}) has no intrinsics covariance; the comparison needs "
                "the full covariance the calibration wrote (result files from `jcalib calibrate` have one)")
        cls = CAMERA_MODELS[cam.model]
        return _Camera(cam.model, cls, tuple(cam.image_size), bool(cam.skew), np.asarray(cam.params, np.float64),
                       np.asarray(cam.covariance, np.float64), tuple(cam.param_names))
    if isinstance(cam, tuple) and len(cam) == 2 and isinstance(cam[0], AbstractCameraModel):
        model, cov = cam
        names = tuple(model.param_names)
        params = np.asarray(model.params, np.float64)
        if cov is not None:
            cov = np.asarray(cov, np.float64)
            if cov.shape != (len(names), len(names)) or not np.all(np.isfinite(cov)):
                raise BadInputError(
                    f"compare: camera {which}: covariance must be finite with shape {(len(names), len(names))} "
                    f"(order {', '.join(names)}); got shape {cov.shape}")
            cov = 0.5 * (cov + cov.T)
        return _Camera(model.name, type(model), tuple(int(s) for s in model.image_size), bool(model.has_skew),
                       params, cov, names)
    raise BadInputError(
        f"compare: camera {which} must be a CameraResult or a (camera model, covariance) pair; got "
        f"{type(cam).__name__}")


def _check_pair(a: _Camera, b: _Camera) -> None:
    if a.image_size != b.image_size:
        raise BadInputError(
            f"compare: the image sizes differ: A is {a.image_size[0]}x{a.image_size[1]} px, B is "
            f"{b.image_size[0]}x{b.image_size[1]} px; compare two calibrations of the same camera and resolution")
    if a.covariance is None and b.covariance is None:
        raise BadInputError(
            "compare: neither camera has an intrinsics covariance; at least one must have one to predict "
            "the difference")


def _check_grid(grid: Any) -> tuple[int, int]:
    try:
        nx, ny = (int(g) for g in grid)
        ok = all(int(g) == g for g in grid)
    except (TypeError, ValueError):
        ok = False
    if not ok or not (2 <= nx <= 400 and 2 <= ny <= 400):
        raise BadInputError(f"compare: grid must be two integers (nx, ny) between 2 and 400; got {grid!r}")
    return nx, ny


def _check_region(region: Any) -> tuple[float, float, float, float] | None:
    if region is None:
        return None
    try:
        u0, v0, u1, v1 = (float(x) for x in region)
    except (TypeError, ValueError):
        u0 = v0 = u1 = v1 = float("nan")
    if not (np.isfinite([u0, v0, u1, v1]).all() and u0 < u1 and v0 < v1):
        raise BadInputError(
            f"compare: region must be (u_min, v_min, u_max, v_max) in pixels with u_min < u_max and "
            f"v_min < v_max; got {region!r}")
    return u0, v0, u1, v1


# ------------------------------------------------------------------------------------------ the JAX part


@functools.cache
def _difference_jacobian(cls_a: type, cls_b: type, image_size: tuple[int, int], skew_a: bool, skew_b: bool,
                         fit_rotation: bool):
    """Compiled ``(θ_a, θ_b, pixels (n, 2), use (n,)) -> (J_a (n,2,p_a), J_b (n,2,p_b)), (d (n,2), valid (n,),
    R_b_a (3,3))``: the difference and its Jacobians w.r.t. both intrinsic vectors."""
    import jax
    import jax.numpy as jnp

    from jcalib.geometry.lie import so3_exp, so3_to_matrix

    def rotation(omega, R0):
        return so3_to_matrix(so3_exp(omega)) @ R0

    def difference(theta_a, theta_b, pixels, use):
        cam_a = cls_a.from_params(image_size, theta_a, skew=skew_a)
        cam_b = cls_b.from_params(image_size, theta_b, skew=skew_b)
        v_a, ok_a = cam_a.unproject_valid(pixels)
        if fit_rotation:
            # Closed-form start (not differentiated): the rotation aligning A's rays with B's (Kabsch).
            v_a0 = jax.lax.stop_gradient(v_a)
            cam_b0 = cls_b.from_params(image_size, jax.lax.stop_gradient(theta_b), skew=skew_b)
            v_b0, ok_b0 = cam_b0.unproject_valid(pixels)
            w0 = (use & ok_a & ok_b0).astype(jnp.float64)
            H = jnp.einsum("n,ni,nj->ij", w0, v_b0, v_a0)
            U, _, Vt = jnp.linalg.svd(H)
            sign = jnp.sign(jnp.linalg.det(U @ Vt))
            R0 = U @ jnp.diag(jnp.stack([jnp.ones(()), jnp.ones(()), sign])) @ Vt
            _, ok_p0 = cam_b0.project_valid(v_a0 @ R0.T)
            w = w0 * ok_p0.astype(jnp.float64)

            def residual(omega, v, cam):
                return cam.project(v @ rotation(omega, R0).T) - pixels

            def gauss_newton(_, omega):
                r = residual(omega, v_a0, cam_b0)
                J = jax.jacfwd(residual)(omega, v_a0, cam_b0)  # (n, 2, 3)
                Hw = jnp.einsum("n,nia,nib->ab", w, J, J)
                g = jnp.einsum("n,nia,ni->a", w, J, r)
                return omega - jnp.linalg.solve(Hw + 1e-12 * jnp.trace(Hw) * jnp.eye(3), g)

            omega = jax.lax.stop_gradient(jax.lax.fori_loop(0, ROTATION_ITERATIONS, gauss_newton, jnp.zeros(3)))

            # One Newton step, differentiated: the rotation's dependence on both parameter vectors. At the
            # converged fit the gradient g is zero, so the step's derivative is -H⁻¹ ∂g/∂θ, the implicit
            # function theorem's (exact); H (the full Hessian of the cost) is needed as a value only.
            def cost(o):
                return 0.5 * jnp.sum(w * jnp.sum(residual(o, v_a0, cam_b0) ** 2, axis=-1))

            Hn = jax.lax.stop_gradient(jax.hessian(cost)(omega))
            J = jax.jacfwd(residual)(omega, v_a, cam_b)
            g = jnp.einsum("n,nia,ni->a", w, J, residual(omega, v_a, cam_b))
            omega = omega - jnp.linalg.solve(Hn, g)
            R = rotation(omega, R0)
        else:
            w = (use & ok_a).astype(jnp.float64)
            R = jnp.eye(3)
        p_b, ok_b = cam_b.project_valid(v_a @ R.T)
        valid = use & ok_a & ok_b & (w > 0.0)
        d = jnp.where(valid[:, None], p_b - pixels, 0.0)
        return d, (d, valid, jax.lax.stop_gradient(R))

    return jax.jit(jax.jacfwd(difference, argnums=(0, 1), has_aux=True))


# ------------------------------------------------------------------------------------------ statistics


def quadratic_form_sf(x: float, weights: np.ndarray) -> float:
    """``P(Σ_k μ_k z_k² > x)`` for independent standard normal ``z_k`` and weights ``μ_k >= 0``.

    The saddlepoint approximation of Lugannani and Rice (Kuonen 1999, "Saddlepoint approximations for
    distributions of quadratic forms in normal variables"): relative error of a few per cent in the upper
    tail, where the verdict is decided; its limit (from the third cumulant) within ``1e-6`` of the mean.
    """
    from scipy.optimize import brentq
    from scipy.stats import norm

    mu = np.asarray(weights, np.float64)
    mu = mu[mu > 1e-12 * max(float(mu.max(initial=0.0)), 1e-300)]
    if mu.size == 0 or x <= 0.0:
        return 1.0 if x <= 0.0 else 0.0
    mean, var = float(np.sum(mu)), float(2.0 * np.sum(mu ** 2))

    def k1(s: float) -> float:
        return float(np.sum(mu / (1.0 - 2.0 * s * mu))) - x

    at_mean = 0.5 - 8.0 * float(np.sum(mu ** 3)) / (6.0 * math.sqrt(2.0 * math.pi) * var ** 1.5)
    if abs(x - mean) < 1e-6 * mean:
        return at_mean  # the formula's limit at the mean (third cumulant)
    if x > mean:
        upper = (1.0 - 1e-15) / (2.0 * mu.max())
        if k1(upper) <= 0.0:
            return 0.0  # beyond 1e15 times the largest weight: no probability to speak of
        s_hat = brentq(k1, 0.0, upper, xtol=1e-300, rtol=1e-14, maxiter=500)
    else:
        lo = -1.0 / (2.0 * mu.max())
        while k1(lo) > 0.0:
            lo *= 2.0
            if lo < -1e12 / mu.min():
                return 1.0  # below 1e-12 of the smallest weight: certain to be exceeded
        s_hat = brentq(k1, lo, 0.0, xtol=1e-300, rtol=1e-14, maxiter=500)
    cgf = float(-0.5 * np.sum(np.log1p(-2.0 * s_hat * mu)))
    w = math.copysign(math.sqrt(max(2.0 * (s_hat * x - cgf), 0.0)), s_hat)
    v = s_hat * math.sqrt(float(np.sum(2.0 * mu ** 2 / (1.0 - 2.0 * s_hat * mu) ** 2)))
    if abs(w) < 1e-8 or v == 0.0:
        return at_mean
    return float(min(max(norm.sf(w) + norm.pdf(w) * (1.0 / v - 1.0 / w), 0.0), 1.0))


def image_region_name(u: float, v: float, image_size: tuple[int, int]) -> str:
    """Where pixel ``(u, v)`` lies in the image, in words: "centre", "left edge", "top-right corner"…
    (the image cut into thirds each way)."""
    width, height = image_size
    col = min(int(3.0 * (u + 0.5) / width), 2) if u >= 0 else 0
    row = min(int(3.0 * (v + 0.5) / height), 2) if v >= 0 else 0
    return _REGIONS[row][col]


@dataclass(frozen=True, eq=False)
class Comparison:
    """Two calibrations of one camera compared over a grid of pixels (see the module docstring).

    Only grid points where both models are valid (A unprojects the pixel, B projects the rotated ray)
    and that lie inside ``region`` are compared; the others are skipped (``num_skipped``), never NaN.

    Attributes:
        camera: the camera's name (or ``None``).
        model: A's lens model name; ``model_b``: B's (another model: compared across lens models);
        ``image_size``: ``(width, height)``, px.
        grid: ``(nx, ny)`` grid points across the image, edges included.
        pixels: ``(m, 2)`` the compared grid pixels ``q`` (OpenCV convention), px.
        grid_index: ``(m, 2)`` ``(ix, iy)`` of each compared pixel in the grid.
        diff_px: ``(m, 2)`` ``d(q) = project_B(R_b_a unproject_A(q)) − q``, px.
        covariance_px2: ``(m, 2, 2)`` predicted covariance of ``d`` from the two intrinsics covariances
            (first order, through the rotation fit), px²; excludes model error.
        sigma_px: ``(m,)`` predicted 1σ of ``d`` in its worst direction, ``sqrt(λ_max(Σ))``, px.
        chi2: ``(m,)`` ``dᵀ (Σ + f² I)⁻¹ d`` (2 dof under "consistent").
        R_b_a: ``(3, 3)`` fitted rotation from A's camera frame to B's (identity without the fit).
        rotation_deg: its angle, degrees.
        num_skipped: grid points not compared (invalid or outside ``region``).
        distance_m: the range of the compared points (None: at infinity); the result does not depend on it.
        fit_rotation: whether ``R_b_a`` was fitted.
        chi2_mean_expected: expected mean of ``chi2`` over the points if the covariances are right (≈ 2).
        chi2_mean_std: its standard deviation under the same hypothesis (the points are correlated).
        p_local: family-wise p-value of the largest per-point χ² (Bonferroni over the ``m`` points).
        p_global: p-value of the sum of the per-point χ² (its exact null distribution).
    """

    camera: str | None
    model: str
    image_size: tuple[int, int]
    grid: tuple[int, int]
    pixels: np.ndarray
    grid_index: np.ndarray
    diff_px: np.ndarray
    covariance_px2: np.ndarray
    sigma_px: np.ndarray
    chi2: np.ndarray
    R_b_a: np.ndarray  # noqa: N815
    rotation_deg: float
    num_skipped: int
    distance_m: float | None
    fit_rotation: bool
    chi2_mean_expected: float
    chi2_mean_std: float
    p_local: float
    p_global: float
    model_b: str | None = None

    @property
    def models(self) -> str:
        """``"opencv5"``, or ``"opencv5 → fisheye"`` when A's and B's lens models differ."""
        return self.model if self.model_b in (None, self.model) else f"{self.model} → {self.model_b}"

    # ---------------------------------------------------------------- summary numbers

    @property
    def num_points(self) -> int:
        """Grid points compared."""
        return int(self.pixels.shape[0])

    @property
    def norm_px(self) -> np.ndarray:
        """``(m,)`` length of each difference, px."""
        return np.linalg.norm(self.diff_px, axis=-1)

    @property
    def rms_px(self) -> float:
        """RMS over the grid of the difference lengths, px."""
        return float(np.sqrt(np.mean(self.norm_px ** 2)))

    @property
    def max_px(self) -> float:
        """Largest difference length, px."""
        return float(np.max(self.norm_px))

    @property
    def sigma_rms_px(self) -> float:
        """RMS over the grid of the predicted σ of the difference length, ``sqrt(trace Σ)``, px."""
        return float(np.sqrt(np.mean(np.trace(self.covariance_px2, axis1=-2, axis2=-1))))

    @property
    def chi2_mean(self) -> float:
        """Mean per-point χ² (≈ ``chi2_mean_expected`` ± ``chi2_mean_std`` when consistent)."""
        return float(np.mean(self.chi2))

    @property
    def fraction_flagged(self) -> float:
        """Fraction of the compared points whose χ² exceeds the 2-dof 99 % quantile (1 % expected)."""
        return float(np.mean(self.chi2 > CHI2_99_2DOF))

    @property
    def verdict(self) -> str:
        """``"consistent"`` when both tests pass at ``ALPHA / 2``, else ``"differ"``."""
        return "consistent" if min(self.p_local, self.p_global) >= 0.5 * ALPHA else "differ"

    @property
    def where(self) -> str:
        """Where the difference is largest (e.g. "top-left corner", "centre")."""
        q = self.pixels[int(np.argmax(self.norm_px))]
        return image_region_name(float(q[0]), float(q[1]), self.image_size)

    @property
    def message(self) -> str:
        """One sentence: the verdict, how large, where."""
        i = int(np.argmax(self.norm_px))
        k = int(np.argmax(self.chi2))
        q, qk = self.pixels[i], self.pixels[k]
        size = (f"RMS {self.rms_px:.3g} px, largest {self.max_px:.3g} px at ({q[0]:.0f}, {q[1]:.0f}) in the "
                f"{self.where}; predicted σ RMS {self.sigma_rms_px:.3g} px")
        if self.verdict == "consistent":
            return (f"consistent: the difference is what the two covariances predict ({size}; mean χ² "
                    f"{self.chi2_mean:.2f}, expected {self.chi2_mean_expected:.2f} ± {self.chi2_mean_std:.2f})")
        where_chi2 = image_region_name(float(qk[0]), float(qk[1]), self.image_size)
        kind = "over most of the image" if self.fraction_flagged >= 0.5 else f"mostly in the {where_chi2}"
        return (f"differ: the difference is larger than the two covariances predict, {kind} ({size}; "
                f"{self.fraction_flagged:.0%} of the points above the 99 % quantile, largest χ² {self.chi2[k]:.3g} at "
                f"({qk[0]:.0f}, {qk[1]:.0f}) in the {where_chi2}; p local {self.p_local:.2g}, global "
                f"{self.p_global:.2g}): model error, a camera that changed, or σ reported too small"
                + (f"; across lens models ({self.models}) this includes what one model cannot represent of the other"
                   if self.models != self.model else ""))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary and per-point values (px, px², degrees)."""
        return {
            "camera": self.camera, "model": self.model, "model_b": self.model_b or self.model,
            "image_size": list(self.image_size),
            "grid": list(self.grid), "distance_m": self.distance_m, "fit_rotation": self.fit_rotation,
            "verdict": self.verdict, "message": self.message, "where": self.where,
            "num_points": self.num_points, "num_skipped": self.num_skipped,
            "rms_px": self.rms_px, "max_px": self.max_px, "sigma_rms_px": self.sigma_rms_px,
            "chi2_mean": self.chi2_mean, "chi2_mean_expected": self.chi2_mean_expected,
            "chi2_mean_std": self.chi2_mean_std, "chi2_max": float(np.max(self.chi2)),
            "fraction_flagged": self.fraction_flagged, "chi2_99_2dof": CHI2_99_2DOF,
            "p_local": self.p_local, "p_global": self.p_global, "alpha": ALPHA,
            "rotation_deg": self.rotation_deg, "R_b_a": self.R_b_a.tolist(),
            "points": {"pixels": self.pixels.tolist(), "grid_index": self.grid_index.tolist(),
                       "diff_px": self.diff_px.tolist(), "covariance_px2": self.covariance_px2.tolist(),
                       "chi2": self.chi2.tolist()},
        }


# ------------------------------------------------------------------------------------------ entry points


def compare_cameras(a: Any, b: Any, *, grid: tuple[int, int] = DEFAULT_GRID, distance_m: float | None = None,
                    fit_rotation: bool = True, region: tuple[float, float, float, float] | None = None,
                    camera: str | None = None) -> Comparison:
    """Compare two calibrations of one camera over a grid of pixels (see the module docstring).

    Args:
        a, b: each a :class:`~jcalib.io.result.CameraResult` with a covariance, or a pair ``(model,
            covariance)`` of a :mod:`jcalib.geometry.cameras` model and its ``(p, p)`` intrinsics
            covariance (order ``model.param_names``; None: the model is known exactly, e.g. a ground
            truth). The same image size; at least one covariance. The lens models may differ (e.g. an
            opencv5 and a fisheye calibration of one lens): the difference then includes what one model
            cannot represent of the other, which no σ predicts.
        grid: ``(nx, ny)`` grid points across the image, edges and corners included.
        distance_m: range of the compared points, m (None: at infinity). Recorded only: with a
            rotation-only fit of central models the comparison is the same at every range.
        fit_rotation: fit the rotation between the two camera frames (default; a rotation of the frame is
            not a lens difference). False compares the rays in one frame.
        region: ``(u_min, v_min, u_max, v_max)``, px: compare (and fit) only the grid points inside; None:
            the whole image.
        camera: a name for messages and tables.

    Returns:
        :class:`Comparison`.

    Raises:
        BadInputError: different image sizes (naming both), no covariance, a bad grid,
            distance or region, or fewer than 4 grid points where both models are valid.
    """
    import jax.numpy as jnp

    ca, cb = _camera(a, "A"), _camera(b, "B")
    _check_pair(ca, cb)
    nx, ny = _check_grid(grid)
    if distance_m is not None and not (isinstance(distance_m, (int, float)) and math.isfinite(distance_m)
                                       and distance_m > 0):
        raise BadInputError(f"compare: distance_m must be a positive number of metres or None; got {distance_m!r}")
    box = _check_region(region)
    width, height = ca.image_size
    u, v = np.meshgrid(np.linspace(0.0, width - 1.0, nx), np.linspace(0.0, height - 1.0, ny))
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny))
    pixels = np.stack([u.ravel(), v.ravel()], -1)
    use = np.ones(len(pixels), bool)
    if box is not None:
        use = ((pixels[:, 0] >= box[0]) & (pixels[:, 0] <= box[2]) & (pixels[:, 1] >= box[1])
               & (pixels[:, 1] <= box[3]))
    fn = _difference_jacobian(ca.cls, cb.cls, ca.image_size, ca.skew, cb.skew, bool(fit_rotation))
    (Ja, Jb), (d, valid, R) = fn(jnp.asarray(ca.params), jnp.asarray(cb.params), jnp.asarray(pixels),
                                            jnp.asarray(use))
    valid = np.asarray(valid)
    if np.count_nonzero(valid) < 4:
        raise BadInputError(
            f"compare: only {np.count_nonzero(valid)} of {len(pixels)} grid points project in both cameras"
            + ("" if box is None else " inside the region") + "; need at least 4")
    d = np.asarray(d)[valid]
    Ja, Jb = np.asarray(Ja)[valid], np.asarray(Jb)[valid]
    Ca = np.zeros((len(ca.params),) * 2) if ca.covariance is None else ca.covariance
    Cb = np.zeros((len(cb.params),) * 2) if cb.covariance is None else cb.covariance
    cov = np.einsum("nip,pq,njq->nij", Ja, Ca, Ja) + np.einsum("nip,pq,njq->nij", Jb, Cb, Jb)
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    floored = cov + SIGMA_FLOOR_PX ** 2 * np.eye(2)
    L = np.linalg.cholesky(floored)
    white = np.linalg.solve(L, d[:, :, None])[..., 0]  # L⁻¹ d, (m, 2)
    chi2 = np.sum(white ** 2, axis=-1)
    m = len(chi2)
    # Null distribution of Σ χ²: eigenvalues of the whitened difference covariance, from the square roots of
    # the parameter covariances (Σ χ² = |K z|², z ~ N(0, I) when the covariances are right).
    blocks = []
    for J, C in ((Ja, Ca), (Jb, Cb)):
        lam, V = np.linalg.eigh(0.5 * (C + C.T))
        S = V * np.sqrt(np.maximum(lam, 0.0))
        blocks.append(np.linalg.solve(L, J @ S))  # (m, 2, p)
    K = np.concatenate(blocks, axis=-1).reshape(2 * m, -1)
    mu = np.linalg.eigvalsh(K.T @ K)
    mu = np.maximum(mu, 0.0)
    p_local = float(min(1.0, m * math.exp(-0.5 * float(np.max(chi2)))))
    p_global = quadratic_form_sf(float(np.sum(chi2)), mu)
    lam_max = np.linalg.eigvalsh(cov)[:, -1]
    R = np.asarray(R)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    angle = float(np.degrees(math.atan2(0.5 * np.linalg.norm(axis), 0.5 * (np.trace(R) - 1.0))))
    grid_index = np.stack([ix.ravel(), iy.ravel()], -1)[valid]
    return Comparison(
        camera=camera, model=ca.name, model_b=cb.name, image_size=ca.image_size, grid=(nx, ny), pixels=pixels[valid],
        grid_index=grid_index, diff_px=d, covariance_px2=cov, sigma_px=np.sqrt(np.maximum(lam_max, 0.0)),
        chi2=chi2, R_b_a=R, rotation_deg=angle, num_skipped=int(len(pixels) - m),
        distance_m=None if distance_m is None else float(distance_m), fit_rotation=bool(fit_rotation),
        chi2_mean_expected=float(np.sum(mu) / m), chi2_mean_std=float(math.sqrt(2.0 * np.sum(mu ** 2)) / m),
        p_local=p_local, p_global=p_global)


def compare_results(a: Any, b: Any, *, cameras: list[str] | None = None, **kwargs: Any) -> dict[str, Comparison]:
    """Compare the cameras two result files have in common (:func:`compare_cameras` for each).

    Args:
        a, b: result files (paths or :class:`~jcalib.io.result.ResultFile`).
        cameras: camera names to compare (default: every camera in both files whose intrinsics were
            estimated in at least one of them).
        **kwargs: ``grid``, ``distance_m``, ``fit_rotation``, ``region`` of :func:`compare_cameras`.

    Returns:
        camera name -> :class:`Comparison`, in A's order.

    Raises:
        BadInputError: a named camera missing from a file, no camera in common, or what
            :func:`compare_cameras` raises.
    """
    fa = a if isinstance(a, ResultFile) else load_result(a)
    fb = b if isinstance(b, ResultFile) else load_result(b)
    if cameras is None:
        names = [n for n in fa.cameras if n in fb.cameras and _estimated(fa.cameras[n], fb.cameras[n])]
        if not names:
            common = [n for n in fa.cameras if n in fb.cameras]
            raise BadInputError(
                "compare: the two results have no camera in common" if not common else
                f"compare: no camera whose intrinsics were estimated in common (cameras {', '.join(common)} have "
                "no covariance or all intrinsics fixed)")
    else:
        names = list(cameras)
        for n in names:
            fa.camera(n)
            fb.camera(n)
    return {n: compare_cameras(fa.cameras[n], fb.cameras[n], camera=n, **kwargs) for n in names}


def _estimated(a: CameraResult, b: CameraResult) -> bool:
    return any(c.covariance is not None and np.any(np.diag(c.covariance) > 0.0) for c in (a, b)) and (
        a.covariance is not None and b.covariance is not None)


@dataclass(frozen=True, eq=False)
class SplitHalfComparison:
    """Split-half cross-validation: the two halves' calibrations and their comparison per camera.

    Attributes:
        halves: the split, its observations and the two results
            (:class:`~jcalib.problems.crossval.SplitHalves`).
        comparisons: camera name -> :class:`Comparison` (A: the first half, B: the second).
        skipped: camera name -> why it was not compared (e.g. all its intrinsics held fixed).
    """

    halves: SplitHalves
    comparisons: dict[str, Comparison]
    skipped: dict[str, str] = field(default_factory=dict)

    @property
    def results(self) -> tuple[Any, Any]:
        """The two halves' results (:class:`~jcalib.problems.calibrate.Result`)."""
        return self.halves.results

    @property
    def verdict(self) -> str:
        """``"differ"`` when any camera's comparison differs, else ``"consistent"``."""
        return "differ" if any(c.verdict == "differ" for c in self.comparisons.values()) else "consistent"


def split_half_comparison(cell: Any, observations: Any, options: Any = None, *, split: str = "interleaved",
                          seed: int = 0, min_views: int | None = None, cameras: list[str] | None = None,
                          **kwargs: Any) -> SplitHalfComparison:
    """Calibrate the two halves of the stations separately and compare every camera's projection.

    The halves are disjoint sets of views with independent noise, so a camera's two calibrations should
    differ by what their covariances predict. "differ" means the model does not describe the lens (the two
    halves see its error in different places), the camera changed during the capture, or the σ are too small.

    Args:
        cell: the cell spec (path, dict or :class:`~jcalib.io.cell.CellSpec`).
        observations: path, dict or :class:`~jcalib.io.observations.Observations`.
        options: calibration options of both halves (:class:`~jcalib.problems.CalibrationOptions` or a dict).
        split: ``"interleaved"`` (even / odd stations) or ``"random"`` (``seed``).
        min_views: fewest views of each camera per half (default
            :data:`jcalib.problems.crossval.MIN_VIEWS_PER_HALF`).
        cameras: the cameras to compare (default: every camera whose intrinsics were estimated).
        **kwargs: ``grid``, ``distance_m``, ``fit_rotation``, ``region`` of :func:`compare_cameras`.

    Raises:
        BadInputError: a half with too few views of a camera (naming it and the counts), malformed input,
            an unknown camera.
        NotObservableError: a half cannot determine the unknowns.
    """
    from jcalib.problems.crossval import MIN_VIEWS_PER_HALF, calibrate_halves

    halves = calibrate_halves(cell, observations, options, split=split, seed=seed,
                              min_views=MIN_VIEWS_PER_HALF if min_views is None else min_views)
    fa, fb = (r.file for r in halves.results)
    names = list(fa.cameras) if cameras is None else list(cameras)
    comparisons, skipped = {}, {}
    for n in names:
        ca, cb = fa.camera(n), fb.camera(n)
        if not _estimated(ca, cb):
            skipped[n] = "its intrinsics were not estimated (held fixed)"
            continue
        comparisons[n] = compare_cameras(ca, cb, camera=n, **kwargs)
    if not comparisons:
        raise BadInputError(f"cross-validation: no camera to compare: {'; '.join(f'{n}: {w}' for n, w in skipped.items())}")
    return SplitHalfComparison(halves, comparisons, skipped)


# ------------------------------------------------------------------------------------------ output


def comparison_table(comparisons: dict[str, Comparison], title: str = "Projection difference (B − A)"):
    """A rich table, one row per camera: size of the difference, its prediction, the χ² statistics, the verdict."""
    from rich.table import Table

    table = Table(title=title)
    for col in ("camera", "points", "RMS (px)", "max (px)", "where", "σ RMS (px)", "mean χ²", "> 99 %",
                "p local", "p global", "rotation (°)", "verdict"):
        table.add_column(col, justify="left" if col in ("camera", "where", "verdict") else "right")
    for name, c in comparisons.items():
        table.add_row(
            name if c.models == c.model else f"{name} ({c.models})", f"{c.num_points}" + (f" (+{c.num_skipped} skipped)" if c.num_skipped else ""),
            f"{c.rms_px:.3g}", f"{c.max_px:.3g}", c.where, f"{c.sigma_rms_px:.3g}",
            f"{c.chi2_mean:.2f} ({c.chi2_mean_expected:.2f} ± {c.chi2_mean_std:.2f})", f"{c.fraction_flagged:.0%}",
            f"{c.p_local:.2g}", f"{c.p_global:.2g}", f"{c.rotation_deg:.4f}",
            ("[green]" if c.verdict == "consistent" else "[bold red]") + c.verdict + "[/]")
    return table


def print_comparisons(comparisons: dict[str, Comparison], console: Any = None, title: str | None = None) -> None:
    """Print :func:`comparison_table` and each camera's one-line message."""
    from rich.console import Console

    console = console or Console()
    console.print(comparison_table(comparisons, **({"title": title} if title else {})))
    for name, c in comparisons.items():
        console.print(f"{name}: {c.message}", highlight=False, markup=False)
    if any(c.distance_m is not None for c in comparisons.values()):
        console.print("note: central lens models and a rotation-only fit: the difference is the same at every "
                      "distance as at infinity", highlight=False, markup=False)


def write_comparisons(path: Any, comparisons: dict[str, Comparison], extra: dict[str, Any] | None = None):
    """Write ``{"schema": "jcalib.compare/1", "cameras": {name: Comparison.to_dict()}, **extra}`` atomically."""
    from jcalib.io.atomic import write_json_atomic

    doc = {"schema": "jcalib.compare/1", **(extra or {}),
           "cameras": {n: c.to_dict() for n, c in comparisons.items()}}
    return write_json_atomic(path, doc)
