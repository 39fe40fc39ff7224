"""A robot cell's held-out prediction (``stats.prediction``) against a leave-one-station-out computed outside
jcalib's warm re-solves: each station left out of a whole new calibration, its corners re-projected by OpenCV
from its recorded flange pose."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

import jcalib
from jcalib.errors import BadInputError

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_prediction", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)


def _without(obs: dict, k: int) -> dict:
    return {**obs, "stations": [s for i, s in enumerate(obs["stations"]) if i != k]}


def _independent_loso(cell: dict, obs: dict) -> dict[str, np.ndarray]:
    """Station id -> per-point pixel error norms of its corners predicted by the cell calibrated without it."""
    out = {}
    for k, st in enumerate(obs["stations"]):
        res = jcalib.calibrate(cell, _without(obs, k), {"prediction": False}).file
        cam = res.cameras["cam0"]
        K, dist = np.asarray(cam.K, np.float64), np.asarray(cam.dist, np.float64)
        T_flange_cam = np.asarray(res.transforms["T_flange_cam0"].matrix, np.float64)
        T_base_board = np.asarray(res.transforms["T_base_board"].matrix, np.float64)
        T_cam_board = np.linalg.inv(np.asarray(st["T_base_flange"]) @ T_flange_cam) @ T_base_board
        det = st["detections"][0]
        points = np.asarray(obs["targets"]["board"]["points"], np.float64)[det["point_index"]]
        rvec, _ = cv2.Rodrigues(T_cam_board[:3, :3])
        pred, _ = cv2.projectPoints(points, rvec, T_cam_board[:3, 3], K, dist)
        out[st["id"]] = np.linalg.norm(pred.reshape(-1, 2) - np.asarray(det["pixels"]), axis=1)
    return out


@pytest.mark.parametrize("robot_m", [0.0, 3e-4], ids=["exact-poses", "pose-model"])
def test_held_out_prediction_matches_an_independent_leave_one_station_out(robot_m):
    cell, obs, _ = J.make_data(11, mount="flange", n=12, sigma_px=0.3, robot_m=robot_m, robot_deg=0.03)
    stats = jcalib.calibrate(cell, obs).file.stats
    pred = stats["prediction"]
    assert pred["method"] == "leave-one-station-out" and pred["stations"] == 12
    assert pred["model"] == {"robot": "pose_noise" if robot_m else "exact"}
    errors = _independent_loso(cell, obs)
    want = float(np.sqrt(np.mean(np.concatenate(list(errors.values())) ** 2)))
    assert pred["rms_px"] == pytest.approx(want, rel=0.05)
    for sid, e in errors.items():  # and station by station
        assert pred["per_station"][sid]["rms_px"] == pytest.approx(float(np.sqrt(np.mean(e * e))), rel=0.10)
        assert pred["per_station"][sid]["points"] == e.size
    # robot pose error makes held-out corners land worse than the fit's own residuals
    if robot_m:
        assert pred["rms_px"] > 1.5 * stats["rms_px"]


def test_prediction_is_only_for_robot_cells_and_can_be_turned_off():
    cell, obs, _ = J.make_data(12, mount="flange", n=8, sigma_px=0.3)
    assert "prediction" not in jcalib.calibrate(cell, obs, {"prediction": False}).file.stats
    camera_only = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
                   "targets": {"board": {**cell["targets"]["board"], "mount": "free"}}}
    free_obs = {**obs, "stations": [{k: v for k, v in s.items() if k != "T_base_flange"} for s in obs["stations"]]}
    assert "prediction" not in jcalib.calibrate(camera_only, free_obs).file.stats
    with pytest.raises(BadInputError, match="prediction"):
        jcalib.calibrate(camera_only, free_obs, {"prediction": False})
