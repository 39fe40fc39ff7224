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
from jcalib.problems.handeye import HandEyeOptions, calibrate_hand_eye

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
    opts = HandEyeOptions(sigma_px=0.2, loss=loss)
    clean = calibrate_hand_eye(cell, load_observations(obs), opts)
    assert clean.outliers == []
    dirty, bad = _inject(obs, np.random.default_rng(5), 25)
    cal = calibrate_hand_eye(cell, load_observations(dirty), opts)
    flagged = {(s, i) for c, s, i in cal.outliers}
    assert all(c == "cam0" for c, _, _ in cal.outliers)
    assert bad <= flagged, bad - flagged
    assert len(flagged - bad) <= 1
    sd = np.sqrt(np.diag(clean.T_hand_eye_covariance))
    d_rot, d_t = _rot_trans_errors(cal.T_hand_eye, clean.T_hand_eye)
    assert d_rot < np.sqrt(3) * sd[:3].max() and d_t < np.sqrt(3) * sd[3:].max(), (d_rot, d_t, sd)
    d_rot, d_t = _rot_trans_errors(cal.T_hand_eye, truth["T_hand_eye"])  # and near the truth (5 σ)
    assert d_rot < 5 * np.sqrt(3) * sd[:3].max() and d_t < 5 * np.sqrt(3) * sd[3:].max(), (d_rot, d_t, sd)
    assert 0.15 < cal.sigma_px < 0.3  # the outliers no longer inflate the noise estimate


def test_without_rejection_outliers_pull_the_estimate():
    """The same outliers with plain least squares and no rejection: nothing flagged and σ̂ inflated
    (so the rejection above is what removes them)."""
    cell, obs, _ = J.make_data(21, "flange", sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    dirty, _ = _inject(obs, np.random.default_rng(5), 25)
    cal = calibrate_hand_eye(load_cell(J.with_known_intrinsics(cell)), load_observations(dirty),
                             HandEyeOptions(sigma_px=0.2, outlier_threshold=None))
    assert cal.outliers == [] and cal.sigma_px > 1.0


def test_pose_model_switch_overrides_the_cell():
    """``HandEyeOptions(pose_model=False)`` on a cell with robot.pose_noise gives the same estimate as
    the cell without pose_noise (to 1e-12: the same problem), through jcalib.calibrate."""
    cell, obs, _ = J.make_data(22, "base", sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    off = jcalib.calibrate(cell, obs, HandEyeOptions(sigma_px=0.2, pose_model=False))
    plain = {k: v for k, v in cell.items() if k != "robot"}
    ref = jcalib.calibrate(plain, obs, HandEyeOptions(sigma_px=0.2))
    on = jcalib.calibrate(cell, obs, HandEyeOptions(sigma_px=0.2))
    assert off.file.stats["robot_pose_model"] is False and "robot" not in off.file.stats
    assert on.file.stats["robot_pose_model"] is True and "robot" in on.file.stats
    np.testing.assert_allclose(np.asarray(off.file.transforms["T_base_cam0"].matrix),
                               np.asarray(ref.file.transforms["T_base_cam0"].matrix), atol=1e-12)
    assert not np.allclose(np.asarray(on.file.transforms["T_base_cam0"].matrix),
                           np.asarray(off.file.transforms["T_base_cam0"].matrix), atol=1e-9)
    with pytest.raises(BadInputError, match="pose_model"):
        jcalib.calibrate(plain, obs, HandEyeOptions(pose_model=True))


def test_bad_options_name_the_argument():
    with pytest.raises(BadInputError, match="loss: got 'l1'"):
        HandEyeOptions(loss="l1")
    with pytest.raises(BadInputError, match="outlier_threshold"):
        HandEyeOptions(outlier_threshold=0.0)
    with pytest.raises(BadInputError, match="unobservable_prior_sigma_m"):
        HandEyeOptions(unobservable_prior_sigma_m=0.0)


def test_cli_style_camera_options_carry_over():
    """The CLI's CameraCalibrationOptions reach the hand-eye problem: the robust loss and threshold
    are honoured (the injected outliers are flagged) rather than refused."""
    from jcalib.problems.camera import CameraCalibrationOptions

    cam_opts = CameraCalibrationOptions(loss="cauchy", loss_scale=2.0, sigma_px=0.2, outlier_threshold=4.0)
    he = HandEyeOptions.from_camera_options(cam_opts, pose_model=False)
    assert (he.loss, he.loss_scale, he.sigma_px, he.outlier_threshold, he.pose_model) == ("cauchy", 2.0, 0.2, 4.0, False)
    cell, obs, _ = J.make_data(23, "flange", sigma_px=0.2)
    dirty, bad = _inject(obs, np.random.default_rng(6), 10)
    result = jcalib.calibrate(J.with_known_intrinsics(cell), dirty, cam_opts)
    flagged = {(o["station"], o["point_index"]) for o in result.file.stats["outliers"]}
    assert bad <= flagged and result.file.stats["num_outliers"] == len(flagged)
    assert result.file.provenance.options["loss"] == "cauchy"
