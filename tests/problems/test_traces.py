"""Each residual type is traced once per problem shape (STYLE.md): a whole calibration, start
excepted, is one compiled solve per shape bucket.

The solve's Python body runs once per trace and never on a cached call, so counting the calls of
``jcalib.solve.core.lm_solve`` (looked up when ``_core`` is traced) counts compilations. Outlier
rounds, re-seeded views and variance-component re-solves change only arrays (weights, σ, start
values) and must reuse the first solve's compilation; a new data set whose counts fall in the same
buckets (:func:`jcalib.solve.bucket_size`) must too.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import jax
import numpy as np
import pytest

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.problems.batch import calibrate_batch
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.solve import bucket_size, core

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_traces", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
CAM = camera_from_opencv(np.array([[1000.0, 0, 650.0], [0, 1000.0, 470.0], [0, 0, 1]]),
                         np.array([-0.25, 0.08, 5e-4, -3e-4, 0.0]), (1280, 960))
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}


@pytest.fixture
def traces(monkeypatch):
    """The list that grows by one per trace of the compiled solve (JAX's caches emptied first)."""
    jax.clear_caches()
    calls = []
    original = core.lm_solve
    monkeypatch.setattr(core, "lm_solve", lambda *a, **k: calls.append(1) or original(*a, **k))
    return calls


def camera_obs(num_views, seed, outliers=0):
    """Observations of ``num_views`` board views (0.2 px noise), ``outliers`` corners 30 px off."""
    rng = np.random.default_rng(seed)
    stations = []
    for i, T in enumerate(random_calibration_views(CAM, BOARD.points, num_views, rng=rng)):
        pix, vis = project_target(CAM, T, BOARD.points)
        assert vis.all()
        pix = pix + 0.2 * rng.standard_normal(pix.shape)
        if i < outliers:
            pix[7] += 30.0
        stations.append({"id": f"v{i:03d}", "detections": [{"camera": "cam0", "target": "board",
                         "point_index": list(range(len(BOARD.points))), "pixels": pix.tolist()}]})
    return load_observations({"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
                              "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations})


def test_camera_calibrations_of_similar_size_compile_once(traces):
    """21 views with outliers (two outlier rounds, re-seed check), then 23 other views: one compilation.
    (20 views would be another bucket: 20 is a bucket boundary, 21-24 round up to 24.)"""
    assert bucket_size(21) == bucket_size(23) == 24 != bucket_size(20)
    cell = load_cell(CELL)
    first = calibrate_cell(cell, camera_obs(21, 1, outliers=3))
    assert len(first.outliers) == 3 and first.status == "converged"  # the rounds re-solved
    assert len(traces) == 1
    second = calibrate_cell(cell, camera_obs(23, 2))
    assert second.status == "converged" and len(second.station_ids) == 23
    assert len(traces) == 1


def test_variance_component_resolves_do_not_retrace(traces):
    """A hand-eye cell with the robot pose model: the pixels' variance component is re-estimated and
    the problem re-solved until stable, with the traces for the redundancies: one compilation, and a
    second data set of the same size reuses it."""
    cell, obs, _ = J.make_data(41, "flange", n=10, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    first = J.calibrate(cell, obs, sigma_px=0.5, prediction=False)  # stated 0.5 px for 0.2 px data: ~0.16 to find
    assert first.pose_model and 0.08 < first.variance_components["corner"] < 0.3
    count = len(traces)  # 1, or 0 when another test worker exported this structure already
    assert count <= 1
    cell, obs, _ = J.make_data(42, "flange", n=10, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    J.calibrate(cell, obs, sigma_px=0.5, prediction=False)
    assert len(traces) == count


def test_batch_compiles_once_for_members_of_different_sizes(traces):
    """calibrate_batch of 10-, 12- and 14-view data sets (buckets 10, 12, 14), one with outliers:
    every member padded to one shape, the first solve and the outlier round vmapped through one
    compiled function."""
    results = calibrate_batch(CELL, [camera_obs(10, 3), camera_obs(12, 4, outliers=2), camera_obs(14, 5)],
                              CalibrationOptions(), raise_errors=True)
    assert [len(r.station_ids) for r in results] == [10, 12, 14]
    assert len(results[1].outliers) == 2
    assert len(traces) == 1


def test_solver_settings_do_not_retrace(traces):
    """The iteration limit is an input of the compiled solve, not a constant of it: a calibration
    stopped after 2 iterations and one run to convergence share one compilation (also through the
    cross-process cache of traced solves, which the tests' JCALIB_CACHE_DIR turns on)."""
    cell = load_cell(CELL)
    obs = camera_obs(12, 6)
    full = calibrate_cell(cell, obs, CalibrationOptions(outlier_threshold=None))
    first = len(traces)  # 1, or 0 when another test worker exported this structure already
    short = calibrate_cell(cell, obs, CalibrationOptions(outlier_threshold=None, max_iterations=2))
    assert full.status == "converged" and full.iterations > 2
    assert short.status == "max_iterations" and short.iterations == 2
    assert first <= 1 and len(traces) == first
