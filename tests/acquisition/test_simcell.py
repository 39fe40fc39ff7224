"""A simulated cell: the frame source renders the board where OpenCV projects it for the robot's pose."""

from __future__ import annotations

import cv2
import numpy as np

from jcalib.acquisition.cameras import SimulatedCamera
from jcalib.acquisition.robots import SimulatedController, SimulatedRobot
from jcalib.acquisition.robots.poses import make_pose, rot_z
from jcalib.acquisition.simcell import SceneTarget, robot_scene_source
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

    from jcalib.acquisition.simcell import scene_frame_source

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
