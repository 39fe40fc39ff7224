"""With shape reuse on (the operator app), a smaller problem of a structure already solved in the process runs
at that compiled shape (the re-solve after a view is left out), with the estimate and σ of its own solve."""

from __future__ import annotations

import numpy as np

import jcalib
import jcalib.solve.core as core
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.geometry.se3 import exp_so3, make_pose
from jcalib.sim.scene import project_target

BOARD = Checkerboard(cols=7, rows=5, square=0.03)
CAMERA = camera_from_opencv(np.array([[800.0, 0, 400], [0, 800, 300], [0, 0, 1]]), np.array([-0.05, 0.01, 0, 0, 0]),
                            (800, 600))
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 7, "rows": 5, "square": 0.03}}}


def observations(n: int, seed: int = 11) -> dict:
    rng = np.random.default_rng(seed)
    stations = []
    for i in range(n):
        T = make_pose(exp_so3(rng.uniform(-0.4, 0.4, 3)), np.array([-0.09, -0.06, 0.55]) + rng.uniform(-0.03, 0.03, 3))
        pix, vis = project_target(CAMERA, T, BOARD.points)
        assert vis.all()
        stations.append({"id": f"s{i:02d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(35)),
            "pixels": (pix + 0.2 * rng.standard_normal(pix.shape)).tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [800, 600]}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def test_a_smaller_problem_runs_at_the_compiled_shape_with_its_own_estimate():
    data = observations(8)  # 8 views and 280 corners; 7 views and 245 corners: other shape buckets
    smaller = {**data, "stations": data["stations"][:7]}
    saved = dict(core._SHAPES)
    core._SHAPES.clear()
    core.reuse_compiled_shapes(True)
    try:
        jcalib.calibrate(CELL, data)
        shapes = {k: list(v) for k, v in core._SHAPES.items()}
        assert shapes
        reused = jcalib.calibrate(CELL, smaller)
        assert {k: list(v) for k, v in core._SHAPES.items()} == shapes  # no new shape: nothing compiled
        core.reuse_compiled_shapes(False)  # a command's solve: the same data at their own shape buckets
        own = jcalib.calibrate(CELL, smaller)
        assert core._SHAPES == {}
    finally:
        core.reuse_compiled_shapes(False)
        core._SHAPES.update(saved)
    a, b = reused.file.cameras["cam0"], own.file.cameras["cam0"]
    for p in ("fx", "fy", "cx", "cy", "k1", "k2"):
        i = a.param_names.index(p)
        # where Levenberg–Marquardt stops moves by its tolerance: ~1e-7 σ (√(ftol·m) ≈ 5e-6 σ at most)
        assert abs(a.params[i] - b.params[i]) <= 1e-5 * b.std[p], p
        assert abs(a.std[p] - b.std[p]) <= 1e-5 * b.std[p], p
