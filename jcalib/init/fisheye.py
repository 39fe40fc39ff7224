"""Closed-form start of a fisheye camera (``cv2.fisheye``'s Kannala–Brandt model) from planar views.

Zhang's method assumes a pinhole: through a fisheye the board's straight lines are curved, the
plane-to-image homographies it rests on do not exist, and its closed form returns a focal length
off by 50 % and more or none at all ("not physical", "fronto-parallel"; measured on rendered 180°
views with boards near the rim). Here the lens starts as the equidistant fisheye (``k1..k4 = 0``:
``θ = r / f``) with the principal point at the image centre, and the one unknown ``f`` is found by a
1-D search:

- for a candidate ``f`` every pixel becomes a unit bearing vector ``b``; a planar target's bearings
  are a homography of its points, ``b ∝ H [x, y, 1]``, exactly when the lens model is right;
- each view's ``H`` is the DLT solution on the sphere (``b × H p = 0``: valid at any angle from the
  axis, beyond 90° too, where ``(x/z, y/z)`` has no meaning); the cost is the sum over all points
  of the squared angle between ``b`` and ``H p``, times ``f²`` (about pixels²);
- ``f`` minimises the cost on a logarithmic grid from ``r_max / π`` (the farthest observed pixel
  at 180° from the axis) to 8 half image diagonals, refined by golden-section search.

The poses follow from the homographies of the best ``f`` (``H = λ [r1 r2 t]``). The joint solve
refines everything (fx, fy, cx, cy, k1..k4 and the poses).

Everything here is NumPy (float64) on the host: a start computed once per data set.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.homography import check_planar_points, normalizing_transform

__all__ = ["FisheyeInit", "bearing_homography", "bearing_pose", "fisheye_bearings", "fisheye_init"]

#: Points of the focal-length grid (logarithmic, ``r_max / π`` .. ``FOCAL_GRID_MAX`` half diagonals).
FOCAL_GRID_POINTS = 96
#: Upper end of the focal-length grid, in units of the half diagonal of the image (or of the farthest
#: observed pixel's radius, when larger).
FOCAL_GRID_MAX = 8.0
#: Golden-section iterations after the grid (relative bracket width ~1e-5).
GOLDEN_ITERATIONS = 30
#: Newton iterations of :func:`fisheye_bearings` (quadratic convergence from ``θ = θd``).
BEARING_ITERATIONS = 30


@dataclass(frozen=True)
class FisheyeInit:
    """The start of a fisheye camera.

    Attributes:
        K: (3, 3) camera matrix, pixels: ``fx = fy = f``, principal point at the image centre (or as
            given), no skew.
        D: (4,) ``k1..k4``, zeros (the equidistant fisheye).
        T_cam_target: one (4, 4) pose per view, target points -> camera points (unit of the points).
        rms_px: RMS of the angular residuals of the view homographies at ``f``, times ``f`` (about
            pixels; the lens's departure from the equidistant model plus the pixel noise).
        focal_grid: (G, 2) the searched ``(f, rms_px)`` pairs (diagnostics).
    """

    K: np.ndarray
    D: np.ndarray
    T_cam_target: list[np.ndarray]
    rms_px: float
    focal_grid: np.ndarray


def _theta_d(k: np.ndarray, theta: np.ndarray) -> np.ndarray:
    t2 = theta * theta
    return theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))


def _theta_d_slope(k: np.ndarray, theta: np.ndarray) -> np.ndarray:
    t2 = theta * theta
    return 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))


def fisheye_bearings(K, D, pixels) -> tuple[np.ndarray, np.ndarray]:
    """Unit bearing vectors of pixels through cv2.fisheye's model (NumPy, on the host).

    Unlike ``cv2.fisheye.undistortPoints``, which clamps the distorted angle to 90° (so every pixel
    beyond it lands on a wrong ray), this inverts ``θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)`` on
    the whole monotonic range of the polynomial (up to 180°), by Newton's method kept inside it.

    Args:
        K: (3, 3) camera matrix, pixels (``K[0][1] = alpha fx``, cv2.fisheye's skew).
        D: (4,) ``k1..k4``.
        pixels: (N, 2) pixels, OpenCV convention.

    Returns:
        ``(bearings, valid)``: (N, 3) unit vectors in the camera frame, and (N,) bool, False where
        the pixel lies beyond the image of the polynomial's monotonic range (no ray reaches it).
    """
    K = np.asarray(K, np.float64)
    k = np.asarray(D, np.float64).reshape(-1)
    if K.shape != (3, 3) or k.shape != (4,):
        raise BadInputError(f"fisheye_bearings: expected K (3, 3) and D (4,), got {K.shape} and {k.shape}")
    px = np.asarray(pixels, np.float64).reshape(-1, 2)
    y = (px[:, 1] - K[1, 2]) / K[1, 1]
    x = (px[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    theta_d = np.hypot(x, y)
    # the end of the monotonic range: first zero of the slope on (0, π] (sampled; 1e-3 rad is ample here)
    grid = np.linspace(0.0, math.pi, 3142)[1:]
    bad = np.flatnonzero(_theta_d_slope(k, grid) <= 0.0)
    theta_max = float(grid[bad[0] - 1]) if bad.size else math.pi
    theta = np.minimum(theta_d, theta_max)
    for _ in range(BEARING_ITERATIONS):
        step = (_theta_d(k, theta) - theta_d) / np.maximum(_theta_d_slope(k, theta), 1e-12)
        theta = np.clip(theta - step, 0.0, theta_max)
    valid = np.abs(_theta_d(k, theta) - theta_d) <= 1e-9 * np.maximum(1.0, theta_d)
    scale = np.where(theta_d > 1e-12, np.sin(theta) / np.where(theta_d > 1e-12, theta_d, 1.0), 1.0)
    b = np.stack([x * scale, y * scale, np.cos(theta)], axis=1)
    return b / np.linalg.norm(b, axis=1, keepdims=True), valid


def _check_view(points: np.ndarray, pixels: np.ndarray, label: str) -> np.ndarray:
    pts = check_planar_points(np.asarray(points, np.float64), label)
    px = np.asarray(pixels, np.float64)
    if pts.ndim != 2 or px.shape != (len(pts), 2):
        raise BadInputError(f"{label}: expected (N, 2|3) target points and (N, 2) pixels, got {pts.shape} and {px.shape}")
    if len(pts) < 4:
        raise BadInputError(f"{label}: a fisheye start needs at least 4 points per view, got {len(pts)}")
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(px))):
        raise BadInputError(f"{label}: target points or pixels contain NaN or inf")
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    if not sv[1] > 1e-6 * sv[0]:
        raise BadInputError(f"{label}: the target points are collinear; a view needs points spanning the plane")
    return pts


def bearing_homography(points_xy, bearings) -> np.ndarray:
    """The homography ``H`` (3, 3) with ``bearings ∝ H [x, y, 1]`` (DLT on ``b × H p = 0``).

    Valid for bearings at any angle from the optical axis. ``H`` has unit Frobenius norm and the sign
    that makes ``H p`` point along the bearings (``Σ b · H p > 0``).

    Args:
        points_xy: (N, 2) target points (z = 0 plane), N >= 4, not collinear.
        bearings: (N, 3) unit bearing vectors in the camera frame.
    """
    p = np.asarray(points_xy, np.float64)
    b = np.asarray(bearings, np.float64)
    T = normalizing_transform(p)
    q = np.column_stack([p, np.ones(len(p))]) @ T.T  # (N, 3)
    zero = np.zeros_like(q)
    # rows of [b]x (I ⊗ q^T) vec(H) = 0, one per component of the cross product
    bx, by, bz = b[:, 0:1], b[:, 1:2], b[:, 2:3]
    A = np.concatenate([
        np.concatenate([zero, -bz * q, by * q], axis=1),
        np.concatenate([bz * q, zero, -bx * q], axis=1),
        np.concatenate([-by * q, bx * q, zero], axis=1),
    ])
    # the null vector of A from its 9x9 normal matrix (float64; the points are normalised, so it is well conditioned)
    H = np.linalg.eigh(A.T @ A)[1][:, 0].reshape(3, 3) @ T
    H /= np.linalg.norm(H)
    hp = np.column_stack([p, np.ones(len(p))]) @ H.T
    return -H if np.sum(hp * b) < 0.0 else H


def _angles(H: np.ndarray, points_xy: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """(N,) angles (rad) between each bearing and ``H p``."""
    hp = np.column_stack([points_xy, np.ones(len(points_xy))]) @ H.T
    return np.arctan2(np.linalg.norm(np.cross(bearings, hp), axis=1), np.sum(bearings * hp, axis=1))


def bearing_pose(points_xy, bearings) -> np.ndarray:
    """``T_cam_target`` (4, 4) of a planar target from the bearings of its points (any angle).

    Args:
        points_xy: (N, 2) target points (z = 0 plane), unit of the returned translation.
        bearings: (N, 3) unit bearing vectors in the camera frame.
    """
    H = bearing_homography(points_xy, bearings)
    lam = 0.5 * (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    r1, r2 = H[:, 0] / lam, H[:, 1] / lam
    U, _, Vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, H[:, 2] / lam
    return T


def _equidistant_bearings(pixels: np.ndarray, centre: np.ndarray, f: float) -> np.ndarray:
    d = (pixels - centre) / f
    theta = np.hypot(d[:, 0], d[:, 1])
    s = np.where(theta > 1e-12, np.sin(theta) / np.where(theta > 1e-12, theta, 1.0), 1.0)
    return np.column_stack([d * s[:, None], np.cos(theta)])


def fisheye_init(
    points_target: Sequence[np.ndarray],
    pixels: Sequence[np.ndarray],
    image_size: tuple[int, int],
    *,
    principal_point=None,
    view_names: Sequence[str] | None = None,
) -> FisheyeInit:
    """Start a fisheye camera (equidistant, ``f`` by a 1-D search) and its views (module docstring).

    Args:
        points_target: per view (N_i, 2|3) target points, z = 0 (any length unit, e.g. m).
        pixels: per view (N_i, 2) observed pixels, OpenCV convention.
        image_size: ``(width, height)``, pixels.
        principal_point: ``(cx, cy)``, pixels; default the image centre ``((w - 1)/2, (h - 1)/2)``.
        view_names: names used in error messages.

    Returns:
        :class:`FisheyeInit`.

    Raises:
        BadInputError: no views, a view with fewer than 4 points, collinear points or NaNs (named).
        NotObservableError: the views do not determine the focal length (the best ``f`` is at an end
            of the searched range: boards too small or only near the image centre).
    """
    if len(points_target) == 0 or len(points_target) != len(pixels):
        raise BadInputError(
            f"fisheye start: expected one array of pixels per view and at least one view, got "
            f"{len(points_target)} views of target points and {len(pixels)} of pixels"
        )
    labels = [f"view {view_names[i]!r}" if view_names is not None else f"view {i}" for i in range(len(pixels))]
    pts = [_check_view(p, q, label) for p, q, label in zip(points_target, pixels, labels)]
    pix = [np.asarray(q, np.float64) for q in pixels]
    w, h = image_size
    centre = np.asarray(principal_point if principal_point is not None else ((w - 1) / 2.0, (h - 1) / 2.0), np.float64)
    r_max = max(float(np.max(np.linalg.norm(q - centre, axis=1))) for q in pix)
    if not r_max > 0.0:
        raise BadInputError("fisheye start: every observed pixel is at the principal point")
    num = sum(len(q) for q in pix)

    def rms(f: float) -> float:
        total = 0.0
        for p, q in zip(pts, pix):
            b = _equidistant_bearings(q, centre, f)
            total += float(np.sum(_angles(bearing_homography(p, b), p, b) ** 2))
        return f * math.sqrt(total / num)

    lo = r_max / math.pi * (1.0 + 1e-9)
    grid = np.geomspace(lo, FOCAL_GRID_MAX * max(r_max, 0.5 * math.hypot(w, h)), FOCAL_GRID_POINTS)
    costs = np.array([rms(float(f)) for f in grid])
    i = int(np.argmin(costs))
    if i in (0, len(grid) - 1):
        raise NotObservableError(
            f"fisheye start: the views do not determine the focal length (the best equidistant focal length "
            f"is at the end of the searched range {grid[0]:.4g}..{grid[-1]:.4g} px); spread the board over the "
            "whole image, near its rim too, and tilt it between views",
            ["fx", "fy"],
        )
    # golden-section search on log f inside the grid bracket
    a, c = math.log(grid[i - 1]), math.log(grid[i + 1])
    g = (math.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = c - g * (c - a), a + g * (c - a)
    f1, f2 = rms(math.exp(x1)), rms(math.exp(x2))
    for _ in range(GOLDEN_ITERATIONS):
        if f1 <= f2:
            c, x2, f2 = x2, x1, f1
            x1 = c - g * (c - a)
            f1 = rms(math.exp(x1))
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (c - a)
            f2 = rms(math.exp(x2))
    f, best = (math.exp(x1), f1) if f1 <= f2 else (math.exp(x2), f2)
    if best > costs[i]:
        f, best = float(grid[i]), float(costs[i])
    poses = [bearing_pose(p, _equidistant_bearings(q, centre, f)) for p, q in zip(pts, pix)]
    K = np.array([[f, 0.0, centre[0]], [0.0, f, centre[1]], [0.0, 0.0, 1.0]])
    return FisheyeInit(K=K, D=np.zeros(4), T_cam_target=poses, rms_px=float(best),
                       focal_grid=np.column_stack([grid, costs]))
