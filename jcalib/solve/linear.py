"""Block-structured normal equations: linearisation, assembly, Schur-complement solves.

Unknowns split into **shared** coordinates (all non-eliminated variable kinds, concatenated into one
vector of length ``n_s``; entry-major, tangent order) and **eliminated** kinds (``num`` blocks of
``d`` coordinates each). The Hessian is held as

- ``H_ss (n_s, n_s)``: dense shared block;
- per eliminated kind ``V (num, d, d)`` (block-diagonal) and ``W (num, n_s, d)`` (shared × block);

and never as one dense matrix of the whole problem. Jacobians come from ``vmap(jacrev)`` (or
``jacfwd`` when the residual has at least as many components as the tangent) per factor group with
respect to each argument's tangent (first-order retraction at zero, see ``retract_linear``), summed
per entry (pair) with whole-block windows into the blocks. Fixed tangent coordinates get zero
Jacobian columns and an identity diagonal (so every solve returns exactly 0 for them and the matrices stay invertible).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jcalib.solve.problem import Problem


class Layout(NamedTuple):
    """Static bookkeeping of where each variable kind lives (all Python ints)."""

    names: tuple[str, ...]
    nums: tuple[int, ...]
    dims: tuple[int, ...]
    eliminate: tuple[bool, ...]
    offsets: tuple[int, ...]  # into the shared vector; -1 for eliminated kinds
    elim_slot: tuple[int, ...]  # position among eliminated kinds; -1 for shared kinds
    n_shared: int

    @property
    def num_elim(self) -> int:
        return sum(self.eliminate)

    def kind(self, name: str) -> int:
        return self.names.index(name)


def make_layout(problem: Problem) -> Layout:
    offsets, slots = [], []
    off = 0
    slot = 0
    for v in problem.variables:
        if v.eliminate:
            offsets.append(-1)
            slots.append(slot)
            slot += 1
        else:
            offsets.append(off)
            slots.append(-1)
            off += v.num * v.tangent_dim
    return Layout(
        names=tuple(v.name for v in problem.variables),
        nums=tuple(v.num for v in problem.variables),
        dims=tuple(v.tangent_dim for v in problem.variables),
        eliminate=tuple(v.eliminate for v in problem.variables),
        offsets=tuple(offsets),
        elim_slot=tuple(slots),
        n_shared=off,
    )


class System(eqx.Module):
    """Block normal equations ``H δ = -g`` (``H ≈ JᵀJ`` or the exact Hessian; whitened units).

    Attributes:
        H_ss: ``(n_s, n_s)`` shared block.
        g_s: ``(n_s,)`` shared gradient.
        V: per eliminated kind, ``(num, d, d)`` diagonal blocks.
        W: per eliminated kind, ``(num, n_s, d)`` coupling blocks (rows: shared).
        g_e: per eliminated kind, ``(num, d)`` gradient.
    """

    H_ss: jax.Array
    g_s: jax.Array
    V: tuple[jax.Array, ...]
    W: tuple[jax.Array, ...]
    g_e: tuple[jax.Array, ...]


def free_masks(problem: Problem) -> dict[str, jax.Array]:
    """``{name: (num, d) float}``: 1 for free tangent coordinates, 0 for fixed ones."""
    return {v.name: jnp.where(v.fixed, 0.0, 1.0) for v in problem.variables}


def retract_all(problem: Problem, values: dict, deltas: dict) -> dict:
    """Apply ``x ⊞ δ`` entry-wise to every kind (re-normalised); fully fixed entries keep ``x`` bit for bit.

    Kinds of one manifold class and parameter size are retracted together (their rows stacked): one
    copy of the group's exponential in the compiled program, not one per kind.
    """
    groups: dict[tuple, list] = {}
    out = {}
    for v in problem.variables:
        if v.constant:
            out[v.name] = values[v.name]
        else:
            groups.setdefault((type(v.manifold), v.manifold.param_dim, v.manifold.tangent_dim), []).append(v)
    for members in groups.values():
        m = members[0].manifold
        x = jnp.concatenate([values[v.name] for v in members])
        new = jax.vmap(m.normalize)(jax.vmap(m.retract)(x, jnp.concatenate([deltas[v.name] for v in members])))
        start = 0
        for v in members:
            n = v.num
            any_free = jnp.any(~v.fixed, axis=-1)
            out[v.name] = jnp.where(any_free[:, None], new[start:start + n], values[v.name])
            start += n
    return {v.name: out[v.name] for v in problem.variables}


def _obs_residual(f, manifolds, first_order: bool = False, raw: bool = False):
    """Whitened residual of one observation as a function of the argument tangents.

    ``first_order=True`` uses the manifolds' ``retract_linear`` (right value and first derivative
    at ``δ = 0`` only): for Gauss–Newton Jacobians, not for second derivatives. ``raw=True`` also
    returns the unwhitened residual (the factor's own unit; also where the weight is 0).
    """

    def r_obs(rows, deltas, obs, w):
        if first_order:
            params = [m.retract_linear(x, d) for m, x, d in zip(manifolds, rows, deltas)]
        else:
            params = [m.retract(x, d) for m, x, d in zip(manifolds, rows, deltas)]
        r = jnp.asarray(f.fn(*params, obs))
        # weight 0 (padding, masked outliers): exact zero, finite derivatives even if r is not.
        r_w = jnp.where(w > 0.0, r * (w / f.sigma), jnp.zeros_like(r))
        return (r_w, r) if raw else r_w

    return r_obs


def _factor_parts(problem: Problem, f):
    by_name = {v.name: v for v in problem.variables}
    manifolds = [by_name[a].manifold for a in f.args]
    dims = [m.tangent_dim for m in manifolds]
    return by_name, manifolds, dims


def active_args(problem: Problem, f) -> tuple[int, ...]:
    """Positions of ``f``'s arguments that are not :attr:`Variable.constant` (differentiated)."""
    by_name = {v.name: v for v in problem.variables}
    return tuple(j for j, a in enumerate(f.args) if not by_name[a].constant)


def factor_linearization(problem: Problem, values: dict, f, free: dict):
    """Per-observation Gauss–Newton blocks of one factor group (IRLS-reweighted).

    Derivatives are taken with respect to the non-constant arguments only (:func:`active_args`),
    by autodiff of ``f.fn`` or from the group's hand-derived ``f.jacobian`` when it has one.

    Returns:
        cost: scalar ``½ Σ ρ(s_k)``; H_obs ``(K, D, D)``; g_obs ``(K, D)``;
        r_w ``(K, m)`` whitened, reweighted residuals; J ``(K, m, D)`` reweighted Jacobian;
        m_eff: number of residual components with nonzero weight; r_raw ``(K, m)`` the residuals in
        the factor's own unit (weight 0 included: the estimate's residuals, without evaluating
        ``f.fn`` again). ``D`` = sum of the active
        arguments' tangent dims. For a chunked group (``f.chunk``), ``H_obs`` and ``g_obs`` are
        per run ``(K / chunk, D, D)``, ``(K / chunk, D)``, summed by one batched product.
    """
    by_name, manifolds, dims = _factor_parts(problem, f)
    active = active_args(problem, f)
    r_obs = _obs_residual(f, manifolds, first_order=True, raw=True)
    rows = tuple(values[a][i] for a, i in zip(f.args, f.indices))
    zeros = tuple(jnp.zeros((f.num_obs, dims[j]), jnp.float64) for j in active)
    n_args = len(f.args)

    def value_and_jac(rows_k, deltas_k, obs_k, w_k):
        def g(*ds):
            full = [jnp.zeros((dims[j],), jnp.float64) for j in range(n_args)]
            for j, d in zip(active, ds):
                full[j] = d
            r, r_raw = r_obs(rows_k, full, obs_k, w_k)
            return r, (r, r_raw)

        # reverse mode when the residual has fewer components than the tangent (e.g. 2 pixels vs
        # 15 tangent directions in camera calibration): m backward passes instead of D forward ones
        m = math.prod(jax.eval_shape(g, *deltas_k)[0].shape)
        D = sum(dims[j] for j in active)
        jac_fn = jax.jacrev if m < D else jax.jacfwd
        jac, (r, r_raw) = jac_fn(g, argnums=tuple(range(len(active))), has_aux=True)(*deltas_k)
        return r, jnp.concatenate(jac, axis=-1), r_raw

    def given_jacobian(rows_k, obs_k, w_k):  # the factor's hand-derived linearisation
        r, Js = f.jacobian(*rows_k, obs_k)
        J = jnp.concatenate([Js[j] for j in active], axis=-1)
        s = w_k / f.sigma
        return (jnp.where(w_k > 0.0, r * s, jnp.zeros_like(r)),
                jnp.where(w_k > 0.0, J * s, jnp.zeros_like(J)), r)

    if f.jacobian is not None and active:
        r, J, r_raw = jax.vmap(given_jacobian)(rows, f.observations, f.sqrt_weight)
    else:
        r, J, r_raw = jax.vmap(value_and_jac)(rows, zeros, f.observations, f.sqrt_weight)
    s = jnp.sum(r * r, axis=-1)
    rho, rho1 = f.loss.rho(s)
    sw = jnp.sqrt(rho1)
    r = r * sw[:, None]
    J = J * sw[:, None, None]

    def free_mask(step=1):  # (K / step, D): which tangent coordinates of the arguments are free
        return jnp.concatenate([free[f.args[j]][f.indices[j][::step]] for j in active], axis=-1).astype(J.dtype)

    if f.chunk is not None:
        # one argument entry per run: mask the (runs, D, D) blocks, not the (K, m, D) Jacobian
        K, m_, D = J.shape
        Jc = J.reshape(K // f.chunk, f.chunk * m_, D)
        rc = r.reshape(K // f.chunk, f.chunk * m_)
        mask_run = free_mask(f.chunk)
        H_obs = jnp.einsum("cri,crj->cij", Jc, Jc) * mask_run[:, :, None] * mask_run[:, None, :]
        g_obs = jnp.einsum("cri,cr->ci", Jc, rc) * mask_run
        J = J * free_mask()[:, None, :]  # returned only (dead code under jit where unused)
    else:
        J = J * free_mask()[:, None, :]
        H_obs = jnp.einsum("kmi,kmj->kij", J, J)
        g_obs = jnp.einsum("kmi,km->ki", J, r)
    m_eff = jnp.sum(jnp.where(f.sqrt_weight > 0.0, 1, 0)) * r.shape[-1]
    return 0.5 * jnp.sum(rho), H_obs, g_obs, r, J, m_eff, r_raw.reshape(r_raw.shape[0], -1)


def factor_exact_hessian(problem: Problem, values: dict, f, free: dict):
    """Per-observation exact Hessian and gradient of ``½ ρ(‖r_w‖²)`` w.r.t. the argument tangents.

    Used by implicit differentiation (the optimality condition needs the full second derivative,
    not Gauss–Newton). Returns ``H_obs (K, D, D)``, ``g_obs (K, D)``, masked by the free mask.
    """
    by_name, manifolds, dims = _factor_parts(problem, f)
    r_obs = _obs_residual(f, manifolds)
    rows = tuple(values[a][i] for a, i in zip(f.args, f.indices))
    splits = np.cumsum(dims)[:-1].tolist()

    def c_obs(delta, rows_k, obs_k, w_k):
        r = r_obs(rows_k, tuple(jnp.split(delta, splits)), obs_k, w_k)
        return 0.5 * f.loss.rho(jnp.sum(r * r))[0]

    zero = jnp.zeros((f.num_obs, sum(dims)), jnp.float64)
    H_obs = jax.vmap(jax.hessian(c_obs))(zero, rows, f.observations, f.sqrt_weight)
    g_obs = jax.vmap(jax.grad(c_obs))(zero, rows, f.observations, f.sqrt_weight)
    mask = jnp.concatenate([free[a][i] for a, i in zip(f.args, f.indices)], axis=-1)
    return H_obs * mask[:, :, None] * mask[:, None, :], g_obs * mask


def empty_system(layout: Layout) -> System:
    n = layout.n_shared
    V, W, g_e = [], [], []
    for k in range(len(layout.names)):
        if layout.eliminate[k]:
            N, d = layout.nums[k], layout.dims[k]
            V.append(jnp.zeros((N, d, d), jnp.float64))
            W.append(jnp.zeros((N, n, d), jnp.float64))
            g_e.append(jnp.zeros((N, d), jnp.float64))
    return System(jnp.zeros((n, n), jnp.float64), jnp.zeros((n,), jnp.float64), tuple(V), tuple(W), tuple(g_e))


def _segment_blocks(blocks, idx, num: int):
    """``out[n] = Σ_{k: idx[k] = n} blocks[k]`` for ``blocks (K, ...)``, ``idx (K,)`` -> ``(num, ...)``.

    One entry (``num == 1``) is a plain sum; otherwise one scatter with whole-block windows (one
    index per observation, not one per matrix element, which is what makes XLA's CPU scatter slow).
    """
    if num == 1:
        return jnp.sum(blocks, axis=0)[None]
    return jax.ops.segment_sum(blocks, idx, num_segments=num)


def _pair_blocks(blocks, idx_a, num_a: int, idx_b, num_b: int):
    """``out[i, j] = Σ_{k: idx_a[k] = i, idx_b[k] = j} blocks[k]`` -> ``(num_a, num_b, ...)``."""
    if num_a == 1:
        return _segment_blocks(blocks, idx_b, num_b)[None]
    if num_b == 1:
        return _segment_blocks(blocks, idx_a, num_a)[:, None]
    flat = _segment_blocks(blocks, idx_a * num_b + idx_b, num_a * num_b)
    return flat.reshape((num_a, num_b) + blocks.shape[1:])


def _factor_slots(layout: Layout, f, active=None):
    """Per active argument ``(kind, offset or -1, elim slot or -1, num, d, positions in the factor tangent)``."""
    out, pos = [], 0
    args = f.args if active is None else tuple(f.args[j] for j in active)
    for a in args:
        k = layout.kind(a)
        d = layout.dims[k]
        out.append((k, layout.offsets[k], layout.elim_slot[k], layout.nums[k], d, slice(pos, pos + d)))
        pos += d
    return out


def scatter_factor(system: System, layout: Layout, f, H_obs, g_obs, active=None, chunked: bool = False) -> System:
    """Add one factor group's per-observation blocks into the block system.

    When the argument entries have at most ``K`` combinations (e.g. camera calibration: one
    intrinsics entry, one rig entry, one view pose per observation), the blocks are first summed
    per combination with one whole-block ``segment_sum`` and then reduced densely; otherwise each
    (argument pair) is summed with its own whole-block ``segment_sum``. Both avoid one scatter
    index per matrix element, which is what makes XLA's CPU scatter slow.
    """
    active = tuple(range(len(f.args))) if active is None else tuple(active)
    slots = _factor_slots(layout, f, active)
    indices = tuple(f.indices[j] for j in active)
    if chunked:  # one block per run: the run's first index
        indices = tuple(i[:: f.chunk] for i in indices)
    if not slots:
        return system
    nums = tuple(s[3] for s in slots)
    if math.prod(nums) <= max(H_obs.shape[0], 1):
        return _scatter_grouped(system, slots, indices, H_obs, g_obs)
    return _scatter_pairs(system, slots, indices, H_obs, g_obs)


def _scatter_grouped(system: System, slots, indices, H_obs, g_obs) -> System:
    nums = tuple(s[3] for s in slots)
    n_args = len(slots)
    key = jnp.zeros_like(indices[0])
    for idx, num in zip(indices, nums):
        key = key * num + idx
    P = math.prod(nums)
    D = H_obs.shape[-1]
    G = jax.ops.segment_sum(H_obs, key, num_segments=P).reshape(nums + (D, D))
    Gg = jax.ops.segment_sum(g_obs, key, num_segments=P).reshape(nums + (D,))

    def keep(*axes):  # sum over every argument axis except ``axes`` (kept in that order)
        return tuple(i for i in range(n_args) if i not in axes)

    H_ss, g_s = system.H_ss, system.g_s
    V, W, g_e = list(system.V), list(system.W), list(system.g_e)
    for i, (_, off_a, slot_a, num_a, d_a, pa) in enumerate(slots):
        if slot_a >= 0:
            V[slot_a] = V[slot_a] + jnp.sum(G[..., pa, pa], axis=keep(i))
            g_e[slot_a] = g_e[slot_a] + jnp.sum(Gg[..., pa], axis=keep(i))
            continue
        g_s = g_s.at[off_a:off_a + num_a * d_a].add(jnp.sum(Gg[..., pa], axis=keep(i)).reshape(-1))
        for j, (_, off_b, slot_b, num_b, d_b, pb) in enumerate(slots):
            if j == i:
                blk = jnp.sum(G[..., pa, pa], axis=keep(i))  # (num_a, d_a, d_a): block diagonal
                full = (blk[:, :, None, :] * jnp.eye(num_a, dtype=blk.dtype)[:, None, :, None])
                H_ss = H_ss.at[off_a:off_a + num_a * d_a, off_a:off_a + num_a * d_a].add(
                    full.reshape(num_a * d_a, num_a * d_a))
                continue
            blk = G[..., pa, pb]
            # axes i, j kept -> (num_a, num_b, d_a, d_b), in argument order i, j
            blk = jnp.sum(blk, axis=keep(i, j))
            if j < i:
                blk = jnp.swapaxes(blk, 0, 1)
            if slot_b >= 0:  # W[e, shared a, e-coords] += H[a, e]
                W[slot_b] = W[slot_b].at[:, off_a:off_a + num_a * d_a].add(
                    jnp.transpose(blk, (1, 0, 2, 3)).reshape(num_b, num_a * d_a, d_b))
            else:
                H_ss = H_ss.at[off_a:off_a + num_a * d_a, off_b:off_b + num_b * d_b].add(
                    jnp.transpose(blk, (0, 2, 1, 3)).reshape(num_a * d_a, num_b * d_b))
    return System(H_ss, g_s, tuple(V), tuple(W), tuple(g_e))


def _scatter_pairs(system: System, slots, indices, H_obs, g_obs) -> System:
    shared, elim = [], None
    for (_, off, slot, num, d, pos), idx in zip(slots, indices):
        if slot >= 0:
            elim = (slot, num, d, idx, pos)
        else:
            shared.append((off, num, d, idx, pos))
    H_ss, g_s = system.H_ss, system.g_s
    V, W, g_e = list(system.V), list(system.W), list(system.g_e)
    for off_a, num_a, d_a, idx_a, pa in shared:
        ga = _segment_blocks(g_obs[:, pa], idx_a, num_a)  # (num_a, d_a)
        g_s = g_s.at[off_a:off_a + num_a * d_a].add(ga.reshape(-1))
        for off_b, num_b, d_b, idx_b, pb in shared:
            hab = _pair_blocks(H_obs[:, pa, pb], idx_a, num_a, idx_b, num_b)  # (num_a, num_b, d_a, d_b)
            hab = jnp.transpose(hab, (0, 2, 1, 3)).reshape(num_a * d_a, num_b * d_b)
            H_ss = H_ss.at[off_a:off_a + num_a * d_a, off_b:off_b + num_b * d_b].add(hab)
    if elim is not None:
        slot, num_e, d_e, idx_e, pe = elim
        V[slot] = V[slot] + _segment_blocks(H_obs[:, pe, pe], idx_e, num_e)
        g_e[slot] = g_e[slot] + _segment_blocks(g_obs[:, pe], idx_e, num_e)
        for off_a, num_a, d_a, idx_a, pa in shared:
            wa = _pair_blocks(H_obs[:, pa, pe], idx_e, num_e, idx_a, num_a)  # (num_e, num_a, d_a, d_e)
            W[slot] = W[slot].at[:, off_a:off_a + num_a * d_a].add(wa.reshape(num_e, num_a * d_a, d_e))
    return System(H_ss, g_s, tuple(V), tuple(W), tuple(g_e))


def add_fixed_identity(system: System, layout: Layout, free: dict) -> System:
    """Put 1 on the diagonal of every fixed coordinate (its rows/columns are zero already)."""
    fixed_s = [1.0 - free[n].reshape(-1) for n, e in zip(layout.names, layout.eliminate) if not e]
    H_ss = system.H_ss
    if fixed_s:
        H_ss = H_ss + jnp.diag(jnp.concatenate(fixed_s))
    V = []
    for slot, n in enumerate([n for n, e in zip(layout.names, layout.eliminate) if e]):
        fx = 1.0 - free[n]
        V.append(system.V[slot] + jax.vmap(jnp.diag)(fx))
    return System(H_ss, system.g_s, tuple(V), system.W, system.g_e)


def linearize(problem: Problem, layout: Layout, values: dict, free: dict, per_group: bool = False,
              residuals: bool = False):
    """Gauss–Newton system at ``values``: returns ``(cost, System, m_eff, groups)``, and with
    ``residuals`` a fifth item: per factor group its ``(K, m)`` residuals in its own unit.

    ``groups`` is ``None``, or with ``per_group`` each factor group's own system (its share of
    ``JᵀJ``, without the fixed-coordinate identity), whose sum is the total.
    """
    system = empty_system(layout)
    cost = jnp.zeros((), jnp.float64)
    m_eff = jnp.zeros((), jnp.int32)
    groups, raws = [], []
    for f in problem.factors:
        c, H_obs, g_obs, _, _, m, r_raw = factor_linearization(problem, values, f, free)
        if per_group:
            own = scatter_factor(empty_system(layout), layout, f, H_obs, g_obs, active_args(problem, f),
                                 f.chunk is not None)
            groups.append(own)
            system = jax.tree.map(jnp.add, system, own)
        else:
            system = scatter_factor(system, layout, f, H_obs, g_obs, active_args(problem, f), f.chunk is not None)
        cost = cost + c
        m_eff = m_eff + m.astype(jnp.int32)
        raws.append(r_raw)
    out = (cost, add_fixed_identity(system, layout, free), m_eff, (tuple(groups) if per_group else None))
    return out + (tuple(raws),) if residuals else out


def exact_system(problem: Problem, layout: Layout, values: dict, free: dict) -> System:
    """Exact-Hessian system at ``values`` (for implicit differentiation)."""
    system = empty_system(layout)
    for f in problem.factors:
        H_obs, g_obs = factor_exact_hessian(problem, values, f, free)
        system = scatter_factor(system, layout, f, H_obs, g_obs)
    return add_fixed_identity(system, layout, free)


def diagonal(system: System) -> tuple[jax.Array, tuple[jax.Array, ...]]:
    """``(diag H_ss (n_s,), per eliminated kind diag V (num, d))``."""
    return jnp.diagonal(system.H_ss), tuple(jnp.diagonal(V, axis1=-2, axis2=-1) for V in system.V)


def matvec(system: System, x_s, x_e):
    """``H x`` in block form for ``x_s (n_s,)``, ``x_e`` per eliminated kind ``(num, d)``."""
    y_s = system.H_ss @ x_s
    y_e = []
    for V, W, xe in zip(system.V, system.W, x_e):
        y_s = y_s + jnp.einsum("nsd,nd->s", W, xe)
        y_e.append(jnp.einsum("nde,ne->nd", V, xe) + jnp.einsum("nsd,s->nd", W, x_s))
    return y_s, tuple(y_e)


def _block_inverse(V):
    """Inverse of SPD blocks ``(num, d, d)`` (symmetric result; nan where a block is not positive
    definite).

    Gauss–Jordan elimination without pivoting (stable for SPD matrices, whose pivots are all
    positive), ``d`` rank-one updates of the whole batch, instead of LAPACK: XLA:CPU runs independent
    batched LAPACK calls (one per eliminated kind) at once on its intra-op pool, and each waits for
    sub-tasks it queued on that same pool, so on a 2-thread pool two of them deadlock (captured: both
    ``tf_XLAEigen`` threads in ``lapack_dtrsm_ffi`` → ``ParallelBatchMap`` waiting, the caller in
    ``device_get``). ``d`` updates in one loop keep the compiled program small (an element-wise Cholesky is
    ``O(d³)`` scalar operations).
    """
    d = V.shape[-1]
    lanes = jnp.arange(d)

    def update(k, carry):  # one pivot; a loop, not d unrolled copies, keeps the compiled program small
        A, positive = carry
        pivot = A[:, k, k]
        positive = positive & (pivot > 0.0)
        inv_pivot = 1.0 / jnp.where(pivot > 0.0, pivot, 1.0)
        row = A[:, k, :] * inv_pivot[:, None]
        col = A[:, :, k]
        in_row = (lanes == k)[None, :, None]  # replaced, not corrected: a correction of a
        in_col = (lanes == k)[None, None, :]  # large entry would leave its rounding error behind
        A = jnp.where(
            in_row & in_col,
            inv_pivot[:, None, None],
            jnp.where(
                in_row,
                row[:, None, :],
                jnp.where(in_col, -(col * inv_pivot[:, None])[:, :, None], A - col[:, :, None] * row[:, None, :]),
            ),
        )
        return A, positive

    A, positive = jax.lax.fori_loop(0, d, update, (V, jnp.ones(V.shape[:1], dtype=bool)))
    A = 0.5 * (A + jnp.swapaxes(A, -1, -2))
    return jnp.where(positive[:, None, None], A, jnp.nan)


def reduced_system(system: System, damp_s, damp_e):
    """Schur complement ``S = H_ss + D_s − Σ W V⁻¹ Wᵀ`` and the block inverses ``V⁻¹`` (damped)."""
    S = system.H_ss + jnp.diag(damp_s) if damp_s is not None else system.H_ss
    Vinvs = []
    for i, (V, W) in enumerate(zip(system.V, system.W)):
        if damp_e is not None:
            V = V + jax.vmap(jnp.diag)(damp_e[i])
        Vinv = _block_inverse(V)
        Vinvs.append(Vinv)
        Y = jnp.einsum("nsd,nde->nse", W, Vinv)
        S = S - jnp.einsum("nse,nte->st", Y, W)
    return S, tuple(Vinvs)


def _block_jacobi(S, layout: Layout):
    """Block-Jacobi preconditioner of ``S``: one ``d × d`` block per shared entry."""
    idxs = []
    for k in range(len(layout.names)):
        if not layout.eliminate[k]:
            N, d = layout.nums[k], layout.dims[k]
            idxs.append(layout.offsets[k] + np.arange(N * d).reshape(N, d))
    invs = [_block_inverse(S[i[:, :, None], i[:, None, :]]) for i in idxs]

    def apply(x):
        out = jnp.zeros_like(x)
        for i, inv in zip(idxs, invs):
            out = out.at[i].set(jnp.einsum("nde,ne->nd", inv, x[i]))
        return out

    return apply


def schur_solve(system: System, layout: Layout, rhs_s, rhs_e, damp_s=None, damp_e=None,
                cg_threshold: int = 1 << 30, cg_max_iterations: int = 500, cg_tol: float = 1e-12):
    """Solve ``(H + diag(damp)) x = rhs`` by eliminating the block-diagonal kinds.

    Args:
        rhs_s: ``(n_s, R)``; rhs_e: per eliminated kind ``(num, d, R)``.
        damp_s, damp_e: optional diagonal additions ``(n_s,)`` / ``(num, d)``.
        cg_threshold: reduced systems larger than this are solved by block-Jacobi preconditioned
            conjugate gradients instead of Cholesky.
    Returns:
        ``(x_s (n_s, R), x_e tuple of (num, d, R))``.
    """
    S, Vinvs = reduced_system(system, damp_s, damp_e)
    b = rhs_s
    for W, Vinv, re in zip(system.W, Vinvs, rhs_e):
        b = b - jnp.einsum("nsd,nde,ner->sr", W, Vinv, re)
    n = layout.n_shared
    if n == 0:
        x_s = b
    elif n > cg_threshold:
        precond = _block_jacobi(S, layout)

        def cg_one(bcol):
            x, _ = jax.scipy.sparse.linalg.cg(lambda v: S @ v, bcol, M=precond, tol=cg_tol,
                                               maxiter=cg_max_iterations)
            return x

        x_s = jax.vmap(cg_one, in_axes=1, out_axes=1)(b)
    else:
        x_s = jsl.cho_solve(jsl.cho_factor(S, lower=True), b)
    x_e = []
    for W, Vinv, re in zip(system.W, Vinvs, rhs_e):
        x_e.append(jnp.einsum("nde,ner->ndr", Vinv, re - jnp.einsum("nsd,sr->ndr", W, x_s)))
    return x_s, tuple(x_e)


def total_cost(problem: Problem, values: dict):
    """``½ Σ_groups Σ_k ρ(‖r_w,k‖²)`` at ``values`` (whitened units); differentiable in everything."""
    cost = jnp.zeros((), jnp.float64)
    for f in problem.factors:
        by_name, manifolds, dims = _factor_parts(problem, f)
        r_obs = _obs_residual(f, manifolds)
        rows = tuple(values[a][i] for a, i in zip(f.args, f.indices))
        zeros = tuple(jnp.zeros((f.num_obs, d), jnp.float64) for d in dims)
        r = jax.vmap(r_obs)(rows, zeros, f.observations, f.sqrt_weight)
        cost = cost + 0.5 * jnp.sum(f.loss.rho(jnp.sum(r * r, axis=-1))[0])
    return cost


def _split_shared(x_s, layout: Layout):
    out = {}
    for k, name in enumerate(layout.names):
        if not layout.eliminate[k]:
            N, d, o = layout.nums[k], layout.dims[k], layout.offsets[k]
            out[name] = x_s[o : o + N * d].reshape(N, d)
    return out


def deltas_to_dict(x_s, x_e, layout: Layout) -> dict:
    """Block vectors (``(n_s,)``, per eliminated kind ``(num, d)``) to ``{name: (num, d)}``."""
    out = _split_shared(x_s, layout)
    for k, name in enumerate(layout.names):
        if layout.eliminate[k]:
            out[name] = x_e[layout.elim_slot[k]]
    return out


def dict_to_blocks(d: dict, layout: Layout):
    """``{name: (num, d, ...)}`` to block vectors ``((n_s, ...), tuple of (num, d, ...))``."""
    shared = [d[n].reshape((-1,) + d[n].shape[2:]) for k, n in enumerate(layout.names) if not layout.eliminate[k]]
    elim = tuple(d[n] for k, n in enumerate(layout.names) if layout.eliminate[k])
    if shared:
        x_s = jnp.concatenate(shared, axis=0)
    else:
        tail = next(iter(d.values())).shape[2:]
        x_s = jnp.zeros((0,) + tail, jnp.float64)
    return x_s, elim
