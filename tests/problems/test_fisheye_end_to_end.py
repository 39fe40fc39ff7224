"""The fisheye (Kannala–Brandt, KB4) model end to end on rendered wide-angle images.

Rendered ChArUco views of a 174° x 130° (over 180° diagonal) fisheye (``fisheye_scene.py``: the
truth, the board, the image formation) -> ``jcalib detect``'s pipeline -> ``jcalib.calibrate``
(``model: fisheye``) -> OpenCV YAML and ROS camera_info, checked against the truth, against
``cv2.fisheye`` and, for the reported σ, by a Monte Carlo on the same views. The full tables
(more trials, per-parameter z) are ``benchmarks/bench_fisheye.py``.

Rendering is the expensive part: the views are rendered and detected once per module (into a
temporary folder, nothing cached between runs).
"""

from __future__ import annotations

import os
import sys

import cv2
import numpy as np
import pytest
import yaml
from scipy import stats

sys.path.insert(0, os.path.dirname(__file__))
from fisheye_scene import (  # noqa: E402
    BOARD,
    CAMERA,
    CELL,
    IMAGE_SIZE,
    PARAM_NAMES,
    RENDER,
    TEXTURE_M_PER_PX,
    TRUE_PARAMS,
    board_views,
    observations,
)

import jcalib  # noqa: E402
from jcalib.geometry import camera_from_opencv  # noqa: E402
from jcalib.geometry.se3 import exp_so3, make_pose, rotation_z_to  # noqa: E402
from jcalib.io.cell import parse_cell  # noqa: E402
from jcalib.io.export import opencv_yaml, ros_camera_info  # noqa: E402
from jcalib.io.observations import parse_observations  # noqa: E402
from jcalib.pipeline.images import detect_images  # noqa: E402
from jcalib.problems import CalibrationOptions, calibrate_cell  # noqa: E402
from jcalib.problems.start import pnp_poses  # noqa: E402
from jcalib.sim.render import render_target_image  # noqa: E402
from jcalib.sim.textures import target_texture  # noqa: E402
from jcalib.vision import detect_target  # noqa: E402

NUM_VIEWS = 12
VIEW_SEED = 1
MC_TRIALS = 30
MC_SIGMA_PX = 0.1  # about the σ of the rendered set's corners (its a-posteriori σ is 0.08-0.11 px)
ALPHA = 2e-3  # the χ² check's two-sided false-alarm rate (central 99.8 %); the seed is fixed anyway


@pytest.fixture(scope="module")
def texture():
    return target_texture(BOARD, TEXTURE_M_PER_PX)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory, texture):
    """``(T_cam_board per view, observations, failures)``: the views rendered to PNG files and detected
    by the pipeline behind ``jcalib detect``."""
    folder = tmp_path_factory.mktemp("fisheye_images")
    views = board_views(CAMERA, BOARD, NUM_VIEWS, VIEW_SEED)
    paths = []
    for i, T in enumerate(views):
        paths.append(folder / f"v{i:02d}.png")
        assert cv2.imwrite(str(paths[-1]), render_target_image(CAMERA, T, texture, RENDER, rng=100 + i))
    obs, failures = detect_images(CELL, "cam0", paths, progress=False)
    return views, obs, failures


@pytest.fixture(scope="module")
def result(rendered):
    return jcalib.calibrate(CELL, rendered[1])


def _true_pixels(views, index) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per view the true pixels of the board points ``index`` and their angles from the optical axis
    (degrees); one projection call for all views (one compilation)."""
    p_cam = [BOARD.points[i] @ T[:3, :3].T + T[:3, 3] for T, i in zip(views, index)]
    stacked = np.concatenate(p_cam)
    pixels = np.asarray(CAMERA.project(stacked))
    angles = np.degrees(np.arctan2(np.linalg.norm(stacked[:, :2], axis=1), stacked[:, 2]))
    split = np.cumsum([len(p) for p in p_cam])[:-1]
    return np.split(pixels, split), np.split(angles, split)


def test_the_camera_is_a_wide_fisheye():
    corners = np.array([[0.0, 0.0], [IMAGE_SIZE[0] - 1.0, IMAGE_SIZE[1] - 1.0]])
    rays, valid = CAMERA.unproject_valid(corners)
    diagonal_fov_deg = 2.0 * np.degrees(np.arccos(np.asarray(rays)[:, 2])).min()
    assert np.all(np.asarray(valid)) and diagonal_fov_deg >= 150.0, diagonal_fov_deg


def test_every_view_is_detected_up_to_the_rim(rendered):
    views, obs, failures = rendered
    assert not failures, failures
    assert len(obs.stations) == NUM_VIEWS
    assert [s.id for s in obs.stations] == [f"v{i:02d}" for i in range(NUM_VIEWS)]
    detections = [s.detections[0] for s in obs.stations]
    assert all(len(d.point_index) >= 12 for d in detections), [len(d.point_index) for d in detections]
    truth, angles = _true_pixels(views, [d.point_index for d in detections])
    errors = np.concatenate([np.linalg.norm(d.pixels - t, axis=1) for d, t in zip(detections, truth)])
    angles = np.concatenate(angles)
    assert angles.max() > 80.0, angles.max()  # corners found near the rim, not only in the centre
    # ~0.1 px per axis near the centre; a few rim corners carry up to ~1 px (the solve rejects those)
    assert np.median(errors) < 0.15 and errors.max() < 2.0, (np.median(errors), errors.max())


def test_intrinsics_within_three_sigma_of_the_truth(result):
    cal = result.details
    model = cal.cameras["cam0"]
    assert cal.status == "converged" and model.name == "fisheye"
    assert model.param_names == PARAM_NAMES
    estimate = np.asarray(model.params)
    covariance = np.asarray(cal.intrinsics_covariance["cam0"])
    assert estimate.dtype == np.float64 and covariance.dtype == np.float64
    sigma = np.sqrt(np.diag(covariance))
    z = (estimate - TRUE_PARAMS) / sigma
    table = {n: (round(float(e), 6), round(float(s), 6), round(float(zz), 2)) for n, e, s, zz in zip(PARAM_NAMES, estimate, sigma, z)}
    assert np.all(np.abs(z) <= 3.0), table
    assert np.all(sigma > 0.0) and sigma[0] < 1.0 and sigma[1] < 1.0, table  # honest, and not absurdly wide
    assert 0.03 < cal.sigma_px < 0.3, cal.sigma_px


def _points_in_view(model, rng, n=400, max_angle_deg=89.0):
    """Random 3-D points (camera frame, m) that the camera sees in front of its image plane."""
    w, h = model.image_size
    pixels = rng.uniform([0.0, 0.0], [w - 1.0, h - 1.0], size=(4 * n, 2))
    rays, valid = model.unproject_valid(pixels)
    rays, valid = np.asarray(rays), np.asarray(valid)
    keep = valid & (rays[:, 2] > np.cos(np.radians(max_angle_deg)))
    return (rays[keep] * rng.uniform(0.2, 5.0, size=(keep.sum(), 1)))[:n]


def test_opencv_yaml_reproduces_the_projection_in_cv2_fisheye(result, tmp_path):
    """cv2.fisheye computes θ = atan(√(x² + y²)) of x = X/Z: it represents points in front of the
    image plane only, so the points are drawn there (up to 89° from the axis)."""
    model = result.details.cameras["cam0"]
    path = tmp_path / "cam0.yaml"
    path.write_text(opencv_yaml(result.file, "cam0"))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        assert fs.getNode("camera_model").string() == "fisheye"
        K, D = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
        size = (int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real()))
    finally:
        fs.release()
    assert K.shape == (3, 3) and D.shape == (1, 4) and size == IMAGE_SIZE
    assert np.array_equal(camera_from_opencv(K, D, size, fisheye=True).params, np.asarray(model.params))
    P = _points_in_view(model, np.random.default_rng(11))
    assert len(P) >= 300
    px_cv, _ = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    px_ours = np.asarray(model.project(P))
    assert np.max(np.abs(px_cv.reshape(-1, 2) - px_ours)) < 1e-6


def test_ros_camera_info_is_equidistant_with_four_coefficients(result):
    info = yaml.safe_load(ros_camera_info(result.file, "cam0"))
    K, D = result.details.cameras["cam0"].to_opencv()
    assert info["distortion_model"] == "equidistant"
    assert info["distortion_coefficients"]["rows"] == 1 and info["distortion_coefficients"]["cols"] == 4
    assert np.array_equal(info["distortion_coefficients"]["data"], D)
    assert np.array_equal(np.reshape(info["camera_matrix"]["data"], (3, 3)), K)
    assert (info["image_width"], info["image_height"]) == IMAGE_SIZE


@pytest.mark.slow(reason="a Monte Carlo study (17 s): ./scripts/test -m slow, and benchmarks/bench_fisheye.py")
def test_reported_covariance_is_consistent_by_monte_carlo(rendered):
    """The rendered views and detected corners, re-observed as their true projections plus Gaussian
    noise: Σ over the trials of d² = eᵀ Σ⁻¹ e (8 intrinsics, Σ as reported) must follow χ²(8 · trials)
    to first order. Same shapes as the rendered set, so every trial reuses its compiled solve."""
    views, obs, _ = rendered
    views = [views[int(s.id[1:])] for s in obs.stations]  # station id = image stem "v<view>"
    index = [s.detections[0].point_index for s in obs.stations]
    clean, _ = _true_pixels(views, index)
    cell = parse_cell(CELL)
    rng = np.random.default_rng(2025)
    d2 = []
    for _ in range(MC_TRIALS):
        noisy = parse_observations(observations(index, [c + MC_SIGMA_PX * rng.standard_normal(c.shape) for c in clean]))
        cal = calibrate_cell(cell, noisy, CalibrationOptions())
        assert cal.status == "converged"
        e = np.asarray(cal.cameras["cam0"].params) - TRUE_PARAMS
        d2.append(float(e @ np.linalg.solve(cal.intrinsics_covariance["cam0"], e)))
    lo, hi = stats.chi2(8 * MC_TRIALS).ppf([ALPHA / 2, 1 - ALPHA / 2])
    assert lo <= sum(d2) <= hi, (sum(d2), lo, hi)


def test_view_poses_from_a_known_lens_reach_behind_the_image_plane(rendered):
    """The start's per-view PnP with a known lens (intrinsics given in the cell, or a view re-seeded):
    exact on exact pixels for every rendered view and for a board seen 76-104° from the axis (the image
    corner), where ``(x/z, y/z)`` does not exist and cv2.fisheye.undistortPoints clamps the rays."""
    views = rendered[0]
    corner_ray = np.asarray(CAMERA.unproject(np.array([60.0, 60.0])))
    R = rotation_z_to(corner_ray)
    views = list(views) + [make_pose(R, 0.5 * corner_ray - R @ BOARD.points.mean(axis=0))]
    w, h = IMAGE_SIZE
    all_pixels, all_angles = _true_pixels(views, [np.arange(BOARD.num_points)] * len(views))
    index = [np.flatnonzero((p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)) for p in all_pixels]
    assert len(index[-1]) >= 12 and all_angles[-1][index[-1]].min() > 75.0 and all_angles[-1][index[-1]].max() > 100.0
    poses = pnp_poses(CAMERA, [BOARD.points[i] for i in index], [p[i] for p, i in zip(all_pixels, index)])
    for T, T0 in zip(views, poses):
        np.testing.assert_allclose(T0, T, atol=1e-9)  # float64 closed form on exact data


def test_charuco_corners_near_the_rim_keep_their_accuracy(texture):
    """A board 60-70° off the axis, compressed radially by the lens: one homography of the whole board
    overstated the white gap around its corners, the refinement window reached the markers and moved
    corners by 1.4-1.9 px (OpenCV's own were within 0.1 px); the gap is now measured locally."""
    T = make_pose(exp_so3(np.array([-0.225, 0.4537, -2.4552])), np.array([0.1904, 0.1309, 0.2218]))
    det = detect_target(render_target_image(CAMERA, T, texture, RENDER, rng=2), BOARD)
    errors = np.linalg.norm(det.pixels - _true_pixels([T], [det.point_index])[0][0], axis=1)
    assert det.num_points >= 40 and errors.max() < 0.5, (det.num_points, errors.max())
