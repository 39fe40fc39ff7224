"""SO(3) and SE(3) kernels generic over the array module: ``xp`` is ``numpy`` or ``jax.numpy``.

The algebra behind :mod:`jcalib.geometry.lie` (its JAX API wraps these with shape checks) and
:mod:`jcalib.geometry.conversions` (NumPy in gives NumPy out, without going through JAX). Layouts as
in :mod:`jcalib.geometry.lie`: quaternions ``(..., 4)`` ``wxyz``, poses ``(..., 7)`` = quaternion then
translation, SE(3) tangents ``(omega, v) (..., 6)``. Every function assumes float64 inputs of the
right trailing shape and checks nothing; leading axes must already agree. Nothing here imports JAX.
"""

from __future__ import annotations

__all__ = [
    "SMALL_ANGLE_SQ",
    "cross",
    "dot",
    "matrix_to_quat",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_normalize_sign",
    "quat_rotate",
    "quat_to_matrix",
    "se3_compose",
    "se3_exp",
    "se3_from_matrix",
    "se3_inverse",
    "se3_log",
    "se3_right_jacobian_inverse",
    "se3_to_matrix",
    "skew",
    "so3_exp",
    "so3_right_jacobian_inverse",
    "so3_log",
    "so3_log_parts",
]

#: Below this squared angle (rad^2), i.e. angle < 1e-2 rad, the coefficient functions use Taylor
#: series. The series are kept to a degree whose first dropped term is < 1e-20 there, and the
#: closed forms above it lose at most ~1e-12 (relative) of a derivative to cancellation.
SMALL_ANGLE_SQ = 1e-4


def cross(a, b, xp):
    """Cross products ``a x b`` of ``(..., 3)`` vectors."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return xp.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def skew(v, xp):
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(a) b = a x b``."""
    z = xp.zeros_like(v[..., 0])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return xp.stack([xp.stack([z, -w, y], -1), xp.stack([w, z, -x], -1), xp.stack([-y, x, z], -1)], axis=-2)


def dot(a, b, xp):
    """Dot products of ``(..., n)`` vectors over the last axis."""
    return xp.sum(a * b, axis=-1)


def _safe_sqrt_and_small(x_sq, xp):
    """sqrt(x_sq) where x_sq >= threshold, 1.0 elsewhere (a safe value for the untaken branch)."""
    small = x_sq < SMALL_ANGLE_SQ
    return xp.sqrt(xp.where(small, 1.0, x_sq)), small


def quat_normalize(q, xp):
    """Quaternions ``(..., 4)`` scaled to unit norm (sign kept)."""
    return q / xp.sqrt(xp.sum(q * q, axis=-1))[..., None]


def quat_normalize_sign(q, xp):
    """Quaternions ``(..., 4)`` ``wxyz`` flipped so that ``w >= 0`` (same rotation)."""
    return xp.where((q[..., 0] < 0.0)[..., None], -q, q)


def quat_multiply(p, q, xp):
    """Hamilton product ``p * q`` of ``wxyz`` quaternions ``(..., 4)``."""
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conjugate(q, xp):
    """Conjugate (the inverse of a unit quaternion) of ``wxyz`` quaternions ``(..., 4)``."""
    return xp.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_rotate(q, p, xp):
    """R(q) p for a unit quaternion: p + 2w (u x p) + 2 u x (u x p)."""
    w, u = q[..., :1], q[..., 1:]
    uxp = cross(u, p, xp)
    return p + 2.0 * w * uxp + 2.0 * cross(u, uxp, xp)


def quat_to_matrix(q, xp):
    """Rotation matrices ``(..., 3, 3)`` of ``wxyz`` quaternions ``(..., 4)`` (normalised first)."""
    q = quat_normalize(q, xp)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
        [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
        [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)],
    ]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat(m, xp):
    """Shepperd's method: pick the best-conditioned of four formulas; unit, sign-normalised (w >= 0).

    The selected pivot t is the largest of four numbers that sum to 4, so t >= 1 and the square
    root never sees a small or negative number (finite gradients everywhere).
    """
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    t = xp.stack(
        [
            1.0 + m00 + m11 + m22,
            1.0 + m00 - m11 - m22,
            1.0 - m00 + m11 - m22,
            1.0 - m00 - m11 + m22,
        ],
        axis=-1,
    )
    cand = xp.stack(
        [
            xp.stack([t[..., 0], m21 - m12, m02 - m20, m10 - m01], axis=-1),
            xp.stack([m21 - m12, t[..., 1], m10 + m01, m02 + m20], axis=-1),
            xp.stack([m02 - m20, m10 + m01, t[..., 2], m21 + m12], axis=-1),
            xp.stack([m10 - m01, m02 + m20, m21 + m12, t[..., 3]], axis=-1),
        ],
        axis=-2,
    )  # (..., 4 candidates, 4)
    k = xp.argmax(t, axis=-1)
    onehot = xp.stack([k == i for i in range(4)], axis=-1).astype(t.dtype)
    t_sel = xp.sum(onehot * t, axis=-1)
    q_sel = xp.sum(onehot[..., None] * cand, axis=-2)
    q = q_sel * (0.5 / xp.sqrt(t_sel))[..., None]
    return quat_normalize_sign(quat_normalize(q, xp), xp)


def so3_exp(omega, xp):
    """Exponential map of SO(3): rotation vectors ``(..., 3)`` (rad) to quaternions ``(..., 4)``."""
    theta_sq = dot(omega, omega, xp)
    theta, small = _safe_sqrt_and_small(theta_sq, xp)
    t2, t4, t6 = theta_sq, theta_sq * theta_sq, theta_sq * theta_sq * theta_sq
    real = xp.where(small, 1.0 - t2 / 8.0 + t4 / 384.0 - t6 / 46080.0, xp.cos(0.5 * theta))
    imag = xp.where(
        small, 0.5 - t2 / 48.0 + t4 / 3840.0 - t6 / 645120.0, xp.sin(0.5 * theta) / theta
    )
    return xp.concatenate([real[..., None], imag[..., None] * omega], axis=-1)


def so3_log_parts(q, xp):
    """Return (omega, theta_sq, half_theta_cot, small) for a quaternion; |omega| <= pi.

    ``half_theta_cot`` is (theta/2) cot(theta/2), needed by the SE(3) log; ``small`` flags
    sin(theta/2) < 1e-2 (theta < 0.02 rad), where series replace the closed forms.
    """
    q = quat_normalize_sign(quat_normalize(q, xp), xp)
    w, u = q[..., 0], q[..., 1:]
    n_sq = dot(u, u, xp)
    n, small = _safe_sqrt_and_small(n_sq, xp)
    # 2 atan(n / w) / n, by series in x^2 = n^2 / w^2 when n < 1e-2 (then w > 0.9999).
    w_safe = xp.where(small, w, 1.0)
    x2 = n_sq / (w_safe * w_safe)
    series = (2.0 / w_safe) * (1.0 - x2 / 3.0 + x2 * x2 / 5.0 - x2 * x2 * x2 / 7.0 + x2**4 / 9.0)
    half_theta = xp.arctan2(n, w)
    factor = xp.where(small, series, 2.0 * half_theta / n)
    omega = factor[..., None] * u
    theta_sq = dot(omega, omega, xp)
    half_theta_cot = xp.where(small, 1.0, half_theta * w / n)  # only used where not small
    return omega, theta_sq, half_theta_cot, small


def so3_log(q, xp):
    """Logarithm of SO(3): quaternions ``(..., 4)`` to rotation vectors ``(..., 3)``, ``|.| <= pi``."""
    return so3_log_parts(q, xp)[0]


def se3_exp(delta, xp):
    """Exponential map of SE(3): tangents ``(omega, v) (..., 6)`` (rad, m) to poses ``(..., 7)``."""
    omega, v = delta[..., :3], delta[..., 3:]
    q = so3_exp(omega, xp)
    theta_sq = dot(omega, omega, xp)
    theta, small = _safe_sqrt_and_small(theta_sq, xp)
    t2, t4, t6 = theta_sq, theta_sq * theta_sq, theta_sq * theta_sq * theta_sq
    s_half = xp.sin(0.5 * theta)
    # B = (1 - cos)/theta^2 = 2 sin^2(theta/2)/theta^2 ; C = (theta - sin)/theta^3
    b = xp.where(
        small, 0.5 - t2 / 24.0 + t4 / 720.0 - t6 / 40320.0, 2.0 * s_half * s_half / (theta * theta)
    )
    c = xp.where(
        small,
        1.0 / 6.0 - t2 / 120.0 + t4 / 5040.0 - t6 / 362880.0,
        (theta - xp.sin(theta)) / (theta * theta * theta),
    )
    wxv = cross(omega, v, xp)
    t = v + b[..., None] * wxv + c[..., None] * cross(omega, wxv, xp)
    return xp.concatenate([q, t], axis=-1)


def se3_log(pose, xp):
    """Logarithm of SE(3): poses ``(..., 7)`` to tangents ``(omega, v) (..., 6)``."""
    omega, theta_sq, htc, small = so3_log_parts(pose[..., :4], xp)
    t = pose[..., 4:]
    theta_sq_safe = xp.where(small, 1.0, theta_sq)
    t2, t4, t6 = theta_sq, theta_sq * theta_sq, theta_sq * theta_sq * theta_sq
    # D = (1 - (theta/2) cot(theta/2)) / theta^2, so that V^-1 = I - 1/2 [w]x + D [w]x^2.
    # The series runs to theta < 0.02 rad here; its first dropped term is < 1e-20.
    d = xp.where(
        small,
        1.0 / 12.0 + t2 / 720.0 + t4 / 30240.0 + t6 / 1209600.0,
        (1.0 - htc) / theta_sq_safe,
    )
    wxt = cross(omega, t, xp)
    v = t - 0.5 * wxt + d[..., None] * cross(omega, wxt, xp)
    return xp.concatenate([omega, v], axis=-1)


def se3_compose(a, b, xp):
    """Composition ``a . b`` of poses ``(..., 7)``."""
    q = quat_multiply(a[..., :4], b[..., :4], xp)
    t = a[..., 4:] + quat_rotate(a[..., :4], b[..., 4:], xp)
    return xp.concatenate([q, t], axis=-1)


def se3_inverse(a, xp):
    """Inverse of unit-quaternion poses ``(..., 7)``."""
    qi = quat_conjugate(a[..., :4], xp)
    return xp.concatenate([qi, -quat_rotate(qi, a[..., 4:], xp)], axis=-1)


def se3_to_matrix(pose, xp):
    """4x4 homogeneous matrices ``(..., 4, 4)`` of poses ``(..., 7)``."""
    r = quat_to_matrix(pose[..., :4], xp)
    top = xp.concatenate([r, pose[..., 4:, None]], axis=-1)
    bottom = xp.broadcast_to(xp.asarray([0.0, 0.0, 0.0, 1.0]), top.shape[:-2] + (1, 4))
    return xp.concatenate([top, bottom], axis=-2)


def se3_from_matrix(mat, xp):
    """Poses ``(..., 7)`` (``w >= 0``) of 4x4 homogeneous matrices ``(..., 4, 4)`` (bottom row not read)."""
    return xp.concatenate([matrix_to_quat(mat[..., :3, :3], xp), mat[..., :3, 3]], axis=-1)


#: Below this squared angle (rad^2, angle < 0.1 rad) the SE(3) Jacobian's coefficients use series to
#: theta^6 (first dropped term < 1e-16 relative); above it the closed forms lose at most ~1e-10 of the
#: (theta^3-sized) terms they multiply to cancellation.
_JACOBIAN_SERIES_SQ = 1e-2


def _jr_inverse_d(t2, small, xp):
    """``D = (1 - (theta/2) cot(theta/2)) / theta^2`` (series below ``_JACOBIAN_SERIES_SQ``)."""
    t2s = xp.where(small, 1.0, t2)
    half = 0.5 * xp.sqrt(t2s)
    return xp.where(small, 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0 + t2 * t2 * t2 / 1209600.0,
                    (1.0 - half * xp.cos(half) / xp.sin(half)) / t2s)


def so3_right_jacobian_inverse(omega, xp):
    """``J_r(omega)^-1 = I + W/2 + D W^2 (..., 3, 3)``: ``Log(Exp(omega) Exp(d)) = omega + J_r^-1 d + O(d^2)``."""
    t2 = dot(omega, omega, xp)
    W = skew(omega, xp)
    d = _jr_inverse_d(t2, t2 < _JACOBIAN_SERIES_SQ, xp)
    return xp.broadcast_to(xp.eye(3), W.shape) + 0.5 * W + d[..., None, None] * (W @ W)


def se3_right_jacobian_inverse(xi, xp):
    """``J_r(xi)^-1 (..., 6, 6)`` of tangents ``xi = (omega, v) (..., 6)``: ``Log(Exp(xi) Exp(d)) = xi +
    J_r(xi)^-1 d + O(d^2)``, the derivative of a pose's logarithm under a right perturbation.

    Block form in the ``(omega, v)`` order: ``[[A, 0], [-A Q A, A]]`` with ``A`` the inverse right
    Jacobian of SO(3) (:func:`so3_right_jacobian_inverse`) and ``Q = Q_l(-omega, -v)``, Barfoot's
    coupling block of the left Jacobian. The left one is ``J_l(xi)^-1 = se3_right_jacobian_inverse(-xi)``.
    """
    omega, v = xi[..., :3], xi[..., 3:]
    t2 = dot(omega, omega, xp)
    small = t2 < _JACOBIAN_SERIES_SQ
    t2s = xp.where(small, 1.0, t2)
    th = xp.sqrt(t2s)
    s, c = xp.sin(th), xp.cos(th)
    t4, t6 = t2 * t2, t2 * t2 * t2
    c1 = xp.where(small, 1.0 / 6.0 - t2 / 120.0 + t4 / 5040.0 - t6 / 362880.0, (th - s) / (t2s * th))
    c2 = xp.where(small, 1.0 / 24.0 - t2 / 720.0 + t4 / 40320.0 - t6 / 3628800.0,
                  (t2s + 2.0 * c - 2.0) / (2.0 * t2s * t2s))
    c3 = xp.where(small, 1.0 / 120.0 - t2 / 2520.0 + t4 / 120960.0 - t6 / 9979200.0,
                  (2.0 * th - 3.0 * s + th * c) / (2.0 * t2s * t2s * th))
    W, P = skew(omega, xp), skew(v, xp)
    WP, PW = W @ P, P @ W
    WPW = WP @ W
    # Q_l(-omega, -v): every product of k skew factors changes sign k times
    Q = (-0.5 * P + c1[..., None, None] * (WP + PW - WPW) + c2[..., None, None] * (-(W @ WP) - PW @ W + 3.0 * WPW)
         + c3[..., None, None] * (WPW @ W + W @ WPW))
    A = xp.broadcast_to(xp.eye(3), W.shape) + 0.5 * W + _jr_inverse_d(t2, small, xp)[..., None, None] * (W @ W)
    zero = xp.zeros_like(A)
    return xp.concatenate([xp.concatenate([A, zero], axis=-1),
                           xp.concatenate([-(A @ Q @ A), A], axis=-1)], axis=-2)
