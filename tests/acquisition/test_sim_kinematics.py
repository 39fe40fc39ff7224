"""A simulated robot with hidden kinematic errors: its controller plans and reports with the nominal preset
while the cameras see the true arm; ``jcalib simulate --kinematic-errors`` writes the true parameters to its
truth file; a session captured from it gives observations whose stations carry the reported joints."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from jcalib.acquisition.robots import SimulatedController, SimulatedRobot, SixAxisArm
from jcalib.acquisition.robots.model import preset_model
from jcalib.acquisition.robots.simulated import kinematics_forward
from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models
from jcalib.geometry.se3 import invert
from jcalib.sim.kinematic_cells import kinematic_errors

PRESET = "kuka_kr10_r1100_sixx"


@pytest.fixture(scope="module")
def arm():
    """The preset's controller model, its kinematics and true parameters with 5x realistic errors
    (a few mm at the flange, so that the effects below stand out of the sub-pixel noise)."""
    model = kinematic_models.PRESETS[PRESET]()
    params = kinematic_errors(model, np.random.default_rng(7), None, 5.0)
    return preset_model(PRESET), model, params


def _pose_error(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation rad) of ``A⁻¹ B``."""
    D = invert(A) @ B
    return float(np.linalg.norm(D[:3, 3])), float(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))


def test_controller_reports_nominal_kinematics_and_renders_the_true_one(arm):
    ctrl_model, model, params = arm
    true_fk = kinematics_forward(model, params)
    nominal_fk = kinematics_forward(model, model.nominal)
    # the preset's parameterised kinematics is the controller's model (same joints, sign and zero)
    q = ctrl_model.home_rad + np.radians([10.0, 5.0, -8.0, 20.0, -15.0, 30.0])
    np.testing.assert_allclose(nominal_fk(q), ctrl_model.forward(q), atol=1e-12)  # float64 identity

    exact = SimulatedController(ctrl_model, time_scale=0.0, repeatability_m=0.0, repeatability_rad=0.0,
                                true_forward=true_fk)  # fmt: skip
    noisy = SimulatedController(ctrl_model, time_scale=0.0, true_forward=true_fk, seed=3)
    T_home = ctrl_model.forward(ctrl_model.home_rad)
    for k, dx in enumerate((0.0, 0.05, -0.08)):
        T = T_home.copy()
        T[:3, 3] += [dx, 0.5 * dx, -0.3 * abs(dx)]
        for ctrl in (exact, noisy):
            robot = SimulatedRobot(ctrl)
            state = robot.move(T)
            q = np.radians(state.joints_deg)
            # reported: the nominal FK at the joints the nominal IK found (= the commanded pose)
            np.testing.assert_allclose(state.T_base_flange, nominal_fk(q), atol=1e-9)
            assert _pose_error(state.T_base_flange, T)[0] < 1e-5  # the controller's IK tolerance
            # rendered: the true FK at the same joints (times the repeatability error)
            shift = true_fk(q) - nominal_fk(q)
            assert np.linalg.norm(shift[:3, 3]) > 1e-3, k  # the errors are real: mm at the flange
            np.testing.assert_allclose(ctrl.true_T_base_flange() - state.T_base_flange, shift,
                                       atol=1e-12 if ctrl is exact else 1e-4)  # 1e-4: > 5 σ of repeatability
            if ctrl is noisy:
                dt, dr = _pose_error(true_fk(q), ctrl.true_T_base_flange())
                assert 0 < dt < 5 * np.sqrt(3) * ctrl.repeatability_m and dr < 5 * np.sqrt(3) * ctrl.repeatability_rad


def test_default_controller_has_no_kinematic_error(arm):
    ctrl_model = arm[0]
    ctrl = SimulatedController(ctrl_model, time_scale=0.0, repeatability_m=0.0, repeatability_rad=0.0)
    assert ctrl.true_forward is None
    np.testing.assert_allclose(ctrl.true_T_base_flange(), ctrl_model.forward(ctrl.joints_rad()), atol=1e-12)
    with pytest.raises(BadInputError, match="true_forward"):
        SimulatedController(ctrl_model, true_forward=np.eye(4))


def test_simulated_kinematics_draws_identifiable_errors_and_refuses_a_non_preset_arm():
    from jcalib.app.simcell import simulated_kinematics

    with pytest.raises(BadInputError, match="robot preset") as e:
        simulated_kinematics(SixAxisArm(), PRESET, 0)
    assert e.value.exit_code == 2
    with pytest.raises(BadInputError, match="no kinematics preset"):
        simulated_kinematics(preset_model(PRESET), "no_such_robot", 0)


def test_simulate_truth_holds_the_true_kinematics(aravis, tmp_path):
    """``jcalib simulate --kinematic-errors SEED --truth FILE`` on loopback: the truth names the true
    parameters; they differ from the nominal ones on the identifiable subset only (the one the
    calibration keeps), by realistic amounts; the same seed gives the same arm."""
    from jcalib.app.simulate import run_simulate
    from jcalib.app.simcell import simulated_kinematics
    from jcalib.problems.kinematics import generic_joints, select_parameters

    cell = tmp_path / "cell.yaml"
    cell.write_text(f"schema: jcalib.cell/1\nrobot: {{model: {PRESET}}}\ncameras:\n  cam0: {{model: opencv5, mount: "
                    "flange}\ntargets:\n  board: {type: checkerboard, cols: 8, rows: 6, square: 0.025, mount: base}\n")
    stop = threading.Event()
    stop.set()  # write the truth, open the devices, stop at once
    run_simulate(cell, robot_protocol="kuka", robot_port=0, camera_addresses={"cam0": "127.0.0.1"},
                 truth=tmp_path / "truth.json", image_size=(320, 240), time_scale=0.0, stop=stop,
                 kinematic_errors=11)  # fmt: skip
    t = json.loads((tmp_path / "truth.json").read_text())["robot"]["kinematics"]
    model = kinematic_models.PRESETS[PRESET]()
    assert t["preset"] == PRESET and t["names"] == list(model.param_names)
    np.testing.assert_array_equal(t["nominal"], np.asarray(model.nominal))
    # the structural selection of the builder (as in tests/problems/test_kinematic_calibration.py)
    free = select_parameters(model, ("joint_offsets", "link_lengths", "twists"), generic_joints(model),
                             np.eye(6) * 1e4, "robot").free  # fmt: skip
    assert t["errors_on"] == [n for n, f in zip(model.param_names, free) if f]
    delta = np.asarray(t["values"]) - np.asarray(t["nominal"])
    assert np.all(delta[~free] == 0.0) and np.all(delta[free] != 0.0)
    assert np.max(np.abs(delta)) < 5e-3  # realistic: σ 0.05 deg / 0.5 mm
    # the same seed gives the same arm, another seed another one
    same, other = (simulated_kinematics(preset_model(PRESET), PRESET, seed) for seed in (11, 12))
    assert same.to_json() == t and other.to_json()["values"] != t["values"]
    # without --kinematic-errors the truth has none
    run_simulate(cell, robot_protocol="kuka", robot_port=0, camera_addresses={"cam0": "127.0.0.1"},
                 truth=tmp_path / "plain.json", image_size=(320, 240), time_scale=0.0, stop=stop)  # fmt: skip
    assert "kinematics" not in json.loads((tmp_path / "plain.json").read_text())["robot"]


def test_session_observations_carry_the_joints_and_show_the_true_arm(arm, tmp_path):
    """Capture a session in-process from a controller with kinematic errors, detect it: each station carries
    the joints the controller reported (and its nominal flange pose), and the board corners are where the
    *true* arm put the camera, not where the nominal one says."""
    import cv2

    from jcalib.acquisition.cameras import SimulatedCamera
    from jcalib.acquisition.capture import capture
    from jcalib.planning.layout import cell_layout
    from jcalib.planning.stations import plan_cell
    from jcalib.app.simcell import scene_frame_source, scene_from_layout
    from jcalib.io.session import read_session
    from jcalib.pipeline.session import detect_session

    ctrl_model, model, params = arm
    cell = {"schema": "jcalib.cell/1", "robot": {"model": PRESET},
            "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 6, "square": 0.025, "mount": "base"}}}
    layout = cell_layout(cell, image_size=(480, 360))
    plan = plan_cell(layout, "handeye", num_stations=4).plan
    ctrl = SimulatedController(ctrl_model, time_scale=0.0, true_forward=kinematics_forward(model, params), seed=1)
    source = scene_frame_source(scene_from_layout(layout), "cam0", ctrl.true_T_base_flange, seed=2)
    cameras = {"cam0": SimulatedCamera(source, name="cam0", sensor_size=(480, 360))}
    capture(plan, SimulatedRobot(ctrl), cameras, tmp_path / "session", cell=cell, progress=False)
    _, records = read_session(tmp_path / "session")
    obs, failures = detect_session(tmp_path / "session", progress=False)
    assert not failures and len(obs.stations) == len(records) == len(plan)

    cam = layout.cameras["cam0"]
    T_base_board, pts = layout.targets["board"].pose, np.asarray(layout.targets["board"].geometry.points)
    nominal_fk = kinematics_forward(model, model.nominal)
    true_fk = kinematics_forward(model, params)
    for st, rec in zip(obs.stations, records):
        assert st.id == rec["id"]
        np.testing.assert_array_equal(st.joints_deg, rec["joints_deg"])
        assert st.to_dict()["joints_deg"] == rec["joints_deg"]
        q = kinematic_models.joints_from_controller(model, st.joints_deg)
        np.testing.assert_allclose(st.T_base_flange, nominal_fk(q), atol=1e-9)  # as the controller reported it
        det = st.detections[0]

        def project(T_base_flange):
            T_cam_board = invert(T_base_flange @ cam.pose) @ T_base_board
            rvec, _ = cv2.Rodrigues(T_cam_board[:3, :3])
            px, _ = cv2.projectPoints(pts[det.point_index], rvec, T_cam_board[:3, 3], cam.K, cam.dist)
            return px.reshape(-1, 2)

        err_true = np.sqrt(np.mean(np.sum((det.pixels - project(true_fk(q))) ** 2, axis=1)))
        err_nominal = np.sqrt(np.mean(np.sum((det.pixels - project(nominal_fk(q))) ** 2, axis=1)))
        assert err_true < 0.3 < 1.0 < err_nominal, (st.id, err_true, err_nominal)
