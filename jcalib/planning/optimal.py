"""Stations chosen for the accuracy the user needs (``jcalib plan --kind optimal --goal ...``).

1. **Candidates** (:mod:`jcalib.planning.candidates`): flange poses within reach and joint limits that
   show each camera / target pair the robot moves, and each tool tip to a base camera observing it.
2. **Prediction** (:class:`jcalib.planning.predict.Predictor`): each candidate's information ``I_m`` over
   the cell's free unknowns, from the one problem builder at the nominal values. The covariance of a set
   ``S`` is ``Σ(S) = (P + Σ_{m∈S} I_m)⁻¹`` (``P``: the cell's priors and a tiny ridge).
3. **Selection**: minimise ``f(S) = Σ_g (σ_g(S) / limit_g)²`` over the goals ``g`` (σ: worst direction,
   :mod:`jcalib.io.goals`). Greedy: add the candidate that lowers ``f`` most, record every goal's σ, stop
   when every goal is met (or at ``max_stations``). Then **exchanges** (Fedorov): swap a chosen station for
   any candidate while that lowers ``f``. Then **local refinement**: around each chosen station, new
   candidates turned by a few degrees about the target (or tool tip) and moved along the line of sight,
   checked for reach and view like every candidate, exchanged in when better; the step halves each round.
   (A derivative-free local search in pose space: the objective is a max over eigenvalues and the
   feasibility checks are discrete, so a pattern search is used instead of gradients.)
4. The stations are visited in nearest-neighbour order in joint space (short moves).

The prediction assumes the stated noise (``--sigma-px`` etc.), the robot's pose noise, the nominal
geometry within the linear range, and a correct model (no lens-model error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jcalib.planning import candidates as cands
from jcalib.planning.layout import CellLayout
from jcalib.planning.stations import PlannedStations, visit_order
from jcalib.errors import BadInputError
from jcalib.geometry.se3 import exp_so3, make_pose
from jcalib.io.goals import Goal
from jcalib.io.plan import make_plan
from jcalib.planning.predict import RIDGE, Predictor
from jcalib.problems.options import CalibrationOptions

__all__ = ["DEFAULT_CANDIDATES", "DEFAULT_MAX_STATIONS", "Design", "design", "plan_optimal", "select"]

#: Candidate stations generated per plan (split over the pairs).
DEFAULT_CANDIDATES = 400
#: Stations an optimal plan holds at most unless told otherwise.
DEFAULT_MAX_STATIONS = 20
#: Exchange passes and local-refinement rounds.
EXCHANGE_PASSES = 3
REFINE_ROUNDS = 2
#: Local refinement: first step (deg about the target / tip; fraction of the distance along the line of sight).
REFINE_STEP_DEG = 8.0
REFINE_STEP_DISTANCE = 0.1


@dataclass
class Design:
    """A selection of stations and what it predicts.

    Attributes:
        chosen: indices into the candidates, in the order they were added (exchanges replace in place).
        history: ``(k, G)`` predicted σ of each goal after 1..k stations (greedy phase).
        sigma: ``(G,)`` predicted σ of the final selection.  met: every goal met.
        information: ``(n, n)`` predicted information of the final selection (priors and ridge included).
        refined: how many of the chosen stations came from the local refinement.
    """

    chosen: list[int]
    history: np.ndarray
    sigma: np.ndarray
    met: bool
    information: np.ndarray
    refined: int = 0


def _ridge(infos: np.ndarray, prior: np.ndarray) -> np.ndarray:
    d = np.mean(np.diagonal(infos, axis1=1, axis2=2), axis=0) + np.diag(prior)
    return np.diag(np.where(d > 0, RIDGE * d, 1.0))


def _objective(pred: Predictor, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(f, σ)`` for information matrices ``A (..., n, n)``."""
    cov = np.linalg.inv(A)
    s = pred.goal_sigmas(cov)
    return np.sum((s / pred.limits()) ** 2, axis=-1), s


def select(pred: Predictor, infos: np.ndarray, prior: np.ndarray, max_stations: int, *, stop_when_met: bool = True,
           start: list[int] | None = None, exchange: bool = True) -> Design:
    """Greedy selection and exchanges (module docstring, step 3) among candidates of information ``infos``.

    Args:
        start: candidates already taken (adaptive capture): kept, never exchanged.
    """
    P = prior + _ridge(infos, prior)
    fixed = list(start or [])
    A = P + infos[fixed].sum(axis=0) if fixed else P.copy()
    chosen: list[int] = []
    history = []
    taken = np.zeros(len(infos), bool)
    taken[fixed] = True
    _, s0 = _objective(pred, A)
    met = bool(np.all(s0 <= pred.limits()))
    while len(fixed) + len(chosen) < max_stations and not (stop_when_met and met):
        f, s = _objective(pred, A[None] + infos)
        f = np.where(taken, np.inf, f)
        k = int(np.argmin(f))
        if not np.isfinite(f[k]):
            break
        chosen.append(k)
        taken[k] = True
        A = A + infos[k]
        history.append(s[k])
        met = bool(np.all(s[k] <= pred.limits()))
    d = Design(chosen, np.array(history).reshape(len(history), len(pred.goals)), s0, met, A)
    return _exchange_from(pred, infos, prior, d, fixed) if exchange and chosen else _final(pred, d)


def _final(pred: Predictor, d: Design) -> Design:
    _, d.sigma = _objective(pred, d.information)
    d.met = bool(np.all(d.sigma <= pred.limits()))
    return d


def generate(layout: CellLayout, count: int, rng: np.random.Generator, amplitude_deg: float | None = None
             ) -> cands.Candidates:
    """Candidates for every pair of the cell, ``count`` in all (split evenly)."""
    views, tips = cands.cell_pairs(layout)
    pairs = [("view", p) for p in views] + [("tip", p) for p in tips]
    if not pairs:
        raise BadInputError("plan --kind optimal: the cell has no camera / target pair that the robot moves relative to "
                            "each other (one on the flange, the other on the base) and no tool observed by a base "
                            "camera: nothing a station could show")
    each = max(10, count // len(pairs))
    parts = []
    for kind, (a, b) in pairs:
        if kind == "view":
            parts.append(cands.view_candidates(layout, a, b, each, rng, amplitude_deg or 45.0))
        else:
            parts.append(cands.tool_candidates(layout, a, b, each, rng, amplitude_deg or 40.0))
    return cands.merge(parts)


def _neighbours(layout: CellLayout, c: cands.Candidates, chosen: list[int], step_deg: float, step_d: float,
                rng: np.random.Generator) -> cands.Candidates:
    """Candidates near the chosen ones: each turned about the point it views (target centre, tool tip) by
    ``step_deg`` about 6 axes, and moved along the line of sight by ``± step_d`` of the distance; checked for
    reach and (views) for view like every candidate."""
    from jcalib.planning.stations import camera_frames, view_problem

    poses, pairs = [], []
    for k in chosen:
        T = c.T_base_flange[k]
        cam_name, thing = c.pair[k]
        cam = layout.cameras[cam_name]
        if thing in layout.targets:
            tl = layout.targets[thing]
            T_base_t = tl.pose if tl.mount == "base" else T @ tl.pose
            centre = T_base_t[:3, :3] @ tl.centre + T_base_t[:3, 3]
        else:
            centre = (T @ layout.tools[thing])[:3, 3]
        T_base_cam = cam.pose if cam.mount == "base" else T @ cam.pose
        sight = centre - T_base_cam[:3, 3]
        axes = np.concatenate([np.eye(3), -np.eye(3)]) @ exp_so3(rng.normal(scale=0.3, size=3)).T
        for a in axes:
            R = exp_so3(a * math.radians(step_deg))
            poses.append(make_pose(R, centre - R @ centre) @ T)
            pairs.append(c.pair[k])
        for s in (-step_d, step_d):
            shift = np.eye(4)
            shift[:3, 3] = (-s if cam.mount == "flange" else s) * sight
            poses.append(shift @ T)
            pairs.append(c.pair[k])
    if not poses:
        return cands.Candidates(np.zeros((0, 4, 4)), np.zeros((0, 6)), [])
    poses = np.stack(poses)
    ok, q = cands.reach(layout, poses)
    keep = []
    for i in np.flatnonzero(ok):
        cam_name, thing = pairs[i]
        if thing in layout.targets:
            T_ct, _ = camera_frames(layout, cam_name, thing, poses[i:i + 1])
            if view_problem(layout, cam_name, thing, T_ct[0], layout.viewing_distance(cam_name, thing)) is not None:
                continue
        keep.append(i)
    return cands.Candidates(poses[keep], q[keep], [pairs[i] for i in keep])


def design(layout: CellLayout, goals: tuple[Goal, ...], max_stations: int, *, options: CalibrationOptions | None = None,
           num_candidates: int = DEFAULT_CANDIDATES, seed: int = 0, stop_when_met: bool = True,
           refine: bool = True, amplitude_deg: float | None = None
           ) -> tuple[Design, cands.Candidates, Predictor]:
    """Candidates, prediction and selection (module docstring) for the nominal cell."""
    if not goals:
        raise BadInputError("plan --kind optimal: give at least one goal (--goal NAME:QUANTITY<=VALUE, e.g. "
                            "T_flange_cam0:translation_mm<=0.05), or goals: in the cell spec")
    if not 1 <= int(max_stations) <= 500:
        raise BadInputError(f"--max-stations: expected 1..500 stations, got {max_stations}")
    cands.check_count(num_candidates)
    rng = np.random.default_rng(seed)
    c = generate(layout, num_candidates, rng, amplitude_deg)
    pred = Predictor(layout, goals, options)
    pred.setup(c)
    infos = pred.informations(c)
    prior = pred.prior_information(c)
    d = select(pred, infos, prior, int(max_stations), stop_when_met=stop_when_met)
    if refine and d.chosen:
        generated = len(c)
        step, step_d = REFINE_STEP_DEG, REFINE_STEP_DISTANCE
        for _ in range(REFINE_ROUNDS):
            extra = _neighbours(layout, c, d.chosen, step, step_d, rng)
            if len(extra):
                c = cands.merge([c, extra])
                infos = np.concatenate([infos, pred.informations(extra)])
                d = _exchange_from(pred, infos, prior, d)
            step, step_d = step / 2, step_d / 2
        d.refined = sum(1 for k in d.chosen if k >= generated)
    return d, c, pred


def _exchange_from(pred: Predictor, infos: np.ndarray, prior: np.ndarray, d: Design,
                   fixed: list[int] | None = None) -> Design:
    """Exchanges (Fedorov) starting from the design's selection, among all of ``infos``; ``fixed``
    stations (already captured) stay."""
    fixed = list(fixed or [])
    P = prior + _ridge(infos, prior)
    chosen = list(d.chosen)
    taken = np.zeros(len(infos), bool)
    taken[chosen + fixed] = True
    A = P + infos[chosen + fixed].sum(axis=0)
    for _ in range(EXCHANGE_PASSES):
        improved = False
        for j in range(len(chosen)):
            base = A - infos[chosen[j]]
            f, _ = _objective(pred, base[None] + infos)
            f = np.where(taken, np.inf, f)
            k = int(np.argmin(f))
            f_now, _ = _objective(pred, A)
            if f[k] < f_now * (1.0 - 1e-9):
                taken[chosen[j]], taken[k] = False, True
                chosen[j] = k
                A = base + infos[k]
                improved = True
        if not improved:
            break
    return _final(pred, Design(chosen, d.history, d.sigma, d.met, A, d.refined))


def plan_optimal(layout: CellLayout, goals: tuple[Goal, ...], max_stations: int, **kw) -> PlannedStations:
    """The plan (``jcalib.plan/1``) of :func:`design`, stations in visiting order, with the prediction."""
    d, c, pred = design(layout, goals, max_stations, **kw)
    if not d.chosen:
        raise BadInputError("plan --kind optimal: the goals are met by the cell's priors alone; no station needed")
    pred.check_start(c.subset(d.chosen))
    order = visit_order(c.joints_rad[d.chosen], layout.home_rad)
    chosen = [d.chosen[i] for i in order]
    joints = None
    if pred.kinematics is not None:  # the configuration the prediction assumed (elbow, wrist branch)
        from jcalib.geometry.kinematic_models import joints_to_controller

        joints = joints_to_controller(pred.kinematics, c.joints_rad[chosen])
    stations = [pred.station(c.T_base_flange[k], c.pair[k], joints_rad=c.joints_rad[k]).T_base_flange for k in chosen]
    plan = make_plan(np.stack(stations), joints_deg=joints)
    texts = [g.text for g in goals]
    details = {
        "goals": texts,
        "predicted": {t: float(s) for t, s in zip(texts, d.sigma)},
        "met": d.met,
        "after_each_station": [{t: float(s) for t, s in zip(texts, row)} for row in d.history],
        "pairs": [list(c.pair[k]) for k in chosen],
        "candidates": len(c),
        "refined": d.refined,
        "assumes": (f"{pred.options.sigma_px:g} px corner noise, {pred.options.tip_sigma_px:g} px tip noise per "
                    "coordinate, the robot's pose noise, the nominal cell geometry (first order)"),
    }
    return PlannedStations(plan, "optimal", dropped={k: str(v) for k, v in c.dropped.items()}, details=details)
