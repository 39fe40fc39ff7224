"""Re-optimisation: re-calibrate a cell from new observations, reuse what still holds, flag what moved.

After a tool change, a crash or a bumped camera, ``jcalib calibrate CELL NEW_OBS --prior OLD_RESULT``
(``jcalib.calibrate(cell, obs, prior=old)``) does three things:

1. solves the new observations on their own (the whole-cell problem, started from the old values);
2. tests every unknown (camera intrinsics, each transform) for a change: with ``d`` the difference
   old → new in the tangent space (``Log(T_old⁻¹ T_new)``, rx..tz, rad and m, for a transform;
   ``p_new − p_old`` for intrinsics) and ``C = Σ_old + Σ_new`` (the two estimates come from
   independent data), ``χ² = dᵀ C⁺ d`` with ``dof = rank C`` (coordinates held fixed in both are
   left out). When both results carry their joint covariance (``extra["joint_covariance"]``, written
   by whole-cell results) the test of each unknown uses the correlations between unknowns: the
   statistic of "only this unknown changed" against "nothing changed" (Baarda's data snooping for a
   block: ``s = Eᵀ C⁺ d``, ``χ² = sᵀ (Eᵀ C⁺ E)⁺ s``, again ``χ²_dof`` under no change), which sees
   e.g. a TCP move that its camera's pose uncertainty would hide in the marginal test. This runs
   iteratively: the most significant unknown is flagged, then the others are tested again with it
   free, until none is significant (so a moved TCP is not also blamed on the camera that sees it).
   The unknown has *moved* when the p-value ``P(χ²_dof > χ²)`` is below
   ``alpha / num_tests`` (Bonferroni: the chance that an unchanged cell gets any flag is at most
   ``alpha``, when the covariances are right);
3. solves again with the old values as Gaussian priors (their covariances) on the unknowns that did
   not move, and without a prior on those that did, so a moved TCP is re-estimated from the new data
   alone while the rest keeps the old information.

The test assumes the reported covariances are right (sampling noise only); model error that differs
between the two sessions (e.g. a lens refocused, or a robot that got less repeatable) shows up as a
change, which is what one wants to know. The new observations must determine every unknown on their
own (a :class:`~jcalib.errors.NotObservableError` names what they cannot).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.result import ResultFile, load_result

__all__ = ["Change", "Reoptimisation", "compare_results", "reoptimise"]


@dataclass(frozen=True)
class Change:
    """The χ² test of one unknown, old vs new.

    Attributes:
        name: camera id (intrinsics) or transform name (``T_flange_needle``).
        coords: coordinate names of ``difference`` (intrinsic names, or rx..tz).
        difference: new − old in those coordinates (px / unitless for intrinsics; rad, m for transforms).
        sigma: standard deviation of the difference (square roots of the diagonal of Σ_old + Σ_new).
        chi2, dof, p_value: the test statistic, its degrees of freedom and ``P(χ²_dof > chi2)``.
        moved: ``p_value < alpha / num_tests``.
    """

    name: str
    coords: tuple[str, ...]
    difference: np.ndarray
    sigma: np.ndarray
    chi2: float
    dof: int
    p_value: float
    moved: bool

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "moved": bool(self.moved),
            "chi2": float(self.chi2),
            "dof": int(self.dof),
            "p_value": float(self.p_value),
            "difference": {c: float(v) for c, v in zip(self.coords, self.difference)},
            "sigma": {c: float(v) for c, v in zip(self.coords, self.sigma)},
        }


@dataclass
class Reoptimisation:
    """Outcome of :func:`reoptimise`.

    Attributes:
        result: the final :class:`jcalib.Result` (priors on what did not move); its
            ``stats["reoptimisation"]`` holds ``alpha``, ``alpha_per_test``, ``moved`` and ``tests``.
        changes: one :class:`Change` per unknown found in both results.
        moved: names of the unknowns that moved.
        data_only: the :class:`jcalib.Result` of the new observations alone.
        alpha, alpha_per_test: family-wise significance level and the per-test level (Bonferroni).
    """

    result: object
    changes: list[Change]
    moved: list[str]
    data_only: object
    alpha: float
    alpha_per_test: float
    extra: dict = field(default_factory=dict)


_SE3_COORDS = ("rx", "ry", "rz", "tx", "ty", "tz")


def _chi2_test(d: np.ndarray, C: np.ndarray) -> tuple[float, int]:
    C = 0.5 * (C + C.T)
    free = np.diag(C) > 0
    if not np.any(free):
        return 0.0, 0
    w, U = np.linalg.eigh(C[np.ix_(free, free)])
    keep = w > float(np.max(w)) * 1e-12
    z = (U[:, keep].T @ d[free]) / np.sqrt(w[keep])
    return float(z @ z), int(np.sum(keep))


def compare_results(old, new, alpha: float = 0.01, names=None) -> list[Change]:
    """χ² tests of every unknown present (with a covariance) in both results (see the module docstring).

    Args:
        old, new: :class:`~jcalib.io.result.ResultFile`, :class:`jcalib.Result` or paths.
        alpha: family-wise significance level in (0, 1).
        names: restrict to these camera ids / transform names (default: all in both).

    Returns:
        One :class:`Change` per tested unknown, cameras first, then transforms.
    """
    from scipy.stats import chi2 as chi2_dist

    from jcalib.geometry import conversions, lie

    if not 0.0 < alpha < 1.0:
        raise BadInputError(f"alpha: got {alpha!r}, expected a significance level in (0, 1)")
    old, new = _as_file(old, "old"), _as_file(new, "new")
    tests = []
    for n, c_new in new.cameras.items():
        c_old = old.cameras.get(n)
        if c_old is None or c_old.covariance is None or c_new.covariance is None:
            continue
        if tuple(c_old.param_names) != tuple(c_new.param_names):
            raise BadInputError(
                f"prior: camera '{n}' has model {c_old.model} in the old result and {c_new.model} in the new one; "
                "compare results of the same lens model"
            )
        d = np.asarray(c_new.params - c_old.params, np.float64)
        tests.append((n, tuple(c_new.param_names), d, np.asarray(c_old.covariance) + np.asarray(c_new.covariance)))
    for n, t_new in new.transforms.items():
        t_old = old.transforms.get(n)
        if t_old is None or t_old.covariance is None or t_new.covariance is None:
            continue
        d = np.asarray(lie.local(np.asarray(conversions.matrix_to_pose(t_old.matrix)),
                                 np.asarray(conversions.matrix_to_pose(t_new.matrix))), np.float64)
        tests.append((n, _SE3_COORDS, d, np.asarray(t_old.covariance) + np.asarray(t_new.covariance)))
    if names is not None:
        tests = [t for t in tests if t[0] in set(names)]
    counted = [t for t in tests if np.any(np.diag(t[3]) > 0)]
    per_test = alpha / max(len(counted), 1)
    C_joint = _joint(old, tests)
    if C_joint is not None:
        C_new = _joint(new, tests)
        C_joint = None if C_new is None else C_joint + C_new
    offsets = np.cumsum([0] + [t[2].size for t in tests])
    d_all = np.concatenate([t[2] for t in tests]) if tests else np.zeros(0)
    stats = {}
    if C_joint is not None:
        # Iterative data snooping: test each unknown given those already found to move (free), flag the
        # most significant one, repeat. A TCP move is then not also blamed on its camera.
        W, free = _pinv(C_joint)
        moved: list[int] = []
        while True:
            base = _lr(d_all, W, free, offsets, moved)
            round_stats = {}
            for k in range(len(tests)):
                if k in moved:
                    continue
                t, r = _lr(d_all, W, free, offsets, moved + [k])
                dof = r - base[1]
                stat = max(t - base[0], 0.0)
                round_stats[k] = (stat, dof, float(chi2_dist.sf(stat, dof)) if dof > 0 else 1.0)
            stats.update(round_stats)
            cand = [k for k, v in round_stats.items() if v[1] > 0 and v[2] < per_test]
            if not cand:
                break
            moved.append(min(cand, key=lambda k: round_stats[k][2]))
    out = []
    for k, (n, coords, d, C) in enumerate(tests):
        if C_joint is not None:
            stat, dof, p = stats[k]
        else:
            stat, dof = _chi2_test(d, C)
            p = float(chi2_dist.sf(stat, dof)) if dof > 0 else 1.0
        out.append(Change(n, coords, d, np.sqrt(np.maximum(np.diag(C), 0.0)), stat, dof, p, bool(dof > 0 and p < per_test)))
    return out


def _pinv(C: np.ndarray):
    C = 0.5 * (C + C.T)
    free = np.diag(C) > 0
    w, U = np.linalg.eigh(C[np.ix_(free, free)])
    keep = w > float(np.max(w)) * 1e-12
    return (U[:, keep] / w[keep]) @ U[:, keep].T, free


def _lr(d: np.ndarray, W: np.ndarray, free: np.ndarray, offsets, blocks: list[int]) -> tuple[float, int]:
    """``sᵀ F⁺ s`` and ``rank F`` with ``s = Eᵀ W d``, ``F = Eᵀ W E``, ``E`` the columns of ``blocks``:
    how much of the χ² of ``d`` the blocks explain (Baarda's data snooping, for blocks)."""
    if not blocks:
        return 0.0, 0
    blk = np.zeros(d.size, bool)
    for k in blocks:
        blk[offsets[k]:offsets[k + 1]] = True
    sel = blk[free]
    if not np.any(sel):
        return 0.0, 0
    s = W[sel] @ d[free]
    F = W[np.ix_(sel, sel)]
    fw, fU = np.linalg.eigh(0.5 * (F + F.T))
    fk = fw > float(np.max(fw)) * 1e-12
    z = (fU[:, fk].T @ s) / np.sqrt(fw[fk])
    return float(z @ z), int(np.sum(fk))


def _joint(result: ResultFile, tests) -> np.ndarray | None:
    """The joint covariance of the tested unknowns from ``extra["joint_covariance"]``, or None."""
    jc = result.extra.get("joint_covariance")
    if not jc:
        return None
    names, dims = list(jc["names"]), [int(d) for d in jc["dims"]]
    if any(t[0] not in names for t in tests):
        return None
    M = np.asarray(jc["matrix"], np.float64)
    starts = np.cumsum([0] + dims)
    idx = np.concatenate([starts[names.index(t[0])] + np.arange(t[2].size) for t in tests])
    return M[np.ix_(idx, idx)]


def _as_file(x, what: str) -> ResultFile:
    if isinstance(x, ResultFile):
        return x
    if hasattr(x, "file") and isinstance(x.file, ResultFile):
        return x.file
    try:
        return load_result(x)
    except (TypeError, OSError) as err:
        raise BadInputError(f"{what}: got {type(x).__name__}, expected a jcalib.result/1 file, ResultFile or Result") from err


def reoptimise(cell, observations, prior, options=None, *, alpha: float = 0.01, input_hash: str | None = None,
               given: set[str] | None = None) -> Reoptimisation:
    """Re-calibrate a robot cell from new observations with a previous result as the prior.

    Args:
        cell: ``jcalib.cell/1`` spec (path, dict or CellSpec) of a robot cell.
        observations: the new ``jcalib.observations/1`` data (path, dict or Observations).
        prior: the old result (path, :class:`~jcalib.io.result.ResultFile` or :class:`jcalib.Result`)
            with covariances.
        options: :class:`~jcalib.problems.options.CalibrationOptions`.
        alpha: family-wise significance level of the change tests (default 1 %).
        input_hash: the inputs' hash for the provenance (computed when None).
        given: option names the user set explicitly (refused where the cell cannot use them).

    Returns:
        :class:`Reoptimisation`.
    """
    import json

    from jcalib.io.cell import cell_to_dict, load_cell
    from jcalib.io.observations import load_observations
    from jcalib.io.result import hash_inputs
    from jcalib.problems.calibrate import Result, calibrate_cell, result_file
    from jcalib.problems.options import CalibrationOptions

    cell_spec = load_cell(cell)
    obs = load_observations(observations)
    old = _as_file(prior, "prior")
    if not (cell_spec.robot is not None or cell_spec.robots):
        raise BadInputError(f"{cell_spec.source}: prior= (re-optimisation) works on robot cells; this cell has no robot")
    options = options or CalibrationOptions()
    if input_hash is None:
        input_hash = hash_inputs(json.dumps(cell_to_dict(cell_spec), sort_keys=True).encode(),
                                 json.dumps(obs.to_dict(), sort_keys=True).encode())
    first = calibrate_cell(cell_spec, obs, options, start=old, given=given)
    data_only = Result(result_file(first, options, input_hash), first)
    changes = compare_results(old, data_only.file, alpha=alpha)
    moved = [c.name for c in changes if c.moved]
    keep = [c.name for c in changes if not c.moved]
    counted = sum(1 for c in changes if c.dof > 0)
    per_test = alpha / max(counted, 1)
    stats = {"reoptimisation": {
        "alpha": alpha,
        "alpha_per_test": per_test,
        "moved": moved,
        "tests": [c.to_dict() for c in changes],
    }}
    final = calibrate_cell(cell_spec, obs, options, prior=old, prior_names=keep, given=given)
    result = Result(result_file(final, options, input_hash, extra_stats=stats), final)
    return Reoptimisation(result, changes, moved, data_only, alpha, per_test)
