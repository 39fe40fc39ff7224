"""Batched hand-eye calibration (``jcalib.calibrate_batch``, vmapped solves): a member padded to a
larger batch shape (fewer stations, dropped corners, a gross outlier) gives what
``calibrate_cell`` gives on it alone, the other member recovers the simulated truth, and a
degenerate member's error comes back in its place (or is raised)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError, NotObservableError
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.problems.batch import calibrate_batch
from jcalib.solve import core

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_batch", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)

ROBOT = {"sigma_px": 0.2, "robot_m": 1e-4, "robot_deg": 0.01}
OPTIONS = CalibrationOptions(sigma_px=0.2, prediction=False)  # pose model from the cell (as calibrate_batch);
# a-posteriori noise: variance components


def _tangent(T_a, T_b):
    """(rx, ry, rz, tx, ty, tz) of ``T_a⁻¹ T_b`` (rad, m), first order: fine for differences ≪ 1."""
    d = np.linalg.inv(T_a) @ T_b
    return np.concatenate([Rotation.from_matrix(d[:3, :3]).as_rotvec(), d[:3, 3]])


@pytest.fixture(scope="module")
def data():
    # A: 10 stations, every corner (the batch's largest shape)
    cell, obs_a, truth_a = J.make_data(31, n=10, **ROBOT)
    # B: 7 stations (a smaller bucket), 12 corners dropped in 3 views, one gross outlier corner
    _, obs_b, truth_b = J.make_data(32, n=7, **ROBOT)
    for s in obs_b["stations"][:3]:
        det = s["detections"][0]
        det["point_index"], det["pixels"] = det["point_index"][12:], det["pixels"][12:]
    obs_b["stations"][4]["detections"][0]["pixels"][5][0] += 25.0
    # C: two stations: not observable (a host-side error, before any solve)
    _, obs_c, _ = J.make_data(33, n=10, **ROBOT)
    obs_c["stations"] = obs_c["stations"][:2]
    cell = load_cell(cell)
    return cell, [load_observations(o) for o in (obs_a, obs_b, obs_c)], (truth_a, truth_b)


@pytest.fixture(scope="module")
def batch(data):
    """One batch call, recording every compiled solve call: (single or vmapped, batch width)."""
    cell, obs, _ = data
    calls = []
    mp = pytest.MonkeyPatch()
    for name in ("_core_jit", "_core_vmap_jit"):
        fn = getattr(core, name)
        mp.setattr(core, name, lambda problem, *a, _fn=fn, _name=name: calls.append(
            (_name, int(problem.variables[0].value.shape[0]) if _name == "_core_vmap_jit" else 1))
            or _fn(problem, *a))
    try:
        out = calibrate_batch(cell, obs, OPTIONS, raise_errors=False)
    finally:
        mp.undo()
    return out, calls


def test_padded_member_equals_the_single_solve(data, batch):
    """Member B, padded to A's shape, against ``calibrate_cell`` on B alone (its own bucket).
    Both solves stop when a step predicts a cost decrease below ftol = 1e-14 relative: the estimates
    then agree to ~sqrt(2·ftol·cost) ≈ 1e-5 of their σ (cost ~ 400), hence 1e-4 σ; covariances are
    smooth in the estimate, 1e-6 relative."""
    cell, obs, _ = data
    (_, b, _), _ = batch
    s = calibrate_cell(cell, obs[1], OPTIONS)
    assert b.pose_model and s.pose_model
    assert b.outliers == s.outliers and len(s.outliers) == 1  # the gross corner, found in both
    assert b.station_ids == s.station_ids and b.status == s.status == "converged"
    assert b.variance_components.keys() == s.variance_components.keys()
    for name in ("T_flange_cam0", "T_base_board"):
        sigma = np.sqrt(np.diag(s.transform_covariance[name]))
        assert np.all(np.abs(_tangent(s.transforms[name], b.transforms[name])) <= 1e-4 * sigma), name
    sigma_k = np.sqrt(np.diag(s.intrinsics_covariance["cam0"]))
    assert np.all(np.abs(np.asarray(b.cameras["cam0"].params) - np.asarray(s.cameras["cam0"].params)) <= 1e-4 * sigma_k)
    for Cb, Cs in ((b.transform_covariance["T_flange_cam0"], s.transform_covariance["T_flange_cam0"]),
                   (b.transform_covariance["T_base_board"], s.transform_covariance["T_base_board"]),
                   (b.intrinsics_covariance["cam0"], s.intrinsics_covariance["cam0"])):
        np.testing.assert_allclose(Cb, Cs, rtol=1e-6, atol=1e-6 * np.max(np.abs(Cs)))
    np.testing.assert_allclose(b.sigma_px, s.sigma_px, rtol=1e-6)
    np.testing.assert_allclose(b.rms_px, s.rms_px, rtol=1e-6)
    for key in ("a_posteriori_sigma_translation_m", "correction_rms_translation_m", "redundancy"):
        np.testing.assert_allclose(b.robot["robot"][key], s.robot["robot"][key], rtol=1e-6)
    assert b.transforms["T_flange_cam0"].dtype == np.float64


def test_largest_member_recovers_the_truth(data, batch):
    """Member A against the simulated truth: the tangent error within 5 reported σ per component."""
    _, _, (truth_a, _) = data
    (a, _, _), _ = batch
    err = _tangent(truth_a["T_hand_eye"], a.transforms["T_flange_cam0"])
    assert np.all(np.abs(err) <= 5.0 * np.sqrt(np.diag(a.transform_covariance["T_flange_cam0"]))), err


def test_members_are_solved_in_vmapped_calls(batch):
    """Members of different sizes share one vmapped call for the first solve; every later round
    (outliers, variance components) is vmapped too: no member is ever solved on its own."""
    _, calls = batch
    assert calls and all(name == "_core_vmap_jit" for name, _ in calls), calls
    assert calls[0] == ("_core_vmap_jit", 2)  # A and B together (C failed before any solve)


def test_degenerate_member_error_in_place(data, batch):
    """The two-station member: the exception ``calibrate_cell`` raises, returned in its place;
    with ``raise_errors=True`` the batch raises it."""
    cell, obs, _ = data
    (_, _, c), _ = batch
    with pytest.raises(NotObservableError) as single:
        calibrate_cell(cell, obs[2], OPTIONS)
    assert isinstance(c, NotObservableError)
    assert str(c) == str(single.value) and c.unknowns == single.value.unknowns
    with pytest.raises(NotObservableError, match="2 station"):
        calibrate_batch(cell, [obs[2], obs[0]], OPTIONS, raise_errors=True)


def test_empty_or_mismatched_batch_is_bad_input(data):
    cell, obs, _ = data
    with pytest.raises(BadInputError, match="^observations: got an empty list"):
        calibrate_batch(cell, [], OPTIONS)
    with pytest.raises(BadInputError, match="cells: got 2 cell specs for 3 observations"):
        calibrate_batch([cell, cell], obs, OPTIONS)
