"""Work-object (user / base) frames from touched points, with covariance.

**Three-point convention** (:func:`frame_from_three_points`), as KUKA's "BASE 3-point" and ABB's
user-frame "3 points" (X1, X2, Y1) methods use it:

1. ``p_origin``: the origin of the frame;
2. ``p_x``: a point on the **+X** axis (the X axis points from the origin towards it);
3. ``p_xy``: any point in the X-Y plane on the **+Y** side (it need not be on the Y axis).

Then ``x = unit(p_x - p_origin)``, ``z = unit(x × (p_xy - p_origin))``, ``y = z × x`` (right-handed),
origin ``p_origin``. Some ABB documentation instead places the origin at the foot of the perpendicular
from ``Y1`` onto the X1-X2 line; ``origin="foot"`` gives that variant. Check which one your controller
uses before comparing numbers with it.

**N-point fit** (:func:`frame_from_points`): a plane fitted to all points (least squares, the
smallest-eigenvalue direction of their scatter matrix = the SVD plane fit) gives Z; X is the in-plane
direction from a designated origin point to a designated X point (default: the first to the second
point); the sign of Z is chosen so a designated Y point (default the third) lies on the +Y side; the
origin is the designated origin point projected onto the plane. With three points it is the
three-point method.

**Covariance**: the 6x6 covariance of the frame ``T_base_wobj`` in the tangent order
``(rx, ry, rz, tx, ty, tz)`` (rad, m), right perturbation ``T . Exp(delta)`` (see
:mod:`jcalib.geometry.lie`), by linear propagation of the point covariances through the construction
(a JAX Jacobian of the construction with respect to the points). It includes the touching noise
given as point covariances only; not TCP error, robot accuracy or an object that is not flat.

Degenerate input raises :class:`jcalib.errors.NotObservableError`: (nearly) collinear points leave the
rotation about the line through the points undetermined; an X point at the origin leaves the X
direction undetermined; a Y point on the X axis leaves the side of +Y undetermined.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import make_pose

__all__ = [
    "DEFAULT_MIN_ANGLE_DEG",
    "FrameResult",
    "frame_from_points",
    "frame_from_three_points",
]

#: Smallest accepted angle (degrees) between the directions from the origin to the X point and to
#: the Y point (three points), or ``atan`` of the ratio of the points' spread across and along their
#: best-fit line (N points). Below it the points count as collinear.
DEFAULT_MIN_ANGLE_DEG = 1.0


@dataclass(frozen=True)
class FrameResult:
    """A work-object frame ``T_base_wobj`` and its uncertainty.

    Attributes:
        T_base_wobj: ``(4, 4)`` the frame in the base frame (maps wobj points to base), metres.
        covariance: ``(6, 6)`` in ``(rx, ry, rz, tx, ty, tz)`` (rad, m), right perturbation, or None
            when no point covariance was given. Point (touching) noise only.
        jacobian: ``(6, 3N)`` derivative of the frame's tangent (same order) with respect to the
            stacked point coordinates ``(p_0x, p_0y, p_0z, p_1x, ...)``.
        plane_residuals: ``(N,)`` signed distances of the points from the frame's X-Y plane (m).
        rms: RMS of ``plane_residuals`` (m); zero for three points.
    """

    T_base_wobj: np.ndarray
    covariance: np.ndarray | None
    jacobian: np.ndarray
    plane_residuals: np.ndarray
    rms: float

    @property
    def std(self) -> np.ndarray | None:
        """``(6,)`` standard deviations ``(rx, ry, rz, tx, ty, tz)`` (rad, m), or None."""
        return None if self.covariance is None else np.sqrt(np.diag(self.covariance))


# --------------------------------------------------------------------------------------------- constructions


def _unit(v: jax.Array) -> jax.Array:
    return v / jnp.linalg.norm(v)


def _three_point(P: jax.Array, foot: bool) -> tuple[jax.Array, jax.Array]:
    p0, p1, p2 = P[0], P[1], P[2]
    x = _unit(p1 - p0)
    z = _unit(jnp.cross(x, p2 - p0))
    y = jnp.cross(z, x)
    o = p0 + x * jnp.dot(p2 - p0, x) if foot else p0
    return jnp.stack([x, y, z], axis=1), o


def _plane_fit(P: jax.Array, idx: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``idx = (origin_index, x_index, y_index)`` (traced: no recompilation per choice)."""
    origin_index, x_index, y_index = idx[0], idx[1], idx[2]
    c = jnp.mean(P, axis=0, keepdims=True)
    Q = P - c
    _, evecs = jnp.linalg.eigh(Q.T @ Q)
    n = evecs[:, 0]
    po = P[origin_index]
    o = po - n * jnp.dot(po - c[0], n)
    v = P[x_index] - po
    x = _unit(v - n * jnp.dot(v, n))
    side = jnp.dot(jnp.cross(x, P[y_index] - po), n)
    z = n * jnp.where(side >= 0.0, 1.0, -1.0)
    y = jnp.cross(z, x)
    return jnp.stack([x, y, z], axis=1), o


@partial(jax.jit, static_argnums=(0, 1))
def _frame_and_jacobian(kind: str, foot: bool, P: jax.Array, idx: jax.Array):
    def build(Pv):
        return _three_point(Pv, foot) if kind == "three" else _plane_fit(Pv, idx)

    R, o = build(P)

    def tangent(Pv):
        Rv, ov = build(Pv)
        M = R.T @ Rv  # I + [omega]x to first order
        omega = 0.5 * jnp.stack([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
        return jnp.concatenate([omega, R.T @ (ov - o)])

    J = jax.jacfwd(tangent)(P).reshape(6, -1)
    return R, o, J


# --------------------------------------------------------------------------------------------- input checks


def _points(P, name: str, n: int | None = None) -> np.ndarray:
    arr = np.asarray(P, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n) or arr.shape[0] < 3:
        want = f"({n}, 3)" if n is not None else "(N, 3) with N >= 3"
        raise BadInputError(f"{name}: expected points of shape {want} (m), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise BadInputError(f"{name}: contain NaN/inf; expected finite coordinates")
    return arr


def _point_covariance(cov, n: int) -> np.ndarray | None:
    """``None``, a scalar sigma (m), ``(3, 3)``, ``(N, 3, 3)`` or ``(3N, 3N)`` -> ``(3N, 3N)``."""
    if cov is None:
        return None
    c = np.asarray(cov, dtype=np.float64)
    if c.ndim == 0:
        if not (np.isfinite(c) and c > 0):
            raise BadInputError(f"covariance: a scalar is read as sigma per coordinate (m) and must be > 0, got {c}")
        return float(c) ** 2 * np.eye(3 * n)
    if c.shape == (3, 3):
        full = np.kron(np.eye(n), c)
    elif c.shape == (n, 3, 3):
        full = np.zeros((3 * n, 3 * n))
        for i in range(n):
            full[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = c[i]
    elif c.shape == (3 * n, 3 * n):
        full = c
    else:
        raise BadInputError(
            f"covariance: expected a sigma (m), (3, 3), ({n}, 3, 3) or ({3 * n}, {3 * n}) (m^2), got shape {c.shape}"
        )
    if not np.isfinite(full).all() or np.abs(full - full.T).max() > 1e-12 * max(np.abs(full).max(), 1e-300):
        raise BadInputError("covariance: expected finite, symmetric point covariances (m^2)")
    return full


def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{c:.4f}" for c in v) + "]"


def _collinear_error(direction: np.ndarray, angle_deg: float, limit: float) -> NotObservableError:
    unknown = f"rotation about the line through the points (direction {_fmt(direction)} in the base frame)"
    return NotObservableError(
        f"work-object frame: the points are (nearly) collinear ({angle_deg:.3g} deg < {limit} deg): not "
        f"observable: {unknown}. Touch a point well off the line.",
        unknowns=[unknown],
    )


def _result(R, o, J, P: np.ndarray, cov: np.ndarray | None) -> FrameResult:
    R, o, J = np.asarray(R), np.asarray(o), np.asarray(J)
    T = make_pose(R, o)
    resid = (P - o) @ R[:, 2]
    out_cov = None
    if cov is not None:
        out_cov = J @ cov @ J.T
        out_cov = 0.5 * (out_cov + out_cov.T)
    return FrameResult(T, out_cov, J, resid, float(np.sqrt(np.mean(resid**2))))


# --------------------------------------------------------------------------------------------- public


def frame_from_three_points(
    p_origin,
    p_x,
    p_xy,
    covariance=None,
    origin: str = "first",
    min_angle_deg: float = DEFAULT_MIN_ANGLE_DEG,
) -> FrameResult:
    """A work-object frame from the 3-point convention (origin, +X point, +Y-side point).

    Args:
        p_origin: ``(3,)`` origin, base frame (m).
        p_x: ``(3,)`` a point on the +X axis (m).
        p_xy: ``(3,)`` a point in the X-Y plane on the +Y side (m).
        covariance: noise of the three points: a sigma per coordinate (m), a shared ``(3, 3)``,
            per point ``(3, 3, 3)`` or joint ``(9, 9)`` (m^2); None for no covariance.
        origin: ``"first"`` (origin at ``p_origin``; KUKA, ABB's X1) or ``"foot"`` (origin at the
            foot of the perpendicular from ``p_xy`` onto the X axis).
        min_angle_deg: smallest accepted angle at ``p_origin`` between the X and Y points.

    Returns:
        :class:`FrameResult`.

    Raises:
        BadInputError: malformed points or covariance, unknown ``origin``.
        NotObservableError: ``p_x`` at the origin, or collinear points.
    """
    rows = []
    for name, p in (("p_origin", p_origin), ("p_x", p_x), ("p_xy", p_xy)):
        arr = np.asarray(p, dtype=np.float64)
        if arr.shape != (3,):
            raise BadInputError(f"{name}: expected a point of shape (3,) (m), got {arr.shape}")
        rows.append(arr)
    P = _points(np.stack(rows), "p_origin, p_x, p_xy", 3)
    if origin not in ("first", "foot"):
        raise BadInputError(f"origin: expected 'first' or 'foot', got {origin!r}")
    cov = _point_covariance(covariance, 3)
    v1, v2 = P[1] - P[0], P[2] - P[0]
    scale = max(np.linalg.norm(v1), np.linalg.norm(v2), np.abs(P).max(), 1e-300)
    if np.linalg.norm(v1) <= 1e-12 * scale:
        raise NotObservableError(
            "work-object frame: p_x coincides with p_origin: the X axis direction is not determined",
            unknowns=["X axis direction (p_x at the origin)"],
        )
    if np.linalg.norm(v2) <= 1e-12 * scale:
        raise _collinear_error(v1 / np.linalg.norm(v1), 0.0, min_angle_deg)
    sin = np.linalg.norm(np.cross(v1, v2)) / (np.linalg.norm(v1) * np.linalg.norm(v2))
    if sin < np.sin(np.deg2rad(min_angle_deg)):
        raise _collinear_error(v1 / np.linalg.norm(v1), np.rad2deg(np.arcsin(min(sin, 1.0))), min_angle_deg)
    R, o, J = _frame_and_jacobian("three", origin == "foot", jnp.asarray(P), jnp.zeros(3, dtype=jnp.int32))
    return _result(R, o, J, P, cov)


def frame_from_points(
    points,
    origin_index: int = 0,
    x_index: int = 1,
    y_index: int = 2,
    covariance=None,
    min_angle_deg: float = DEFAULT_MIN_ANGLE_DEG,
) -> FrameResult:
    """A work-object frame from N >= 3 points in one plane (plane fit + designated X direction).

    Args:
        points: ``(N, 3)`` touched points, base frame (m).
        origin_index: the point whose projection onto the plane is the origin.
        x_index: the point giving +X (the in-plane direction from the origin point to it).
        y_index: a point on the +Y side (fixes the sign of the plane normal, Z).
        covariance: point noise: a sigma per coordinate (m), a shared ``(3, 3)``, per point
            ``(N, 3, 3)`` or joint ``(3N, 3N)`` (m^2); None for no covariance.
        min_angle_deg: collinearity limit (see :data:`DEFAULT_MIN_ANGLE_DEG`).

    Returns:
        :class:`FrameResult` (``plane_residuals`` are the plane-fit residuals).

    Raises:
        BadInputError: malformed points, indices or covariance.
        NotObservableError: collinear points, X point at the origin (across the plane), or a Y point
            on the X axis.
    """
    P = _points(points, "points")
    n = P.shape[0]
    idx = (origin_index, x_index, y_index)
    names = ("origin_index", "x_index", "y_index")
    for name, i in zip(names, idx, strict=True):
        if not isinstance(i, (int, np.integer)) or not 0 <= i < n:
            raise BadInputError(f"{name}: expected an int in [0, {n}), got {i!r}")
    if len(set(int(i) for i in idx)) != 3:
        raise BadInputError(f"origin_index, x_index, y_index: expected three different points, got {idx}")
    cov = _point_covariance(covariance, n)
    c = P.mean(axis=0)
    _, s, vt = np.linalg.svd(P - c)
    limit = np.deg2rad(min_angle_deg)
    if s[0] == 0.0 or np.arctan2(s[1], s[0]) < limit:
        raise _collinear_error(vt[0], float(np.rad2deg(np.arctan2(s[1], s[0]))), min_angle_deg)
    normal = vt[2]
    v = P[x_index] - P[origin_index]
    v_in = v - normal * (v @ normal)
    if np.linalg.norm(v_in) <= 1e-9 * s[0]:
        raise NotObservableError(
            "work-object frame: the X point projects onto the origin point: the X axis direction is not determined",
            unknowns=["X axis direction (x_index point at the origin)"],
        )
    w = P[y_index] - P[origin_index]
    side = np.cross(v_in / np.linalg.norm(v_in), w) @ normal
    if abs(side) < np.sin(limit) * max(np.linalg.norm(w), 1e-300):
        raise NotObservableError(
            "work-object frame: the Y point lies on the X axis: the side of +Y (the sign of Z) is not determined",
            unknowns=["direction of +Y (sign of the plane normal)"],
        )
    R, o, J = _frame_and_jacobian("plane", False, jnp.asarray(P), jnp.asarray([int(i) for i in idx], dtype=jnp.int32))
    return _result(R, o, J, P, cov)
