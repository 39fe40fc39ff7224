"""Zhang's closed-form camera calibration from planar views (Z. Zhang, MSR-TR-98-71, 1998).

From the target-plane -> pixel homographies ``H_i = s K [r1 r2 t]`` of several views:

1. intrinsics ``K`` from the image of the absolute conic ``B = K^-T K^-1``: every view gives two
   linear constraints ``h1^T B h2 = 0`` and ``h1^T B h1 = h2^T B h2`` (Zhang's ``v_ij``), optionally
   with zero skew, a fixed aspect ratio ``fy / fx`` or a fixed principal point;
2. per-view extrinsics ``T_cam_target`` from ``K^-1 H`` (nearest rotation by SVD);
3. radial distortion ``k1, k2`` by linear least squares given ``K`` and the poses (Zhang's 3.3).

This is only a starting point for the joint least-squares refinement. ``K`` follows OpenCV
(``K[0, 1]`` is the skew, pixel centre of the top-left pixel is (0, 0)); ``k1, k2`` are OpenCV's
radial coefficients (normalised image coordinates). Translations have the unit of the target points.
Plain numpy, float64.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.homography import (
    DEGENERATE_RTOL,
    check_planar_points,
    estimate_homographies,
    estimate_homography_stack,
    homography_residuals,
)

__all__ = [
    "ZhangInit",
    "estimate_radial_distortion",
    "extrinsics_from_homographies",
    "intrinsics_from_homographies",
    "zhang_init",
]

#: The constraint system's null space must be one-dimensional: its second-smallest singular value
#: must exceed this fraction of the largest. Exactly degenerate sets give ~1e-16; a 5-degree tilt
#: with 0.1 px noise gives ~1e-4.
RANK_RTOL = 1e-9

_FRONTO_MESSAGE = (
    "all views are fronto-parallel (or parallel to each other): focal length is not observable; "
    "tilt the target (views rotated by 20-45 degrees about different axes)"
)


@dataclass(frozen=True)
class ZhangInit:
    """Closed-form camera calibration (Zhang), a starting point for the refinement.

    Attributes:
        K: (3, 3) camera matrix, pixels (``K[0, 1]`` is the skew; 0 when ``skew=False``).
        dist: (2,) radial distortion ``[k1, k2]`` (OpenCV, normalised coordinates); zeros when not
            estimated.
        R: (V, 3, 3) rotations of ``T_cam_target`` (target -> camera).
        t: (V, 3) translations of ``T_cam_target``, in the unit of the target points (e.g. m).
        homographies: (V, 3, 3) target plane -> pixel homographies used.
        homography_rms_px: (V,) RMS transfer error of each homography, pixels (model fit + noise +
            distortion; a view far above the others is suspect).
        tilt_deg: (V,) angle between the target normal and the optical axis, degrees. Views with a
            small tilt constrain the focal length little.
        orthonormality_error: (V,) how far ``K^-1 H`` was from ``[r1 r2 t]`` with orthonormal
            ``r1, r2`` (max of ``| |r1|/|r2| - 1 |`` and ``|cos(r1, r2)|``): consistency of the view
            with ``K``; 0 for exact data.
        singular_values: singular values of the (normalised) constraint system on ``B``, descending;
            the last is the algebraic residual, the second-to-last measures how well ``K`` is
            determined.
        condition: ``singular_values[-2] / singular_values[0]``: near 0 means near-degenerate views.
        focal_rel_std: relative spread of the closed-form ``fx`` (half the relative std of
            ``1/fx^2``, which stays finite when the focal length runs off to infinity) when the pixels are
            perturbed by Gaussian noise of the homographies' RMS residual (Monte Carlo, fixed seed;
            includes noise and unmodelled distortion treated as noise). 0 for exact data; near 1
            means the views do not determine the focal length; nan when ``check_observability``
            is off.
    """

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    homographies: np.ndarray
    homography_rms_px: np.ndarray
    tilt_deg: np.ndarray
    orthonormality_error: np.ndarray
    singular_values: np.ndarray
    condition: float
    focal_rel_std: float

    @property
    def T_cam_target(self) -> np.ndarray:
        """(V, 4, 4) poses of the target in the camera frame (maps target points to camera points)."""
        T = np.zeros(self.R.shape[:-2] + (4, 4))
        T[..., :3, :3] = self.R
        T[..., :3, 3] = self.t
        T[..., 3, 3] = 1.0
        return T

    @property
    def dist_opencv(self) -> np.ndarray:
        """(5,) OpenCV distortion vector ``[k1, k2, p1, p2, k3]`` with ``p1 = p2 = k3 = 0``."""
        return np.concatenate([self.dist, np.zeros(3)])


def _free_intrinsics(skew: bool, aspect_ratio, principal_point) -> list[str]:
    names = ["fx", "fy"] if aspect_ratio is None else ["fx (fy = aspect_ratio * fx)"]
    if principal_point is None:
        names += ["cx", "cy"]
    if skew:
        names.append("skew")
    return names


def _v(H: np.ndarray, i: int, j: int) -> np.ndarray:
    """Zhang's v_ij: (V, 3, 3) -> (V, 6) with h_i^T B h_j = v_ij . b, b = (B11, B12, B22, B13, B23, B33)."""
    hi, hj = H[:, :, i], H[:, :, j]
    return np.stack(
        [
            hi[:, 0] * hj[:, 0],
            hi[:, 0] * hj[:, 1] + hi[:, 1] * hj[:, 0],
            hi[:, 1] * hj[:, 1],
            hi[:, 2] * hj[:, 0] + hi[:, 0] * hj[:, 2],
            hi[:, 2] * hj[:, 1] + hi[:, 1] * hj[:, 2],
            hi[:, 2] * hj[:, 2],
        ],
        axis=-1,
    )


def _normalization(image_size, principal_point, H: np.ndarray) -> np.ndarray:
    """A common pixel similarity N (centre -> 0, scale -> ~1) that conditions the B system."""
    if principal_point is not None:
        centre = np.asarray(principal_point, np.float64)
    elif image_size is not None:
        centre = (np.asarray(image_size, np.float64) - 1.0) / 2.0
    else:
        origins = H[:, :2, 2] / H[:, 2:3, 2]  # pixels of the target origins
        centre = np.median(origins, axis=0)
    if image_size is not None:
        scale = float(np.mean(np.asarray(image_size, np.float64)))
    else:
        scale = 1000.0  # typical focal length / image size in pixels; only conditions the system
    return np.array(
        [[1.0 / scale, 0.0, -centre[0] / scale], [0.0, 1.0 / scale, -centre[1] / scale], [0.0, 0.0, 1.0]]
    )


def intrinsics_from_homographies(
    homographies,
    *,
    skew: bool = False,
    aspect_ratio: float | None = None,
    principal_point=None,
    image_size=None,
    _return_diagnostics: bool = False,
):
    """Zhang's closed-form camera matrix from plane -> pixel homographies.

    Args:
        homographies: (V, 3, 3) target plane -> pixel homographies (any scale).
        skew: estimate the skew ``K[0, 1]``; ``False`` adds the zero-skew constraint.
        aspect_ratio: if given, ``fy / fx`` is held at this value (requires ``skew=False``).
        principal_point: if given, ``(cx, cy)`` in pixels is held at this value.
        image_size: ``(width, height)`` in pixels, used only to condition the linear system.

    Returns:
        (3, 3) camera matrix ``K`` (pixels).

    Raises:
        NotObservableError: too few views for the free intrinsics, or views that leave the focal
            length undetermined (all fronto-parallel or parallel to each other); ``unknowns`` names
            the free intrinsics.
        BadInputError: malformed homographies or options.
    """
    H = np.asarray(homographies, np.float64)
    if H.ndim != 3 or H.shape[1:] != (3, 3):
        raise BadInputError(f"homographies: expected shape (V, 3, 3), got {H.shape}")
    if not np.all(np.isfinite(H)):
        raise BadInputError("homographies: contain NaN or inf")
    if aspect_ratio is not None:
        if skew:
            raise BadInputError(
                f"aspect_ratio: a fixed aspect ratio ({aspect_ratio}) needs skew=False, got skew=True"
            )
        if not (np.isfinite(aspect_ratio) and aspect_ratio > 0):
            raise BadInputError(f"aspect_ratio: expected a positive number fy/fx, got {aspect_ratio}")
    if principal_point is not None:
        pp = np.asarray(principal_point, np.float64)
        if pp.shape != (2,) or not np.all(np.isfinite(pp)):
            raise BadInputError(f"principal_point: expected (cx, cy) in pixels, got {principal_point!r}")

    basis = constraint_basis(skew, aspect_ratio, principal_point)
    m = basis.shape[1]
    V = H.shape[0]
    free = _free_intrinsics(skew, aspect_ratio, principal_point)
    needed = int(np.ceil((m - 1) / 2))
    if V < needed:
        raise NotObservableError(
            f"{V} view(s) cannot determine the camera matrix: Zhang's closed form needs at least "
            f"{needed} views (with skew={'free' if skew else 'zero'}"
            f"{', fixed aspect ratio' if aspect_ratio is not None else ''}"
            f"{', fixed principal point' if principal_point is not None else ''}); add tilted views",
            unknowns=free,
        )

    N = _normalization(image_size, principal_point, H)
    M = _constraint_rows(N, H) @ basis
    if M.shape[0] < m:  # pad so the SVD returns the full right singular basis
        M = np.concatenate([M, np.zeros((m - M.shape[0], m))], axis=0)
    _, s, Vt = np.linalg.svd(M, full_matrices=False)
    if s[0] == 0.0 or s[m - 2] <= RANK_RTOL * s[0]:
        raise NotObservableError(_FRONTO_MESSAGE, unknowns=free)
    b = basis @ Vt[-1]
    B = np.array([[b[0], b[1], b[3]], [b[1], b[2], b[4]], [b[3], b[4], b[5]]])
    if B[0, 0] < 0:
        B = -B
    try:
        L = np.linalg.cholesky(B)
    except np.linalg.LinAlgError:
        raise NotObservableError(
            "the closed-form intrinsics are not physical (B = K^-T K^-1 is not positive definite): "
            + _FRONTO_MESSAGE
            + ", or the data are too noisy / distorted for the selected model",
            unknowns=free,
        ) from None
    K = _camera_matrix_from_cholesky(N, L)
    if not skew:
        K[0, 1] = 0.0
    if aspect_ratio is not None:
        K[1, 1] = aspect_ratio * K[0, 0]
    if principal_point is not None:
        K[0, 2], K[1, 2] = pp
    if _return_diagnostics:
        return K, s
    return K


def constraint_basis(skew: bool, aspect_ratio, principal_point) -> np.ndarray:
    """Constraint subspace ``b = basis @ c`` of ``b = (B11, B12, B22, B13, B23, B33)`` (normalised B)."""
    basis = np.eye(6)
    keep = [0, 1, 2, 3, 4, 5]
    if not skew:
        keep.remove(1)  # B12 = 0  <=>  zero skew
    if principal_point is not None:
        keep.remove(3)  # principal point at the normalisation centre: B13 = B23 = 0
        keep.remove(4)
    basis = basis[:, keep]
    if aspect_ratio is not None:
        # B11 = r^2 B22 (r = fy / fx): merge the B11 and B22 columns into one.
        col = np.zeros(6)
        col[0], col[2] = aspect_ratio**2, 1.0
        basis = np.column_stack([col] + [basis[:, k] for k in range(basis.shape[1]) if keep[k] not in (0, 2)])
    return basis


def _constraint_rows(N: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Zhang's two constraints per view on ``b`` for (..., V, 3, 3) homographies -> (..., 2V, 6)."""
    Hn = N @ H
    Hn = Hn / np.linalg.norm(Hn, axis=(-2, -1), keepdims=True)
    lead = Hn.shape[:-3]
    Hf = Hn.reshape((-1,) + Hn.shape[-2:])
    rows = np.concatenate(
        [_v(Hf, 0, 1).reshape(lead + (-1, 6)), (_v(Hf, 0, 0) - _v(Hf, 1, 1)).reshape(lead + (-1, 6))], axis=-2
    )
    return rows


def _camera_matrix_from_cholesky(N: np.ndarray, L: np.ndarray) -> np.ndarray:
    """``B = L Lᵀ = K⁻ᵀ K⁻¹`` (normalised pixels, up to scale) -> (..., 3, 3) K in pixels."""
    # K^-1 upper triangular: K^-1 ~ L^T.
    Kn = np.linalg.inv(np.swapaxes(L, -1, -2))
    Kn = Kn / Kn[..., 2:3, 2:3]
    K = np.linalg.solve(N, Kn)
    K = K / K[..., 2:3, 2:3]
    K[..., 1, 0] = K[..., 2, 0] = K[..., 2, 1] = 0.0
    return K


def _focal_lengths_batch(H: np.ndarray, kw: dict) -> np.ndarray | None:
    """fx of the closed form for (D, V, 3, 3) homographies at once, or None if any draw fails.

    Same numerics as :func:`intrinsics_from_homographies` (which names the failure of a draw).
    """
    if kw.get("image_size") is None:
        return None
    basis = constraint_basis(kw["skew"], kw["aspect_ratio"], kw["principal_point"])
    m = basis.shape[1]
    N = _normalization(kw["image_size"], kw["principal_point"], H[0])
    M = _constraint_rows(N, H) @ basis
    if M.shape[-2] < m:
        return None
    _, s, Vt = np.linalg.svd(M, full_matrices=False)
    if np.any(s[:, 0] == 0.0) or np.any(s[:, m - 2] <= RANK_RTOL * s[:, 0]):
        return None
    b = Vt[:, -1, :] @ basis.T
    B = np.stack([b[:, [0, 1, 3]], b[:, [1, 2, 4]], b[:, [3, 4, 5]]], axis=-2)
    B = B * np.where(B[:, 0, 0] < 0.0, -1.0, 1.0)[:, None, None]
    try:
        L = np.linalg.cholesky(B)
    except np.linalg.LinAlgError:
        return None
    return _camera_matrix_from_cholesky(N, L)[:, 0, 0]


def extrinsics_from_homographies(K, homographies) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses ``T_cam_target`` from homographies and K: ``K^-1 H ~ [r1 r2 t]``, nearest rotation by SVD.

    The sign is chosen so the target lies in front of the camera (``t_z > 0``).

    Args:
        K: (3, 3) camera matrix, pixels.
        homographies: (V, 3, 3) target plane -> pixel homographies.

    Returns:
        R: (V, 3, 3) rotations (target -> camera).
        t: (V, 3) translations, in the unit of the target points.
        orthonormality_error: (V,) max of ``| |r1|/|r2| - 1 |`` and ``|cos(r1, r2)|`` before the
            projection onto SO(3).
    """
    K = np.asarray(K, np.float64)
    H = np.asarray(homographies, np.float64)
    A = np.linalg.solve(K, H)  # (V, 3, 3): K^-1 H
    a1, a2, a3 = A[..., 0], A[..., 1], A[..., 2]
    n1 = np.linalg.norm(a1, axis=-1)
    n2 = np.linalg.norm(a2, axis=-1)
    lam = 2.0 / (n1 + n2)
    lam = np.where(a3[..., 2] < 0.0, -lam, lam)
    r1 = lam[..., None] * a1
    r2 = lam[..., None] * a2
    t = lam[..., None] * a3
    Q = np.stack([r1, r2, np.cross(r1, r2)], axis=-1)
    U, _, Wt = np.linalg.svd(Q)
    d = np.sign(np.linalg.det(U @ Wt))
    D = np.ones(U.shape[:-2] + (3,))
    D[..., 2] = d
    R = (U * D[..., None, :]) @ Wt
    ortho = np.maximum(np.abs(n1 / n2 - 1.0), np.abs(np.sum(a1 * a2, axis=-1)) / (n1 * n2))
    return R, t, ortho


def _as_views(points_target, pixels) -> tuple[list[np.ndarray], list[np.ndarray]]:
    if isinstance(pixels, (list, tuple)):
        pix = [np.asarray(p, np.float64) for p in pixels]
    else:
        arr = np.asarray(pixels, np.float64)
        if arr.ndim != 3 or arr.shape[-1] != 2:
            raise BadInputError(f"pixels: expected shape (V, N, 2) or a list of (N_i, 2), got {arr.shape}")
        pix = list(arr)
    if isinstance(points_target, (list, tuple)):
        pts = [np.asarray(p, np.float64) for p in points_target]
    else:
        arr = np.asarray(points_target, np.float64)
        pts = [arr] * len(pix) if arr.ndim == 2 else list(arr)
    if len(pts) != len(pix):
        raise BadInputError(
            f"points_target: {len(pts)} views of target points for {len(pix)} views of pixels"
        )
    pts = [check_planar_points(p, f"points_target (view {i})") for i, p in enumerate(pts)]
    return pts, pix


def estimate_radial_distortion(K, R, t, points_target, pixels) -> np.ndarray:
    """Linear least-squares radial distortion ``k1, k2`` given K and poses (Zhang, section 3.3).

    With ``(u, v)`` the distortion-free projection, ``(x, y)`` its normalised coordinates and
    ``r^2 = x^2 + y^2``, OpenCV's radial model gives exactly
    ``u_obs - u = (u - cx)(k1 r^2 + k2 r^4)`` and ``v_obs - v = (v - cy)(k1 r^2 + k2 r^4)``.

    Args:
        K: (3, 3) camera matrix, pixels.
        R: (V, 3, 3) rotations of ``T_cam_target``.
        t: (V, 3) translations of ``T_cam_target`` (unit of the target points).
        points_target: (N, 2|3) shared, (V, N, 2|3) or a list of (N_i, 2|3); z = 0 plane.
        pixels: (V, N, 2) or a list of (N_i, 2) observed pixels.

    Returns:
        (2,) ``[k1, k2]``.
    """
    K = np.asarray(K, np.float64)
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    pts, pix = _as_views(points_target, pixels)
    rows, rhs = [], []
    for i in range(len(pix)):
        X = pts[i] @ R[i][:, :2].T + t[i]
        x = X[:, :2] / X[:, 2:3]
        uv = x @ K[:2, :2].T + K[:2, 2]
        r2 = np.sum(x * x, axis=-1)
        d = uv - K[:2, 2]  # (N, 2): u - cx, v - cy
        rows.append(np.stack([d * r2[:, None], d * (r2 * r2)[:, None]], axis=-1).reshape(-1, 2))
        rhs.append((pix[i] - uv).reshape(-1))
    D = np.concatenate(rows)
    e = np.concatenate(rhs)
    k, *_ = np.linalg.lstsq(D, e, rcond=None)
    return k


def _undistort_radial(pixels: np.ndarray, K: np.ndarray, k: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Invert OpenCV's radial model ``x_d = x (1 + k1 r^2 + k2 r^4)`` by fixed-point iteration.

    Args:
        pixels: (..., 2) distorted pixels.
        K: (3, 3) camera matrix.
        k: (2,) ``[k1, k2]``.

    Returns:
        (..., 2) distortion-free pixels (same K).
    """
    xd = (pixels - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    x = xd
    for _ in range(iterations):
        r2 = np.sum(x * x, axis=-1, keepdims=True)
        x = xd / (1.0 + k[0] * r2 + k[1] * r2 * r2)
    return x @ K[:2, :2].T + K[:2, 2]


class _Closed:
    """One pass of the closed form on (optionally undistorted) pixels; holds the fixed options."""

    def __init__(self, pts, pix, refine, view_names, intrinsics_kwargs):
        self.pts, self.pix = pts, pix
        self.refine, self.view_names = refine, view_names
        self.kw = intrinsics_kwargs
        self.scale = float(np.mean(np.asarray(intrinsics_kwargs["image_size"], np.float64)))

    def run(self, K_und=None, k_und=None, distortion: bool = True):
        if K_und is None:
            pix = self.pix
        else:
            flat = _undistort_radial(np.concatenate(self.pix), K_und, k_und)
            pix = np.split(flat, np.cumsum([len(p) for p in self.pix])[:-1])
        # inputs were validated by the first pass; undistorted pixels keep the configuration
        H = estimate_homographies(
            self.pts, pix, refine=self.refine, view_names=self.view_names, _checked=K_und is not None
        )
        K, s = intrinsics_from_homographies(H, _return_diagnostics=True, **self.kw)
        R, t, ortho = extrinsics_from_homographies(K, H)
        k = estimate_radial_distortion(K, R, t, self.pts, self.pix) if distortion else np.zeros(2)
        return H, K, s, R, t, ortho, k, pix

    def pack(self, K, k):
        return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]]) / self.scale, np.asarray(k)

    def unpack(self, theta):
        fx, fy, cx, cy, sk = theta[:5] * self.scale
        return np.array([[fx, sk, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), theta[5:7]

    def fixed_point_residual(self, theta):
        K, k = self.unpack(theta)
        try:
            out = self.run(K, k)
        except (NotObservableError, BadInputError, np.linalg.LinAlgError):
            return None, None
        new = np.concatenate(self.pack(out[1], out[6]))
        if not np.all(np.isfinite(new)):
            return None, None
        return new - theta, out


def _distortion_fixed_point(closed: _Closed, K, dist, free: list[int], iterations: int):
    """Newton on ``F(theta) - theta`` for the alternation F (undistort -> closed form -> k1, k2).

    Returns the outputs of :meth:`_Closed.run` at the best iterate, or None if none succeeded.
    """
    theta = np.concatenate(closed.pack(K, dist))
    g, out = closed.fixed_point_residual(theta)
    if g is None:
        return None
    best = (float(np.linalg.norm(g)), theta, g, out)
    eps = 1e-6  # finite-difference step in scaled units (K / image size, k1, k2)
    J = None
    for _ in range(iterations):
        if best[0] < 1e-10:  # scaled units: ~1e-7 px
            break
        norm, theta, g, _ = best
        if J is None:  # chord method: keep the Jacobian while it makes good progress
            J = np.zeros((7, len(free)))
            for c, j in enumerate(free):
                e = np.zeros(7)
                e[j] = eps
                gj, _ = closed.fixed_point_residual(theta + e)
                if gj is None:
                    return best[3]
                J[:, c] = (gj - g) / eps
        step = np.zeros(7)
        step[free] = -np.linalg.lstsq(J, g, rcond=None)[0]
        for _halving in range(6):
            g_new, out_new = closed.fixed_point_residual(theta + step)
            if g_new is not None and np.linalg.norm(g_new) < norm:
                best = (float(np.linalg.norm(g_new)), theta + step, g_new, out_new)
                break
            step = step / 2.0
        else:
            break
        if best[0] > 0.25 * norm:
            J = None  # slow progress: re-linearise
    return best[3]


_MC_DRAWS = 16
_MC_SCREEN_DRAWS = 4  # a first, cheap stage: accept at once when far below the threshold
#: Views the screening stage uses at most (evenly spaced): fewer views spread the closed form more, so
#: a subset far below the threshold vouches for the whole set (25 views: 2x, 400 views: 33x less work; a
#: set whose 12-view subset does not pass is decided by all its views, as before).
_MC_SCREEN_VIEWS = 12


def _fx_of_draws(closed: _Closed, draws) -> tuple[list[float], int]:
    """Closed-form fx of each noisy draw of the pixels (failed draws counted, not raised)."""
    fx: list[float] = []
    if isinstance(draws, np.ndarray):  # (D, V, N, 2): every view has the same point count
        # all draws' homographies in one batched DLT and all closed forms in one batched solve
        D, V = draws.shape[:2]
        pts = np.stack([np.asarray(p, np.float64)[:, :2] for p in closed.pts] * D)
        try:
            H_all, sv = estimate_homography_stack(pts, draws.reshape((-1,) + draws.shape[2:]), False, 0)
            if np.all(sv[:, -2] > DEGENERATE_RTOL * sv[:, 0]) and np.all(np.isfinite(H_all)):
                fx_all = _focal_lengths_batch(H_all.reshape(D, V, 3, 3), closed.kw)
                if fx_all is not None and np.all(np.isfinite(fx_all)):
                    return list(fx_all), 0
        except np.linalg.LinAlgError:
            pass
        draws = [list(d) for d in draws]  # some draw fails: the per-draw path counts which
    failures = 0
    for d in draws:
        try:
            Hd = estimate_homographies(closed.pts, d, refine=False, _checked=True)
            fx.append(intrinsics_from_homographies(Hd, **closed.kw)[0, 0])
        except (NotObservableError, BadInputError):
            failures += 1
    return fx, failures


def _focal_spread(closed: _Closed, H: np.ndarray, K: np.ndarray, check: bool, max_rel_std: float) -> float:
    """Monte Carlo spread of the closed-form fx under pixel noise of the homography residual.

    A screening stage of 4 draws (of at most ``_MC_SCREEN_VIEWS`` views) accepts at once when the spread
    is below a quarter of ``max_rel_std`` with no failed draw; otherwise all 16 draws of every view
    decide.
    """
    if len({p.shape[0] for p in closed.pix}) == 1:  # one batched evaluation
        res = homography_residuals(H, np.stack(closed.pts), np.stack(closed.pix)).reshape(-1)
    else:
        res = np.concatenate(
            [homography_residuals(H[i], closed.pts[i], closed.pix[i]).reshape(-1) for i in range(len(H))]
        )
    dof = max(res.size - 8 * len(H), 1)
    sigma = float(np.sqrt(np.sum(res * res) / dof))
    if sigma == 0.0 or not check:
        return 0.0 if sigma == 0.0 else float("nan")
    rng = np.random.default_rng(0)
    same_count = len({p.shape[0] for p in closed.pix}) == 1

    def draw(num, pix_list):  # noisy copies of the views' pixels, drawn only when needed
        if same_count:
            pix = np.stack(pix_list)
            return pix[None] + sigma * rng.standard_normal((num,) + pix.shape)
        return [[p + sigma * rng.standard_normal(p.shape) for p in pix_list] for _ in range(num)]

    def spread(fx):  # of 1/fx^2 (linear in B: finite, also when the focal length runs off to infinity)
        w = 1.0 / np.asarray(fx) ** 2
        return float(0.5 * np.std(w, ddof=1) * K[0, 0] ** 2) if len(fx) >= 2 else float("inf")

    V = len(closed.pts)
    subset = V > _MC_SCREEN_VIEWS
    if subset:
        idx = np.linspace(0, V - 1, _MC_SCREEN_VIEWS).round().astype(int)
        screen = _Closed([closed.pts[i] for i in idx], [closed.pix[i] for i in idx], closed.refine,
                         None, closed.kw)
    else:
        screen = closed
    screen_draws = draw(_MC_SCREEN_DRAWS, screen.pix)
    fx, failures = _fx_of_draws(screen, screen_draws)
    rel = spread(fx)
    if failures or rel > 0.25 * max_rel_std:
        if subset:
            draws = draw(_MC_DRAWS, closed.pix)
        else:  # the screening draws and the rest of the same stream
            rest = draw(_MC_DRAWS - _MC_SCREEN_DRAWS, closed.pix)
            draws = np.concatenate([screen_draws, rest]) if same_count else screen_draws + rest
        fx, failures = _fx_of_draws(closed, draws)
        rel = spread(fx)
    if failures > _MC_DRAWS // 4 or rel > max_rel_std:
        if failures > _MC_DRAWS // 4:
            how = f"is non-physical in {failures}/{_MC_DRAWS} draws"
        else:
            how = f"varies by {rel:.0%}"
        raise NotObservableError(
            _FRONTO_MESSAGE
            + f" (with pixel noise of {sigma:.2g} px, as observed, the closed-form focal length {how})",
            unknowns=_free_intrinsics(
                closed.kw["skew"], closed.kw["aspect_ratio"], closed.kw["principal_point"]
            ),
        )
    return rel


def zhang_init(
    points_target,
    pixels,
    *,
    skew: bool = False,
    aspect_ratio: float | None = None,
    principal_point=None,
    image_size=None,
    estimate_distortion: bool = True,
    distortion_iterations: int = 8,
    refine_homographies: bool = True,
    check_observability: bool = True,
    max_focal_rel_std: float = 0.15,
    view_names: Sequence[str] | None = None,
) -> ZhangInit:
    """Zhang's closed-form calibration: homographies, K, poses and radial distortion.

    Zhang's single pass (``distortion_iterations=0``) fits K to the distorted pixels, which biases
    it (on Zhang's own data: f = 877 px instead of 832.5) and makes the linear ``k1, k2`` estimate
    meaningless. With ``distortion_iterations > 0`` the alternation "undistort the pixels with the
    current ``K, k1, k2`` -> closed-form K and poses -> linear ``k1, k2``" is driven to its fixed
    point by Newton's method (finite-difference Jacobian, 7 unknowns, a few ms per iteration);
    exact data is a fixed point, so noise-free data is recovered exactly. If an iteration fails
    (non-physical K), the best iterate so far is kept.

    Args:
        points_target: target points in the target frame, z = 0 plane (any length unit, e.g. m):
            (N, 2|3) shared by all views, (V, N, 2|3), or a list of V arrays (N_i, 2|3).
        pixels: (V, N, 2) or a list of V arrays (N_i, 2), observed pixels (OpenCV convention).
        skew: estimate the skew; ``False`` (default, as OpenCV) holds it at 0.
        aspect_ratio: hold ``fy / fx`` at this value (OpenCV's ``CALIB_FIX_ASPECT_RATIO``).
        principal_point: hold ``(cx, cy)`` at this value, pixels.
        image_size: ``(width, height)``, pixels; only conditions the linear system.
        estimate_distortion: estimate ``k1, k2`` (else zeros, and no alternation).
        distortion_iterations: Newton iterations of the distortion alternation (0: single pass).
        refine_homographies: refine each homography on the pixel transfer error first.
        check_observability: perturb the pixels with noise of the observed homography residual
            (16 draws, fixed seed) and raise :class:`NotObservableError` when the closed-form focal
            length is not determined (relative spread above ``max_focal_rel_std``, or more than a
            quarter of the draws non-physical). Noise-free degenerate sets are always caught.
        max_focal_rel_std: threshold of that check.
        view_names: names used in error messages.

    Returns:
        :class:`ZhangInit` with K, ``[k1, k2]``, per-view ``T_cam_target`` and diagnostics.

    Raises:
        BadInputError: a view with fewer than 4 points, collinear points or NaNs (named).
        NotObservableError: too few views, or views that leave the focal length undetermined.
    """
    pts, pix = _as_views(points_target, pixels)
    if image_size is None:
        allpix = np.concatenate(pix)
        lo, hi = allpix.min(axis=0), allpix.max(axis=0)
        # a stand-in image whose centre is the middle of the observed pixels
        image_size = tuple(hi + lo + 1.0)
    closed = _Closed(
        pts,
        pix,
        refine_homographies,
        view_names,
        dict(skew=skew, aspect_ratio=aspect_ratio, principal_point=principal_point, image_size=image_size),
    )
    H, K, s, R, t, ortho, dist, used_pix = closed.run(distortion=estimate_distortion)
    focal_rel_std = _focal_spread(closed, H, K, check_observability, max_focal_rel_std)
    if not estimate_distortion:
        dist = np.zeros(2)
    elif distortion_iterations > 0:
        free = [0, 1, 2, 3, 5, 6]  # fx, fy, cx, cy, (skew), k1, k2
        if skew:
            free.append(4)
        if principal_point is not None:
            free = [i for i in free if i not in (2, 3)]
        out = _distortion_fixed_point(closed, K, dist, free, distortion_iterations)
        if out is not None:
            H, K, s, R, t, ortho, dist, used_pix = out
    if len({p.shape[0] for p in pts}) == 1:  # one batched evaluation
        res = homography_residuals(H, np.stack(pts), np.stack(used_pix))
        rms = np.sqrt(np.mean(res.reshape(len(pix), -1) ** 2, axis=-1))
    else:
        rms = np.array(
            [np.sqrt(np.mean(homography_residuals(H[i], pts[i], used_pix[i]) ** 2)) for i in range(len(pix))]
        )
    tilt = np.degrees(np.arccos(np.clip(np.abs(R[:, 2, 2]), 0.0, 1.0)))
    return ZhangInit(
        K=K,
        dist=dist,
        R=R,
        t=t,
        homographies=H,
        homography_rms_px=rms,
        tilt_deg=tilt,
        orthonormality_error=ortho,
        singular_values=s,
        condition=float(s[-2] / s[0]),
        focal_rel_std=focal_rel_std,
    )
