"""Cross-validation: calibrate the two halves of the stations separately and compare (mrcal-style).

The difference in projection across the image (and between the halves' transforms) is evidence
beyond the reprojection error: much larger than the halves' σ predict, the reported σ are too small
(model error, unmodelled effects); comparable, they are honest. Both halves are solved by the one
calibration path (:func:`jcalib.problems.api.calibrate`), any cell.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.report.taskspace import projection_difference, projection_sigma_map

__all__ = ["CrossValidation", "cross_validate"]


@dataclass
class CrossValidation:
    """Two calibrations on the two halves of the stations (even / odd), compared.

    Attributes:
        stations: ``(ids of half A, ids of half B)``.
        maps: camera id -> ``(u, v, diff, expected)``: grid pixels ``(ny, nx)``, the distance between
            the two halves' projections of the same ray (px, after the best-fit common rotation), and
            the expected distance from their reported covariances (``sqrt(σ_A² + σ_B²)``, worst
            direction each, px).
        transforms: transform name -> ``{"rotation_deg", "translation_mm"}``: difference between the
            halves, and ``{"rotation_sigma_deg", "translation_sigma_mm"}``: its expected 1σ (totals).
        results: the two half results (:class:`jcalib.Result`).
    """

    stations: tuple[list[str], list[str]]
    maps: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    transforms: dict[str, dict[str, float]]
    results: tuple[Any, Any]


def cross_validate(cell: Any, observations: Any, options: Any = None, grid: tuple[int, int] = (33, 25)
                   ) -> CrossValidation:
    """Calibrate on the even and the odd stations separately and compare.

    Args:
        cell: the cell spec (path, dict or ``CellSpec``).
        observations: the observations (path, dict or ``Observations``).
        options: calibration options for both halves (``CalibrationOptions`` or a dict of its fields).
        grid: ``(nx, ny)`` pixels of the maps.

    Raises:
        BadInputError: fewer than 4 stations.
        NotObservableError: a half cannot determine the unknowns (propagated from the solver).
    """
    from jcalib.geometry.conversions import matrix_to_rvec
    from jcalib.io.observations import load_observations
    from jcalib.problems.api import calibrate

    obs = load_observations(observations)
    stations = [s for s in obs.stations if s.detections or s.contacts or s.poses]
    if len(stations) < 4:
        raise BadInputError(
            f"observations: got {len(stations)} stations with observations, cross-validation needs at least 4")
    halves = (stations[0::2], stations[1::2])
    results = [calibrate(cell, replace(obs, stations=tuple(half)), options) for half in halves]
    fa, fb = results[0].file, results[1].file
    maps = {}
    for name, ca in fa.cameras.items():
        cb = fb.cameras.get(name)
        if cb is None or ca.covariance is None or not np.any(np.diag(ca.covariance) > 0.0):
            continue  # intrinsics held: nothing to compare
        u, v, diff = projection_difference(ca, cb, grid)
        sa = projection_sigma_map(ca, grid)[2]
        sb = projection_sigma_map(cb, grid)[2] if cb.covariance is not None else np.full_like(diff, np.nan)
        maps[name] = (u, v, diff, np.sqrt(sa**2 + sb**2))
    transforms = {}
    for name, ta in fa.transforms.items():
        tb = fb.transforms.get(name)
        if tb is None:
            continue
        D = np.linalg.inv(ta.matrix) @ tb.matrix
        entry = {"rotation_deg": float(np.degrees(np.linalg.norm(matrix_to_rvec(D[:3, :3])))),
                 "translation_mm": float(1e3 * np.linalg.norm(ta.matrix[:3, 3] - tb.matrix[:3, 3]))}
        if ta.covariance is not None and tb.covariance is not None:
            C = np.asarray(ta.covariance) + np.asarray(tb.covariance)
            entry["rotation_sigma_deg"] = float(np.degrees(np.sqrt(np.trace(C[:3, :3]))))
            entry["translation_sigma_mm"] = float(1e3 * np.sqrt(np.trace(C[3:, 3:])))
        transforms[name] = entry
    return CrossValidation(([s.id for s in halves[0]], [s.id for s in halves[1]]), maps, transforms,
                           (results[0], results[1]))
