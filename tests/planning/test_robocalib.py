"""RoboCalib station planning: centring (OpenCV projection through FK of the IK joints), rotation
axes, joint limits, adjustment / rejection, and hand-eye observability of the planned stations."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from jcalib.planning.layout import cell_layout
from jcalib.planning.robocalib import handeye_stations, viewset_stations
from jcalib.errors import BadInputError
from jcalib.geometry.kinematics import forward_kinematics
from jcalib.geometry.robots import robot_preset
from jcalib.init.handeye import solve_hand_eye
from jcalib.init.handeye_motion import analyse_motion, check_observable

ROBOT = "kuka_kr10_r1100_sixx"
EYE_IN_HAND = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "pinhole", "mount": "flange"}},
    "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}},
}
EYE_TO_HAND = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "pinhole", "mount": "base"}},
    "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "flange"}},
}
# IK converges to 1e-6 m / 1e-6 rad: at 0.5-0.75 m and 768 px focal length, ~0.002 px
CENTRE_TOL_PX = 0.01
ANGLE_TOL_RAD = 1e-5


@pytest.fixture(scope="module")
def cell():
    L = cell_layout(EYE_IN_HAND, robot=ROBOT)
    return {
        "layout": L,
        "kw": {
            "T_base_target": L.targets["board"].pose,
            "T_flange_cam": L.cameras["cam0"].pose,
            "centre": L.targets["board"].centre,
            "q_reference": L.home_rad,
        },
        "K": L.cameras["cam0"].K,
        "size": L.cameras["cam0"].image_size,
        "points": np.asarray(L.targets["board"].geometry.points, dtype=np.float64),
    }


@pytest.fixture(scope="module")
def handeye_plan(cell):
    return handeye_stations(ROBOT, distance_m=0.5, **cell["kw"])


def inv(T):
    return np.linalg.inv(T)


def T_cam_target_by_fk(cell, q):
    """The camera's view of the target where the robot actually goes: FK of the IK joints."""
    L = cell["layout"]
    T_base_cam = np.asarray(forward_kinematics(robot_preset(ROBOT), q)) @ L.cameras["cam0"].pose
    return inv(T_base_cam) @ L.targets["board"].pose


def project(cell, T_cam_target, p):
    rvec, _ = cv2.Rodrigues(T_cam_target[:3, :3])
    px, _ = cv2.projectPoints(np.asarray(p, dtype=np.float64).reshape(1, 3), rvec, T_cam_target[:3, 3], cell["K"], None)
    return px.reshape(2)


def check_reachable(plan, robot=ROBOT):
    dh = robot_preset(robot)
    q = plan.joints_rad
    assert np.all(q >= np.asarray(dh.lower) - 1e-12) and np.all(q <= np.asarray(dh.upper) + 1e-12)
    fk = np.asarray(forward_kinematics(dh, q))
    assert np.abs(fk[:, :3, 3] - plan.T_base_flange[:, :3, 3]).max() < 2e-6
    assert np.abs(fk[:, :3, :3] - plan.T_base_flange[:, :3, :3]).max() < 2e-6


# --------------------------------------------------------------------------------------------- hand-eye


def test_handeye_target_stays_centred(cell, handeye_plan):
    assert len(handeye_plan) == 13 and not handeye_plan.rejected and not handeye_plan.adjusted
    principal = cell["K"][:2, 2]
    for s in handeye_plan.stations:
        T_ct = T_cam_target_by_fk(cell, s.joints_rad)
        assert np.linalg.norm(project(cell, T_ct, cell["kw"]["centre"]) - principal) < CENTRE_TOL_PX, s.description
        # re-centring keeps the distance (eq. 4.7)
        p_cam = T_ct[:3, :3] @ cell["kw"]["centre"] + T_ct[:3, 3]
        assert abs(p_cam[2] - 0.5) < 1e-5


def test_handeye_rotations_are_about_the_stated_camera_axes(cell, handeye_plan):
    start = handeye_plan.stations[0]
    assert start.kind == "start"
    R0 = inv(T_cam_target_by_fk(cell, start.joints_rad))[:3, :3]  # R_target_cam of the start
    seen = set()
    for s in handeye_plan.stations[1:]:
        R = inv(T_cam_target_by_fk(cell, s.joints_rad))[:3, :3]
        rvec = cv2.Rodrigues(R0.T @ R)[0].ravel()  # camera motion in the start camera's frame
        expected = np.radians(s.used_angle_deg) * np.eye(3)["XYZ".index(s.axis)]
        assert np.linalg.norm(rvec - expected) < ANGLE_TOL_RAD, (s.description, rvec)
        seen.add(s.axis)
    assert seen == {"X", "Y", "Z"}
    assert [s.axis for s in handeye_plan.stations[1:]] == ["Z"] * 4 + ["Y"] * 4 + ["X"] * 4


def test_handeye_stations_reachable_and_observable(cell, handeye_plan):
    check_reachable(handeye_plan)
    motion = analyse_motion(handeye_plan.T_base_flange, frame="flange", rotation_noise_deg=0.05)
    assert motion.rank == 3 and not motion.planar
    check_observable(motion)  # raises NotObservableError on degenerate stations
    assert motion.axis_spread_deg > 45.0 and not motion.warnings
    # exact camera views through FK: the closed form recovers the nominal hand-eye transform
    T_ct = np.array([T_cam_target_by_fk(cell, s.joints_rad) for s in handeye_plan.stations])
    fk = np.asarray(forward_kinematics(robot_preset(ROBOT), handeye_plan.joints_rad))
    res = solve_hand_eye(fk, T_ct, method="park_martin")
    assert np.abs(res.T - cell["layout"].cameras["cam0"].pose).max() < 1e-9
    plan = handeye_plan.to_plan()
    assert [st.id for st in plan.stations] == [s.id for s in handeye_plan.stations]


def test_unreachable_rotations_are_adjusted_or_rejected(cell):
    """At 0.75 m the KR 10 cannot swing the camera by 60 deg about its X and Y axes everywhere."""
    angles = (-60.0, -30.0, 30.0, 60.0)
    plan = handeye_stations(ROBOT, distance_m=0.75, angles_y_deg=angles, angles_x_deg=angles, **cell["kw"])
    assert plan.adjusted and plan.rejected
    described = {s.description: s for s in plan.stations}
    for desc, note in plan.adjusted.items():
        s = described[desc]
        assert s.adjusted and abs(s.used_angle_deg) < abs(s.angle_deg) and np.sign(s.used_angle_deg) == np.sign(s.angle_deg)
        assert "reach or joint limits" in note
    for desc in plan.rejected:
        assert desc not in described
    assert len(plan) + len(plan.rejected) == 13
    check_reachable(plan)
    for s in plan.stations:
        T_ct = T_cam_target_by_fk(cell, s.joints_rad)
        assert np.linalg.norm(project(cell, T_ct, cell["kw"]["centre"]) - cell["K"][:2, 2]) < CENTRE_TOL_PX


def test_start_pose_is_recentred(cell, handeye_plan):
    """A jogged start pose with the target off-centre: station s000 brings it back (eqs 4.6-4.7)."""
    off = handeye_plan.stations[0].T_base_flange.copy()
    off[:3, 3] += [0.03, -0.02, 0.01]
    plan = handeye_stations(ROBOT, distance_m=0.5, start_T_base_flange=off, angles_z_deg=(90.0,),
                            angles_y_deg=(20.0,), angles_x_deg=(-20.0,), **cell["kw"])  # fmt: skip
    assert plan.stations[0].description.startswith("start: given pose")
    for s in plan.stations:
        T_ct = T_cam_target_by_fk(cell, s.joints_rad)
        assert np.linalg.norm(project(cell, T_ct, cell["kw"]["centre"]) - cell["K"][:2, 2]) < CENTRE_TOL_PX


def test_eye_to_hand_stations():
    L = cell_layout(EYE_TO_HAND, robot=ROBOT)
    T_base_cam, T_flange_target = L.cameras["cam0"].pose, L.targets["board"].pose
    c = L.targets["board"].centre
    plan = handeye_stations(ROBOT, mode="eye_to_hand", distance_m=0.5, T_base_cam=T_base_cam,
                            T_flange_target=T_flange_target, centre=c, q_reference=L.home_rad)  # fmt: skip
    assert len(plan) == 13
    check_reachable(plan)
    fk = np.asarray(forward_kinematics(robot_preset(ROBOT), plan.joints_rad))
    T_ct = inv(T_base_cam) @ fk @ T_flange_target
    K = L.cameras["cam0"].K
    R0 = inv(T_ct[0])[:3, :3]
    for s, T in zip(plan.stations, T_ct, strict=True):
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        px = cv2.projectPoints(c.reshape(1, 3), rvec, T[:3, 3], K, None)[0].reshape(2)
        assert np.linalg.norm(px - K[:2, 2]) < CENTRE_TOL_PX
        if s.axis is not None:
            rv = cv2.Rodrigues(R0.T @ inv(T)[:3, :3])[0].ravel()
            assert np.linalg.norm(rv - np.radians(s.used_angle_deg) * np.eye(3)["XYZ".index(s.axis)]) < ANGLE_TOL_RAD
    motion = analyse_motion(plan.T_base_flange, frame="base", rotation_noise_deg=0.05)
    check_observable(motion, "T_base_cam")
    assert motion.rank == 3


# --------------------------------------------------------------------------------------------- view sets


def test_viewsets_geometry(cell):
    plan = viewset_stations(ROBOT, distance_m=0.5, camera=(cell["K"], cell["size"]), target_points=cell["points"],
                            tilt_deg=30.0, heights=(0.8, 1.25), rolls_deg=(0.0, 45.0), **cell["kw"])  # fmt: skip
    kinds = [s.kind for s in plan.stations]
    assert kinds == ["frontal"] + ["tilt"] * 4 + ["origin"] + ["height"] * 4, plan.rejected
    check_reachable(plan)
    c = cell["kw"]["centre"]
    principal = cell["K"][:2, 2]
    R_frontal = inv(T_cam_target_by_fk(cell, plan.stations[0].joints_rad))[:3, :3]
    tilt_axes = set()
    for s in plan.stations:
        T_ct = T_cam_target_by_fk(cell, s.joints_rad)
        point = np.zeros(3) if s.kind == "origin" else c
        assert np.linalg.norm(project(cell, T_ct, point) - principal) < CENTRE_TOL_PX, s.description
        # the whole board in the image (OpenCV projection of every corner)
        rvec, _ = cv2.Rodrigues(T_ct[:3, :3])
        px = cv2.projectPoints(cell["points"], rvec, T_ct[:3, 3], cell["K"], None)[0].reshape(-1, 2)
        assert np.all((px >= 0) & (px <= np.array(cell["size"]) - 1))
        R_tc = inv(T_ct)[:3, :3]
        depth = (T_ct[:3, :3] @ point + T_ct[:3, 3])[2]
        if s.kind in ("frontal", "origin"):
            assert np.abs(R_tc - np.eye(3)).max() < 1e-5 and abs(depth - 0.5) < 1e-5
        elif s.kind == "tilt":
            # (4.2, 4.3): rotation about the target's x or y axis by the tilt, camera still at D
            rv = cv2.Rodrigues(R_tc)[0].ravel()
            axis = np.eye(3)["XYZ".index(s.axis)]
            assert np.linalg.norm(rv - np.radians(s.used_angle_deg) * axis) < ANGLE_TOL_RAD
            assert abs(depth - 0.5) < 1e-5
            tilt_axes.add((s.axis, np.sign(s.used_angle_deg)))
        else:
            # (4.4): frontal orientation rolled about the optical axis, at h·D
            rv = cv2.Rodrigues(R_frontal.T @ R_tc)[0].ravel()
            assert np.linalg.norm(rv - np.radians(s.used_angle_deg) * np.eye(3)[2]) < ANGLE_TOL_RAD
            h = float(s.description.split()[1])
            assert abs(depth - h * 0.5) < 1e-5
    assert tilt_axes == {("X", 1.0), ("X", -1.0), ("Y", 1.0), ("Y", -1.0)}


def test_viewsets_drop_views_that_lose_the_target(cell):
    """Far too close (0.15 m): the board overflows the image, every view is dropped with the reason."""
    plan = viewset_stations(ROBOT, distance_m=0.15, camera=(cell["K"], cell["size"]), target_points=cell["points"],
                            heights=(1.0,), rolls_deg=(0.0,), **cell["kw"])  # fmt: skip
    assert len(plan) == 0
    assert all("not entirely in the image" in why or "reach" in why for why in plan.rejected.values())
    assert any("not entirely in the image" in why for why in plan.rejected.values())


# --------------------------------------------------------------------------------------------- bad input


def test_bad_input(cell):
    kw = dict(cell["kw"])
    with pytest.raises(BadInputError, match="distance_m"):
        handeye_stations(ROBOT, distance_m=-1.0, **kw)
    with pytest.raises(BadInputError, match="mode"):
        handeye_stations(ROBOT, distance_m=0.5, mode="both", **kw)
    with pytest.raises(BadInputError, match="T_flange_cam"):
        handeye_stations(ROBOT, distance_m=0.5, T_base_target=kw["T_base_target"])
    with pytest.raises(BadInputError, match="angles_y_deg"):
        handeye_stations(ROBOT, distance_m=0.5, angles_y_deg=(0.0,), **kw)
    with pytest.raises(BadInputError, match="robot"):
        handeye_stations("no_such_robot", distance_m=0.5, **kw)
    with pytest.raises(BadInputError, match="start station is unreachable"):
        handeye_stations(ROBOT, distance_m=3.0, **kw)
