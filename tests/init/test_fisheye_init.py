"""The fisheye closed-form start (jcalib.init.fisheye): bearings through the KB4 model beyond 90°, and
the equidistant start on views where Zhang's pinhole closed form fails."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import Fisheye
from jcalib.geometry.se3 import exp_so3, make_pose, rotation_z_to
from jcalib.geometry.targets import Charuco
from jcalib.init import zhang_init
from jcalib.init.fisheye import bearing_pose, fisheye_bearings, fisheye_init

SIZE = (1024, 768)
K = np.array([[331.2, 0.0, 515.4], [0.0, 330.6, 381.9], [0.0, 0.0, 1.0]])
D = np.array([0.021, -0.012, 0.004, -0.0006])  # monotonic up to 127° from the axis
BOARD = Charuco(9, 7, 0.04, 0.03)


def test_bearings_match_the_model_beyond_90_degrees_where_cv2_clamps():
    rng = np.random.default_rng(0)
    pixels = rng.uniform([0.0, 0.0], [SIZE[0] - 1.0, SIZE[1] - 1.0], size=(3000, 2))
    for alpha in (None, 0.002):
        Ks = K.copy()
        Ks[0, 1] = 0.0 if alpha is None else alpha * K[0, 0]
        model = Fisheye(SIZE, (K[0, 0], K[1, 1]), (K[0, 2], K[1, 2]), D, alpha=alpha)
        expected, valid = (np.asarray(a) for a in model.unproject_valid(pixels))
        bearings, ours_valid = fisheye_bearings(Ks, D, pixels)
        assert np.array_equal(ours_valid, valid) and valid.all()
        np.testing.assert_allclose(bearings, expected, rtol=0, atol=1e-12)  # float64 identity of one model
    beyond = bearings[:, 2] < 0.0
    assert beyond.sum() > 100  # the image corners look behind the camera plane (up to 110°)
    # cv2.fisheye.undistortPoints clamps the distorted angle at 90°: every such pixel gets a wrong ray
    xy = cv2.fisheye.undistortPoints(pixels[beyond].reshape(-1, 1, 2), K, D).reshape(-1, 2)
    cv_rays = np.column_stack([xy, np.ones(len(xy))])
    cv_rays /= np.linalg.norm(cv_rays, axis=1, keepdims=True)
    assert np.all(np.degrees(np.arccos(np.sum(cv_rays * bearings[beyond], axis=1))) > 1.0)


def _views(num: int, seed: int, sigma_px: float):
    """Board poses facing the camera across the image (up to 85° off the axis) and noisy pixels."""
    rng = np.random.default_rng(seed)
    model = Fisheye(SIZE, (K[0, 0], K[1, 1]), (K[0, 2], K[1, 2]), D)
    centre = BOARD.points.mean(axis=0)
    poses, points, pixels = [], [], []
    while len(poses) < num:
        ray = np.asarray(model.unproject(rng.uniform([0.0, 0.0], [SIZE[0] - 1.0, SIZE[1] - 1.0])))
        if ray[2] < np.cos(np.radians(85.0)):
            continue
        R = rotation_z_to(ray) @ exp_so3(np.r_[rng.normal(0.0, 0.4, 2), rng.uniform(-np.pi, np.pi)])
        T = make_pose(R, rng.uniform(0.3, 0.5) * ray - R @ centre)
        p_cam = BOARD.points @ R.T + T[:3, 3]
        front = p_cam[:, 2] > 0.05 * np.linalg.norm(p_cam, axis=1)
        px = cv2.fisheye.projectPoints(p_cam[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
        inside = np.all((px >= 0.0) & (px <= np.array(SIZE) - 1.0), axis=1)
        if inside.sum() < 0.5 * len(BOARD.points):
            continue
        poses.append(T)
        points.append(BOARD.points[front][inside])
        pixels.append(px[inside] + sigma_px * rng.standard_normal((inside.sum(), 2)))
    return poses, points, pixels


@pytest.mark.parametrize("seed", [1, 10, 16])  # Zhang: not observable, +168 %, +99 %
def test_equidistant_start_where_zhang_fails(seed):
    poses, points, pixels = _views(6, seed, sigma_px=0.2)
    start = fisheye_init(points, pixels, SIZE, view_names=[f"v{i}" for i in range(6)])
    f_true = 0.5 * (K[0, 0] + K[1, 1])
    assert abs(start.K[0, 0] / f_true - 1.0) < 0.03 and start.K[1, 1] == start.K[0, 0]  # k1 = 0.021 ~ 1-2 %
    np.testing.assert_array_equal(start.K[:2, 2], [(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2])
    assert np.array_equal(start.D, np.zeros(4)) and start.rms_px < 2.0
    for T, T0 in zip(poses, start.T_cam_target):
        angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3].T @ T0[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        assert angle < 3.0 and np.linalg.norm(T0[:3, 3] - T[:3, 3]) < 0.05 * np.linalg.norm(T[:3, 3])
    # Zhang's pinhole closed form on the same pixels: no answer, or a focal length far off
    try:
        z = zhang_init([p[:, :2] for p in points], pixels, image_size=SIZE, estimate_distortion=False,
                       distortion_iterations=0, refine_homographies=False)
        assert abs(z.K[0, 0] / f_true - 1.0) > 0.3
    except NotObservableError:
        pass


def test_bearing_pose_is_exact_on_exact_bearings():
    poses, points, pixels = _views(3, 5, sigma_px=0.0)
    for T, pts, px in zip(poses, points, pixels):
        b, valid = fisheye_bearings(K, D, px)
        assert valid.all()
        np.testing.assert_allclose(bearing_pose(pts[:, :2], b), T, atol=1e-9)


def test_bad_views_are_named():
    _, points, pixels = _views(2, 3, sigma_px=0.0)
    with pytest.raises(BadInputError, match="view 'second'.*at least 4 points"):
        fisheye_init([points[0], points[1][:3]], [pixels[0], pixels[1][:3]], SIZE, view_names=["first", "second"])
    row = np.flatnonzero(np.isclose(points[0][:, 1], points[0][0, 1]))
    with pytest.raises(BadInputError, match="view 0: the target points are collinear"):
        fisheye_init([points[0][row]], [pixels[0][row]], SIZE)
    with pytest.raises(BadInputError, match="one array of pixels per view"):
        fisheye_init([], [], SIZE)


def test_a_focal_length_the_views_do_not_determine_is_named():
    """A 6° telephoto (pinhole, f = 9000 px): its views fit an equidistant lens best at the end of the
    searched range, i.e. they say nothing about a fisheye's focal length."""
    K_tele = np.array([[9000.0, 0.0, 511.5], [0.0, 9000.0, 383.5], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(0)
    points, pixels = [], []
    for _ in range(4):
        R = exp_so3(np.r_[rng.normal(0.0, 0.4, 2), rng.uniform(-3.0, 3.0)])
        t = np.array([0.0, 0.0, 6.0]) - R @ BOARD.points.mean(axis=0)
        points.append(BOARD.points)
        pixels.append(cv2.projectPoints(BOARD.points, cv2.Rodrigues(R)[0], t, K_tele, None)[0].reshape(-1, 2))
    with pytest.raises(NotObservableError, match="do not determine the focal length") as info:
        fisheye_init(points, pixels, SIZE)
    assert info.value.unknowns == ["fx", "fy"]
