"""Covariances of a solution, from the Schur-reduced system (no dense inverse of the whole problem).

With ``H`` the Gauss–Newton information at the solution (whitened, IRLS-reweighted for robust
losses), shared block inverse ``Σ_ss = S⁻¹`` (``S`` the Schur complement) and eliminated blocks

    Σ_ii = V_i⁻¹ + V_i⁻¹ W_iᵀ Σ_ss W_i V_i⁻¹,   Σ_ij = V_i⁻¹ W_iᵀ Σ_ss W_j V_j⁻¹,
    Σ_s,i = −Σ_ss W_i V_i⁻¹,

all multiplied by the variance factor: ``noise="a_posteriori"`` (default) uses
``σ̂² = 2·cost / (m − n)``; ``noise="stated"`` trusts the factor groups' σ (factor 1).

What it includes: first-order propagation of the measurement noise described by the factor groups'
σ (sampling noise). What it does not: model error (a wrong lens model, unmodelled robot error),
bias from a wrong local minimum, or the nonlinearity of the problem beyond first order.
Fixed coordinates have zero (co)variance. Covariances are in the tangent space of each variable:
SE(3) as ``(rx, ry, rz, tx, ty, tz)`` (rad, m; right perturbation ``T·Exp(δ)``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jcalib.errors import BadInputError, NotObservableError
from jcalib.solve import linear
from jcalib.solve.lm import Solution, dict_to_blocks


def _scale(solution: Solution, noise: str) -> float:
    if noise == "stated":
        return 1.0
    if noise != "a_posteriori":
        raise BadInputError(f"noise: got {noise!r}, expected 'a_posteriori' or 'stated'.")
    if not solution.sigma2 == solution.sigma2:  # nan
        raise NotObservableError(
            f"The a-posteriori noise level needs more residuals ({solution.num_residuals}) than free "
            f"unknowns ({solution.num_free}); use noise='stated'.",
            ["sigma2"],
        )
    return solution.sigma2


@eqx.filter_jit
def _shared_inverse(system: linear.System):
    S, Vinvs = linear.reduced_system(system, None, None)
    n = S.shape[0]
    if n == 0:
        return S, Vinvs
    return jsl.cho_solve(jsl.cho_factor(S, lower=True), jnp.eye(n, dtype=S.dtype)), Vinvs


def _inverse_blocks(solution: Solution):
    cached = getattr(solution, "_cov_cache", None)
    if cached is None:
        cached = _shared_inverse(solution.raw.system)
        solution._cov_cache = cached
    return cached


def covariance(solution: Solution, name: str, index: int | None = None, noise: str = "a_posteriori"):
    """Covariance of variable ``name`` in its tangent space.

    Args:
        solution: a :class:`jcalib.solve.Solution`.
        name: variable name.
        index: one entry ``i`` -> ``(d, d)``; ``None`` -> the joint covariance of all entries,
            ``(num·d, num·d)``, entry-major (``(d, d)`` when ``num = 1``).
        noise: ``"a_posteriori"`` (scale by ``σ̂²``) or ``"stated"``.
    Returns:
        float64 array in tangent units squared (e.g. rad², m², px² for intrinsics in px).
    """
    var = solution.problem.variable(name)
    layout = solution.layout
    k = layout.kind(name)
    num, d = var.num, layout.dims[k]
    if index is not None and not (0 <= int(index) < num):
        raise BadInputError(f"covariance index for {name!r}: got {index}, expected 0 <= index < {num}.")
    scale = _scale(solution, noise)
    sigma_ss, Vinvs = _inverse_blocks(solution)
    free = jnp.where(solution.padded_problem.variable(name).fixed, 0.0, 1.0)  # (num_padded, d)
    if not layout.eliminate[k]:
        o = layout.offsets[k]
        if index is None:
            C = sigma_ss[o : o + num * d, o : o + num * d]
            f = free[:num].reshape(-1)
        else:
            a = o + int(index) * d
            C = sigma_ss[a : a + d, a : a + d]
            f = free[int(index)]
    else:
        slot = layout.elim_slot[k]
        Vinv = Vinvs[slot]
        W = solution.raw.system.W[slot]
        sel = slice(0, num) if index is None else slice(int(index), int(index) + 1)
        Vi = Vinv[sel]
        Y = jnp.einsum("nde,nse->nds", Vi, W[sel])  # V⁻¹ Wᵀ  (n, d, n_s)
        C = jnp.einsum("nds,st,mxt->ndmx", Y, sigma_ss, Y)
        nsel = Vi.shape[0]
        C = C + jnp.einsum("nm,nde->ndme", jnp.eye(nsel, dtype=C.dtype), Vi)
        C = C.reshape(nsel * d, nsel * d)
        f = free[sel].reshape(-1)
    return scale * C * f[:, None] * f[None, :]


def propagate(solution: Solution, fn: Callable[[dict], Any], noise: str = "a_posteriori"):
    """Covariance of a derived quantity ``y = fn(values)`` by linear propagation.

    ``Σ_y = J_y H⁻¹ J_yᵀ · σ̂²`` with ``J_y`` the JAX Jacobian of ``fn`` with respect to every
    variable's tangent (at the solution) and ``H⁻¹ J_yᵀ`` from the block (Schur) solver.

    Args:
        fn: ``fn(values) -> y`` with ``values`` as in :attr:`Solution.values`; ``y`` any shape ``(...)``,
            flattened to ``p`` components.
        noise: ``"a_posteriori"`` or ``"stated"``.
    Returns:
        ``(p, p)`` covariance of ``y.reshape(-1)`` in the units of ``y`` squared.
    """
    scale = _scale(solution, noise)
    return scale * _propagate(solution.padded_problem, solution.raw.system, solution.raw.values,
                              tuple(v.num for v in solution.problem.variables), fn)


@eqx.filter_jit
def _propagate(padded, system, values, nums, fn):
    layout = linear.make_layout(padded)
    free = linear.free_masks(padded)
    zeros = {v.name: jnp.zeros((v.num, v.tangent_dim), jnp.float64) for v in padded.variables}

    def y_of(deltas):
        x = linear.retract_all(padded, values, deltas)
        x = {v.name: x[v.name][:n] for v, n in zip(padded.variables, nums)}
        return jnp.reshape(jnp.asarray(fn(x)), (-1,))

    J = jax.jacfwd(y_of)(zeros)  # {name: (p, num, d)}
    Jt = {n: jnp.moveaxis(J[n], 0, -1) * free[n][..., None] for n in J}  # (num, d, p)
    rhs_s, rhs_e = dict_to_blocks(Jt, layout)
    z_s, z_e = linear.schur_solve(system, layout, rhs_s, rhs_e)
    out = rhs_s.T @ z_s
    for r, z in zip(rhs_e, z_e):
        out = out + jnp.einsum("ndp,ndq->pq", r, z)
    return 0.5 * (out + out.T)
