"""Manifolds of the engine's variable kinds: Euclidean, SO(3), SE(3).

Every manifold maps one parameter row (``param_dim``) and one tangent vector (``tangent_dim``):

- ``retract(x, delta) -> x'`` is the update the solver applies (right perturbation ``x · Exp(δ)``
  for the groups, ``x + δ`` for Euclidean);
- ``local(x, y) -> delta`` is its inverse, ``Log(x⁻¹ y)``, so ``retract(x, local(x, y)) == y``;
- ``retract_linear(x, delta)`` equals ``retract`` in value and first derivative at ``δ = 0`` but has
  no exp, trig or normalisation: the engine differentiates through it for Gauss–Newton Jacobians
  (always taken at ``δ = 0``), never for updates or second derivatives.

Layouts (docs/design.md): SO(3) parameters are a ``wxyz`` unit quaternion, tangent ``(rx, ry, rz)`` in
radians. SE(3) parameters are ``wxyz_xyz`` (quaternion, then translation in metres), tangent
``(rx, ry, rz, tx, ty, tz)`` — rotation first, unlike jaxlie's ``(tx, ty, tz, rx, ry, rz)``; the
SE(3) exponential and logarithm are jcalib.geometry's, so no SE(3) tangent is ever handed to jaxlie.

A partial fixed mask on a group element constrains each *step* ``δ`` in the element's local frame;
only Euclidean coordinates and whole fixed group elements keep their values bit-for-bit.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from jcalib.geometry import lie_kernels as K

# The group algebra is jcalib.geometry's (one SO(3)/SE(3) exp and log in the package, with series
# branches below 0.01 rad). jaxlie 1.5's SE(3) exp is not usable here: under θ² = 1e-10 it takes the
# rotation matrix ``I + W`` for ``V(ω) ≈ I + W/2``, so ``Log(Exp(δ))`` misses ``½ ω × v`` for
# rotations under 1e-5 rad.


def quat_multiply(a, b):
    """Hamilton product of ``wxyz`` quaternions ``a (4,)``, ``b (4,)``."""
    return K.quat_multiply(a, b, jnp)


def quat_conjugate(q):
    """Inverse of a unit ``wxyz`` quaternion."""
    return K.quat_conjugate(q, jnp)


def quat_rotate(q, v):
    """Rotate ``v (3,)`` by the unit ``wxyz`` quaternion ``q``: ``R(q) v``."""
    return K.quat_rotate(q, v, jnp)


class Euclidean(eqx.Module):
    """``R^dim``: parameters and tangent coincide; ``retract(x, δ) = x + δ``."""

    dim: int = eqx.field(static=True)

    @property
    def param_dim(self) -> int:
        return self.dim

    @property
    def tangent_dim(self) -> int:
        return self.dim

    @property
    def coord_labels(self) -> tuple[str, ...]:
        return tuple(f"x{i}" for i in range(self.dim))

    def retract(self, x, delta):
        """``x (dim,)``, ``delta (dim,)`` -> ``x + delta (dim,)``."""
        return x + delta

    def retract_linear(self, x, delta):
        """Same as :meth:`retract` (already linear)."""
        return x + delta

    def local(self, x, y):
        """``y - x (dim,)``."""
        return y - x

    def local_jacobian(self, x, y):
        """``∂ local(x, y ⊞ δ) / ∂δ`` at ``δ = 0``: the identity."""
        return jnp.eye(self.dim, dtype=y.dtype)

    def normalize(self, x):
        return x


class SO3(eqx.Module):
    """Rotations; parameters ``wxyz`` (4,), tangent ``(rx, ry, rz)`` rad, ``R · Exp(ω)``."""

    @property
    def param_dim(self) -> int:
        return 4

    @property
    def tangent_dim(self) -> int:
        return 3

    @property
    def coord_labels(self) -> tuple[str, ...]:
        return ("rx", "ry", "rz")

    def retract(self, x, delta):
        """``x (4,) wxyz``, ``delta (3,) rad`` -> ``x · Exp(delta) (4,)``."""
        return quat_multiply(x, K.so3_exp(delta, jnp))

    def retract_linear(self, x, delta):
        """First-order ``x · Exp(δ) ≈ x ⊗ [1, δ/2]`` (exact value and derivative at ``δ = 0``; not unit norm)."""
        return x + 0.5 * quat_multiply(x, jnp.concatenate([jnp.zeros((1,), delta.dtype), delta]))

    def local(self, x, y):
        """``Log(x⁻¹ y) (3,) rad``."""
        return K.so3_log(quat_multiply(quat_conjugate(x), y), jnp)

    def local_jacobian(self, x, y):
        """``∂ local(x, y · Exp(δ)) / ∂δ`` at ``δ = 0``: SO(3)'s inverse right Jacobian at ``local(x, y)``."""
        return K.so3_right_jacobian_inverse(self.local(x, y), jnp)

    def normalize(self, x):
        """Unit norm and ``w >= 0`` (the sign convention of docs/design.md)."""
        q = x / jnp.linalg.norm(x)
        return jnp.where(q[0] < 0.0, -q, q)


class SE3(eqx.Module):
    """Rigid transforms; parameters ``wxyz_xyz`` (7,), tangent ``(rx, ry, rz, tx, ty, tz)``.

    ``retract(T, δ) = T · Exp(δ)`` with the SE(3) exponential (rad, m).
    """

    @property
    def param_dim(self) -> int:
        return 7

    @property
    def tangent_dim(self) -> int:
        return 6

    @property
    def coord_labels(self) -> tuple[str, ...]:
        return ("rx", "ry", "rz", "tx", "ty", "tz")

    def retract(self, x, delta):
        """``x (7,) wxyz_xyz``, ``delta (6,)`` -> ``x · Exp(delta) (7,)``."""
        return K.se3_compose(x, K.se3_exp(delta, jnp), jnp)

    def retract_linear(self, x, delta):
        """First-order ``T · Exp(δ) ≈ (q ⊗ [1, ω/2], t + R(q) v)`` for ``δ = (ω, v)``.

        Equal to :meth:`retract` in value and first derivative at ``δ = 0`` (the ``V(ω) v`` term of
        the exponential is second order); cheap to differentiate. Not a unit quaternion for ``δ ≠ 0``.
        """
        q, t = x[:4], x[4:]
        w = jnp.concatenate([jnp.zeros((1,), delta.dtype), delta[:3]])
        return jnp.concatenate([q + 0.5 * quat_multiply(q, w), t + quat_rotate(q, delta[3:])])

    def local(self, x, y):
        """``Log(x⁻¹ y) (6,)`` in the order ``(rx, ry, rz, tx, ty, tz)``."""
        return K.se3_log(K.se3_compose(K.se3_inverse(x, jnp), y, jnp), jnp)

    def local_jacobian(self, x, y):
        """``∂ local(x, y · Exp(δ)) / ∂δ`` at ``δ = 0``: SE(3)'s inverse right Jacobian at ``local(x, y)``."""
        return K.se3_right_jacobian_inverse(self.local(x, y), jnp)

    def normalize(self, x):
        """Unit quaternion with ``w >= 0``; translation unchanged."""
        q = x[:4] / jnp.linalg.norm(x[:4])
        q = jnp.where(q[0] < 0.0, -q, q)
        return jnp.concatenate([q, x[4:]])


Manifold = Euclidean | SO3 | SE3
