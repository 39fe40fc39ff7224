"""Zoom and focus lenses: a camera's intrinsics and the axial shift of its frame as smooth functions of a
lens setting (GenICam ``Zoom``, ``Focus``, ``FocusPosition``: a motor position).

The setting ``s`` is normalised over the calibrated range, ``u = (s − lo) / (hi − lo)`` (0 at the lowest
calibrated setting, 1 at the highest). Every function is a clamped B-spline of ``degree`` with ``knots``
uniform interior knots in ``u`` (``degree + 1 + knots`` control points; ``knots = 0`` is a polynomial of
``degree`` in Bernstein form). Outside ``[0, 1]`` the end pieces' polynomials continue (extrapolation).

The splined quantities are the *transformed* intrinsics ``q = (log fx, log fy, cx, cy, k1, ...)`` (a zoom
lens's focal length varies about geometrically with its motor position, ``f ∝ r^u``, which is linear in
``log f``) and the shift ``d`` (m) of the camera frame along its optical axis (the entrance pupil moves with
the zoom): the camera at ``u`` is ``T_<holder>_<cam>(u) = T_<holder>_<cam> · Trans(0, 0, d(u))``, so
``p_cam(u) = p_cam − d(u) e_z``.

Parameterisation (the unknowns of the one builder): the first control point row is the camera's ordinary
intrinsic vector at ``u = 0`` (``intrinsics:<cam>``, transformed) with ``d = 0`` (the gauge: the camera's
pose on its holder is the camera frame at the lowest calibrated setting); the other rows
(``lens:<cam>``, ``(nb − 1) · (P + 1)`` values, row-major, columns ``q`` then ``d``) are free.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

#: Default spline of a lens function: a cubic (4 control points), enough for a 6x zoom's log focal
#: length, principal point drift, distortion and pupil shift with 6-10 captured settings.
DEFAULT_DEGREE = 3
DEFAULT_KNOTS = 0

#: Name of the axial shift among a lens function's columns (after the intrinsic names).
SHIFT = "shift_m"


def num_control_points(degree: int, knots: int) -> int:
    """Number of control points (basis functions) of a clamped B-spline."""
    return int(degree) + 1 + int(knots)


def knot_vector(degree: int, knots: int) -> np.ndarray:
    """``(nb + degree + 1,)`` clamped uniform knot vector on ``[0, 1]``."""
    inner = np.linspace(0.0, 1.0, int(knots) + 2)[1:-1]
    return np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])


def basis(u, degree: int = DEFAULT_DEGREE, knots: int = DEFAULT_KNOTS) -> np.ndarray:
    """``(n, nb)`` B-spline basis at normalised settings ``u`` ``(n,)`` (NumPy; rows sum to one).

    The Cox–de Boor recursion on the span of each ``u`` (NURBS book A2.2); outside ``[0, 1]`` the end
    span's polynomial continues.
    """
    u = np.atleast_1d(np.asarray(u, np.float64))
    p, U = int(degree), knot_vector(degree, knots)
    nb = num_control_points(degree, knots)
    span = np.clip(np.searchsorted(U, u, side="right") - 1, p, nb - 1)
    N = np.zeros((u.size, p + 1))
    N[:, 0] = 1.0
    left = np.zeros((u.size, p + 1))
    right = np.zeros((u.size, p + 1))
    for j in range(1, p + 1):
        left[:, j] = u - U[span + 1 - j]
        right[:, j] = U[span + j] - u
        saved = np.zeros(u.size)
        for r in range(j):
            temp = N[:, r] / (right[:, r + 1] + left[:, j - r])
            N[:, r] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        N[:, j] = saved
    out = np.zeros((u.size, nb))
    rows = np.arange(u.size)[:, None]
    out[rows, span[:, None] - p + np.arange(p + 1)[None, :]] = N
    return out


def to_transformed(params):
    """Intrinsics ``(..., P)`` (``fx, fy`` first) -> ``(log fx, log fy, cx, ...)``."""
    return jnp.concatenate([jnp.log(params[..., :2]), params[..., 2:]], axis=-1)


def from_transformed(q):
    """Inverse of :func:`to_transformed`."""
    return jnp.concatenate([jnp.exp(q[..., :2]), q[..., 2:]], axis=-1)


def control_points(intrinsics, lens):
    """``(nb, P + 1)`` control points (transformed intrinsics and shift) from the camera's intrinsics at
    ``u = 0`` ``(P,)`` and the free rows ``lens`` ``((nb − 1) (P + 1),)``."""
    P = intrinsics.shape[-1]
    first = jnp.concatenate([to_transformed(intrinsics), jnp.zeros((1,), intrinsics.dtype)])
    return jnp.concatenate([first[None, :], lens.reshape(-1, P + 1)], axis=0)


def lens_at(intrinsics, lens, b):
    """``(params (P,), shift_m ())`` at the setting whose basis row is ``b`` ``(nb,)`` (jnp, traceable)."""
    q = b @ control_points(intrinsics, lens)
    return from_transformed(q[:-1]), q[-1]


def fit_control_points(u, params, shifts=None, degree: int = DEFAULT_DEGREE, knots: int = DEFAULT_KNOTS):
    """Least-squares control points ``(nb, P + 1)`` through per-setting intrinsics ``params (n, P)`` at
    normalised settings ``u (n,)`` (and shifts ``(n,)``, default 0), the first row's shift pinned at 0
    (NumPy; the closed-form start of a lens)."""
    u = np.asarray(u, np.float64)
    params = np.asarray(params, np.float64)
    shifts = np.zeros(u.size) if shifts is None else np.asarray(shifts, np.float64)
    B = basis(u, degree, knots)
    Q = np.concatenate([np.asarray(to_transformed(jnp.asarray(params))), shifts[:, None]], axis=1)
    ctrl = np.linalg.lstsq(B, Q, rcond=None)[0]
    # the shift is relative to the first control point (the gauge): refit its column with it pinned
    ctrl[:, -1] = 0.0
    if B.shape[1] > 1:
        ctrl[1:, -1] = np.linalg.lstsq(B[:, 1:], shifts, rcond=None)[0]
    return ctrl


def _stacked(intrinsics, lens, b):
    p, d = lens_at(intrinsics, lens, b)
    return jnp.concatenate([p, d[None]])


@jax.jit
def _value_and_jacobian(intrinsics, lens, b):
    """``(y (P + 1,), ∂y/∂intrinsics, ∂y/∂lens)`` of ``y = (params, shift)`` at basis row ``b`` (compiled once
    per shape)."""
    Ji, Jl = jax.jacfwd(_stacked, argnums=(0, 1))(intrinsics, lens, b)
    return _stacked(intrinsics, lens, b), Ji, Jl


@dataclass(frozen=True)
class LensFunction:
    """A calibrated lens: its functions of one setting and their covariance (NumPy in, NumPy out).

    Attributes:
        setting: the GenICam feature (``"Zoom"``); range_: ``(lo, hi)`` the calibrated range of it.
        degree, knots: the spline (:func:`basis`).
        param_names: the intrinsic names (the camera model's order).
        intrinsics: ``(P,)`` the camera at the lowest calibrated setting; lens: ``((nb − 1)(P + 1),)``.
        covariance: ``(P + L + 6, P + L + 6)`` over ``(intrinsics, lens, mount tangent)`` (the mount's
            right perturbation rx..tz, rad and m), or None.
        mount: ``(4, 4)`` the camera's pose on its holder at the lowest calibrated setting (m), or None.
    """

    setting: str
    range_: tuple[float, float]
    degree: int
    knots: int
    param_names: tuple[str, ...]
    intrinsics: np.ndarray
    lens: np.ndarray
    covariance: np.ndarray | None = None
    mount: np.ndarray | None = None

    def normalise(self, value) -> np.ndarray:
        lo, hi = self.range_
        return (np.asarray(value, np.float64) - lo) / (hi - lo)

    def inside(self, value, tol: float = 1e-9) -> bool:
        u = float(self.normalise(value))
        return -tol <= u <= 1.0 + tol

    def control_points(self) -> np.ndarray:
        return np.asarray(control_points(jnp.asarray(self.intrinsics), jnp.asarray(self.lens)))

    def at(self, value) -> dict:
        """The camera at a setting: ``params (P,)``, ``shift_m``, ``params_covariance (P, P)``,
        ``shift_std_m``, and with a mount ``mount (4, 4)`` and ``mount_covariance (6, 6)`` (right
        perturbation of the camera frame at that setting). Covariances are None without one."""
        b = jnp.asarray(basis(self.normalise([float(value)]), self.degree, self.knots)[0])
        intr, lens = jnp.asarray(self.intrinsics), jnp.asarray(self.lens)
        y, Ji, Jl = (np.asarray(a) for a in _value_and_jacobian(intr, lens, b))
        P, L = intr.size, lens.size
        out = {"params": y[:P], "shift_m": float(y[P])}
        J = None
        if self.covariance is not None:
            J = np.concatenate([Ji, Jl], axis=1)  # (P + 1, P + L)
            C = np.asarray(self.covariance)[: P + L, : P + L]
            Cy = J @ C @ J.T
            out["params_covariance"] = Cy[:P, :P]
            out["shift_std_m"] = float(np.sqrt(max(Cy[P, P], 0.0)))
        else:
            out["params_covariance"], out["shift_std_m"] = None, None
        if self.mount is not None:
            d = out["shift_m"]
            shift = np.eye(4)
            shift[2, 3] = d
            out["mount"] = np.asarray(self.mount, np.float64) @ shift
            out["mount_covariance"] = None
            if J is not None:
                # T Exp(δ) Tz(d + ε) = T Tz(d) Exp(Ad_{Tz(−d)} δ + ε e_tz): Ad of a translation t = −d e_z
                # maps (ω, v) to (ω, v + t × ω)
                t = np.array([0.0, 0.0, -d])
                tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
                A = np.zeros((6, P + L + 6))
                A[:3, P + L:P + L + 3] = np.eye(3)
                A[3:, P + L:P + L + 3] = tx
                A[3:, P + L + 3:] = np.eye(3)
                A[5, : P + L] += J[P]
                out["mount_covariance"] = A @ np.asarray(self.covariance) @ A.T
        return out
