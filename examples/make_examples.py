"""Write every example's data from a simulation: ``cell.yaml``, ``observations.json`` and ``expected.json``.

Run from the repository root (``.venv/bin/python examples/make_examples.py``); each example's README.md is
written by hand and names the commands. ``expected.json`` holds the simulation's *truth* (never jcalib's
output) and how far a result may be from it, in units of the result's own σ::

    {"result": "result.json",
     "max_sigma": 5.0,
     "transforms": {"T_flange_cam0": [[4x4]]},          # per tangent component rx ry rz tx ty tz
     "cameras": {"cam0": {"fx": 1400.0, ...}},           # per intrinsic
     "points": {"divot": [x, y, z]},                     # per coordinate
     "kinematics": {"robot": {"tilt.a": 0.0008, ...}}}   # per calibrated parameter

``tests/test_examples.py`` runs the commands and checks a result against these values. The data are small
on purpose (few stations, small boards): the test runs every example in the default suite.
"""

from __future__ import annotations

import copy
import json
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent
BOARD = {"type": "checkerboard", "cols": 7, "rows": 5, "square": 0.03}
MAX_SIGMA = 5.0
#: Every intrinsic of an opencv5 camera: held at the (known) true values.
KNOWN = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]

#: name -> (study scenario without its schema, what the expected values list)
SCENARIOS = {
    "camera": ({"cell": {"cameras": {"cam0": {"model": "opencv5"}}, "targets": {"board": {**BOARD, "mount": "free"}}},
                "stations": {"strategy": "random", "camera": "cam0", "count": 10, "fill": [0.3, 0.6]}},
               {"cameras": ["cam0"]}),
    "stereo": ({"cell": {"cameras": {"left": {"model": "opencv5"}, "right": {"model": "opencv5"}},
                         "targets": {"board": {**BOARD, "mount": "free"}}},
                "truth": {"poses": {"right": {"pose": [[1, 0, 0, 0.12], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}},
                "stations": {"strategy": "random", "count": 10, "fill": [0.3, 0.5]}},
               {"cameras": ["left", "right"], "transforms": ["T_left_right"]}),
    "eye-in-hand": ({"cell": {"cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
                              "targets": {"board": {**BOARD, "mount": "base"}},
                              "robot": {"pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}},
                     "stations": {"strategy": "random", "count": 10}},
                    {"cameras": ["cam0"], "transforms": ["T_flange_cam0", "T_base_board"]}),
    "eye-to-hand": ({"cell": {"cameras": {"cam0": {"model": "opencv5", "mount": "base"}},
                              "targets": {"board": {**BOARD, "mount": "flange"}},
                              "robot": {"pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}},
                     "stations": {"strategy": "random", "count": 10}},
                    {"cameras": ["cam0"], "transforms": ["T_base_cam0", "T_flange_board"]}),
    "camera-tcp": ({"cell": {"cameras": {"cam1": {"model": "pinhole", "mount": "base", "fix": ["fx", "fy", "cx", "cy"]}},
                             "tools": {"needle": {"observed_by": ["cam1"]}}, "robot": {}, "fixed": ["cam1"]},
                    "truth": {"poses": {"needle": {"position": [0.01, -0.02, 0.18], "rotation_deg": 10}}},
                    "stations": {"strategy": "tcp_spread", "count": 10, "axis_points": 4}},
                   {"transforms": ["T_flange_needle"]}),
    "pivot-tracker": ({"cell": {"cameras": {}, "tools": {"pointer": {}}, "points": {"divot": {}}, "robot": {}},
                       "stations": {"strategy": "pivot", "tool": "pointer", "point": "divot", "count": 8}},
                      {"transforms": ["T_flange_pointer"], "points": ["divot"]}),
    "two-robots": ({"cell": {"robots": {"r1": {}, "r2": {}},
                             "cameras": {"cam0": {"model": "opencv5", "mount": "flange", "robot": "r1"},
                                         "cam1": {"model": "opencv5", "mount": "world", "fix": KNOWN}},
                             "targets": {"board": {**BOARD, "mount": "world"},
                                         "plate": {**BOARD, "mount": "flange", "robot": "r2"}}},
                    "stations": [{"strategy": "random", "camera": "cam0", "target": "board", "count": 8},
                                 {"strategy": "random", "camera": "cam1", "target": "plate", "count": 8},
                                 {"strategy": "random", "camera": "cam0", "target": "plate", "count": 5}]},
                   {"cameras": ["cam0"], "transforms": ["T_flange_cam0", "T_world_board", "T_flange_plate",
                                                        "T_world_cam1", "T_world_r2"]}),
    "tracker-handeye": ({"cell": {"cameras": {"tracker": {"model": "pinhole", "mount": "base"}},
                                  "targets": {"marker": {"type": "points", "mount": "flange"}}, "robot": {}},
                         "truth": {"targets": {"marker": {"points": (0.05 * np.eye(3, 6).T).tolist()}}},
                         "noise": {"pose_rotation_deg": 0.02, "pose_translation_m": 2e-4},
                         "stations": {"strategy": "robocalib_handeye", "camera": "tracker", "target": "marker",
                                      "measure": "poses", "distance_m": 2.0}},
                        {"transforms": ["T_base_tracker", "T_flange_marker"]}),
}


def _as_sensor(cell: dict, obs: dict, name: str) -> tuple[dict, dict]:
    """The camera ``name`` written as a pose sensor (``sensors:``; no lens, no image size)."""
    cell, obs = copy.deepcopy(cell), copy.deepcopy(obs)
    mount = cell["cameras"].pop(name)["mount"]
    if not cell["cameras"]:
        del cell["cameras"]
    cell = {"schema": cell.pop("schema"), "sensors": {name: {"kind": "pose", "mount": mount}}, **cell}
    obs["cameras"].pop(name, None)
    obs["targets"] = {}
    for st in obs["stations"]:
        st["poses"] = [{"sensor": p["camera"], "target": p["target"], "T_sensor_target": p["T_cam_target"]}
                       for p in st.get("poses", [])]
        if not st.get("detections"):
            st.pop("detections", None)
    return cell, obs


def study_example(name: str, seed: int = 0) -> tuple[dict, dict, dict]:
    from jcalib.study.scenario import load_scenario
    from jcalib.study.simulate import simulate_trial

    scenario, wanted = SCENARIOS[name]
    sc = load_scenario({"schema": "jcalib.study/1", **copy.deepcopy(scenario),
                        "cell": {"schema": "jcalib.cell/1", **scenario["cell"]}})
    trial = simulate_trial(sc, seed, 0)
    cell, obs, truth = trial.cell_dict, trial.observations.to_dict(), trial.truth
    expected: dict = {"result": "result.json", "max_sigma": MAX_SIGMA}
    for c in wanted.get("cameras", []):
        model = truth.cameras[c]
        expected.setdefault("cameras", {})[c] = dict(zip(model.param_names, np.asarray(model.params).tolist()))
    for t in wanted.get("transforms", []):
        expected.setdefault("transforms", {})[t] = np.asarray(truth.transform(t)).tolist()
    for p in wanted.get("points", []):
        expected.setdefault("points", {})[p] = np.asarray(truth.points[p]).tolist()
    if name == "pivot-tracker":  # a tracked pointer: no robot, the tracker gives the marker's pose exactly
        cell.pop("robot")
    if name == "tracker-handeye":
        cell, obs = _as_sensor(cell, obs, "tracker")
    return cell, obs, expected


def kinematics_example(seed: int = 3) -> tuple[dict, dict, dict]:
    """A 2-axis positioner with hidden DH errors, its target measured by a fixed laser tracker (6-DOF)."""
    from jcalib.geometry import kinematic_models
    from jcalib.problems.kinematics import select_parameters
    from jcalib.sim.kinematic_cells import synthetic_positioner_cell

    model = kinematic_models.PRESETS["positioner_2axis"]()
    joints = np.random.default_rng(0).uniform(model.lower, model.upper, size=(64, model.num_joints))
    mask = select_parameters(model, ("joint_offsets", "link_lengths", "twists"), joints, np.eye(6) * 1e4, "robot").free
    cell, obs, truth = synthetic_positioner_cell(seed, num_stations=12, num_heldout=0, error_mask=mask,
                                                 error_scale=10.0, form="sensor")
    obs.pop("targets")
    expected = {"result": "result.json", "max_sigma": MAX_SIGMA,
                "transforms": {"T_base_tracker": truth["T_base_tracker"].tolist(),
                               "T_flange_part": truth["T_flange_part"].tolist()},
                "kinematics": {"robot": dict(zip(truth["names"], np.asarray(truth["params"]).tolist()))}}
    return cell, obs, expected


def point_sensor_example(seed: int = 1, num: int = 16) -> tuple[dict, dict, dict]:
    """A laser tracker (a 3-D point sensor) following a reflector on the flange at ``num`` stations, 20 µm."""
    from jcalib.geometry.se3 import exp_so3, invert, make_pose

    rng = np.random.default_rng(seed)
    T_base_tracker = make_pose(exp_so3(np.array([0.3, -1.2, 0.5])), np.array([2.0, 0.5, 1.0]))
    T_flange_smr = make_pose(np.eye(3), np.array([0.01, -0.03, 0.12]))
    stations = []
    for i in range(num):
        F = make_pose(exp_so3(rng.normal(0, 0.6, 3)), rng.normal([0.6, 0.0, 0.5], 0.2))
        p = (invert(T_base_tracker) @ F @ T_flange_smr)[:3, 3] + 2e-5 * rng.normal(size=3)
        stations.append({"id": f"s{i:02d}", "T_base_flange": F.tolist(),
                         "positions": [{"sensor": "tracker", "tool": "smr", "p_sensor_tool": p.tolist()}]})
    cell = {"schema": "jcalib.cell/1", "sensors": {"tracker": {"kind": "point", "mount": "base"}},
            "tools": {"smr": {}}, "robot": {}}
    expected = {"result": "result.json", "max_sigma": MAX_SIGMA,
                "transforms": {"T_base_tracker": T_base_tracker.tolist(), "T_flange_smr": T_flange_smr.tolist()}}
    return cell, {"schema": "jcalib.observations/1", "stations": stations}, expected


def write(name: str, cell: dict, obs: dict, expected: dict) -> None:
    d = ROOT / name
    d.mkdir(exist_ok=True)
    head = "# yaml-language-server: $schema=../../jcalib/io/schema/json/cell.schema.json\n"
    (d / "cell.yaml").write_text(head + yaml.safe_dump(cell, sort_keys=False, default_flow_style=None, width=110))
    (d / "observations.json").write_text(json.dumps(_rounded(obs)) + "\n")
    (d / "expected.json").write_text(json.dumps(expected, indent=1) + "\n")


def _rounded(x):
    """Numbers to 12 significant digits (smaller files; far below any noise here)."""
    if isinstance(x, float):
        return float(f"{x:.12g}")
    if isinstance(x, list):
        return [_rounded(v) for v in x]
    if isinstance(x, dict):
        return {k: _rounded(v) for k, v in x.items()}
    return x


def main(names: list[str]) -> None:
    special = {"kinematics-tracker": kinematics_example, "tracker-reflector": point_sensor_example}
    for name in names or [*SCENARIOS, *special]:
        data = special[name]() if name in special else study_example(name)
        write(name, *data)
        print("wrote", ROOT / name)


if __name__ == "__main__":
    main(sys.argv[1:])
