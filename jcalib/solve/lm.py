"""Levenberg–Marquardt on the block-structured normal equations, as one jit-compiled while loop.

Algorithm (per iteration, all inside one ``lax.while_loop``):

1. Solve ``(H + μ D) h = −g`` by Schur complement (:func:`jcalib.solve.linear.schur_solve`), where
   ``H ≈ JᵀJ`` (IRLS-reweighted for robust losses) and ``D`` is Marquardt's scaling: the running
   maximum of ``diag(JᵀJ)`` (MINPACK), floored so untouched coordinates stay invertible.
2. Retract ``x' = x ⊞ h`` and linearise there (cost and Jacobian in one pass).
3. Gain ratio ``ϱ = (F(x) − F(x')) / (L(0) − L(h))``; accept when ``ϱ > 0``; Nielsen's update:
   ``μ ← μ·max(1/3, 1 − (2ϱ − 1)³), ν ← 2`` on success, ``μ ← μ·ν, ν ← 2ν`` on failure.
4. Converged when, after an accepted step, the predicted cost decrease is below ``ftol·cost``,
   the Marquardt-scaled step ``max_i |h_i|·√D_i`` is below ``xtol·‖r‖``, or the scaled gradient ``max |g_i| / (‖J_i‖ ‖r‖)`` (the cosine of
   MINPACK's ``gtol`` test) is below ``gtol``, or the whitened RMS residual is below ``xtol``
   (an exact fit: noiseless data); also when a step predicts less than ``ftol·cost`` or ``μ``
   overflows ``mu_max`` (no further progress possible).

This module is the pure loop; :func:`jcalib.solve.solve` wraps it with padding, the covariance blocks and
named errors in one compiled function. ``jax.vmap`` of :func:`lm_solve` solves many problems of one
shape at once. JAX's batching rule for
``while_loop`` keeps a finished member's state unchanged (``select`` on its own predicate), so each
member reports its own iterations and stops moving once converged, but the batch runs until the
slowest member finishes.
"""

from __future__ import annotations

import enum
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp

from jcalib.solve import linear
from jcalib.solve.problem import Problem


class Status(enum.IntEnum):
    """Outcome of a solve (the jitted solver returns the int code)."""

    CONVERGED = 0
    MAX_ITERATIONS = 1
    NOT_OBSERVABLE = 2
    NON_FINITE = 3


class SolveOptions(eqx.Module):
    """Solver settings.

    The tolerances, the damping settings and ``max_iterations`` are arguments of the compiled solve
    (:meth:`traced` turns them into arrays at the ``jit`` boundary): changing them re-uses the compiled
    function. The PCG settings and ``check_observability`` change the program and are static.

    Attributes:
        max_iterations: LM iterations (accepted or not).
        ftol: stop when the predicted cost decrease of a step is below ``ftol · cost`` (the
            resolution of a float64 cost is ~1e-16 relative, so 1e-14 is near the floor).
        xtol: stop when the Marquardt-scaled step ``max_i |h_i| √D_i`` is below ``xtol ‖r‖``.
        gtol: scaled-gradient (cosine) test.
        mu0: initial damping relative to Marquardt's scaling ``diag(JᵀJ)``.
        mu_max: damping beyond which the solve stops (no decrease possible).
        cg_threshold: reduced (shared) systems larger than this use block-Jacobi PCG, not Cholesky.
        cg_max_iterations, cg_tol: PCG settings.
        check_observability: run the rank analysis at the solution.
        rank_rtol: an eigenvalue of a Jacobi-scaled information block below ``rank_rtol`` times the
            block's largest flags an unobservable direction.
    """

    max_iterations: int = 100
    ftol: float = 1e-14
    xtol: float = 1e-10
    gtol: float = 1e-10
    mu0: float = 1e-4
    mu_max: float = 1e32
    cg_threshold: int = eqx.field(static=True, default=2000)
    cg_max_iterations: int = eqx.field(static=True, default=500)
    cg_tol: float = eqx.field(static=True, default=1e-12)
    check_observability: bool = eqx.field(static=True, default=True)
    rank_rtol: float = 1e-10

    def traced(self) -> SolveOptions:
        """These options with the numeric settings as arrays: passed to a ``jit``-ed solve they are
        arguments, not constants, so another ``max_iterations`` or tolerance does not recompile."""
        numbers = (self.max_iterations, self.ftol, self.xtol, self.gtol, self.mu0, self.mu_max, self.rank_rtol)
        if all(isinstance(x, (int, float)) for x in numbers):
            return eqx.tree_at(_numeric_fields, self, _traced_numbers(*numbers))
        return eqx.tree_at(_numeric_fields, self, (jnp.asarray(numbers[0], jnp.int32),
                                                   *(jnp.asarray(x, jnp.float64) for x in numbers[1:])))


def _numeric_fields(o: SolveOptions) -> tuple:
    return o.max_iterations, o.ftol, o.xtol, o.gtol, o.mu0, o.mu_max, o.rank_rtol


@functools.lru_cache(maxsize=64)
def _traced_numbers(max_iterations, *tolerances) -> tuple:
    """The options' numbers as arrays, made once per distinct setting (each ``jnp.asarray`` is a
    transfer: seven of them cost ~0.6 ms per solve)."""
    return (jnp.asarray(max_iterations, jnp.int32), *(jnp.asarray(x, jnp.float64) for x in tolerances))


class Observability(eqx.Module):
    """Eigen-analysis of the Jacobi-scaled information at the solution.

    Attributes:
        eigvals_s, eigvecs_s: of the scaled Schur complement ``(n_s,)``, ``(n_s, n_s)``.
        eigvals_e, eigvecs_e: per eliminated kind, of each scaled block ``(num, d)``, ``(num, d, d)``.
        deficient: scalar bool, some direction below ``rank_rtol``.
    """

    eigvals_s: jax.Array
    eigvecs_s: jax.Array
    eigvals_e: tuple[jax.Array, ...]
    eigvecs_e: tuple[jax.Array, ...]
    deficient: jax.Array


class RawSolution(eqx.Module):
    """Everything :func:`lm_solve` returns (a pytree of arrays; batched under ``vmap``).

    Attributes:
        values: ``{name: (num, param_dim)}`` the estimate.
        cost: ``½ Σ ρ(‖r_w‖²)`` at the estimate (whitened units).
        iterations: LM iterations used (int32).
        status: :class:`Status` code (int32).
        num_residuals: residual components with nonzero weight (int32).
        num_free: free tangent coordinates (int32).
        system: undamped Gauss–Newton system at the estimate (for covariances).
        observability: :class:`Observability` at the estimate.
        groups: with ``per_group``, each factor group's own system at the estimate (else None).
        residuals: per factor group ``(K, m)`` residuals at the estimate in the factor's own unit
            (from the loop's last linearisation; weight-0 observations included).
    """

    values: dict[str, jax.Array]
    cost: jax.Array
    iterations: jax.Array
    status: jax.Array
    num_residuals: jax.Array
    num_free: jax.Array
    system: linear.System
    observability: Observability
    groups: tuple | None = None
    residuals: tuple | None = None


def after(x, previous):
    """``x``, computed only once ``previous`` is: one batched LAPACK call at a time.

    XLA:CPU runs independent operations at once on its intra-op pool, and a batched LAPACK call
    waits there for sub-tasks it queued on that same pool; two of them at once can deadlock a
    2-thread pool (seen with batched ``trsm``, see :func:`jcalib.solve.linear.reduced_system`).
    """
    if previous is None:
        return x
    return jax.lax.optimization_barrier((x, previous))[0]


def _scaled_eigh(M):
    """Eigen-decomposition of ``M`` after Jacobi scaling (unit diagonal where ``diag > 0``)."""
    dg = jnp.diagonal(M, axis1=-2, axis2=-1)
    positive = dg > 0.0
    s = jnp.where(positive, 1.0 / jnp.sqrt(jnp.where(positive, dg, 1.0)), 0.0)
    Ms = M * s[..., :, None] * s[..., None, :]
    Ms = 0.5 * (Ms + jnp.swapaxes(Ms, -1, -2))
    return jnp.linalg.eigh(Ms)


def observability(system: linear.System, layout: linear.Layout, options: SolveOptions) -> Observability:
    """Rank analysis of the eliminated blocks ``V_i`` and of the Schur complement."""
    deficient = jnp.zeros((), bool)
    ev_e, evec_e = [], []
    w = None
    for V in system.V:
        w, U = _scaled_eigh(after(V, w))
        ev_e.append(w)
        evec_e.append(U)
        bad = w < options.rank_rtol * jnp.max(w, axis=-1, keepdims=True)
        deficient = deficient | jnp.any(bad) | ~jnp.all(jnp.isfinite(w))
    n = layout.n_shared
    if n > 0 and n <= options.cg_threshold:
        # Pseudo-damping keeps the Schur complement defined when some V_i is singular (that case
        # is already reported by the block analysis above).
        damp_e = tuple(1e-300 + jnp.zeros(V.shape[:-1], V.dtype) for V in system.V)
        S, _ = linear.reduced_system(system, None, damp_e)
        w_s, U_s = _scaled_eigh(after(S, w))
        deficient = deficient | jnp.any(w_s < options.rank_rtol * jnp.max(w_s)) | ~jnp.all(jnp.isfinite(w_s))
    else:
        w_s = jnp.ones((n,), jnp.float64)
        U_s = jnp.eye(n, dtype=jnp.float64)
    return Observability(w_s, U_s, tuple(ev_e), tuple(evec_e), deficient)


def _dot(a_s, a_e, b_s, b_e):
    out = jnp.vdot(a_s, b_s)
    for x, y in zip(a_e, b_e):
        out = out + jnp.vdot(x, y)
    return out


def _grad_ratio(system, diag_jtj_s, diag_jtj_e, cost):
    """MINPACK's scaled gradient: ``max_i |g_i| / (‖J_i‖ ‖r‖)`` over coordinates with ``‖J_i‖ > 0``."""
    rnorm = jnp.sqrt(2.0 * cost)

    def ratio(g, dg):
        den = jnp.sqrt(jnp.where(dg > 0.0, dg, 1.0)) * rnorm
        val = jnp.where((dg > 0.0) & (den > 0.0), jnp.abs(g) / jnp.where(den > 0.0, den, 1.0), 0.0)
        return jnp.max(val, initial=0.0)

    out = ratio(system.g_s, diag_jtj_s)
    for g, dg in zip(system.g_e, diag_jtj_e):
        out = jnp.maximum(out, ratio(g, dg))
    return out


def _residual_size(f, values: dict) -> int:
    """Components of one observation's residual (``f.fn`` traced for its shape only)."""
    rows = tuple(jax.ShapeDtypeStruct(values[a].shape[1:], values[a].dtype) for a in f.args)
    obs = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), f.observations)
    return math.prod(jax.eval_shape(f.fn, *rows, obs).shape)


def lm_solve(problem: Problem, options: SolveOptions = SolveOptions(), per_group: bool = False) -> RawSolution:
    """Pure, jit- and vmap-able Levenberg–Marquardt solve of ``problem`` from its start values.

    Args:
        problem: a :class:`Problem` (start values in ``problem.variables[i].value``).
        options: :class:`SolveOptions` (static).
        per_group: also carry each factor group's own system (:attr:`RawSolution.groups`), for its
            share of the unknowns (variance components) without a second linearisation.
    Returns:
        :class:`RawSolution`; ``status`` is an int code of :class:`Status`. Nothing raises inside:
        use :func:`solve` for checked, named errors.
    """
    layout = linear.make_layout(problem)
    free = linear.free_masks(problem)
    x0 = problem.initial_values()
    fixed_diag_s, fixed_diag_e = linear.diagonal(linear.add_fixed_identity(linear.empty_system(layout), layout, free))

    def lin(x):
        return linear.linearize(problem, layout, x, free, per_group, residuals=True)

    def jtj_diag(system):
        ds, de = linear.diagonal(system)
        return ds - fixed_diag_s, tuple(a - b for a, b in zip(de, fixed_diag_e))

    def all_finite(system, cost):
        ok = jnp.isfinite(cost) & jnp.all(jnp.isfinite(system.g_s)) & jnp.all(jnp.isfinite(system.H_ss))
        for V, W, g in zip(system.V, system.W, system.g_e):
            ok = ok & jnp.all(jnp.isfinite(V)) & jnp.all(jnp.isfinite(W)) & jnp.all(jnp.isfinite(g))
        return ok

    # The first pass through the loop body linearises at x0 (a zero step, accepted unconditionally):
    # the residual functions are traced once, which keeps compile time down.
    init = dict(
        x=x0,
        system=linear.empty_system(layout),
        groups=tuple(linear.empty_system(layout) for _ in problem.factors) if per_group else None,
        residuals=tuple(jnp.zeros((f.num_obs, _residual_size(f, x0)), jnp.float64) for f in problem.factors),
        cost=jnp.asarray(jnp.inf, jnp.float64),
        mu=jnp.asarray(options.mu0, jnp.float64),
        nu=jnp.asarray(2.0, jnp.float64),
        D_s=fixed_diag_s,
        D_e=fixed_diag_e,
        it=jnp.asarray(-1, jnp.int32),
        done=jnp.zeros((), bool),
        status=jnp.int32(Status.CONVERGED),
        m_eff=jnp.zeros((), jnp.int32),
    )

    def cond(st):
        return ~st["done"] & (st["it"] < options.max_iterations)

    def body(st):
        system, cost, mu = st["system"], st["cost"], st["mu"]
        first = st["it"] < 0
        h_s, h_e = linear.schur_solve(
            system, layout, -system.g_s[:, None], tuple(-g[..., None] for g in system.g_e),
            mu * st["D_s"], tuple(mu * d for d in st["D_e"]),
            options.cg_threshold, options.cg_max_iterations, options.cg_tol,
        )
        h_s = h_s[:, 0]
        h_e = tuple(h[..., 0] for h in h_e)
        h_ok = jnp.all(jnp.isfinite(h_s))
        for h in h_e:
            h_ok = h_ok & jnp.all(jnp.isfinite(h))
        h_s = jnp.where(h_ok & ~first, h_s, 0.0)
        h_e = tuple(jnp.where(h_ok & ~first, h, 0.0) for h in h_e)
        x_new = linear.retract_all(problem, st["x"], linear.deltas_to_dict(h_s, h_e, layout))
        x_new = jax.tree.map(lambda a, b: jnp.where(first, a, b), st["x"], x_new)
        cost_new, sys_new, m_eff, groups_new, res_new = lin(x_new)
        Hh_s, Hh_e = linear.matvec(system, h_s, h_e)
        hHh = _dot(h_s, h_e, Hh_s, Hh_e)
        gh = _dot(system.g_s, system.g_e, h_s, h_e)
        pred = -gh - 0.5 * hHh
        actual = cost - cost_new
        new_ok = all_finite(sys_new, cost_new)
        rho = jnp.where(pred > 0.0, actual / jnp.where(pred > 0.0, pred, 1.0), -1.0)
        # a step whose predicted decrease is at the resolution of the cost (≤ ftol·cost) is taken
        # unless it raises the cost by more than that resolution: its measured change is rounding
        # noise, and whether such a last Gauss–Newton step is kept must not depend on it
        at_resolution = (pred > 0.0) & (pred <= options.ftol * cost) & (actual >= -options.ftol * cost)
        accept = (h_ok & new_ok & (pred > 0.0) & ((rho > 0.0) | at_resolution) & ~first) | (first & new_ok)
        no_progress = h_ok & (pred <= options.ftol * cost) & ~first

        ds_new, de_new = jtj_diag(sys_new)
        # step in Marquardt-scaled coordinates, relative to the residual norm (MINPACK's xtol test
        # in the units of the data; catches slow progress along correlated directions that a
        # residual-space test would miss)
        scaled_step = jnp.max(jnp.abs(h_s) * jnp.sqrt(st["D_s"]), initial=0.0)
        for h, d in zip(h_e, st["D_e"]):
            scaled_step = jnp.maximum(scaled_step, jnp.max(jnp.abs(h) * jnp.sqrt(d), initial=0.0))
        small_step = (scaled_step <= options.xtol * jnp.sqrt(2.0 * cost)) & ~first
        # predicted decrease below ftol·cost: further steps are at the resolution of the cost
        small_decrease = (pred <= options.ftol * cost) & ~first
        small_grad = _grad_ratio(sys_new, ds_new, de_new, cost_new) <= options.gtol
        # exact fit (noiseless data): whitened RMS below xtol, i.e. below xtol·σ
        exact_fit = 2.0 * cost_new <= (options.xtol**2) * m_eff.astype(jnp.float64)
        converged_after_accept = small_step | small_decrease | small_grad | exact_fit

        mu_acc = jnp.where(first, mu, mu * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
        mu_rej = mu * st["nu"]
        new_mu = jnp.where(accept, mu_acc, mu_rej)
        new_nu = jnp.where(accept, 2.0, 2.0 * st["nu"])
        stalled = ~accept & (mu_rej > options.mu_max)

        def pick(a, b):
            return jax.tree.map(lambda u, v: jnp.where(accept, u, v), a, b)

        # Marquardt scaling: running max of diag(JᵀJ), floored so untouched coordinates stay invertible
        dmax = jnp.max(ds_new, initial=0.0)
        for d in de_new:
            dmax = jnp.maximum(dmax, jnp.max(d, initial=0.0))
        floor = 1e-12 * jnp.maximum(dmax, 1e-300)
        D_s = jnp.where(accept, jnp.maximum(st["D_s"], jnp.maximum(ds_new, floor) + fixed_diag_s), st["D_s"])
        D_e = tuple(jnp.where(accept, jnp.maximum(d, jnp.maximum(n, floor) + f), d)
                    for d, n, f in zip(st["D_e"], de_new, fixed_diag_e))
        non_finite_start = first & ~new_ok
        done = (accept & converged_after_accept) | (~accept & (no_progress | stalled)) | non_finite_start
        return dict(
            x=pick(x_new, st["x"]),
            system=pick(sys_new, system),
            groups=pick(groups_new, st["groups"]) if per_group else None,
            residuals=jax.tree.map(lambda u, v: jnp.where(accept | first, u, v), res_new, st["residuals"]),
            cost=jnp.where(accept | first, cost_new, cost),
            mu=new_mu,
            nu=new_nu,
            D_s=D_s,
            D_e=D_e,
            it=st["it"] + 1,
            done=done,
            status=jnp.where(non_finite_start, jnp.int32(Status.NON_FINITE), st["status"]),
            m_eff=m_eff,
        )

    st = jax.lax.while_loop(cond, body, init)
    status = jnp.where(st["done"], st["status"], jnp.int32(Status.MAX_ITERATIONS))
    if options.check_observability:
        obs = observability(st["system"], layout, options)
        status = jnp.where((status != Status.NON_FINITE) & obs.deficient, jnp.int32(Status.NOT_OBSERVABLE), status)
    else:
        obs = Observability(
            jnp.ones((layout.n_shared,)), jnp.eye(layout.n_shared), tuple(jnp.ones(d.shape) for d in st["D_e"]),
            tuple(jnp.broadcast_to(jnp.eye(d.shape[-1]), d.shape + (d.shape[-1],)) for d in st["D_e"]),
            jnp.zeros((), bool),
        )
    num_free = sum(jnp.sum(~v.fixed).astype(jnp.int32) for v in problem.variables)
    return RawSolution(
        values=st["x"],
        cost=st["cost"],
        iterations=st["it"],
        status=status.astype(jnp.int32),
        num_residuals=st["m_eff"],
        num_free=jnp.asarray(num_free, jnp.int32),
        system=st["system"],
        observability=obs,
        groups=st["groups"],
        residuals=st["residuals"],
    )
