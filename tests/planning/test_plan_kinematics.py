"""``jcalib plan --kind kinematics``: joint configurations within the limits, the board in view, D-optimal
against random stations, every joint moving, the plan file and the refusals.

Small candidate sets (128 configurations, 12 stations) keep the inverse-kinematics batches cheap; the
candidate count is the same in every test so that each robot compiles its solver once."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import yaml

from jcalib.planning import kinematic_design as kd
from jcalib.planning.stations import (
    MAX_VIEW_ANGLE_DEG,
    MIN_JOINT_SPAN,
    kinematic_candidates,
    plan_kinematics,
)
from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.se3 import invert, make_pose, rotation
from jcalib.geometry.targets import Checkerboard
from jcalib.io.cell import parse_cell
from jcalib.io.plan import load_plan, plan_from_json
from jcalib.problems.kinematics import repeatability_sqrt_info, select_parameters

STATIONS, CANDIDATES = 12, 128
IMAGE_SIZE = (1600, 1200)
CAMERA_PARAMS = np.array([1400.0, 1398.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])  # as synthetic_arm_cell
K = [[1400.0, 0.0, 801.5], [0.0, 1398.0, 598.0], [0.0, 0.0, 1.0]]
BOARD = {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}
#: synthetic_arm_cell's hand-eye and board for the KUKA; the ABB uses the layout's defaults
T_FLANGE_CAM = make_pose(rotation((0.3, 0.2, 1.0), 0.4), [0.04, -0.03, 0.07])
T_BASE_BOARD = make_pose(rotation((1, 0, 0), np.pi), [0.55, -0.12, 0.05])
GROUPS = ["joint_offsets", "link_lengths", "twists"]


def arm_cell(preset: str) -> dict:
    cam = {"model": "opencv5", "mount": "flange", "intrinsics": {"K": K, "dist": CAMERA_PARAMS[4:].tolist()}}
    board = dict(BOARD)
    if preset == "kuka_kr10_r1100_sixx":
        cam["pose"], board["pose"] = T_FLANGE_CAM.tolist(), T_BASE_BOARD.tolist()
    return {"schema": "jcalib.cell/1", "cameras": {"cam0": cam}, "targets": {"board": board},
            "robot": {"kinematics": preset, "calibrate_kinematics": GROUPS}}


@pytest.fixture(scope="module", params=["kuka_kr10_r1100_sixx", "abb_irb4600_45_205"])
def planned(request):
    cell = arm_cell(request.param)
    return cell, plan_kinematics(cell, num_stations=STATIONS, num_candidates=CANDIDATES)


def test_stations_are_within_the_joint_limits_and_reach_their_poses(planned):
    cell, p = planned
    model = parse_cell(cell).robot.kinematics
    doc = json.loads(json.dumps(p.to_json()))  # what the plan file holds
    plan = plan_from_json(doc)
    assert len(plan) == STATIONS and doc["planner"]["kind"] == "kinematics"
    joints = np.array([s.joints_deg for s in plan.stations])
    q = kinematic_models.joints_from_controller(model, joints)
    margin = kd.joint_margin(model)
    assert np.all(q >= np.asarray(model.lower) + margin - 1e-9) and np.all(q <= np.asarray(model.upper) - margin + 1e-9)
    T = np.asarray(kinematic_models.forward(model, model.nominal, q))
    np.testing.assert_allclose(T, np.stack([s.T_base_flange for s in plan.stations]), atol=1e-6)  # IK to 1e-7 m/rad


def test_the_builder_keeps_the_same_parameters_and_accepts_the_stations(planned):
    """The planner's identifiable set is the builder's (same structural scan), and the builder's motion
    check passes on the planned joints (it raises when they leave a parameter undetermined)."""
    cell, p = planned
    spec = parse_cell(cell)
    model = spec.robot.kinematics
    q = kinematic_models.joints_from_controller(model, np.array([s.joints_deg for s in p.plan.stations]))
    S, _ = repeatability_sqrt_info(spec.robot)
    sel = select_parameters(model, spec.robot.calibrate_kinematics, q, S, "robot")
    assert [n for n, f in zip(model.param_names, sel.free) if f] == p.details["free_parameters"]
    assert set(sel.held) == set(p.details["held_parameters"])


def test_every_station_sees_the_whole_board_at_a_usable_angle(planned):
    cell, p = planned
    from jcalib.planning.layout import cell_layout

    layout = cell_layout(cell, robot=cell["robot"]["kinematics"])
    T_flange_cam, T_base_board = layout.cameras["cam0"].pose, layout.targets["board"].pose
    cam = camera_model_from_name("opencv5", IMAGE_SIZE, CAMERA_PARAMS)
    pts = np.asarray(Checkerboard(cols=9, rows=6, square=0.03).points)
    w, h = IMAGE_SIZE
    for s in p.plan.stations:
        T_cam_board = invert(s.T_base_flange @ T_flange_cam) @ T_base_board
        pc = pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
        assert np.all(pc[:, 2] > 0.05)
        u = np.asarray(cam.project(pc))
        assert np.all((u >= 0) & (u <= [w - 1, h - 1])), s.id
        centre = pc.mean(axis=0)
        cos_view = float(T_cam_board[:3, 2] @ centre / np.linalg.norm(centre))  # board normal vs line of sight
        assert cos_view >= np.cos(np.radians(MAX_VIEW_ANGLE_DEG)) - 1e-12, s.id


def test_every_joint_moves(planned):
    _, p = planned
    spans = p.details["joint_span"]
    assert len(spans) == 6
    for joint, span in spans.items():
        assert span["unit"] == "deg" and span["value"] >= MIN_JOINT_SPAN[0], joint


def test_d_optimal_beats_random_stations_from_the_same_candidates():
    """The planner's choice (Ds-optimal: the kinematic parameters' information with the two poses
    eliminated) against random usable stations: a larger log det of that information and of the whole
    information (parameters and poses), and smaller worst σ per group than typical random plans."""
    c = kinematic_candidates(arm_cell("kuka_kr10_r1100_sixx"), num_candidates=CANDIDATES)
    rows = c.design.normalised
    best = kd.d_optimal(rows, STATIONS, nuisance=kd.GAUGE_COLUMNS)
    opt = kd.prediction(c.model, c.design, best)
    rng = np.random.default_rng(0)
    picks = [rng.choice(len(c.q), STATIONS, replace=False) for _ in range(5)]
    rand = [kd.prediction(c.model, c.design, idx) for idx in picks]
    assert all(opt["log_det"] > r["log_det"] for r in rand)
    assert all(kd.log_det(rows, best) > kd.log_det(rows, idx) for idx in picks)
    assert opt["log_det"] == pytest.approx(kd.log_det(rows, best, nuisance=kd.GAUGE_COLUMNS))
    plain = kd.d_optimal(rows, STATIONS)  # the D-optimal plan of all columns maximises the whole information
    assert kd.log_det(rows, plain) >= kd.log_det(rows, best) - 1e-9
    for group, worst in opt["worst"].items():  # typical random plans, not the luckiest of five
        assert worst["value"] < np.median([r["worst"][group]["value"] for r in rand]), group
    assert opt["condition"] < np.median([r["condition"] for r in rand])


def positioner_table(rotate_limits_deg) -> dict:
    """A tilt-rotate positioner (dh table) whose pose a fixed 6-DOF sensor measures (no grid target)."""
    joints = [{"name": "tilt", "a_m": 0.0, "alpha_deg": -90.0, "d_m": 0.0, "theta_deg": -90.0,
               "limits_deg": [-135, 135]},
              {"name": "rotate", "a_m": 0.0, "alpha_deg": 0.0, "d_m": 0.15, "theta_deg": -90.0,
               "limits_deg": list(rotate_limits_deg)}]
    base = [[0, 0, 1, 0], [0, -1, 0, 0], [1, 0, 0, 0.65], [0, 0, 0, 1]]
    return {"schema": "jcalib.cell/1", "cameras": {"tracker": {"model": "pinhole", "mount": "base"}},
            "targets": {"part": {"type": "points", "mount": "flange"}},
            "robot": {"kinematics": {"convention": "dh", "joints": joints, "base": base},
                      "calibrate_kinematics": GROUPS}}


def test_external_axis_plans_in_joint_space_and_a_joint_that_cannot_move_is_refused():
    p = plan_kinematics(positioner_table([-360, 360]), num_stations=STATIONS, num_candidates=CANDIDATES)
    assert p.details["view_checked"] is False and p.camera is None
    joints = np.array([s.joints_deg for s in p.plan.stations])
    assert np.all(np.abs(joints[:, 0]) <= 135) and np.ptp(joints[:, 0]) > 90 and np.ptp(joints[:, 1]) > 90
    with pytest.raises(BadInputError, match=r"rotate \(.*deg\) of .* move less than"):
        plan_kinematics(positioner_table([-0.5, 0.5]), num_stations=STATIONS, num_candidates=CANDIDATES)


def test_cli_writes_a_plan_and_refuses_a_cell_without_kinematics(tmp_path, capsys):
    from jcalib.app.cli import main

    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(arm_cell("kuka_kr10_r1100_sixx")))
    with pytest.raises(SystemExit) as e:
        main(["plan", "--cell", str(tmp_path / "cell.yaml"), "--kind", "kinematics", "-o", str(tmp_path / "plan.json"),
              "--stations", str(STATIONS), "--candidates", str(CANDIDATES)])
    out = capsys.readouterr()
    assert e.value.code == 0, out.err
    assert "predicted worst σ joint_offsets (deg)" in out.out and "0.2 px corner noise" in out.out
    plan = load_plan(tmp_path / "plan.json")
    assert len(plan) == STATIONS and all(len(s.joints_deg) == 6 for s in plan.stations)
    doc = json.loads((tmp_path / "plan.json").read_text())
    assert doc["planner"]["prediction"]["worst"]["twists (deg)"]["value"] > 0

    bare = copy.deepcopy(arm_cell("kuka_kr10_r1100_sixx"))
    del bare["robot"]
    (tmp_path / "bare.yaml").write_text(yaml.safe_dump(bare))
    with pytest.raises(SystemExit) as e:
        main(["plan", "--cell", str(tmp_path / "bare.yaml"), "--kind", "kinematics", "-o", str(tmp_path / "p2.json")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "kinematics:" in err and "Traceback" not in err
    assert not (tmp_path / "p2.json").exists()


def test_plan_files_without_joints_stay_valid_and_bad_joints_are_named():
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.0, 0.8]
    old = {"schema": "jcalib.plan/1", "stations": [{"id": "s000", "T_base_flange": T.tolist()}]}
    plan = plan_from_json(old)
    assert plan.stations[0].joints_deg is None and "joints_deg" not in plan.to_json()["stations"][0]
    bad = copy.deepcopy(old)
    bad["stations"][0]["joints_deg"] = [0.0, float("nan")]
    with pytest.raises(BadInputError, match="joints_deg"):
        plan_from_json(bad)


@pytest.mark.parametrize("mount", ["flange", "base"])
def test_view_information_is_the_pixel_jacobian_of_a_flange_perturbation(mount):
    """The flange-pose information from one view equals J^T J / σ² of central differences of the pinhole
    pixels under right perturbations of the flange (eye-in-hand and eye-to-hand); 1e-6 relative: step 1e-6."""
    from jcalib.geometry.se3 import exp_so3

    rng = np.random.default_rng(3)
    pts = np.asarray(Checkerboard(cols=4, rows=3, square=0.05).points)
    Kc = np.array(K)
    T_bf = make_pose(rotation((0.2, 1.0, 0.1), 2.5), [0.6, 0.1, 0.9])
    X = make_pose(rotation(rng.normal(size=3), 0.3), [0.03, -0.02, 0.06])  # camera or target on the flange
    # the other thing in the base, so that the target sits 0.5 m in front of the camera
    if mount == "flange":
        T_base_target = T_bf @ X @ make_pose(rotation((1, 0, 0), 0.2), [-0.07, -0.05, 0.5])
    else:
        T_base_cam = T_bf @ X @ invert(make_pose(rotation((1, 0, 0), 0.2), [-0.07, -0.05, 0.5]))

    def pixels(T):
        T_ct = invert(T @ X) @ T_base_target if mount == "flange" else invert(T_base_cam) @ T @ X
        p = pts @ T_ct[:3, :3].T + T_ct[:3, 3]
        return (p[:, :2] / p[:, 2:] * [Kc[0, 0], Kc[1, 1]]).ravel(), T_ct

    _, T_ct = pixels(T_bf)
    T_cf = invert(X) if mount == "flange" else invert(T_base_cam) @ T_bf
    info = kd.view_information(T_ct[None], T_cf[None], pts, Kc, 0.2)[0]
    h, J = 1e-6, np.zeros((2 * len(pts), 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        E = [make_pose(exp_so3(s * d[:3]), s * d[3:]) for s in (1.0, -1.0)]  # first order: enough for 1e-6
        J[:, k] = (pixels(T_bf @ E[0])[0] - pixels(T_bf @ E[1])[0]) / (2 * h)
    np.testing.assert_allclose(info, J.T @ J / 0.2**2, rtol=1e-6, atol=1e-6 * np.abs(info).max())
