"""The input layer (jcalib.io.schema) and output checks (jcalib.io.outputs): limits, messages,
the extensions in force in docs/design.md, legitimate YAML that must keep working."""

from __future__ import annotations

import copy
import json
import textwrap

import numpy as np
import pytest
import yaml

from jcalib.errors import BadInputError
from jcalib.io.cell import load_cell, parse_cell
from jcalib.io.observations import parse_observations
from jcalib.io.outputs import check_output_dir, check_outputs
from jcalib.io.schema import (
    SchemaError,
    check_name,
    read_document,
    validate_cell_document,
    validate_observations_document,
)

CELL = yaml.safe_load(textwrap.dedent("""
    schema: jcalib.cell/1
    robot: {pose_noise: {translation_m: 1e-4, rotation_deg: 0.01}}
    cameras:
      cam0: {model: opencv5, mount: flange}
      cam1: {model: opencv5, mount: base, intrinsics: {K: [[800, 0, 320], [0, 800, 240], [0, 0, 1]],
                                                        dist: [0.1, 0, 0, 0, 0]}}
    targets:
      board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: base}
    tools:
      needle: {observed_by: [cam1]}
    points:
      divot: {}
"""))

OBS = {
    "schema": "jcalib.observations/1",
    "cameras": {"cam0": {"image_size": [1600, 1200]}},
    "targets": {"board": {"points": [[0.0, 0.0, 0.0], [0.025, 0.0, 0.0]]}},
    "stations": [{"id": "s000", "T_base_flange": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0.8], [0, 0, 0, 1]],
                  "detections": [{"camera": "cam0", "target": "board", "point_index": [0, 1],
                                  "pixels": [[812.4, 600.1], [850.2, 601.0]]}]}],
}


def test_yaml_numbers_written_as_text_and_anchors_keep_working(tmp_path):
    """1e-4 is a string in YAML 1.1 (PyYAML): still a number; anchors and merge keys are fine."""
    path = tmp_path / "cell.yaml"
    path.write_text(textwrap.dedent("""
        schema: jcalib.cell/1
        robot: {pose_noise: {translation_m: 1e-4, rotation_deg: 1e-2}}
        cameras:
          cam0: &cam {model: opencv5, mount: flange}
          cam1: {<<: *cam, mount: base}
        targets:
          board: {type: checkerboard, cols: 9, rows: 6, square: 25e-3, mount: base}
    """))
    cell = load_cell(path)
    assert cell.cameras["cam1"].mount == "base" and cell.cameras["cam1"].model == "opencv5"
    np.testing.assert_array_equal(cell.robot.pose_noise_translation_m, [1e-4] * 3)
    assert cell.targets["board"].params["square"] == 0.025


def test_extensions_in_force_are_accepted():
    d = copy.deepcopy(CELL)
    d["targets"]["dots"] = {"type": "points", "mount": "base", "warp": True}
    d["targets"]["board"]["warp"] = True
    d["tools"]["needle"]["axis"] = [0, 0, 1]
    d["tools"]["pen"] = {"orientation": np.eye(3).tolist()}
    d["cameras"]["cam0"]["settings"] = {"ExposureTime": 5000, "Gain": "1.5", "PixelFormat": "Mono8", "ReverseX": True}
    d["robot"]["kinematics"] = "kuka_kr10_r1100_sixx"
    d["robot"]["calibrate_kinematics"] = ["joint_offsets", "link_lengths"]
    validate_cell_document(d, "cell.yaml")
    d["robot"]["kinematics"] = {"type": "dh", "a": [0.0] * 6}
    validate_cell_document(d, "cell.yaml")
    o = copy.deepcopy(OBS)
    o["stations"][0]["joints_deg"] = [0.0, -90.0, 90.0, 0.0, 45.0, 0.0]
    o["stations"][0]["poses"] = [{"camera": "cam0", "target": "board", "T_cam_target": np.eye(4).tolist()}]
    validate_observations_document(o, "obs.json")
    o["stations"][0]["joints_deg"] = {"r1": [0.0] * 6, "r2": [1.0] * 7}
    validate_observations_document(o, "obs.json")


@pytest.mark.parametrize("mutate, path, needle", [
    (lambda d: d["targets"]["dots"].update(cols=3), "targets.dots.cols", "observations"),
    (lambda d: d["tools"]["needle"].update(axis=[0, 0, 0]), "tools.needle.axis", "non-zero"),
    (lambda d: d["tools"]["needle"].update(orientation=[[2, 0, 0], [0, 1, 0], [0, 0, 1]]), "tools.needle.orientation",
     "rotation"),
    (lambda d: d["cameras"]["cam0"].update(settings={"ExposureTime": [1, 2]}), "cameras.cam0.settings.ExposureTime",
     "GenICam value"),
    (lambda d: d["robot"].update(kinematics=5), "robot.kinematics", "preset name or a table"),
    (lambda d: d["robot"].update(calibrate_kinematics="joint_offsets"), "robot.calibrate_kinematics", "list"),
])
def test_extensions_are_checked(mutate, path, needle):
    d = copy.deepcopy(CELL)
    d["targets"]["dots"] = {"type": "points", "mount": "base"}
    mutate(d)
    with pytest.raises(SchemaError, match=needle) as info:
        validate_cell_document(d, "cell.yaml")
    assert info.value.key_path == path


def test_messages_name_file_key_path_station_and_suggest():
    o = copy.deepcopy(OBS)
    o["stations"][0]["detections"][0]["pixels"][1][0] = float("nan")
    with pytest.raises(SchemaError) as info:
        parse_observations(o, "obs.json")
    msg = str(info.value)
    assert msg.startswith("obs.json: station 's000'.detections[0].pixels[1][0]: expected a finite number"), msg
    d = copy.deepcopy(CELL)
    d["cameras"]["cam0"]["mount"] = "flang"
    with pytest.raises(SchemaError, match="cameras.cam0.mount: got 'flang'.*did you mean 'flange'"):
        parse_cell(d, "cell.yaml")


def test_many_problems_are_counted_not_listed():
    o = copy.deepcopy(OBS)
    o["stations"][0]["detections"][0]["pixels"] = [["a", "b"]] * 1000
    o["stations"][0]["detections"][0]["point_index"] = list(range(1000))
    with pytest.raises(SchemaError, match=r"and \d+ more problems") as info:
        parse_observations(o, "obs.json")
    assert len(str(info.value)) < 1500


@pytest.mark.parametrize("text, needle", [
    ('{"a": 1, "a": 2}', "appears twice"),
    ("[" * 70 + "]" * 70, "nested"),
    ('{"x": NaN}', None),  # read: the schema names the key holding it
])
def test_json_reading_limits(tmp_path, text, needle):
    path = tmp_path / "f.json"
    path.write_text(text)
    if needle is None:
        assert np.isnan(read_document(path, "file")["x"])
        return
    with pytest.raises(BadInputError, match=needle):
        read_document(path, "file")


@pytest.mark.parametrize("text, needle", [
    ("a: 1\na: 2\n", "line 2: the key 'a' appears twice"),
    ("a: &x [1, *x]\n", "refers to the structure that contains it"),
    ("---\na: 1\n---\nb: 2\n", "not valid YAML"),
    ("a: !!python/object:os.system [ls]\n", "not valid YAML"),
    ("a: [\n", "line"),
])
def test_yaml_reading_limits(tmp_path, text, needle):
    path = tmp_path / "f.yaml"
    path.write_text(text)
    with pytest.raises(BadInputError, match=needle):
        read_document(path, "file")


def test_utf8_with_bom_is_read_and_other_encodings_are_named(tmp_path):
    path = tmp_path / "f.yaml"
    path.write_bytes("\ufeffa: 1\n".encode())
    assert read_document(path, "file") == {"a": 1}
    path.write_bytes("a: 1\nb: caf\xe9\n".encode("latin-1"))
    with pytest.raises(BadInputError, match="line 2 column 7: byte 0xe9 is not UTF-8"):
        read_document(path, "file")


@pytest.mark.parametrize("name, ok", [
    ("cam0", True), ("cam-left.1", True), ("Kamera links", True), ("caméra", True), ("", False), ("a/b", False),
    ("..", False), (".hidden", False), ("a\nb", False), ("c[/x]", False), ('a"b', False), (" cam", False),
    ("x" * 65, False), ("a\u202eb", False), ("a\\b", False),
])
def test_names(name, ok):
    if ok:
        assert check_name(name) == name
    else:
        with pytest.raises(ValueError):
            check_name(name)


def test_output_checks(tmp_path):
    inp = tmp_path / "in.json"
    inp.write_text("{}")
    check_outputs({"-o": tmp_path / "new.json"}, [inp])  # fine
    (tmp_path / "exists.json").write_text("old")
    check_outputs({"-o": tmp_path / "exists.json"}, [inp])  # overwriting an output is fine
    for out, needle in [(tmp_path, "is a directory"), (inp, "also an input"), (inp / "x.json", "is a file, not a folder"),
                        (tmp_path / "a" / "b.json", "does not exist")]:
        with pytest.raises(BadInputError, match=needle):
            check_outputs({"-o": out}, [inp])
    with pytest.raises(BadInputError, match="same file"):
        check_outputs({"-o": tmp_path / "x.json", "--export-out": tmp_path / "x.json"})
    session = tmp_path / "session"
    (session / "images").mkdir(parents=True)
    check_outputs({"-o": session / "observations.json"}, input_dirs={session: ["observations.json"]})
    with pytest.raises(BadInputError, match="inside the input folder"):
        check_outputs({"-o": session / "images" / "x.png"}, input_dirs={session: ["observations.json"]})
    check_output_dir("--out", tmp_path / "new-session")
    check_output_dir("--out", session)  # resume
    with pytest.raises(BadInputError, match="is a file"):
        check_output_dir("--out", inp)
    with pytest.raises(BadInputError, match="inside"):
        check_output_dir("--out", session, [session / "session.json"], managed=("session.json",))


def test_observation_files_of_jcalib_itself_round_trip(tmp_path):
    from jcalib.io.observations import load_observations, save_observations

    obs = parse_observations(OBS, "obs.json")
    again = load_observations(save_observations(tmp_path / "o.json", obs))
    assert json.loads((tmp_path / "o.json").read_text()) == again.to_dict() == obs.to_dict()


_ODD_NUMBERS = [True, False, None, "812.4", float("nan"), float("inf"), np.float64(812.4), np.int64(812), 2**80, 10**400, 812,
                812.4, [812.4], {"u": 1.0}]


@pytest.mark.parametrize("where", ["pixel", "row", "pixels", "index", "index list"])
@pytest.mark.parametrize("odd", range(len(_ODD_NUMBERS)), ids=[repr(v)[:12] for v in _ODD_NUMBERS])
def test_the_fast_number_check_refuses_whatever_the_schema_refuses(where, odd):
    """Detections whose numbers pass a quick check skip pydantic's per-number validation: every value the
    schema refuses must still be refused, with the schema's own message and key path."""
    from jcalib.io.schema.base import validate
    from jcalib.io.schema.observations import ObservationsDocument

    o = copy.deepcopy(OBS)
    det = o["stations"][0]["detections"][0]
    value = copy.deepcopy(_ODD_NUMBERS[odd])
    if where == "pixel":
        det["pixels"][1][0] = value
    elif where == "row":
        det["pixels"][1] = [value, 601.0, 3.0] if isinstance(value, float) else value
    elif where == "pixels":
        det["pixels"] = value
    elif where == "index":
        det["point_index"][1] = value
    else:
        det["point_index"] = value
    try:
        validate(ObservationsDocument, o, "obs.json")  # the schema alone, every number through pydantic
        schema_says = None
    except SchemaError as e:
        schema_says = str(e)
    try:
        validate_observations_document(o, "obs.json")
        ours = None
    except SchemaError as e:
        ours = str(e)
    except BadInputError:  # refused later, by the plausibility checks, never accepted where the schema refuses
        ours = "refused"
    if schema_says is not None:
        assert ours is not None, f"accepted what the schema refuses: {schema_says}"
        if ours != "refused":
            # same key path and reason (ours names the station by its id, not its index)
            assert ours.split("detections[0]", 1)[-1] == schema_says.split("detections[0]", 1)[-1], (ours, schema_says)
