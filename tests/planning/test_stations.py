"""Station planners: geometric identities of each kind, reachability (FK of an IK solution), bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from jcalib.planning.layout import cell_layout
from jcalib.planning.stations import plan_cell, reachable
from jcalib.geometry.se3 import invert, rotation_angle
from jcalib.errors import BadInputError

CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}, "cam1": {"model": "pinhole", "mount": "base"}},
    "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 5, "square": 0.02, "mount": "base"}},
    "tools": {"needle": {"observed_by": ["cam1"]}},
}


@pytest.fixture(scope="module")
def layout():
    return cell_layout(CELL, image_size=(320, 240))


def _camera_poses(layout, plan):
    return [T @ layout.cameras["cam0"].pose for T in (s.T_base_flange for s in plan.stations)]


def test_layout_defaults(layout):
    # KUKA's $FLANGE points its x axis out of the flange; the tool axis is derived, not assumed
    np.testing.assert_allclose(layout.tool_axis, [1.0, 0.0, 0.0], atol=1e-12)
    assert layout.cameras["cam0"].image_size == (320, 240)
    np.testing.assert_allclose(layout.cameras["cam0"].K[:2, 2], [159.5, 119.5])
    abb = cell_layout({**CELL, "robot": {"model": "abb_irb4600_45_205"}})
    np.testing.assert_allclose(abb.tool_axis, [0.0, 0.0, 1.0], atol=1e-12)  # ABB tool0: z out of the flange
    assert abb.cameras["cam0"].image_size == (640, 480)


def test_handeye_rotations_are_recentred_on_the_target(layout):
    planned = plan_cell(layout, "handeye", num_stations=13)
    assert len(planned.plan) == 13 and not planned.dropped
    t = layout.targets["board"]
    c = t.pose[:3, :3] @ t.centre + t.pose[:3, 3]  # target centre in the base, m
    D = layout.viewing_distance("cam0", "board")
    cams = _camera_poses(layout, planned.plan)
    angles = []
    for T in cams:
        # every view looks at the target centre from distance D (identities: 1e-9 m in float64)
        v = c - T[:3, 3]
        assert np.linalg.norm(v) == pytest.approx(D, abs=1e-9)
        np.testing.assert_allclose(v / np.linalg.norm(v), T[:3, 2], atol=1e-9)
        angles.append(np.degrees(rotation_angle(cams[0][:3, :3].T @ T[:3, :3])))
    # Z group: same position as the frontal view, rotated about the optical axis up to 90 deg
    z_group = [T for T in cams[1:5]]
    for T in z_group:
        np.testing.assert_allclose(T[:3, 3], cams[0][:3, 3], atol=1e-9)
    assert max(angles[1:5]) == pytest.approx(90.0, abs=1e-6)
    assert max(angles[5:]) == pytest.approx(30.0, abs=1e-6)


def test_viewsets_origin_view_and_visibility(layout):
    planned = plan_cell(layout, "viewsets", num_stations=12)
    assert len(planned.plan) == 12
    cam, t = layout.cameras["cam0"], layout.targets["board"]
    for k, s in enumerate(planned.plan.stations):
        T_cam_target = invert(s.T_base_flange @ cam.pose) @ t.pose
        rvec, _ = cv2.Rodrigues(T_cam_target[:3, :3])
        px, _ = cv2.projectPoints(t.geometry.points, rvec, T_cam_target[:3, 3], cam.K, cam.dist)
        px = px.reshape(-1, 2)
        assert np.all((px >= 0) & (px <= [319, 239])), k  # the whole board is in the image
        if k == 1:  # the view over the target origin puts point 0 on the principal point
            np.testing.assert_allclose(px[0], cam.K[:2, 2], atol=1e-6)


def test_tcp_tip_stays_on_one_point(layout):
    planned = plan_cell(layout, "tcp", num_stations=9, amplitude_deg=25.0)
    T_flange_tool = layout.tools["needle"]
    tips = np.array([(s.T_base_flange @ T_flange_tool)[:3, 3] for s in planned.plan.stations])
    np.testing.assert_allclose(tips, np.broadcast_to(tips[0], tips.shape), atol=1e-9)
    cam1 = layout.cameras["cam1"].pose  # the tip is 0.35 m in front of the camera observing the tool
    np.testing.assert_allclose(tips[0], cam1[:3, 3] + 0.35 * cam1[:3, 2], atol=1e-9)
    R = [s.T_base_flange[:3, :3] for s in planned.plan.stations]
    axes = {tuple(np.round(np.abs(cv2.Rodrigues(Rk @ R[0].T)[0].ravel()) / max(rotation_angle(Rk @ R[0].T), 1e-12), 6))
            for Rk in R[1:]}  # fmt: skip
    assert axes == {(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)}  # two rotation axes: base x and base y
    assert max(np.degrees(rotation_angle(Rk @ R[0].T)) for Rk in R) == pytest.approx(25.0, abs=1e-6)


def test_planned_stations_are_reachable_by_forward_kinematics(layout):
    from jcalib.geometry.kinematics import forward_kinematics

    planned = plan_cell(layout, "handeye", num_stations=13)
    poses = [s.T_base_flange for s in planned.plan.stations]
    ok, q = reachable(layout, poses)
    assert ok.all()
    dh = layout.dh_robot()
    lo, hi = np.asarray(dh.lower), np.asarray(dh.upper)
    for T, qk in zip(poses, q, strict=True):
        assert np.all((qk >= lo) & (qk <= hi))
        np.testing.assert_allclose(np.asarray(forward_kinematics(dh, qk)), T, atol=1e-6)  # IK tolerance 1e-6


def test_eye_to_hand_plan_presents_the_target_to_the_camera():
    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {"cam0": {"model": "opencv5", "mount": "base"}},
        "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 5, "square": 0.02, "mount": "flange"}},
    }
    layout = cell_layout(cell, image_size=(320, 240))
    planned = plan_cell(layout, "handeye", num_stations=7)
    assert planned.camera == "cam0" and planned.target == "board" and len(planned.plan) >= 4
    cam, t = layout.cameras["cam0"], layout.targets["board"]
    D = layout.viewing_distance("cam0", "board")
    for s in planned.plan.stations:
        T_cam_target = invert(cam.pose) @ s.T_base_flange @ t.pose
        centre = T_cam_target[:3, :3] @ t.centre + T_cam_target[:3, 3]
        np.testing.assert_allclose(centre, [0.0, 0.0, D], atol=1e-9)  # target centre on the optical axis


def test_bad_requests_are_bad_input(layout):
    with pytest.raises(BadInputError, match="--kind"):
        plan_cell(layout, "stereo")
    far = {**CELL, "targets": {"board": {**CELL["targets"]["board"], "pose": np.diag([1.0, -1.0, -1.0, 1.0]).tolist()}}}
    far["targets"]["board"]["pose"][0][3] = 4.0  # 4 m away from a 1.1 m robot
    with pytest.raises(BadInputError, match="reachable"):
        plan_cell(cell_layout(far, image_size=(320, 240)), "handeye", num_stations=7)
    with pytest.raises(BadInputError, match="mount 'free'"):
        cell_layout({**CELL, "cameras": {"cam0": {"model": "opencv5"}, "cam1": CELL["cameras"]["cam1"]}})
    with pytest.raises(BadInputError, match="unknown preset"):
        cell_layout(CELL, robot="ur5")
    with pytest.raises(BadInputError, match="no tool"):
        plan_cell(cell_layout({k: v for k, v in CELL.items() if k != "tools"}, image_size=(320, 240)), "tcp")
