"""Shape buckets and batches: padding a problem so that data sets of similar size share one compiled
solve, and stacking same-shape problems for one vmapped call.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jcalib.solve.problem import Problem, replace


def bucket_size(n: int) -> int:
    """Round a count up to a bucket: multiples of ``2^(⌊log2 n⌋ - 2)`` (at most 25 % padding)."""
    if n <= 8:
        return max(n, 1)
    step = 2 ** (int(math.floor(math.log2(n))) - 2)
    return int(-(-n // step) * step)


def batch_width(num: int) -> int:
    """Data sets per vmapped call when ``num`` same-shape problems are solved in batches.

    On XLA:CPU a batch costs what its members cost one by one (the work is compute, not dispatch)
    and a ``while_loop`` over 64+ members stalled, so calls take at most 8 members. On an
    accelerator (GPU/TPU) one call takes the whole group, rounded up to a :func:`bucket_size` so that
    groups of similar size share one compiled width. Callers fill a call that has fewer members than
    the width with copies of one of them.
    """
    return min(num, 8) if jax.default_backend() == "cpu" else bucket_size(num)


def pad_problem(problem: Problem, size_fn: Callable[[int], int] = bucket_size, *,
                num_entries: dict[str, int] | None = None, num_obs: dict[str, int] | None = None) -> Problem:
    """Pad every variable kind and factor group to ``size_fn(count)`` entries / observations.

    Padded variable entries copy entry 0 and are fully fixed (no unknowns, zero covariance).
    Padded observations copy observation 0, point at entry 0 of each argument (valid indices) and
    have ``sqrt_weight = 0``, so they add nothing to cost, gradient or Hessian. Padding goes at
    the end: entry ``i`` and observation ``k`` keep their positions.

    ``num_entries`` (variable name -> entries) and ``num_obs`` (factor group name -> observations,
    whole runs of a chunked group) give explicit targets instead, e.g. one shape shared by a batch
    of problems; names they leave out use ``size_fn``.
    """
    num_entries, num_obs = num_entries or {}, num_obs or {}

    def xp(*arrays):  # NumPy on the host, JAX inside a trace
        return jnp if any(isinstance(a, jax.core.Tracer) for a in arrays) else np

    new_vars = []
    for v in problem.variables:
        n = v.num
        target = num_entries.get(v.name, size_fn(n))
        extra = target - n
        if extra:
            m = xp(v.value, v.fixed)
            value = m.concatenate([v.value, m.broadcast_to(v.value[:1], (extra, v.value.shape[1]))])
            fixed = m.concatenate([v.fixed, m.ones((extra, v.fixed.shape[1]), dtype=bool)])
            v = replace(v, value=value, fixed=fixed)
        new_vars.append(v)
    new_factors = []
    for f in problem.factors:
        k = f.num_obs
        c = f.chunk or 1
        # whole runs of copies of observation 0
        extra = num_obs[f.name] - k if f.name in num_obs else (size_fn(k // c) - k // c) * c
        if extra and k > 0:

            def pad(a, extra=extra):
                m = xp(a)
                return m.concatenate([a, m.broadcast_to(a[:1], (extra,) + a.shape[1:])])

            f = replace(
                f,
                indices=tuple(xp(i).concatenate([i, xp(i).zeros((extra,), i.dtype)]) for i in f.indices),
                observations=jax.tree.map(pad, f.observations),
                sqrt_weight=xp(f.sqrt_weight).concatenate([f.sqrt_weight,
                                                           xp(f.sqrt_weight).zeros((extra,), np.float64)]),
            )
        new_factors.append(f)
    return replace(problem, variables=tuple(new_vars), factors=tuple(new_factors))


def stack_problems(problems: Sequence[Problem]) -> Problem:
    """Stack same-shaped problems along a new leading axis (for ``jax.vmap``)."""
    return jax.tree.map(lambda *xs: np.stack(xs), *problems)
