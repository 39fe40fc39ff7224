"""The result of a solve, on the host: values, status, per-factor-group statistics, covariances and
the linear model.

Covariances come from the inverse blocks the compiled solve returned (no dense inverse of the whole
problem, nothing compiled here): with ``Σ_ss = S⁻¹`` (``S`` the Schur complement over the shared
unknowns) and the eliminated blocks ``V_i``,

    Σ_ii = V_i⁻¹ + V_i⁻¹ W_iᵀ Σ_ss W_i V_i⁻¹,   Σ_ij = V_i⁻¹ W_iᵀ Σ_ss W_j V_j⁻¹,   Σ_s,i = −Σ_ss W_i V_i⁻¹,

all multiplied by the variance factor: ``noise="a_posteriori"`` (default) uses
``σ̂² = 2·cost / (m − n)``; ``noise="stated"`` trusts the factor groups' σ (factor 1).

What a covariance includes: first-order propagation of the measurement noise described by the factor
groups' σ (sampling noise). What it does not: model error (a wrong lens model, unmodelled robot
error), bias from a wrong local minimum, or the nonlinearity of the problem beyond first order.
Fixed coordinates have zero (co)variance. Covariances are in the tangent space of each variable:
SE(3) as ``(rx, ry, rz, tx, ty, tz)`` (rad, m; right perturbation ``T·Exp(δ)``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.solve import linear
from jcalib.solve.lm import SolveOptions, Status
from jcalib.solve.problem import Problem


class Solution:
    """The result of :func:`jcalib.solve.solve`.

    Attributes:
        values: ``{name: (num, param_dim)}`` estimate (quaternions unit-norm, ``w >= 0``), NumPy.
        status: :class:`Status`.
        cost: final ``½ Σ ρ(‖r_w‖²)`` (whitened units).
        iterations: LM iterations.
        num_residuals: ``m``, residual components with nonzero weight (priors included).
        num_free: ``n``, free tangent coordinates.
        sigma2: a-posteriori variance factor ``2·cost / (m − n)`` (≈ 1 when the stated σ are right;
            ``nan`` when ``m <= n``).
        residuals: factor group name -> ``(K, m)`` residuals at the estimate, in the factor's own unit
            (unwhitened, unweighted; rejected observations included).
        chi2, count, hat: factor group name -> ``Σ ρ'(s) s`` of its whitened residuals, its number of
            residual components with nonzero weight, and ``tr(H_g H⁻¹)`` (the unknowns it uses up;
            ``nan`` unless the solve was asked for traces). ``count − hat`` is the group's redundancy.
        problem: the problem as given; padded_problem: as solved; raw: the padded
            :class:`jcalib.solve.lm.RawSolution`; layout: the padded problem's
            :class:`jcalib.solve.linear.Layout`.
    """

    def __init__(self, problem: Problem, padded: Problem, out, options: SolveOptions):
        self.problem = problem
        self.padded_problem = padded
        self.raw = out.raw
        self.options = options
        self.layout = linear.make_layout(padded)
        self._sigma_ss = np.asarray(out.sigma_ss)
        self._v_inv = tuple(np.asarray(v) for v in out.v_inv)
        self.values = {v.name: np.asarray(out.raw.values[v.name])[: v.num] for v in problem.variables}
        self.status = Status(int(out.raw.status))
        self.cost = float(out.raw.cost)
        self.iterations = int(out.raw.iterations)
        self.num_residuals = int(out.raw.num_residuals)
        self.num_free = int(out.raw.num_free)
        dof = self.num_residuals - self.num_free
        self.sigma2 = 2.0 * self.cost / dof if dof > 0 else float("nan")
        names = [f.name for f in problem.factors]
        self.residuals = {f.name: np.asarray(r)[: f.num_obs] for f, r in zip(problem.factors, out.residuals)}
        self.chi2 = dict(zip(names, np.asarray(out.chi2, np.float64).tolist()))
        self.count = dict(zip(names, np.asarray(out.count).astype(int).tolist()))
        hat = np.asarray(out.hat, np.float64)
        self.hat = dict(zip(names, (hat if np.any(hat) else np.full(len(names), np.nan)).tolist()))

    # ------------------------------------------------------------------------- covariance

    def variance_factor(self, noise: str = "a_posteriori") -> float:
        """The factor every stated-noise covariance is multiplied by: σ̂² or 1."""
        if noise == "stated":
            return 1.0
        if noise != "a_posteriori":
            raise BadInputError(f"noise: got {noise!r}, expected 'a_posteriori' or 'stated'.")
        if not self.sigma2 == self.sigma2:  # nan
            raise NotObservableError(
                f"The a-posteriori noise level needs more residuals ({self.num_residuals}) than free "
                f"unknowns ({self.num_free}); use noise='stated'.",
                ["sigma2"],
            )
        return self.sigma2

    def _free(self, name: str) -> np.ndarray:
        return ~np.asarray(self.padded_problem.variable(name).fixed)

    def covariance(self, name: str, index: int | None = None, noise: str = "a_posteriori") -> np.ndarray:
        """Covariance of variable ``name`` in its tangent space.

        Args:
            name: variable name.
            index: one entry ``i`` -> ``(d, d)``; ``None`` -> the joint covariance of all entries,
                ``(num·d, num·d)``, entry-major (``(d, d)`` when ``num = 1``).
            noise: ``"a_posteriori"`` (scale by ``σ̂²``) or ``"stated"``.
        Returns:
            float64 array in tangent units squared (e.g. rad², m², px² for intrinsics in px).
        """
        var = self.problem.variable(name)
        layout = self.layout
        k = layout.kind(name)
        num, d = var.num, layout.dims[k]
        if index is not None and not (0 <= int(index) < num):
            raise BadInputError(f"covariance index for {name!r}: got {index}, expected 0 <= index < {num}.")
        scale = self.variance_factor(noise)
        free = self._free(name).astype(np.float64)
        if not layout.eliminate[k]:
            o = layout.offsets[k]
            if index is None:
                C = self._sigma_ss[o:o + num * d, o:o + num * d]
                f = free[:num].reshape(-1)
            else:
                a = o + int(index) * d
                C = self._sigma_ss[a:a + d, a:a + d]
                f = free[int(index)]
        else:
            slot = layout.elim_slot[k]
            sel = slice(0, num) if index is None else slice(int(index), int(index) + 1)
            Vi = self._v_inv[slot][sel]
            Y = np.einsum("nde,nse->nds", Vi, np.asarray(self.raw.system.W[slot])[sel])  # V⁻¹ Wᵀ
            C = np.einsum("nds,st,mxt->ndmx", Y, self._sigma_ss, Y)
            nsel = Vi.shape[0]
            C = C + np.einsum("nm,nde->ndme", np.eye(nsel), Vi)
            C = C.reshape(nsel * d, nsel * d)
            f = free[sel].reshape(-1)
        return scale * C * f[:, None] * f[None, :]

    def joint_covariance(self, names: Sequence[str], noise: str = "a_posteriori") -> np.ndarray:
        """Joint covariance of shared (not eliminated) variables ``names``, in that order (entry-major,
        tangent order within an entry), with the cross terms the per-variable blocks leave out."""
        scale = self.variance_factor(noise)
        idx = []
        for name in names:
            k = self.layout.kind(name)
            if self.layout.eliminate[k]:
                raise BadInputError(f"joint_covariance: {name!r} is eliminated; ask for shared variables only")
            num, d = self.problem.variable(name).num, self.layout.dims[k]
            rows = self.layout.offsets[k] + np.arange(num * d)
            idx.append(np.where(self._free(name)[:num].reshape(-1), rows, -1))
        idx = np.concatenate(idx) if idx else np.zeros(0, int)
        ok = idx >= 0
        M = np.zeros((idx.size, idx.size))
        M[np.ix_(ok, ok)] = scale * self._sigma_ss[np.ix_(idx[ok], idx[ok])]
        return M

    def shared_information(self, noise: str = "a_posteriori") -> np.ndarray:
        """``(n_s, n_s)`` information of the shared unknowns with the eliminated ones marginalised
        (the Schur complement ``S``; fixed coordinates carry 1 on the diagonal), divided by the
        variance factor: the inverse of :meth:`joint_covariance` over every shared variable."""
        S, _ = linear.reduced_system(self.raw.system, None, None)
        return np.asarray(S) / self.variance_factor(noise)

    def information(self, names: Sequence[str], noise: str = "a_posteriori") -> np.ndarray:
        """Information of the shared variables ``names`` with every other unknown marginalised
        (:func:`marginal_information` of the solve's system), divided by the variance factor: the
        inverse of :meth:`joint_covariance` of ``names`` on their free coordinates."""
        S, _ = linear.reduced_system(self.raw.system, None, None)
        return marginal_information(np.asarray(S), self.layout, self.padded_problem, names) / self.variance_factor(noise)

    def propagate(self, fn: Callable[[dict], Any], noise: str = "a_posteriori") -> np.ndarray:
        """Covariance of a derived quantity ``y = fn(values)`` by linear propagation.

        ``Σ_y = J_y H⁻¹ J_yᵀ · σ̂²`` with ``J_y`` the JAX Jacobian of ``fn`` with respect to every
        variable's tangent (at the solution) and ``H⁻¹ J_yᵀ`` from the block (Schur) solver. Define
        ``fn`` once (module level): one compilation per function.

        Args:
            fn: ``fn(values) -> y`` with ``values`` as in :attr:`values`; ``y`` any shape, flattened
                to ``p`` components.
        Returns:
            ``(p, p)`` covariance of ``y.reshape(-1)`` in the units of ``y`` squared.
        """
        scale = self.variance_factor(noise)
        return scale * np.asarray(_propagate(self.padded_problem, self.raw.system, self.raw.values,
                                             tuple(v.num for v in self.problem.variables), fn))

    def __repr__(self) -> str:
        return (f"Solution(status={self.status.name}, cost={self.cost:.6g}, iterations={self.iterations}, "
                f"sigma2={self.sigma2:.4g})")


def marginal_information(S: np.ndarray, layout: linear.Layout, problem: Problem, names: Sequence[str]) -> np.ndarray:
    """The information of the shared variables ``names`` from a Schur complement ``S`` over every
    shared unknown, with the other shared unknowns marginalised (``S_kk − S_ko S_oo⁻¹ S_ok``).

    Args:
        S: ``(n_s, n_s)`` reduced information of ``problem`` (fixed coordinates: 1 on the diagonal).
        layout: the problem's :class:`jcalib.solve.linear.Layout`; problem: the problem ``S`` is of.
        names: shared (not eliminated) variables, in this order.
    Returns:
        ``(n, n)`` over the names' coordinates (entry-major, tangent order within an entry); rows and
        columns of fixed coordinates are zero.
    Raises:
        BadInputError: a name that is eliminated or not in the problem.
    """
    keep, free = [], []
    for name in names:
        k = layout.kind(name) if name in layout.names else None
        if k is None or layout.eliminate[k]:
            raise BadInputError(f"information: {name!r} is not a shared variable of the problem; ask for shared "
                                "variables only")
        v = problem.variable(name)
        rows = layout.offsets[k] + np.arange(layout.nums[k] * layout.dims[k])
        keep.append(rows)
        free.append(~np.asarray(v.fixed).reshape(-1))
    keep = np.concatenate(keep) if keep else np.zeros(0, int)
    free = np.concatenate(free) if free else np.zeros(0, bool)
    other = np.setdiff1d(np.arange(S.shape[0]), keep)
    M = S[np.ix_(keep, keep)]
    if other.size:
        B = S[np.ix_(keep, other)]
        M = M - B @ np.linalg.solve(S[np.ix_(other, other)], B.T)
    M = 0.5 * (M + M.T)
    return M * free[:, None] * free[None, :]


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
    rhs_s, rhs_e = linear.dict_to_blocks(Jt, layout)
    z_s, z_e = linear.schur_solve(system, layout, rhs_s, rhs_e)
    out = rhs_s.T @ z_s
    for r, z in zip(rhs_e, z_e):
        out = out + jnp.einsum("ndp,ndq->pq", r, z)
    return 0.5 * (out + out.T)


def unobservable_names(problem: Problem, layout: linear.Layout, obs, rtol: float, max_directions: int = 8) -> list[str]:
    """Names of the unknowns with the largest weight in each null direction of the information."""
    names: list[str] = []
    by_name = {v.name: v for v in problem.variables}

    def add(direction_names):
        label = " + ".join(direction_names) if len(direction_names) > 1 else direction_names[0]
        if label not in names:
            names.append(label)

    for k, name in enumerate(layout.names):
        if not layout.eliminate[k]:
            continue
        v = by_name[name]
        w = np.asarray(obs.eigvals_e[layout.elim_slot[k]])
        U = np.asarray(obs.eigvecs_e[layout.elim_slot[k]])
        for i in range(min(v.num, w.shape[0])):
            wmax = np.max(w[i]) if np.all(np.isfinite(w[i])) else np.inf
            for j in np.flatnonzero(~(w[i] >= rtol * wmax)):
                vec = np.abs(U[i][:, j])
                top = np.flatnonzero(vec >= 0.5 * vec.max()) if np.all(np.isfinite(vec)) else np.arange(vec.size)
                add([v.coordinate_name(i, int(c)) for c in top[np.argsort(-vec[top])]])
    if names:
        return names[:max_directions]
    w = np.asarray(obs.eigvals_s)
    U = np.asarray(obs.eigvecs_s)
    coord = []
    for k, name in enumerate(layout.names):
        if not layout.eliminate[k]:
            for i in range(layout.nums[k]):
                for j in range(layout.dims[k]):
                    coord.append(by_name[name].coordinate_name(i, j))
    if w.size == 0:
        return names
    for j in np.flatnonzero(~(w >= rtol * np.max(w))):
        vec = np.abs(U[:, j])
        top = np.flatnonzero(vec >= 0.5 * vec.max())
        add([coord[c] for c in top[np.argsort(-vec[top])]])
    return names[:max_directions]
