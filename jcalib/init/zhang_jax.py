"""Zhang's closed form as one traced JAX function: the start of a calibration inside its jit.

The same algorithm as :func:`jcalib.init.zhang.zhang_init` in its single-pass form (normalised DLT
homographies, closed-form ``K`` with the optional zero-skew / fixed-aspect / fixed-principal-point
constraints, poses from ``K⁻¹ H``), on padded ``(views, corners)`` arrays with a weight per corner, so
that it runs inside the jitted solve and under ``jax.vmap`` (a Monte-Carlo batch initialises and
solves in one call). No exception can be raised inside a trace, so every check of the numpy version
becomes part of one boolean ``ok``:

- every homography is non-degenerate (second-smallest singular value of its DLT system above
  ``DEGENERATE_RTOL`` of the largest) and finite;
- the constraint system on ``B = K⁻ᵀK⁻¹`` has a one-dimensional null space and ``B`` is positive
  definite;
- the focal length is determined by the views: its spread under pixel noise of the homographies'
  own residual, propagated to first order (one reverse-mode pass through the closed form, where
  the numpy check repeats it on noisy copies), is below ``_SPREAD_FACTOR`` of the numpy check's
  threshold.

``ok = False`` means "let the numpy path decide": the caller re-runs :func:`zhang_init`, which
names the problem (too few points, collinear points, fronto-parallel views) or accepts the data
after its own Monte-Carlo check. ``ok = True`` data pass the numpy checks too: a first-order spread
well below the threshold means the closed form is in its linear regime, where the Monte-Carlo spread
equals it up to sampling noise.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jcalib.geometry.lie import so3_from_matrix
from jcalib.init.homography import DEGENERATE_RTOL
from jcalib.init.zhang import RANK_RTOL, constraint_basis

#: ``ok`` needs a first-order focal-length spread below this fraction of the numpy check's threshold
#: (``max_focal_rel_std``, a Monte-Carlo spread); near the threshold the numpy check decides.
_SPREAD_FACTOR = 0.5


def _normalizer(xy, w):
    """Hartley similarity (weighted centroid -> 0, mean distance -> √2) of ``(C, 2)`` points."""
    sw = jnp.maximum(jnp.sum(w), 1.0)
    m = jnp.sum(xy * w[:, None], axis=0) / sw
    d = jnp.sum(jnp.linalg.norm(xy - m[None, :], axis=-1) * w) / sw
    s = jnp.sqrt(2.0) / jnp.where(d > 0.0, d, 1.0)
    zero = jnp.zeros((), xy.dtype)
    return jnp.array([[s, zero, -s * m[0]], [zero, s, -s * m[1]], [zero, zero, jnp.ones((), xy.dtype)]])


def _apply(T, xy):
    return xy @ T[:2, :2].T + T[:2, 2][None, :]


def _homography(xy, uv, w):
    """Normalised weighted DLT of one view: ``(H (3, 3), ok)`` with ``uv ~ H [x, y, 1]``.

    In Hartley-normalised coordinates both centroids are at the origin, so ``H[2, 2]`` is the
    dominant entry: it is set to 1 and the other eight come from the 8x8 normal equations of the
    DLT system (one Cholesky solve instead of a 9x9 eigendecomposition; equal to the homogeneous
    DLT for exact data). ``ok`` is False when the system is (numerically) singular: collinear or
    coincident points, which the numpy path then names.
    """
    Tx, Tu = _normalizer(xy, w), _normalizer(uv, w)
    x, u = _apply(Tx, xy), _apply(Tu, uv)
    one, zero = jnp.ones_like(x[:, :1]), jnp.zeros_like(x[:, :1])
    X = jnp.concatenate([x, one], axis=-1)  # (C, 3)
    r1 = jnp.concatenate([X, zero, zero, zero, -u[:, :1] * X], axis=-1)
    r2 = jnp.concatenate([zero, zero, zero, X, -u[:, 1:] * X], axis=-1)
    A = jnp.concatenate([r1 * w[:, None], r2 * w[:, None]], axis=0)  # (2C, 9)
    M = A.T @ A
    c, lower = jsl.cho_factor(M[:8, :8], lower=True)
    h = jnp.concatenate([jsl.cho_solve((c, lower), -M[:8, 8]), jnp.ones((1,), M.dtype)])
    pivots = jnp.diagonal(c) ** 2
    ok = (jnp.min(pivots) > DEGENERATE_RTOL**2 * jnp.max(jnp.diagonal(M))) & jnp.all(jnp.isfinite(h))
    H = jnp.linalg.solve(Tu, h.reshape(3, 3) @ Tx)
    return H / jnp.linalg.norm(H), ok


def _transfer(H, xy):
    p = xy @ H[:, :2].T + H[:, 2][None, :]
    return p[:, :2] / p[:, 2:3]


def _v(H, i, j):
    hi, hj = H[:, :, i], H[:, :, j]
    return jnp.stack([hi[:, 0] * hj[:, 0], hi[:, 0] * hj[:, 1] + hi[:, 1] * hj[:, 0], hi[:, 1] * hj[:, 1],
                      hi[:, 2] * hj[:, 0] + hi[:, 0] * hj[:, 2], hi[:, 2] * hj[:, 1] + hi[:, 1] * hj[:, 2],
                      hi[:, 2] * hj[:, 2]], axis=-1)


def _camera_matrix(H, view_w, N, basis, skew: bool, aspect_ratio, principal_point):
    """Closed-form K of ``(V, 3, 3)`` homographies (views with weight 0 ignored): ``(K, ok)``."""
    Hn = N @ H
    Hn = Hn / jnp.linalg.norm(Hn, axis=(-2, -1), keepdims=True)
    rows = jnp.concatenate([_v(Hn, 0, 1) * view_w[:, None], (_v(Hn, 0, 0) - _v(Hn, 1, 1)) * view_w[:, None]])
    M = rows @ basis
    m = basis.shape[1]
    e, vec = jnp.linalg.eigh(M.T @ M)
    sv = jnp.sqrt(jnp.maximum(e, 0.0))
    ok = (sv[-1] > 0.0) & (sv[1] > RANK_RTOL * sv[-1]) if m > 1 else sv[-1] > 0.0
    b = basis @ vec[:, 0]
    B = jnp.stack([b[jnp.array([0, 1, 3])], b[jnp.array([1, 2, 4])], b[jnp.array([3, 4, 5])]])
    B = jnp.where(B[0, 0] < 0.0, -B, B)
    L = jnp.linalg.cholesky(B)  # NaN when B is not positive definite
    Kn = jnp.linalg.inv(L.T)
    Kn = Kn / Kn[2, 2]
    K = jnp.linalg.solve(N, Kn)
    K = K / K[2, 2]
    K = K * jnp.array([[1.0, 1.0 if skew else 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    if aspect_ratio is not None:
        K = K.at[1, 1].set(aspect_ratio * K[0, 0])
    if principal_point is not None:
        K = K.at[0, 2].set(principal_point[0]).at[1, 2].set(principal_point[1])
    return K, ok & jnp.all(jnp.isfinite(K)) & (K[0, 0] > 0.0) & (K[1, 1] > 0.0)


def _poses(K, H):
    """``T_cam_target`` rotations and translations from ``K⁻¹ H`` (nearest rotation by SVD)."""
    A = jnp.linalg.solve(K[None], H)
    a1, a2, a3 = A[..., 0], A[..., 1], A[..., 2]
    n1, n2 = jnp.linalg.norm(a1, axis=-1), jnp.linalg.norm(a2, axis=-1)
    lam = 2.0 / (n1 + n2)
    lam = jnp.where(a3[..., 2] < 0.0, -lam, lam)
    r1, r2, t = lam[:, None] * a1, lam[:, None] * a2, lam[:, None] * a3
    Q = jnp.stack([r1, r2, jnp.cross(r1, r2)], axis=-1)
    U, _, Wt = jnp.linalg.svd(Q)
    d = jnp.sign(jnp.linalg.det(U @ Wt))
    U = U * jnp.stack([jnp.ones_like(d), jnp.ones_like(d), d], axis=-1)[:, None, :]
    return U @ Wt, t


def zhang_start(points_xy, pixels, weight, *, image_size: tuple[int, int], skew: bool = False,
                aspect_ratio: float | None = None, principal_point: tuple[float, float] | None = None,
                max_focal_rel_std: float = 0.15):
    """Zhang's single-pass closed form on padded views, traceable (see the module docstring).

    Args:
        points_xy: (V, C, 2) target points of each view (z = 0 plane), any length unit.
        pixels: (V, C, 2) observed pixels.
        weight: (V, C) 1 for a real corner, 0 for padding; a view whose weights are all 0 is padding.
        image_size: ``(width, height)`` pixels (static; conditions the system).
        skew, aspect_ratio, principal_point: as :func:`jcalib.init.zhang.zhang_init` (static).
        max_focal_rel_std: the numpy check's threshold on the focal-length spread.

    Returns:
        ``(K (3, 3), T_cam_target (V, 7) wxyz_xyz, ok)``; padded views get finite dummy poses.
    """
    w = weight.astype(points_xy.dtype)
    view_w = (jnp.sum(w, axis=-1) > 0.0).astype(points_xy.dtype)
    # a padded view: a copy of the first real view, so that its numbers stay finite
    first = jnp.argmax(view_w)
    xy = jnp.where(view_w[:, None, None] > 0.0, points_xy, points_xy[first][None])
    uv = jnp.where(view_w[:, None, None] > 0.0, pixels, pixels[first][None])
    w = jnp.where(view_w[:, None] > 0.0, w, w[first][None])

    basis = jnp.asarray(constraint_basis(skew, aspect_ratio, principal_point))
    centre = np.asarray(principal_point if principal_point is not None else (np.asarray(image_size) - 1.0) / 2.0,
                        np.float64)
    scale = float(np.mean(np.asarray(image_size, np.float64)))
    N = jnp.asarray(np.array([[1 / scale, 0, -centre[0] / scale], [0, 1 / scale, -centre[1] / scale], [0, 0, 1.0]]))

    def closed_form(uv):
        H, ok_h = jax.vmap(_homography)(xy, uv, w)
        K, ok_k = _camera_matrix(H, view_w, N, basis, skew, aspect_ratio, principal_point)
        return 1.0 / K[0, 0] ** 2, (H, K, ok_h, ok_k)

    # the spread of the closed-form focal length under pixel noise of the homographies' own residual
    # (numpy: a Monte-Carlo _focal_spread), to first order: std(1/fx²) = σ ‖∂(1/fx²)/∂pixels‖
    grad, (H, K, ok_h, ok_k) = jax.grad(closed_form, has_aux=True)(uv)
    R, t = _poses(K, H)
    pose = jnp.concatenate([so3_from_matrix(R), t], axis=-1)
    res = (jax.vmap(_transfer)(H, xy) - uv) * w[..., None] * view_w[:, None, None]
    dof = jnp.maximum(2.0 * jnp.sum(w * view_w[:, None]) - 8.0 * jnp.sum(view_w), 1.0)
    sigma = jnp.sqrt(jnp.sum(res * res) / dof)
    spread = 0.5 * sigma * jnp.linalg.norm(grad * view_w[:, None, None]) * K[0, 0] ** 2
    ok_spread = (spread < _SPREAD_FACTOR * max_focal_rel_std) & jnp.isfinite(spread)

    ok = jnp.all(ok_h | (view_w == 0.0)) & ok_k & ok_spread & jnp.all(jnp.isfinite(pose))
    return K, pose, ok, spread
