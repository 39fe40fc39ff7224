"""Cross-validation in the report: the split-half comparison of :mod:`jcalib.report.compare`, plus the
difference of every transform between the halves.

The two halves of the stations (even / odd) are calibrated separately by the one calibration path
(:func:`jcalib.problems.crossval.calibrate_halves`) and each estimated camera's projections are compared
with :func:`jcalib.report.compare.compare_cameras`: the difference after the rotation that best aligns
the two camera frames, against the difference their covariances predict (χ² per point and over the
image, a verdict). Much larger than predicted means the σ are too small (model error, a camera that
changed); comparable means they are honest. Transforms are compared by their rotation and translation
differences against the halves' summed covariances.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from jcalib.report.compare import Comparison, compare_cameras

__all__ = ["CrossValidation", "cross_validate"]


@dataclass
class CrossValidation:
    """Two calibrations on the two halves of the stations, compared.

    Attributes:
        stations: ``(ids of half A, ids of half B)``.
        comparisons: camera id -> :class:`~jcalib.report.compare.Comparison` (A: the first half).
        maps: camera id -> ``(u, v, diff, expected)``: grid pixels ``(ny, nx)``, the length of the
            projection difference (px) and its predicted 1σ in its worst direction (px); NaN where
            the grid point was not compared (outside either model's valid region).
        transforms: transform name -> ``{"rotation_deg", "translation_mm"}``: difference between the
            halves, and ``{"rotation_sigma_deg", "translation_sigma_mm"}``: its expected 1σ (totals).
        results: the two half results (:class:`jcalib.Result`).
    """

    stations: tuple[list[str], list[str]]
    comparisons: dict[str, Comparison]
    maps: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    transforms: dict[str, dict[str, float]]
    results: tuple[Any, Any]


def _maps(c: Comparison) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    nx, ny = c.grid
    w, h = c.image_size
    u, v = np.meshgrid(np.linspace(0.0, w - 1.0, nx), np.linspace(0.0, h - 1.0, ny))
    diff, expected = np.full((ny, nx), np.nan), np.full((ny, nx), np.nan)
    ix, iy = c.grid_index[:, 0], c.grid_index[:, 1]
    diff[iy, ix] = np.linalg.norm(c.diff_px, axis=1)
    expected[iy, ix] = c.sigma_px
    return u, v, diff, expected


def cross_validate(cell: Any, observations: Any, options: Any = None, grid: tuple[int, int] = (33, 25)
                   ) -> CrossValidation:
    """Calibrate on the even and the odd stations separately and compare.

    Args:
        cell: the cell spec (path, dict or ``CellSpec``).
        observations: the observations (path, dict or ``Observations``).
        options: calibration options for both halves (``CalibrationOptions`` or a dict of its fields).
        grid: ``(nx, ny)`` pixels of the comparison.

    Raises:
        BadInputError: a half with too few views of a camera (:func:`jcalib.problems.crossval.split_stations`).
        NotObservableError: a half cannot determine the unknowns (propagated from the solver).
    """
    from jcalib.geometry.conversions import matrix_to_rvec
    from jcalib.problems.crossval import calibrate_halves

    halves = calibrate_halves(cell, observations, options)
    fa, fb = (r.file for r in halves.results)
    comparisons = {}
    for name, ca in fa.cameras.items():
        cb = fb.cameras.get(name)
        if cb is None or ca.covariance is None or cb.covariance is None or not np.any(np.diag(ca.covariance) > 0.0):
            continue  # intrinsics held: nothing to compare
        comparisons[name] = compare_cameras(ca, cb, grid=grid, camera=name)
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
    return CrossValidation((list(halves.stations[0]), list(halves.stations[1])), comparisons,
                           {n: _maps(c) for n, c in comparisons.items()}, transforms, halves.results)
