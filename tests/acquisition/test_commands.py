"""End to end on loopback: a simulated cell (KUKA server + fake GigE camera rendering the scene at the
robot's pose), captured through the real clients by URL, the way ``jcalib simulate`` / ``capture`` run."""

from __future__ import annotations

import socket
import threading

import cv2
import numpy as np
import pytest

from jcalib.io.plan import make_plan, save_plan
from jcalib.io.session import read_session
from jcalib.app.simulate import run_simulated_cell
from jcalib.workflow.capture import run_capture
from jcalib.workflow.devices import open_camera, open_robot
from jcalib.acquisition.robots import SixAxisArm
from jcalib.geometry.se3 import make_pose
from jcalib.errors import BadInputError


def test_device_urls_are_checked():
    with pytest.raises(BadInputError, match="kuka://"):
        open_robot("fanuc://127.0.0.1")
    with pytest.raises(BadInputError, match="port must be a number"):
        open_robot("abb://127.0.0.1:x")
    with pytest.raises(BadInputError, match="gige://"):
        open_camera("cam0", "127.0.0.1")


def test_simulated_cell_captured_through_kuka_and_gige(aravis, tmp_path):
    from jcalib.geometry.cameras.factory import camera_from_opencv
    from jcalib.geometry.targets import Checkerboard
    from jcalib.sim.scene import Scene, SceneCamera, SceneTarget, View
    from jcalib.sim.textures import target_texture

    K = np.array([[300.0, 0.0, 79.5], [0.0, 300.0, 59.5], [0.0, 0.0, 1.0]])
    board = Checkerboard(cols=5, rows=4, square=0.02)
    T_home = SixAxisArm().forward(SixAxisArm().home_rad)
    R = T_home[:3, :3]
    T_base_board = make_pose(R, T_home[:3, 3] + R @ np.array([-0.04, -0.03, 0.45]))
    scene = Scene(
        cameras={"cam0": SceneCamera(camera_from_opencv(K, np.zeros(5), (160, 120)), "flange", make_pose(np.eye(3), np.array([0.0, 0.0, 0.05])))},
        targets={"board": SceneTarget(board, target_texture(board, 0.0005), "base", T_base_board)},
        views=[View("s000", T_home)],
    )
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    stop, ready = threading.Event(), threading.Event()
    sim = threading.Thread(
        target=run_simulated_cell, args=(scene,),
        kwargs=dict(robot_protocol="kuka", robot_port=port, camera_addresses={"cam0": "127.0.0.1"},
                    time_scale=0.0, stop=stop, ready=ready),
        daemon=True,
    )  # fmt: skip
    sim.start()
    try:
        assert ready.wait(60)
        poses = []
        for dx, dy in ((0.0, 0.0), (0.01, -0.01), (-0.01, 0.01)):
            T = T_home.copy()
            T[:3, 3] += [dx, dy, 0.0]
            poses.append(T)
        save_plan(make_plan(poses), tmp_path / "plan.json")
        res = run_capture(
            robot_url=f"kuka://127.0.0.1:{port}", camera_urls={"cam0": "gige://127.0.0.1"},
            plan_path=tmp_path / "plan.json", out=tmp_path / "session", progress=False, packet_size=1400,
        )  # fmt: skip
        assert res.captured == ["s000", "s001", "s002"]
    finally:
        stop.set()
        sim.join(30)
    meta, stations = read_session(tmp_path / "session")
    assert meta["devices"]["robot"]["address"] == f"kuka://127.0.0.1:{port}"
    for st in stations:
        img = cv2.imread(str(tmp_path / "session" / st["images"]["cam0"]), cv2.IMREAD_UNCHANGED)
        found, _ = cv2.findChessboardCorners(img, (5, 4))
        assert found, st["id"]
