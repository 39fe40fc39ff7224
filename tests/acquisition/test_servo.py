"""Visual servo (thesis algorithm 4.1) end to end: simulated robot + simulated camera rendering the tool."""

from __future__ import annotations

import numpy as np
import pytest

from jcalib.acquisition.cameras.simulated import SimulatedCamera
from jcalib.acquisition.robots import KukaRobot, KukaSimServer
from jcalib.acquisition.robots.simulated import SimulatedController, SimulatedRobot
from jcalib.acquisition.servo import servo_tool_tip
from jcalib.errors import BadInputError, DetectionError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.sim.tool import SymmetricTool, render_tool_image
from jcalib.vision.tooltip import detect_tool_tip

SIZE = (640, 480)
K = np.array([[1216.0, 0.0, 322.8], [0.0, 1216.0, 237.4], [0.0, 0.0, 1.0]])
CAMERA = camera_from_opencv(K, np.array([-0.25, 0.12, 0.001, -0.0005, -0.02]), SIZE)


def DETECT(image, name):  # noqa: N802 - the tip detector the servo loop is given
    return detect_tool_tip(image, camera=CAMERA, name=name).pixel


TOOL = SymmetricTool(shaft_radius_m=0.003, cone_half_angle_deg=20.0, length_m=0.25)
# tcp frame: tip 0.2 m beyond the flange, tcp +z pointing back into the tool (flange -z)
T_FLANGE_TCP = np.diag([1.0, -1.0, -1.0, 1.0])
T_FLANGE_TCP[2, 3] = 0.2


def make_cell(offset_m=(0.01, -0.008), repeatability_m=1.3e-5, seed=0):
    """A robot at home, a camera 0.3 m beside the tip looking along base +y (image x = base x, image
    down = base -z) at a point ``offset_m`` away from the tip (tip ~40 px off the centre)."""
    controller = SimulatedController(time_scale=0.0, repeatability_m=repeatability_m, seed=seed)
    robot = SimulatedRobot(controller, settle_poll_s=0.0)
    tip = (robot.state().T_base_flange @ T_FLANGE_TCP)[:3, 3]
    T_base_cam = np.eye(4)
    T_base_cam[:3, :3] = np.column_stack([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    T_base_cam[:3, 3] = tip + np.array([offset_m[0], -0.3, -offset_m[1]])
    frames = []

    def source(req):
        T_cam_tcp = np.linalg.inv(T_base_cam) @ controller.true_T_base_flange() @ T_FLANGE_TCP
        rendered = render_tool_image(CAMERA, T_cam_tcp, TOOL, rng=seed + req.index)
        frames.append(rendered)
        return rendered.image

    camera = SimulatedCamera(source, name="cam0", sensor_size=SIZE)
    return robot, camera, T_base_cam, controller, frames


def true_tip_px(controller, T_base_cam):
    p = (np.linalg.inv(T_base_cam) @ controller.true_T_base_flange() @ T_FLANGE_TCP)[:3, 3]
    return np.asarray(CAMERA.project(p)), p


def test_servo_brings_tip_to_image_centre():
    robot, camera, T_base_cam, controller, frames = make_cell()
    start_px, start_p = true_tip_px(controller, T_base_cam)
    centre = np.array([(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2])
    assert np.linalg.norm(start_px - centre) > 30.0  # starts well off the centre
    res = servo_tool_tip(robot, camera, T_base_cam[:3, :3], DETECT, tolerance_px=0.5)
    assert res.converged and res.error_px < 0.5
    assert res.iterations <= 5  # a handful: probing gives J, Broyden keeps it right
    np.testing.assert_allclose(res.target_px, centre)
    final_px, final_p = true_tip_px(controller, T_base_cam)
    # ground truth: detection error (~0.05 px) + repeatability (13 um ~0.05 px) on top of the tolerance
    assert np.linalg.norm(final_px - centre) < 0.7
    assert abs(final_p[2] - start_p[2]) < 1e-4  # moved in the camera's x-y plane: depth kept (0.1 mm)
    np.testing.assert_allclose(res.T_base_flange[:3, :3], robot.state().T_base_flange[:3, :3], atol=1e-4)
    assert [s.kind for s in res.steps][:3] == ["start", "probe", "probe"]
    assert len(frames) == len(res.steps)
    # the measured Jacobian is about f / depth (px per m) on the diagonal
    np.testing.assert_allclose(np.diag(res.image_jacobian), [1216.0 / 0.3] * 2, rtol=0.1)


def test_servo_over_the_kuka_protocol_on_loopback():
    """The same loop through a network driver: KUKAVARPROXY on 127.0.0.1 (simulated controller)."""
    _, camera, T_base_cam, controller, _ = make_cell(offset_m=(0.008, 0.006), seed=5)
    with KukaSimServer(controller) as srv:
        robot = KukaRobot("127.0.0.1", srv.port, motion_timeout_s=10.0)
        try:
            res = servo_tool_tip(robot, camera, T_base_cam, DETECT)
        finally:
            robot.close()
    assert res.converged and res.iterations <= 5
    centre = np.array([(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2])
    assert np.linalg.norm(true_tip_px(controller, T_base_cam)[0] - centre) < 0.7
    assert controller.num_moves == 2 + res.iterations  # two probes, then the corrections


def test_servo_with_given_jacobian_and_a_custom_target():
    robot, camera, T_base_cam, controller, _ = make_cell(offset_m=(-0.006, 0.004), seed=3)
    target = np.array([300.0, 250.0])
    J0 = np.diag([1216.0, 1216.0]) / 0.35  # a rough depth guess (true 0.3 m)
    res = servo_tool_tip(robot, camera, T_base_cam, DETECT, target_px=target, image_jacobian=J0)
    assert res.converged and res.iterations <= 6
    assert [s.kind for s in res.steps][1] == "correction"  # no probing moves
    np.testing.assert_allclose(true_tip_px(controller, T_base_cam)[0], target, atol=0.7)


def test_servo_reports_non_convergence_and_detection_failures():
    robot, camera, T_base_cam, _, _ = make_cell()
    res = servo_tool_tip(robot, camera, T_base_cam, DETECT, max_iterations=0)
    assert not res.converged and res.iterations == 0 and res.error_px > 30.0

    blank = SimulatedCamera(lambda req: np.full((req.height, req.width), 200, np.uint8), name="blank",
                            sensor_size=SIZE)
    with pytest.raises(DetectionError, match="visual servo: .*servo image 0 \\(start\\)") as info:
        servo_tool_tip(robot, blank, T_base_cam, DETECT)
    assert info.value.reason == "not_found"


def test_servo_bad_input():
    robot, camera, T_base_cam, _, _ = make_cell()
    with pytest.raises(BadInputError, match="R_base_cam"):
        servo_tool_tip(robot, camera, np.eye(2), DETECT)
    with pytest.raises(BadInputError, match="gain"):
        servo_tool_tip(robot, camera, T_base_cam, DETECT, gain=1.5)
    with pytest.raises(BadInputError, match="image_jacobian"):
        servo_tool_tip(robot, camera, T_base_cam, DETECT, image_jacobian=np.zeros((2, 2)))
