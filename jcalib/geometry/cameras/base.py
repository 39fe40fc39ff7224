"""The camera-model interface shared by every lens model, and the checks their constructors use.

A camera model maps points in the camera frame ``cam`` (metres, x right, y down, z forward, as in
OpenCV) to pixels (OpenCV convention: the centre of the top-left pixel is (0, 0)) and back to unit
bearing vectors. Every model is an :class:`equinox.Module` whose array fields are the intrinsic
unknowns and whose configuration (image size, skew on/off) is static, so a model is a pytree that
``jit``, ``vmap`` and ``grad`` see through. The solver optimises the flat vector
:attr:`AbstractCameraModel.params` and rebuilds models with :meth:`AbstractCameraModel.with_params`.
"""

from __future__ import annotations

import abc
import functools
import numbers

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError

#: Points closer to the camera's image plane than this (metres, along z for perspective models,
#: distance from the centre for the fisheye) are invalid: their projection is not defined.
MIN_DEPTH_M = 1e-9

#: Iterations of the bracketed 1-D Newton solve of ``unproject`` (radius or angle). Each step is
#: a Newton step, or a bisection of the bracket where Newton would leave it, so it converges
#: whatever the start; Newton's quadratic convergence usually reaches machine precision in < 10.
UNPROJECT_ITERATIONS = 40

#: Newton iterations refining the 1-D (radial) solution in 2-D (tangential, prism terms).
UNPROJECT_REFINE_ITERATIONS = 8

#: An ``unproject`` solve has converged when the distortion residual (normalised image
#: coordinates) is below this, relative to ``max(1, |target|)``. 1e-10 normalised is ~1e-7 px at
#: f = 1000 px before the final Newton step; the returned ray is one (quadratically convergent)
#: step better than that.
UNPROJECT_TOLERANCE = 1e-10

#: Samples used to locate the edge of the monotonic range of a distortion polynomial.
VALID_RANGE_SAMPLES = 512
#: Levels of sampling that locate the edge: resolution ``range / VALID_RANGE_SAMPLES**levels``
#: (3 levels over 0..90°: ~1e-8 rad).
VALID_RANGE_LEVELS = 3


class AbstractCameraModel(eqx.Module):
    """A camera lens model: project points in the camera frame to pixels and back.

    Subclasses are final; each is one lens model with OpenCV's meaning of its parameters.

    Attributes:
        name: class-level model name, as in the cell spec (``pinhole``, ``opencv4``, ``opencv5``,
            ``opencv8``, ``opencv12``, ``opencv14``, ``fisheye``).
        mrcal_name: mrcal's name of the same model (``LENSMODEL_OPENCV5``…) or None where mrcal has
            none. mrcal orders intrinsics as OpenCV does, so :attr:`params` (without skew) is also
            mrcal's intrinsics vector.
        image_size: ``(width, height)`` in pixels, static.
    """

    name: eqx.AbstractClassVar[str]
    mrcal_name: eqx.AbstractClassVar[str | None]
    image_size: eqx.AbstractVar[tuple[int, int]]

    # ---------------------------------------------------------------- parameters

    @property
    @abc.abstractmethod
    def param_names(self) -> tuple[str, ...]:
        """Names of the entries of :attr:`params`, in order (OpenCV naming)."""

    @property
    @abc.abstractmethod
    def params(self) -> jax.Array:
        """All intrinsics as one flat float64 vector, shape ``(len(param_names),)``.

        Order: ``fx, fy, cx, cy`` (pixels), then ``skew`` (pixels, K[0][1]) or ``alpha`` (fisheye,
        K[0][1] / fx) when the model has one, then the distortion coefficients in OpenCV's order.
        """

    @property
    @abc.abstractmethod
    def has_skew(self) -> bool:
        """Whether the model has a skew parameter (``skew`` or, for the fisheye, ``alpha``)."""

    @classmethod
    @abc.abstractmethod
    def from_params(
        cls, image_size: tuple[int, int], params: jax.Array, skew: bool = False
    ) -> AbstractCameraModel:
        """Build a model from its flat parameter vector (the inverse of :attr:`params`).

        Jit-friendly: only the shape of ``params`` is checked (values may be traced).

        Args:
            image_size: ``(width, height)`` in pixels.
            params: shape ``(n,)``, in the order of :attr:`param_names`.
            skew: whether ``params`` holds the skew entry after ``cx, cy``.
        """

    def with_params(self, params: jax.Array) -> AbstractCameraModel:
        """The same model type, image size and configuration with new parameter values.

        Args:
            params: shape ``(len(self.param_names),)``, float64.
        """
        if not isinstance(params, jax.core.Tracer):  # on the host: no JAX dispatch, nothing to compile
            return self.with_params_many(np.asarray(params, dtype=np.float64)[None])[0]
        return type(self).from_params(self.image_size, params, skew=self.has_skew)

    def with_params_many(self, params) -> list[AbstractCameraModel]:
        """``[self.with_params(p) for p in params]`` for a stack of parameter vectors.

        The results of batched calibrations: the parameters are sorted into the models' fields on
        the host (NumPy), and each model is assembled from its fields directly, about a third of
        the cost of :meth:`with_params` per model and no compilation for a new batch size.

        Args:
            params: shape ``(B, len(self.param_names))``, float64.
        """
        params = np.asarray(params, dtype=np.float64)
        n = len(self.param_names)
        if params.ndim != 2 or params.shape[1] != n:
            raise BadInputError(
                f"params for model {self.name!r} must have shape (B, {n}) "
                f"({', '.join(self.param_names)}); got shape {params.shape}"
            )
        layout = _param_fields(type(self), self.image_size, self.has_skew, n)
        if layout is None:
            return [self.with_params(p) for p in params]
        treedef, fields = layout
        columns = [params[:, idx] for idx in fields]  # (B, *field shape) per field
        # NumPy fields: a model on the host dispatches and compiles nothing until it is traced
        return [jax.tree.unflatten(treedef, [np.array(c[i]) for c in columns]) for i in range(params.shape[0])]

    @property
    @abc.abstractmethod
    def K(self) -> jax.Array:
        """The 3x3 camera matrix (pixels), OpenCV layout; ``K[0][1]`` holds the skew."""

    @abc.abstractmethod
    def to_opencv(self) -> tuple[np.ndarray, np.ndarray]:
        """``(K, dist)`` as float64 NumPy arrays that ``cv2`` takes unchanged.

        ``K`` is ``(3, 3)``; ``dist`` is ``(n,)`` in OpenCV's order (``(0,)`` for the pinhole,
        the 4 ``D`` coefficients of ``cv2.fisheye`` for the fisheye). Not traceable (returns NumPy).
        """

    # ---------------------------------------------------------------- projection

    @abc.abstractmethod
    def project_valid(self, p_cam: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Project points to pixels and say which projections are valid.

        Args:
            p_cam: points in the camera frame, shape ``(..., 3)``, metres.

        Returns:
            ``(pixels, valid)``: pixels shape ``(..., 2)`` (always finite, also where invalid),
            ``valid`` shape ``(...)`` bool, False where the point is behind the camera or outside
            the region where the model is one-to-one (see the model's docstring).
        """

    def project(self, p_cam: jax.Array) -> jax.Array:
        """Project points in the camera frame ``(..., 3)`` (metres) to pixels ``(..., 2)``.

        Always finite, with finite derivatives, also for invalid points (see
        :meth:`project_valid`). Under ``jit`` the validity test is dead code and costs nothing.
        """
        return self.project_valid(p_cam)[0]

    @abc.abstractmethod
    def unproject_valid(self, pixels: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Bearing vectors of pixels, and whether the inversion is valid.

        Args:
            pixels: shape ``(..., 2)``, OpenCV pixel convention.

        Returns:
            ``(rays, valid)``: unit vectors in the camera frame, shape ``(..., 3)`` (always finite),
            and ``valid`` shape ``(...)`` bool, False where the iterative inversion did not converge
            or landed outside the model's valid region (no point projects to that pixel).
        """

    def unproject(self, pixels: jax.Array) -> jax.Array:
        """Unit bearing vectors ``(..., 3)`` in the camera frame of pixels ``(..., 2)``."""
        return self.unproject_valid(pixels)[0]


# -------------------------------------------------------------------- helpers for the models


def as_float64(x, what: str, last: int | None) -> jax.Array:
    """Convert an array-like to float64 and check its trailing dimension (static shapes only)."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating) and not jnp.issubdtype(
        x.dtype, jnp.integer
    ):
        raise BadInputError(f"{what} must be a real array, got dtype {x.dtype}")
    x = x.astype(jnp.float64)
    if last is not None and (x.ndim == 0 or x.shape[-1] != last):
        raise BadInputError(
            f"{what} must have shape (..., {last}), got shape {x.shape}"
        )
    return x


def check_image_size(image_size) -> tuple[int, int]:
    """Validate ``(width, height)``: two positive Python/NumPy ints. Returns a tuple of ints."""
    try:
        items = tuple(image_size)
    except TypeError:
        items = None
    if (
        items is None
        or len(items) != 2
        or any(
            isinstance(v, bool) or not isinstance(v, numbers.Integral) for v in items
        )
        or any(int(v) <= 0 for v in items)
    ):
        raise BadInputError(
            f"image_size must be (width, height), two positive integers in pixels; got {image_size!r}"
        )
    return (int(items[0]), int(items[1]))


@functools.lru_cache(maxsize=None)
def _param_fields(cls: type, image_size: tuple[int, int], skew: bool, n: int):
    """``(treedef, [index array per field])``: where :meth:`~AbstractCameraModel.from_params` puts
    each parameter, read off a model built from the parameter indices themselves; None for a model
    that computes a field from several parameters (then each model needs ``with_params``)."""
    probe = cls.from_params(image_size, np.arange(n, dtype=np.float64), skew=skew)
    leaves, treedef = jax.tree.flatten(probe)
    fields = [np.asarray(leaf).astype(np.int64) for leaf in leaves]
    used = np.sort(np.concatenate([f.ravel() for f in fields]))
    placed = all(np.array_equal(np.asarray(leaf), f) for leaf, f in zip(leaves, fields))
    return (treedef, fields) if placed and np.array_equal(used, np.arange(n)) else None


def check_param_vector(params, n: int, model: str, names: tuple[str, ...]) -> jax.Array | np.ndarray:
    """Convert a parameter vector to float64 and check its shape is ``(n,)`` (static check).

    Values that are not JAX arrays come back as a NumPy array: a model built from them slices it
    on the host, one device transfer per field instead of a dispatched slice each.
    """
    params = params if isinstance(params, jax.Array) else np.asarray(params)
    if params.shape != (n,):
        raise BadInputError(
            f"params for model {model!r} must have shape ({n},) ({', '.join(names)}); "
            f"got shape {params.shape}"
        )
    return params.astype(np.float64)


def check_vector(value, shape: tuple[int, ...], what: str) -> jax.Array:
    """A float64 JAX array of the given static shape (BadInputError naming ``what`` otherwise)."""
    arr = value if isinstance(value, jax.Array) else np.asarray(value)
    if arr.shape != shape:
        raise BadInputError(f"{what} must have shape {shape}, got shape {arr.shape}")
    if not (
        jnp.issubdtype(arr.dtype, jnp.floating)
        or jnp.issubdtype(arr.dtype, jnp.integer)
    ):
        raise BadInputError(f"{what} must be real numbers, got dtype {arr.dtype}")
    return jnp.asarray(arr, dtype=jnp.float64)


def is_concrete(x) -> bool:
    """True when ``x`` holds values (not a JAX tracer), so value checks can run."""
    return not isinstance(x, jax.core.Tracer)


def edge_of_valid_range(
    margin, upper: float, num: int = VALID_RANGE_SAMPLES
) -> jax.Array:
    """Largest ``R`` in ``(0, upper]`` with ``h(t) > tau(R)`` for all ``t <= R`` (``inf`` if all).

    ``margin(t)`` returns ``(h(t), tau(t))``, with ``h(0) > tau(0) = 0`` and ``tau`` increasing.
    ``h`` is sampled at ``num`` equally spaced points of ``(0, upper]`` (its running minimum stands
    for the minimum over ``[0, R]``); the sample interval where the condition first fails is
    sampled again at ``num`` points, ``VALID_RANGE_LEVELS`` times (resolution
    ``upper / num**VALID_RANGE_LEVELS``). A dip of ``h`` narrower than one sample spacing can be
    missed. Not differentiated (``stop_gradient``): the result is a region boundary.

    Args:
        margin: elementwise function of a float64 array returning two arrays of its shape.
        upper: end of the search interval.
    """
    fraction = jnp.arange(1, num + 1, dtype=jnp.float64) / num

    def level(i, state):
        lo, width, h_before, any_bad = state
        t = lo + width * fraction
        h, tau = margin(t)
        h_min = jnp.minimum(jax.lax.cummin(h), h_before)
        bad = h_min <= tau
        first = jnp.argmax(bad)
        found = jnp.any(bad)
        previous = jnp.maximum(first - 1, 0)
        # Zoom into the sample interval (t[first - 1], t[first]] (if nothing failed, stay put).
        zoom = found & (first > 0)
        return (
            jnp.where(zoom, t[previous], lo),
            jnp.where(found, width / num, width),
            jnp.where(zoom, h_min[previous], h_before),
            jnp.where(i == 0, found, any_bad),
        )

    init = (
        jnp.zeros(()),
        jnp.asarray(float(upper)),
        jnp.asarray(jnp.inf),
        jnp.asarray(False),
    )
    lo, width, _, any_bad = jax.lax.fori_loop(0, VALID_RANGE_LEVELS, level, init)
    return jax.lax.stop_gradient(jnp.where(any_bad, lo + width, jnp.inf))


def bracketed_newton(fn, target: jax.Array, upper: jax.Array) -> jax.Array:
    """Solve ``fn(t) = target`` for ``t`` in ``[0, upper]``, ``fn`` increasing with ``fn(0) = 0``.

    Newton steps that would leave the current bracket are replaced by bisection, so the
    iteration cannot diverge. Where ``target > fn(upper)`` the result tends to ``upper`` (check the
    residual). Runs ``UNPROJECT_ITERATIONS`` steps, not differentiated (``stop_gradient``).

    Args:
        fn: elementwise increasing function (closed over gradient-stopped parameters).
        target: shape ``(...)``, non-negative.
        upper: 0-d, end of the interval where ``fn`` is increasing (finite).
    """
    target = jax.lax.stop_gradient(target)
    upper = jax.lax.stop_gradient(upper)

    def body(_, state):
        t, lo, hi = state
        value, slope = jax.jvp(fn, (t,), (jnp.ones_like(t),))
        below = value < target
        lo = jnp.where(below, t, lo)
        hi = jnp.where(below, hi, t)
        t_newton = t - safe_divide(value - target, slope)
        inside = (t_newton > lo) & (t_newton < hi)
        return jnp.where(inside, t_newton, 0.5 * (lo + hi)), lo, hi

    lo = jnp.zeros_like(target)
    hi = jnp.broadcast_to(upper, target.shape)
    t0 = jnp.where(target < hi, target, 0.5 * hi)
    t, _, _ = jax.lax.fori_loop(0, UNPROJECT_ITERATIONS, body, (t0, lo, hi))
    return jax.lax.stop_gradient(t)


def safe_divide(num: jax.Array, den: jax.Array, tiny: float = 1e-12) -> jax.Array:
    """``num / den`` with ``|den|`` floored at ``tiny`` (sign kept), so values and gradients stay finite."""
    den_safe = jnp.where(jnp.abs(den) > tiny, den, jnp.where(den < 0.0, -tiny, tiny))
    return num / den_safe


def concatenate_params(parts) -> jax.Array | np.ndarray:
    """One flat parameter vector from a model's fields: NumPy when every field is (a host model),
    JAX otherwise (a traced or device model)."""
    if all(isinstance(p, np.ndarray) for p in parts):
        return np.concatenate([np.asarray(p, np.float64).reshape(-1) for p in parts])
    return jnp.concatenate([jnp.reshape(p, (-1,)) for p in parts])
