"""SO(3) and SE(3) for calibration: unit quaternions, rigid poses, exp/log, retraction.

Layouts (the same as jaxlie's, so ``jaxlie.SE3(wxyz_xyz=pose)`` wraps one of our poses):

- a rotation is a unit quaternion ``(..., 4)`` in ``wxyz`` order (Hamilton convention);
- a pose ``T_a_b`` is ``(..., 7)``: the quaternion ``wxyz`` of ``R_a_b`` then the translation
  ``t_a_b`` (metres), so ``p_a = R_a_b p_b + t_a_b``;
- a tangent vector of SO(3) is ``omega (..., 3)`` (radians, axis * angle, the OpenCV rotation
  vector); a tangent vector of SE(3) is ``delta = (omega, v) (..., 6)`` -- **rotation first,
  translation second**, in the order ``(rx, ry, rz, tx, ty, tz)`` that results use
  (:data:`SE3_TANGENT_ORDER`). jaxlie orders its SE(3) tangent the other way round
  ``(vx, vy, vz, wx, wy, wz)``; nothing here uses that order.

Perturbations are on the **right** (in the local frame *b* of ``T_a_b``)::

    retract(T, delta) = T . Exp(delta)            local(T, U) = Log(T^-1 . U)

with ``Exp`` the exponential map of SE(3) (``Exp((omega, v)) = [Exp(omega), V(omega) v]``). To first
order ``omega`` is a small rotation and ``v`` a small translation, both expressed in frame *b*; a
covariance of ``delta`` moves to frame *a* with :func:`se3_adjoint`.

Every function is pure ``jax.numpy``: jittable, vmappable, batched over leading axes (leading axes of
two arguments broadcast explicitly, so the code also runs under
``jax_numpy_rank_promotion="raise"``), float64, and differentiable with finite, exact derivatives
at the identity (Taylor branches below angle 1e-2 rad) and up to a rotation of pi (where the
rotation vector itself jumps from ``pi * axis`` to ``-pi * axis``). Poses on output are not
sign-normalised unless said so (keeping ``retract`` smooth); ``se3_from_matrix`` and
``quat_normalize_sign`` return ``w >= 0``.

``SO3`` / ``SE3`` are jaxlie's classes, re-exported for users who want its object API. Note that
jaxlie 1.5's ``SO3.multiply``/``inverse`` and batched ``SE3`` operations fail under the strict dtype
and rank promotion our tests turn on; the functions here do not.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jaxlie import SE3, SO3

from jcalib.errors import BadInputError
from jcalib.geometry import lie_kernels as kernels

__all__ = [
    "SE3",
    "SE3_TANGENT_ORDER",
    "SO3",
    "local",
    "quat_inverse",
    "quat_multiply",
    "quat_normalize",
    "quat_normalize_sign",
    "quat_rotate",
    "retract",
    "rotation_angle_between",
    "se3_adjoint",
    "se3_apply",
    "se3_compose",
    "se3_exp",
    "se3_from_matrix",
    "se3_from_rvec_tvec",
    "se3_identity",
    "se3_inverse",
    "se3_log",
    "se3_to_matrix",
    "se3_to_rvec_tvec",
    "so3_exp",
    "so3_from_matrix",
    "so3_from_rvec",
    "so3_local",
    "so3_log",
    "so3_retract",
    "so3_to_matrix",
    "so3_to_rvec",
]

SE3_TANGENT_ORDER = ("rx", "ry", "rz", "tx", "ty", "tz")
"""Order of the SE(3) tangent vector (and of every 6x6 pose covariance): rotation (rad) then
translation (m), right perturbation ``T . Exp(delta)``."""

# jcalib.study.estimators reaches these kernels as ``lie._se3_*``; the algebra itself lives in
# jcalib.geometry.lie_kernels. Remove once it uses jcalib.geometry.se3 (tests/test_layout.py lists it).
_se3_from_matrix = kernels.se3_from_matrix
_se3_log = kernels.se3_log
_se3_compose = kernels.se3_compose
_se3_inverse = kernels.se3_inverse

# ----------------------------------------------------------------------------------------------
# Public JAX API
# ----------------------------------------------------------------------------------------------


def _f64(x: Any, name: str, trailing: tuple[int, ...]) -> jax.Array:
    """Cast to a float64 jax array and check the trailing shape (a static check, fine under jit)."""
    if isinstance(x, (SO3, SE3)):
        x = x.parameters()
    arr = jnp.asarray(x, dtype=jnp.float64)
    if arr.ndim < len(trailing) or tuple(arr.shape[arr.ndim - len(trailing) :]) != trailing:
        raise BadInputError(
            f"{name}: expected an array of shape (..., {', '.join(map(str, trailing))}), "
            f"got shape {tuple(arr.shape)}"
        )
    return arr


def _broadcast_leading(a: jax.Array, na: int, b: jax.Array, nb: int) -> tuple[jax.Array, jax.Array]:
    """Broadcast the leading (batch) axes of a and b; na/nb are their trailing (element) ranks."""
    lead = jnp.broadcast_shapes(a.shape[: a.ndim - na], b.shape[: b.ndim - nb])
    return (
        jnp.broadcast_to(a, lead + a.shape[a.ndim - na :]),
        jnp.broadcast_to(b, lead + b.shape[b.ndim - nb :]),
    )


def quat_normalize(q) -> jax.Array:
    """Scale quaternions ``(..., 4)`` to unit norm (the sign is kept)."""
    return kernels.quat_normalize(_f64(q, "q", (4,)), jnp)


def quat_normalize_sign(q) -> jax.Array:
    """Flip quaternions ``(..., 4)`` (``wxyz``) so that ``w >= 0``; the rotation is unchanged."""
    return kernels.quat_normalize_sign(_f64(q, "q", (4,)), jnp)


def quat_multiply(p, q) -> jax.Array:
    """Hamilton product ``p * q`` of quaternions ``(..., 4)`` (``wxyz``): rotation ``R(p) R(q)``."""
    p, q = _broadcast_leading(_f64(p, "p", (4,)), 1, _f64(q, "q", (4,)), 1)
    return kernels.quat_multiply(p, q, jnp)


def quat_inverse(q) -> jax.Array:
    """Inverse of unit quaternions ``(..., 4)`` (the conjugate)."""
    return kernels.quat_conjugate(_f64(q, "q", (4,)), jnp)


def quat_rotate(q, p) -> jax.Array:
    """Rotate points ``p (..., 3)`` by unit quaternions ``q (..., 4)``: ``R(q) p``."""
    q, p = _broadcast_leading(_f64(q, "q", (4,)), 1, _f64(p, "p", (3,)), 1)
    return kernels.quat_rotate(q, p, jnp)


def so3_to_matrix(q) -> jax.Array:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` ``wxyz`` (normalised first)."""
    return kernels.quat_to_matrix(_f64(q, "q", (4,)), jnp)


def so3_from_matrix(rotation) -> jax.Array:
    """Unit quaternions ``(..., 4)`` ``wxyz`` (``w >= 0``) of rotation matrices ``(..., 3, 3)``.

    Shepperd's method, exact to float64 rounding at every angle including pi. The input is assumed
    orthonormal (see ``conversions.matrix_to_quat`` for a checked version); a slightly
    non-orthonormal matrix gives the nearby unit quaternion.
    """
    return kernels.matrix_to_quat(_f64(rotation, "rotation", (3, 3)), jnp)


def so3_exp(omega) -> jax.Array:
    """Exponential map of SO(3): rotation vectors ``(..., 3)`` (rad) to quaternions ``(..., 4)``.

    ``w = cos(theta/2) >= 0`` for ``|omega| <= pi`` (larger vectors give ``w < 0``, the same rotation
    as the sign-normalised quaternion).
    """
    return kernels.so3_exp(_f64(omega, "omega", (3,)), jnp)


def so3_log(q) -> jax.Array:
    """Logarithm of SO(3): quaternions ``(..., 4)`` to rotation vectors ``(..., 3)``, ``|.| <= pi``.

    Quaternions are normalised and sign-normalised first, so ``q`` and ``-q`` give the same vector.
    At exactly pi the sign of the returned axis follows the quaternion's vector part.
    """
    return kernels.so3_log(_f64(q, "q", (4,)), jnp)


def so3_from_rvec(rvec) -> jax.Array:
    """Quaternions ``(..., 4)`` ``wxyz``, ``w >= 0``, of OpenCV rotation vectors ``(..., 3)`` (rad)."""
    return kernels.quat_normalize_sign(kernels.so3_exp(_f64(rvec, "rvec", (3,)), jnp), jnp)


def so3_to_rvec(q) -> jax.Array:
    """OpenCV rotation vectors ``(..., 3)`` (axis * angle, rad, angle in [0, pi]) of quaternions."""
    return kernels.so3_log(_f64(q, "q", (4,)), jnp)


def so3_retract(q, omega) -> jax.Array:
    """Right retraction of SO(3): ``q * Exp(omega)`` (unit quaternion out), omega ``(..., 3)`` rad."""
    q, omega = _broadcast_leading(_f64(q, "q", (4,)), 1, _f64(omega, "omega", (3,)), 1)
    return kernels.quat_normalize(kernels.quat_multiply(q, kernels.so3_exp(omega, jnp), jnp), jnp)


def so3_local(q_a, q_b) -> jax.Array:
    """Inverse of :func:`so3_retract`: ``Log(q_a^-1 * q_b)`` ``(..., 3)`` rad, so that
    ``so3_retract(q_a, so3_local(q_a, q_b)) == q_b`` (up to sign)."""
    q_a, q_b = _broadcast_leading(_f64(q_a, "q_a", (4,)), 1, _f64(q_b, "q_b", (4,)), 1)
    return kernels.so3_log(kernels.quat_multiply(kernels.quat_conjugate(q_a, jnp), q_b, jnp), jnp)


def se3_identity(batch_shape: tuple[int, ...] = ()) -> jax.Array:
    """Identity poses ``(*batch_shape, 7)``."""
    ident = jnp.asarray([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], dtype=jnp.float64)
    return jnp.broadcast_to(ident, tuple(batch_shape) + (7,))


def se3_to_matrix(pose) -> jax.Array:
    """4x4 homogeneous matrices ``(..., 4, 4)`` (m) of poses ``(..., 7)`` (``wxyz`` + ``xyz`` m)."""
    return kernels.se3_to_matrix(_f64(pose, "pose", (7,)), jnp)


def se3_from_matrix(matrix) -> jax.Array:
    """Poses ``(..., 7)`` (``w >= 0``) of 4x4 homogeneous matrices ``(..., 4, 4)`` (m).

    The bottom row is not read; the rotation block is assumed orthonormal (use
    ``conversions.matrix_to_pose`` for checked input).
    """
    return kernels.se3_from_matrix(_f64(matrix, "matrix", (4, 4)), jnp)


def se3_from_rvec_tvec(rvec, tvec) -> jax.Array:
    """Poses ``(..., 7)`` from OpenCV ``rvec (..., 3)`` (rad) and ``tvec (..., 3)`` (m).

    ``T_cam_target = se3_from_rvec_tvec(*cv2.solvePnP(...)[1:])`` maps target points to the camera.
    """
    rvec, tvec = _broadcast_leading(_f64(rvec, "rvec", (3,)), 1, _f64(tvec, "tvec", (3,)), 1)
    q = kernels.quat_normalize_sign(kernels.so3_exp(rvec, jnp), jnp)
    return jnp.concatenate([q, tvec], axis=-1)


def se3_to_rvec_tvec(pose) -> tuple[jax.Array, jax.Array]:
    """OpenCV ``(rvec (..., 3) rad, tvec (..., 3) m)`` of poses ``(..., 7)``; ``|rvec| <= pi``."""
    pose = _f64(pose, "pose", (7,))
    return kernels.so3_log(pose[..., :4], jnp), pose[..., 4:]


def se3_compose(T_a_b, T_b_c) -> jax.Array:
    """Composition ``T_a_c = T_a_b . T_b_c`` of poses ``(..., 7)`` (leading axes broadcast)."""
    a, b = _broadcast_leading(_f64(T_a_b, "T_a_b", (7,)), 1, _f64(T_b_c, "T_b_c", (7,)), 1)
    return kernels.se3_compose(a, b, jnp)


def se3_inverse(T_a_b) -> jax.Array:
    """Inverse ``T_b_a`` of unit-quaternion poses ``(..., 7)``."""
    return kernels.se3_inverse(_f64(T_a_b, "T_a_b", (7,)), jnp)


def se3_apply(T_a_b, p_b) -> jax.Array:
    """Transform points: ``p_a = T_a_b @ p_b``, poses ``(..., 7)``, points ``(..., 3)`` (m).

    Leading axes broadcast: one pose ``(7,)`` with points ``(N, 3)``, or poses ``(V, 1, 7)`` with
    points ``(N, 3)`` for ``(V, N, 3)``.
    """
    pose, p = _broadcast_leading(_f64(T_a_b, "T_a_b", (7,)), 1, _f64(p_b, "p_b", (3,)), 1)
    return kernels.quat_rotate(pose[..., :4], p, jnp) + pose[..., 4:]


def se3_exp(delta) -> jax.Array:
    """Exponential map of SE(3): tangent ``(omega, v) (..., 6)`` (rad, m) to poses ``(..., 7)``."""
    return kernels.se3_exp(_f64(delta, "delta", (6,)), jnp)


def se3_log(pose) -> jax.Array:
    """Logarithm of SE(3): poses ``(..., 7)`` to tangent ``(omega, v) (..., 6)``, ``|omega| <= pi``."""
    return kernels.se3_log(_f64(pose, "pose", (7,)), jnp)


def retract(T, delta) -> jax.Array:
    """Right retraction of SE(3), the solver's update: ``T . Exp(delta)``.

    Args:
        T: poses ``(..., 7)``.
        delta: tangent ``(..., 6)`` in the order ``(rx, ry, rz, tx, ty, tz)`` (rad, m), expressed in
            the pose's own (child) frame.

    Returns:
        poses ``(..., 7)`` with unit quaternions.
    """
    T, delta = _broadcast_leading(_f64(T, "T", (7,)), 1, _f64(delta, "delta", (6,)), 1)
    out = kernels.se3_compose(T, kernels.se3_exp(delta, jnp), jnp)
    return jnp.concatenate([kernels.quat_normalize(out[..., :4], jnp), out[..., 4:]], axis=-1)


def local(T, U) -> jax.Array:
    """Inverse of :func:`retract`: ``Log(T^-1 . U)`` ``(..., 6)`` = ``(rx, ry, rz, tx, ty, tz)``.

    ``retract(T, local(T, U)) == U`` whenever the relative rotation is below pi.
    """
    T, U = _broadcast_leading(_f64(T, "T", (7,)), 1, _f64(U, "U", (7,)), 1)
    return kernels.se3_log(kernels.se3_compose(kernels.se3_inverse(T, jnp), U, jnp), jnp)


def se3_adjoint(T_a_b) -> jax.Array:
    """Adjoint ``(..., 6, 6)`` in the ``(omega, v)`` order: ``T . Exp(delta) = Exp(Ad delta) . T``.

    ``Ad = [[R, 0], [[t]x R, R]]``. A right-perturbation covariance ``S`` of ``T_a_b`` (tangent in
    frame *b*) is ``Ad S Ad^T`` as a left perturbation (tangent in frame *a*).
    """
    pose = _f64(T_a_b, "T_a_b", (7,))
    r = kernels.quat_to_matrix(pose[..., :4], jnp)
    tx = kernels.skew(pose[..., 4:], jnp)
    top = jnp.concatenate([r, jnp.zeros_like(r)], axis=-1)
    bottom = jnp.concatenate([jnp.einsum("...ij,...jk->...ik", tx, r), r], axis=-1)
    return jnp.concatenate([top, bottom], axis=-2)


def _rotation_quat(x: jax.Array, name: str) -> jax.Array:
    shape = tuple(x.shape)
    if shape[-1:] == (4,) and not shape[-2:] == (4, 4):
        return x
    if shape[-1:] == (7,):
        return x[..., :4]
    if shape[-2:] == (3, 3):
        return kernels.matrix_to_quat(x, jnp)
    if shape[-2:] == (4, 4):
        return kernels.matrix_to_quat(x[..., :3, :3], jnp)
    raise BadInputError(
        f"{name}: expected quaternions (..., 4), poses (..., 7), rotations (..., 3, 3) or "
        f"transforms (..., 4, 4), got shape {shape}"
    )


def rotation_angle_between(a, b) -> jax.Array:
    """Angle (rad, in [0, pi]) of the rotation taking ``a`` to ``b``, batched ``(...)``.

    ``a`` and ``b`` are each quaternions ``(..., 4)``, poses ``(..., 7)``, rotation matrices
    ``(..., 3, 3)`` or transforms ``(..., 4, 4)`` (a 4x4 input is read as a transform, never as four
    quaternions). Computed as ``2 atan2(|u|, |w|)`` of ``a^-1 b``: accurate at small angles, where
    ``arccos((trace - 1) / 2)`` loses half the digits. The derivative at angle 0 is taken as 0.
    """
    qa = _rotation_quat(jnp.asarray(a, dtype=jnp.float64), "a")
    qb = _rotation_quat(jnp.asarray(b, dtype=jnp.float64), "b")
    qa, qb = _broadcast_leading(qa, 1, qb, 1)
    qa_inv = kernels.quat_conjugate(kernels.quat_normalize(qa, jnp), jnp)
    d = kernels.quat_multiply(qa_inv, kernels.quat_normalize(qb, jnp), jnp)
    n_sq = kernels.dot(d[..., 1:], d[..., 1:], jnp)
    positive = n_sq > 0.0
    n = jnp.where(positive, jnp.sqrt(jnp.where(positive, n_sq, 1.0)), 0.0)
    return 2.0 * jnp.arctan2(n, jnp.abs(d[..., 0]))

