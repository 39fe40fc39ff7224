"""Cell spec and observations: contracts of docs/design.md, validation messages, atomic writes."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.io.atomic import append_line_durable, write_json_atomic
from jcalib.io.cell import cell_to_dict, load_cell, parse_cell
from jcalib.io.observations import load_observations, parse_observations, save_observations

DESIGN_CELL = textwrap.dedent(
    """
    schema: jcalib.cell/1
    cameras:
      cam0: {model: opencv5, mount: flange}
      cam1: {model: opencv5, mount: base}
    targets:
      board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: base}
    tools:
      needle: {observed_by: [cam1]}
    points:
      divot: {}
    robot:
      pose_noise: {translation_m: 0.0001, rotation_deg: 0.01}
    fixed: []
    """
)

DESIGN_OBS = {
    "schema": "jcalib.observations/1",
    "cameras": {"cam0": {"image_size": [1600, 1200]}},
    "targets": {"board": {"points": [[0.0, 0.0, 0.0], [0.025, 0.0, 0.0]]}},
    "stations": [
        {
            "id": "s000",
            "T_base_flange": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0.8], [0, 0, 0, 1]],
            "detections": [
                {"camera": "cam0", "target": "board", "point_index": [0, 1],
                 "pixels": [[812.4, 600.1], [850.2, 601.0]]}
            ],
        }
    ],
}


def test_design_cell_example_parses_and_round_trips(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(DESIGN_CELL)
    cell = load_cell(path)
    assert set(cell.cameras) == {"cam0", "cam1"}
    assert cell.cameras["cam0"].mount == "flange"
    assert cell.targets["board"].params == {"cols": 9, "rows": 6, "square": 0.025}
    assert cell.tools["needle"].observed_by == ("cam1",)
    np.testing.assert_array_equal(cell.robot.pose_noise_translation_m, [1e-4] * 3)
    again = parse_cell(cell_to_dict(cell))
    assert cell_to_dict(again) == cell_to_dict(cell)


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda d: d.update(schema="jcalib.cell/9"), "schema"),
        (lambda d: d["cameras"]["cam0"].update(model="opencv6"), "opencv6"),
        (lambda d: d["cameras"]["cam0"].update(mount="wall"), "wall"),
        (lambda d: d["targets"]["board"].update(type="dots"), "dots"),
        (lambda d: d["targets"]["board"].update(cols=0), "board"),
        (lambda d: d["tools"]["needle"].update(observed_by=["cam7"]), "cam7"),
        (lambda d: d["cameras"]["cam0"].update(colour="red"), "colour"),
        (lambda d: d["cameras"]["cam1"].update(pose=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
         "rotation"),
    ],
)
def test_bad_cell_names_the_problem(mutate, needle):
    import yaml

    data = yaml.safe_load(DESIGN_CELL)
    mutate(data)
    with pytest.raises(BadInputError, match=needle):
        parse_cell(data, source="cell.yaml")


def test_invalid_yaml_reports_line(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text("schema: jcalib.cell/1\ncameras: {cam0: [\n")
    with pytest.raises(BadInputError, match="line"):
        load_cell(path)


def test_design_observations_example_round_trips(tmp_path):
    obs = parse_observations(DESIGN_OBS)
    assert obs.cameras == {"cam0": (1600, 1200)}
    assert obs.stations[0].detections[0].point_index.tolist() == [0, 1]
    path = save_observations(tmp_path / "obs.json", obs)
    again = load_observations(path)
    assert json.loads(path.read_text()) == DESIGN_OBS | {"schema": "jcalib.observations/1"}
    np.testing.assert_array_equal(again.stations[0].detections[0].pixels, obs.stations[0].detections[0].pixels)


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda d: d["stations"][0]["detections"][0]["pixels"].__setitem__(0, [float("nan"), 1.0]), "NaN"),
        (lambda d: d["stations"][0]["detections"][0].update(point_index=[0, 5]), "out of range"),
        (lambda d: d["stations"][0]["detections"][0].update(point_index=[0]), "pair one to one"),
        (lambda d: d["stations"][0]["detections"][0].update(camera="cam9"), "cam9"),
        (lambda d: d["stations"][0].update(T_base_flange=[[1, 0, 0], [0, 1, 0]]), "T_base_flange"),
        (lambda d: d["stations"].append(dict(d["stations"][0])), "duplicate"),
    ],
)
def test_bad_observations_name_station(mutate, needle):
    data = json.loads(json.dumps(DESIGN_OBS))
    mutate(data)
    with pytest.raises(BadInputError, match=needle) as info:
        parse_observations(data, source="obs.json")
    assert "obs.json" in str(info.value)


def test_atomic_write_survives_kill_mid_write(tmp_path):
    """A writer killed at any point leaves either the old or the new complete file."""
    target = tmp_path / "result.json"
    write_json_atomic(target, {"version": "old"})
    code = (
        "import os, sys\n"
        "from jcalib.io import atomic\n"
        "real = os.replace\n"
        "def die(*a, **k): os._exit(9)\n"
        "os.replace = die\n"
        f"atomic.write_json_atomic({str(target)!r}, {{'version': 'new', 'x': list(range(100000))}})\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True)
    assert proc.returncode == 9
    assert json.loads(target.read_text()) == {"version": "old"}
    write_json_atomic(target, {"version": "new"})
    assert json.loads(target.read_text()) == {"version": "new"}
    leftovers = [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]
    assert len(leftovers) == 1  # the killed writer's temp file, never mistaken for the result


def test_append_line_durable(tmp_path):
    path = tmp_path / "stations.jsonl"
    append_line_durable(path, '{"id": "s000"}')
    append_line_durable(path, '{"id": "s001"}')
    assert [json.loads(line)["id"] for line in path.read_text().splitlines()] == ["s000", "s001"]
    with pytest.raises(ValueError):
        append_line_durable(path, "two\nlines")


# ------------------------------------------------------------------------------------ several robots

TWO_ROBOT_CELL = textwrap.dedent(
    """
    schema: jcalib.cell/1
    robots:
      r1: {pose_noise: {translation_m: 0.0001, rotation_deg: 0.01}}
      r2: {pose_noise: {translation_m: 0.0002, rotation_deg: 0.02},
           base: [[0, -1, 0, 1.5], [1, 0, 0, 0.2], [0, 0, 1, 0], [0, 0, 0, 1]]}
    cameras:
      cam0: {model: opencv5, mount: flange, robot: r1}
      cam1: {model: opencv5, mount: world}
    targets:
      board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: world}
      plate: {type: checkerboard, cols: 7, rows: 5, square: 0.03, mount: flange, robot: r2}
    tools:
      gripper: {robot: r2, observed_by: [cam1]}
    fixed: [T_world_r2]
    """
)


def test_two_robot_cell_parses_and_round_trips(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(TWO_ROBOT_CELL)
    cell = load_cell(path)
    assert cell.multi_robot and cell.frame == "world" and cell.robot is None
    assert list(cell.robots) == ["r1", "r2"]
    assert cell.cameras["cam0"].robot == "r1" and cell.cameras["cam1"].robot is None
    assert cell.targets["plate"].robot == "r2" and "robot" not in cell.targets["plate"].params
    assert cell.tools["gripper"].robot == "r2"
    np.testing.assert_array_equal(cell.robots["r2"].base[:3, 3], [1.5, 0.2, 0.0])
    np.testing.assert_array_equal(cell.robots["r2"].pose_noise_rotation_deg, [0.02] * 3)
    again = parse_cell(cell_to_dict(cell))
    assert cell_to_dict(again) == cell_to_dict(cell)
    assert "robot" not in cell_to_dict(cell) and cell_to_dict(cell)["robots"]["r2"]["base"][0] == [0, -1, 0, 1.5]


def test_one_entry_robots_is_the_one_robot_cell():
    """A one-entry robots: names the one robot; the cell stays in its base frame (as robot:)."""
    import yaml

    data = yaml.safe_load(DESIGN_CELL)
    data["robots"] = {"arm": data.pop("robot")}
    cell = parse_cell(data)
    assert not cell.multi_robot and cell.frame == "base"
    assert cell.robot is cell.robots["arm"]
    assert cell.cameras["cam0"].robot == "arm" and cell.tools["needle"].robot == "arm"  # the default
    np.testing.assert_array_equal(cell.robot.pose_noise_translation_m, [1e-4] * 3)
    assert cell_to_dict(parse_cell(cell_to_dict(cell))) == cell_to_dict(cell)


@pytest.mark.parametrize(
    "mutate, needle",
    [
        (lambda d: d["cameras"]["cam0"].update(robot="r9"), r"cameras.cam0.robot.*'r9'"),
        (lambda d: d["cameras"]["cam1"].update(mount="base"), r"cameras.cam1.mount.*ambiguous.*mount: world"),
        (lambda d: d["targets"]["board"].update(mount="base"), r"targets.board.mount.*world"),
        (lambda d: d.update(robot={"pose_noise": None}), r"both 'robot' and 'robots'"),
        (lambda d: d["cameras"]["cam0"].pop("robot"), r"cameras.cam0.robot.*several robots"),
        (lambda d: d["tools"]["gripper"].pop("robot"), r"tools.gripper.robot"),
        (lambda d: d["cameras"]["cam1"].update(robot="r1"), r"cameras.cam1.robot.*flange"),
        (lambda d: d["robots"].update(world={}), r"robot name 'world'"),
        (lambda d: d["robots"].update(cam1={}), r"robots.cam1.*name of a camera"),
        (lambda d: d["robots"]["r2"].update(base=[[1, 0], [0, 1]]), r"robots.r2.base"),
        (lambda d: d["robots"]["r1"].update(reach=2.0), r"robots.r1.*reach"),
    ],
)
def test_bad_two_robot_cell_names_the_key(mutate, needle):
    import yaml

    data = yaml.safe_load(TWO_ROBOT_CELL)
    mutate(data)
    with pytest.raises(BadInputError, match=needle):
        parse_cell(data, source="cell.yaml")


def test_world_mount_and_base_need_several_robots():
    import yaml

    data = yaml.safe_load(DESIGN_CELL)
    data["cameras"]["cam1"]["mount"] = "world"
    with pytest.raises(BadInputError, match=r"cameras.cam1.mount.*use mount: base"):
        parse_cell(data)
    data = yaml.safe_load(DESIGN_CELL)
    data["robots"] = {"r1": dict(data.pop("robot"), base=np.eye(4).tolist())}
    with pytest.raises(BadInputError, match=r"robots.r1.base.*one-robot"):
        parse_cell(data)
    data = yaml.safe_load(DESIGN_CELL)
    data["cameras"]["cam0"]["robot"] = "r1"  # robot: names a robot, the cell's robot: has no name
    with pytest.raises(BadInputError, match=r"cameras.cam0.robot.*no named robots"):
        parse_cell(data)


def test_flange_poses_round_trip_and_are_validated(tmp_path):
    data = json.loads(json.dumps(DESIGN_OBS))
    T = data["stations"][0].pop("T_base_flange")
    data["stations"][0]["flange_poses"] = {"r1": T, "r2": np.eye(4).tolist()}
    obs = parse_observations(data)
    assert obs.stations[0].T_base_flange is None
    np.testing.assert_array_equal(obs.stations[0].flange_poses["r1"], np.asarray(T, np.float64))
    again = load_observations(save_observations(tmp_path / "obs.json", obs))
    assert again.to_dict() == obs.to_dict() == data | {"schema": "jcalib.observations/1"}
    for bad, needle in [({"r1": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, r"flange_poses.r1.*rotation"),
                        ({"r1": [[1, 0, 0], [0, 1, 0]]}, r"flange_poses.r1"),
                        ({"r1": [[float("nan")] * 4] * 4}, r"flange_poses.r1.*NaN"),
                        ([T], r"flange_poses.*mapping")]:
        d = json.loads(json.dumps(data))
        d["stations"][0]["flange_poses"] = bad
        with pytest.raises(BadInputError, match=needle) as info:
            parse_observations(d, source="obs.json")
        assert "station 's000'" in str(info.value)
    d = json.loads(json.dumps(data))
    d["stations"][0]["T_base_flange"] = T
    with pytest.raises(BadInputError, match="both T_base_flange .* and flange_poses"):
        parse_observations(d)
