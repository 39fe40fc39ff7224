"""Camera pose from known points (PnP): planar IPPE with both candidates, and general SQPnP.

A planar target seen from afar, nearly fronto-parallel, has two poses that explain the pixels
almost equally well (the second one tilted the other way, "flipped"). Starting a refinement from
the wrong one leaves it in the wrong minimum (the joint solve does not cross the ridge between them), so the
planar solver returns **both** candidates, sorted by reprojection error, and the caller can re-seed
a suspect view with the other one.

The planar solver is our implementation of IPPE (T. Collins, A. Bartoli, "Infinitesimal Plane-based
Pose Estimation", IJCV 2014) on our normalised DLT homography; OpenCV is used only to undistort
pixels (``cv2.undistortPointsIter``), to project with the full distortion model when scoring
candidates, and for the general (non-planar) case (``cv2.solvePnP(SOLVEPNP_SQPNP)``).

Poses are ``T_cam_target`` (target points -> camera points), rotation matrix ``R`` and translation
``t`` in the unit of the target points. ``K`` and ``dist`` are OpenCV's (``dist`` any OpenCV length:
4, 5, 8, 12 or 14).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, make_pose, rotation_z_to, skew
from jcalib.init.homography import check_planar_points, estimate_homography

__all__ = [
    "PlanarPnPResult",
    "PnPResult",
    "planar_pnp",
    "planar_pnp_views",
    "solve_pnp",
]


@dataclass(frozen=True)
class PlanarPnPResult:
    """The two candidate poses of a planar PnP problem, best first.

    Attributes:
        R: (..., 2, 3, 3) rotations of ``T_cam_target`` (candidate 0 has the lower RMS).
        t: (..., 2, 3) translations of ``T_cam_target``, in the unit of the target points.
        rms_px: (..., 2) RMS reprojection error of each candidate, pixels (full distortion model).
    """

    R: np.ndarray
    t: np.ndarray
    rms_px: np.ndarray

    @property
    def T_cam_target(self) -> np.ndarray:
        """(..., 2, 4, 4) candidate poses of the target in the camera frame."""
        return make_pose(self.R, self.t)

    @property
    def ambiguity_ratio(self) -> np.ndarray:
        """(...,) ``rms_px[1] / rms_px[0]``: near 1 means the view cannot tell the two poses apart."""
        return self.rms_px[..., 1] / np.maximum(self.rms_px[..., 0], 1e-300)


@dataclass(frozen=True)
class PnPResult:
    """One pose from a general PnP problem.

    Attributes:
        R: (3, 3) rotation of ``T_cam_target``.
        t: (3,) translation of ``T_cam_target``, unit of the points.
        rms_px: RMS reprojection error, pixels.
    """

    R: np.ndarray
    t: np.ndarray
    rms_px: float

    @property
    def T_cam_target(self) -> np.ndarray:
        """(4, 4) pose of the target in the camera frame."""
        return make_pose(self.R, self.t)


def _check_camera(K, dist) -> tuple[np.ndarray, np.ndarray]:
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise BadInputError(f"K: expected a finite (3, 3) camera matrix with fx, fy > 0, got {K.tolist()}")
    if dist is None:
        dist = np.zeros(5)
    dist = np.asarray(dist, np.float64).reshape(-1)
    if dist.shape[0] not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
        raise BadInputError(
            f"dist: expected an OpenCV distortion vector of length 4, 5, 8, 12 or 14, got {dist.tolist()}"
        )
    return K, dist


def _normalized(pixels: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Pixels -> undistorted normalised image coordinates (N, 2)."""
    if not np.any(dist):
        return (pixels - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    out = cv2.undistortPointsIter(pixels.reshape(-1, 1, 2), K, dist, None, None, criteria)
    return out.reshape(-1, 2).astype(np.float64)


def _project_px(points, R, t, K, dist) -> np.ndarray:
    """(N, 3) target points -> (N, 2) pixels through OpenCV's full distortion model."""
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, t.reshape(3, 1), K, dist)
    return uv.reshape(-1, 2)


def _ippe_rotations(J: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IPPE: the two rotations from the homography's Jacobian J (2, 2) at the image point v (2,)."""
    vh = np.array([v[0], v[1], 1.0])
    Rv = rotation_z_to(vh / np.linalg.norm(vh))
    B = (np.column_stack([np.eye(2), -v]) @ Rv)[:, :2]
    A = np.linalg.solve(B, J)
    gamma = np.linalg.svd(A, compute_uv=False)[0]
    Rt = A / gamma  # top-left 2x2 of the rotation in the Rv frame
    b = np.sqrt(np.clip(1.0 - np.sum(Rt * Rt, axis=0), 0.0, None))  # (2,) third-row entries
    if -(Rt[0, 0] * Rt[0, 1] + Rt[1, 0] * Rt[1, 1]) < 0:
        b[1] = -b[1]
    out = []
    for sign in (1.0, -1.0):
        c0 = np.array([Rt[0, 0], Rt[1, 0], sign * b[0]])
        c1 = np.array([Rt[0, 1], Rt[1, 1], sign * b[1]])
        out.append(Rv @ np.column_stack([c0, c1, np.cross(c0, c1)]))
    return out[0], out[1]


def _translation(R: np.ndarray, u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Linear least-squares t with pi(R [u, 0] + t) = q: (3, 3), (N, 2), (N, 2) -> (3,)."""
    Ru = u @ R[:, :2].T  # (N, 3)
    n = u.shape[0]
    A = np.zeros((n, 2, 3))
    A[:, 0, 0] = 1.0
    A[:, 1, 1] = 1.0
    A[:, :, 2] = -q
    rhs = -(Ru[:, :2] - q * Ru[:, 2:3])
    t, *_ = np.linalg.lstsq(A.reshape(-1, 3), rhs.reshape(-1), rcond=None)
    return t


def _refine_pose(R, t, P, q, num_iterations: int):
    """Levenberg–Marquardt on the normalised reprojection error of one pose. P (N, 3), q (N, 2)."""

    def residual(R_, t_):
        X = P @ R_.T + t_
        return (X[:, :2] / X[:, 2:3] - q).reshape(-1), X

    r, X = residual(R, t)
    cost = float(r @ r)
    lam = 1e-6
    for _ in range(num_iterations):
        if not np.all(X[:, 2] > 0):
            break
        z = X[:, 2]
        dpi = np.zeros((P.shape[0], 2, 3))
        dpi[:, 0, 0] = 1.0 / z
        dpi[:, 1, 1] = 1.0 / z
        dpi[:, 0, 2] = -X[:, 0] / z**2
        dpi[:, 1, 2] = -X[:, 1] / z**2
        Jw = dpi @ -skew(P @ R.T)  # d pi / d omega (left perturbation): dpi @ (-[RP]x)
        J = np.concatenate([Jw, dpi], axis=-1).reshape(-1, 6)
        JtJ = J.T @ J
        step = -np.linalg.solve(JtJ + lam * np.diag(np.diag(JtJ)), J.T @ r)
        R_new = exp_so3(step[:3]) @ R
        t_new = t + step[3:]
        r_new, X_new = residual(R_new, t_new)
        c_new = float(r_new @ r_new)
        if np.isfinite(c_new) and c_new <= cost and np.all(X_new[:, 2] > 0):
            R, t, r, X, cost = R_new, t_new, r_new, X_new, c_new
            lam *= 0.1
        else:
            lam *= 10.0
    U, _, Wt = np.linalg.svd(R)
    return U @ Wt, t


def planar_pnp(
    points_target,
    pixels,
    K,
    dist=None,
    *,
    refine: bool = False,
    num_iterations: int = 20,
    view_name: str | None = None,
) -> PlanarPnPResult:
    """Both IPPE poses of a planar target in one view, sorted by reprojection error.

    Args:
        points_target: (N, 2) or (N, 3) target points in the target frame, z = 0 (any length unit).
        pixels: (N, 2) observed pixels (OpenCV convention).
        K: (3, 3) camera matrix, pixels.
        dist: OpenCV distortion vector (length 4, 5, 8, 12 or 14) or None.
        refine: polish each candidate with Levenberg–Marquardt on the reprojection error
            (normalised image coordinates); a candidate may then converge onto the other.
        num_iterations: refinement iterations.
        view_name: name used in error messages.

    Returns:
        :class:`PlanarPnPResult` with ``R`` (2, 3, 3), ``t`` (2, 3), ``rms_px`` (2,), best first.

    Raises:
        BadInputError: fewer than 4 points, NaNs, collinear points (naming the view), bad K/dist.
    """
    K, dist = _check_camera(K, dist)
    label = "view" if view_name is None else f"view {view_name!r}"
    pts = check_planar_points(np.asarray(points_target, np.float64), f"points_target ({label})")
    pix = np.asarray(pixels, np.float64)
    if pix.ndim != 2 or pix.shape[-1] != 2 or pix.shape[0] != pts.shape[0]:
        raise BadInputError(
            f"pixels ({label}): expected shape ({pts.shape[0]}, 2) matching the target points, "
            f"got {pix.shape}"
        )
    if not np.all(np.isfinite(pix)):
        raise BadInputError(f"pixels ({label}): contain NaN or inf; drop those points first")
    q = _normalized(pix, K, dist)
    mean = pts.mean(axis=0)
    u = pts - mean
    H = estimate_homography(u, q, refine=True, view_name=view_name)
    H = H / H[2, 2]
    v = H[:2, 2]
    J = H[:2, :2] - v[:, None] * H[2, :2][None, :]
    P = np.column_stack([pts, np.zeros(len(pts))])
    Rs, ts, rms = [], [], []
    for R in _ippe_rotations(J, v):
        t = _translation(R, u, q)
        t = t - R[:, :2] @ mean  # back from the centred target frame
        if refine:
            R, t = _refine_pose(R, t, P, q, num_iterations)
        err = _project_px(P, R, t, K, dist) - pix
        Rs.append(R)
        ts.append(t)
        rms.append(float(np.sqrt(np.mean(err * err))))
    order = np.argsort(rms, kind="stable")
    return PlanarPnPResult(
        R=np.stack(Rs)[order], t=np.stack(ts)[order], rms_px=np.asarray(rms)[order]
    )


def planar_pnp_views(
    points_target,
    pixels,
    K,
    dist=None,
    *,
    refine: bool = False,
    num_iterations: int = 20,
    view_names: Sequence[str] | None = None,
) -> PlanarPnPResult:
    """:func:`planar_pnp` for many views of one camera.

    Args:
        points_target: (N, 2|3) shared, (V, N, 2|3) or a list of V arrays (N_i, 2|3); z = 0.
        pixels: (V, N, 2) or a list of V arrays (N_i, 2).
        K: (3, 3) camera matrix, pixels.
        dist: OpenCV distortion vector or None.
        refine: polish each candidate (see :func:`planar_pnp`).
        num_iterations: refinement iterations.
        view_names: names used in error messages.

    Returns:
        :class:`PlanarPnPResult` with ``R`` (V, 2, 3, 3), ``t`` (V, 2, 3), ``rms_px`` (V, 2).
    """
    pix = list(pixels) if isinstance(pixels, (list, tuple)) else list(np.asarray(pixels, np.float64))
    if isinstance(points_target, (list, tuple)):
        pts = list(points_target)
    else:
        arr = np.asarray(points_target, np.float64)
        pts = [arr] * len(pix) if arr.ndim == 2 else list(arr)
    if len(pts) != len(pix):
        raise BadInputError(
            f"points_target: {len(pts)} views of target points for {len(pix)} views of pixels"
        )
    if view_names is not None and len(view_names) != len(pix):
        raise BadInputError(f"view_names: expected {len(pix)} names, got {len(view_names)}")
    results = [
        planar_pnp(
            pts[i],
            pix[i],
            K,
            dist,
            refine=refine,
            num_iterations=num_iterations,
            view_name=str(i) if view_names is None else view_names[i],
        )
        for i in range(len(pix))
    ]
    return PlanarPnPResult(
        R=np.stack([r.R for r in results]),
        t=np.stack([r.t for r in results]),
        rms_px=np.stack([r.rms_px for r in results]),
    )


def solve_pnp(
    points, pixels, K, dist=None, *, refine: bool = True, view_name: str | None = None
) -> PnPResult:
    """General PnP (3-D points, planar or not): OpenCV's SQPnP, optionally LM-refined.

    Args:
        points: (N, 3) points in the target frame (any length unit), N >= 3.
        pixels: (N, 2) observed pixels.
        K: (3, 3) camera matrix, pixels.
        dist: OpenCV distortion vector or None.
        refine: polish with ``cv2.solvePnPRefineLM``.
        view_name: name used in error messages.

    Returns:
        :class:`PnPResult` (``T_cam_target``).
    """
    K, dist = _check_camera(K, dist)
    label = "view" if view_name is None else f"view {view_name!r}"
    P = np.asarray(points, np.float64)
    pix = np.asarray(pixels, np.float64)
    if P.ndim != 2 or P.shape[-1] != 3:
        raise BadInputError(f"points ({label}): expected shape (N, 3), got {P.shape}")
    if pix.shape != (P.shape[0], 2):
        raise BadInputError(f"pixels ({label}): expected shape ({P.shape[0]}, 2), got {pix.shape}")
    if P.shape[0] < 3:
        raise BadInputError(f"{label}: PnP needs at least 3 points, got {P.shape[0]}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(pix))):
        raise BadInputError(f"{label}: points or pixels contain NaN or inf; drop those points first")
    ok, rvec, tvec = cv2.solvePnP(
        P.reshape(-1, 1, 3), pix.reshape(-1, 1, 2), K, dist, flags=cv2.SOLVEPNP_SQPNP
    )
    if not ok:
        raise BadInputError(f"{label}: SQPnP found no pose (degenerate points, e.g. all collinear)")
    if refine:
        rvec, tvec = cv2.solvePnPRefineLM(P.reshape(-1, 1, 3), pix.reshape(-1, 1, 2), K, dist, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    t = tvec.reshape(3).astype(np.float64)
    err = _project_px(P, R, t, K, dist) - pix
    return PnPResult(R=R, t=t, rms_px=float(np.sqrt(np.mean(err * err))))
