"""Issue 32, the solve side: unit errors in kinematic data are named before the solve (radians where degrees
are expected, with the station; a 560 m link or a base 1.5 km away at parse time), a solve that ends at its
iteration limit or with residuals far beyond the stated noise warns by name for every kind of cell (one
check, :mod:`jcalib.problems.outcome`), and a splined camera's ``fov_x_deg`` is a physical field of view."""

from __future__ import annotations

import copy
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models
from jcalib.geometry.kinematic_tables import to_spec
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.io.result import ResultFile
from jcalib.problems.graph import Graph
from jcalib.problems.outcome import NOISE_RATIO, outcome_warnings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fuzz"))
from fuzz_helpers import run_cli  # noqa: E402


@pytest.fixture(scope="module")
def arm():
    """A 6-axis arm with a flange camera: the controller's joints_deg and its T_base_flange (its FK)."""
    from jcalib.sim.kinematic_cells import synthetic_arm_cell

    cell, obs, _ = synthetic_arm_cell(1, num_stations=8, num_heldout=0, calibrate=("joint_offsets",))
    return cell, obs


def _graph(cell, obs):
    return Graph(parse_cell(cell), parse_observations(obs))


def test_recorded_joints_and_poses_that_agree_pass(arm):
    _graph(*arm)


def test_joints_in_radians_are_named_with_the_station(arm):
    """Joints written in radians, flange poses from the controller: refused before the solve, naming the
    station, the distance and the unit error (not blamed on the camera's distortion)."""
    cell, obs = arm
    obs = copy.deepcopy(obs)
    obs["stations"][3]["joints_deg"] = np.radians(obs["stations"][3]["joints_deg"]).tolist()
    with pytest.raises(BadInputError, match=r"station 's003': the flange pose recorded is [0-9.]+ m .*forward "
                                            r"kinematics of its joints.*joints in radians where degrees are expected"):
        _graph(cell, obs)


def test_joints_in_radians_without_poses_are_refused_for_a_kinematic_calibration(arm):
    cell, obs = arm
    obs = copy.deepcopy(obs)
    for s in obs["stations"]:
        s["joints_deg"] = np.radians(s["joints_deg"]).tolist()
        del s["T_base_flange"]
    with pytest.raises(BadInputError, match="joints in radians where degrees are expected"):
        _graph(cell, obs)


def test_a_tool_pose_recorded_as_the_flange_is_named(arm):
    cell, obs = arm
    obs = copy.deepcopy(obs)
    tcp = np.eye(4)
    tcp[:3, 3] = [0.0, 0.02, 0.25]
    for s in obs["stations"]:
        s["T_base_flange"] = (np.asarray(s["T_base_flange"]) @ tcp).tolist()
    with pytest.raises(BadInputError, match=r"same offset from the flange \(\[0.0, 0.02, 0.25\].*TCP"):
        _graph(cell, obs)


def test_joints_in_radians_exit_2_from_the_cli_before_the_solve(arm, tmp_path):
    cell, obs = arm
    obs = copy.deepcopy(obs)
    for s in obs["stations"]:
        s["joints_deg"] = np.radians(s["joints_deg"]).tolist()
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    (tmp_path / "obs.json").write_text(json.dumps(obs))
    code, text = run_cli("calibrate", tmp_path / "cell.json", tmp_path / "obs.json", "-o", tmp_path / "r.json")
    assert code == 2 and "joints in radians where degrees are expected" in text and "station 's" in text, text
    assert not (tmp_path / "r.json").exists()


def _kuka_cell(edit=None) -> dict:
    """The KUKA preset as a dh table in a cell, ``edit(table)`` applied."""
    model = kinematic_models.PRESETS["kuka_kr10_r1100_sixx"]()
    spec = to_spec(model, model.nominal)
    if edit is not None:
        edit(spec)
    return {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}},
            "robot": {"kinematics": spec, "calibrate_kinematics": ["joint_offsets"]}}


def _set_link(value):
    def edit(spec):
        spec["joints"][1]["a_m"] = value
    return edit


def _set_base_x(value):
    def edit(spec):
        spec["base"][0][3] = value
    return edit


@pytest.mark.parametrize(("edit", "match"), [
    (_set_link(560.0), (r"flange lies up to 5.+ m from the base .*beyond the reach limit of 5 m; its largest "
                        r"length is joint 2 \('A2'\) a_m = 560 m.*millimetres")),
    (_set_link(1e308), r"joint 2 \('A2'\): a_m: 1e\+308 m is beyond the reach limit of 1e\+06 m"),
    (_set_base_x(1500.0), r"base \(its translation\): 1500 m is beyond the reach limit"),
])
def test_kinematic_lengths_beyond_the_reach_limit_are_refused_at_parse_time(edit, match):
    with pytest.raises(BadInputError, match=match):
        parse_cell(_kuka_cell(edit), "cell.yaml")


def test_the_reach_limit_can_be_raised_for_a_larger_machine(monkeypatch):
    monkeypatch.setenv("JCALIB_MAX_REACH_M", "600")
    parse_cell(_kuka_cell(_set_link(560.0)), "cell.yaml")


def test_angles_beyond_ten_turns_and_absurd_limits_are_refused():
    def twist(spec):
        spec["joints"][0]["alpha_deg"] = 1e308

    def limits(spec):
        spec["joints"][0]["limits_deg"] = [-1e308, 1e308]

    with pytest.raises(BadInputError, match="alpha_deg: 1e\\+308 deg is beyond ±3600 deg"):
        parse_cell(_kuka_cell(twist), "cell.yaml")
    with pytest.raises(BadInputError, match="limits_deg: -1e\\+308 deg is beyond ±3600 deg"):
        parse_cell(_kuka_cell(limits), "cell.yaml")


# ------------------------------------------------------------------------------------ solve outcome


def test_outcome_check_names_the_iteration_limit_and_each_kind_far_beyond_its_noise():
    sigma = {"corner": 0.25, "tip": 0.25, "contact": 5e-5, "pose_rotation": np.radians(0.1), "pose_translation": 1e-3}
    rms = {"corner": 0.3, "tip": 10.0, "contact": 1e-3, "pose_rotation": np.radians(0.05), "pose_translation": 9.8}
    out = outcome_warnings("max_iterations", 100, rms, sigma, max_iterations=100)
    assert "iteration limit (100)" in out[0] and "--max-iterations" in out[0]
    text = "\n".join(out[1:])
    assert "tool-tip RMS 10 px" in text and "contact RMS 1 mm" in text and "translation RMS 9.8e+03 mm" in text
    assert "reprojection" not in text and "rotation RMS" not in text  # within NOISE_RATIO of their σ
    assert outcome_warnings("converged", 5, {"corner": 0.9 * NOISE_RATIO * 0.25}, sigma) == []
    few = outcome_warnings("converged", 5, {}, sigma, num_measurements=96, num_free=426)
    assert len(few) == 1 and "96 residuals" in few[0] and "(426)" in few[0]


def _camera_views(num_views: int, seed: int = 0):
    from jcalib.geometry import Checkerboard, camera_from_opencv
    from jcalib.sim.scene import project_target, random_calibration_views

    board = Checkerboard(cols=9, rows=6, square=0.03)
    size = (1280, 960)
    cam = camera_from_opencv(np.array([[900.0, 0, 640], [0, 905.0, 480], [0, 0, 1]]),
                             np.array([-0.2, 0.05, 0, 0, 0]), size)
    rng = np.random.default_rng(seed)
    stations = []
    for T in random_calibration_views(cam, board.points, 4 * num_views, rng=rng, fill=(0.25, 0.45)):
        pix, vis = project_target(cam, T, board.points)
        if vis.all():
            stations.append({"id": f"s{len(stations):02d}", "detections": [{
                "camera": "cam0", "target": "board", "point_index": list(range(len(board.points))),
                "pixels": (np.asarray(pix) + 0.2 * rng.standard_normal(np.shape(pix))).tolist()}]})
        if len(stations) == num_views:
            break
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(size)}},
           "targets": {"board": {"points": board.points.tolist()}}, "stations": stations}
    return cell, obs


def test_a_solve_at_its_iteration_limit_warns_by_name_from_the_cli(tmp_path):
    cell, obs = _camera_views(5)
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    (tmp_path / "obs.json").write_text(json.dumps(obs))
    out = tmp_path / "r.json"
    code, text = run_cli("calibrate", tmp_path / "cell.json", tmp_path / "obs.json", "-o", out, "--max-iterations", "1")
    assert code == 0, text
    assert "warning:" in text and "iteration limit (1)" in text, text
    stats = json.loads(out.read_text())["stats"]
    assert stats["status"] == "max_iterations"
    assert any("iteration limit" in w for w in stats["warnings"])


def test_a_splined_camera_from_one_view_warns_that_the_data_cannot_hold_it():
    """One view of a board: far fewer residuals than the spline's unknowns; the fit absorbs the noise and
    the focal length is far off, so the result says so by name."""
    import jcalib

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fisheye_scene import BOARD, board_views, observations, splined_truth

    from jcalib.sim.scene import project_target

    truth = splined_truth()
    rng = np.random.default_rng(0)
    (T,) = board_views(truth, BOARD, 1, seed=0)
    pix, ok = project_target(truth, T, BOARD.points)
    obs = observations([np.flatnonzero(ok)], [pix[ok] + 0.25 * rng.standard_normal((int(ok.sum()), 2))])
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "splined"}}, "targets": {"board": BOARD.to_spec()}}
    result = jcalib.calibrate(cell, obs)
    warnings = result.file.stats.get("warnings", [])
    assert any("do not outnumber the free unknowns" in w for w in warnings), warnings


@pytest.mark.parametrize("fov", [0.0, -10.0, 359.0, 1e6])
def test_splined_fov_outside_a_physical_field_of_view_is_refused(fov):
    from jcalib.io.schema.lens import LENS_DIST_NAMES

    dist = [fov] + [0.0] * (len(LENS_DIST_NAMES["splined"]) - 1)
    K = [[330.0, 0.0, 512.0], [0.0, 330.0, 384.0], [0.0, 0.0, 1.0]]
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "splined", "intrinsics": {"K": K, "dist": dist}}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    with pytest.raises(BadInputError, match="fov_x_deg"):
        parse_cell(cell, "cell.yaml")
    result = {"schema": "jcalib.result/1", "cameras": {"cam0": {"model": "splined", "image_size": [1024, 768], "K": K,
                                                                "dist": dist}}}
    with pytest.raises(BadInputError, match=r"cameras.cam0.dist: fov_x_deg .* expected a horizontal field of view"):
        ResultFile.from_dict(result, "result.json")
