"""Cells the report tests share, calibrated once per session: a camera, a weak hand-eye cell, a whole cell
(flange camera, fixed camera, board, tool) and a two-robot cell. Each case is ``(cell dict, observations
dict, jcalib.Result)``; the data and helpers are in ``cases.py``."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import jcalib
from jcalib.sim.cells import synthetic_cell, synthetic_two_robot_cell
from jcalib.sim.scene import random_calibration_views

_spec = importlib.util.spec_from_file_location("_report_cases", Path(__file__).with_name("cases.py"))
C = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(C)


@pytest.fixture(scope="session")
def cases():
    """The ``cases.py`` module (constants and helpers)."""
    return C


# Sizes are chosen so that one more station stays in the same shape bucket (jcalib.solve.bucket_size: 9 and
# 10 views -> 10, 11 and 12 -> 12, 22 and 24 stations -> 24): the re-solves of test_model.py reuse the
# compiled solve of the case.


@pytest.fixture(scope="session")
def camera_case():
    rng = np.random.default_rng(11)
    obs = C.camera_observations(random_calibration_views(C.CAMERA, C.BOARD.points, 9, rng=rng), rng)
    return C.CAMERA_CELL, obs, jcalib.calibrate(C.CAMERA_CELL, obs, C.STATED)


@pytest.fixture(scope="session")
def handeye_case():
    cell, obs = C.weak_handeye(n=11)
    return cell, obs, jcalib.calibrate(cell, obs, C.STATED)


@pytest.fixture(scope="session")
def cell_case():
    cell, obs, _ = synthetic_cell(3, num_board_stations=11, num_tool_stations=11)
    return cell, obs, jcalib.calibrate(cell, obs, C.STATED_TIPS)


@pytest.fixture(scope="session")
def two_robot_case():
    """Default options: a-posteriori noise with variance components (corners, tips) and two pose models.
    The generator's default sizes: the shape of the golden case ``cell_two_robots`` (tests/golden), so the
    two share one compiled solve (no re-solve here adds a station)."""
    cell, obs, _ = synthetic_two_robot_cell(1)
    return cell, obs, jcalib.calibrate(cell, obs)
