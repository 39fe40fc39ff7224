"""Closed-form robot-world / hand-eye (AX = ZB, Shah and Li): against OpenCV, ground truth and real data."""

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.robot_world import ROBOT_WORLD_METHODS, solve_ax_zb, solve_robot_world_hand_eye

# the scene generator, noise models and real-data loader of the AX = XB tests (loaded by path, so it
# works whether or not tests/ is a package)
_spec = importlib.util.spec_from_file_location("_handeye_test_helpers", Path(__file__).with_name("test_handeye.py"))
H = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(H)

METHODS = list(ROBOT_WORLD_METHODS)


def opencv_robot_world(T_base_flange, T_cam_target, method, mount="flange"):
    """OpenCV's AX = ZB in jcalib frames; returns (T, T_other) like solve_robot_world_hand_eye."""
    A = T_cam_target  # world2cam, world = target
    B = H.inv(T_base_flange) if mount == "flange" else T_base_flange  # base2gripper
    R_x, t_x, R_z, t_z = cv2.calibrateRobotWorldHandEye(
        list(A[:, :3, :3]), list(A[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]),
        method=getattr(cv2, ROBOT_WORLD_METHODS[method]),
    )
    X, Z = H.pose(R_x, t_x.ravel()), H.pose(R_z, t_z.ravel())
    return H.inv(Z), H.inv(X)


@given(st.integers(0, 2**32 - 1), st.sampled_from(["flange", "base"]))
def test_noise_free_matches_opencv_and_truth(seed, mount):
    rng = np.random.default_rng(seed)
    T_true, T_other_true, T_bf, T_ct = H.make_scene(rng, n=int(rng.integers(3, 12)), mount=mount)
    for method in METHODS:
        res = solve_robot_world_hand_eye(T_bf, T_ct, method=method, mount=mount)
        T_cv, T_other_cv = opencv_robot_world(T_bf, T_ct, method, mount)
        # float64 closed form on exact data: ~1e-13; 1e-9 leaves room for conditioning
        for T_a, T_b in [(res.T, T_cv), (res.T_other, T_other_cv), (res.T, T_true), (res.T_other, T_other_true)]:
            d_rot, d_t = H.errors(T_a, T_b)
            assert d_rot < 1e-9 and d_t < 1e-9, (method, mount, d_rot, d_t)


def test_noisy_matches_opencv():
    for seed in range(4):
        rng = np.random.default_rng(seed)
        _, _, T_bf, T_ct = H.make_scene(rng, n=12)
        T_bf = H.perturb_robot(T_bf, rng, sigma_m=3e-3, sigma_deg=0.5)
        T_ct = H.perturb_camera(T_ct, rng, sigma_px=5.0)
        for method in METHODS:
            res = solve_robot_world_hand_eye(T_bf, T_ct, method=method)
            T_cv, T_other_cv = opencv_robot_world(T_bf, T_ct, method)
            for T_a, T_b in [(res.T, T_cv), (res.T_other, T_other_cv)]:
                d_rot, d_t = H.errors(T_a, T_b)
                assert d_rot < 1e-9 and d_t < 1e-9, (seed, method, d_rot, d_t)


def test_solve_ax_zb_identity():
    rng = np.random.default_rng(9)
    T_flange_cam, T_base_target, T_bf, T_ct = H.make_scene(rng, n=6)
    X, Z = solve_ax_zb(T_ct, H.inv(T_bf), "shah")
    # A_i X = Z B_i for every station, and X, Z are the inverses of the ground truth
    np.testing.assert_allclose(T_ct @ X, Z @ H.inv(T_bf), atol=1e-12)
    np.testing.assert_allclose(X, H.inv(T_base_target), atol=1e-9)
    np.testing.assert_allclose(Z, H.inv(T_flange_cam), atol=1e-9)


def test_noisy_errors_small():
    """15 stations, robot 0.1 mm / 0.01 deg, camera pose noise of 0.2 px corners."""
    rng = np.random.default_rng(77)
    rot = {m: [] for m in METHODS}
    tra = {m: [] for m in METHODS}
    for _ in range(20):
        X, _, T_bf, T_ct = H.make_scene(rng, n=15)
        T_bf = H.perturb_robot(T_bf, rng)
        T_ct = H.perturb_camera(T_ct, rng)
        for method in METHODS:
            d_rot, d_t = H.errors(solve_robot_world_hand_eye(T_bf, T_ct, method=method).T, X)
            rot[method].append(np.degrees(d_rot))
            tra[method].append(d_t)
    # the AX = XB closed forms reach ~0.03 deg / 0.3-0.5 mm here (measured when this test was written);
    # bound at ~3x
    for m in METHODS:
        assert np.median(rot[m]) < 0.1, (m, np.median(rot[m]))
        assert np.median(tra[m]) < 2e-3, (m, np.median(tra[m]))


def test_degenerate_motion_raises():
    R0 = H.Rotation.from_euler("xyz", [30, -50, 20], degrees=True).as_matrix()
    T_bf, T_ct = H._stations_for(H._one_axis_stations([0.0, 0.0, 1.0], [0, 25, -40, 60, 80], R0))
    for method in METHODS:
        with pytest.raises(NotObservableError) as exc:
            solve_robot_world_hand_eye(T_bf, T_ct, method=method)
        where = "the common rotation axis (axis = [0, 0, 1] in the flange frame)"
        assert f"translation of T_flange_cam along {where}" in exc.value.unknowns
    with pytest.raises(NotObservableError, match="at least 3 stations"):
        solve_robot_world_hand_eye(T_bf[:2], T_ct[:2])


def test_bad_input():
    rng = np.random.default_rng(1)
    _, _, T_bf, T_ct = H.make_scene(rng, n=5)
    with pytest.raises(BadInputError, match="method"):
        solve_robot_world_hand_eye(T_bf, T_ct, method="kronecker")
    with pytest.raises(BadInputError, match="T_cam_target"):
        solve_robot_world_hand_eye(T_bf, T_ct[:3])
    with pytest.raises(BadInputError, match="mount"):
        solve_robot_world_hand_eye(T_bf, T_ct, mount="world")


def test_real_camodocal_eye_to_hand():
    """Real data (marker on the gripper, camera fixed): T_other = T_flange_target = marker in the ee frame."""
    T_base_ee, T_cam_marker, ref = H.load_camodocal()
    for method in METHODS:
        res = solve_robot_world_hand_eye(
            T_base_ee, T_cam_marker, method=method, mount="base", rotation_noise_deg=0.5
        )
        T_cv, T_other_cv = opencv_robot_world(T_base_ee, T_cam_marker, method, mount="base")
        d_rot, d_t = H.errors(res.T_other, T_other_cv)
        assert d_rot < 1e-9 and d_t < 1e-9
        if method == "shah":
            # noisy data (~4 deg / ~7 mm per-station scatter): Shah lands ~2 cm from the source project's answer
            assert np.linalg.norm(res.T_other[:3, 3] - ref[:3, 3]) < 0.03
        else:
            # Li's linear system (free scale of vec(R), like Andreff) lands ~6 cm away on this data
            assert np.linalg.norm(res.T_other[:3, 3] - ref[:3, 3]) < 0.1
