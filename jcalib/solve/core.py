"""The one solve path: ``solve(problem)`` and ``solve_many(problems)``.

A whole solve is **one** compiled function per problem structure and shape bucket
(:func:`jcalib.solve.batch.pad_problem`): the Levenberg–Marquardt loop (:func:`jcalib.solve.lm.lm_solve`),
then at the estimate every factor group's residuals, the inverse blocks of the information matrix
that every covariance is read from (``Σ_ss = S⁻¹`` of the Schur complement ``S`` and the eliminated
blocks ``V⁻¹``) and, on request, each factor group's share ``tr(H_g H⁻¹)`` of the unknowns (its
"hat trace", for variance components and redundancy). Outlier rounds and variance-component
iterations change only arrays (weights, σ) and re-use that compiled function. ``solve_many``
vmaps the same function over problems of one structure (Monte Carlo, fleets of identical cells).

The result is a host-side :class:`jcalib.solve.solution.Solution`: values, status, statistics per
factor group, covariances and the linear model — nothing outside ``solve/`` assembles normal
equations.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.solve import linear, traced
from jcalib.solve.batch import batch_width, bucket_size, pad_problem, stack_problems
from jcalib.solve.lm import Observability, RawSolution, SolveOptions, Status, after, lm_solve
from jcalib.solve.problem import Problem
from jcalib.solve.solution import Solution, marginal_information, unobservable_names


class Outcome(eqx.Module):
    """What the compiled solve returns (a pytree of arrays; batched under ``vmap``).

    Attributes:
        raw: the :class:`jcalib.solve.lm.RawSolution` (values, status, the information system).
        residuals: per factor group ``(K, m)`` residuals at the estimate, unwhitened (the factor's
            own unit, e.g. pixels), padded observations included.
        sigma_ss: ``(n_s, n_s)`` inverse of the Schur complement (shared unknowns).
        v_inv: per eliminated kind ``(num, d, d)`` inverse diagonal blocks.
        chi2: ``(G,)`` per factor group ``Σ_k ρ'(s_k) s_k`` of the whitened squared norms ``s_k``.
        count: ``(G,)`` residual components with nonzero weight per group.
        hat: ``(G,)`` per group ``tr(H_g H⁻¹)`` (zeros unless asked for).
    """

    raw: RawSolution
    residuals: tuple[jax.Array, ...]
    sigma_ss: jax.Array
    v_inv: tuple[jax.Array, ...]
    chi2: jax.Array
    count: jax.Array
    hat: jax.Array


def _hat_traces(raw: RawSolution, sigma_ss, v_inv) -> jax.Array:
    """``tr(H_g H⁻¹)`` of every factor group ``g`` from its own system and the inverse blocks.

    ``Σ_ee = V⁻¹ + V⁻¹Wᵀ Σ_ss W V⁻¹`` and ``Σ_es = −V⁻¹Wᵀ Σ_ss`` per eliminated entry; no dense inverse.
    """
    sigma_ee, sigma_es = [], []
    for W, Vinv in zip(raw.system.W, v_inv):
        Y = jnp.einsum("nde,nse->nds", Vinv, W)
        sigma_ee.append(Vinv + jnp.einsum("nds,st,nxt->ndx", Y, sigma_ss, Y))
        sigma_es.append(-jnp.einsum("nds,st->ndt", Y, sigma_ss))
    out = []
    for Hg in raw.groups:
        total = jnp.sum(Hg.H_ss * sigma_ss)
        for Vg, Wg, s_ee, s_es in zip(Hg.V, Hg.W, sigma_ee, sigma_es):
            total = total + jnp.einsum("nde,ned->", Vg, s_ee) + 2.0 * jnp.einsum("nsd,nds->", Wg, s_es)
        out.append(total)
    return jnp.stack(out) if out else jnp.zeros((0,), jnp.float64)


def _core(problem: Problem, options: SolveOptions, traces: bool) -> Outcome:
    raw = lm_solve(problem, options, per_group=traces)
    S, v_inv = linear.reduced_system(raw.system, None, None)
    # the Cholesky after the observability's eigen-decompositions: two batched LAPACK calls at once can
    # deadlock XLA:CPU's 2-thread pool (both waiting in ParallelBatchMap; seen in a vmapped batch)
    S = after(S, raw.observability)
    n = S.shape[0]
    sigma_ss = jsl.cho_solve(jsl.cho_factor(S, lower=True), jnp.eye(n, dtype=S.dtype)) if n else S
    residuals, chi2, count = [], [], []
    for f, r in zip(problem.factors, raw.residuals):  # the loop's residuals at the estimate
        w = f.sqrt_weight
        s = jnp.sum((r * (w / f.sigma)[:, None]) ** 2, axis=-1)
        _, rho1 = f.loss.rho(s)
        residuals.append(r)
        chi2.append(jnp.sum(jnp.where(w > 0.0, rho1 * s, 0.0)))
        count.append(jnp.sum(jnp.where(w > 0.0, r.shape[-1], 0)))
    hat = _hat_traces(raw, sigma_ss, v_inv) if traces else jnp.zeros((len(problem.factors),))
    # not needed on the host (the residuals travel once, in the Outcome)
    raw = eqx.tree_at(lambda r: (r.groups, r.residuals), raw, (None, None), is_leaf=lambda x: x is None)
    return Outcome(raw, tuple(residuals), sigma_ss, tuple(v_inv), jnp.stack(chi2), jnp.stack(count), hat)


_core_jit = eqx.filter_jit(_core)


def _outcome_treedef(problem: Problem):
    """The pytree structure of :func:`_core`'s output for ``problem``, from a skeleton (no tracing)."""
    names = tuple(v.name for v in problem.variables)
    return _skeleton_treedef(names, sum(bool(v.eliminate) for v in problem.variables), len(problem.factors))


@functools.lru_cache(maxsize=256)
def _skeleton_treedef(names: tuple[str, ...], e: int, num_factors: int):
    z = 0
    system = linear.System(z, z, (z,) * e, (z,) * e, (z,) * e)
    obs = Observability(z, z, (z,) * e, (z,) * e, z)
    raw = RawSolution(dict.fromkeys(names, z), z, z, z, z, z, system, obs, None)
    return jax.tree.structure(Outcome(raw, (z,) * num_factors, z, (z,) * e, z, z, z))
_core_vmap_jit = eqx.filter_jit(eqx.filter_vmap(_core, in_axes=(0, None, None)))


def check_finite_start(problem: Problem) -> None:
    """Raise :class:`BadInputError` naming the first variable with a non-finite start value."""
    for v in problem.variables:
        value = np.asarray(v.value)
        if not np.all(np.isfinite(value)):
            bad = np.argwhere(~np.isfinite(value))[0]
            raise BadInputError(
                f"Variable {v.name!r} value: entry {int(bad[0])} contains {value[tuple(bad)]}, expected finite numbers."
            )


def raise_if_unobservable(sol: Solution) -> None:
    if sol.status == Status.NOT_OBSERVABLE:
        unknowns = unobservable_names(sol.padded_problem, sol.layout, sol.raw.observability, sol.options.rank_rtol)
        raise NotObservableError(
            "The data do not determine these unknowns (rank-deficient information matrix at the "
            f"solution): {', '.join(unknowns)}. Fix them, add a prior, or collect data that constrains them.",
            unknowns,
        )


def solve(problem: Problem, x0: dict | None = None, options: SolveOptions = SolveOptions(), *,
          pad: bool = True, raise_on_unobservable: bool = True, traces: bool = False) -> Solution:
    """Solve ``problem`` by Levenberg–Marquardt, with covariance blocks, in one compiled call.

    Args:
        problem: the problem graph; start values from its variables unless ``x0`` overrides them.
        x0: optional ``{name: (num, param_dim)}`` start values.
        options: :class:`SolveOptions` (its tolerances and ``max_iterations`` do not recompile).
        pad: round variable and observation counts up to buckets (:func:`pad_problem`) so that a new
            data set of similar size reuses the compiled solve (and, with :func:`reuse_compiled_shapes`, a
            smaller problem of a structure already solved in this process is padded up to that shape).
        raise_on_unobservable: raise instead of returning ``Status.NOT_OBSERVABLE``.
        traces: also compute every factor group's ``tr(H_g H⁻¹)`` (:attr:`Solution.hat`), for
            variance components (a second linearisation at the estimate; a separate compiled function).
    Returns:
        :class:`Solution` (``status`` CONVERGED, MAX_ITERATIONS, or NON_FINITE when the residuals
        or Jacobians at the start are not finite).
    Raises:
        NotObservableError: the data do not determine some unknowns; ``err.unknowns`` names them.
        BadInputError: non-finite start values.
    """
    if x0 is not None:
        problem = problem.with_values(x0)
    check_finite_start(problem)
    padded = pad_problem(problem, **_fitted_shape(problem)) if pad else problem
    out = traced.run(_core, padded, options, bool(traces), _outcome_treedef(padded))
    if out is None:
        out = jax.device_get(_core_jit(padded, options.traced(), bool(traces)))
    sol = Solution(problem, padded, out, options)
    if raise_on_unobservable:
        raise_if_unobservable(sol)
    return sol


#: Shapes this process has solved, per problem structure: ``[(entries, obs)]`` (name -> padded count).
_SHAPES: dict = {}
_REUSE = {"on": False}


def reuse_compiled_shapes(on: bool = True) -> None:
    """From now on, let :func:`solve` run a problem at a larger shape already compiled in this process
    (:func:`_fitted_shape`): a long-lived process (the operator app) re-solves after a view is left out
    without compiling. The estimate then differs from the problem's own-shape solve by the solver's stopping
    tolerance (about 1e-7 σ), not more. Off by default: a command computes at its own shapes."""
    _REUSE["on"] = bool(on)
    if not on:
        _SHAPES.clear()
#: A smaller problem is padded up to a shape already compiled in this process when no count grows beyond
#: this factor (and this many entries): a re-solve with a view or a station left out costs no compilation.
SHAPE_REUSE_FACTOR = 2.0
SHAPE_REUSE_SLACK = 8


def _fitted_shape(problem: Problem) -> dict:
    """Padding targets for :func:`solve`: the problem's own shape buckets, or — with
    :func:`reuse_compiled_shapes` on, when this process has already solved a problem of the same structure
    whose counts are all at least these and at most :data:`SHAPE_REUSE_FACTOR` times them — the smallest such
    shape, so that the compiled solve is reused.

    Padded entries and observations add nothing to the solve (zero weight, fixed); sums of different lengths
    round differently (~1e-15 relative), which can move where Levenberg–Marquardt stops by its tolerance
    (~1e-7 σ). Returns ``{"num_entries", "num_obs"}`` for :func:`jcalib.solve.batch.pad_problem`.
    """
    own_entries = {v.name: bucket_size(v.num) for v in problem.variables}
    own_obs = {f.name: bucket_size(f.num_obs // (f.chunk or 1)) * (f.chunk or 1) for f in problem.factors}
    if not _REUSE["on"]:
        return {"num_entries": own_entries, "num_obs": own_obs}
    needed = {**{("v", n): v.num for n, v in zip(own_entries, problem.variables)},
              **{("f", f.name): f.num_obs for f in problem.factors}}
    try:
        key = (jax.tree.structure(problem),
               tuple(np.shape(x)[1:] for x in jax.tree.leaves(problem) if hasattr(x, "shape")))
        hash(key)
    except TypeError:  # an unhashable static field: no reuse
        return {"num_entries": own_entries, "num_obs": own_obs}
    best, best_size = None, None
    for entries, obs in _SHAPES.get(key, ()):
        counts = {**{("v", n): c for n, c in entries.items()}, **{("f", n): c for n, c in obs.items()}}
        if all(need <= counts[k] <= max(SHAPE_REUSE_FACTOR * need, need + SHAPE_REUSE_SLACK)
               for k, need in needed.items()):
            size = sum(counts.values())
            if best_size is None or size < best_size:
                best, best_size = (entries, obs), size
    if best is None:
        best = (own_entries, own_obs)
        shapes = _SHAPES.setdefault(key, [])
        if best not in shapes:
            shapes.append(best)
            del shapes[:-16]  # a bounded memory per structure
    return {"num_entries": dict(best[0]), "num_obs": dict(best[1])}


def solve_many(problems: Sequence[Problem], options: SolveOptions = SolveOptions(), *,
               traces: bool = False, width: int | None = None) -> list[Solution]:
    """Solve problems of one structure in vmapped, jitted calls; no exception on a bad status.

    Every problem is padded to the largest bucket among them (one shape), then solved ``width`` at a
    time (:func:`jcalib.solve.batch.batch_width` by default; a short last call is filled with copies).

    Raises:
        BadInputError: problems of different structure (variable or factor names, residual
            functions), or a non-positive ``width``.
    """
    problems = list(problems)
    if not problems:
        return []
    for p in problems:
        check_finite_start(p)
    structure = {jax.tree.structure(p) for p in problems}
    if len(structure) != 1:
        raise BadInputError("solve_many problems: got problems of different structure, expected one structure.")
    entries = {v.name: max(bucket_size(p.variable(v.name).num) for p in problems) for v in problems[0].variables}
    num_obs = {}
    for k, f in enumerate(problems[0].factors):
        c = f.chunk or 1
        num_obs[f.name] = max(bucket_size(p.factors[k].num_obs // c) for p in problems) * c
    padded = [pad_problem(p, num_entries=entries, num_obs=num_obs) for p in problems]
    width = batch_width(len(padded)) if width is None else int(width)
    if width < 1:
        raise BadInputError(f"solve_many width: got {width}, expected a positive integer")
    out: list[Solution] = []
    for start in range(0, len(padded), width):
        chunk = padded[start:start + width]
        filled = chunk + [chunk[-1]] * (width - len(chunk))
        batch = jax.device_get(_core_vmap_jit(stack_problems(filled), options.traced(), bool(traces)))
        for i, pp in enumerate(chunk):
            member = jax.tree.map(lambda a, i=i: a[i], batch)
            out.append(Solution(problems[start + i], pp, member, options))
    return out


def _information_core(problem: Problem) -> jax.Array:
    layout = linear.make_layout(problem)
    free = linear.free_masks(problem)
    _, system, _, _ = linear.linearize(problem, layout, problem.initial_values(), free)
    S, _ = linear.reduced_system(system, None, None)
    return S


_information_jit = eqx.filter_jit(_information_core)


def information(problem: Problem, names: Sequence[str], x0: dict | None = None, *, pad: bool = True) -> np.ndarray:
    """The Gauss–Newton information of the shared variables ``names`` at ``x0`` (no iteration).

    The problem is linearised once at its start values (overridden by ``x0``) with the solve's own
    linearisation (:func:`jcalib.solve.linear.linearize`: every factor group's residuals and Jacobians,
    robust weights, priors), the eliminated kinds are removed by the Schur complement, and every other
    shared unknown is marginalised (:func:`jcalib.solve.solution.marginal_information`). E.g. the
    information one more hypothetical station would add to a calibration, at its estimate.

    Args:
        problem: the problem graph (the factor groups' σ as stated: no variance factor is applied).
        names: shared (not eliminated) variables to keep, in this order.
        x0: optional ``{name: (num, param_dim)}`` values to linearise at.
        pad: round counts up to buckets (:func:`jcalib.solve.batch.pad_problem`) so that problems of
            similar size share one compiled linearisation.
    Returns:
        ``(n, n)`` information over the names' coordinates (entry-major, tangent order), in the inverse
        units of the tangent squared; fixed coordinates have zero rows and columns.
    Raises:
        BadInputError: non-finite values, or a name that is not a shared variable.
    """
    if x0 is not None:
        problem = problem.with_values(x0)
    check_finite_start(problem)
    padded = pad_problem(problem) if pad else problem
    S = np.asarray(jax.device_get(_information_jit(padded)))
    return marginal_information(S, linear.make_layout(padded), padded, names)
