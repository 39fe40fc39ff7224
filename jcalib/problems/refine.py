"""Refinement rounds around the one solve: re-seeded views, outlier rejection, variance components.

All rounds re-use the compiled solve of the first (only weights, σ and start values change), and
they run on a list of data sets at once: a round re-solves every member that needs it in one
vmapped call (:func:`jcalib.solve.solve_many`), so a Monte-Carlo batch is as cheap as one data set
per member; a single calibration is a list of one.

1. **Re-seeding** (free targets): a view whose typical corner error (the median over its corners)
   is far above the other views' may have started in the flipped planar-PnP minimum; its other PnP
   pose starts a second solve, kept when the cost drops. The median, not the RMS: a view with one
   gross outlier corner is a good pose with a bad corner (round 2 rejects it), and re-seeding it cost
   a PnP and a long second solve that was then thrown away.
2. **Outliers**: corners, tool tips and axis points beyond ``outlier_threshold`` σ of their own kind
   are rejected (σ: a robust scale, 1.4826 MAD of the kind's inlier residual coordinates, with
   a-posteriori noise; the stated σ otherwise) and the problem re-solved from the last estimate; every
   round re-decides every measurement, so one pulled along by an outlier comes back.
3. **Variance components**: corners, tips, axis points, contacts and pose measurements come from
   different sensors; one σ̂² of all residuals would let the most numerous kind set the noise of the
   others, and would rescale stated priors (the robot's pose noise, a previous result). Each kind
   ``k`` gets its own factor ``f_k = χ²_k / (r_k − 2)`` (Helmert's ``χ²_k / r_k``, with
   ``r_k = m_k − Σ_g tr(H_g H⁻¹)`` its redundancy, times ``r_k / (r_k − 2)``: an error scaled by a σ
   estimated from ``r_k`` degrees of freedom follows Student's t, whose variance that is; it matters
   for a kind with few residuals, such as 7 tool tips), re-solved until every factor is within 1 % of
   1; stated priors keep their σ. A kind
   with too little redundancy (:data:`MIN_REDUNDANCY`) keeps its stated σ; when no kind can estimate
   its own, one factor σ̂² of all residuals scales the covariance.
4. **View noise**: the images of one camera are not equally sharp (a tilted or distant board is
   blurred and foreshortened: its corners are noisier), and the tilted views are the ones that
   determine focal length and hand-eye. Under one σ for all corners the covariance of exactly those
   unknowns comes out too small. Each view therefore gets its own factor on its kind's σ² (with the
   kind factors, in the same iterations): ``f_v = (χ²_v + ν₀) / (r_v + ν₀)``, its χ² against the kind's
   σ over its share ``r_v`` of the kind's redundancy, shrunk towards 1 by :data:`VIEW_PRIOR_DOF`
   pseudo-observations (a view of a few corners keeps about the kind's σ), normalised to a
   redundancy-weighted mean of 1 per kind.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import JcalibError, NotObservableError
from jcalib.problems.build import CORNER_KINDS, Built, se3_matrix, se3_params
from jcalib.problems.graph import Graph
from jcalib.problems.start import Start, pnp_poses
from jcalib.solve import Solution, SolveOptions, Status, batch_width, bucket_size, solve, solve_many
from jcalib.solve.core import raise_if_unobservable

#: Rounds of outlier rejection (each re-solves once; stops when the rejected set stops changing).
MAX_OUTLIER_ROUNDS = 5
#: Iterations of the variance-component estimation (each re-solves from the previous solution).
VARIANCE_COMPONENT_ITERATIONS = 25
#: A kind estimates its own noise factor only with at least this redundancy (and a quarter of its
#: count); below, χ² has too few degrees of freedom (e.g. tool tips whose 2 coordinates per station
#: the station's robot pose correction can absorb) and the kind keeps its stated σ.
MIN_REDUNDANCY = 5.0
#: Smallest variance factor of a kind (its σ at least 1e-3 of the stated one): noise-free data would
#: drive ``χ²_k / r_k`` to ~0 and that kind's weight to infinity, which buries every stated prior
#: (the robot's pose noise) below the rank test's resolution and reports them as not observable.
MIN_VARIANCE_FACTOR = 1e-6
#: Pseudo-degrees of freedom that pull a view's noise factor towards its kind's (a 54-corner view has
#: ~100 of its own).
VIEW_PRIOR_DOF = 20.0
#: relative cost decrease a re-seeded solve must bring to replace the first one
RESEED_MIN_DECREASE = 1e-6
#: Views whose median corner error exceeds this many times the median over views are re-seeded.
RESEED_FACTOR = 3.0


@dataclass
class Refined:
    """The final solve and what the rounds decided.

    Attributes:
        sol: the final :class:`jcalib.solve.Solution`; weights: group -> ``(n,)`` (0 = rejected).
        outliers: ``(camera/tool, station id, point index or -1)`` of rejected measurements.
        reseeded: station ids whose start pose was replaced by the other PnP candidate.
        components: kind -> variance factor on its stated σ² (empty: one factor σ̂² for all).
        views: corner group -> ``(n,)`` noise factor of each observation's view, on its kind's σ² (empty:
            all 1).
        cov_noise: ``"stated"`` (the σ carry the factors) or ``"a_posteriori"`` (scale by σ̂²).
    """

    sol: Solution
    weights: dict[str, np.ndarray]
    outliers: list[tuple[str, str, int]] = field(default_factory=list)
    reseeded: list[str] = field(default_factory=list)
    components: dict[str, float] = field(default_factory=dict)
    cov_noise: str = "a_posteriori"
    views: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class Member:
    """One data set in the rounds: its graph, start, problem and current state."""

    g: Graph
    start: Start
    built: Built
    weights: dict[str, np.ndarray] = field(default_factory=dict)
    sol: Solution | None = None
    scale: dict[str, float] = field(default_factory=dict)
    error: JcalibError | None = None
    outliers: list = field(default_factory=list)
    reseeded: list = field(default_factory=list)
    components: dict = field(default_factory=dict)
    views: dict = field(default_factory=dict)


def residuals(built: Built, sol: Solution) -> dict[str, np.ndarray]:
    """Group -> ``(n, m)`` residuals of its real observations at ``sol`` (the kind's unit)."""
    return {gr.name: sol.residuals[gr.name][gr.pad] for gr in built.groups}


def _kinds(built: Built) -> list[str]:
    return sorted({gr.kind for gr in built.groups})


def uses_components(built: Built, options) -> bool:
    """Whether variance components apply: a-posteriori noise with several kinds or stated priors."""
    stated = any(f.name.startswith(("prior:", "kinematic:")) for f in built.problem.factors)  # stated σ, held
    return options.noise == "a_posteriori" and (len(_kinds(built)) > 1 or stated)


class _Rounds:
    def __init__(self, members: list[Member], options, batched: bool):
        self.m, self.o, self.batched = members, options, batched
        # mu0 1e-6: closed-form starts are close enough that near-Gauss-Newton steps are accepted at once
        self.so = SolveOptions(max_iterations=options.max_iterations, mu0=1e-6)
        self.traces = [uses_components(x.built, options) for x in members]

    def solve(self, idx: list[int], x0s: list[dict | None] | None = None) -> list[Solution | None]:
        """Solve members ``idx`` (their current weights and scales); errors go to ``member.error``."""
        x0s = x0s or [None] * len(idx)
        out: list[Solution | None] = [None] * len(idx)
        if not self.batched:
            for j, (i, x0) in enumerate(zip(idx, x0s)):
                x = self.m[i]
                try:
                    out[j] = solve(x.built.with_weights(x.weights, x.scale or None, x.views or None), x0=x0,
                                   options=self.so, traces=self.traces[i])
                except JcalibError as err:
                    x.error = err
            return out
        groups: dict[tuple, list[int]] = {}
        for j, i in enumerate(idx):
            groups.setdefault((self.traces[i], id(type(self.m[i].built.problem))), []).append(j)
        for (traces, kind), js in groups.items():
            problems = []
            for j in js:
                x = self.m[idx[j]]
                p = x.built.with_weights(x.weights, x.scale or None, x.views or None)
                problems.append(p if x0s[j] is None else p.with_values(x0s[j]))
            fill, width = self._shape_fillers((traces, kind), {idx[j] for j in js})
            try:
                sols = solve_many(problems + fill, self.so, traces=traces, width=width)[:len(problems)]
            except JcalibError:  # different structures: one by one
                sols = []
                for p in problems[:len(js)]:
                    sols.append(solve(p, options=self.so, traces=traces, raise_on_unobservable=False))
            for j, s in zip(js, sols):
                x = self.m[idx[j]]
                try:
                    raise_if_unobservable(s)
                    if s.status == Status.NON_FINITE:
                        raise NotObservableError("the residuals or their derivatives are not finite at the start "
                                                 "(check the inputs)", ["start"])
                    out[j] = s
                except JcalibError as err:
                    x.error = err
        return out

    def _shape_fillers(self, key: tuple, taking: set[int]) -> tuple[list, int]:
        """Problems that keep a later round's vmapped call at the first call's shape and width (one
        compiled solve for every round): the members whose counts set the batch's padded size, at their
        current solution (their results are dropped), and the first call's width."""
        group = [i for i, x in enumerate(self.m)
                 if (self.traces[i], id(type(x.built.problem))) == key]
        biggest: dict[str, tuple[int, int]] = {}
        for i in group:
            p = self.m[i].built.problem
            sizes = {v.name: bucket_size(v.num) for v in p.variables}
            sizes.update({f.name: bucket_size(f.num_obs // (f.chunk or 1)) for f in p.factors})
            for name, n in sizes.items():
                if n > biggest.get(name, (-1, -1))[0]:
                    biggest[name] = (n, i)
        fill = []
        for i in sorted({i for _, i in biggest.values()} - taking):
            x = self.m[i]
            if x.sol is not None:
                p = x.built.with_weights(x.weights, x.scale or None, x.views or None)
                fill.append(p.with_values(x.sol.values))
        return fill, batch_width(len(group))

    def live(self) -> list[int]:
        return [i for i, x in enumerate(self.m) if x.error is None]

    def run(self) -> None:
        for x in self.m:
            x.weights = x.built.unit_weights()
        idx = list(range(len(self.m)))
        for i, s in zip(idx, self.solve(idx)):
            self.m[i].sol = s
        if self.o.reseed_views:
            self.reseed()
        if self.o.outlier_threshold is not None:
            self.reject()
        for i in self.live():
            x = self.m[i]
            if self.o.noise == "a_posteriori" and not x.sol.sigma2 == x.sol.sigma2:
                x.error = NotObservableError(
                    f"The a-posteriori noise level needs more residuals ({x.sol.num_residuals}) than free unknowns "
                    f"({x.sol.num_free}); use noise='stated'.", ["sigma2"])
        self.components()

    # ------------------------------------------------------------------------- rounds

    def reseed(self) -> None:
        todo, x0s, suspects = [], [], {}
        for i in self.live():
            x = self.m[i]
            if not x.g.free_things():
                continue
            values, ks = _reseed_values(x)
            if ks:
                todo.append(i)
                x0s.append(values)
                suspects[i] = ks
        for i, s in zip(todo, self.solve(todo, x0s)):
            x = self.m[i]
            if s is None:
                x.error = None  # the re-seeded start failed: keep the first solve
                continue
            # a re-seeded start that lands in the same minimum differs from it by rounding only: it is
            # neither taken nor reported (the flipped-view minimum it guards against costs far more)
            if s.cost < x.sol.cost * (1.0 - RESEED_MIN_DECREASE):
                x.sol, x.reseeded = s, [x.g.station_ids[k] for k in sorted(set(suspects[i]))]

    def reject(self) -> None:
        for _ in range(MAX_OUTLIER_ROUNDS):
            todo = []
            for i in self.live():
                x = self.m[i]
                new = _outlier_weights(x, self.o)
                if not all(np.array_equal(new[n], x.weights[n]) for n in x.weights):
                    x.weights = new
                    todo.append(i)
            if not todo:
                break
            for i, s in zip(todo, self.solve(todo, [self.m[i].sol.values for i in todo])):
                if s is not None:
                    self.m[i].sol = s
        for i in self.live():
            x = self.m[i]
            for gr in x.built.groups:
                who = "/".join(gr.key) if gr.kind not in CORNER_KINDS else gr.key[0]
                x.outliers += [(who, x.g.station_ids[int(gr.stations[j])], int(gr.index[j]))
                               for j in np.flatnonzero(x.weights[gr.name] == 0)]

    def components(self) -> None:
        active = [i for i in self.live() if self.traces[i]]
        for i in active:
            x = self.m[i]
            x.scale = dict.fromkeys(_kinds(x.built), 1.0)
        for _ in range(VARIANCE_COMPONENT_ITERATIONS):
            todo = []
            for i in active:
                x = self.m[i]
                if x.error is not None:
                    continue
                use = _component_update(x)
                if not use:
                    continue
                step = {}
                for k, f in use.items():
                    new = max(x.scale[k] * f, MIN_VARIANCE_FACTOR)
                    step[k], x.scale[k] = new / x.scale[k], new
                views = _view_update(x) if "corner" in use else {}
                moved = max([0.0] + [float(np.max(np.abs(views[n] / x.views[n] - 1.0))) if n in x.views
                                     else float(np.max(np.abs(views[n] - 1.0))) for n in views])
                x.views = views
                todo.append((i, all(abs(v - 1.0) < 0.01 for v in step.values()) and moved < 0.01))
            if not todo:
                break
            idx = [i for i, _ in todo]
            for i, s in zip(idx, self.solve(idx, [self.m[i].sol.values for i in idx])):
                if s is not None:
                    self.m[i].sol = s
            active = [i for i, done in todo if not done]
            if not active:
                break
        for i in self.live():
            x = self.m[i]
            x.components = {k: v for k, v in x.scale.items() if v != 1.0}


def _reseed_values(x: Member):
    """Start values with suspect views of free targets re-started from their other PnP pose."""
    g, built, sol, start = x.g, x.built, x.sol, x.start
    typical = _view_error(built, sol, x.weights)
    median = float(np.median(list(typical.values()))) if typical else 0.0
    by_name = {gr.name: gr for gr in built.groups}
    values = {k: v.copy() for k, v in sol.values.items()}
    suspects = []
    for (name, k), v in sorted(typical.items()):
        gr = by_name[name]
        cam, target = gr.key
        if v <= RESEED_FACTOR * max(median, 1e-3) or target not in built.free_entry:
            continue
        model = start.models[cam].with_params(sol.values[f"intrinsics:{cam}"][0])
        p = g.pairs[gr.key]
        j = p.views.index(k)
        T_ct = pnp_poses(model, [p.points[j]], [p.pixels[j]], second=True)[0]
        W_cam = se3_matrix(sol.values[g.mount_name(g.cell.cameras[cam])][0])
        values[g.free_name(target)][built.free_entry[target][k]] = se3_params(W_cam @ T_ct)
        suspects.append(k)
    return values, suspects


def _view_error(built: Built, sol: Solution, weights) -> dict[tuple[str, int], float]:
    """``(group, station) -> median`` corner error (pixels) of each view's inlier corners: robust to a
    few gross outliers in a view, high for a view whose pose is wrong (every corner off)."""
    out = {}
    res = residuals(built, sol)
    for gr in built.groups:
        if gr.kind != "corner":
            continue
        inlier = weights[gr.name] > 0
        err, stations = np.linalg.norm(res[gr.name], axis=1)[inlier], gr.stations[inlier]
        order = np.lexsort((err, stations))  # by station, then error: each view's errors sorted
        views, first, count = np.unique(stations[order], return_index=True, return_counts=True)
        ranked = err[order]
        median = 0.5 * (ranked[first + (count - 1) // 2] + ranked[first + count // 2])
        out.update(((gr.name, int(k)), float(m)) for k, m in zip(views, median))
        out.update(((gr.name, int(k)), 0.0) for k in np.setdiff1d(gr.stations, views))
    return out


def _outlier_weights(x: Member, options) -> dict[str, np.ndarray]:
    built = x.built
    res = residuals(built, x.sol)
    scale = {}
    for kind in {gr.kind for gr in built.groups if gr.robust}:
        coords = [res[gr.name][x.weights[gr.name] > 0].reshape(-1) for gr in built.groups if gr.kind == kind]
        coords = np.concatenate(coords) if coords else np.zeros(0)
        scale[kind] = (1.4826 * float(np.median(np.abs(coords))) if coords.size >= 10
                       and options.noise == "a_posteriori" else built.sigma[kind])
    return {gr.name: (np.where(np.linalg.norm(res[gr.name], axis=1) > options.outlier_threshold * scale[gr.kind],
                               0.0, 1.0) if gr.robust else x.weights[gr.name]) for gr in built.groups}


def _component_update(x: Member) -> dict[str, float]:
    """Kind -> ``χ²_k / (r_k − 2)`` for the kinds with enough redundancy (module docstring, round 3)."""
    sol, built = x.sol, x.built
    use = {}
    for k in _kinds(built):
        names = [gr.name for gr in built.groups if gr.kind == k]
        count = sum(sol.count[n] for n in names)
        chi2 = sum(sol.chi2[n] for n in names)
        redundancy = count - sum(sol.hat[n] for n in names)
        if redundancy >= max(MIN_REDUNDANCY, 0.25 * count) and chi2 > 0.0:
            use[k] = chi2 / (redundancy - 2.0)
    return use


def _view_update(x: Member) -> dict[str, np.ndarray]:
    """Corner group -> ``(n,)`` new view factors (module docstring, round 4); empty with a single view."""
    sol, built = x.sol, x.built
    groups = [gr for gr in built.groups if gr.kind == "corner"]
    count = sum(sol.count[gr.name] for gr in groups)
    if not groups or count <= 0:
        return {}
    share = (count - sum(sol.hat[gr.name] for gr in groups)) / count  # redundancy per residual
    sigma2 = built.sigma["corner"] ** 2 * x.scale["corner"]
    out, chi2, red = {}, {}, {}
    for gr in groups:
        res = sol.residuals[gr.name][gr.pad]
        inlier = x.weights[gr.name] > 0
        z2 = np.sum(res * res, axis=1) / sigma2 * inlier
        k = gr.stations
        chi2[gr.name] = np.bincount(k, weights=z2)
        red[gr.name] = share * res.shape[1] * np.bincount(k, weights=inlier.astype(float))
    if sum(int(np.count_nonzero(r)) for r in red.values()) < 2:
        return {}
    factor = {n: (chi2[n] + VIEW_PRIOR_DOF) / (red[n] + VIEW_PRIOR_DOF) for n in chi2}
    mean = sum(float(np.sum(factor[n] * red[n])) for n in factor) / sum(float(np.sum(red[n])) for n in red)
    for gr in groups:
        out[gr.name] = factor[gr.name][gr.stations] / mean
    return out


def refine_many(members: list[Member], options, batched: bool = False) -> list[Refined | JcalibError]:
    """Run the rounds of the module docstring on every member (each re-solve of a round in one
    vmapped call when ``batched``). Returns each member's :class:`Refined` or its error."""
    rounds = _Rounds(members, options, batched)
    rounds.run()
    out: list[Refined | JcalibError] = []
    for x, traced in zip(members, rounds.traces):
        if x.error is not None:
            out.append(x.error)
            continue
        noise = "stated" if traced and x.components else options.noise
        out.append(Refined(x.sol, x.weights, x.outliers, x.reseeded, x.components, noise, x.views))
    return out


def refine(g: Graph, start: Start, built: Built, options) -> Refined:
    """The rounds of one data set; raises its error."""
    out = refine_many([Member(g, start, built)], options)[0]
    if isinstance(out, JcalibError):
        raise out
    return out
