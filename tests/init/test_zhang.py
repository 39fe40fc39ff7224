"""Zhang's closed form: exact on noise-free views, sane with noise, close to Zhang's result on his data."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.zhang import (
    estimate_radial_distortion,
    extrinsics_from_homographies,
    intrinsics_from_homographies,
    zhang_init,
)

GRID = np.stack(np.meshgrid(np.arange(9), np.arange(6)), axis=-1).reshape(-1, 2) * 0.025  # m
GRID3 = np.column_stack([GRID, np.zeros(len(GRID))])
ZHANG = Path(__file__).resolve().parents[1] / "data" / "real" / "zhang1998"


def _rotation_deg(Ra, Rb):
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _camera(rng, skew=0.0, pp=None):
    f = rng.uniform(500.0, 2000.0)
    cx, cy = pp if pp is not None else (rng.uniform(280, 360), rng.uniform(200, 280))
    return np.array([[f, skew, cx], [0.0, f * rng.uniform(0.9, 1.1), cy], [0.0, 0.0, 1.0]])


def _project(K, R, t, dist=None):
    """Pinhole + OpenCV radial (k1, k2) projection with skew (cv2.projectPoints ignores K[0, 1])."""
    X = GRID3 @ R.T + t
    x = X[:, :2] / X[:, 2:]
    if dist is not None:
        r2 = np.sum(x * x, axis=-1, keepdims=True)
        x = x * (1.0 + dist[0] * r2 + dist[1] * r2 * r2)
    return x @ K[:2, :2].T + K[:2, 2]


def _views(rng, K, num_views, *, tilt_deg=(15.0, 45.0), dist=None, noise_px=0.0):
    """Board views tilted about different axes, board centre near the optical axis."""
    Rs, ts, pixels = [], [], []
    for i in range(num_views):
        phi = 2 * np.pi * i / num_views + rng.uniform(-0.3, 0.3)
        tilt = np.radians(rng.uniform(*tilt_deg))
        rvec = np.array([np.cos(phi), np.sin(phi), 0.0]) * tilt
        R_tilt, _ = cv2.Rodrigues(rvec)
        R_spin, _ = cv2.Rodrigues(np.array([0.0, 0.0, rng.uniform(-0.5, 0.5)]))
        R = R_tilt @ R_spin
        depth = K[0, 0] * 0.3 / 640.0 * rng.uniform(0.8, 1.2)  # board fills ~ half the image
        t = np.array([0.0, 0.0, depth]) - R @ np.array([0.1, 0.0625, 0.0])
        Rs.append(R)
        ts.append(t)
        pixels.append(_project(K, R, t, dist) + rng.normal(scale=noise_px, size=(len(GRID), 2)))
    return np.stack(Rs), np.stack(ts), np.stack(pixels)


@settings(max_examples=20)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_noise_free_recovers_K_and_poses(seed, skew):
    rng = np.random.default_rng(seed)
    K = _camera(rng, skew=rng.uniform(-2.0, 2.0) if skew else 0.0)
    R, t, pixels = _views(rng, K, 3 if skew else 2)
    z = zhang_init(GRID, pixels, skew=skew, image_size=(640, 480))
    # parameter recovery from noiseless data: 1e-6 relative (STYLE.md)
    np.testing.assert_allclose(z.K, K, rtol=1e-6, atol=1e-6 * K[0, 0])
    np.testing.assert_allclose(z.R, R, atol=1e-8)
    np.testing.assert_allclose(z.t, t, atol=1e-8)
    np.testing.assert_allclose(z.dist, 0.0, atol=1e-8)
    assert z.K.dtype == np.float64
    assert np.all(z.orthonormality_error < 1e-8)
    # T_cam_target maps target points into the camera: reprojects onto the pixels
    X = GRID3 @ z.T_cam_target[0, :3, :3].T + z.T_cam_target[0, :3, 3]
    uv = X @ z.K.T
    np.testing.assert_allclose(uv[:, :2] / uv[:, 2:], pixels[0], atol=1e-6)


def test_constrained_variants_are_exact():
    rng = np.random.default_rng(5)
    K = _camera(rng)
    K[1, 1] = 1.02 * K[0, 0]
    _, _, pixels = _views(rng, K, 2)
    z = zhang_init(GRID, pixels, aspect_ratio=1.02, image_size=(640, 480))
    np.testing.assert_allclose(z.K, K, rtol=1e-6)
    # a fixed principal point and zero skew leave 2 unknowns: one tilted view suffices
    z = zhang_init(GRID, pixels[:1], principal_point=K[:2, 2], image_size=(640, 480))
    np.testing.assert_allclose(z.K, K, rtol=1e-6)
    z = zhang_init(GRID, pixels[:1], principal_point=K[:2, 2], aspect_ratio=1.02)
    np.testing.assert_allclose(z.K, K, rtol=1e-6)
    with pytest.raises(BadInputError, match="aspect_ratio.*skew=False"):
        intrinsics_from_homographies(z.homographies, skew=True, aspect_ratio=1.0)


def test_distortion_noise_free():
    """k1, k2 of OpenCV's model are recovered exactly: the linear model of section 3.3 is exact."""
    rng = np.random.default_rng(6)
    K = _camera(rng)
    dist = np.array([-0.25, 0.12, 0.0, 0.0, 0.0])
    R, t, pixels = _views(rng, K, 6, dist=dist)
    uv, _ = cv2.projectPoints(GRID3, cv2.Rodrigues(R[0])[0], t[0], K, dist)  # the same model as OpenCV's
    np.testing.assert_allclose(pixels[0], uv.reshape(-1, 2), atol=1e-9)
    np.testing.assert_allclose(estimate_radial_distortion(K, R, t, GRID, pixels), dist[:2], atol=1e-9)
    z = zhang_init(GRID, pixels, image_size=(640, 480))
    np.testing.assert_allclose(z.K, K, rtol=1e-6)
    np.testing.assert_allclose(z.dist, dist[:2], atol=1e-6)
    np.testing.assert_allclose(z.dist_opencv, dist, atol=1e-6)
    # Zhang's single pass fits K to distorted pixels: biased, which the alternation removes
    single = zhang_init(GRID, pixels, image_size=(640, 480), distortion_iterations=0)
    assert abs(single.K[0, 0] / K[0, 0] - 1.0) > 1e-3


def test_noisy_views_are_sane():
    rng = np.random.default_rng(7)
    K = _camera(rng)
    R, t, pixels = _views(rng, K, 10, noise_px=0.2)
    for skew in (False, True):
        z = zhang_init(GRID, pixels, skew=skew, image_size=(640, 480))
        # 0.2 px over 10 views of 54 points: the closed form is within a few percent
        assert abs(z.K[0, 0] / K[0, 0] - 1) < 0.03
        assert abs(z.K[1, 1] / K[1, 1] - 1) < 0.03
        assert np.linalg.norm(z.K[:2, 2] - K[:2, 2]) < 0.03 * K[0, 0]
        assert max(_rotation_deg(a, b) for a, b in zip(z.R, R)) < 2.0
        # no distortion: k1, k2 are correlated, but the radial displacement they imply at the
        # largest observed radius stays within a few noise sigmas
        r = np.linalg.norm((pixels.reshape(-1, 2) - K[:2, 2]) / np.diag(K)[:2], axis=-1).max()
        assert K[0, 0] * r * abs(z.dist[0] * r**2 + z.dist[1] * r**4) < 1.0
        assert np.all((z.homography_rms_px > 0.1) & (z.homography_rms_px < 0.3))
        assert 0.0 < z.focal_rel_std < 0.05


def test_agrees_with_opencv_initCameraMatrix2D():
    """Same model (principal point at the image centre, zero skew): same linear estimate."""
    rng = np.random.default_rng(8)
    size = (640, 480)
    centre = ((size[0] - 1) / 2, (size[1] - 1) / 2)  # OpenCV's choice
    K = _camera(rng, pp=centre)
    _, _, pixels = _views(rng, K, 6)
    obj = [GRID3.astype(np.float32)] * 6
    K_cv = cv2.initCameraMatrix2D(obj, [p.astype(np.float32) for p in pixels], size, 0)
    z = zhang_init(GRID, pixels, principal_point=centre, estimate_distortion=False)
    np.testing.assert_allclose(z.K, K, rtol=1e-6)
    np.testing.assert_allclose(K_cv, K, rtol=1e-4)  # OpenCV takes float32 points
    # noisy: two algebraic estimates of one model, agreeing to well within their scatter (~1 %)
    _, _, noisy = _views(rng, K, 6, noise_px=0.3)
    K_cv = cv2.initCameraMatrix2D(obj, [p.astype(np.float32) for p in noisy], size, 0)
    z = zhang_init(GRID, noisy, principal_point=centre, estimate_distortion=False)
    np.testing.assert_allclose(np.diag(z.K)[:2], np.diag(K_cv)[:2], rtol=0.01)


def _zhang_data():
    model = np.loadtxt(ZHANG / "Model.txt").reshape(-1, 2)  # inches
    pixels = [np.loadtxt(ZHANG / f"data{i}.txt").reshape(-1, 2) for i in range(1, 6)]
    vals = np.array(
        (ZHANG / "results" / "calibration-result-zhang-withdistortion.txt").read_text().split(), dtype=float
    )
    return model, pixels, vals[:7], vals[7:].reshape(5, 4, 3)


@pytest.mark.parametrize("skew", [False, True])
def test_zhang_real_data(skew):
    model, pixels, (a, c, b, u0, v0, k1, k2), poses = _zhang_data()
    z = zhang_init(model, pixels, skew=skew, image_size=(640, 480))
    # the closed form is a start: within a few pixels of Zhang's refined result
    assert abs(z.K[0, 0] - a) < 3.0 and abs(z.K[1, 1] - b) < 3.0
    assert abs(z.K[0, 2] - u0) < 3.0 and abs(z.K[1, 2] - v0) < 3.0
    assert abs(z.K[0, 1] - (c if skew else 0.0)) < 1.0
    # radial distortion: right sign and magnitude
    assert -0.27 < z.dist[0] < -0.19 and k1 < 0
    assert 0.05 < z.dist[1] < 0.3 and k2 > 0
    for i in range(5):
        assert _rotation_deg(z.R[i], poses[i, :3]) < 0.5
        # inches, as the model; 1 % of the distance (a 2.5 px principal point offset moves t_y)
        assert np.linalg.norm(z.t[i] - poses[i, 3]) < 0.01 * np.linalg.norm(poses[i, 3])
    # Zhang's single pass (no distortion) is ~45 px off on this lens
    single = zhang_init(model, pixels, skew=skew, image_size=(640, 480), distortion_iterations=0)
    assert abs(single.K[0, 0] - a) > 20.0


def test_too_few_views():
    rng = np.random.default_rng(9)
    K = _camera(rng)
    _, _, pixels = _views(rng, K, 2)
    with pytest.raises(NotObservableError, match="at least 3 views") as err:
        zhang_init(GRID, pixels, skew=True)
    assert err.value.unknowns[:2] == ["fx", "fy"]
    with pytest.raises(NotObservableError, match="at least 2 views") as err:
        zhang_init(GRID, pixels[:1])
    assert "fx" in err.value.unknowns


@pytest.mark.parametrize("skew", [False, True])
@pytest.mark.parametrize("case", ["fronto", "parallel", "fronto_noisy"])
def test_degenerate_views_name_focal_length(case, skew):
    rng = np.random.default_rng(10)
    K = _camera(rng)
    base = {"fronto": np.eye(3), "parallel": cv2.Rodrigues(np.array([0.4, 0.1, 0.0]))[0]}
    base["fronto_noisy"] = base["fronto"]
    pixels = []
    for i in range(6):  # in-plane rotations and translations only: parallel planes
        R = base[case] @ cv2.Rodrigues(np.array([0.0, 0.0, 1.0 * i]))[0]
        t = np.array([0.02 * i - 0.1, -0.05, 0.6 + 0.05 * i]) - R @ np.array([0.1, 0.0625, 0.0])
        uv, _ = cv2.projectPoints(GRID3, cv2.Rodrigues(R)[0], t, K, None)
        pixels.append(uv.reshape(-1, 2))
    pixels = np.stack(pixels)
    if case == "fronto_noisy":
        pixels = pixels + rng.normal(scale=0.5, size=pixels.shape)
    with pytest.raises(NotObservableError, match="focal length is not observable; tilt the target") as err:
        zhang_init(GRID, pixels, skew=skew, image_size=(640, 480))
    assert "fx" in err.value.unknowns[0]


def test_extrinsics_sign_keeps_target_in_front():
    rng = np.random.default_rng(11)
    K = _camera(rng)
    R, t, pixels = _views(rng, K, 3)
    H = np.stack([K @ np.column_stack([r[:, 0], r[:, 1], tt]) for r, tt in zip(R, t)])
    R_e, t_e, _ = extrinsics_from_homographies(K, -3.0 * H)  # any scale, either sign
    np.testing.assert_allclose(R_e, R, atol=1e-10)
    np.testing.assert_allclose(t_e, t, atol=1e-10)


def test_bad_view_is_named():
    rng = np.random.default_rng(12)
    K = _camera(rng)
    _, _, pixels = _views(rng, K, 3)
    pixels[2, 4] = np.nan
    with pytest.raises(BadInputError, match="view 's2'"):
        zhang_init(GRID, pixels, view_names=["s0", "s1", "s2"])
