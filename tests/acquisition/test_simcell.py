"""A simulated cell: the frame source renders the board where OpenCV projects it for the robot's pose, and a
base camera observing a tool shows its silhouette, tip where OpenCV projects the true TCP, in its tool zone."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from jcalib.acquisition.cameras import SimulatedCamera
from jcalib.acquisition.robots import SimulatedController, SimulatedRobot
from jcalib.geometry.se3 import make_pose, rot_z
from jcalib.app.simcell import SceneTarget, robot_scene_source
from jcalib.geometry.cameras.factory import camera_from_opencv
from jcalib.geometry.targets import Checkerboard
from jcalib.sim.textures import target_texture


def test_rendered_corners_follow_the_robot():
    K = np.array([[400.0, 0.0, 159.5], [0.0, 400.0, 119.5], [0.0, 0.0, 1.0]])
    camera = camera_from_opencv(K, np.zeros(5), (320, 240))
    board = Checkerboard(cols=7, rows=5, square=0.02)
    ctrl = SimulatedController(time_scale=0.0)
    robot = SimulatedRobot(ctrl)
    T_home = robot.state().T_base_flange  # flange z points down
    T_flange_cam = make_pose(rot_z(0.3), np.array([0.03, 0.0, 0.05]))
    # board face-up 0.45 m below the home camera, centred under it (target z along the view direction)
    T_base_cam_home = T_home @ T_flange_cam
    centre = np.array([3 * 0.02, 2 * 0.02, 0.0])
    R = T_base_cam_home[:3, :3]
    T_base_board = make_pose(R, T_base_cam_home[:3, 3] + R @ np.array([0.0, 0.0, 0.45]) - R @ centre)
    source = robot_scene_source(
        ctrl.true_T_base_flange, camera, [SceneTarget(target_texture(board, 0.0005), T_base_board)],
        T_flange_cam=T_flange_cam,
    )  # fmt: skip
    cam = SimulatedCamera(source, name="cam0", sensor_size=(320, 240))
    for dx in (0.0, 0.03):
        T = T_home.copy()
        T[0, 3] += dx
        state = robot.move(T)
        img = cam.grab().image
        found, corners = cv2.findChessboardCorners(img, (7, 5))
        assert found
        corners = cv2.cornerSubPix(
            img, corners, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
        ).reshape(-1, 2)
        T_cam_board = np.linalg.inv(state.T_base_flange @ T_flange_cam) @ T_base_board
        rvec, _ = cv2.Rodrigues(T_cam_board[:3, :3])
        ref, _ = cv2.projectPoints(board.points, rvec, T_cam_board[:3, 3], K, np.zeros(5))
        ref = ref.reshape(-1, 2)
        if np.linalg.norm(corners[0] - ref[0]) > np.linalg.norm(corners[0] - ref[-1]):
            corners = corners[::-1]  # a symmetric board's detection order is ambiguous
        # sub-pixel detection on a rendered noisy image: well under a pixel
        assert np.max(np.linalg.norm(corners - ref, axis=1)) < 0.3


def test_scene_frame_source_matches_render_view():
    """The live source renders exactly what jcalib.sim renders for a recorded view at that pose."""
    from jcalib.sim.scene import Scene, SceneCamera, View, render_view
    from jcalib.sim.scene import SceneTarget as SimTarget

    from jcalib.app.simcell import scene_frame_source

    K = np.array([[300.0, 0.0, 79.5], [0.0, 300.0, 59.5], [0.0, 0.0, 1.0]])
    camera = camera_from_opencv(K, np.zeros(5), (160, 120))
    board = Checkerboard(cols=5, rows=4, square=0.02)
    ctrl = SimulatedController(time_scale=0.0)
    T_home = ctrl.true_T_base_flange()
    T_flange_cam = make_pose(np.eye(3), np.array([0.0, 0.0, 0.05]))
    R = T_home[:3, :3]
    T_base_board = make_pose(R, T_home[:3, 3] + R @ np.array([-0.04, -0.03, 0.4]))
    scene = Scene(
        cameras={"cam0": SceneCamera(camera, "flange", T_flange_cam)},
        targets={"board": SimTarget(board, target_texture(board, 0.0005), "base", T_base_board)},
        views=[View("s000", T_home)],
    )
    source = scene_frame_source(scene, "cam0", ctrl.true_T_base_flange, seed=5)
    img = SimulatedCamera(source, name="cam0", sensor_size=(160, 120)).grab().image
    np.testing.assert_array_equal(img, render_view(scene, 0, "cam0", rng=5))


def _tool_cell(size=(320, 240)):
    """A controller at home, a board beside the work area, a 0.15 m tool along the flange z axis, and a
    base camera ``cam1`` looking at the tip side-on (along base +y) from the tool-zone distance."""
    from jcalib.planning.stations import TOOL_VIEW_DISTANCE_M
    from jcalib.app.simcell import CellScene, SceneTool
    from jcalib.sim.scene import Scene, SceneCamera
    from jcalib.sim.scene import SceneTarget as SimTarget
    from jcalib.sim.tool import SymmetricTool

    K = np.array([[400.0, 0.0, 161.3], [0.0, 401.0, 118.2], [0.0, 0.0, 1.0]])
    dist = np.array([-0.1, 0.04, 0.0, 0.0, 0.0])
    camera = camera_from_opencv(K, dist, size)
    ctrl = SimulatedController(time_scale=0.0)
    T_home = ctrl.true_T_base_flange()
    T_flange_tool = make_pose(np.eye(3), np.array([0.0, 0.0, 0.15]))
    tip = (T_home @ T_flange_tool)[:3, 3]
    # the camera looks along base +y at the tip from the zone distance; image down = the direction the
    # tool points (flange z, made perpendicular to the view): the tool is seen side-on
    z = np.array([0.0, 1.0, 0.0])
    y = T_home[:3, 2] - np.dot(T_home[:3, 2], z) * z
    y /= np.linalg.norm(y)
    R = np.stack([np.cross(y, z), y, z], axis=1)
    T_base_cam = make_pose(R, tip - TOOL_VIEW_DISTANCE_M * z)
    board = Checkerboard(cols=5, rows=4, square=0.02)
    # the board 0.3 m beyond the tip, facing the camera (its z along the view direction), centred
    T_base_board = make_pose(R, tip + 0.3 * z - R @ np.array([0.04, 0.03, 0.0]))
    scene = Scene(
        cameras={"cam1": SceneCamera(camera, "base", T_base_cam)},
        targets={"board": SimTarget(board, target_texture(board, 0.0005), "base", T_base_board)},
        views=[],
    )
    tool = SceneTool(SymmetricTool(shaft_radius_m=0.005, cone_half_angle_deg=15.0, length_m=0.15), T_flange_tool,
                     ("cam1",))  # fmt: skip
    return CellScene(scene, {"torch": tool}), ctrl, camera, K, dist, T_base_cam, T_flange_tool


def test_a_base_camera_shows_the_tool_tip_in_its_zone_and_the_scene_elsewhere():
    """In the zone: a silhouette whose detected tip is where OpenCV projects the true TCP; out of it:
    exactly what jcalib.sim renders for the targets at that pose."""
    from jcalib.app.simcell import scene_frame_source
    from jcalib.sim.scene import Scene, View, render_view
    from jcalib.vision.tooltip import detect_tool_tip

    cell, ctrl, camera, K, dist, T_base_cam, T_flange_tool = _tool_cell()
    robot = SimulatedRobot(ctrl, settle_poll_s=0.0)
    cam = SimulatedCamera(scene_frame_source(cell, "cam1", ctrl.true_T_base_flange, seed=3), name="cam1",
                          sensor_size=(320, 240))  # fmt: skip
    T_home = robot.state().T_base_flange
    for k, (axis, angle) in enumerate(((0, 0.0), (0, 0.3), (1, -0.3))):  # turned about base x / y through the tip
        rvec = np.zeros(3)
        rvec[axis] = angle
        R, _ = cv2.Rodrigues(rvec)
        tip = (T_home @ T_flange_tool)[:3, 3]
        T = make_pose(R @ T_home[:3, :3], R @ (T_home[:3, 3] - tip) + tip)
        robot.move(T)
        assert cell.tool_in_view("cam1", ctrl.true_T_base_flange()) == "torch", k
        img = cam.grab().image
        T_cam_tip = np.linalg.inv(T_base_cam) @ ctrl.true_T_base_flange() @ T_flange_tool
        ref, _ = cv2.projectPoints(T_cam_tip[None, :3, 3], np.zeros(3), np.zeros(3), K, dist)
        det = detect_tool_tip(img, camera=camera)
        # rendered noisy 320x240 silhouette, 11 px wide shaft: a sub-pixel tip (measured 0.04-0.17 px)
        assert np.linalg.norm(det.pixel - ref.ravel()) < 0.5, (k, det.pixel, ref.ravel())
    # the tip 0.1 m aside (outside the 0.05 m zone): the board scene, as jcalib.sim renders it
    T = T_home.copy()
    T[:3, 3] += T_base_cam[:3, 0] * 0.1
    robot.move(T)
    assert cell.tool_in_view("cam1", ctrl.true_T_base_flange()) is None
    img = cam.grab().image
    live = Scene(cell.scene.cameras, cell.scene.targets, [View("v", ctrl.true_T_base_flange())])
    expected = render_view(live, 0, "cam1", rng=3 + 3)  # the 4th frame (index 3) of a source seeded 3
    np.testing.assert_array_equal(img, expected)
    assert cv2.findChessboardCorners(img, (5, 4))[0]  # and that scene is the board


def test_scene_tools_from_a_layout_and_bad_tools():
    from jcalib.planning.layout import cell_layout
    from jcalib.app.simcell import CellScene, SceneTool, scene_from_layout
    from jcalib.errors import BadInputError

    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}, "cam1": {"model": "opencv5", "mount": "base"}},
        "targets": {"board": {"type": "checkerboard", "cols": 5, "rows": 4, "square": 0.02, "mount": "base"}},
        "tools": {"torch": {"observed_by": ["cam0", "cam1"]}},
    }
    layout = cell_layout(cell, image_size=(160, 120))
    cs = scene_from_layout(layout)
    tool = cs.tools["torch"]
    assert tool.observed_by == ("cam1",)  # a flange camera cannot see the tool it carries
    np.testing.assert_array_equal(tool.T_flange_tool, layout.tools["torch"])
    # the silhouette solid starts at the tip and runs along its +z for its length to the flange origin
    T_flange_solid = tool.T_flange_tool @ tool.T_tool_solid
    end = T_flange_solid[:3, 3] + tool.geometry.length_m * T_flange_solid[:3, 2]
    np.testing.assert_allclose(end, np.zeros(3), atol=1e-12)  # float64 identity
    assert set(cs.cameras) == {"cam0", "cam1"} and set(cs.targets) == {"board"}
    with pytest.raises(BadInputError, match="mount 'flange'"):
        CellScene(cs.scene, {"t": dataclasses.replace(tool, observed_by=("cam0",))})
    with pytest.raises(BadInputError, match="not in the scene"):
        CellScene(cs.scene, {"t": dataclasses.replace(tool, observed_by=("cam9",))})
    with pytest.raises(BadInputError, match="flange origin"):
        SceneTool(tool.geometry, np.eye(4), ("cam1",))
    with pytest.raises(BadInputError, match="zone_radius_m"):
        dataclasses.replace(tool, zone_radius_m=0.0)


def test_scene_frame_source_renders_through_a_zoom_lens():
    """With a zoom lens, a frame is what jcalib.sim renders with the lens's camera at the request's Zoom and
    Focus and the camera frame shifted along its axis (jcalib.sim.zoom); other settings give other images."""

    from jcalib.acquisition.cameras import FrameRequest
    from jcalib.app.simcell import scene_frame_source
    from jcalib.sim.scene import Scene, SceneCamera, View, render_view
    from jcalib.sim.scene import SceneTarget as SimTarget
    from jcalib.sim.zoom import ZoomLensModel, mount_at

    lens = ZoomLensModel(f_wide_px=130.0, image_size=(160, 120))
    board = Checkerboard(cols=5, rows=4, square=0.02)
    ctrl = SimulatedController(time_scale=0.0)
    T_home = ctrl.true_T_base_flange()
    T_flange_cam = make_pose(np.eye(3), np.array([0.0, 0.0, 0.05]))
    R = T_home[:3, :3]
    T_base_board = make_pose(R, T_home[:3, 3] + R @ np.array([-0.04, -0.03, 0.4]))
    scene = Scene(cameras={"cam0": SceneCamera(lens.camera(0.0), "flange", T_flange_cam)},
                  targets={"board": SimTarget(board, target_texture(board, 0.0005), "base", T_base_board)},
                  views=[View("s000", T_home)])
    source = scene_frame_source(scene, "cam0", ctrl.true_T_base_flange, seed=5, lens=lens)
    images = {}
    for zoom in (200.0, 800.0):
        images[zoom] = source(FrameRequest(160, 120, lens={"Zoom": zoom, "Focus": 400.0}))
        at = SceneCamera(lens.camera(zoom, 400.0), "flange", mount_at(T_flange_cam, lens, zoom, 400.0))
        want = render_view(dataclasses.replace(scene, cameras={"cam0": at}), 0, "cam0", rng=5)
        np.testing.assert_array_equal(images[zoom], want)
    assert not np.array_equal(images[200.0], images[800.0])
