"""Re-seeding a view is for a wrong pose, not for a bad corner (refinement round 1, robust per view)."""

from __future__ import annotations

import numpy as np

import jcalib
import jcalib.problems.refine as refine
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
K = np.array([[1000.0, 0, 640.0], [0, 1000.0, 480.0], [0, 0, 1]])
DIST = np.array([-0.2, 0.05, 1e-3, -5e-4, 0.0])
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}


def _observations(bad_views: dict[int, int], seed: int = 3) -> dict:
    """25 views at 0.2 px; in each of ``bad_views`` (view -> corner) one corner moved by ~10 px."""
    cam = camera_from_opencv(K, DIST, (1280, 960))
    rng = np.random.default_rng(seed)
    stations = []
    for i, T in enumerate(random_calibration_views(cam, BOARD.points, 25, rng=seed)):
        pix, _ = project_target(cam, T, BOARD.points)
        pix = pix + 0.2 * rng.standard_normal(pix.shape)
        if i in bad_views:
            pix[bad_views[i]] += (7.0, -7.0)
        stations.append({"id": f"s{i:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": list(range(len(BOARD.points))), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [1280, 960]}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def test_gross_outlier_corners_are_rejected_without_restarting_their_views(monkeypatch):
    restarts = []
    pnp = refine.pnp_poses
    monkeypatch.setattr(refine, "pnp_poses", lambda *a, **k: (restarts.append(a), pnp(*a, **k))[1])
    bad = {0: 7, 5: 12, 10: 30, 15: 41, 20: 53}
    result = jcalib.calibrate(CELL, _observations(bad))
    cal = result.details
    # a view with one bad corner keeps its pose: no second PnP start, no second solve from it
    assert restarts == []
    assert cal.reseeded_views == []
    assert sorted((st, idx) for _, st, idx in cal.outliers) == sorted((f"s{v:03d}", c) for v, c in bad.items())
    # and the estimate is that of clean data: focal length within 4 σ of the truth
    fx, sigma = float(cal.cameras["cam"].params[0]), float(np.sqrt(cal.intrinsics_covariance["cam"][0, 0]))
    assert abs(fx - K[0, 0]) < 4 * sigma
