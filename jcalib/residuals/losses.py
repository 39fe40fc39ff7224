"""Robust losses ρ(s) of a factor's squared whitened residual norm ``s = ‖r‖²``.

The engine minimises ``½ Σ_k ρ(s_k)`` over observations ``k``. It uses **IRLS-style** reweighting
(no Triggs second-order correction): at each linearisation the whitened residual and its Jacobian
of observation ``k`` are multiplied by ``√ρ'(s_k)``. The gradient ``Σ ρ' Jᵀr`` is then exact;
the Gauss–Newton Hessian omits the ``2ρ'' (Jᵀr)(Jᵀr)ᵀ`` term, which keeps it positive
semi-definite (Ceres' "corrected" form needs ρ'' and can go indefinite for Cauchy). Covariances of
a robust solve use the same reweighted information matrix.

A loss is a small equinox module with one method, ``rho(s) -> (ρ(s), ρ'(s))``, jit/vmap-safe,
with finite derivatives at ``s = 0``.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp


class TrivialLoss(eqx.Module):
    """Plain least squares: ``ρ(s) = s``."""

    def rho(self, s):
        """``s (...)`` -> ``(ρ, ρ')``, both shaped like ``s``."""
        return s, jnp.ones_like(s)


class HuberLoss(eqx.Module):
    """Huber: quadratic for ``‖r‖ <= scale``, linear beyond.

    ``ρ(s) = s`` for ``s <= a²`` else ``2a√s − a²`` (``a = scale``, in whitened units, i.e. σ).
    """

    scale: float = eqx.field(static=True, default=1.0)

    def rho(self, s):
        a = self.scale
        a2 = a * a
        outside = s > a2
        sqrt_s = jnp.sqrt(jnp.where(outside, s, a2))  # safe branch: never sqrt(0)
        value = jnp.where(outside, 2.0 * a * sqrt_s - a2, s)
        slope = jnp.where(outside, a / sqrt_s, jnp.ones_like(s))
        return value, slope


class CauchyLoss(eqx.Module):
    """Cauchy (Lorentzian): ``ρ(s) = a² log(1 + s/a²)``, ``a = scale`` in whitened units."""

    scale: float = eqx.field(static=True, default=1.0)

    def rho(self, s):
        a2 = self.scale * self.scale
        return a2 * jnp.log1p(s / a2), 1.0 / (1.0 + s / a2)


Loss = TrivialLoss | HuberLoss | CauchyLoss
