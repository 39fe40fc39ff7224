"""Hand-eye options: robust loss and outlier rejection against injected gross corner outliers, and
the ``pose_model`` switch through ``jcalib.calibrate``."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

import jcalib
from jcalib.errors import BadInputError
from jcalib.io.cell import load_cell
from jcalib.io.observations import load_observations
from jcalib.problems import CalibrationOptions, calibrate_cell

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_options", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)


def _inject(obs, rng, num):
    """Move ``num`` random corners by 15-40 px in a random direction; returns their (station, index)."""
    out = json.loads(json.dumps(obs))
    where = [(s, k) for s in range(len(out["stations"])) for k in range(len(out["stations"][s]["detections"][0]["point_index"]))]
    picked = rng.choice(len(where), num, replace=False)
    bad = set()
    for p in picked:
        s, k = where[p]
        det = out["stations"][s]["detections"][0]
        ang = rng.uniform(0, 2 * np.pi)
        det["pixels"][k] = (np.asarray(det["pixels"][k]) + rng.uniform(15, 40) * np.array([np.cos(ang), np.sin(ang)])).tolist()
        bad.add((out["stations"][s]["id"], det["point_index"][k]))
    return out, bad


def _rot_trans_errors(T_est, T_ref):
    d = np.linalg.solve(T_ref, T_est)
    return np.linalg.norm(np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]]) / 2), np.linalg.norm(d[:3, 3])


@pytest.mark.parametrize("loss", ["huber", "none"])
def test_gross_outliers_are_flagged_and_do_not_move_the_estimate(loss):
    """25 corners (of ~800) moved by 15-40 px: all are flagged, at most 1 inlier is, the estimate
    is within 5 reported σ of the truth and within 1 reported σ (rotation and translation norms, against the largest axis σ
    times sqrt(3)) of the estimate from the clean data (the reference: same data without outliers)."""
    cell, obs, truth = J.make_data(21, "flange", sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    cell = load_cell(J.with_known_intrinsics(cell))
    opts = CalibrationOptions(sigma_px=0.2, loss=loss)
    clean = calibrate_cell(cell, load_observations(obs), opts)
    assert clean.outliers == []
    dirty, bad = _inject(obs, np.random.default_rng(5), 25)
    cal = calibrate_cell(cell, load_observations(dirty), opts)
    flagged = {(s, i) for c, s, i in cal.outliers}
    assert all(c == "cam0" for c, _, _ in cal.outliers)
    assert bad <= flagged, bad - flagged
    assert len(flagged - bad) <= 1
    X = "T_flange_cam0"
    sd = np.sqrt(np.diag(clean.transform_covariance[X]))
    d_rot, d_t = _rot_trans_errors(cal.transforms[X], clean.transforms[X])
    assert d_rot < np.sqrt(3) * sd[:3].max() and d_t < np.sqrt(3) * sd[3:].max(), (d_rot, d_t, sd)
    d_rot, d_t = _rot_trans_errors(cal.transforms[X], truth["T_hand_eye"])  # and near the truth (5 σ)
    assert d_rot < 5 * np.sqrt(3) * sd[:3].max() and d_t < 5 * np.sqrt(3) * sd[3:].max(), (d_rot, d_t, sd)
    assert 0.15 < cal.sigma_px < 0.3  # the outliers no longer inflate the noise estimate


def test_without_rejection_outliers_pull_the_estimate():
    """The same outliers with plain least squares and no rejection: nothing flagged and σ̂ inflated
    (so the rejection above is what removes them)."""
    cell, obs, _ = J.make_data(21, "flange", sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    dirty, _ = _inject(obs, np.random.default_rng(5), 25)
    cal = calibrate_cell(load_cell(J.with_known_intrinsics(cell)), load_observations(dirty),
                         CalibrationOptions(sigma_px=0.2, outlier_threshold=None))
    assert cal.outliers == [] and cal.sigma_px > 1.0


def test_pose_model_switch_overrides_the_cell():
    """``CalibrationOptions(pose_model=False)`` on a cell with robot.pose_noise gives the same estimate as
    the cell without pose_noise (to 1e-12: the same problem), through jcalib.calibrate."""
    cell, obs, _ = J.make_data(22, "base", sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    off = jcalib.calibrate(cell, obs, CalibrationOptions(sigma_px=0.2, pose_model=False))
    plain = {k: v for k, v in cell.items() if k != "robot"} | {"robot": {"error_model": "exact"}}
    ref = jcalib.calibrate(plain, obs, CalibrationOptions(sigma_px=0.2))
    on = jcalib.calibrate(cell, obs, CalibrationOptions(sigma_px=0.2, prediction=False))  # the cell's pose_noise
    assert off.file.stats["robot_pose_model"] is False and "robot" not in off.file.stats
    assert on.file.stats["robot_pose_model"] is True and "robot" in on.file.stats
    np.testing.assert_allclose(np.asarray(off.file.transforms["T_base_cam0"].matrix),
                               np.asarray(ref.file.transforms["T_base_cam0"].matrix), atol=1e-12)
    assert not np.allclose(np.asarray(on.file.transforms["T_base_cam0"].matrix),
                           np.asarray(off.file.transforms["T_base_cam0"].matrix), atol=1e-9)
    with pytest.raises(BadInputError, match="--pose-model has no effect here.*pose_noise"):
        jcalib.calibrate(plain, obs, CalibrationOptions(pose_model=True))


@pytest.mark.parametrize(("changes", "needle"), [
    ({"loss": "l1"}, "loss: got 'l1'"),
    ({"outlier_threshold": 0.0}, "outlier_threshold"),
    ({"unobservable_prior_sigma_m": 0.0}, "unobservable_prior_sigma_m"),
    ({"sigma_px": -0.2}, "sigma_px: got -0.2"),
    ({"tip_sigma_px": float("nan")}, "tip_sigma_px"),
    ({"contact_sigma_m": float("inf")}, "contact_sigma_m"),
    ({"noise": "guess"}, "noise: got 'guess'"),
    ({"pose_model": "yes"}, "pose_model"),
    ({"method": "magic"}, "method: got 'magic'"),
    ({"max_iterations": 0}, "max_iterations"),
    ({"max_iterations": True}, "max_iterations"),
    ({"unobservable_prior_m": float("nan")}, "unobservable_prior_m"),
    ({"sigma_pix": 0.2}, r"unknown name\(s\) \['sigma_pix'\]"),
])
def test_bad_options_name_the_argument(changes, needle):
    with pytest.raises(BadInputError, match=needle):
        CalibrationOptions().replace(**changes)
    if "sigma_pix" not in changes:
        with pytest.raises(BadInputError, match=needle):
            CalibrationOptions(**changes)


def test_camera_options_reach_the_hand_eye_cell():
    """One options type for every cell: the robust loss and threshold a user sets for cameras are
    honoured by the hand-eye cell (the injected outliers are flagged) rather than refused."""
    opts = CalibrationOptions(loss="cauchy", loss_scale=2.0, sigma_px=0.2, outlier_threshold=4.0)
    cell, obs, _ = J.make_data(23, "flange", sigma_px=0.2)
    dirty, bad = _inject(obs, np.random.default_rng(6), 10)
    result = jcalib.calibrate(J.with_known_intrinsics(cell), dirty, opts)
    flagged = {(o["station"], o["point_index"]) for o in result.file.stats["outliers"]}
    assert bad <= flagged and result.file.stats["num_outliers"] == len(flagged)
    assert result.file.provenance.options["loss"] == "cauchy"
    assert result.file.provenance.options["loss_scale"] == 2.0
