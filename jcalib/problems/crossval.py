"""Split-half cross-validation: one observation set split into two halves of its stations, each calibrated
with the same cell and options by the one calibration path (:func:`jcalib.problems.api.calibrate`).

The two results are independent estimates of the same cell (disjoint stations, independent noise), so their
differences should be what their covariances predict; :func:`jcalib.report.compare.split_half_comparison`
compares the cameras.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.observations import Observations, load_observations

__all__ = ["MIN_VIEWS_PER_HALF", "SPLITS", "SplitHalves", "calibrate_halves", "split_stations"]

#: Fewest views (stations where the camera sees a target) of every camera in each half.
MIN_VIEWS_PER_HALF = 4

#: How the stations are split: ``interleaved`` (even / odd in file order) or ``random`` (seeded).
SPLITS = ("interleaved", "random")


@dataclass(frozen=True)
class SplitHalves:
    """The two halves of one observation set and their calibrations.

    Attributes:
        stations: ``(ids of half A, ids of half B)``, each in file order.
        observations: the two halves (:class:`~jcalib.io.observations.Observations`).
        results: the two results (:class:`~jcalib.problems.calibrate.Result`), or ``(None, None)`` from
            :func:`split_stations` alone.
    """

    stations: tuple[tuple[str, ...], tuple[str, ...]]
    observations: tuple[Observations, Observations]
    results: tuple[Any, Any] = (None, None)


def _views(stations) -> Counter:
    """Camera id -> number of stations where it sees a target."""
    return Counter(c for s in stations for c in {d.camera for d in s.detections if d.target is not None})


def split_stations(observations: Any, *, split: str = "interleaved", seed: int = 0,
                   min_views: int = MIN_VIEWS_PER_HALF) -> SplitHalves:
    """Split the stations with observations into two halves.

    Args:
        observations: path, dict or :class:`~jcalib.io.observations.Observations`.
        split: ``"interleaved"``: even and odd stations in file order (halves of the same spread when the
            stations were planned as a sequence); ``"random"``: a random half (``seed``), the rest.
        seed: seed of the random split.
        min_views: fewest views of every camera (stations where it sees a target) in each half.

    Returns:
        :class:`SplitHalves` without results.

    Raises:
        BadInputError: an unknown split, or a camera with fewer than ``min_views`` views in a half (naming
            the camera and the counts).
    """
    if split not in SPLITS:
        raise BadInputError(f"split: expected one of {', '.join(SPLITS)}, got {split!r}")
    obs = load_observations(observations)
    stations = [s for s in obs.stations if s.detections or s.contacts or s.poses]
    if split == "interleaved":
        halves = (stations[0::2], stations[1::2])
    else:
        order = np.random.default_rng(seed).permutation(len(stations))
        first = set(order[: (len(stations) + 1) // 2].tolist())
        halves = ([s for i, s in enumerate(stations) if i in first],
                  [s for i, s in enumerate(stations) if i not in first])
    total = _views(stations)
    counts = (_views(halves[0]), _views(halves[1]))
    for camera in obs.cameras:
        n_a, n_b = counts[0][camera], counts[1][camera]
        if min(n_a, n_b) < min_views:
            short = 2 * min_views - total[camera]
            hint = (f"add at least {short} more views of it" if short > 0 else
                    "its views fall unevenly into the halves: try the other split")
            raise BadInputError(
                f"observations ({obs.source}): split-half cross-validation needs at least {min_views} views of "
                f"each camera in each half; camera {camera!r} has {total[camera]} views ({n_a} and {n_b} in the "
                f"{split} halves): {hint}")
    return SplitHalves(
        (tuple(s.id for s in halves[0]), tuple(s.id for s in halves[1])),
        (replace(obs, stations=tuple(halves[0])), replace(obs, stations=tuple(halves[1]))))


def calibrate_halves(cell: Any, observations: Any, options: Any = None, *, split: str = "interleaved",
                     seed: int = 0, min_views: int = MIN_VIEWS_PER_HALF) -> SplitHalves:
    """Split the stations (:func:`split_stations`) and calibrate each half with the same cell and options.

    Args:
        cell: the cell spec (path, dict or :class:`~jcalib.io.cell.CellSpec`).
        observations: path, dict or :class:`~jcalib.io.observations.Observations`.
        options: :class:`~jcalib.problems.options.CalibrationOptions` (or a dict of its fields), both halves.
        split, seed, min_views: as :func:`split_stations`.

    Returns:
        :class:`SplitHalves` with both results.

    Raises:
        BadInputError: as :func:`split_stations`, and malformed inputs.
        NotObservableError: a half cannot determine the unknowns.
    """
    from jcalib.io.cell import load_cell
    from jcalib.io.schema import check_cell_observations
    from jcalib.problems.api import calibrate

    cell_spec = load_cell(cell)
    obs = load_observations(observations)
    check_cell_observations(cell_spec, obs)
    halves = split_stations(obs, split=split, seed=seed, min_views=min_views)
    results = tuple(calibrate(cell_spec, half, options) for half in halves.observations)
    return replace(halves, results=results)
