"""Multi-view triangulation of points seen by N >= 2 calibrated cameras, with honest covariance.

Two steps, as in Hartley & Zisserman (ch. 12):

1. **DLT** on bearing vectors: each pixel is turned into a unit ray ``b_i`` in its camera frame by
   the camera model's ``unproject`` (distortion removed exactly, any OpenCV model or the fisheye),
   and ``b_i x (R_i X + t_i w) = 0`` (two independent rows per view) is solved for the homogeneous
   point ``(X, w)`` by SVD. The 3-D frame is normalised first (origin at the mean camera centre,
   mean centre distance 1), so the SVD is well conditioned at any scale.
2. **Gauss-Newton** on the whitened reprojection error, ``sum_i |project_i(R_i X + t_i) - u_i|^2 /
   sigma_i^2``, a fixed number of iterations. One ``jit`` per camera layout and number of views; many
   points are solved at once (``vmap``), each over the views that see it (the others get weight 0,
   so points seen by different subsets of views share one compilation).

**Covariance.** The point ``X`` is the minimiser of the reprojection error given the pixels ``u``,
the intrinsics ``theta`` and the camera poses ``delta`` (right-perturbation tangents). By the
implicit-function theorem (JAX Jacobians of the residual at the solution, ``J = dr/dX``)::

    dX = -(J^T J)^-1 J^T (du + dr/dtheta dtheta + dr/ddelta ddelta)

so ``Cov(X) = (J^T J)^-1`` (pixel noise, whitened) ``+ G Sigma_cam G^T`` with
``G = -(J^T J)^-1 J^T [dr/dtheta, dr/ddelta]`` and ``Sigma_cam`` the given intrinsics and pose
covariances. Views that share one camera model object share its intrinsic errors; a joint pose
covariance ``(6N, 6N)`` carries correlations between views (a hand-eye transform common to all views
of a robot-held camera: :func:`jcalib.init.pose_chains.compose_pose_chains` builds it; that module
also moves a triangulated point along RoboCalib's camera -> target / flange / base chain). Several
points triangulated with the same uncertain cameras are correlated: :func:`triangulate_points`
returns their joint covariance and
:meth:`TriangulatedPoints.distance` uses it. What it does not include: model error (a lens model too
simple for the lens), wrong correspondences, intrinsics/pose cross-correlations (a result file keeps
none), and second-order effects (it is a linearisation: fine while the errors are small against the
geometry).

Degeneracy: when the viewing rays are nearly parallel (largest angle between two rays below
``min_parallax_deg``) the depth of the point along the viewing ray is not determined and
:class:`jcalib.errors.NotObservableError` says so; a DLT point behind a camera (the rays meet behind
it: usually a wrong correspondence) raises it too. Frames: ``T_cam_base`` maps base points into the
camera (``p_cam = R p_base + t``); pass ``T_base_cam`` instead if that is what you have. "base" is
whatever frame the poses are given in (a camera frame, a target, the robot base).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import AbstractCameraModel
from jcalib.geometry.lie import se3_apply, se3_exp
from jcalib.geometry.se3 import adjoint, as_pose_matrices, invert, make_pose, skew

__all__ = [
    "DEFAULT_MIN_PARALLAX_DEG",
    "TriangulatedPoint",
    "TriangulatedPoints",
    "point_distance",
    "triangulate_dlt",
    "triangulate_point",
    "triangulate_points",
]

#: Smallest accepted angle (degrees) between two viewing rays. At 0.1 deg and 1 px noise with
#: f = 1000 px the depth standard deviation is already ~35x the lateral one (~1/tan(parallax)).
DEFAULT_MIN_PARALLAX_DEG = 0.1

#: Gauss-Newton iterations after the DLT (quadratic convergence from a DLT start; 5 reach float64
#: precision in practice, the tests check against an independent optimiser).
DEFAULT_ITERATIONS = 5



@dataclass(frozen=True)
class TriangulatedPoint:
    """A triangulated point with its covariance.

    Attributes:
        p_base: ``(3,)`` the point in the frame of the poses ("base"; metres, or the poses' unit).
        covariance: ``(3, 3)`` total covariance, same frame, unit^2: ``covariance_px`` +
            ``covariance_camera``.
        residuals_px: ``(N, 2)`` reprojection errors ``project - pixel`` per view, pixels (zeros
            for views that do not see the point).
        rms_px: RMS of ``residuals_px`` over the coordinates of the views that see the point.
        sigma_px: the pixel noise assumed (a float, or ``(N,)`` per view).
        p_base_dlt: ``(3,)`` the DLT point before the Gauss-Newton refinement.
        parallax_deg: largest angle between two viewing rays, degrees.
        covariance_px: ``(3, 3)`` the part from pixel noise, ``(J^T J)^-1`` (whitened ``J``).
        covariance_camera: ``(3, 3)`` the part from the given intrinsics and pose covariances
            (zeros when none were given).
        num_views: number of views that see the point.
    """

    p_base: np.ndarray
    covariance: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    sigma_px: float | np.ndarray
    p_base_dlt: np.ndarray
    parallax_deg: float
    covariance_px: np.ndarray | None = None
    covariance_camera: np.ndarray | None = None
    num_views: int = 0

    @property
    def std(self) -> np.ndarray:
        """``(3,)`` standard deviations of ``p_base`` (axes of the poses' frame)."""
        return np.sqrt(np.diag(self.covariance))


@dataclass(frozen=True)
class TriangulatedPoints:
    """Several points triangulated from the same views, with their joint covariance.

    Attributes:
        points: one :class:`TriangulatedPoint` per point (its ``covariance`` is the diagonal block).
        names: the point names (default ``"0"``, ``"1"``...).
        covariance: ``(3M, 3M)`` joint covariance of the stacked points ``(x0, y0, z0, x1, ...)``,
            unit^2: independent pixel noise per point plus the camera uncertainty they share.
    """

    points: tuple[TriangulatedPoint, ...]
    names: tuple[str, ...]
    covariance: np.ndarray

    @property
    def p_base(self) -> np.ndarray:
        """``(M, 3)`` the points."""
        return np.stack([p.p_base for p in self.points])

    def __len__(self) -> int:
        return len(self.points)

    def __getitem__(self, key: int | str) -> TriangulatedPoint:
        return self.points[self._index(key)]

    def _index(self, key: int | str) -> int:
        if isinstance(key, str):
            if key not in self.names:
                raise BadInputError(f"point: no point {key!r}; have {', '.join(self.names)}")
            return self.names.index(key)
        if not isinstance(key, (int, np.integer)) or not -len(self) <= key < len(self):
            raise BadInputError(f"point: expected a name or an index in [0, {len(self)}), got {key!r}")
        return int(key) % len(self)

    def cross_covariance(self, a: int | str, b: int | str) -> np.ndarray:
        """``(3, 3)`` ``Cov(point a, point b)`` (shared camera uncertainty)."""
        i, j = self._index(a), self._index(b)
        return self.covariance[3 * i : 3 * i + 3, 3 * j : 3 * j + 3]

    def distance(self, a: int | str, b: int | str) -> tuple[float, float]:
        """``(distance, sigma)`` between two of the points, with their correlation (unit)."""
        return point_distance(self[a], self[b], cross_covariance=self.cross_covariance(a, b))


# --------------------------------------------------------------------------------------------- input


def _cameras(cameras, n: int) -> tuple[AbstractCameraModel, ...]:
    if isinstance(cameras, AbstractCameraModel):
        return (cameras,) * n
    if not isinstance(cameras, Sequence) or len(cameras) != n:
        got = len(cameras) if isinstance(cameras, Sequence) else type(cameras).__name__
        raise BadInputError(f"cameras: expected one camera model or a sequence of {n} (one per view), got {got}")
    for i, cam in enumerate(cameras):
        if not isinstance(cam, AbstractCameraModel):
            raise BadInputError(f"cameras[{i}]: expected a jcalib camera model, got {type(cam).__name__}")
    return tuple(cameras)


def _poses(T_cam_base, T_base_cam, n: int) -> tuple[np.ndarray, np.ndarray]:
    if (T_cam_base is None) == (T_base_cam is None):
        raise BadInputError("give exactly one of T_cam_base and T_base_cam (camera poses, one per view)")
    name = "T_cam_base" if T_cam_base is not None else "T_base_cam"
    T = as_pose_matrices(T_cam_base if T_cam_base is not None else T_base_cam, name)
    if T.shape[0] != n:
        raise BadInputError(f"{name}: expected {n} poses (one per pixel), got {T.shape[0]}")
    R, t = T[:, :3, :3], T[:, :3, 3]
    if T_base_cam is not None:  # invert: R_cam_base = R^T, t_cam_base = -R^T t
        R = np.swapaxes(R, -1, -2)
        t = -np.einsum("nij,nj->ni", R, t)
    return R, t


def _pixels(pixels) -> np.ndarray:
    px = np.asarray(pixels, dtype=np.float64)
    if px.ndim != 2 or px.shape[1] != 2 or px.shape[0] < 2:
        raise BadInputError(f"pixels: expected shape (N, 2) with N >= 2 views, got {px.shape}")
    if not np.isfinite(px).all():
        raise BadInputError("pixels: contain NaN/inf; expected finite pixel coordinates")
    return px


def _pixel_sets(pixels, names) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """``(M, N, 2)`` pixels with NaN rows for unseen -> (pixels with zeros there, mask, names)."""
    try:
        px = np.asarray(pixels, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"pixels: expected an (M, N, 2) array of numbers, got {type(pixels).__name__}") from None
    if px.ndim != 3 or px.shape[2] != 2 or px.shape[0] < 1 or px.shape[1] < 2:
        raise BadInputError(f"pixels: expected shape (M, N, 2) (M points, N >= 2 views), got {px.shape}")
    m = px.shape[0]
    names = tuple(str(i) for i in range(m)) if names is None else tuple(str(s) for s in names)
    if len(names) != m or len(set(names)) != m:
        raise BadInputError(f"names: expected {m} different point names, got {list(names)}")
    nan = np.isnan(px)
    if (nan[..., 0] != nan[..., 1]).any() or np.isinf(px).any():
        k = int(np.argwhere((nan[..., 0] != nan[..., 1]) | np.isinf(px).any(-1))[0][0])
        raise BadInputError(
            f"pixels: point {names[k]!r} has a half-NaN or infinite pixel; expected finite (u, v), or NaN "
            f"in both coordinates for a view that does not see the point"
        )
    mask = ~nan[..., 0]
    for k in range(m):
        if mask[k].sum() < 2:
            raise BadInputError(
                f"pixels: point {names[k]!r} is seen in {int(mask[k].sum())} view(s); triangulation needs >= 2"
            )
    return np.where(nan, 0.0, px), mask, names


def _sigma(sigma_px, n: int) -> np.ndarray:
    s = np.asarray(sigma_px, dtype=np.float64)
    if s.ndim == 0:
        s = np.full(n, float(s))
    if s.shape != (n,) or not (np.isfinite(s).all() and (s > 0).all()):
        raise BadInputError(
            f"sigma_px: expected a positive pixel noise level (or {n} of them, one per view), got {sigma_px!r}"
        )
    return s


@dataclass(frozen=True)
class _Layout:
    """Static description of the views: which unique camera each view uses (hashable)."""

    groups: tuple[tuple[int, ...], ...]  # view indices of each unique camera
    order: tuple[int, ...]  # inverse permutation of concat(groups)
    num_views: int


def _layout(cams: tuple[AbstractCameraModel, ...]) -> tuple[tuple[AbstractCameraModel, ...], _Layout]:
    unique: list[AbstractCameraModel] = []
    members: list[list[int]] = []
    for i, cam in enumerate(cams):
        for u, c in enumerate(unique):
            if c is cam:
                members[u].append(i)
                break
        else:
            unique.append(cam)
            members.append([i])
    flat = [i for g in members for i in g]
    order = tuple(int(k) for k in np.argsort(flat))
    return tuple(unique), _Layout(tuple(tuple(g) for g in members), order, len(cams))


def _intrinsics_covariance(cov, single: bool, unique, layout: _Layout) -> list[np.ndarray]:
    """One ``(p_u, p_u)`` per unique camera (zeros where none is given)."""
    out = [np.zeros((len(c.param_names),) * 2) for c in unique]
    if cov is None:
        return out

    def check(c, u, where):
        p = len(unique[u].param_names)
        try:
            c = np.asarray(c, dtype=np.float64)
        except (TypeError, ValueError):
            raise BadInputError(f"{where}: expected a ({p}, {p}) covariance, got {type(c).__name__}") from None
        if c.shape != (p, p) or not np.isfinite(c).all() or np.abs(c - c.T).max(initial=0.0) > 1e-9 * max(
            np.abs(c).max(initial=0.0), 1e-300
        ):
            raise BadInputError(
                f"{where}: expected a finite symmetric ({p}, {p}) covariance of the intrinsics "
                f"{list(unique[u].param_names)}, got shape {c.shape}"
            )
        return c

    if single or (isinstance(cov, np.ndarray) and cov.ndim == 2):
        if len(unique) != 1:
            raise BadInputError(
                f"intrinsics_covariance: one matrix given for {len(unique)} different camera models; give a "
                f"sequence with one entry (or None) per view"
            )
        out[0] = check(cov, 0, "intrinsics_covariance")
        return out
    if not isinstance(cov, Sequence) or len(cov) != layout.num_views:
        raise BadInputError(
            f"intrinsics_covariance: expected None, one (p, p) matrix (one camera model) or a sequence of "
            f"{layout.num_views} entries (one per view, None for exact intrinsics)"
        )
    for u, group in enumerate(layout.groups):
        given = [(i, cov[i]) for i in group if cov[i] is not None]
        if not given:
            continue
        first = check(given[0][1], u, f"intrinsics_covariance[{given[0][0]}]")
        for i, c in given[1:]:
            if not np.array_equal(check(c, u, f"intrinsics_covariance[{i}]"), first):
                raise BadInputError(
                    f"intrinsics_covariance[{i}]: views {given[0][0]} and {i} share one camera model but "
                    f"give different intrinsics covariances"
                )
        out[u] = first
    return out


def _pose_covariance(cov, n: int, name: str) -> np.ndarray:
    if cov is None:
        return np.zeros((6 * n, 6 * n))
    c = np.asarray(cov, dtype=np.float64)
    if c.shape == (n, 6, 6):
        full = np.zeros((6 * n, 6 * n))
        for i in range(n):
            full[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = c[i]
    elif c.shape == (6, 6) and n == 1 or c.shape == (6 * n, 6 * n):
        full = c
    else:
        raise BadInputError(
            f"pose_covariance: expected ({n}, 6, 6) per view or ({6 * n}, {6 * n}) joint, over the right-"
            f"perturbation tangents (rx, ry, rz, tx, ty, tz) of {name} (rad, m), got shape {c.shape}"
        )
    if not np.isfinite(full).all() or np.abs(full - full.T).max(initial=0.0) > 1e-9 * max(np.abs(full).max(), 1e-300):
        raise BadInputError("pose_covariance: expected finite, symmetric covariances (rad^2, m^2)")
    return full


@eqx.filter_jit
def _unproject(camera, pixels):
    return camera.unproject_valid(pixels)


def _bearings(cams: tuple[AbstractCameraModel, ...], px: np.ndarray) -> np.ndarray:
    if all(c is cams[0] for c in cams):
        rays, valid = _unproject(cams[0], jnp.asarray(px))
    else:
        out = [_unproject(c, jnp.asarray(p)) for c, p in zip(cams, px, strict=True)]
        rays, valid = jnp.stack([o[0] for o in out]), jnp.stack([o[1] for o in out])
    valid = np.asarray(valid)
    if not valid.all():
        i = int(np.argmin(valid))
        raise BadInputError(
            f"pixels[{i}] = {px[i].tolist()}: camera {i} cannot unproject it (outside the region where "
            f"its lens model is one-to-one)"
        )
    return np.asarray(rays)


def _bearings_masked(unique, layout: _Layout, px: np.ndarray, mask: np.ndarray, names) -> np.ndarray:
    """``(M, N, 3)`` bearings (zeros where unseen); one unproject call per unique camera."""
    m, n = mask.shape
    rays = np.zeros((m, n, 3))
    for cam, group in zip(unique, layout.groups, strict=True):
        idx = np.array(group)
        r, valid = _unproject(cam, jnp.asarray(px[:, idx].reshape(-1, 2)))
        r, valid = np.asarray(r).reshape(m, len(idx), 3), np.asarray(valid).reshape(m, len(idx))
        bad = mask[:, idx] & ~valid
        if bad.any():
            k, j = (int(v) for v in np.argwhere(bad)[0])
            raise BadInputError(
                f"pixels: point {names[k]!r} in view {int(idx[j])} at {px[k, idx[j]].tolist()}: the camera cannot "
                f"unproject it (outside the region where its lens model is one-to-one)"
            )
        rays[:, idx] = r
    return rays


# --------------------------------------------------------------------------------------------- DLT


def _dlt(R: np.ndarray, t: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalised homogeneous DLT; returns the point and ``|w|`` of the unit homogeneous solution."""
    centres = -np.einsum("nji,nj->ni", R, t)
    c = centres.mean(axis=0)
    dist = np.linalg.norm(centres - c, axis=1).mean()
    s = 1.0 / dist if dist > 0 else 1.0
    # X = c + X' / s  =>  s (R X + t) = R X' + s (R c + t) w'
    P = np.concatenate([R, (s * (np.einsum("nij,j->ni", R, c) + t))[..., None]], axis=2)
    A = np.einsum("nij,njk->nik", skew(b), P).reshape(-1, 4)
    _, _, vt = np.linalg.svd(A)
    h = vt[-1]
    w = h[3]
    if abs(w) < 1e-12:
        return np.full(3, np.inf), 0.0
    return c + h[:3] / w / s, float(abs(w))


def _parallax_deg(R: np.ndarray, b: np.ndarray) -> float:
    rays = np.einsum("nji,nj->ni", R, b)  # base frame
    cosines = np.clip(rays @ rays.T, -1.0, 1.0)
    return float(np.rad2deg(np.arccos(cosines.min())))


def triangulate_dlt(
    cameras, pixels, T_cam_base=None, *, T_base_cam=None, min_parallax_deg: float = DEFAULT_MIN_PARALLAX_DEG
) -> np.ndarray:
    """The normalised DLT point ``(3,)`` (base frame) alone, without refinement or covariance.

    Arguments and errors as for :func:`triangulate_point`.
    """
    px = _pixels(pixels)
    cams = _cameras(cameras, len(px))
    R, t = _poses(T_cam_base, T_base_cam, len(px))
    b = _bearings(cams, px)
    return _checked_dlt(R, t, b, min_parallax_deg)[0]


def _checked_dlt(R, t, b, min_parallax_deg: float) -> tuple[np.ndarray, float]:
    parallax = _parallax_deg(R, b)
    X, _ = _dlt(R, t, b)
    if parallax < min_parallax_deg or not np.isfinite(X).all():
        raise NotObservableError(
            f"triangulation: the viewing rays are nearly parallel (largest angle between two rays "
            f"{parallax:.3g} deg < {min_parallax_deg} deg): the depth of the point along the viewing "
            f"ray is not determined; use cameras with a wider baseline",
            unknowns=["depth of the point along the viewing ray"],
        )
    depth = np.einsum("ni,ni->n", b, np.einsum("nij,j->ni", R, X) + t)
    if (depth <= 0).any():
        i = int(np.argmin(depth))
        raise NotObservableError(
            f"triangulation: the rays meet behind camera {i} (depth {depth[i]:.4g} along its ray): "
            f"no point in front of all cameras matches these pixels; check the correspondences",
            unknowns=[f"point position (the rays meet behind camera {i})"],
        )
    return X, parallax


# --------------------------------------------------------------------------------------------- refinement


def _project_views(cams, layout: _Layout, p_cam):
    """Project ``p_cam (N, 3)`` view by view (one batched call per unique camera)."""
    pix, valid = [], []
    for cam, group in zip(cams, layout.groups, strict=True):
        p, v = cam.project_valid(p_cam[jnp.asarray(group)])
        pix.append(p)
        valid.append(v)
    order = jnp.asarray(layout.order)
    return jnp.concatenate(pix, axis=0)[order], jnp.concatenate(valid, axis=0)[order]


def _residual(cams, layout: _Layout, R, t, X, theta, delta, px, w):
    """Whitened residuals ``(2N,)`` and validity ``(N,)`` of one point.

    ``theta`` stacks the unique cameras' intrinsics; ``delta (6N,)`` right-perturbs each view's
    ``T_cam_base``: ``p_cam = R (Exp(d) X) + t``.
    """
    n = layout.num_views
    sizes = [len(c.param_names) for c in cams]
    offsets = np.cumsum([0, *sizes])
    models = [c.with_params(theta[offsets[u] : offsets[u + 1]]) for u, c in enumerate(cams)]
    q = se3_apply(se3_exp(delta.reshape(n, 6)), jnp.broadcast_to(X, (n, 3)))
    p_cam = jnp.einsum("nij,nj->ni", R, q) + t
    pix, valid = _project_views(models, layout, p_cam)
    return (w[:, None] * (pix - px)).reshape(-1), valid


@eqx.filter_jit
def _refine(cams, layout: _Layout, R, t, px, w, X0, num_iterations: int):
    """Gauss-Newton for M points at once (``vmap``), then the Jacobian of the whitened residual
    with respect to ``(X, theta, delta)`` at the solution (one trace of the projection each)."""
    theta0 = jnp.concatenate([c.params for c in cams])
    delta0 = jnp.zeros(6 * layout.num_views)
    p = theta0.shape[0]

    def one(px_m, w_m, X0_m):
        def f(X):
            r = _residual(cams, layout, R, t, X, theta0, delta0, px_m, w_m)[0]
            return r, r

        def step(_, X):
            J, r = jax.jacfwd(f, has_aux=True)(X)
            return X + jnp.linalg.solve(J.T @ J, -(J.T @ r))

        X = jax.lax.fori_loop(0, num_iterations, step, X0_m)

        def full(z):
            r, valid = _residual(cams, layout, R, t, z[:3], z[3 : 3 + p], z[3 + p :], px_m, w_m)
            return r, (r, valid)

        J, (r, valid) = jax.jacfwd(full, has_aux=True)(jnp.concatenate([X, theta0, delta0]))
        return X, r, J[:, :3], J[:, 3 : 3 + p], J[:, 3 + p :], valid

    return jax.vmap(one)(px, w, X0)


def _checked_dlt_named(R, t, b, min_parallax_deg: float, name: str | None) -> tuple[np.ndarray, float]:
    if name is None:
        return _checked_dlt(R, t, b, min_parallax_deg)
    try:
        return _checked_dlt(R, t, b, min_parallax_deg)
    except NotObservableError as e:
        raise NotObservableError(f"point {name!r}: {e}", [f"point {name!r}: {u}" for u in e.unknowns]) from None


def _triangulate(
    cameras, px, mask, names, T_cam_base, T_base_cam, sigma_px, intrinsics_covariance, pose_covariance,
    num_iterations, min_parallax_deg, single_point: bool,
) -> TriangulatedPoints:  # fmt: skip
    m, n = mask.shape
    cams = _cameras(cameras, n)
    R, t = _poses(T_cam_base, T_base_cam, n)
    sigma = _sigma(sigma_px, n)
    if not (isinstance(num_iterations, (int, np.integer)) and num_iterations >= 0):
        raise BadInputError(f"num_iterations: expected a non-negative int, got {num_iterations!r}")
    unique, layout = _layout(cams)
    cov_theta = _intrinsics_covariance(intrinsics_covariance, isinstance(cameras, AbstractCameraModel), unique, layout)
    cov_delta = _pose_covariance(pose_covariance, n, "T_cam_base" if T_cam_base is not None else "T_base_cam")
    if T_base_cam is not None and pose_covariance is not None:
        # (T_base_cam Exp(d))^-1 = T_cam_base Exp(-Ad(T_base_cam) d): move to T_cam_base tangents
        A = np.zeros((6 * n, 6 * n))
        Ad = adjoint(invert(make_pose(R, t)))  # of T_base_cam
        for i in range(n):
            A[6 * i : 6 * i + 6, 6 * i : 6 * i + 6] = -Ad[i]
        cov_delta = A @ cov_delta @ A.T
    if single_point:
        b = _bearings(cams, px[0])[None]
    else:
        b = _bearings_masked(unique, layout, px, mask, names)
    X0 = np.zeros((m, 3))
    parallax = np.zeros(m)
    for k in range(m):
        sel = mask[k]
        X0[k], parallax[k] = _checked_dlt_named(R[sel], t[sel], b[k, sel], min_parallax_deg, None if single_point else names[k])
    w = mask / sigma[None, :]
    X, r, J_X, J_theta, J_delta, valid = (
        np.asarray(a)
        for a in _refine(unique, layout, jnp.asarray(R), jnp.asarray(t), jnp.asarray(px), jnp.asarray(w),
                         jnp.asarray(X0), int(num_iterations))
    )  # fmt: skip
    bad = mask & ~valid
    if bad.any() or not np.isfinite(X).all():
        k, i = (int(v) for v in np.argwhere(bad)[0]) if bad.any() else (int(np.argmin(np.isfinite(X).all(1))), 0)
        who = "" if single_point else f"point {names[k]!r}: "
        raise NotObservableError(
            f"triangulation: {who}the refined point is behind camera {i} or outside its valid field of view; "
            f"check the correspondences",
            unknowns=[f"{who}point position (invalid in camera {i})"],
        )
    sigma_out: float | np.ndarray = float(sigma[0]) if np.all(sigma == sigma[0]) else sigma
    cov_cam_params = np.zeros((J_theta.shape[2] + 6 * n,) * 2)
    o = 0
    for c in cov_theta:
        cov_cam_params[o : o + len(c), o : o + len(c)] = c
        o += len(c)
    cov_cam_params[o:, o:] = cov_delta
    has_camera_cov = bool(np.any(cov_cam_params != 0.0))
    G = np.zeros((3 * m, cov_cam_params.shape[0]))
    points = []
    for k in range(m):
        H_inv = np.linalg.inv(J_X[k].T @ J_X[k])
        cov_px = 0.5 * (H_inv + H_inv.T)
        G[3 * k : 3 * k + 3] = -H_inv @ J_X[k].T @ np.concatenate([J_theta[k], J_delta[k]], axis=1)
        Gk = G[3 * k : 3 * k + 3]
        cov_cam = Gk @ cov_cam_params @ Gk.T if has_camera_cov else np.zeros((3, 3))
        cov_cam = 0.5 * (cov_cam + cov_cam.T)
        res = r[k].reshape(n, 2) * (sigma[:, None] * mask[k][:, None])  # un-whiten, pixels
        points.append(
            TriangulatedPoint(
                p_base=X[k],
                covariance=cov_px + cov_cam,
                residuals_px=res,
                rms_px=float(np.sqrt(np.sum(res**2) / (2 * mask[k].sum()))),
                sigma_px=sigma_out,
                p_base_dlt=X0[k],
                parallax_deg=float(parallax[k]),
                covariance_px=cov_px,
                covariance_camera=cov_cam,
                num_views=int(mask[k].sum()),
            )
        )
    joint = G @ cov_cam_params @ G.T if has_camera_cov else np.zeros((3 * m, 3 * m))
    for k, p in enumerate(points):
        joint[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] += p.covariance_px
    joint = 0.5 * (joint + joint.T)
    return TriangulatedPoints(tuple(points), tuple(names), joint)


def triangulate_point(
    cameras,
    pixels,
    T_cam_base=None,
    *,
    T_base_cam=None,
    sigma_px=1.0,
    intrinsics_covariance=None,
    pose_covariance=None,
    num_iterations: int = DEFAULT_ITERATIONS,
    min_parallax_deg: float = DEFAULT_MIN_PARALLAX_DEG,
) -> TriangulatedPoint:
    """Triangulate one point from N >= 2 views: normalised DLT, then Gauss-Newton on pixels.

    Args:
        cameras: one :class:`~jcalib.geometry.cameras.AbstractCameraModel` for all views, or a
            sequence of N (one per view; views given the *same object* share its intrinsic errors).
        pixels: ``(N, 2)`` the point's pixel in each view (OpenCV convention).
        T_cam_base: ``(N, 4, 4)`` (or ``(N, 7)``) pose of the base in each camera
            (``p_cam = T_cam_base @ p_base``), metres. Give this or ``T_base_cam``.
        T_base_cam: ``(N, 4, 4)`` (or ``(N, 7)``) camera poses in the base frame instead.
        sigma_px: standard deviation of each pixel coordinate (one value, or ``(N,)`` per view).
        intrinsics_covariance: uncertainty of the intrinsics: None (exact), one ``(p, p)``
            matrix (order ``camera.param_names``) when ``cameras`` is one model, or a sequence of
            N entries (``(p_i, p_i)`` or None) when it is a sequence.
        pose_covariance: uncertainty of the poses as given (``T_cam_base`` or ``T_base_cam``),
            over their right-perturbation tangents ``(rx, ry, rz, tx, ty, tz)`` (rad, m):
            ``(N, 6, 6)`` independent per view or ``(6N, 6N)`` joint; None for exact poses.
        num_iterations: Gauss-Newton iterations after the DLT.
        min_parallax_deg: smallest accepted largest-angle between two viewing rays.

    Returns:
        :class:`TriangulatedPoint` (covariance: pixel noise + the given camera uncertainty,
        linearised; see the module docstring for what it leaves out).

    Raises:
        BadInputError: malformed pixels, poses, cameras, covariances, or a pixel a camera cannot
            unproject.
        NotObservableError: nearly parallel rays (depth along the ray), or rays meeting behind a
            camera.
    """
    px = _pixels(pixels)
    return _triangulate(
        cameras, px[None], np.ones((1, len(px)), dtype=bool), ("0",), T_cam_base, T_base_cam, sigma_px,
        intrinsics_covariance, pose_covariance, num_iterations, min_parallax_deg, single_point=True,
    ).points[0]  # fmt: skip


def triangulate_points(
    cameras,
    pixels,
    T_cam_base=None,
    *,
    T_base_cam=None,
    names: Sequence[str] | None = None,
    sigma_px=1.0,
    intrinsics_covariance=None,
    pose_covariance=None,
    num_iterations: int = DEFAULT_ITERATIONS,
    min_parallax_deg: float = DEFAULT_MIN_PARALLAX_DEG,
) -> TriangulatedPoints:
    """Triangulate M points seen in (subsets of) the same N views, with their joint covariance.

    Args:
        cameras, T_cam_base, T_base_cam, sigma_px, intrinsics_covariance, pose_covariance,
            num_iterations, min_parallax_deg: as for :func:`triangulate_point` (per view).
        pixels: ``(M, N, 2)`` pixel of point m in view i; NaN (both coordinates) where view i does
            not see point m. Every point needs >= 2 views.
        names: M point names for messages and lookups (default ``"0"``, ``"1"``...).

    Returns:
        :class:`TriangulatedPoints`: per-point results and the ``(3M, 3M)`` joint covariance
        (pixel noise is independent per point; the camera uncertainty is shared).

    Raises:
        BadInputError / NotObservableError: as :func:`triangulate_point`, naming the point.
    """
    px, mask, names = _pixel_sets(pixels, names)
    return _triangulate(
        cameras, px, mask, names, T_cam_base, T_base_cam, sigma_px, intrinsics_covariance, pose_covariance,
        num_iterations, min_parallax_deg, single_point=False,
    )  # fmt: skip


def point_distance(a, b, cross_covariance=None) -> tuple[float, float]:
    """Distance between two points and its standard deviation (linear propagation).

    ``sigma^2 = u^T (C_a + C_b - C_ab - C_ab^T) u`` with ``u = (a - b) / |a - b|``. Points
    triangulated from independent pixels with exact cameras are independent (``C_ab = 0``, the
    default); with uncertain cameras they are not: use :meth:`TriangulatedPoints.distance`, or
    pass :meth:`TriangulatedPoints.cross_covariance`.

    Args:
        a, b: :class:`TriangulatedPoint` results, or ``(point (3,), covariance (3, 3))`` pairs.
        cross_covariance: ``(3, 3)`` ``Cov(a, b)``, or None for independent points.

    Returns:
        ``(distance, sigma)`` in the points' unit.
    """

    def parts(p, name):
        if isinstance(p, TriangulatedPoint):
            return p.p_base, p.covariance
        try:
            x, c = p
            x, c = np.asarray(x, np.float64), np.asarray(c, np.float64)
        except (TypeError, ValueError):
            raise BadInputError(
                f"{name}: expected a TriangulatedPoint or (point, covariance), got {type(p).__name__}"
            ) from None
        if x.shape != (3,) or c.shape != (3, 3):
            raise BadInputError(f"{name}: expected point (3,) and covariance (3, 3), got {x.shape} and {c.shape}")
        return x, c

    pa, ca = parts(a, "a")
    pb, cb = parts(b, "b")
    cab = np.zeros((3, 3)) if cross_covariance is None else np.asarray(cross_covariance, np.float64)
    if cab.shape != (3, 3):
        raise BadInputError(f"cross_covariance: expected shape (3, 3), got {cab.shape}")
    diff = pa - pb
    dist = float(np.linalg.norm(diff))
    if dist == 0.0:
        raise BadInputError("a, b: the two points coincide; the distance's derivative is undefined")
    u = diff / dist
    var = float(u @ (ca + cb - cab - cab.T) @ u)
    return dist, float(np.sqrt(max(var, 0.0)))
