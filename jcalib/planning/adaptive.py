"""Adaptive capture: add stations until the calibration *achieves* the accuracy goals (``jcalib capture --goal``).

Independent of hardware: the robot, the cameras and the detection are behind ``acquire``, the solve behind
``calibrate``. The candidates, the :class:`~jcalib.planning.predict.Predictor` and each candidate's
information are computed **once** (:mod:`jcalib.planning.optimal`); every choice below is a
:func:`~jcalib.planning.optimal.select` over the candidates not yet tried, with the stations captured so
far as its fixed start.

1. **Initial set.** Stations are chosen (greedy + exchanges) until the predicted σ of every goal is within
   :data:`DETERMINED` times its limit, or within :data:`DETERMINED` times the σ that all the candidates
   together would give (for a goal far stricter than the cell can reach), and at least :data:`MIN_INITIAL`
   stations (or ``max_stations`` when fewer). The data then determine every goal quantity (a quantity
   they leave undetermined has a σ many orders of magnitude larger): what is left is accuracy, not
   observability, and adding stations one by one against the measured σ takes over. They are acquired in that order; a failed acquisition (``acquire`` returns None: unreachable,
   target not found) excludes its candidate and the rest of the initial set is chosen again.
2. **Calibrate** all captured stations; each goal's achieved σ comes from the result's covariances
   (:func:`jcalib.problems.goals.achieved_sigmas`). Every goal met: stop.
3. **Rescale and add one station.** ``r_g = achieved_g / predicted_g``, the predicted σ being that of the
   captured stations (the measured poses and every camera / target or tool pair each station showed):
   how much the real noise, outliers and geometry differ from the prediction. The next station is the
   one :func:`~jcalib.planning.optimal.select` adds with every limit divided by ``r_g`` (so the choice
   aims at the real gap), without exchanges (captured stations stay). Acquire (a failure excludes the
   candidate and the next best is tried), go to 2, until met or ``max_stations`` stations are captured.
   A calibration the data cannot determine yet (:class:`~jcalib.errors.NotObservableError`) counts as
   unmet with ``r_g = 1``.

When the goals stay unmet, :attr:`AdaptiveOutcome.message` says which goal, by how much, and how many more
stations the rescaled prediction expects (or that the candidates cannot reach it).

The calibrations re-use one compiled solve per shape bucket (:mod:`jcalib.solve`), so re-solving after
each station costs a solve, not a compilation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jcalib.planning.candidates import Candidates, check_count
from jcalib.planning.layout import CellLayout
from jcalib.errors import BadInputError, NotObservableError
from jcalib.io.goals import Goal, parse_goals
from jcalib.io.observations import Observations, Station
from jcalib.planning.optimal import DEFAULT_CANDIDATES, Design, generate, select
from jcalib.planning.predict import Predictor
from jcalib.problems.options import CalibrationOptions

__all__ = ["DETERMINED", "MIN_INITIAL", "AdaptiveOutcome", "AdaptiveStep", "calibrate_stations",
           "observations_of", "run_adaptive"]

#: The initial set is chosen until every goal's predicted σ is within this factor of its limit.
DETERMINED = 100.0
#: ... and has at least this many stations (or ``max_stations`` when fewer).
MIN_INITIAL = 3
#: Stations the rescaled prediction may add when it estimates how many more would meet the goals.
LOOKAHEAD = 200
#: Largest and smallest rescale ratio ``achieved / predicted`` used.
RATIO_RANGE = (1e-3, 1e6)

#: ``acquire(candidate index, T_base_flange (4, 4) m, (camera, target or tool)) -> Station | None``.
Acquire = Callable[[int, np.ndarray, tuple[str, str]], "Station | None"]
#: ``calibrate(stations) -> ResultFile`` (or a :class:`jcalib.Result`, or a result path).
Calibrate = Callable[[list[Station]], Any]
#: ``on_progress(number of stations, achieved σ per goal text, predicted σ per goal text, met)``.
Progress = Callable[[int, dict, dict, bool], None]


@dataclass(frozen=True)
class AdaptiveStep:
    """One calibration of adaptive capture.

    Attributes:
        num_stations: stations calibrated.  achieved: goal text -> σ from the calibration (inf when the
        data could not determine the unknowns yet).  predicted: goal text -> σ predicted for those stations
        (stated noise).  met: every goal met.
    """

    num_stations: int
    achieved: dict[str, float]
    predicted: dict[str, float]
    met: bool


@dataclass
class AdaptiveOutcome:
    """What adaptive capture did.

    Attributes:
        stations: the captured stations, in order (those given as ``captured`` first).
        candidates: for each station its index into :attr:`candidate_set` (-1: captured before the run).
        history: one :class:`AdaptiveStep` per calibration.
        met: every goal met by the last calibration.
        result: what the last ``calibrate`` returned (None when none succeeded).
        message: a one-paragraph summary (which goals are unmet, by how much, what would help).
        failed: candidate indices whose acquisition failed.
        candidate_set: the candidates.
    """

    stations: list[Station]
    candidates: list[int]
    history: list[AdaptiveStep]
    met: bool
    result: Any
    message: str
    failed: list[int] = field(default_factory=list)
    candidate_set: Candidates | None = None

    @property
    def achieved(self) -> dict[str, float]:
        """The last calibration's achieved σ per goal text (empty before any)."""
        return dict(self.history[-1].achieved) if self.history else {}


class _Scaled:
    """A :class:`Predictor` as :func:`select` sees it, each goal's limit divided by ``ratio``."""

    def __init__(self, pred: Predictor, ratio: np.ndarray):
        self._pred, self.goals = pred, pred.goals
        self._ratio = np.asarray(ratio, np.float64)

    def goal_sigmas(self, cov: np.ndarray) -> np.ndarray:
        return self._pred.goal_sigmas(cov)

    def limits(self) -> np.ndarray:
        return self._pred.limits() / self._ratio


def observations_of(layout: CellLayout, stations: Iterable[Station]) -> Observations:
    """The observations of ``stations`` in the nominal cell (image sizes, target points from ``layout``)."""
    return Observations({c: tuple(int(s) for s in cl.image_size) for c, cl in layout.cameras.items()},
                        {t: np.asarray(tl.geometry.points, np.float64) for t, tl in layout.targets.items()},
                        tuple(stations))


def calibrate_stations(layout: CellLayout, options: CalibrationOptions | None = None) -> Calibrate:
    """A ``calibrate`` for :func:`run_adaptive`: :func:`jcalib.calibrate` of the layout's cell spec on the
    stations (:func:`observations_of`); returns the result file."""
    from jcalib.problems.api import calibrate

    def run(stations: list[Station]):
        return calibrate(layout.cell, observations_of(layout, stations), options).file

    return run


def _pairs(station: Station) -> list[tuple[str, str]]:
    out = []
    for d in station.detections:
        p = (d.camera, d.target if d.target is not None else d.tool)
        if p[1] is not None and p not in out:
            out.append(p)
    return out


def _station_information(pred: Predictor, layout: CellLayout, station: Station) -> np.ndarray:
    """``(n, n)`` predicted information of a captured station: its measured pose, every pair it showed."""
    pairs = _pairs(station)
    if station.T_base_flange is None or not pairs:
        return np.zeros((pred.size, pred.size))
    T = np.asarray(station.T_base_flange, np.float64)
    c = Candidates(np.stack([T] * len(pairs)), np.zeros((len(pairs), np.size(layout.home_rad))), pairs)
    try:
        return pred.informations(c).sum(axis=0)
    except KeyError:  # a pair the nominal cell does not place (nothing to predict)
        return np.zeros((pred.size, pred.size))


def _select(pred_like, captured: list[np.ndarray], infos: np.ndarray, prior: np.ndarray, available: np.ndarray,
            count: int, *, stop_when_met: bool, exchange: bool) -> tuple[list[int], Design]:
    """Up to ``count`` new candidates (indices into ``infos``) among ``available``, captured stations fixed;
    and the design (its ``sigma``: predicted σ of captured + new)."""
    avail = np.flatnonzero(available)
    n = infos.shape[-1]
    fixed = np.stack(captured) if captured else np.zeros((0, n, n))
    k = len(captured)
    d = select(pred_like, np.concatenate([fixed, infos[avail]]), prior, k + max(int(count), 0),
               stop_when_met=stop_when_met, start=list(range(k)), exchange=exchange)
    return [int(avail[j - k]) for j in d.chosen], d


def _ratios(achieved: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    r = np.where(np.isfinite(achieved) & (predicted > 0), achieved / np.where(predicted > 0, predicted, 1.0), 1.0)
    return np.clip(r, *RATIO_RANGE)


def _achieved(calibrate: Calibrate, stations: list[Station], goals: tuple[Goal, ...]) -> tuple[Any, np.ndarray, str]:
    """``(result, achieved σ (G,), note)``: inf and the reason when the data cannot determine the unknowns yet."""
    from jcalib.problems.goals import achieved_sigmas

    try:
        result = calibrate(list(stations))
    except NotObservableError as e:
        return None, np.full(len(goals), np.inf), str(e)
    s = achieved_sigmas(goals, result)
    return result, np.array([s[g.text] for g in goals]), ""


def _unmet_message(goals: tuple[Goal, ...], achieved: np.ndarray, n: int, why: str, more: str) -> str:
    bad = [f"{g.text} (σ {a:.3g} {g.unit})" if math.isfinite(a) else f"{g.text} (not determined yet)"
           for g, a in zip(goals, achieved) if not a <= g.limit]
    return f"goals not met after {n} station(s) ({why}): {'; '.join(bad)}. {more}"


def _lookahead(pred: Predictor, ratio: np.ndarray, captured: list[np.ndarray], infos: np.ndarray, prior: np.ndarray,
               available: np.ndarray) -> str:
    """What the rescaled prediction says about meeting the goals with more stations."""
    count = min(LOOKAHEAD, int(available.sum()))
    if count == 0:
        return "No candidate station is left to try."
    new, d = _select(_Scaled(pred, ratio), captured, infos, prior, available, count, stop_when_met=True,
                     exchange=False)
    if d.met:
        return (f"At the noise seen so far about {len(new)} more station(s) would meet them: raise --max-stations "
                f"to {len(captured) + len(new)} or more and resume.")
    return (f"Even {len(new)} more of the candidate stations would not meet them at the noise seen so far: relax "
            "the goal, lower the detection noise (focus, exposure, a larger or finer target) or widen the "
            "candidates (--amplitude-deg).")


def _check(goals: Sequence[Goal | str], max_stations: int) -> tuple[Goal, ...]:
    goals = tuple(g if isinstance(g, Goal) else parse_goals([g])[0] for g in goals)
    if not goals:
        raise BadInputError("adaptive capture: give at least one goal (--goal NAME:QUANTITY<=VALUE, e.g. "
                            "T_flange_cam0:translation_mm<=0.05)")
    parse_goals([g.text for g in goals])  # the same quantity twice is refused
    if not 1 <= int(max_stations) <= 500:
        raise BadInputError(f"--max-stations: expected 1..500 stations, got {max_stations}")
    return goals


def run_adaptive(layout: CellLayout, goals: Sequence[Goal | str], *, acquire: Acquire, calibrate: Calibrate,
                 max_stations: int, options: CalibrationOptions | None = None, seed: int = 0,
                 num_candidates: int = DEFAULT_CANDIDATES, on_progress: Progress | None = None,
                 captured: Sequence[Station] = (), max_failures: int | None = None,
                 amplitude_deg: float | None = None) -> AdaptiveOutcome:
    """Capture stations until every goal is achieved or ``max_stations`` are captured (module docstring).

    Args:
        layout: the nominal cell (:func:`jcalib.planning.layout.cell_layout`).
        goals: :class:`~jcalib.io.goals.Goal` s or their texts.
        acquire: moves the robot to a candidate and returns the detected station, or None when the
            station is unusable (unreachable, nothing detected); see :data:`Acquire`.
        calibrate: calibrates the captured stations; see :data:`Calibrate` (e.g.
            :func:`calibrate_stations`).
        max_stations: most stations to capture (those in ``captured`` included), 1..500.
        options: calibration options the prediction assumes (σ of corners, tips, ...).
        seed: seed of the candidates.  num_candidates: candidates generated (10..20000).
        on_progress: called after every calibration; see :data:`Progress`.
        captured: stations captured before (a resumed session): kept, counted, never repeated.
        max_failures: failed acquisitions allowed in all (default ``max(5, max_stations)``); then stop.
        amplitude_deg: largest view / tool tilt of the candidates (default the planner's).

    Returns:
        :class:`AdaptiveOutcome`.

    Raises:
        BadInputError: no goal, a goal the cell does not estimate, ``max_stations`` out of range, a cell
            with nothing a station could show; what ``acquire`` / ``calibrate`` raise.
    """
    goals = _check(goals, max_stations)
    max_stations = int(max_stations)
    max_failures = max(5, max_stations) if max_failures is None else int(max_failures)
    check_count(num_candidates)
    cands = generate(layout, num_candidates, np.random.default_rng(seed), amplitude_deg)
    pred = Predictor(layout, goals, options)
    pred.setup(cands)
    infos = pred.informations(cands)
    prior = pred.prior_information(cands)
    limits = pred.limits()
    available = np.ones(len(cands), bool)
    stations, where = list(captured), [-1] * len(captured)
    info = [_station_information(pred, layout, s) for s in stations]
    failed: list[int] = []

    def take(j: int) -> bool:
        available[j] = False
        st = acquire(j, np.array(cands.T_base_flange[j]), tuple(cands.pair[j]))
        if st is None:
            failed.append(j)
            return False
        stations.append(st)
        where.append(j)
        info.append(_station_information(pred, layout, st))
        return True

    def outcome(history, met, result, message) -> AdaptiveOutcome:
        return AdaptiveOutcome(stations, where, history, met, result, message, failed, cands)

    # 1. the initial set: every goal determined (within DETERMINED x its limit, or x the σ of all candidates
    # together), at least MIN_INITIAL stations
    _, everything = _select(pred, info + [infos.sum(axis=0)], infos, prior, np.zeros(len(cands), bool), 0,
                            stop_when_met=False, exchange=False)
    loose = _Scaled(pred, limits / (DETERMINED * np.maximum(limits, everything.sigma)))
    minimum = min(MIN_INITIAL, max_stations)

    def initial() -> list[int]:
        new, _ = _select(loose, info, infos, prior, available, max_stations - len(stations), stop_when_met=True,
                         exchange=True)
        short = minimum - len(stations) - len(new)
        if short > 0:
            rest = available.copy()
            rest[new] = False
            more, _ = _select(loose, info + [infos[j] for j in new], infos, prior, rest, short, stop_when_met=False,
                              exchange=False)
            new += more
        return new

    pending = initial()
    while pending and len(stations) < max_stations:
        if not take(pending.pop(0)):
            if len(failed) >= max_failures:
                return outcome([], False, None, f"stopped: {len(failed)} acquisitions failed (unreachable or "
                               "nothing detected); check the cell's poses and the detection")
            pending = initial()
    if not stations:
        return outcome([], False, None, "no station could be captured: no candidate is left to try")

    # 2-3. calibrate; rescale the prediction by what was achieved; add the station that closes the gap most
    history: list[AdaptiveStep] = []
    while True:
        result, achieved, note = _achieved(calibrate, stations, goals)
        _, d = _select(pred, info, infos, prior, available, 0, stop_when_met=False, exchange=False)
        met = bool(np.all(achieved <= limits))
        step = AdaptiveStep(len(stations), {g.text: float(a) for g, a in zip(goals, achieved)},
                            {g.text: float(s) for g, s in zip(goals, d.sigma)}, met)
        history.append(step)
        if on_progress is not None:
            on_progress(step.num_stations, dict(step.achieved), dict(step.predicted), met)
        if met:
            return outcome(history, True, result, f"every goal met with {len(stations)} station(s)")
        ratio = _ratios(achieved, np.asarray(d.sigma))
        if len(stations) >= max_stations:
            more = _lookahead(pred, ratio, info, infos, prior, available)
            if note:
                more = f"The last calibration could not determine every unknown: {note} {more}"
            return outcome(history, False, result, _unmet_message(goals, achieved, len(stations),
                                                                  f"--max-stations {max_stations}", more))
        aim = _Scaled(pred, ratio)
        while True:
            new, _ = _select(aim, info, infos, prior, available, 1, stop_when_met=False, exchange=False)
            if not new:
                return outcome(history, False, result, _unmet_message(
                    goals, achieved, len(stations), "no candidate station left", "Generate more candidates "
                    "(--candidates) or widen them (--amplitude-deg)."))
            if take(new[0]):
                break
            if len(failed) >= max_failures:
                return outcome(history, False, result, _unmet_message(
                    goals, achieved, len(stations), f"{len(failed)} acquisitions failed", "Check the cell's poses "
                    "(unreachable stations) and the detection (target not found)."))
