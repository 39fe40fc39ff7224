"""Renderer tests: rendered geometry against independent projections (cv2), sensor levels against the
closed-form signal model, determinism, bit depths, fisheye, partial views, background, bad input.

Images are small (640x480 .. 1280x960). One camera per image size is reused so that the grid
unprojection is compiled a handful of times in the whole file.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from sim_standins import make_camera, make_checkerboard, make_checkerboard_texture

from jcalib.errors import BadInputError
from jcalib.sim.render import RenderOptions, render_reflectance, render_target_image, render_targets_image
from jcalib.sim.scene import random_calibration_views
from jcalib.sim.textures import TargetTexture

# An opencv5 lens with noticeable barrel distortion (~ -40 px at the corners of 1280x960).
W, H = 1280, 960
K5 = np.array([[1000.0, 0.0, 641.7], [0.0, 1001.5, 478.2], [0.0, 0.0, 1.0]])
DIST5 = np.array([-0.28, 0.11, 0.0008, -0.0006, -0.02])
NOISE_FREE = RenderOptions(shot_noise=False, read_noise_e=0.0, bit_depth=16, vignetting_power=0.0)


@pytest.fixture(scope="module")
def cam5():
    return make_camera(K5, DIST5, (W, H))


@pytest.fixture(scope="module")
def board():
    return make_checkerboard(9, 6, 0.03)


@pytest.fixture(scope="module")
def board_texture(board):
    return make_checkerboard_texture(board, 0.0001, 0.03)


def _pose(rvec, tvec) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    T[:3, 3] = tvec
    return T


def _cv2_project(T, points, K, dist, fisheye=False) -> np.ndarray:
    rvec = cv2.Rodrigues(T[:3, :3])[0]
    if fisheye:
        px, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), rvec, T[:3, 3], K, dist)
    else:
        px, _ = cv2.projectPoints(points, rvec, T[:3, 3], K, dist)
    return px.reshape(-1, 2)


def _detect(image, board):
    from jcalib.vision import detect_target

    det = detect_target(image, board)
    return det.point_index, det.pixels


# ------------------------------------------------------------------------------------------------
# Geometry


def test_edge_position_matches_cv2_projection(cam5):
    """A straight printed edge x = x_e renders where cv2.projectPoints puts it, to 0.01 px.

    Reference: cv2.projectPoints of 60 001 points along the edge (independent of the renderer). The
    rendered edge is located per row as the centroid of the gradient of the noise-free reflectance
    blurred by a Gaussian (sigma 1.5 px): exact for a symmetric edge profile. Budget 0.01 px:
    cv2.remap resolves texture coordinates to 1/32 texel (texel ~ 0.2 px here) and sub-pixel rays
    are interpolated between pixel centres (< 1e-3 px); measured max ~ 3e-3 px.
    """
    mpp, x_e = 0.0003, 0.0123
    origin = np.array([-0.3 + mpp / 2, -0.3 + mpp / 2])
    u_edge = (x_e - origin[0]) / mpp
    cover = np.clip(np.arange(2000) + 0.5 - u_edge, 0.0, 1.0)  # exact area coverage of the edge texel
    texture = TargetTexture(np.tile(cover, (2000, 1)), mpp, origin)
    T = _pose([0.25, -0.35, 0.15], [0.0, 0.0, 0.45])
    refl, _, _ = render_reflectance(cam5, [(T, texture)], RenderOptions(supersample=3))
    blurred = cv2.GaussianBlur(refl, (0, 0), 1.5).astype(np.float64)

    ys = np.linspace(-0.3, 0.3, 60001)
    line = _cv2_project(T, np.stack([np.full_like(ys, x_e), ys, 0 * ys], axis=1), K5, DIST5)
    errors = []
    for v in range(40, H - 40, 9):
        k = np.nonzero(np.diff(np.sign(line[:, 1] - v)))[0]
        assert len(k) == 1
        k = int(k[0])
        a = (v - line[k, 1]) / (line[k + 1, 1] - line[k, 1])
        u_true = line[k, 0] + a * (line[k + 1, 0] - line[k, 0])
        i0 = int(round(u_true))
        grad = np.abs(np.diff(blurred[v, i0 - 9 : i0 + 9]))
        u_rendered = float(np.sum(grad * (np.arange(i0 - 9, i0 + 8) + 0.5)) / np.sum(grad))
        errors.append(u_rendered - u_true)
    errors = np.array(errors)
    assert len(errors) > 80
    assert np.max(np.abs(errors)) < 0.01, errors


def test_acceptance_corner_error_realistic_noise(cam5, board, board_texture):
    """THE acceptance test: mean corner error <= 0.05 px against the ground truth.

    Camera: opencv5, k1 = -0.28 (about 40 px of barrel distortion at the image corners), 1280x960.
    Capture: 8-bit, full well 10 000 e-, gain 255/10 000 DN/e-, Poisson shot noise (white paper ~ 6300 e-,
    i.e. ~2 DN rms), read noise 2 DN (78 e-), Gaussian defocus sigma 0.7 px, cos^4 vignetting,
    3x3 supersampling. Detection: jcalib.vision.detect_target. Truth: cv2.projectPoints.
    """
    full_well = 10000.0
    gain = 255.0 / full_well
    options = RenderOptions(
        bit_depth=8, full_well_e=full_well, read_noise_e=2.0 / gain, blur_sigma_px=0.7, supersample=3
    )
    poses = random_calibration_views(cam5, board.points, 4, rng=7, fill=(0.5, 0.8), max_tilt_deg=40.0)
    errors = []
    for k, T in enumerate(poses):
        image = render_target_image(cam5, T, board_texture, options, rng=k)
        assert image.dtype == np.uint8
        index, pixels = _detect(image, board)
        truth = _cv2_project(T, board.points, K5, DIST5)
        assert len(index) == len(board.points)
        errors.append(np.linalg.norm(pixels - truth[index], axis=1))
    errors = np.concatenate(errors)
    print(f"acceptance: mean corner error {np.mean(errors):.4f} px, max {np.max(errors):.4f} px, n={errors.size}")
    assert np.mean(errors) <= 0.05, (np.mean(errors), np.max(errors))
    assert np.max(errors) < 0.25


def test_fisheye_renders_where_cv2_fisheye_projects():
    """A fisheye (Kannala-Brandt, ~150 deg diagonal field) image: the board's corners are found where
    cv2.fisheye.projectPoints puts them (0.1 px mean: detection on a strongly curved board)."""
    Kf = np.array([[300.0, 0.0, 320.4], [0.0, 300.0, 239.6], [0.0, 0.0, 1.0]])
    Df = np.array([0.02, -0.01, 0.003, -0.0005])
    cam = make_camera(Kf, Df, (640, 480), fisheye=True)
    board = make_checkerboard(7, 5, 0.03)
    texture = make_checkerboard_texture(board, 0.0002, 0.03)
    T = _pose([0.2, -0.3, 0.05], [-0.09, -0.06, 0.3])
    image = render_target_image(cam, T, texture, RenderOptions(vignetting_power=1.0), rng=3)
    assert image.shape == (480, 640) and image.dtype == np.uint8
    index, pixels = _detect(image, board)
    truth = _cv2_project(T, board.points, Kf, Df, fisheye=True)
    err = np.linalg.norm(pixels - truth[index], axis=1)
    assert len(index) == len(board.points)
    assert np.mean(err) < 0.1, err


def test_partly_out_of_view_and_background_where_rays_miss(cam5, board_texture):
    """A board hanging off the image edge renders without error: pixels that see the board are bright
    or dark, the rest shows the background level, computed in closed form (noise off)."""
    options = RenderOptions(shot_noise=False, read_noise_e=0.0, vignetting_power=0.0, blur_sigma_px=0.0)
    gain = 255.0 / options.full_well_e
    background_dn = round(options.background_reflectance * options.white_electrons * gain)
    T = _pose([0.0, 0.0, 0.0], [0.35, 0.0, 0.5])  # board centre far to the right: partly outside
    image = render_target_image(cam5, T, board_texture, options)
    assert image.shape == (H, W)
    assert image[H // 2, 5] == background_dn  # left part of the image: the ray misses the board
    assert np.any(image[:, -20:] != background_dn)  # right edge: the board is there
    # Board behind the camera: every ray misses it.
    behind = render_target_image(cam5, _pose([0, 0, 0], [0, 0, -0.5]), board_texture, options)
    assert np.all(behind == background_dn)
    # Back face: the camera on the board's +z side sees no print, only background.
    back = render_target_image(cam5, _pose([np.pi, 0, 0], [-0.1, 0.06, 0.5]), board_texture, options)
    assert np.all(back == background_dn)


def test_nearest_board_wins(cam5):
    """Two overlapping boards: where both are hit, the nearer one is seen."""
    black = TargetTexture(np.zeros((200, 200)), 0.001, np.array([-0.1, -0.1]))
    white = TargetTexture(np.ones((400, 400)), 0.001, np.array([-0.2, -0.2]))
    options = RenderOptions(shot_noise=False, read_noise_e=0.0, vignetting_power=0.0)
    near_black = render_targets_image(
        cam5, [(_pose([0, 0, 0], [0, 0, 1.0]), white), (_pose([0, 0, 0], [0, 0, 0.6]), black)], options
    )
    near_white = render_targets_image(
        cam5, [(_pose([0, 0, 0], [0, 0, 0.6]), white), (_pose([0, 0, 0], [0, 0, 1.0]), black)], options
    )
    c = (H // 2, W // 2)
    ink_dn = round(options.ink_reflectance * options.white_electrons * 255.0 / options.full_well_e)
    paper_dn = round(options.paper_reflectance * options.white_electrons * 255.0 / options.full_well_e)
    assert near_black[c] == ink_dn and near_white[c] == paper_dn


# ------------------------------------------------------------------------------------------------
# Photometry and sensor


def test_levels_noise_and_16_bit(cam5):
    """16-bit output: the mean and spread of a uniform white patch follow the sensor model in closed
    form: mean = paper * white_e * gain, variance = (mean_e + read_e^2) * gain^2 + 1/12 (rounding).
    Bounds: 5 standard errors of the mean; variance within 10 % (n = 40 000, rel. s.e. ~0.7 %)."""
    white = TargetTexture(np.ones((600, 600)), 0.002, np.array([-0.6, -0.6]))
    options = RenderOptions(bit_depth=16, vignetting_power=0.0, read_noise_e=5.0, blur_sigma_px=0.0)
    image = render_target_image(cam5, _pose([0, 0, 0], [0, 0, 0.5]), white, options, rng=11)
    assert image.dtype == np.uint16
    gain = 65535.0 / options.full_well_e
    mean_e = options.paper_reflectance * options.white_electrons
    patch = image[H // 2 - 100 : H // 2 + 100, W // 2 - 100 : W // 2 + 100].astype(np.float64)
    var = (mean_e + options.read_noise_e**2) * gain**2 + 1.0 / 12.0
    assert abs(patch.mean() - mean_e * gain) < 5.0 * np.sqrt(var / patch.size)
    assert abs(patch.var() / var - 1.0) < 0.1
    assert patch.max() > 255


def test_vignetting_follows_cos4(cam5):
    """Noise off: the ratio of a corner to the centre is cos^4 of the field angle, the angle taken
    from cv2.undistortPoints (independent). Budget: 2 DN of 16-bit rounding/blur over ~20 000 DN."""
    options = RenderOptions(shot_noise=False, read_noise_e=0.0, bit_depth=16, vignetting_power=4.0, blur_sigma_px=0.0)
    nothing = TargetTexture(np.ones((4, 4)), 0.001, np.array([0.0, 0.0]))
    image = render_target_image(cam5, _pose([0, 0, 0], [0, 0, -1.0]), nothing, options).astype(np.float64)
    pix = np.array([[[W // 2, H // 2]], [[30, 20]]], dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    xy = cv2.undistortPointsIter(pix, K5, DIST5, None, None, criteria)
    xy = xy.reshape(-1, 2)
    cos = 1.0 / np.sqrt(1.0 + np.sum(xy**2, axis=1))
    expected = (cos[1] / cos[0]) ** 4
    measured = image[20, 30] / image[H // 2, W // 2]
    assert abs(measured - expected) < 2.0 / image[H // 2, W // 2] + 1e-4


def test_determinism_with_seed(cam5, board_texture):
    T = _pose([0.1, 0.2, 0.0], [-0.12, -0.08, 0.6])
    a = render_target_image(cam5, T, board_texture, RenderOptions(), rng=5)
    b = render_target_image(cam5, T, board_texture, RenderOptions(), rng=np.random.default_rng(5))
    c = render_target_image(cam5, T, board_texture, RenderOptions(), rng=6)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    quiet = RenderOptions(shot_noise=False, read_noise_e=0.0)
    first = render_target_image(cam5, T, board_texture, quiet, rng=1)
    assert np.array_equal(first, render_target_image(cam5, T, board_texture, quiet, rng=2))


def test_psf_widens_edges(cam5, board_texture):
    """Gaussian and disk PSFs blur (smaller max gradient than no PSF) and keep the mean level
    (a normalised kernel: within 0.5 % on the whole image)."""
    T = _pose([0.0, 0.0, 0.0], [-0.12, -0.08, 0.6])
    base = dict(shot_noise=False, read_noise_e=0.0, bit_depth=16, vignetting_power=0.0)
    images = {}
    for psf in ("none", "gaussian", "disk"):
        options = RenderOptions(psf=psf, blur_radius_px=2.0, **base)
        images[psf] = render_target_image(cam5, T, board_texture, options).astype(float)
    grad = {k: np.abs(np.diff(v, axis=1)).max() for k, v in images.items()}
    assert grad["gaussian"] < grad["none"] and grad["disk"] < grad["gaussian"]
    for k in ("gaussian", "disk"):
        assert abs(images[k].mean() / images["none"].mean() - 1.0) < 5e-3


# ------------------------------------------------------------------------------------------------
# Bad input


@pytest.mark.parametrize(
    "T",
    [np.eye(3), np.full((4, 4), np.nan), np.diag([1.0, 1.0, -1.0, 1.0]), 2.0 * np.eye(4)],
    ids=["shape", "nan", "reflection", "scaled"],
)
def test_bad_pose_raises(cam5, board_texture, T):
    with pytest.raises(BadInputError, match="T_cam_target"):
        render_target_image(cam5, T, board_texture)


@pytest.mark.parametrize(
    "kwargs",
    [{"supersample": 0}, {"psf": "box"}, {"bit_depth": 9}, {"paper_reflectance": 1.5}, {"full_well_e": -1.0}],
)
def test_bad_options_raise(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(BadInputError, match=name):
        RenderOptions(**kwargs)


def test_bad_texture_and_camera_raise(cam5):
    T = _pose([0, 0, 0], [0, 0, 0.5])
    with pytest.raises(BadInputError, match="texture"):
        render_target_image(cam5, T, TargetTexture(np.full((8, 8), 2.0), 0.001, np.zeros(2)))
    with pytest.raises(BadInputError, match="metres_per_pixel"):
        render_target_image(cam5, T, TargetTexture(np.ones((8, 8)), 0.0, np.zeros(2)))
    with pytest.raises(BadInputError, match="image_size"):
        render_target_image(object(), T, TargetTexture(np.ones((8, 8)), 0.001, np.zeros(2)))


def test_fast_noise_has_the_exact_models_mean_and_variance():
    """The normal approximation of the live cameras (``fast_noise``) against the exact Poisson + read model,
    on flat fields from dark to bright: mean and variance in DN agree within their sampling errors."""
    from jcalib.sim.noise import sensor_response

    rng = np.random.default_rng(0)
    for mean_e in (20.0, 120.0, 3000.0):
        field = np.full((400, 500), mean_e)
        kw = dict(read_noise_e=6.0, gain_dn_per_e=150.0 / mean_e, black_level_dn=2.0)  # ~150 DN: no clipping
        exact = sensor_response(field, rng, **kw).astype(np.float64)
        fast = sensor_response(field, rng, approximate=True, **kw).astype(np.float64)
        n = field.size
        for a, b in ((exact, fast),):
            se_mean = np.sqrt(a.var() / n + b.var() / n)
            assert abs(a.mean() - b.mean()) < 5 * se_mean + 0.01, mean_e
            assert abs(a.var() / b.var() - 1.0) < 5 * np.sqrt(4.0 / n) + 0.01, mean_e
    assert sensor_response(np.zeros((4, 4)), rng, approximate=True).min() >= 0
