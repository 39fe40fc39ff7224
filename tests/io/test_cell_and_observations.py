"""Cell spec and observations: contracts of DESIGN.md, validation messages, atomic writes."""

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
