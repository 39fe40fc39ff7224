"""Batched hand-eye calibration (``calibrate_hand_eye_batch``, vmapped solves): a member padded to a
larger batch shape (fewer stations, dropped corners, a gross outlier) gives what
``calibrate_hand_eye`` gives on it alone, the other member recovers the simulated truth, and a
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
from jcalib.problems import handeye
from jcalib.problems.handeye import (
    HandEyeOptions,
    calibrate_hand_eye,
    calibrate_hand_eye_batch,
)

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_batch", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)

ROBOT = {"sigma_px": 0.2, "robot_m": 1e-4, "robot_deg": 0.01}
OPTIONS = HandEyeOptions(sigma_px=0.2)  # pose model from the cell; a-posteriori noise: covariance re-solve


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
    """One batch call, counting the vmapped calls (main solves; covariance systems)."""
    cell, obs, _ = data
    calls = []
    mp = pytest.MonkeyPatch()
    for name in ("_batch_core_jit", "_system_core_jit"):
        fn = getattr(handeye, name)
        mp.setattr(handeye, name, lambda *a, _fn=fn, _name=name: calls.append(_name) or _fn(*a))
    try:
        out = calibrate_hand_eye_batch(cell, obs, OPTIONS, raise_errors=False)
    finally:
        mp.undo()
    return out, calls


def test_padded_member_equals_the_single_solve(data, batch):
    """Member B, padded to A's shape, against ``calibrate_hand_eye`` on B alone (its own bucket).
    Both solves stop when a step predicts a cost decrease below ftol = 1e-14 relative: the estimates
    then agree to ~sqrt(2·ftol·cost) ≈ 1e-5 of their σ (cost ~ 400), hence 1e-4 σ; covariances are
    smooth in the estimate, 1e-6 relative."""
    cell, obs, _ = data
    (_, b, _), _ = batch
    s = calibrate_hand_eye(cell, obs[1], OPTIONS)
    assert b.pose_model and s.pose_model
    assert b.outliers == s.outliers and len(s.outliers) == 1  # the gross corner, found in both
    assert b.station_ids == s.station_ids and b.status == s.status == "converged"
    sigma = np.sqrt(np.diag(s.T_hand_eye_covariance))
    assert np.all(np.abs(_tangent(s.T_hand_eye, b.T_hand_eye)) <= 1e-4 * sigma)
    sigma_tg = np.sqrt(np.diag(s.T_target_covariance))
    assert np.all(np.abs(_tangent(s.T_target, b.T_target)) <= 1e-4 * sigma_tg)
    sigma_k = np.sqrt(np.diag(s.intrinsics_covariance))
    assert np.all(np.abs(np.asarray(b.model.params) - np.asarray(s.model.params)) <= 1e-4 * sigma_k)
    for Cb, Cs in ((b.T_hand_eye_covariance, s.T_hand_eye_covariance), (b.T_target_covariance, s.T_target_covariance),
                   (b.intrinsics_covariance, s.intrinsics_covariance)):
        np.testing.assert_allclose(Cb, Cs, rtol=1e-6, atol=1e-6 * np.max(np.abs(Cs)))
    np.testing.assert_allclose(b.sigma_px, s.sigma_px, rtol=1e-6)
    np.testing.assert_allclose(b.rms_px, s.rms_px, rtol=1e-6)
    for key in ("a_posteriori_sigma_translation_m", "correction_rms_translation_m", "redundancy"):
        np.testing.assert_allclose(b.robot[key], s.robot[key], rtol=1e-6)
    assert b.T_hand_eye.dtype == np.float64


def test_largest_member_recovers_the_truth(data, batch):
    """Member A against the simulated truth: the tangent error within 5 reported σ per component."""
    _, _, (truth_a, _) = data
    (a, _, _), _ = batch
    err = _tangent(truth_a["T_hand_eye"], a.T_hand_eye)
    assert np.all(np.abs(err) <= 5.0 * np.sqrt(np.diag(a.T_hand_eye_covariance))), err


def test_one_vmapped_call_per_stage(batch):
    """Members of different sizes share one main-solve call and one covariance-system call."""
    _, calls = batch
    assert calls == ["_batch_core_jit", "_system_core_jit"]


def test_degenerate_member_error_in_place(data, batch):
    """The two-station member: the exception ``calibrate_hand_eye`` raises, returned in its place;
    with ``raise_errors=True`` the batch raises it."""
    cell, obs, _ = data
    (_, _, c), _ = batch
    with pytest.raises(NotObservableError) as single:
        calibrate_hand_eye(cell, obs[2], OPTIONS)
    assert isinstance(c, NotObservableError)
    assert str(c) == str(single.value) and c.unknowns == single.value.unknowns
    with pytest.raises(NotObservableError, match="2 station"):
        calibrate_hand_eye_batch(cell, [obs[2], obs[0]], OPTIONS)


def test_empty_batch_is_bad_input(data):
    cell, _, _ = data
    with pytest.raises(BadInputError, match="^observations: got an empty list"):
        calibrate_hand_eye_batch(cell, [], OPTIONS)
