"""Whole-cell problem: exact recovery from noiseless data (flange + fixed camera, fixed board, a tool
seen by the fixed camera), routing from ``jcalib.calibrate`` to result.json, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

import jcalib
from jcalib.errors import BadInputError
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.io.result import load_result
from jcalib.problems.cell import CellOptions, calibrate_cell, synthetic_cell

SIZES = dict(num_board_stations=10, num_tool_stations=20)  # one problem shape: one compilation


@pytest.fixture(scope="module")
def noiseless():
    cell, obs, truth = synthetic_cell(0, sigma_px=0.0, tip_sigma_px=0.0, robot_m=1e-9, robot_deg=1e-7, **SIZES)
    cal = calibrate_cell(load_cell(cell), load_observations(obs), CellOptions(noise="stated"))
    return cell, obs, truth, cal


def test_noiseless_recovery_against_ground_truth(noiseless):
    _, _, truth, cal = noiseless
    assert cal.status == "converged"
    for name in ("T_flange_cam0", "T_base_cam1", "T_base_board", "T_flange_needle"):
        # 1e-6 m / 1e-6 (rotation entries): parameter recovery from noiseless data
        np.testing.assert_allclose(cal.transforms[name], truth[name], atol=1e-6, err_msg=name)
        assert cal.transforms[name].dtype == np.float64
    # intrinsics: 1e-4 px (fx ~ 1400 px; relative 1e-7), distortion 1e-6
    np.testing.assert_allclose(np.asarray(cal.cameras["cam0"].params), truth["cam0"], atol=1e-4)
    assert cal.start_method["T_flange_needle"] == "tip_rays"
    assert cal.start_method["T_flange_cam0"].startswith("hand_eye")
    # the TCP's rotation is not observable from a tip: held, zero covariance
    assert np.all(cal.transform_covariance["T_flange_needle"][:3, :3] == 0.0)


def test_calibrate_routes_mixed_cell_and_writes_result(tmp_path):
    cell, obs, truth = synthetic_cell(1, **SIZES)
    result = jcalib.calibrate(cell, obs, CellOptions(sigma_px=0.2, tip_sigma_px=0.2))
    path = result.to_json(tmp_path / "result.json")
    back = load_result(path)
    assert set(back.transforms) == {"T_flange_cam0", "T_base_cam1", "T_base_board", "T_flange_needle"}
    assert back.stats["problem"] == "cell"
    # errors against the ground truth within 5 σ of the reported covariance (a loose sanity bound:
    # the Monte-Carlo χ² check of the covariance is in benchmarks/bench_cell.py)
    t_err = back.transforms["T_flange_needle"].matrix[:3, 3] - truth["T_flange_needle"][:3, 3]
    cov = result.covariance("T_flange_needle")[3:, 3:]
    assert float(t_err @ np.linalg.solve(cov, t_err)) < 25.0
    jc = back.extra["joint_covariance"]
    M = np.asarray(jc["matrix"])
    np.testing.assert_allclose(M, M.T, atol=1e-15)
    # the joint covariance's diagonal blocks are the per-unknown covariances (1e-9 relative: same numbers)
    o = int(np.sum(jc["dims"][: jc["names"].index("T_base_cam1")]))
    np.testing.assert_allclose(M[o:o + 6, o:o + 6], result.covariance("T_base_cam1"), rtol=1e-9, atol=1e-20)


def test_static_camera_without_intrinsics_is_refused():
    cell, obs, _ = synthetic_cell(2, **SIZES)
    cell = json.loads(json.dumps(cell))
    del cell["cameras"]["cam1"]["intrinsics"]
    cell["cameras"]["cam1"]["fix"] = []
    with pytest.raises(BadInputError, match="cam1"):
        calibrate_cell(load_cell(cell), load_observations(obs))
