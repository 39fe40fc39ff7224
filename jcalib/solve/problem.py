"""The problem graph: variable kinds, factor groups, and the problem that ties them together.

A :class:`Variable` stacks all unknowns of one type (``(num, param_dim)`` values on one manifold)
with a fixed mask over their tangent coordinates and optional Gaussian priors. A
:class:`FactorGroup` is one residual function vmapped over ``K`` observations, with one index
array per argument into the variable kinds. A :class:`Problem` validates the graph (names, shapes,
index ranges — JAX would silently clamp an out-of-range gather) and turns priors into factor groups.

All three are equinox modules (pytrees): arrays are leaves, configuration (names, manifolds,
residual functions, losses) is static. Two problems with the same static configuration and the same
array shapes share one compiled solver; :func:`jcalib.solve.batch.pad_problem` rounds counts up to
buckets so that data sets of similar size do too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.residuals.losses import Loss, TrivialLoss
from jcalib.residuals.priors import gaussian_prior_jacobian, gaussian_prior_residual
from jcalib.solve.manifolds import SE3, SO3, Euclidean


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _array(x, dtype):
    """NumPy on the host (building a problem dispatches nothing), JAX inside a trace."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x)):
        return jnp.asarray(x, dtype=dtype)
    return np.asarray(x, dtype=dtype)


def replace(module: eqx.Module, **changes) -> eqx.Module:
    """A copy of ``module`` with the named fields replaced (what ``eqx.tree_at`` does for top-level
    fields, without walking the tree: ~40 µs less per call, and the build and padding make several per
    solve). Like ``tree_at`` it runs no ``__init__`` checks: the caller passes valid values."""
    new = object.__new__(type(module))
    old = module.__dict__
    for f in dataclasses.fields(module):
        object.__setattr__(new, f.name, changes.pop(f.name) if f.name in changes else old[f.name])
    if changes:
        raise TypeError(f"{type(module).__name__} has no field(s) {sorted(changes)}")
    return new


class Variable(eqx.Module):
    """One variable kind: ``num`` entries of one manifold, stacked.

    Args:
        name: unique name, e.g. ``"intrinsics"``, ``"T_cam_target"``.
        manifold: ``Euclidean(d)``, ``SO3()`` or ``SE3()`` (see :mod:`jcalib.solve.manifolds`).
        value: ``(num, param_dim)`` initial values (a single ``(param_dim,)`` row means ``num = 1``).
            SE(3) rows are ``wxyz_xyz`` (m), SO(3) rows ``wxyz``.
        fixed: ``(num, tangent_dim)`` bool, or ``(tangent_dim,)`` for every entry, or a bool for
            everything: tangent coordinates held fixed. Default: all free.
        prior_mean: ``(num, param_dim)`` mean of a Gaussian prior per entry (optional).
        prior_sqrt_info: ``(num, d, d)`` or ``(d, d)`` square-root information ``S`` (``SᵀS = Σ⁻¹``)
            in the tangent space at the mean; zero rows switch the prior off for an entry.
        eliminate: the kind is block-diagonal in the Hessian (e.g. per-view poses: every factor
            touches at most one entry of it, and at most one eliminated kind) and is removed by a
            Schur complement before the dense solve.
        coord_names: ``tangent_dim`` labels of the tangent coordinates (``("fx", "fy", ...)``);
            default the manifold's (``rx ... tz``, ``x0 ...``).
        entry_label: how an entry is called in messages, a format string with ``{name}`` and
            ``{i}``, e.g. ``"view {i} pose"``. Default ``"{name}[{i}]"`` (``"{name}"`` if num = 1).
        constant: every coordinate of every entry is fixed, and that is known when the problem is
            traced (e.g. the reference camera's rig pose of a one-camera problem, exact robot poses):
            factors do not differentiate with respect to it, which saves Jacobian columns and Hessian
            blocks. Implies ``fixed=True``; it is laid out as an eliminated kind (identity blocks), so
            that many constant entries never enter the dense system.
    """

    name: str = eqx.field(static=True)
    manifold: Euclidean | SO3 | SE3 = eqx.field(static=True)
    value: jax.Array
    fixed: jax.Array
    prior_mean: jax.Array | None
    prior_sqrt_info: jax.Array | None
    eliminate: bool = eqx.field(static=True)
    coord_names: tuple[str, ...] = eqx.field(static=True)
    entry_label: str | None = eqx.field(static=True)
    constant: bool = eqx.field(static=True)

    def __init__(
        self,
        name: str,
        manifold,
        value,
        fixed=False,
        prior_mean=None,
        prior_sqrt_info=None,
        eliminate: bool = False,
        coord_names: Sequence[str] | None = None,
        entry_label: str | None = None,
        constant: bool = False,
    ):
        if not isinstance(name, str) or not name:
            raise BadInputError(f"Variable name: got {name!r}, expected a non-empty string.")
        if not isinstance(manifold, (Euclidean, SO3, SE3)):
            raise BadInputError(
                f"Variable {name!r} manifold: got {manifold!r}, expected Euclidean(d), SO3() or SE3()."
            )
        value = _array(value, np.float64)
        if value.ndim == 1:
            value = value[None, :]
        p, d = manifold.param_dim, manifold.tangent_dim
        if value.ndim != 2 or value.shape[1] != p or value.shape[0] < 1:
            raise BadInputError(
                f"Variable {name!r} value: got shape {value.shape}, expected (num >= 1, {p})."
            )
        num = value.shape[0]
        if constant and prior_mean is not None:
            raise BadInputError(f"Variable {name!r}: a constant variable cannot have a prior.")
        fixed = _array(True if constant else fixed, bool)
        try:
            xp = np if isinstance(fixed, np.ndarray) else jnp
            fixed = xp.broadcast_to(fixed.reshape(fixed.shape if fixed.ndim != 1 else (1, d)), (num, d))
        except (ValueError, TypeError) as err:
            raise BadInputError(
                f"Variable {name!r} fixed: got shape {fixed.shape}, expected a bool, ({d},) or ({num}, {d})."
            ) from err
        if (prior_mean is None) != (prior_sqrt_info is None):
            raise BadInputError(
                f"Variable {name!r}: prior_mean and prior_sqrt_info must be given together."
            )
        if prior_mean is not None:
            prior_mean = _array(prior_mean, np.float64)
            if prior_mean.ndim == 1:
                prior_mean = (np if isinstance(prior_mean, np.ndarray) else jnp).broadcast_to(prior_mean[None, :], (num, p))
            if prior_mean.shape != (num, p):
                raise BadInputError(
                    f"Variable {name!r} prior_mean: got shape {prior_mean.shape}, expected ({num}, {p})."
                )
            prior_sqrt_info = _array(prior_sqrt_info, np.float64)
            if prior_sqrt_info.ndim == 2:
                prior_sqrt_info = (np if isinstance(prior_sqrt_info, np.ndarray) else jnp).broadcast_to(prior_sqrt_info[None], (num, d, d))
            if prior_sqrt_info.shape != (num, d, d):
                raise BadInputError(
                    f"Variable {name!r} prior_sqrt_info: got shape {prior_sqrt_info.shape}, "
                    f"expected ({d}, {d}) or ({num}, {d}, {d})."
                )
        labels = tuple(coord_names) if coord_names is not None else manifold.coord_labels
        if len(labels) != d:
            raise BadInputError(
                f"Variable {name!r} coord_names: got {len(labels)} names, expected {d} (tangent dim)."
            )
        self.name = name
        self.manifold = manifold
        self.value = value
        self.fixed = fixed
        self.prior_mean = prior_mean
        self.prior_sqrt_info = prior_sqrt_info
        self.eliminate = bool(eliminate) or bool(constant)
        self.coord_names = labels
        self.entry_label = entry_label
        self.constant = bool(constant)

    @property
    def num(self) -> int:
        return self.value.shape[-2]

    @property
    def tangent_dim(self) -> int:
        return self.manifold.tangent_dim

    def coordinate_name(self, i: int, j: int) -> str:
        """Human-readable name of tangent coordinate ``j`` of entry ``i``, e.g. ``"view 3 pose rx"``."""
        if self.entry_label is not None:
            entry = self.entry_label.format(name=self.name, i=i)
            return f"{entry} {self.coord_names[j]}"
        if self.num == 1:
            return f"{self.name}.{self.coord_names[j]}"
        return f"{self.name}[{i}].{self.coord_names[j]}"


class FactorGroup(eqx.Module):
    """One residual type applied to ``K`` observations.

    Args:
        name: unique name, e.g. ``"reprojection"``.
        fn: ``fn(*param_rows, obs) -> r (m,)``: one observation's residual (unwhitened, e.g. px).
            ``param_rows[j]`` is one ``(param_dim,)`` row of variable ``args[j]``; ``obs`` is one
            slice of ``observations``. Must be pure and traceable. Define it once (module level)
            so that problems built from new data reuse the compiled solver.
        args: variable names, one per parameter argument of ``fn``.
        indices: one ``(K,)`` integer array per argument: the entry of ``args[j]`` used by each
            observation.
        observations: a pytree of arrays with leading dimension ``K`` (or ``None``).
        sigma: noise standard deviation of each residual component (same unit as ``r``);
            residuals are whitened as ``r / sigma``.
        sqrt_weight: ``(K,)`` extra per-observation weights (default ones). Weight 0 removes an
            observation with finite derivatives (used for padding and outlier masks).
        loss: robust loss on the whitened squared norm (:mod:`jcalib.residuals.losses`).
        chunk: observations come in contiguous runs of ``chunk`` that share every argument index
            (e.g. the corners of one view: same intrinsics, same view pose). The normal equations
            are then summed per run with one batched matrix product instead of forming a
            ``(D, D)`` block per observation (much less memory traffic, and what makes a vmapped
            batch of calibrations fast). ``K`` must be a multiple of ``chunk``.
        jacobian: optional hand-derived linearisation of ``fn`` for the Gauss–Newton system,
            ``jacobian(*param_rows, obs) -> (r (m,), (J_0, ..., J_{n-1}))`` with ``r`` as ``fn``
            returns it and ``J_j (m, tangent_dim_j)`` the derivative with respect to the tangent
            ``δ`` of ``args[j]`` at ``δ = 0`` in the manifold's convention (e.g. ``T · Exp(δ)`` for
            SE(3)). Used instead of autodiff of ``fn`` where part of the chain rule is cheaper by hand
            (the camera reprojection: autodiff through the lens model only, the poses in closed
            form; a camera calibration solves ~20 % faster). It must equal autodiff of ``fn``: test it
            against the engine without it. ``fn`` is still used for residuals, implicit
            derivatives and exact Hessians. Columns of constant arguments are ignored.
    """

    name: str = eqx.field(static=True)
    fn: Callable = eqx.field(static=True)
    args: tuple[str, ...] = eqx.field(static=True)
    indices: tuple[jax.Array, ...]
    observations: Any
    sigma: jax.Array
    sqrt_weight: jax.Array
    loss: Loss = eqx.field(static=True)
    chunk: int | None = eqx.field(static=True)
    jacobian: Callable | None = eqx.field(static=True)

    def __init__(
        self,
        name: str,
        fn: Callable,
        args: Sequence[str],
        indices: Sequence,
        observations: Any = None,
        sigma: float = 1.0,
        sqrt_weight=None,
        loss: Loss | None = None,
        chunk: int | None = None,
        jacobian: Callable | None = None,
    ):
        if not isinstance(name, str) or not name:
            raise BadInputError(f"FactorGroup name: got {name!r}, expected a non-empty string.")
        args = tuple(args)
        if len(args) == 0:
            raise BadInputError(f"Factor group {name!r} args: got none, expected at least one variable name.")
        indices = tuple(i if isinstance(i, jax.core.Tracer) else np.asarray(i) for i in indices)
        if len(indices) != len(args):
            raise BadInputError(
                f"Factor group {name!r} indices: got {len(indices)} index arrays, expected {len(args)} "
                f"(one per argument {args})."
            )
        num_obs = None
        for a, idx in zip(args, indices):
            if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
                raise BadInputError(
                    f"Factor group {name!r} argument {a!r} index array: got shape {idx.shape} dtype "
                    f"{idx.dtype}, expected a 1-D integer array (K,)."
                )
            if num_obs is None:
                num_obs = idx.shape[0]
            elif idx.shape[0] != num_obs:
                raise BadInputError(
                    f"Factor group {name!r} argument {a!r} index array: got length {idx.shape[0]}, "
                    f"expected {num_obs} (same K for every argument)."
                )
        observations = jax.tree.map(lambda a: _array(a, None), observations)
        for leaf in jax.tree.leaves(observations):
            if leaf.ndim < 1 or leaf.shape[0] != num_obs:
                raise BadInputError(
                    f"Factor group {name!r} observations: got a leaf of shape {leaf.shape}, expected "
                    f"leading dimension K = {num_obs}."
                )
        sigma = _array(sigma, np.float64)
        if sigma.shape != () or (_is_concrete(sigma) and not float(sigma) > 0.0):
            raise BadInputError(f"Factor group {name!r} sigma: got {sigma}, expected a positive scalar.")
        if sqrt_weight is None:
            sqrt_weight = np.ones((num_obs,), dtype=np.float64)
        sqrt_weight = _array(sqrt_weight, np.float64)
        if sqrt_weight.shape != (num_obs,):
            raise BadInputError(
                f"Factor group {name!r} sqrt_weight: got shape {sqrt_weight.shape}, expected ({num_obs},)."
            )
        self.name = name
        self.fn = fn
        self.args = args
        self.indices = tuple(i.astype(np.int32) for i in indices)
        self.observations = observations
        self.sigma = sigma
        self.sqrt_weight = sqrt_weight
        self.loss = loss if loss is not None else TrivialLoss()
        if chunk is not None:
            chunk = int(chunk)
            if chunk < 1 or num_obs % chunk:
                raise BadInputError(
                    f"Factor group {name!r} chunk: got {chunk}, expected a positive divisor of K = {num_obs}."
                )
            for a, idx in zip(args, self.indices):
                if _is_concrete(idx) and idx.size:
                    runs = np.asarray(idx).reshape(-1, chunk)
                    bad = np.flatnonzero(np.any(runs != runs[:, :1], axis=1))
                    if bad.size:
                        raise BadInputError(
                            f"Factor group {name!r} argument {a!r}: indices differ inside run {int(bad[0])} "
                            f"(observations {int(bad[0]) * chunk}..{(int(bad[0]) + 1) * chunk - 1}), "
                            f"expected one index per run of chunk = {chunk}."
                        )
        self.chunk = chunk
        self.jacobian = jacobian

    @property
    def num_obs(self) -> int:
        return self.sqrt_weight.shape[-1]


class Problem(eqx.Module):
    """A validated problem graph.

    Priors of the variables become factor groups named ``"prior:<variable>"`` (residual
    :func:`jcalib.residuals.gaussian_prior_residual`, σ = 1, weight 1 per entry).

    Raises:
        BadInputError: duplicate names, unknown variable names, an index out of range (naming the
            factor group, argument, position and value), a factor touching two eliminated entries.
    """

    variables: tuple[Variable, ...]
    factors: tuple[FactorGroup, ...]

    def __init__(self, variables: Sequence[Variable], factors: Sequence[FactorGroup]):
        variables = tuple(variables)
        factors = tuple(factors)
        names = [v.name for v in variables]
        if len(set(names)) != len(names):
            raise BadInputError(f"Problem variables: duplicate names in {names}.")
        by_name = {v.name: v for v in variables}
        prior_factors = []
        stripped = []
        for v in variables:
            if v.prior_mean is not None:
                prior_factors.append(
                    FactorGroup(
                        f"prior:{v.name}",
                        gaussian_prior_residual(v.manifold),
                        (v.name,),
                        (np.arange(v.num, dtype=np.int32),),
                        (v.prior_mean, v.prior_sqrt_info),
                        jacobian=gaussian_prior_jacobian(v.manifold),
                    )
                )
                v = eqx.tree_at(lambda w: (w.prior_mean, w.prior_sqrt_info), v, (None, None),
                                is_leaf=lambda x: x is None)
            stripped.append(v)
        factors = factors + tuple(prior_factors)
        fnames = [f.name for f in factors]
        if len(set(fnames)) != len(fnames):
            raise BadInputError(f"Problem factor groups: duplicate names in {fnames}.")
        for f in factors:
            elim_args = []
            for j, (a, idx) in enumerate(zip(f.args, f.indices)):
                if a not in by_name:
                    raise BadInputError(
                        f"Factor group {f.name!r} argument {j}: got variable {a!r}, expected one of {names}."
                    )
                num = by_name[a].num
                if _is_concrete(idx) and idx.size:
                    idx_np = np.asarray(idx)
                    bad = np.flatnonzero((idx_np < 0) | (idx_np >= num))
                    if bad.size:
                        k = int(bad[0])
                        raise BadInputError(
                            f"Factor group {f.name!r} argument {a!r}: index {int(idx_np[k])} at "
                            f"observation {k} is out of range, expected 0 <= index < {num} "
                            f"({bad.size} bad indices in all)."
                        )
                if by_name[a].eliminate and not by_name[a].constant:
                    elim_args.append(a)
            if len(elim_args) > 1:
                raise BadInputError(
                    f"Factor group {f.name!r}: touches eliminated variables {elim_args}, expected at "
                    "most one eliminated argument per factor (the Hessian must stay block-diagonal "
                    "over eliminated entries). Set eliminate=False on one of them."
                )
        self.variables = tuple(stripped)
        self.factors = factors

    def variable(self, name: str) -> Variable:
        for v in self.variables:
            if v.name == name:
                return v
        raise BadInputError(
            f"Variable name: got {name!r}, expected one of {[v.name for v in self.variables]}."
        )

    def initial_values(self) -> dict[str, jax.Array]:
        """``{name: (num, param_dim)}`` start values."""
        return {v.name: v.value for v in self.variables}

    def with_values(self, values: dict[str, Any]) -> Problem:
        """A copy with new start values for the named variables (shapes must match)."""
        new = []
        for v in self.variables:
            if v.name in values:
                x = _array(values[v.name], np.float64).reshape(v.value.shape)
                v = eqx.tree_at(lambda w: w.value, v, x)
            new.append(v)
        unknown = set(values) - {v.name for v in self.variables}
        if unknown:
            raise BadInputError(
                f"x0: got unknown variable names {sorted(unknown)}, expected names from "
                f"{[v.name for v in self.variables]}."
            )
        return eqx.tree_at(lambda p: p.variables, self, tuple(new))
