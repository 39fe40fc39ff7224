"""Derivatives of the solution by the implicit function theorem.

At the optimum ``x*`` the free part of the gradient vanishes: ``G(ε, θ) = P ∇_ε C(x(ε, θ), θ) = 0``
at ``ε = 0``, where ``θ`` are the problem's floating-point data (observations, σ, weights, priors,
the values of fixed coordinates) and ``x(ε, θ) = x* ⊞ (P ε + (I − P) τ(θ))`` (``P`` projects on
the free tangent coordinates, ``τ`` is the tangent displacement of the fixed coordinates' values).
Then ``dε*/dθ = −H⁻¹ ∂G/∂θ`` with ``H = ∂G/∂ε`` the **exact** Hessian of the cost (not
Gauss–Newton), assembled block-wise per observation and solved with the same Schur complement as
the solver. The backward pass costs one exact-Hessian assembly, one block solve and one
reverse-over-forward pass through the cost: no re-solve, no dense matrix.

Derivatives with respect to the start values of *free* coordinates are zero (the optimum does not
depend on where the solver started). For a group element with a *partial* fixed mask, the
fixed-coordinate derivative is taken in the tangent space at the solution (first-order exact for
whole fixed entries and Euclidean coordinates).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jcalib.solve import linear
from jcalib.solve.lm import SolveOptions, lm_solve
from jcalib.solve.problem import Problem


def _x_of(problem: Problem, x_star: dict, eps: dict) -> dict:
    deltas = {}
    for v in problem.variables:
        free = jnp.where(v.fixed, 0.0, 1.0)
        tau = jax.vmap(v.manifold.local)(jax.lax.stop_gradient(v.value), v.value)
        deltas[v.name] = free * eps[v.name] + (1.0 - free) * tau
    return linear.retract_all(problem, x_star, deltas)


@eqx.filter_custom_vjp
def _solve_values(problem: Problem, options: SolveOptions):
    return lm_solve(problem, options).values


@_solve_values.def_fwd
def _solve_values_fwd(perturbed, problem, options):
    values = lm_solve(problem, options).values
    return values, values


@_solve_values.def_bwd
def _solve_values_bwd(x_star, grad_obj, perturbed, problem, options):
    x_star = jax.lax.stop_gradient(x_star)
    layout = linear.make_layout(problem)
    free = linear.free_masks(problem)
    xbar = {
        n: (jnp.zeros_like(x_star[n]) if grad_obj.get(n) is None else grad_obj[n]) for n in x_star
    }
    zeros = {v.name: jnp.zeros((v.num, v.tangent_dim), jnp.float64) for v in problem.variables}

    # u = (∂x/∂ε)ᵀ x̄ on the free coordinates.
    _, vjp_eps = jax.vjp(lambda e: _x_of(problem, x_star, e), zeros)
    (u,) = vjp_eps(xbar)
    u = {n: u[n] * free[n] for n in u}
    # λ = H⁻¹ u with the exact Hessian at the optimum.
    at_opt = eqx.tree_at(lambda p: tuple(v.value for v in p.variables), problem,
                         tuple(x_star[v.name] for v in problem.variables))
    system = linear.exact_system(at_opt, layout, x_star, free)
    rhs_s, rhs_e = linear.dict_to_blocks({n: u[n][..., None] for n in u}, layout)
    lam_s, lam_e = linear.schur_solve(system, layout, rhs_s, rhs_e)
    lam = linear.deltas_to_dict(lam_s[:, 0], tuple(x[..., 0] for x in lam_e), layout)
    lam = {n: lam[n] * free[n] for n in lam}

    def psi(prob):
        direct = sum(jnp.vdot(xbar[n], x) for n, x in _x_of(prob, x_star, zeros).items())
        _, dcost = jax.jvp(lambda e: linear.total_cost(prob, _x_of(prob, x_star, e)), (zeros,), (lam,))
        return direct - dcost

    grads = eqx.filter_grad(psi)(problem)
    return jax.tree.map(lambda g, p: g if p else None, grads, perturbed, is_leaf=lambda x: x is None)


def solve_differentiable(problem: Problem, options: SolveOptions = SolveOptions()) -> dict:
    """Solve and return ``{name: (num, param_dim)}`` values that JAX can differentiate.

    Gradients flow to every floating-point array of ``problem`` (observations, ``sigma``,
    ``sqrt_weight``, priors, values of fixed coordinates) through the implicit function theorem
    (see the module docstring), e.g.::

        dfx_duv = jax.grad(lambda uv: solve_differentiable(make_problem(uv))["intrinsics"][0, 0])(uv)

    No padding and no status check happen here: the solve must converge (check with
    :func:`jcalib.solve.solve` first); jit the caller for speed.
    """
    return _solve_values(problem, options)
