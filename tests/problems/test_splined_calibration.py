"""A splined lens model calibrated end to end: a lens that the 4-coefficient fisheye cannot represent
(the fisheye truth of ``fisheye_scene`` plus a smooth spline of ~1.5 px) is recovered by the splined
model to a small fraction of a pixel over the image the views cover, where the fisheye model is left
with a visible misfit."""

import os
import sys

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

sys.path.insert(0, os.path.dirname(__file__))
from fisheye_scene import BOARD, CAMERA, IMAGE_SIZE, board_views, observations  # noqa: E402

import jcalib  # noqa: E402
from jcalib.geometry.cameras.splined import GRID, SplinedStereographic, fov_covering  # noqa: E402
from jcalib.sim.scene import project_target  # noqa: E402


def _truth():
    """A stereographic lens with the fisheye scene's focal length and principal point, plus a smooth,
    non-radial spline of about 1.3 px that no KB4 lens has."""
    nx, ny = GRID
    fov = fov_covering(CAMERA.focal, CAMERA.principal_point, IMAGE_SIZE)
    j, i = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
    bump = 0.004 * np.stack([np.sin(i / 3.0) * np.cos(j / 4.0), np.cos(i / 4.0) * np.sin(j / 3.0)], axis=-1)
    return SplinedStereographic(IMAGE_SIZE, CAMERA.focal, CAMERA.principal_point, fov, bump)


@pytest.fixture(scope="module")
def data():
    truth = _truth()
    rng = np.random.default_rng(7)
    index, pixels = [], []
    for T in board_views(truth, BOARD, 16, seed=3):
        pix, ok = project_target(truth, T, BOARD.points)
        index.append(np.flatnonzero(ok))
        pixels.append(pix[ok] + 0.01 * rng.standard_normal((int(ok.sum()), 2)))
    return truth, observations(index, pixels)


def _projection_error(model, truth, pixels):
    """``|model.project(R · ray_truth(q)) − q|`` over pixels ``q`` after the best rotation ``R`` (two
    calibrations of one lens may differ by a rotation of the camera frame)."""
    rays = np.asarray(truth.unproject(pixels))

    def residual(w):
        R = Rotation.from_rotvec(w).as_matrix()
        return (np.asarray(model.project(rays @ R.T)) - pixels).ravel()

    return np.linalg.norm(least_squares(residual, np.zeros(3)).fun.reshape(-1, 2), axis=1)


def _check_tables(file):
    """The console and the report list the core and the extent, and the 416 spline values in one row."""
    from rich.console import Console

    from jcalib.report.console import print_result
    from jcalib.report.sections import intrinsics

    console = Console(record=True, width=160)
    print_result(file, console)
    text = console.export_text()
    assert "416 values" in text and "fov_x_deg" in text and "su0_0" not in text
    html = intrinsics(file)
    assert "416 values" in html and "su0_0" not in html


def test_splined_model_recovers_a_lens_the_fisheye_cannot(data):
    """The splined model holds the lens to 0.05 px (median over the covered pixels, after the best
    camera-frame rotation); the truth's non-radial part is 1.3 px, which no radial fisheye can hold
    (``benchmarks/bench_splined.py`` calibrates the fisheye on the same data for comparison)."""
    truth, obs = data
    seen = np.concatenate([np.asarray(d["pixels"]) for s in obs["stations"] for d in s["detections"]])
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "splined"}}, "targets": {"board": BOARD.to_spec()}}
    result = jcalib.calibrate(cell, obs)
    assert result.details.status == "converged"
    assert result.file.cameras["cam0"].model == "splined"
    assert result.details.rms_px < 0.02  # 0.01 px per coordinate of noise: ~0.014 px per corner
    _check_tables(result.file)
    err = _projection_error(result.details.cameras["cam0"], truth, seen[::7])
    assert np.median(err) < 0.05, np.median(err)
    # the truth's non-radial spline reaches more than 1 px: what the test asks the model to hold is real
    assert np.max(np.abs(np.asarray(truth.control))) * float(truth.focal[0]) > 1.0
