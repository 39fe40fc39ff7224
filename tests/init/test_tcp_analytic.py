"""Camera-based analytic TCP (Toffano): noise-free recovery, error amplification by Monte Carlo, degeneracy."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.init.tcp_analytic import tcp_from_camera_ray, tcp_three_pose, viewing_ray_base

K = np.array([[1400.0, 0.0, 640.0], [0.0, 1400.0, 512.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.08, 0.001, -0.0005, 0.0])


def rot(axis, deg):
    return Rotation.from_rotvec(np.deg2rad(deg) * np.asarray(axis, float)).as_matrix()


def servo_poses(rng, x, R_bc, rel_cam, d=None):
    """Flange poses whose tip (flange ``x``) is servoed back onto one viewing ray.

    Each pose is pose 0 rotated by ``rel_cam[i]`` (camera coordinates), then translated in the camera
    x-y plane (the visual servo) until the tip is back on the ray of direction ``d`` (base frame,
    default the camera z axis). Returns (N, 4, 4).
    """
    R0 = Rotation.random(random_state=rng).as_matrix()
    t0 = rng.uniform(-0.5, 0.5, 3) + [0.8, 0.0, 0.6]
    p0 = R0 @ x + t0
    ez = R_bc[:, 2]
    d = ez if d is None else d
    out = []
    for Rrel in rel_cam:
        Ri = R_bc @ Rrel @ R_bc.T @ R0
        lam = ez @ (Ri @ x + t0 - p0) / (ez @ d)  # servo keeps the camera-z position of the flange
        ti = p0 + lam * d - Ri @ x
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Ri, ti
        out.append(T)
    return np.stack(out)


def setup(seed):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.1, 0.1, 3) + [0.0, 0.0, 0.15]  # a 15 cm tool
    R_bc = Rotation.random(random_state=rng).as_matrix()
    return rng, x, R_bc


# --------------------------------------------------------------------------------------------- exactness


@given(
    seed=st.integers(0, 2**32 - 1),
    alpha=st.floats(10.0, 120.0) | st.floats(-120.0, -10.0),
    beta=st.floats(10.0, 60.0) | st.floats(-60.0, -10.0),
)
def test_three_pose_noise_free_exact(seed, alpha, beta):
    rng, x, R_bc = setup(seed)
    T = servo_poses(rng, x, R_bc, [np.eye(3), rot([0, 0, 1], alpha), rot([1, 0, 0], beta)])
    res = tcp_three_pose(T, R_bc)
    np.testing.assert_allclose(res.p_flange_tip, x, atol=1e-9)  # float64 closed form, metres
    assert res.rms < 1e-9  # servo in the camera x-y plane: no unused component moved
    # the least-squares variant on the same three poses and the camera-z ray gives the same TCP
    lsq = tcp_from_camera_ray(T, R_bc[:, 2])
    np.testing.assert_allclose(lsq.p_flange_tip, x, atol=1e-9)


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 30))
def test_ray_lsq_off_axis_pixel_exact(seed, n):
    """General rotations, tip held on an off-centre pixel of a distorted camera: exact recovery."""
    rng, x, R_bc = setup(seed)
    cam = camera_from_opencv(K, DIST, (1280, 1024))
    pixel = rng.uniform([100.0, 100.0], [1180.0, 924.0])
    d = viewing_ray_base(cam, pixel, R_bc)
    # independent ray: undistort with OpenCV, then rotate into the base frame
    import cv2

    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    xn = cv2.undistortPointsIter(pixel.reshape(1, 1, 2), K, DIST, None, None, crit).reshape(2)
    d_ref = R_bc @ np.append(xn, 1.0) / np.linalg.norm(np.append(xn, 1.0))
    np.testing.assert_allclose(d, d_ref, atol=1e-9)  # both iterate to convergence
    rel = [np.eye(3)] + [Rotation.from_rotvec(v).as_matrix() for v in rng.uniform(-0.6, 0.6, (n - 1, 3))]
    T = servo_poses(rng, x, R_bc, rel, d=d)
    res = tcp_from_camera_ray(T, d)
    np.testing.assert_allclose(res.p_flange_tip, x, atol=1e-9)
    assert res.rms < 1e-9


def test_three_pose_biased_off_axis_but_ray_lsq_exact():
    """The thesis' closed form assumes the ray is the camera z axis; off-axis it is biased."""
    rng, x, R_bc = setup(11)
    cam = camera_from_opencv(K, DIST, (1280, 1024))
    d = viewing_ray_base(cam, np.array([1100.0, 900.0]), R_bc)
    T = servo_poses(rng, x, R_bc, [np.eye(3), rot([0, 0, 1], 40), rot([1, 0, 0], 30)], d=d)
    assert np.linalg.norm(tcp_three_pose(T, R_bc).p_flange_tip - x) > 1e-4  # > 0.1 mm bias
    np.testing.assert_allclose(tcp_from_camera_ray(T, d).p_flange_tip, x, atol=1e-9)


def test_point_mode_is_pivot():
    rng, x, R_bc = setup(5)
    R = [Rotation.random(random_state=rng).as_matrix() for _ in range(5)]
    p = np.array([0.7, 0.1, 0.3])
    T = np.stack([np.block([[Ri, (p - Ri @ x)[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]) for Ri in R])
    np.testing.assert_allclose(tcp_from_camera_ray(T).p_flange_tip, x, atol=1e-9)


# --------------------------------------------------------------------------------------------- error amplification


@pytest.mark.parametrize("method", ["three_pose", "ray_lsq"])
def test_jacobians_match_finite_differences(method):
    rng, x, R_bc = setup(2)
    rel = [np.eye(3), rot([0, 0, 1], 35), rot([1, 0, 0], -25)]
    if method == "three_pose":
        T = servo_poses(rng, x, R_bc, rel)
        solve = lambda T: tcp_three_pose(T, R_bc)  # noqa: E731
    else:  # noisy (non-zero residuals exercise every term), general rotations, off-axis ray
        T = servo_poses(rng, x, R_bc, rel + [rot([0.3, 1, 0.2], 40), rot([1, -0.5, 0.4], -30)])
        T[:, :3, 3] += rng.normal(0.0, 1e-3, (5, 3))
        d = R_bc @ np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
        solve = lambda T: tcp_from_camera_ray(T, d)  # noqa: E731
    res = solve(T)
    n = len(T)
    h = 1e-6
    Jt = np.zeros((3, 3 * n))
    Jr = np.zeros((3, 3 * n))
    for k in range(3 * n):
        i, c = divmod(k, 3)
        for sgn in (1.0, -1.0):
            Tp = T.copy()
            Tp[i, c, 3] += sgn * h
            Jt[:, k] += sgn * solve(Tp).p_flange_tip / (2 * h)
            Tp = T.copy()
            Tp[i, :3, :3] = T[i, :3, :3] @ Rotation.from_rotvec(sgn * h * np.eye(3)[c]).as_matrix()
            Jr[:, k] += sgn * solve(Tp).p_flange_tip / (2 * h)
    np.testing.assert_allclose(res.jacobian_translation, Jt, atol=1e-7)  # central differences, h = 1e-6
    np.testing.assert_allclose(res.jacobian_rotation, Jr, atol=1e-7)


@pytest.mark.parametrize("method", ["three_pose", "ray_lsq"])
def test_monte_carlo_repeatability_matches_amplification(method):
    """Robot repeatability 0.03 mm per coordinate: TCP errors follow sigma^2 J J^T (chi^2 bound)."""
    rng, x, R_bc = setup(21)
    T0 = servo_poses(rng, x, R_bc, [np.eye(3), rot([0, 0, 1], 30), rot([1, 0, 0], 20)])
    sigma = 0.03e-3  # m
    solve = (lambda T: tcp_three_pose(T, R_bc)) if method == "three_pose" else (
        lambda T: tcp_from_camera_ray(T, R_bc[:, 2]))
    cov = solve(T0).covariance(sigma)
    trials = 500
    errs = np.empty((trials, 3))
    for k in range(trials):
        T = T0.copy()
        T[:, :3, 3] += rng.normal(0.0, sigma, (3, 3))
        errs[k] = solve(T).p_flange_tip - x
    stat = np.einsum("ki,ij,kj->", errs, np.linalg.inv(cov), errs)
    lo, hi = chi2.ppf([0.0005, 0.9995], 3 * trials)
    assert lo < stat < hi, (stat, lo, hi)
    # the TCP error is an amplified repeatability: larger than sigma along the poorly seen direction
    assert np.sqrt(np.linalg.eigvalsh(cov)[-1]) > sigma


# --------------------------------------------------------------------------------------------- degeneracy


def test_rotations_about_one_axis_not_observable():
    rng, x, R_bc = setup(4)
    T = servo_poses(rng, x, R_bc, [np.eye(3), rot([0, 0, 1], 30), rot([0, 0, 1], 70), rot([0, 0, 1], -40)])
    with pytest.raises(NotObservableError) as info:
        tcp_from_camera_ray(T, R_bc[:, 2])
    assert len(info.value.unknowns) == 1
    named = np.array([float(v) for v in info.value.unknowns[0].split("[")[1].split("]")[0].split(",")])
    axis_flange = T[0, :3, :3].T @ R_bc[:, 2]  # the camera z axis seen from the flange
    assert abs(abs(named @ axis_flange) - 1.0) < 1e-3
    with pytest.raises(NotObservableError, match="common rotation axis"):
        tcp_three_pose(T[:3], R_bc)


def test_rotations_about_camera_x_only_leave_that_axis():
    """Two different angles about one axis across the ray fix the tip except along that axis."""
    rng, x, R_bc = setup(8)
    T = servo_poses(rng, x, R_bc, [np.eye(3), rot([1, 0, 0], 30), rot([1, 0, 0], -30)])
    with pytest.raises(NotObservableError) as info:
        tcp_from_camera_ray(T, R_bc[:, 2])
    assert len(info.value.unknowns) == 1
    named = np.array([float(v) for v in info.value.unknowns[0].split("[")[1].split("]")[0].split(",")])
    assert abs(abs(named @ (T[0, :3, :3].T @ R_bc[:, 0])) - 1.0) < 1e-3


def test_bad_input():
    rng, x, R_bc = setup(9)
    T = servo_poses(rng, x, R_bc, [np.eye(3), rot([0, 1, 0], 30), rot([1, 0, 0], 30)])
    with pytest.raises(BadInputError, match="camera z axis"):
        tcp_three_pose(T, R_bc)
    with pytest.raises(BadInputError, match="exactly 3 poses"):
        tcp_three_pose(np.concatenate([T, T[:1]]), R_bc)
    with pytest.raises(BadInputError, match="ray_base"):
        tcp_from_camera_ray(T, [0.0, 0.0, 0.0])
    with pytest.raises(NotObservableError, match="at least 3 poses"):
        tcp_from_camera_ray(T[:2], R_bc[:, 2])
