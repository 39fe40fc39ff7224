"""Joint hand-eye on degenerate robot motion: every suite raises NotObservableError naming the
unknowns it leaves undetermined, and one-axis (SCARA) motion gives the partial answer on request
(``CalibrationOptions(fix_unobservable=True)``), checked against the ground truth."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jcalib.errors import NotObservableError
from jcalib.sim.scene import project_target

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_degenerate", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)
H = J.H

#: Translation of T_flange_cam0 along the flange z axis in the SCARA scene (m).
SCARA_X = H.pose(Rotation.from_euler("xz", [20.0, 35.0], degrees=True).as_matrix(), [0.04, -0.03, 0.08])
SCARA_TARGET = H.pose(Rotation.from_euler("zx", [25.0, 180.0], degrees=True).as_matrix(), [0.6, 0.1, 0.0])
FLANGE_DOWN = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()


def scara_data(seed, angles_deg=None, n=8, sigma_px=0.0, pose_noise=None, rotate=True):
    """A SCARA-like eye-in-hand data set: flange z down, every rotation about the base z, flange
    heights 0.40-0.50 m and xy chosen so the camera looks near the board (on the table, z = 0).

    ``rotate=False`` keeps one orientation (pure translations). Returns (cell, obs, truth) like
    :func:`test_handeye_joint.make_data`, intrinsics known and fixed.
    """
    rng = np.random.default_rng(seed)
    if angles_deg is None:
        angles_deg = np.linspace(-80.0, 80.0, n) + rng.uniform(-5.0, 5.0, n)
    stations, T_bfs = [], []
    for i, ang in enumerate(angles_deg):
        R = Rotation.from_euler("z", ang if rotate else 0.0, degrees=True).as_matrix() @ FLANGE_DOWN
        h = 0.45 + rng.uniform(-0.05, 0.05)
        T_bc = H.pose(R, [0.0, 0.0, h]) @ SCARA_X
        c, dz = T_bc[:3, 3], T_bc[:3, 2]
        look = c - c[2] / dz[2] * dz  # where the optical axis meets the table
        t = np.array([*(SCARA_TARGET[:2, 3] + rng.uniform(-0.06, 0.06, 2) - look[:2]), h])
        T_bf = H.pose(R, t)
        T_ct = H.inv(T_bf @ SCARA_X) @ SCARA_TARGET
        pix, vis = project_target(J.CAMERA, T_ct, H.BOARD)
        assert vis.sum() >= 30, "scene generator: the board must be seen"
        pix = pix + sigma_px * rng.normal(size=pix.shape)
        idx = np.flatnonzero(vis)
        T_bfs.append(T_bf)
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_bf.tolist(),
                         "detections": [{"camera": "cam0", "target": "board", "point_index": idx.tolist(),
                                         "pixels": pix[idx].tolist()}]})
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(J.IMAGE_SIZE)}},
           "targets": {"board": {"points": H.BOARD.tolist()}}, "stations": stations}
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}}}
    if pose_noise is not None:
        cell["robot"] = {"pose_noise": {"translation_m": pose_noise[0], "rotation_deg": pose_noise[1]}}
    return J.with_known_intrinsics(cell), obs, {"T_hand_eye": SCARA_X, "T_target": SCARA_TARGET,
                                                 "T_base_flange": np.array(T_bfs)}


def _solve(cell, obs, **kw):
    return J.calibrate(cell, obs, **kw)


AXIS_Z = "the common rotation axis (axis = [0, 0, 1] in the flange frame)"


def test_scara_planar_motion_names_translation_along_axis():
    cell, obs, _ = scara_data(1)
    with pytest.raises(NotObservableError) as err:
        _solve(cell, obs)
    assert "planar motion (SCARA-like)" in str(err.value)
    assert f"translation of T_flange_cam0 along {AXIS_Z}" in err.value.unknowns
    assert err.value.exit_code == 3


def test_pure_translation_names_rotation_and_translation():
    cell, obs, _ = scara_data(2, rotate=False)
    with pytest.raises(NotObservableError) as err:
        _solve(cell, obs, fix_unobservable=True)  # no partial answer for this one
    assert "pure translations" in str(err.value)
    assert err.value.unknowns[0].startswith("rotation of T_flange_cam0")
    assert err.value.unknowns[1].startswith("translation of T_flange_cam0 (all 3 components")


def test_rotations_too_small_for_the_stated_robot_noise():
    """Rotations of a few thousandths of a degree against a stated robot noise of 0.01 deg."""
    cell, obs, _ = scara_data(3, angles_deg=np.linspace(-0.004, 0.004, 6), pose_noise=(1e-4, 0.01))
    with pytest.raises(NotObservableError) as err:
        _solve(cell, obs)
    assert "too small relative to the stated noise" in str(err.value)
    assert err.value.unknowns[0].startswith("rotation of T_flange_cam0")


def test_fewer_than_three_stations():
    cell, obs, _ = J.make_data(4, "flange", n=5)
    obs["stations"] = obs["stations"][:2]
    with pytest.raises(NotObservableError) as err:
        _solve(J.with_known_intrinsics(cell), obs)
    # one motion: the closed forms' check names what it leaves free (about / along its rotation axis)
    assert "got 2 station(s)" in str(err.value)
    assert len(err.value.unknowns) == 2
    assert err.value.unknowns[0].startswith("rotation of T_flange_cam0 about the rotation axis of the single motion")
    assert err.value.unknowns[1].startswith("translation of T_flange_cam0 along the rotation axis")


def _along(T):
    """Translation along the flange z (the SCARA rotation axis), m."""
    return float(T[2, 3])


def test_scara_fix_unobservable_recovers_the_rest_exactly():
    """Noise-free SCARA data with the true value as the prior: everything is recovered to 1e-6
    (noiseless recovery), the held component has the prior's σ, and the warning says so."""
    cell, obs, truth = scara_data(5)
    value = _along(truth["T_hand_eye"])
    cal = _solve(cell, obs, fix_unobservable=True, unobservable_prior_m=value, noise="stated")
    np.testing.assert_allclose(cal.transforms["T_flange_cam0"], truth["T_hand_eye"], atol=1e-6)
    np.testing.assert_allclose(cal.transforms["T_base_board"], truth["T_target"], atol=1e-6)
    fixed = dict(cal.unobservable_fixed)
    np.testing.assert_allclose(fixed.pop("axis"), [0.0, 0.0, 1.0], atol=1e-12)  # rotation vectors' rounding
    assert fixed == {"transform": "T_flange_cam0", "frame": "flange", "value_m": value, "sigma_m": 1e-6}
    assert any("held at the stated prior" in w and "T_flange_cam0" in w for w in cal.warnings)
    # the stated-noise variance along the axis is the prior's (the data say nothing about it)
    R = cal.transforms["T_flange_cam0"][:3, :3]
    a_tangent = R.T @ np.array([0.0, 0.0, 1.0])
    var = a_tangent @ cal.transform_covariance["T_flange_cam0"][3:, 3:] @ a_tangent
    np.testing.assert_allclose(np.sqrt(var), 1e-6, rtol=1e-3)


def test_scara_fix_unobservable_with_a_wrong_prior_shifts_only_that_component():
    """A prior 5 mm off: the along-axis translation follows the prior, the target shifts with it
    along the base z (flange z points down), every other component is still the truth."""
    cell, obs, truth = scara_data(6, sigma_px=0.0)
    value = _along(truth["T_hand_eye"]) + 0.005
    cal = _solve(cell, obs, fix_unobservable=True, unobservable_prior_m=value, noise="stated")
    X, Xt = cal.transforms["T_flange_cam0"], truth["T_hand_eye"]
    np.testing.assert_allclose(X[:3, :3], Xt[:3, :3], atol=1e-6)
    np.testing.assert_allclose(X[:3, 3], Xt[:3, 3] + [0.0, 0.0, 0.005], atol=1e-6)
    shift = truth["T_base_flange"][0][:3, :3] @ np.array([0.0, 0.0, 0.005])  # = (0, 0, -5 mm) in the base
    T_target = cal.transforms["T_base_board"]
    np.testing.assert_allclose(T_target[:3, 3], truth["T_target"][:3, 3] + shift, atol=1e-6)
    np.testing.assert_allclose(T_target[:3, :3], truth["T_target"][:3, :3], atol=1e-6)


def test_scara_fix_unobservable_noisy_within_reported_sigma():
    """0.2 px corners, robot 0.1 mm / 0.01 deg: the determined components are within 5 reported σ
    of the truth (a gross check; the Monte-Carlo consistency is bench_handeye_consistency.py)."""
    cell, obs, truth = scara_data(7, n=12, sigma_px=0.2)
    value = _along(truth["T_hand_eye"])
    cal = _solve(cell, obs, fix_unobservable=True, unobservable_prior_m=value, sigma_px=0.2)
    delta = np.linalg.solve(cal.transforms["T_flange_cam0"], truth["T_hand_eye"])
    rot = Rotation.from_matrix(delta[:3, :3]).as_rotvec()
    sd = np.sqrt(np.diag(cal.transform_covariance["T_flange_cam0"]))
    assert np.all(np.abs(rot) < 5 * sd[:3] + 1e-9), (rot, sd)
    assert np.all(np.abs(delta[:3, 3]) < 5 * sd[3:] + 1e-9), (delta[:3, 3], sd)


#: Eye-to-hand SCARA: camera 1 m above the table looking down, board 5 cm below the flange facing up.
E2H_CAM = H.pose(Rotation.from_euler("zx", [15.0, 180.0], degrees=True).as_matrix(), [0.6, 0.1, 1.0])
E2H_TARGET = H.pose(Rotation.from_euler("xy", [8.0, -6.0], degrees=True).as_matrix(), [0.02, -0.01, 0.05])


def scara_eye_to_hand_data(seed, n=8):
    """Noise-free eye-to-hand SCARA data (camera on the base, board on the flange); intrinsics known."""
    rng = np.random.default_rng(seed)
    stations, T_bfs = [], []
    for i, ang in enumerate(np.linspace(-80.0, 80.0, n) + rng.uniform(-5.0, 5.0, n)):
        R = Rotation.from_euler("z", ang, degrees=True).as_matrix() @ FLANGE_DOWN
        T_bf = H.pose(R, [0.6 + rng.uniform(-0.1, 0.1), 0.1 + rng.uniform(-0.1, 0.1), rng.uniform(0.3, 0.4)])
        pix, vis = project_target(J.CAMERA, H.inv(E2H_CAM) @ T_bf @ E2H_TARGET, H.BOARD)
        assert vis.sum() >= 30, "scene generator: the board must be seen"
        idx = np.flatnonzero(vis)
        T_bfs.append(T_bf)
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_bf.tolist(),
                         "detections": [{"camera": "cam0", "target": "board", "point_index": idx.tolist(),
                                         "pixels": pix[idx].tolist()}]})
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(J.IMAGE_SIZE)}},
           "targets": {"board": {"points": H.BOARD.tolist()}}, "stations": stations}
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "base"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025,
                                  "mount": "flange"}}}
    return J.with_known_intrinsics(cell), obs


def test_scara_eye_to_hand_names_base_axis_and_fixes_camera_height():
    """Eye-to-hand SCARA: the height of T_base_cam (along the base z) is undetermined; with a prior
    5 mm off, the camera moves up 5 mm, the board moves 5 mm along the flange -z (up in the base),
    and everything else is the truth."""
    cell, obs = scara_eye_to_hand_data(9)
    with pytest.raises(NotObservableError) as err:
        _solve(cell, obs)
    assert ("translation of T_base_cam0 along the common rotation axis (axis = [0, 0, 1] in the base frame)"
            in err.value.unknowns)
    cal = _solve(cell, obs, fix_unobservable=True, unobservable_prior_m=E2H_CAM[2, 3] + 0.005, noise="stated")
    assert cal.unobservable_fixed["transform"] == "T_base_cam0" and cal.unobservable_fixed["frame"] == "base"
    X, Y = cal.transforms["T_base_cam0"], cal.transforms["T_flange_board"]
    np.testing.assert_allclose(X[:3, :3], E2H_CAM[:3, :3], atol=1e-6)
    np.testing.assert_allclose(X[:3, 3], E2H_CAM[:3, 3] + [0.0, 0.0, 0.005], atol=1e-6)
    np.testing.assert_allclose(Y[:3, :3], E2H_TARGET[:3, :3], atol=1e-6)
    np.testing.assert_allclose(Y[:3, 3], E2H_TARGET[:3, 3] + [0.0, 0.0, -0.005], atol=1e-6)
