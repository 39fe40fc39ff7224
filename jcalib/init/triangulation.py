"""Multi-view triangulation of one point seen by N >= 2 calibrated cameras with known poses.

Two steps, as in Hartley & Zisserman (ch. 12):

1. **DLT** on bearing vectors: each pixel is turned into a unit ray ``b_i`` in its camera frame by
   the camera model's ``unproject`` (distortion removed exactly, any OpenCV model or the fisheye),
   and ``b_i x (R_i X + t_i w) = 0`` (two independent rows per view) is solved for the homogeneous
   point ``(X, w)`` by SVD. The 3-D frame is normalised first (origin at the mean camera centre,
   mean centre distance 1), so the SVD is well conditioned at any scale.
2. **Gauss-Newton** on the reprojection error in pixels, ``sum_i |project_i(R_i X + t_i) - u_i|^2``,
   a fixed number of iterations (one ``jit`` per number of views and camera types).

The covariance is ``sigma_px^2 (J^T J)^-1`` with ``J`` the ``(2N, 3)`` Jacobian of the reprojection
(pixels per metre) at the solution: **pixel noise only** (isotropic, independent, ``sigma_px``); the
camera intrinsics and poses are taken as exact.

Degeneracy: when the viewing rays are nearly parallel (largest angle between two rays below
``min_parallax_deg``) the depth of the point along the viewing ray is not determined and
:class:`jcalib.errors.NotObservableError` says so; a DLT point behind a camera (the rays meet behind
it: usually a wrong correspondence) raises it too. Frames: ``T_cam_base`` maps base points into the
camera (``p_cam = R p_base + t``); pass ``T_base_cam`` instead if that is what you have.
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
from jcalib.init.pivot import as_pose_matrices

__all__ = [
    "DEFAULT_MIN_PARALLAX_DEG",
    "TriangulatedPoint",
    "point_distance",
    "triangulate_dlt",
    "triangulate_point",
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
        p_base: ``(3,)`` the point in the base frame (metres, or the unit of the pose translations).
        covariance: ``(3, 3)`` ``sigma_px^2 (J^T J)^-1``, base frame, unit^2; pixel noise only.
        residuals_px: ``(N, 2)`` reprojection errors ``project - pixel`` per view, pixels.
        rms_px: RMS of ``residuals_px`` over all coordinates, pixels.
        sigma_px: the pixel noise assumed for ``covariance``.
        p_base_dlt: ``(3,)`` the DLT point before the Gauss-Newton refinement.
        parallax_deg: largest angle between two viewing rays, degrees.
    """

    p_base: np.ndarray
    covariance: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    sigma_px: float
    p_base_dlt: np.ndarray
    parallax_deg: float

    @property
    def std(self) -> np.ndarray:
        """``(3,)`` standard deviations of ``p_base`` (base-frame axes)."""
        return np.sqrt(np.diag(self.covariance))


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


# --------------------------------------------------------------------------------------------- DLT


def _dlt(R: np.ndarray, t: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalised homogeneous DLT; returns the point and ``|w|`` of the unit homogeneous solution."""
    centres = -np.einsum("nji,nj->ni", R, t)
    c = centres.mean(axis=0)
    dist = np.linalg.norm(centres - c, axis=1).mean()
    s = 1.0 / dist if dist > 0 else 1.0
    # X = c + X' / s  =>  s (R X + t) = R X' + s (R c + t) w'
    P = np.concatenate([R, (s * (np.einsum("nij,j->ni", R, c) + t))[..., None]], axis=2)
    bx = np.stack(
        [
            np.stack([np.zeros(len(b)), -b[:, 2], b[:, 1]], -1),
            np.stack([b[:, 2], np.zeros(len(b)), -b[:, 0]], -1),
            np.stack([-b[:, 1], b[:, 0], np.zeros(len(b))], -1),
        ],
        axis=-2,
    )
    A = np.einsum("nij,njk->nik", bx, P).reshape(-1, 4)
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
    X, w = _dlt(R, t, b)
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


@eqx.filter_jit
def _gauss_newton(cams, R, t, px, X0, num_iterations: int):
    """``cams`` is one camera (shared by all views, vmapped) or a tuple (one per view, unrolled)."""
    shared = isinstance(cams, AbstractCameraModel)

    def project_all(X):
        p_cam = jnp.einsum("nij,j->ni", R, X) + t
        if shared:
            return cams.project_valid(p_cam)
        out = [cam.project_valid(p_cam[i]) for i, cam in enumerate(cams)]
        return jnp.stack([o[0] for o in out]), jnp.stack([o[1] for o in out])

    def residual(X):
        return (project_all(X)[0] - px).reshape(-1)

    def step(_, X):
        r = residual(X)
        J = jax.jacfwd(residual)(X)
        return X + jnp.linalg.solve(J.T @ J, -(J.T @ r))

    X = jax.lax.fori_loop(0, num_iterations, step, X0)
    return X, residual(X), jax.jacfwd(residual)(X), project_all(X)[1]


def triangulate_point(
    cameras,
    pixels,
    T_cam_base=None,
    *,
    T_base_cam=None,
    sigma_px: float = 1.0,
    num_iterations: int = DEFAULT_ITERATIONS,
    min_parallax_deg: float = DEFAULT_MIN_PARALLAX_DEG,
) -> TriangulatedPoint:
    """Triangulate one point from N >= 2 views: normalised DLT, then Gauss-Newton on pixels.

    Args:
        cameras: one :class:`~jcalib.geometry.cameras.AbstractCameraModel` for all views, or a
            sequence of N (one per view).
        pixels: ``(N, 2)`` the point's pixel in each view (OpenCV convention).
        T_cam_base: ``(N, 4, 4)`` (or ``(N, 7)``) pose of the base in each camera
            (``p_cam = T_cam_base @ p_base``), metres. Give this or ``T_base_cam``.
        T_base_cam: ``(N, 4, 4)`` (or ``(N, 7)``) camera poses in the base frame instead.
        sigma_px: standard deviation of each pixel coordinate, for the covariance.
        num_iterations: Gauss-Newton iterations after the DLT.
        min_parallax_deg: smallest accepted largest-angle between two viewing rays.

    Returns:
        :class:`TriangulatedPoint`.

    Raises:
        BadInputError: malformed pixels, poses, cameras, or a pixel a camera cannot unproject.
        NotObservableError: nearly parallel rays (depth along the ray), or rays meeting behind a
            camera.
    """
    px = _pixels(pixels)
    n = len(px)
    cams = _cameras(cameras, n)
    R, t = _poses(T_cam_base, T_base_cam, n)
    if not (np.isfinite(sigma_px) and sigma_px > 0):
        raise BadInputError(f"sigma_px: expected a positive pixel noise level, got {sigma_px!r}")
    if not (isinstance(num_iterations, int) and num_iterations >= 0):
        raise BadInputError(f"num_iterations: expected a non-negative int, got {num_iterations!r}")
    b = _bearings(cams, px)
    X0, parallax = _checked_dlt(R, t, b, min_parallax_deg)
    shared = cams[0] if all(c is cams[0] for c in cams) else cams
    X, r, J, valid = _gauss_newton(
        shared, jnp.asarray(R), jnp.asarray(t), jnp.asarray(px), jnp.asarray(X0), num_iterations
    )
    X, r, J, valid = np.asarray(X), np.asarray(r), np.asarray(J), np.asarray(valid)
    if not valid.all() or not np.isfinite(X).all():
        i = int(np.argmin(valid)) if not valid.all() else 0
        raise NotObservableError(
            f"triangulation: the refined point is behind camera {i} or outside its valid field of view; "
            f"check the correspondences",
            unknowns=[f"point position (invalid in camera {i})"],
        )
    cov = sigma_px**2 * np.linalg.inv(J.T @ J)
    return TriangulatedPoint(
        p_base=X,
        covariance=0.5 * (cov + cov.T),
        residuals_px=r.reshape(n, 2),
        rms_px=float(np.sqrt(np.mean(r**2))),
        sigma_px=float(sigma_px),
        p_base_dlt=X0,
        parallax_deg=parallax,
    )


def point_distance(a, b, cross_covariance=None) -> tuple[float, float]:
    """Distance between two points and its standard deviation (linear propagation).

    ``sigma^2 = u^T (C_a + C_b - C_ab - C_ab^T) u`` with ``u = (a - b) / |a - b|``. Two points
    triangulated from independent pixels are independent (``C_ab = 0``, the default), as long as the
    camera poses and intrinsics are taken as exact.

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
    diff = pa - pb
    dist = float(np.linalg.norm(diff))
    if dist == 0.0:
        raise BadInputError("a, b: the two points coincide; the distance's derivative is undefined")
    u = diff / dist
    var = float(u @ (ca + cb - cab - cab.T) @ u)
    return dist, float(np.sqrt(max(var, 0.0)))
