"""Plane-to-image homographies: normalised DLT (Hartley) and Gauss–Newton refinement, batched over views.

A homography ``H`` (3, 3) maps a point ``(x, y)`` of a planar target (target frame, ``z = 0``,
any length unit) to a pixel: ``[u, v, 1] ~ H @ [x, y, 1]``. Pixels follow OpenCV (centre of the
top-left pixel is (0, 0)). Returned homographies are scaled to unit Frobenius norm with
``H[2, 2] >= 0``.

Everything here is plain numpy (float64): these are closed-form starting points computed once per
data set, outside any ``jit``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jcalib.errors import BadInputError

__all__ = [
    "estimate_homographies",
    "estimate_homography",
    "homography_residuals",
    "normalizing_transform",
    "refine_homographies",
]

#: A configuration is degenerate when its second-smallest singular value (of the centred,
#: normalised point cloud, or of the DLT matrix) falls below this fraction of the largest one.
#: Exactly collinear points give ~1e-16; a 1 mm bow over a 0.2 m row of a board gives ~1e-2.
DEGENERATE_RTOL = 1e-9
#: Views whose normalised DLT matrix has ``s₈ < _EIGH_GAP s₁`` take the SVD (estimate_homography_stack).
_EIGH_GAP = 1e-3
_COLLINEAR_RTOL = 1e-6


def _view_label(view_names: Sequence[str] | None, i: int) -> str:
    return f"view {view_names[i]!r}" if view_names is not None else f"view {i}"


def normalizing_transform(points: np.ndarray) -> np.ndarray:
    """Hartley's isotropic normalisation: centroid to the origin, mean distance sqrt(2).

    Args:
        points: (..., N, 2) points (any unit).

    Returns:
        (..., 3, 3) similarity ``T`` with ``T @ [p, 1]`` normalised.
    """
    points = np.asarray(points, dtype=np.float64)
    mean = points.mean(axis=-2)  # (..., 2)
    centred = points - mean[..., None, :]
    dist = np.sqrt(np.einsum("...i,...i->...", centred, centred)).mean(axis=-1)  # (...,)
    scale = np.sqrt(2.0) / np.where(dist > 0.0, dist, 1.0)
    T = np.zeros(points.shape[:-2] + (3, 3))
    T[..., 0, 0] = scale
    T[..., 1, 1] = scale
    T[..., 0, 2] = -scale * mean[..., 0]
    T[..., 1, 2] = -scale * mean[..., 1]
    T[..., 2, 2] = 1.0
    return T


def _apply(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(..., 3, 3) homography applied to (..., N, 2) points -> (..., N, 2)."""
    ph = points @ np.swapaxes(H[..., :, :2], -1, -2) + H[..., None, :, 2]
    return ph[..., :2] / ph[..., 2:3]


def homography_residuals(H: np.ndarray, points_target: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Transfer error ``H(x) - u`` in pixels.

    Args:
        H: (..., 3, 3) target plane -> pixel homographies.
        points_target: (..., N, 2) target points (z = 0 plane of the target frame).
        pixels: (..., N, 2) observed pixels.

    Returns:
        (..., N, 2) residuals, pixels.
    """
    return _apply(np.asarray(H, np.float64), np.asarray(points_target, np.float64)) - np.asarray(
        pixels, np.float64
    )


def check_planar_points(points_target: np.ndarray, name: str) -> np.ndarray:
    """Accept (..., N, 2) or (..., N, 3) with z == 0; return (..., N, 2)."""
    if points_target.ndim < 2 or points_target.shape[-1] not in (2, 3):
        raise BadInputError(
            f"{name}: expected an array of shape (N, 2) or (N, 3) (planar target points, z = 0), "
            f"got shape {points_target.shape}"
        )
    if points_target.shape[-1] == 3:
        z = points_target[..., 2]
        scale = max(float(np.nanmax(np.abs(points_target[..., :2]), initial=0.0)), 1e-300)
        if np.nanmax(np.abs(z), initial=0.0) > 1e-9 * scale:
            raise BadInputError(
                f"{name}: target points must lie in the z = 0 plane of the target frame; "
                f"got max |z| = {np.nanmax(np.abs(z)):.3g} (xy extent {scale:.3g})"
            )
        points_target = points_target[..., :2]
    return points_target


def _check_view(points: np.ndarray, pixels: np.ndarray, label: str) -> None:
    """Raise BadInputError for NaNs, too few points or collinear points in one view."""
    n = points.shape[0]
    if n < 4:
        raise BadInputError(f"{label}: a homography needs at least 4 points, got {n}")
    for what, arr in (("target points", points), ("pixels", pixels)):
        if not np.all(np.isfinite(arr)):
            bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=-1))
            raise BadInputError(
                f"{label}: {what} contain NaN or inf at point index {bad[:10].tolist()}; "
                "drop those points before estimating the homography"
            )
        centred = arr - arr.mean(axis=0)
        # singular values of the centred cloud from its 2x2 scatter matrix (cheaper than an SVD)
        sxx, syy, sxy = np.sum(centred * centred, axis=0).tolist() + [float(centred[:, 0] @ centred[:, 1])]
        half_gap = np.hypot(0.5 * (sxx - syy), sxy)
        lam_max = 0.5 * (sxx + syy) + half_gap
        lam_min = max(0.5 * (sxx + syy) - half_gap, 0.0)
        # (the eigenvalue difference loses half the digits: collinear to ~1e-8 reads as collinear)
        if lam_max == 0.0 or np.sqrt(lam_min) <= _COLLINEAR_RTOL * np.sqrt(lam_max):
            raise BadInputError(
                f"{label}: the {what} are collinear (or all equal); a homography needs points "
                "spanning the plane (at least 4, no three of four on a line)"
            )


def _check_views(pts_list: list, pix_list: list, view_names) -> None:
    """:func:`_check_view` of every view, one batch per point count; a view the batch flags is checked on
    its own, which raises naming it (the first such view in order)."""
    by_size: dict[int, list[int]] = {}
    for i, p in enumerate(pix_list):
        by_size.setdefault(p.shape[0], []).append(i)
    flagged = []
    for n, idx in by_size.items():
        ok = np.full(len(idx), n >= 4)
        for arr in (np.stack([pts_list[i] for i in idx]), np.stack([pix_list[i] for i in idx])):
            with np.errstate(invalid="ignore", over="ignore"):
                c = arr - arr.mean(axis=1, keepdims=True)
                sxx, syy = np.sum(c[..., 0] ** 2, axis=1), np.sum(c[..., 1] ** 2, axis=1)
                sxy = np.sum(c[..., 0] * c[..., 1], axis=1)
                half_gap = np.hypot(0.5 * (sxx - syy), sxy)
                lam_max = 0.5 * (sxx + syy) + half_gap
                lam_min = np.maximum(0.5 * (sxx + syy) - half_gap, 0.0)
                ok &= np.all(np.isfinite(arr), axis=(1, 2)) & (lam_max > 0.0) & (
                    np.sqrt(lam_min) > _COLLINEAR_RTOL * np.sqrt(lam_max))
        flagged += [i for i, good in zip(idx, ok) if not good]
    for i in sorted(flagged):
        _check_view(pts_list[i], pix_list[i], _view_label(view_names, i))


def _dlt_matrix(xn: np.ndarray, un: np.ndarray) -> np.ndarray:
    """(..., N, 2) normalised target points and pixels -> (..., 2N, 9) DLT matrix."""
    n = xn.shape[-2]
    A = np.zeros(xn.shape[:-2] + (2 * n, 9))
    A[..., :n, 0:2] = xn
    A[..., :n, 2] = 1.0
    A[..., n:, 3:5] = xn
    A[..., n:, 5] = 1.0
    A[..., :n, 6:8] = -un[..., 0:1] * xn
    A[..., :n, 8] = -un[..., 0]
    A[..., n:, 6:8] = -un[..., 1:2] * xn
    A[..., n:, 8] = -un[..., 1]
    return A


def _canonical(H: np.ndarray) -> np.ndarray:
    """Unit Frobenius norm, H[2, 2] >= 0 (or the last nonzero sign convention when H[2, 2] == 0)."""
    H = H / np.linalg.norm(H, axis=(-2, -1), keepdims=True)
    sign = np.where(H[..., 2, 2] < 0.0, -1.0, 1.0)
    return H * sign[..., None, None]


def _gauss_newton(
    Hn: np.ndarray, xn: np.ndarray, un: np.ndarray, num_iterations: int
) -> np.ndarray:
    """Levenberg–Marquardt on the transfer error of (V, 3, 3) normalised homographies (in place)."""
    V = Hn.shape[0]
    h = Hn.reshape(V, 9).copy()
    xh = np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], axis=-1)  # (V, N, 3)

    def residual(h_):
        H_ = h_.reshape(V, 3, 3)
        return (_apply(H_, xn) - un).reshape(V, -1)

    r = residual(h)
    cost = np.sum(r * r, axis=-1)
    lam = np.full(V, 1e-6)
    for _ in range(num_iterations):
        H_ = h.reshape(V, 3, 3)
        w = xh @ H_[:, 2, :][..., None]  # (V, N, 1)
        p = _apply(H_, xn)  # (V, N, 2)
        J = np.zeros(xn.shape[:-1] + (2, 9))
        J[..., 0, 0:3] = xh / w
        J[..., 1, 3:6] = xh / w
        J[..., 0, 6:9] = -p[..., 0:1] * xh / w
        J[..., 1, 6:9] = -p[..., 1:2] * xh / w
        J = J.reshape(V, -1, 9)
        JtJ = np.swapaxes(J, -1, -2) @ J
        g = np.swapaxes(J, -1, -2) @ r[..., None]
        # The scale of h is a gauge freedom: damp it with h h^T so the system is regular.
        hhT = h[:, :, None] * h[:, None, :] / np.sum(h * h, axis=-1)[:, None, None]
        diag = np.einsum("vii->vi", JtJ)
        A = JtJ + hhT * np.mean(diag, axis=-1)[:, None, None] + lam[:, None, None] * (
            np.eye(9) * diag[:, None, :]
        )
        step = -np.linalg.solve(A, g)[..., 0]
        h_new = h + step
        r_new = residual(h_new)
        cost_new = np.sum(r_new * r_new, axis=-1)
        ok = np.isfinite(cost_new) & (cost_new <= cost)
        h = np.where(ok[:, None], h_new, h)
        r = np.where(ok[:, None], r_new, r)
        cost = np.where(ok, cost_new, cost)
        lam = np.where(ok, lam * 0.1, lam * 10.0)
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    return h.reshape(V, 3, 3)


def estimate_homography_stack(
    points: np.ndarray, pixels: np.ndarray, refine: bool, num_iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Same-size views: (V, N, 2), (V, N, 2) -> (V, 3, 3) homographies and (V, 9) singular values of
    the normalised DLT matrices; inputs already validated.

    The null vector comes from ``eigh(AᵀA)`` (3x faster than the SVD of ``A`` for stacks of views).
    Squaring ``A`` costs accuracy only where its two smallest singular values are close: the vector's
    error is about ``eps (s₁ / s₈)²``. A view with ``s₈ < _EIGH_GAP s₁`` (a view near degeneracy; a
    checkerboard view has ``s₈ ≈ 0.25 s₁``) takes the SVD instead, so every null vector is good to
    ~1e-10 and the degeneracy test (``DEGENERATE_RTOL``) reads SVD singular values.
    """
    Tx = normalizing_transform(points)
    Tu = normalizing_transform(pixels)
    xn = _apply(Tx, points)
    un = _apply(Tu, pixels)
    A = _dlt_matrix(xn, un)
    if A.shape[-2] < 9:  # 4 points: 8 equations; a zero row gives the full right singular basis
        A = np.concatenate([A, np.zeros(A.shape[:-2] + (9 - A.shape[-2], 9))], axis=-2)
    w, U = np.linalg.eigh(np.swapaxes(A, -1, -2) @ A)  # ascending
    s = np.sqrt(np.maximum(w[..., ::-1], 0.0))
    h = U[..., :, 0]
    close = ~(s[..., -2] >= _EIGH_GAP * s[..., 0])  # (NaN too)
    if np.any(close):
        _, s_svd, Vt = np.linalg.svd(A[close], full_matrices=False)
        s[close], h[close] = s_svd, Vt[..., -1, :]
    Hn = h.reshape(-1, 3, 3)
    if refine and num_iterations > 0:
        Hn = _gauss_newton(Hn, xn, un, num_iterations)
    H = np.linalg.inv(Tu) @ Hn @ Tx
    return _canonical(H), s


def estimate_homographies(
    points_target,
    pixels,
    *,
    refine: bool = True,
    num_iterations: int = 10,
    view_names: Sequence[str] | None = None,
    _checked: bool = False,
) -> np.ndarray:
    """Normalised DLT homographies (target plane -> pixels) of many views, optionally refined.

    Hartley normalisation of both point sets, the DLT null vector by SVD, then (``refine=True``)
    a few Levenberg–Marquardt steps on the transfer error ``|H(x) - u|^2`` in pixels. Views of equal
    point count are solved as one batch.

    Args:
        points_target: target points in the target frame (z = 0 plane; any length unit, e.g. m):
            (N, 2) or (N, 3) shared by all views, (V, N, 2|3) per view, or a sequence of V arrays
            (N_i, 2|3) when views see different subsets.
        pixels: (V, N, 2) array or a sequence of V arrays (N_i, 2), pixels (OpenCV convention).
        refine: run the nonlinear refinement (the DLT alone minimises an algebraic error).
        num_iterations: refinement iterations.
        view_names: names used in error messages (default: the view index).

    Returns:
        (V, 3, 3) homographies, unit Frobenius norm, ``H[2, 2] >= 0``.

    Raises:
        BadInputError: naming the view, for fewer than 4 points, NaN/inf coordinates, collinear
            points, mismatched shapes or a degenerate configuration (e.g. 3 of 4 points collinear).
    """
    ragged = isinstance(pixels, (list, tuple))
    if ragged:
        pix_list = [np.asarray(p, np.float64) for p in pixels]
        if isinstance(points_target, (list, tuple)):
            pts_list = [np.asarray(p, np.float64) for p in points_target]
        else:
            shared = np.asarray(points_target, np.float64)
            pts_list = [shared] * len(pix_list)
    else:
        pix = np.asarray(pixels, np.float64)
        if pix.ndim != 3 or pix.shape[-1] != 2:
            raise BadInputError(
                f"pixels: expected shape (V, N, 2) or a list of (N_i, 2) arrays, got shape {pix.shape}"
            )
        pts = np.asarray(points_target, np.float64)
        if pts.ndim == 2:
            pts = np.broadcast_to(pts, (pix.shape[0],) + pts.shape)
        pix_list = list(pix)
        pts_list = list(pts)
    if len(pts_list) != len(pix_list):
        raise BadInputError(
            f"points_target: got {len(pts_list)} views of target points for {len(pix_list)} views of pixels"
        )
    if view_names is not None and len(view_names) != len(pix_list):
        raise BadInputError(
            f"view_names: expected {len(pix_list)} names (one per view), got {len(view_names)}"
        )
    V = len(pix_list)
    for i in range(V):
        label = _view_label(view_names, i)
        pts_list[i] = check_planar_points(pts_list[i], f"points_target ({label})")
        if pix_list[i].ndim != 2 or pix_list[i].shape[-1] != 2:
            raise BadInputError(f"pixels ({label}): expected shape (N, 2), got {pix_list[i].shape}")
        if pts_list[i].shape[0] != pix_list[i].shape[0]:
            raise BadInputError(
                f"{label}: {pts_list[i].shape[0]} target points but {pix_list[i].shape[0]} pixels; "
                "they must correspond one to one"
            )
    if not _checked:
        _check_views(pts_list, pix_list, view_names)

    H = np.empty((V, 3, 3))
    by_size: dict[int, list[int]] = {}
    for i, p in enumerate(pix_list):
        by_size.setdefault(p.shape[0], []).append(i)
    for idx in by_size.values():
        P = np.stack([pts_list[i] for i in idx])
        U = np.stack([pix_list[i] for i in idx])
        Hs, s = estimate_homography_stack(P, U, refine, num_iterations)
        # A unique homography has a 1-D null space: the second-smallest singular value of the
        # normalised DLT matrix must be clearly nonzero (else e.g. 3 of 4 points are collinear).
        degenerate = s[:, -2] <= DEGENERATE_RTOL * s[:, 0]
        if np.any(degenerate):
            i = idx[int(np.flatnonzero(degenerate)[0])]
            raise BadInputError(
                f"{_view_label(view_names, i)}: degenerate point configuration (the homography is not "
                "unique: e.g. three of four points are collinear); use more points spread over the target"
            )
        if not np.all(np.isfinite(Hs)):
            i = idx[int(np.flatnonzero(~np.all(np.isfinite(Hs), axis=(-2, -1)))[0])]
            raise BadInputError(f"{_view_label(view_names, i)}: homography estimation gave non-finite values")
        H[idx] = Hs
    return H


def estimate_homography(
    points_target, pixels, *, refine: bool = True, num_iterations: int = 10, view_name: str | None = None
) -> np.ndarray:
    """Normalised DLT homography of one view (see :func:`estimate_homographies`).

    Args:
        points_target: (N, 2) or (N, 3) target points, z = 0 plane of the target frame.
        pixels: (N, 2) pixels.
        refine: run the nonlinear refinement of the transfer error.
        num_iterations: refinement iterations.
        view_name: name used in error messages.

    Returns:
        (3, 3) homography, unit Frobenius norm, ``H[2, 2] >= 0``.
    """
    names = None if view_name is None else [view_name]
    return estimate_homographies(
        [np.asarray(points_target, np.float64)],
        [np.asarray(pixels, np.float64)],
        refine=refine,
        num_iterations=num_iterations,
        view_names=names,
    )[0]


def refine_homographies(H, points_target, pixels, *, num_iterations: int = 10) -> np.ndarray:
    """Refine given homographies on the pixel transfer error (same-size views).

    Args:
        H: (V, 3, 3) initial homographies.
        points_target: (N, 2) shared or (V, N, 2) target points.
        pixels: (V, N, 2) pixels.
        num_iterations: Levenberg–Marquardt iterations.

    Returns:
        (V, 3, 3) refined homographies, unit Frobenius norm, ``H[2, 2] >= 0``.
    """
    H = np.asarray(H, np.float64)
    pix = np.asarray(pixels, np.float64)
    pts = check_planar_points(np.asarray(points_target, np.float64), "points_target")
    pts = np.broadcast_to(pts, pix.shape)
    Tx = normalizing_transform(pts)
    Tu = normalizing_transform(pix)
    Hn = Tu @ H @ np.linalg.inv(Tx)
    Hn = Hn / np.linalg.norm(Hn, axis=(-2, -1), keepdims=True)
    Hn = _gauss_newton(Hn, _apply(Tx, pts), _apply(Tu, pix), num_iterations)
    return _canonical(np.linalg.inv(Tu) @ Hn @ Tx)
