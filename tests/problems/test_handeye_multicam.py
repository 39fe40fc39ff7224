"""Several flange cameras sharing stations (eye-in-hand): each its own T_flange_cam and
intrinsics, one shared T_base_target and one robot pose per station; against ground truth."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import jcalib
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.problems import CalibrationOptions
from jcalib.sim.scene import project_target

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_multicam", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)
H = J.H

IMAGE_SIZE_1 = (1280, 960)
#: cam1, opencv4: fx, fy, cx, cy, k1, k2, p1, p2
PARAMS_1 = np.array([1100.0, 1102.0, 642.0, 478.5, -0.05, 0.01, 0.0002, 0.0001])
CAMERA_1 = camera_model_from_name("opencv4", IMAGE_SIZE_1, PARAMS_1)
#: cam1 in the cam0 frame: 6 cm to the side, turned 4 deg towards cam0's axis
T_CAM0_CAM1 = H.pose(Rotation.from_euler("y", -4.0, degrees=True).as_matrix(), [0.06, 0.005, 0.0])


def make_two_camera_data(seed, sigma_px=0.0, robot_m=0.0, robot_deg=0.0, drop_cam1=()):
    """cam0 as in make_data, cam1 rigidly beside it; cam1 misses the stations in ``drop_cam1``."""
    cell, obs, truth = J.make_data(seed, "flange", sigma_px=sigma_px, robot_m=robot_m, robot_deg=robot_deg)
    rng = np.random.default_rng(seed + 1000)
    X1 = truth["T_hand_eye"] @ T_CAM0_CAM1
    for i, station in enumerate(obs["stations"]):
        if i in drop_cam1:
            continue
        T_ct1 = H.inv(T_CAM0_CAM1) @ truth["T_cam_target"][i]  # from the true (unperturbed) poses
        pix, vis = project_target(CAMERA_1, T_ct1, H.BOARD)
        idx = np.flatnonzero(vis)
        assert idx.size >= 20
        pix = pix[idx] + sigma_px * rng.normal(size=(idx.size, 2))
        station["detections"].append({"camera": "cam1", "target": "board", "point_index": idx.tolist(),
                                      "pixels": pix.tolist()})
    obs["cameras"]["cam1"] = {"image_size": list(IMAGE_SIZE_1)}
    cell["cameras"]["cam1"] = {"model": "opencv4", "mount": "flange"}
    truth["T_hand_eye_1"] = X1
    return cell, obs, truth


def test_two_flange_cameras_noise_free_recovery():
    """Exact data: both hand-eye transforms, both intrinsics and the shared target to 1e-6."""
    cell, obs, truth = make_two_camera_data(31, drop_cam1=(2, 7))
    cal = J.calibrate(cell, obs, noise="stated")
    assert set(cal.cameras) == {"cam0", "cam1"}
    assert set(cal.transforms) == {"T_flange_cam0", "T_flange_cam1", "T_base_board"}
    # cam1 misses two stations: its views are the others (one shared robot pose per station)
    views = {cam: {s for (c, s) in cal.view_rms_px if c == cam} for cam in ("cam0", "cam1")}
    assert views["cam1"] < views["cam0"] and len(views["cam1"]) == len(views["cam0"]) - 2
    assert len(cal.station_ids) == len(views["cam0"])
    np.testing.assert_allclose(cal.transforms["T_flange_cam0"], truth["T_hand_eye"], atol=1e-6)
    np.testing.assert_allclose(cal.transforms["T_flange_cam1"], truth["T_hand_eye_1"], atol=1e-6)
    np.testing.assert_allclose(cal.transforms["T_base_board"], truth["T_target"], atol=1e-6)
    np.testing.assert_allclose(np.asarray(cal.cameras["cam0"].params), J.TRUE_PARAMS, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(cal.cameras["cam1"].params), PARAMS_1, rtol=1e-6, atol=1e-6)


def test_two_flange_cameras_noisy_through_calibrate():
    """0.2 px, robot 0.1 mm / 0.01 deg, pose model on: jcalib.calibrate writes both transforms and
    both cameras; each hand-eye is within 5 reported σ per axis of the truth, and the relative pose
    cam0 -> cam1 too (a quantity neither closed form sees)."""
    cell, obs, truth = make_two_camera_data(32, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    result = jcalib.calibrate(cell, obs, CalibrationOptions(sigma_px=0.2))
    assert set(result.file.transforms) == {"T_flange_cam0", "T_flange_cam1", "T_base_board"}
    assert set(result.file.cameras) == {"cam0", "cam1"}
    for name, X in (("T_flange_cam0", truth["T_hand_eye"]), ("T_flange_cam1", truth["T_hand_eye_1"])):
        T = np.asarray(result.file.transforms[name].matrix)
        sd = np.sqrt(np.diag(result.covariance(name)))
        d = np.linalg.solve(T, X)  # T_true = T_est · Exp(δ): right perturbation, as the covariance
        rotvec = Rotation.from_matrix(d[:3, :3]).as_rotvec()
        assert np.all(np.abs(rotvec) < 5 * sd[:3]), (name, rotvec, sd)
        assert np.all(np.abs(d[:3, 3]) < 5 * sd[3:]), (name, d[:3, 3], sd)
    T0 = np.asarray(result.file.transforms["T_flange_cam0"].matrix)
    T1 = np.asarray(result.file.transforms["T_flange_cam1"].matrix)
    rel = np.linalg.solve(T0, T1)
    assert np.linalg.norm(rel[:3, 3] - T_CAM0_CAM1[:3, 3]) < 5e-4  # sub-mm: gross check of the sharing
    assert result.file.stats["robot_pose_model"] is True
    assert any(k.startswith("cam1/") for k in result.file.stats["view_rms_px"])
