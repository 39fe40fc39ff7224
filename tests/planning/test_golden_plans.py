"""Station plans and task-space σ against golden outputs recorded before station planning moved out of
``jcalib/acquisition/`` into ``jcalib/planning/`` and the task-space σ out of ``jcalib/report/`` (issue 30).

The plans are what ``jcalib plan`` writes (``jcalib.plan/1``: poses, ids, joints and the ``planner``
details with the predicted σ) for every kind on small fixed cells and seeds, and the demo's plan
(:func:`jcalib.app.demo_cell.plan_demo`; recorded again when it started planning toward the demo cell's goals,
issue 30). The task-space numbers are the goals' achieved σ, the goals
table's rows, projection σ maps, transform σ, pixel effects and a projection difference of a fixed result
file (stored with the outputs, so the comparison does not depend on a solver).

Tolerances: geometric poses 1e-9 m / rad (the planners build them in closed form); poses and joints that
come out of inverse kinematics (``kinematics`` plans) to the IK's own tolerance, 1e-7 m / rad (1e-5 deg):
a converged IK may end a different number of iterations on another CPU; every σ and other number to a
relative 1e-6. Discrete outcomes (ids, kinds, dropped candidates, chosen pairs, met) must be equal.

Record again (only when a planner's behaviour changes on purpose, saying why in the commit):

    PYTHONPATH=. .venv/bin/python tests/planning/test_golden_plans.py --record
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from jcalib.geometry.se3 import make_pose, rotation

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "planning"

#: The station planners' test cell (tests/acquisition/test_planner.py): a flange camera and a fixed one, a
#: board on the table, a tool seen by the fixed camera; small images keep the view checks cheap.
CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}, "cam1": {"model": "pinhole", "mount": "base"}},
    "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 5, "square": 0.02, "mount": "base"}},
    "tools": {"needle": {"observed_by": ["cam1"]}},
}
#: The goal-driven planner's test cell (tests/planning/test_optimal.py).
OPTIMAL_CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv4", "mount": "flange"}},
    "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 6, "square": 0.025, "mount": "base"}},
    "robot": {},
}
OPTIMAL_GOALS = ["T_flange_cam0:translation_mm<=0.05", "T_flange_cam0:rotation_deg<=0.005", "cam0:projection_px<=0.2"]
#: The kinematic planner's test cell (tests/acquisition/test_plan_kinematics.py: the KUKA with given poses).
KINEMATIC_CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv5", "mount": "flange",
                         "intrinsics": {"K": [[1400.0, 0.0, 801.5], [0.0, 1398.0, 598.0], [0.0, 0.0, 1.0]],
                                        "dist": [-0.12, 0.08, 0.0005, -0.0003, -0.02]},
                         "pose": make_pose(rotation((0.3, 0.2, 1.0), 0.4), [0.04, -0.03, 0.07]).tolist()}},
    "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base",
                          "pose": make_pose(rotation((1, 0, 0), np.pi), [0.55, -0.12, 0.05]).tolist()}},
    "robot": {"kinematics": "kuka_kr10_r1100_sixx", "calibrate_kinematics": ["joint_offsets", "link_lengths"]},
}

#: case -> (cell, ``jcalib plan`` arguments after ``--cell CELL -o OUT``)
PLAN_CASES = {
    "plan_viewsets": (CELL, ["--kind", "viewsets", "--stations", "8", "--image-size", "320x240"]),
    "plan_handeye": (CELL, ["--kind", "handeye", "--stations", "8", "--image-size", "320x240", "--amplitude-deg", "25"]),
    "plan_tcp": (CELL, ["--kind", "tcp", "--stations", "7", "--image-size", "320x240"]),
    "plan_kinematics": (KINEMATIC_CELL, ["--kind", "kinematics", "--stations", "10", "--candidates", "128",
                                         "--seed", "1"]),
    "plan_optimal": (OPTIMAL_CELL, ["--kind", "optimal", "--max-stations", "6", "--candidates", "60", "--seed", "3",
                                    *[a for g in OPTIMAL_GOALS for a in ("--goal", g)]]),
}
#: plans whose poses and joints come out of inverse kinematics: compared to the IK's tolerance
IK_POSES = {"plan_kinematics"}
POSE_ATOL = 1e-9  # m, rad: closed-form poses
IK_POSE_ATOL = 1e-7  # m, rad: the IK's convergence tolerance
IK_JOINT_ATOL_DEG = 1e-5
RTOL = 1e-6  # σ, predictions, spans, task-space numbers
TINY = 1e-15  # absolute floor for numbers that are exactly 0


# --------------------------------------------------------------------------------------------- computing


def run_plan_case(name: str, tmp: Path) -> dict:
    """The plan file ``jcalib plan`` writes for case ``name`` (read back as JSON)."""
    from jcalib.app.cli import main

    cell, args = PLAN_CASES[name]
    cell_path, out = tmp / f"{name}.cell.yaml", tmp / f"{name}.plan.json"
    cell_path.write_text(yaml.safe_dump(cell, sort_keys=False))
    try:
        main(["plan", "--cell", str(cell_path), "-o", str(out), *args])
    except SystemExit as e:  # the command ends with its exit status
        assert e.code in (0, None), f"jcalib plan {' '.join(args)}: exit status {e.code}"
    return json.loads(out.read_text())


def run_demo_plan(tmp: Path) -> dict:
    """The demo's plan toward its cell's goals (board views + tool stations), as ``jcalib demo`` makes it."""
    from jcalib.app.demo_cell import plan_demo
    from jcalib.workflow.simulate import DEMO_CELL

    cell_path, out = tmp / "demo.cell.yaml", tmp / "demo.plan.json"
    cell_path.write_text(DEMO_CELL)
    planned = plan_demo(cell_path, out, robot="kuka_kr10_r1100_sixx", image_size=(640, 480))
    return {"counts": [planned.num_views, planned.num_tool, planned.num_kinematic], "plan": json.loads(out.read_text())}


def taskspace_input() -> dict:
    """A fixed result file (seeded random covariances with strongly unequal directions): two cameras, one of
    them fisheye, a hand-eye transform, a TCP of which only the position was calibrated, a cell point."""
    from jcalib.io.result import CameraResult, PointResult, ResultFile, TransformResult

    rng = np.random.default_rng(5)

    def spd(scale):
        A = rng.normal(size=(len(scale), len(scale))) * np.asarray(scale)[None, :]
        return A.T @ A / len(scale)

    K = np.array([[400.0, 0.0, 159.5], [0.0, 405.0, 119.5], [0.0, 0.0, 1.0]])
    Kf = np.array([[300.0, 0.0, 320.0], [0.0, 301.0, 240.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, 3] = [0.01, -0.02, 0.05]
    cov6 = spd([1e-4, 3e-4, 2e-5, 2e-4, 5e-5, 1e-3])
    file = ResultFile(
        cameras={
            "cam0": CameraResult("opencv5", (320, 240), K, np.array([-0.12, 0.05, 1e-3, -8e-4, 0.01]),
                                 covariance=spd([0.5, 0.5, 0.4, 0.4, 2e-3, 4e-3, 1e-4, 1e-4, 5e-3])),
            "cam1": CameraResult("fisheye", (640, 480), Kf, np.array([0.02, -0.01, 0.003, -0.001]),
                                 covariance=spd([0.6, 0.6, 0.5, 0.5, 2e-3, 2e-3, 1e-3, 5e-4])),
        },
        transforms={"T_flange_cam0": TransformResult(T, cov6), "T_base_board": TransformResult(np.eye(4)),
                    "T_flange_torch": TransformResult(T, spd([2e-4, 1e-4, 3e-4, 1e-4, 2e-4, 4e-4]),
                                                      extra={"calibrated": ["tx", "ty", "tz"]})},
        points={"divot": PointResult(np.array([0.4, 0.1, 0.02]), "base", spd([1e-4, 2e-5, 4e-4]))},
        stats={"rms_px": 0.2, "num_residuals": 100, "sigma_px": 0.2})
    return json.loads(file.to_json())


TASKSPACE_GOALS = ["T_flange_cam0:translation_mm<=0.5", "T_flange_cam0:rotation_deg<=0.5",
                   "T_flange_torch:position_mm<=0.3", "divot:position_mm<=1", "cam0:projection_px<=0.3",
                   "cam1:projection_px<=0.3"]
TASKSPACE_PREDICTED = {"T_flange_cam0:translation_mm<=0.5": 0.4, "cam0:projection_px<=0.3": 0.25}


def run_taskspace(result: dict, tmp: Path) -> dict:
    """The task-space numbers of the result: what the report and the goal-driven planner compute from it."""
    from jcalib.io.result import load_result
    from jcalib.problems.goals import achieved_sigmas, goal_rows
    from jcalib.problems.taskspace import (pixel_effect, project, projection_difference, projection_sigma_at,
                                          projection_sigma_map, transform_sigma, unproject)

    path = tmp / "result.json"
    path.write_text(json.dumps(result))
    file = load_result(path)
    cam0, cam1 = file.cameras["cam0"], file.cameras["cam1"]
    # a second calibration of cam0, slightly different (cross-validation's projection difference)
    other = type(cam0)(cam0.model, cam0.image_size, cam0.K + np.diag([0.8, -0.5, 0.0]),
                       cam0.dist + np.array([3e-3, -1e-3, 0.0, 1e-4, 0.0]))
    pixels = np.array([[0.0, 0.0], [159.5, 119.5], [319.0, 239.0], [40.0, 200.0]])
    rays, valid = unproject(cam0, pixels)
    out = {
        "achieved": achieved_sigmas(TASKSPACE_GOALS, file),
        "rows": [[r.goal.text, r.achieved, r.predicted, r.met] for r in goal_rows(TASKSPACE_GOALS, file,
                                                                                     TASKSPACE_PREDICTED)],
        "projection_sigma_map": {name: projection_sigma_map(cam, grid=(9, 7))[2] for name, cam in
                                 (("cam0", cam0), ("cam1", cam1))},
        "projection_sigma_at": projection_sigma_at(cam0, pixels, cam0.covariance),
        "transform_sigma": {name: transform_sigma(file.transforms[name]) for name in ("T_flange_cam0", "T_flange_torch")},
        "pixel_effect": {"cam0": pixel_effect(cam0), "cam1": pixel_effect(cam1)},
        "projection_difference": projection_difference(cam0, other, grid=(9, 7))[2],
        "unproject": [rays, valid],
        "project": project(cam1, np.array([[0.1, -0.05, 1.0], [0.5, 0.4, 0.6], [-0.2, 0.1, 2.0]])),
    }
    return jsonable(out)


def jsonable(x):
    """Arrays to lists, numpy scalars to Python ones, NaN to None (JSON)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return None if math.isnan(float(x)) else float(x)
    return x


# ------------------------------------------------------------------------------------------- comparing


def compare(got, want, where: str, *, pose_atol: float = POSE_ATOL, joint_atol: float = 0.0) -> None:
    """``got`` equals ``want`` structurally; floats within the tolerances (module docstring)."""
    if isinstance(want, dict):
        assert isinstance(got, dict), f"{where}: expected a mapping, got {got!r}"
        assert sorted(got) == sorted(want), f"{where}: keys {sorted(got)} != {sorted(want)}"
        for k in want:
            compare(got[k], want[k], f"{where}.{k}", pose_atol=pose_atol, joint_atol=joint_atol)
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), f"{where}: {got!r} != {want!r}"
        for i, (g, w) in enumerate(zip(got, want)):
            compare(g, w, f"{where}[{i}]", pose_atol=pose_atol, joint_atol=joint_atol)
    elif isinstance(want, float) and not isinstance(got, bool) and isinstance(got, (int, float)):
        if ".T_base_flange" in where:
            atol, rtol = pose_atol, 0.0
        elif ".joints_deg" in where:
            atol, rtol = joint_atol, 0.0
        else:
            atol, rtol = TINY, RTOL
        assert abs(got - want) <= atol + rtol * abs(want), f"{where}: {got!r} != {want!r} (atol {atol}, rtol {rtol})"
    else:
        assert type(got) is type(want) and got == want, f"{where}: {got!r} != {want!r}"


def _golden(name: str) -> dict:
    path = GOLDEN / f"{name}.json"
    assert path.is_file(), f"no golden output {path}; record with `python {Path(__file__).name} --record`"
    return json.loads(path.read_text())


# ------------------------------------------------------------------------------------------------ tests


@pytest.mark.parametrize("name", sorted(PLAN_CASES))
def test_plan_equals_golden(name, tmp_path):
    ik = name in IK_POSES
    compare(run_plan_case(name, tmp_path), _golden(name), name, pose_atol=IK_POSE_ATOL if ik else POSE_ATOL,
            joint_atol=IK_JOINT_ATOL_DEG if ik else POSE_ATOL)


@pytest.fixture(scope="module")
def demo_plan(tmp_path_factory):
    return run_demo_plan(tmp_path_factory.mktemp("demo_plan"))


def test_demo_plan_equals_golden(demo_plan):
    """Recorded again when the demo started planning toward its cell's goals (issue 30): a deliberate change."""
    compare(demo_plan, _golden("plan_demo"), "plan_demo")


def test_demo_plan_meets_the_demo_cells_goals(demo_plan):
    """The demo's planned stations, observed without noise by the independent simulator of
    :mod:`jcalib.sim.observe` as the simulated cell shows them (the board to both cameras at a view, the tool
    tip and four points of its axis to the fixed camera at a tool station), then calibrated by the one
    builder with the noise the plan assumes (stated): every goal of the demo cell is met, with about the σ
    the plan predicted (its information sum is first order, as is the solve's covariance; the simulator's
    axis points are not the predictor's, hence the loose band)."""
    import jcalib
    from jcalib.app.demo_cell import PLAN_NOISE
    from jcalib.geometry import camera_from_opencv
    from jcalib.geometry.se3 import SHAFT_POINTS_M
    from jcalib.io.goals import parse_goals
    from jcalib.planning.layout import cell_layout
    from jcalib.problems.goals import achieved_sigmas
    from jcalib.problems.options import CalibrationOptions
    from jcalib.sim.observe import CellTruth, ObservationNoise, SimStation, simulate_observations
    from jcalib.workflow.simulate import DEMO_CELL

    cell = yaml.safe_load(DEMO_CELL)
    layout = cell_layout(cell, robot="kuka_kr10_r1100_sixx", image_size=(640, 480))
    truth = CellTruth(
        cameras={n: camera_from_opencv(c.K, c.dist, c.image_size) for n, c in layout.cameras.items()},
        poses={**{n: c.pose for n, c in layout.cameras.items()}, **{n: t.pose for n, t in layout.targets.items()},
               **layout.tools},
        target_points={n: np.asarray(t.geometry.points) for n, t in layout.targets.items()}, frame="base")
    plan = demo_plan["plan"]
    stations = [SimStation(s["id"], flange={"robot": np.array(s["T_base_flange"])}, axis_points=len(SHAFT_POINTS_M),
                           axis_length_m=max(SHAFT_POINTS_M)) for s in plan["stations"]]
    obs, _ = simulate_observations(cell, truth, stations, ObservationNoise(), np.random.default_rng(0))
    # what the simulated cell shows: no tool outside its zone (views), no board behind the backlight (tools)
    for st in obs["stations"]:
        tool_station = st["id"].startswith("t")
        st["detections"] = [d for d in st["detections"] if ("tool" in d) == tool_station]
    assert [st["id"] for st in obs["stations"] if st["detections"]] == [s["id"] for s in plan["stations"]]
    result = jcalib.calibrate(cell, obs, CalibrationOptions(noise="stated", **PLAN_NOISE))
    goals = parse_goals(cell["goals"])
    achieved = achieved_sigmas(goals, result)
    predicted = plan["planner"]["predicted"]
    for g in goals:
        assert achieved[g.text] <= g.limit, (g.text, achieved[g.text])
        assert 0.6 < achieved[g.text] / predicted[g.text] < 1.5, (g.text, achieved[g.text], predicted[g.text])


def test_taskspace_equals_golden(tmp_path):
    want = _golden("taskspace")
    compare(run_taskspace(want["input"], tmp_path), want["output"], "taskspace")


def _record() -> None:
    import tempfile

    import jcalib  # noqa: F401  (float64)

    GOLDEN.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        docs = {name: run_plan_case(name, tmp) for name in PLAN_CASES}
        docs["plan_demo"] = run_demo_plan(tmp)
        result = taskspace_input()
        docs["taskspace"] = {"input": result, "output": run_taskspace(result, tmp)}
    for name, doc in docs.items():
        (GOLDEN / f"{name}.json").write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {GOLDEN / name}.json")


if __name__ == "__main__":
    if sys.argv[1:] != ["--record"]:
        sys.exit(f"usage: {sys.argv[0]} --record   (pytest runs the comparison)")
    _record()
