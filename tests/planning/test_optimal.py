"""Goal-driven planning: the prediction against the calibration's own covariance, the selection against a
fixed plan, reach, joint limits and view angles of the chosen stations, the goal language and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

import jcalib
from jcalib.planning.layout import cell_layout
from jcalib.planning.stations import plan_cell
from jcalib.errors import BadInputError
from jcalib.geometry.kinematics import forward_kinematics
from jcalib.io.goals import parse_goal, parse_goals, sigma_from_covariance
from jcalib.io.observations import Observations
from jcalib.planning.optimal import design, select
from jcalib.problems.options import CalibrationOptions

CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv4", "mount": "flange"}},
    "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 6, "square": 0.025, "mount": "base"}},
    "robot": {},
}
GOALS = parse_goals(["T_flange_cam0:translation_mm<=0.05", "T_flange_cam0:rotation_deg<=0.005"])
CANDIDATES = 60


@pytest.fixture(scope="module")
def layout():
    return cell_layout(CELL)


@pytest.fixture(scope="module")
def planned(layout):
    return design(layout, GOALS, 8, num_candidates=CANDIDATES, seed=3, stop_when_met=False)


def test_goal_language():
    g = parse_goal("T_flange_torch:position_mm<=0.02")
    assert (g.name, g.measures, g.limit, g.unit) == ("T_flange_torch", "translation", 0.02, "mm")
    for bad, words in [("T_flange_cam0:translation<=1", "unknown quantity"), ("cam0 projection_px 0.1", "not a goal"),
                       ("T_flange_cam0:projection_px<=0.1", "camera's goal"), ("cam0:rotation_deg<=1", "transform's"),
                       ("T_flange_cam0:rotation_deg<=0", "positive"), ("T_flange_cam0:rotation_deg<=nan", "positive")]:
        with pytest.raises(BadInputError, match=words):
            parse_goal(bad)
    with pytest.raises(BadInputError, match="two limits"):
        parse_goals(["T_flange_cam0:position_mm<=1", "T_flange_cam0:translation_mm<=2"])
    # worst direction: the largest eigenvalue of the block, in the goal's unit
    cov = np.zeros((6, 6))
    cov[3:, 3:] = np.diag([1e-8, 4e-8, 9e-8])
    cov[:3, :3] = np.diag([1e-6, 0.0, 0.0])
    assert sigma_from_covariance(parse_goal("T_a_b:translation_mm<=1"), cov) == pytest.approx(0.3)
    assert sigma_from_covariance(parse_goal("T_a_b:rotation_deg<=1"), cov) == pytest.approx(np.degrees(1e-3))


def test_prediction_equals_the_calibrations_covariance(layout, planned):
    """The sum of the stations' predicted information, inverted, is the covariance the calibration of exactly
    those (noise-free, predicted) stations reports with stated noise: two different code paths (one-station
    problems summed vs the whole problem solved), the same first-order model."""
    d, c, pred = planned
    stations = tuple(pred.station(c.T_base_flange[k], c.pair[k], f"s{i}") for i, k in enumerate(d.chosen))
    obs = Observations(dict(pred.sizes), dict(pred.targets), stations)
    result = jcalib.calibrate(layout.cell, obs, CalibrationOptions(noise="stated"))
    cov = result.covariance("T_flange_cam0")
    achieved = [sigma_from_covariance(g, cov) for g in GOALS]
    # the design's information includes a ridge of 1e-8 of a station's: the prediction is that close
    np.testing.assert_allclose(d.sigma, achieved, rtol=2e-3)
    assert all(s > 0 for s in achieved)


def test_optimal_beats_the_fixed_handeye_plan_at_equal_count(layout, planned):
    d, c, pred = planned
    fixed = plan_cell(layout, "handeye", num_stations=len(d.chosen))
    stations = [s.T_base_flange for s in fixed.plan.stations]
    from jcalib.planning.candidates import Candidates

    other = Candidates(np.stack(stations), np.zeros((len(stations), 6)), [("cam0", "board")] * len(stations))
    infos = pred.informations(other)
    prior = pred.prior_information(other)
    mine = select(pred, infos, prior, len(stations), stop_when_met=False, exchange=False)  # all of them
    assert sorted(mine.chosen) == list(range(len(stations)))
    assert np.all(d.sigma < mine.sigma), (d.sigma, mine.sigma)


def test_stations_are_reachable_within_limits_and_not_edge_on(layout, planned):
    d, c, _ = planned
    robot = layout.dh_robot()
    q = c.joints_rad[d.chosen]
    assert np.all(q >= np.asarray(robot.lower) - 1e-9) and np.all(q <= np.asarray(robot.upper) + 1e-9)
    T_fk = np.asarray(forward_kinematics(robot, q))
    np.testing.assert_allclose(T_fk, c.T_base_flange[d.chosen], atol=2e-6)
    board = layout.targets["board"]
    for T in c.T_base_flange[d.chosen]:
        T_base_cam = T @ layout.cameras["cam0"].pose
        centre = board.pose[:3, :3] @ board.centre + board.pose[:3, 3]
        sight = (centre - T_base_cam[:3, 3]) / np.linalg.norm(centre - T_base_cam[:3, 3])
        # the printed side faces the camera within 60 deg of the target normal (target z points into the board)
        assert float(sight @ board.pose[:3, 2]) > np.cos(np.radians(60.0)) - 1e-9


def test_stops_when_the_goals_are_met(layout):
    loose = parse_goals(["T_flange_cam0:translation_mm<=2", "T_flange_cam0:rotation_deg<=0.5"])
    d, _, _ = design(layout, loose, 15, num_candidates=CANDIDATES, seed=3, refine=False)
    assert d.met and len(d.chosen) < 15
    assert np.all(d.history[-1] <= [2, 0.5]) and not np.all(d.history[-2] <= [2, 0.5])


def test_goal_on_something_not_estimated_is_refused(layout):
    with pytest.raises(BadInputError, match="T_flange_cam1 is not estimated"):
        design(layout, parse_goals(["T_flange_cam1:translation_mm<=1"]), 5, num_candidates=CANDIDATES)
    with pytest.raises(BadInputError, match="no camera 'cam9'"):
        design(layout, parse_goals(["cam9:projection_px<=1"]), 5, num_candidates=CANDIDATES)


def test_cli_plan_optimal(tmp_path, run_cli):
    import yaml

    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump({**CELL, "goals": ["T_flange_cam0:translation_mm<=0.5"]}))
    out = tmp_path / "plan.json"
    code, text = run_cli("plan", "--cell", cell, "--kind", "optimal", "-o", out, "--candidates", CANDIDATES,
                         "--max-stations", 6)
    assert code == 0, text
    plan = json.loads(out.read_text())
    assert plan["planner"]["kind"] == "optimal" and 1 <= len(plan["stations"]) <= 6
    assert plan["planner"]["goals"] == ["T_flange_cam0:translation_mm<=0.5"]
    assert "predicted σ after each station" in text
    # options the kind does not use are refused, naming them
    for extra, words in [(["--goal", "cam0:projection_px<=1", "--kind", "handeye"], "--goal: not used by --kind handeye"),
                         (["--stations", "5", "--kind", "optimal"], "--max-stations"),
                         (["--kind", "optimal", "--goal", "T_flange_cam0:roll<=1"], "unknown quantity")]:
        code, text = run_cli("plan", "--cell", cell, "-o", tmp_path / "p2.json", *extra)
        assert code == 2 and words in text, text


def test_tool_tip_plan_and_projection_goal():
    """A TCP seen by a fixed camera (no target in the cell) and the camera's projection σ as goals: the prediction
    is again the calibration's own covariance."""
    K = [[768.0, 0.0, 319.5], [0.0, 768.0, 239.5], [0.0, 0.0, 1.0]]
    cell = {"schema": "jcalib.cell/1", "targets": {},
            "cameras": {"cam1": {"model": "pinhole", "mount": "base", "intrinsics": {"K": K, "dist": []}}},
            "tools": {"torch": {"observed_by": ["cam1"], "axis": [1.0, 0.0, 0.0]}}, "robot": {}}
    # a calibration starts a TCP from tips only where the camera's pose is known roughly: give the default one
    cell["cameras"]["cam1"]["pose"] = cell_layout(cell).cameras["cam1"].pose.tolist()
    layout = cell_layout(cell)
    goals = parse_goals(["T_flange_torch:position_mm<=0.05", "cam1:projection_px<=0.2"])
    d, c, pred = design(layout, goals, 10, num_candidates=CANDIDATES, seed=1, stop_when_met=False, refine=False)
    assert len(d.chosen) == 10 and {c.pair[k] for k in d.chosen} == {("cam1", "torch")}
    stations = tuple(pred.station(c.T_base_flange[k], c.pair[k], f"s{i}") for i, k in enumerate(d.chosen))
    result = jcalib.calibrate(layout.cell, Observations(dict(pred.sizes), {}, stations),
                              CalibrationOptions(noise="stated"))
    from jcalib.problems.taskspace import projection_jacobian, unproject
    from jcalib.io.goals import projection_grid

    rays, ok = unproject(pred.cameras["cam1"], projection_grid(pred.sizes["cam1"]))
    J = projection_jacobian(pred.cameras["cam1"], rays[ok])
    achieved = [sigma_from_covariance(goals[0], result.covariance("T_flange_torch")),
                sigma_from_covariance(goals[1], result.covariance("cam1"), J)]
    np.testing.assert_allclose(d.sigma, achieved, rtol=2e-3)


def test_kinematic_cell_plans_record_joints(layout):
    cell = {**CELL, "robot": {"model": "kuka_kr10_r1100_sixx", "kinematics": "kuka_kr10_r1100_sixx",
                              "calibrate_kinematics": ["joint_offsets"]}}
    from jcalib.planning.optimal import plan_optimal

    planned = plan_optimal(cell_layout(cell), GOALS[:1], 12, num_candidates=CANDIDATES, seed=2, refine=False)
    assert all(s.joints_deg is not None and len(s.joints_deg) == 6 for s in planned.plan.stations)
    robot = layout.dh_robot()
    for s in planned.plan.stations:  # the nominal model's flange at the recorded joints (KUKA: degrees = model)
        q = np.radians(s.joints_deg)
        np.testing.assert_allclose(np.asarray(forward_kinematics(robot, q)), s.T_base_flange, atol=1e-6)


def test_capture_needs_a_plan_or_goals(tmp_path, run_cli):
    """Neither --plan nor --goal nor the cell's goals: refused before anything connects (exit 2)."""
    import yaml

    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump(CELL))
    for extra in ([], ["--cell", cell]):
        code, text = run_cli("capture", "--robot", "kuka://127.0.0.1:9", "--camera", "cam0=gige://127.0.0.1",
                             "--out", tmp_path / "session", *extra)
        assert code == 2 and "give a station plan (--plan PLAN) or accuracy goals" in text, text


def test_shaft_points_lie_between_tip_and_flange():
    from jcalib.geometry.se3 import make_pose, rot_x, shaft_points

    for R in (np.eye(3), rot_x(np.pi)):  # the TCP's z pointing away from the flange, or towards it
        T_flange_tool = make_pose(R, np.array([0.0, 0.0, 0.15]))
        for p in shaft_points(T_flange_tool):
            p_flange = T_flange_tool[:3, :3] @ p + T_flange_tool[:3, 3]
            assert 0.10 < p_flange[2] < 0.15  # on the shaft: between the flange (z 0) and the tip (z 0.15)


def test_a_target_no_station_observes_is_named():
    """A flange target in the cell that no station shows: not observable, named (was a bare KeyError)."""
    from jcalib.errors import NotObservableError
    from jcalib.planning.predict import Predictor

    cell = {**CELL, "targets": {**CELL["targets"], "plate": {"type": "checkerboard", "cols": 5, "rows": 4,
                                                             "square": 0.02, "mount": "flange"}}}
    layout = cell_layout(cell)
    pred = Predictor(layout, ())
    fixed = plan_cell(layout, "handeye", camera="cam0", target="board")
    stations = tuple(pred.station(s.T_base_flange, ("cam0", "board"), s.id) for s in fixed.plan.stations)
    with pytest.raises(NotObservableError, match="target 'plate' .* no station observes it") as err:
        jcalib.calibrate(layout.cell, Observations(dict(pred.sizes), dict(pred.targets), stations))
    assert err.value.unknowns == ["T_flange_plate"]
