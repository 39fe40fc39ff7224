"""Task-space uncertainty: what a covariance means where the calibration is used.

- :func:`projection_sigma_map`: σ (pixels) of the projection of a point anywhere in the image due to
  a camera's intrinsics covariance (mrcal's "worst-direction stdev");
- :func:`transform_sigma`: σ of a transform per axis, in degrees and millimetres;
- :func:`pixel_effect`: how far one unit of each intrinsic moves some image point (the tolerance of
  an intrinsic in pixels);
- :func:`projection_difference`: where two calibrations of one camera disagree (cross-validation).

The covariances come from the solve (its linear model, or the result file the solve wrote), or from a
planner's prediction; they are propagated through the lens model's projection of fixed rays, a derived
quantity (docs/design.md: "the projection of a pixel ray ... by linear propagation with JAX Jacobians"),
not a model of the calibration: the calibration's own linear model is never re-derived here.
The report draws these numbers and the goal-driven planner predicts with them (both import this module).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.result import CameraResult, TransformResult

__all__ = [
    "camera_model",
    "image_grid",
    "pixel_effect",
    "project",
    "projection_jacobian",
    "projection_difference",
    "projection_sigma_at",
    "projection_sigma_map",
    "transform_sigma",
    "unproject",
]


def camera_model(cam: Any):
    """The lens model of a :class:`CameraResult` (a model is returned as it is)."""
    if not isinstance(cam, CameraResult):
        return cam
    from jcalib.geometry.cameras import camera_from_opencv

    return camera_from_opencv(cam.K, cam.dist, cam.image_size, fisheye=cam.model == "fisheye")


def _config(model) -> tuple[type, tuple[int, int], bool]:
    return type(model), tuple(int(s) for s in model.image_size), bool(model.has_skew)


def _bucket(n: int) -> int:
    from jcalib.solve import bucket_size

    return bucket_size(max(int(n), 1))


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    if x.shape[0] >= n:
        return x
    return np.concatenate([x, np.broadcast_to(x[:1], (n - x.shape[0],) + x.shape[1:])])


@functools.cache
def _project_jit(model_cls: type, image_size: tuple[int, int], skew: bool):
    import jax

    return jax.jit(lambda q, p: model_cls.from_params(image_size, q, skew=skew).project(p))


@functools.cache
def _unproject_jit(model_cls: type, image_size: tuple[int, int], skew: bool):
    import jax

    return jax.jit(lambda q, x: model_cls.from_params(image_size, q, skew=skew).unproject_valid(x))


@functools.cache
def _projection_jacobian_jit(model_cls: type, image_size: tuple[int, int], skew: bool):
    """``(params (p,), p_cam (n, 3)) -> (n, 2, p)``: the projection of fixed camera-frame points
    differentiated w.r.t. the intrinsic vector (order ``param_names``)."""
    import jax

    def one(params, p):
        return jax.jacfwd(lambda q: model_cls.from_params(image_size, q, skew=skew).project(p))(params)

    return jax.jit(jax.vmap(one, in_axes=(None, 0)))


def project(cam: Any, p_cam: np.ndarray) -> np.ndarray:
    """Pixels ``(n, 2)`` of camera-frame points ``(n, 3)`` (m); one compiled function per shape bucket."""
    import jax.numpy as jnp

    m = camera_model(cam)
    p_cam = np.asarray(p_cam, np.float64).reshape(-1, 3)
    n = p_cam.shape[0]
    fn = _project_jit(*_config(m))
    return np.asarray(fn(jnp.asarray(m.params), jnp.asarray(_pad(p_cam, _bucket(n)))))[:n]


def unproject(cam: Any, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays ``(n, 3)`` (camera frame, z = 1 for perspective models) and validity ``(n,)`` of pixels ``(n, 2)``."""
    import jax.numpy as jnp

    m = camera_model(cam)
    pixels = np.asarray(pixels, np.float64).reshape(-1, 2)
    n = pixels.shape[0]
    rays, valid = _unproject_jit(*_config(m))(jnp.asarray(m.params), jnp.asarray(_pad(pixels, _bucket(n))))
    return np.asarray(rays)[:n], np.asarray(valid)[:n]


def projection_jacobian(cam: Any, p_cam: np.ndarray) -> np.ndarray:
    """``(n, 2, p)``: how the pixels of fixed camera-frame points ``(n, 3)`` move with the intrinsics
    (order ``param_names``); one compiled function per shape bucket."""
    import jax.numpy as jnp

    m = camera_model(cam)
    n = p_cam.shape[0]
    fn = _projection_jacobian_jit(*_config(m))
    return np.asarray(fn(jnp.asarray(m.params), jnp.asarray(_pad(p_cam, _bucket(n)))))[:n]


def image_grid(image_size, grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)`` pixel coordinates ``(ny, nx)`` of a grid spanning the image, edges included."""
    width, height = image_size
    nx, ny = grid
    return np.meshgrid(np.linspace(0.0, width - 1.0, nx), np.linspace(0.0, height - 1.0, ny))


def projection_sigma_at(cam: Any, pixels: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Worst-direction σ (px) ``(n,)`` of the projection at ``pixels (n, 2)`` for an intrinsics covariance
    ``(p, p)`` (order ``param_names``); NaN where a pixel has no valid ray."""
    rays, valid = unproject(cam, pixels)
    valid = valid & (rays[:, 2] > 1e-6)
    J = projection_jacobian(cam, rays)
    cov_px = np.einsum("nip,pq,njq->nij", J, np.asarray(covariance, np.float64), J)
    eig = np.linalg.eigvalsh(0.5 * (cov_px + np.swapaxes(cov_px, -1, -2)))
    return np.where(valid, np.sqrt(np.maximum(eig[:, -1], 0.0)), np.nan)


def projection_sigma_map(cam: CameraResult, grid: tuple[int, int] = (33, 25), covariance: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """σ (pixels) of the projection of points across the image due to the intrinsics covariance.

    For a grid of pixels, the estimated model unprojects each pixel to a point ``p_cam`` on its ray
    (held fixed); the Jacobian ``J (2, p)`` of ``project(p_cam)`` w.r.t. the intrinsic vector
    (order :attr:`CameraResult.param_names`) propagates the covariance ``C``: ``Σ = J C Jᵀ (2, 2)``.
    The value is the worst-direction σ, ``sqrt(λ_max(Σ))`` (mrcal's "worstdirection-stdev").

    Includes: the intrinsics uncertainty caused by the measurement noise (as the solve reported it).
    Excludes: model error (a too-simple lens model) and the uncertainty of the camera and target
    poses. The lens models are central, so the value is the same at any depth along the pixel's ray.

    Args:
        cam: a camera with a ``covariance`` (or pass ``covariance``).
        grid: ``(nx, ny)`` grid points across the image.
        covariance: ``(p, p)`` intrinsics covariance to use instead of the camera's (e.g. predicted).

    Returns:
        ``(u, v, sigma)``: pixel coordinates ``(ny, nx)`` each (OpenCV convention) and σ ``(ny, nx)``
        in pixels; NaN where the pixel has no valid ray (outside a fisheye's valid range).
    """
    cov = cam.covariance if covariance is None else np.asarray(covariance, np.float64)
    if cov is None:
        raise BadInputError(f"cam: the camera ({cam.model}) has no intrinsics covariance; the projection "
                            "uncertainty needs one")
    u, v = image_grid(cam.image_size, grid)
    sigma = projection_sigma_at(cam, np.stack([u.ravel(), v.ravel()], axis=-1), cov)
    return u, v, sigma.reshape(u.shape)


def pixel_effect(cam: Any, grid: tuple[int, int] = (9, 7)) -> np.ndarray:
    """``(p,)`` largest pixel displacement per unit change of each intrinsic over the image.

    The norm of ``∂ project(ray) / ∂θ_j`` (px per unit of θ_j) at a grid of pixels including the
    image edges and corners, maximised over the grid: e.g. ``max |x/z|`` for ``fx``, 1 for ``cx``.
    """
    m = camera_model(cam)
    u, v = image_grid(m.image_size, grid)
    rays, valid = unproject(m, np.stack([u.ravel(), v.ravel()], -1))
    ok = valid & (rays[:, 2] > 1e-6)
    J = projection_jacobian(m, rays[ok])
    return np.max(np.linalg.norm(J, axis=1), axis=0)


def transform_sigma(transform: TransformResult) -> dict[str, Any] | None:
    """1σ of a transform per axis and in total, in display units.

    Returns:
        ``{"rotation_deg": (3,), "translation_mm": (3,), "rotation_total_deg": float,
        "translation_total_mm": float}`` (per-axis σ of the right-perturbation tangent, in the
        child frame; totals ``sqrt(trace)`` of the 3x3 blocks), or None without a covariance.
    """
    if transform.covariance is None:
        return None
    C = np.asarray(transform.covariance, np.float64)
    d = np.sqrt(np.maximum(np.diag(C), 0.0))
    return {
        "rotation_deg": np.degrees(d[:3]),
        "translation_mm": 1e3 * d[3:],
        "rotation_total_deg": float(np.degrees(np.sqrt(max(np.trace(C[:3, :3]), 0.0)))),
        "translation_total_mm": float(1e3 * np.sqrt(max(np.trace(C[3:, 3:]), 0.0))),
    }


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation ``R`` minimising ``Σ |R a_i − b_i|²`` (unit vectors ``(n, 3)``)."""
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)))])
    return U @ D @ Vt


def projection_difference(cam_a: CameraResult, cam_b: CameraResult, grid: tuple[int, int] = (33, 25),
                          fit_rotation: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance (px) between where two calibrations of one camera project the same point.

    Each grid pixel is unprojected by ``cam_a`` to a ray; ``cam_b`` projects that ray (after the
    rotation that best aligns the two models' rays over the grid, when ``fit_rotation``: a small
    rotation of the camera frame is not a difference in the lens, mrcal's "projection_diff" with
    points at infinity). Returns ``(u, v, diff)``, each ``(ny, nx)``; NaN where a ray is invalid.
    """
    u, v = image_grid(cam_a.image_size, grid)
    pix = np.stack([u.ravel(), v.ravel()], -1)
    ra, va = unproject(cam_a, pix)
    rb, vb = unproject(cam_b, pix)
    ok = va & vb & (ra[:, 2] > 1e-6) & (rb[:, 2] > 1e-6)
    ra = ra / np.linalg.norm(ra, axis=-1, keepdims=True)
    rb = rb / np.linalg.norm(rb, axis=-1, keepdims=True)
    R = _kabsch(ra[ok], rb[ok]) if fit_rotation and np.count_nonzero(ok) >= 3 else np.eye(3)
    proj = project(cam_b, ra @ R.T)
    diff = np.where(ok, np.linalg.norm(proj - pix, axis=-1), np.nan)
    return u, v, diff.reshape(u.shape)
