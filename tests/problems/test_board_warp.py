"""Board warp (``warp: true``): mrcal's parabolic definition, exact recovery from noise-free corners,
σ consistent by Monte Carlo, a bowed board in a hand-eye cell, and the result file / report."""

import json

import numpy as np
import pytest
import scipy.stats

import jcalib
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.geometry.se3 import invert, log_se3
from jcalib.geometry.targets import warp_bow, warped_points
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.io.result import ResultFile
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.sim.cells import synthetic_cell
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
K = np.array([[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]])
DIST = np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02])
WARP = np.array([0.002, -0.001])


def _cell(warp: bool):
    return parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
                       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03,
                                             "warp": warp}}})


def _observations(views, rng, sigma_px, warp=WARP, camera=None):
    """Corners of a board bent by ``warp`` seen in ``views``; the file holds the flat design."""
    cam = camera or camera_from_opencv(K, DIST, (1280, 960))
    seen = warped_points(BOARD.points, warp)
    stations = []
    for i, T in enumerate(views):
        pix, vis = project_target(cam, T, seen)
        assert vis.all()
        pix = pix + sigma_px * rng.standard_normal(pix.shape)
        stations.append({"id": f"v{i:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": list(range(BOARD.num_points)), "pixels": pix.tolist()}]})
    return parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [1280, 960]}},
                               "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations})


def test_warp_shape_is_mrcals_parabola():
    """mrcal (``mrcal.c``): corner (i, j) of a W x H grid moves by ``c0·4u(1−u) + c1·4v(1−v)``,
    ``u = i/(W−1)``, ``v = j/(H−1)`` (``i`` along x): zero on the edges' corners, ``c0 + c1`` in the middle."""
    pts = Checkerboard(cols=10, rows=7, square=0.04).points
    i, j = np.round(pts[:, 0] / 0.04), np.round(pts[:, 1] / 0.04)
    u, v = i / 9, j / 6
    expected = np.stack([4 * u * (1 - u), 4 * v * (1 - v)], axis=1)
    np.testing.assert_allclose(warp_bow(pts, pts), expected, atol=1e-12)
    bent = warped_points(pts, [0.001, 0.0005])
    np.testing.assert_allclose(bent[:, :2], pts[:, :2])
    np.testing.assert_allclose(bent[:, 2], expected @ [0.001, 0.0005], atol=1e-15)


def test_noise_free_corners_give_the_warp_exactly():
    rng = np.random.default_rng(1)
    views = random_calibration_views(camera_from_opencv(K, DIST, (1280, 960)), BOARD.points, 12, rng=rng)
    obs = _observations(views, rng, 0.0)
    cal = calibrate_cell(_cell(True), obs)
    np.testing.assert_allclose(cal.warps["board"], WARP, atol=1e-9)
    np.testing.assert_allclose(np.asarray(cal.cameras["cam"].params)[:4], K[[0, 1, 0, 1], [0, 1, 2, 2]], rtol=1e-8)
    assert cal.rms_px < 1e-6
    # the same data taken as flat: a bent board biases the intrinsics and leaves a visible residual
    flat = calibrate_cell(_cell(False), obs)
    assert flat.rms_px > 0.1
    assert abs(float(flat.cameras["cam"].params[0]) - 900.0) > 1.0
    assert flat.warps == {}


def test_warp_sigma_is_consistent_by_monte_carlo():
    """30 noisy data sets of one view geometry (0.3 px): Σ over trials of the warp's d² (2 dof each,
    ``d² = eᵀ Σ⁻¹ e``) lies within the central 99.8 % of χ²(60)."""
    rng = np.random.default_rng(7)
    views = random_calibration_views(camera_from_opencv(K, DIST, (1280, 960)), BOARD.points, 10, rng=rng)
    d2 = []
    for _ in range(30):
        cal = calibrate_cell(_cell(True), _observations(views, rng, 0.3), CalibrationOptions(outlier_threshold=None))
        e = cal.warps["board"] - WARP
        d2.append(float(e @ np.linalg.solve(cal.warp_covariance["board"], e)))
    total = sum(d2)
    lo, hi = scipy.stats.chi2.ppf([0.001, 0.999], 2 * len(d2))
    assert lo < total < hi, (total, lo, hi)


def test_bowed_board_in_a_hand_eye_cell():
    """Nearly noise-free synthetic hand-eye cell whose board sags 0.5 mm: with the warp estimated the
    warp, the hand-eye and the flange camera's intrinsics come out right (taken as flat, the same data
    leave about 0.2° and 0.4 mm of hand-eye error and 0.7 px of fx: the noise-free row of
    ``benchmarks/bench_board_warp.py``)."""
    warp = np.array([0.0003, 0.0002])
    cell, obs, true = synthetic_cell(3, num_tool_stations=8, sigma_px=1e-4, tip_sigma_px=1e-4, robot_m=1e-7,
                                     robot_deg=1e-6, board_warp=warp)
    cell["targets"]["board"]["warp"] = True
    cal = calibrate_cell(parse_cell(cell), parse_observations(obs))
    np.testing.assert_allclose(cal.warps["board"], warp, atol=2e-6)
    e = log_se3(invert(true["T_flange_cam0"]) @ cal.transforms["T_flange_cam0"])
    assert np.degrees(np.linalg.norm(e[:3])) < 0.005 and np.linalg.norm(e[3:]) < 2e-5, e
    assert abs(cal.cameras["cam0"].params[0] - true["cam0"][0]) < 0.05


@pytest.fixture(scope="module")
def warped_result(tmp_path_factory):
    rng = np.random.default_rng(3)
    views = random_calibration_views(camera_from_opencv(K, DIST, (1280, 960)), BOARD.points, 10, rng=rng)
    obs = _observations(views, rng, 0.2)
    cell = _cell(True)
    return jcalib.calibrate(cell, obs), cell, obs


def test_result_file_has_the_warp_with_its_sigma(warped_result):
    result, _, _ = warped_result
    cal = result.details
    target = result.file.targets["board"]
    np.testing.assert_array_equal(target.warp_m, cal.warps["board"])
    np.testing.assert_allclose(target.warp_std_m, np.sqrt(np.diag(cal.warp_covariance["board"])))
    text = result.file.to_json()
    data = json.loads(text)
    entry = data["targets"]["board"]
    assert set(entry) == {"warp_m", "warp_std_m", "warp_covariance", "warp_definition"}
    assert "mrcal" in entry["warp_definition"]
    again = ResultFile.from_dict(data)
    np.testing.assert_array_equal(again.targets["board"].warp_m, target.warp_m)
    np.testing.assert_array_equal(again.targets["board"].warp_covariance, target.warp_covariance)
    # the joint covariance names the warp's block (it correlates with the intrinsics)
    joint = data["joint_covariance"]
    assert "warp:board" in joint["names"]


def test_report_restores_and_names_the_warp(warped_result, tmp_path):
    """A result file with a warp, read back with its cell and observations: the restored solve stays at
    the file's warp, and the linear model lists the warp's two coefficients (mm)."""
    from jcalib.report.model import calibration_of, linear_model

    result, cell, obs = warped_result
    path = result.file.save(tmp_path / "result.json")
    cal = calibration_of(path, obs, cell)
    std = np.sqrt(np.diag(result.details.warp_covariance["board"]))
    assert np.all(np.abs(cal.warps["board"] - result.file.targets["board"].warp_m) < 1e-3 * std)
    model = linear_model(cal)
    names = [u.key for u in model.unknowns]
    assert "warp:board.c0" in names and "warp:board.c1" in names
    unit = {u.key: u.unit for u in model.unknowns}
    assert unit["warp:board.c0"] == "mm"


def test_result_without_the_warp_is_refused_for_a_warp_cell(warped_result, tmp_path):
    from jcalib.errors import BadInputError
    from jcalib.report.model import calibration_of

    result, cell, obs = warped_result
    data = result.file.to_dict()
    del data["targets"]
    path = tmp_path / "no_warp.json"
    path.write_text(json.dumps(data))
    with pytest.raises(BadInputError, match="warp_m"):
        calibration_of(path, obs, cell)


def test_report_and_console_show_the_warp(warped_result):
    from rich.console import Console

    from jcalib.report.console import print_result
    from jcalib.report.html import render_report

    result, _, _ = warped_result
    html = render_report(result, cross_validation=False)
    assert "Target warp" in html and "c0, c1 [mm]" in html
    c0 = result.file.targets["board"].warp_m[0] * 1e3
    assert f"{c0:.4f}" in html
    console = Console(record=True, width=200)
    print_result(result.file, console)
    assert "Target warp" in console.export_text()
