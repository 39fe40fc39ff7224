"""Gaussian priors on variables, as residual blocks.

A prior on one entry ``x`` of a variable with manifold ``M`` is the whitened residual
``r = S · M.local(mean, x)``, where ``S`` is the square-root information (``Sᵀ S = Σ⁻¹``) in the
tangent space at the mean (order and units of ``M``'s tangent, e.g. ``(rx, ry, rz, tx, ty, tz)``,
rad and m for SE(3)). The engine adds one such factor group per variable that carries priors.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax.numpy as jnp


@functools.cache
def gaussian_prior_residual(manifold) -> Callable:
    """Return ``f(x, obs) -> r (d,)`` with ``obs = (mean (p,), sqrt_info (d, d))``.

    Args:
        manifold: a :mod:`jcalib.solve.manifolds` manifold (param dim ``p``, tangent dim ``d``).

    Cached per manifold, so the same function object (and one jit trace) serves every problem.
    """

    def prior(x, obs):
        mean, sqrt_info = obs
        return jnp.matmul(sqrt_info, manifold.local(mean, x))

    prior.__name__ = f"gaussian_prior_{type(manifold).__name__}"
    prior.__jcalib_key__ = repr(("gaussian_prior", type(manifold).__name__, manifold.param_dim))
    return prior


@functools.cache
def gaussian_prior_jacobian(manifold) -> Callable:
    """The hand-derived linearisation of :func:`gaussian_prior_residual` (``FactorGroup.jacobian``):
    ``(r, (S · ∂ local(mean, x ⊞ δ)/∂δ,))``, the manifold's own ``local_jacobian`` (SE(3)'s inverse right
    Jacobian) instead of autodiff through its logarithm's series branches."""

    def jacobian(x, obs):
        mean, sqrt_info = obs
        return jnp.matmul(sqrt_info, manifold.local(mean, x)), (jnp.matmul(sqrt_info, manifold.local_jacobian(mean, x)),)

    jacobian.__jcalib_key__ = repr(("gaussian_prior_jacobian", type(manifold).__name__, manifold.param_dim))
    return jacobian
