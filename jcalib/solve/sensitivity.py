"""First-order effect of stated inputs on the solution, with the system the solve already has.

A stated input ``θ`` (a board's printed scale, intrinsics or a transform held at an earlier result,
a robot's nominal kinematics, a stated noise level) enters the problem as data. At the optimum the
free part of the gradient vanishes, ``g(x*(θ), θ) = 0``, so to first order

    dx*/dθ = −H⁻¹ ∂g/∂θ,        H = JᵀWJ (the Gauss–Newton system of the final solve),

one block (Schur) solve with ``p`` right-hand sides, no re-solve. ``∂g/∂θ`` is one forward-over-reverse
pass through the cost. The same pass gives ``∂C/∂θ`` and ``∂²C/∂θ²``, from which
:func:`sensitivities` also returns the marginal information of ``θ`` given the data
(``M = C_θθ − Bᵀ H⁻¹ B``) and the score ``∂C/∂θ``: what the data say about a stated input (a score test
of it, :mod:`jcalib.problems.budget`).

A :class:`Perturbation` says how ``θ`` enters a problem, by name (static), so that one compiled function
serves every problem of the same structure.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.solve import linear, traced
from jcalib.solve.problem import Problem, replace


class Perturbation(eqx.Module):
    """How a vector ``θ (p,)`` of stated inputs enters a problem (all fields static; ``θ = 0``: as solved).

    Attributes:
        size: ``p``.
        scale_points: ``(factor group, θ index)``: the group's first observation leaf (target points, m) is
            multiplied by ``1 + θ_i`` (a target's printed scale).
        held: ``(variable, entry, coordinates, θ start)``: the variable's value moves by ``δ = θ[start:start+len]``
            on those tangent coordinates of that entry (``value ⊞ δ``; the coordinates must be fixed).
        prior_mean: ``(prior factor group, entry, coordinates, θ start)``: a Euclidean prior's mean moves by ``δ``.
        log_sigma: ``(factor groups, θ index)``: the groups' σ are multiplied by ``exp(θ_i)``.
        pose_jacobian: ``(variable, θ start, θ size)``: each entry of an SE(3) variable (and its prior mean, when
            ``prior`` names one) moves by ``J_k δ`` with ``J`` given at call time (e.g. flange poses computed from
            nominal kinematics).
    """

    size: int = eqx.field(static=True)
    scale_points: tuple = eqx.field(static=True, default=())
    held: tuple = eqx.field(static=True, default=())
    prior_mean: tuple = eqx.field(static=True, default=())
    log_sigma: tuple = eqx.field(static=True, default=())
    pose_jacobian: tuple = eqx.field(static=True, default=())

    def factors_of(self, problem: Problem) -> tuple[str, ...]:
        """The factor groups that depend on ``θ`` (the others drop out of every derivative)."""
        names = {n for n, _ in self.scale_points} | {n for ns, _ in self.log_sigma for n in ns}
        names |= {n for n, *_ in self.prior_mean} | {p for *_, p in self.pose_jacobian if p is not None}
        moved = {v for v, *_ in self.held} | {v for v, *_ in self.pose_jacobian}
        return tuple(f.name for f in problem.factors if f.name in names or moved & set(f.args))

    def apply(self, problem: Problem, theta, jacobians: tuple = ()) -> Problem:
        """The problem with inputs ``θ`` (traceable)."""
        factors = list(problem.factors)
        index = {f.name: i for i, f in enumerate(factors)}
        for name, i in self.scale_points:
            f = factors[index[name]]
            obs = tuple(f.observations)
            factors[index[name]] = replace(f, observations=(obs[0] * (1.0 + theta[i]),) + obs[1:])
        for names, i in self.log_sigma:
            for name in names:
                f = factors[index[name]]
                factors[index[name]] = replace(f, sigma=f.sigma * jnp.exp(theta[i]))
        for name, entry, coords, start in self.prior_mean:
            f = factors[index[name]]
            mean, S = f.observations
            delta = jnp.zeros(mean.shape[-1], jnp.float64).at[jnp.asarray(coords)].set(
                theta[start:start + len(coords)])
            factors[index[name]] = replace(f, observations=(mean.at[entry].add(delta), S))
        variables = list(problem.variables)
        vindex = {v.name: i for i, v in enumerate(variables)}
        for name, entry, coords, start in self.held:
            v = variables[vindex[name]]
            delta = jnp.zeros(v.tangent_dim, jnp.float64).at[jnp.asarray(coords)].set(theta[start:start + len(coords)])
            row = v.manifold.retract(jnp.asarray(v.value[entry]), delta)
            variables[vindex[name]] = replace(v, value=jnp.asarray(v.value).at[entry].set(row))
        for (name, start, size, prior), J in zip(self.pose_jacobian, jacobians):
            v = variables[vindex[name]]
            deltas = jnp.einsum("kdp,p->kd", J, theta[start:start + size])
            n = J.shape[0]
            value = jnp.asarray(v.value)
            moved = jax.vmap(v.manifold.retract)(value[:n], deltas)
            variables[vindex[name]] = replace(v, value=value.at[:n].set(moved))
            if prior is not None:
                f = factors[index[prior]]
                mean, S = f.observations
                mean = jnp.asarray(mean)
                factors[index[prior]] = replace(f, observations=(mean.at[:n].set(
                    jax.vmap(v.manifold.retract)(mean[:n], deltas)), S))
        return replace(problem, variables=tuple(variables), factors=tuple(factors))


class Sensitivity(NamedTuple):
    """What :func:`sensitivities` returns (NumPy, the solved problem's variables, unpadded).

    Attributes:
        dx: variable -> ``(num, d, p)`` derivative of its tangent coordinates (right perturbation) with
            respect to ``θ`` (zero on fixed coordinates).
        information: ``(p, p)`` marginal information ``M`` of ``θ`` given the data (whitened units: the
            inverse of its sampling covariance were ``θ`` estimated, before the variance factor).
        score: ``(p,)`` ``∂C/∂θ`` at the solution (zero when the data agree with ``θ = 0`` exactly).
        chi2: factor group -> ``(at the solution, after the stated inputs' adjustment)``: each group's
            ``2 C_g`` (its χ² in the whitened units the solve used) at ``x*`` and at ``(θ̂, x* + dx/dθ θ̂)``, where
            ``θ̂ = −(M + P)⁻¹ g`` is the adjustment of the stated inputs that the data ask for under their prior
            information ``P``: what each kind's residuals would be if the inputs were where the data put them
            within their stated σ (first order). Empty without ``prior_information``.
    """

    dx: dict
    information: np.ndarray
    score: np.ndarray
    chi2: dict


def _x_of(problem: Problem, nominal: Problem, x_star: dict, eps: dict) -> dict:
    """``x* ⊞ (P ε + (I − P) τ)``: free coordinates from ``ε``, fixed ones follow ``problem``'s values
    (unlike :func:`jcalib.solve.linear.retract_all`, whole fixed entries move too: they are the inputs)."""
    out = {}
    for v, v0 in zip(problem.variables, nominal.variables):
        if v.constant:
            out[v.name] = jnp.asarray(v.value)
            continue
        free = jnp.where(v.fixed, 0.0, 1.0)
        tau = jax.vmap(v.manifold.local)(jnp.asarray(v0.value), jnp.asarray(v.value))
        delta = free * eps[v.name] + (1.0 - free) * tau
        out[v.name] = jax.vmap(v.manifold.normalize)(jax.vmap(v.manifold.retract)(x_star[v.name], delta))
    return out


def _group_chi2(problem: Problem, values: dict):
    return jnp.stack([2.0 * linear.total_cost(replace(problem, factors=(f,)), values) for f in problem.factors])


@eqx.filter_jit
def _core(padded: Problem, system: linear.System, values: dict, perturbation: Perturbation, jacobians: tuple,
          exact: bool, prior_information):
    layout = linear.make_layout(padded)
    free = linear.free_masks(padded)
    if exact:
        at_opt = eqx.tree_at(lambda p: tuple(v.value for v in p.variables), padded,
                             tuple(values[v.name] for v in padded.variables))
        system = linear.exact_system(at_opt, layout, values, free)
    zeros = {v.name: jnp.zeros((v.num, v.tangent_dim), jnp.float64) for v in padded.variables}
    theta0 = jnp.zeros((perturbation.size,), jnp.float64)
    affected = set(perturbation.factors_of(padded))
    part = replace(padded, factors=tuple(f for f in padded.factors if f.name in affected))

    def cost(eps, theta):
        prob = perturbation.apply(part, theta, jacobians)
        return linear.total_cost(prob, _x_of(prob, part, values, eps))

    def gradients(theta):
        return jax.grad(cost, argnums=(0, 1))(zeros, theta)

    _, g_theta = gradients(theta0)
    B, C_tt = jax.jacfwd(gradients)(theta0)
    B = {n: B[n] * free[n][..., None] for n in B}  # (num, d, p)
    rhs_s, rhs_e = linear.dict_to_blocks(B, layout)
    z_s, z_e = linear.schur_solve(system, layout, -rhs_s, tuple(-r for r in rhs_e))
    dx = {}
    for k, name in enumerate(layout.names):
        N, d = layout.nums[k], layout.dims[k]
        if layout.eliminate[k]:
            dx[name] = z_e[layout.elim_slot[k]]
        else:
            dx[name] = z_s[layout.offsets[k]:layout.offsets[k] + N * d].reshape(N, d, -1)
    dx = {n: dx[n] * free[n][..., None] for n in dx}
    cross = rhs_s.T @ z_s
    for r, z in zip(rhs_e, z_e):
        cross = cross + jnp.einsum("ndp,ndq->pq", r, z)
    M = 0.5 * (C_tt + cross + (C_tt + cross).T)  # C_θθ − Bᵀ H⁻¹ B
    chi2 = None
    if prior_information is not None:
        theta_hat = -jnp.linalg.solve(M + prior_information, g_theta)
        moved = perturbation.apply(padded, theta_hat, jacobians)
        x_hat = _x_of(moved, padded, values, {n: dx[n] @ theta_hat for n in dx})
        chi2 = (_group_chi2(padded, values), _group_chi2(moved, x_hat))
    return dx, M, g_theta, chi2


class _Inputs(eqx.Module):
    """The arguments of :func:`_core` besides the problem, as the ``options`` of :func:`jcalib.solve.traced.run`
    (arrays are inputs of the exported program; the perturbation is static and part of its key)."""

    system: linear.System
    values: dict
    perturbation: Perturbation
    jacobians: tuple
    prior_information: jax.Array

    def traced(self):
        return self


def _traced_core(problem: Problem, inputs: _Inputs, exact: bool):
    return _core(problem, inputs.system, inputs.values, inputs.perturbation, inputs.jacobians, exact,
                 inputs.prior_information)


def sensitivities(sol, perturbation: Perturbation, jacobians: tuple = (), exact: bool = False,
                  prior_information=None) -> Sensitivity:
    """``dx*/dθ`` of a solved problem (see the module docstring).

    Args:
        sol: the :class:`jcalib.solve.Solution` (its padded problem, estimate and Gauss–Newton system).
        perturbation: how ``θ`` enters the problem (names of its factor groups and variables).
        jacobians: one ``(num, 6, size)`` array per ``perturbation.pose_jacobian`` entry.
        exact: solve with the exact Hessian of the cost (one more assembly and compile) instead of the solve's
            Gauss–Newton system; the two differ by the residuals' curvature terms (first order in the residuals).
        prior_information: ``(p, p)`` information of the stated inputs (the inverse of their stated covariance;
            large where an input is to stay put): adds :attr:`Sensitivity.chi2`.
    Returns:
        :class:`Sensitivity`: first order, at the solution; in whitened units the solve used.
    """
    jac = tuple(jnp.asarray(np.asarray(J, np.float64)) for J in jacobians)
    P = None if prior_information is None else jnp.asarray(np.asarray(prior_information, np.float64))
    out = None
    if P is not None:  # through the cache of traced programs: a warm process neither traces nor compiles
        names = [v.name for v in sol.padded_problem.variables]
        treedef = jax.tree.structure(({n: 0 for n in names}, 0, 0, (0, 0)))
        out = traced.run(_traced_core, sol.padded_problem, _Inputs(sol.raw.system, sol.raw.values, perturbation, jac, P),
                         bool(exact), treedef)
    if out is None:
        out = _core(sol.padded_problem, sol.raw.system, sol.raw.values, perturbation, jac, bool(exact), P)
    dx, M, g, chi2 = out
    nums = {v.name: v.num for v in sol.problem.variables}
    groups = {} if chi2 is None else {f.name: (float(a), float(b)) for f, a, b in
                                      zip(sol.padded_problem.factors, np.asarray(chi2[0]), np.asarray(chi2[1]))}
    return Sensitivity({n: np.asarray(dx[n])[:nums[n]] for n in nums}, np.asarray(M), np.asarray(g), groups)
