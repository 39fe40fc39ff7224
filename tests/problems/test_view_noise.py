"""Noise per view and the mean corners of a static scene (:mod:`jcalib.problems.refine`, rounds 3-4).

The synthetic demo cell (flange camera, fixed camera, board on the table, needle) with the
corners of four of the flange camera's views made twice as noisy as the others: the per-view noise
factors find those four, and the fixed camera's repeated views of the fixed board are one
``corner_mean`` kind with its own variance factor.
"""

from __future__ import annotations

import numpy as np

import jcalib
from jcalib.sim.cells import synthetic_cell

SIZES = dict(num_board_stations=10, num_tool_stations=20)  # the shape of tests/problems/test_cell.py
NOISY = 4  # the first board stations, whose cam0 corners get σ 0.4 px instead of 0.2 px


def _noisier(obs: dict, seed: int) -> tuple[dict, set[str]]:
    rng = np.random.default_rng(seed)
    noisy = set()
    for station in obs["stations"]:
        for det in station["detections"]:
            if det.get("camera") == "cam0" and det.get("target") == "board" and len(noisy) < NOISY:
                pix = np.asarray(det["pixels"], np.float64)
                det["pixels"] = (pix + 0.2 * np.sqrt(3.0) * rng.standard_normal(pix.shape)).tolist()
                noisy.add(station["id"])
    return obs, noisy


def test_noisier_views_get_larger_noise_factors():
    cell, obs, _ = synthetic_cell(4, sigma_px=0.2, **SIZES)
    obs, noisy = _noisier(obs, 5)
    assert len(noisy) == NOISY
    stats = jcalib.calibrate(cell, obs).file.stats
    factors = stats["view_noise_factor"]
    loud = [f for k, f in factors.items() if k.split("/")[0] == "cam0" and k.split("/")[1] in noisy]
    quiet = [f for k, f in factors.items() if k.split("/")[0] == "cam0" and k.split("/")[1] not in noisy]
    assert len(loud) == NOISY and len(quiet) == SIZES["num_board_stations"] - NOISY
    # variance ratio 4, shrunk towards 1 by 20 pseudo-degrees of freedom against ~100 of each view's own
    ratio = np.mean(loud) / np.mean(quiet)
    assert 2.3 < ratio < 5.0, (loud, quiet)
    assert min(loud) > max(quiet), (loud, quiet)
    # redundancy-weighted mean 1 over the kind's views
    assert 0.5 < np.mean(quiet) < 1.0 < np.mean(loud)


def test_static_scene_mean_corners_are_their_own_kind():
    cell, obs, _ = synthetic_cell(6, sigma_px=0.2, **SIZES)
    stats = jcalib.calibrate(cell, obs).file.stats
    components = stats["variance_components"]
    assert "corner_mean" in components and "corner" in components
    # ten images of the same corners averaged: the mean's variance is about 1/10 of one image's
    assert 0.03 < components["corner_mean"] / components["corner"] < 0.3, components
    # the fixed camera's averaged view is not a view of its own in the per-view factors
    assert not [k for k in stats["view_noise_factor"] if k.startswith("cam1/")]
