"""Multi-view triangulation: OpenCV, ground truth, an independent optimiser, Monte Carlo covariance."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.optimize import least_squares
from scipy.stats import chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.init.triangulation import point_distance, triangulate_dlt, triangulate_point

SIZE = (1280, 1024)
K = np.array([[1200.0, 0.0, 640.0], [0.0, 1200.0, 512.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.25, 0.1, 0.0008, -0.0006, -0.02])
CAM = camera_from_opencv(K, DIST, SIZE)
PINHOLE = camera_from_opencv(K, np.zeros(0), SIZE)
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)


def look_at(centre, target, rng):
    """T_cam_base (4, 4) of a camera at ``centre`` looking at ``target`` (random roll)."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(rng.normal(size=3), z)
    x /= np.linalg.norm(x)
    R_base_cam = np.column_stack([x, np.cross(z, x), z])
    T = np.eye(4)
    T[:3, :3] = R_base_cam.T
    T[:3, 3] = -R_base_cam.T @ centre
    return T


def rig(rng, n, point, radius=1.5, spread=0.6):
    """n cameras around ``point`` at ~``radius`` m, looking at it (roughly)."""
    T = []
    for _ in range(n):
        d = rng.normal(size=3) * [spread, spread, 0.3] + [0.0, 0.0, -1.0]
        centre = point + radius * d / np.linalg.norm(d)
        T.append(look_at(centre, point + rng.normal(0, 0.05, 3), rng))
    return np.stack(T)


def project_cv(T, X, dist=DIST):
    rvec = cv2.Rodrigues(T[:3, :3])[0]
    return cv2.projectPoints(X.reshape(1, 3), rvec, T[:3, 3], K, dist)[0].reshape(2)


# --------------------------------------------------------------------------------------------- exactness


def test_pinhole_matches_cv2_triangulate_points():
    rng = np.random.default_rng(0)
    X = np.array([0.1, -0.2, 1.0])
    T = rig(rng, 2, X)
    px = np.stack([project_cv(Ti, X, np.zeros(5)) for Ti in T])
    P = [K @ Ti[:3] for Ti in T]
    ref = cv2.triangulatePoints(P[0], P[1], px[0].reshape(2, 1), px[1].reshape(2, 1)).reshape(4)
    ref = ref[:3] / ref[3]
    res = triangulate_point(PINHOLE, px, T)
    np.testing.assert_allclose(res.p_base, ref, atol=1e-9)  # noise-free: both exact (float64, ~1 m)
    np.testing.assert_allclose(triangulate_dlt(PINHOLE, px, T), ref, atol=1e-9)
    np.testing.assert_allclose(res.p_base, X, atol=1e-9)


def test_distorted_dlt_matches_cv2_on_undistorted_points():
    rng = np.random.default_rng(1)
    X = np.array([-0.3, 0.2, 0.5])
    T = rig(rng, 2, X)
    px = np.stack([project_cv(Ti, X) for Ti in T])
    xn = [cv2.undistortPointsIter(p.reshape(1, 1, 2), K, DIST, None, None, CRIT).reshape(2, 1) for p in px]
    ref = cv2.triangulatePoints(T[0][:3], T[1][:3], xn[0], xn[1]).reshape(4)
    np.testing.assert_allclose(triangulate_dlt(CAM, px, T), ref[:3] / ref[3], atol=1e-9)


@given(seed=st.integers(0, 2**32 - 1), n=st.sampled_from([2, 4]), inverse=st.booleans())
def test_noise_free_recovers_ground_truth(seed, n, inverse):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1.0, 1.0, 3)
    T = rig(rng, n, X)
    px = np.stack([project_cv(Ti, X) for Ti in T])
    if inverse:
        res = triangulate_point(CAM, px, T_base_cam=np.linalg.inv(T))
    else:
        res = triangulate_point([CAM] * n, px, T)
    np.testing.assert_allclose(res.p_base, X, atol=1e-9)  # float64, exact unproject
    assert res.rms_px < 1e-6
    assert res.p_base.dtype == np.float64


def test_refinement_matches_independent_optimiser():
    """Noisy pixels: the GN optimum equals scipy's least_squares on cv2.projectPoints residuals."""
    rng = np.random.default_rng(2)
    X = np.array([0.2, 0.1, 0.3])
    T = rig(rng, 3, X)
    px = np.stack([project_cv(Ti, X) for Ti in T]) + rng.normal(0, 2.0, (3, 2))
    res = triangulate_point(CAM, px, T)
    ref = least_squares(lambda Y: np.concatenate([project_cv(Ti, Y) for Ti in T]) - px.reshape(-1), res.p_base_dlt,
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(res.p_base, ref.x, atol=1e-9)
    assert res.rms_px <= np.sqrt(np.mean(np.square(
        np.stack([project_cv(Ti, res.p_base_dlt) for Ti in T]) - px))) + 1e-12


# --------------------------------------------------------------------------------------------- uncertainty


def test_monte_carlo_covariance_and_distance():
    rng = np.random.default_rng(3)
    A, B = np.array([0.0, 0.0, 0.0]), np.array([0.25, -0.1, 0.05])
    T = rig(rng, 3, 0.5 * (A + B))
    pa = np.stack([project_cv(Ti, A) for Ti in T])
    pb = np.stack([project_cv(Ti, B) for Ti in T])
    sigma = 0.5
    trials = 300
    stat, dstat = 0.0, 0.0
    true_d = np.linalg.norm(A - B)
    for _ in range(trials):
        ra = triangulate_point(CAM, pa + rng.normal(0, sigma, pa.shape), T, sigma_px=sigma)
        rb = triangulate_point(CAM, pb + rng.normal(0, sigma, pb.shape), T, sigma_px=sigma)
        e = ra.p_base - A
        stat += e @ np.linalg.solve(ra.covariance, e)
        d, sd = point_distance(ra, rb)
        dstat += ((d - true_d) / sd) ** 2
    lo, hi = chi2.ppf([0.0005, 0.9995], 3 * trials)
    assert lo < stat < hi, (stat, lo, hi)
    lo, hi = chi2.ppf([0.0005, 0.9995], trials)
    assert lo < dstat < hi, (dstat, lo, hi)


def test_point_distance_linear_propagation():
    a = (np.array([1.0, 0.0, 0.0]), np.diag([4.0, 1.0, 1.0]))
    b = (np.array([0.0, 0.0, 0.0]), np.diag([5.0, 1.0, 1.0]))
    d, s = point_distance(a, b)
    assert d == 1.0 and np.isclose(s, 3.0)  # sqrt(4 + 5): only the x variances matter
    d, s = point_distance(a, b, cross_covariance=np.diag([2.0, 0.0, 0.0]))
    assert np.isclose(s, np.sqrt(4.0 + 5.0 - 4.0))


# --------------------------------------------------------------------------------------------- degeneracy


def test_parallel_rays_not_observable():
    rng = np.random.default_rng(4)
    X = np.array([0.0, 0.0, 5.0])
    T1 = look_at(np.zeros(3), X, rng)
    T2 = look_at(np.array([1e-4, 0.0, 0.0]), X, rng)  # 0.1 mm baseline at 5 m
    px = np.stack([project_cv(Ti, X) for Ti in (T1, T2)])
    with pytest.raises(NotObservableError) as info:
        triangulate_point(CAM, px, np.stack([T1, T2]))
    assert info.value.unknowns == ["depth of the point along the viewing ray"]


def test_rays_meeting_behind_camera():
    rng = np.random.default_rng(5)
    X = np.array([0.0, 0.0, 1.0])
    T1 = look_at(np.array([-0.5, 0.0, 0.0]), X, rng)
    T2 = look_at(np.array([0.5, 0.0, 0.0]), X, rng)
    # pixels of two points that make the rays diverge: they meet behind the cameras
    zero = np.zeros(5)
    px = np.stack([project_cv(T1, np.array([-0.8, 0.0, 1.0]), zero), project_cv(T2, np.array([0.8, 0.0, 1.0]), zero)])
    with pytest.raises(NotObservableError, match="behind camera"):
        triangulate_point(PINHOLE, px, np.stack([T1, T2]))


def test_bad_input():
    T = rig(np.random.default_rng(6), 2, np.zeros(3))
    with pytest.raises(BadInputError, match="pixels"):
        triangulate_point(CAM, np.zeros((1, 2)), T[:1])
    with pytest.raises(BadInputError, match="T_cam_base"):
        triangulate_point(CAM, np.zeros((2, 2)) + 500, T[:1])
    with pytest.raises(BadInputError, match="exactly one"):
        triangulate_point(CAM, np.zeros((2, 2)) + 500, T, T_base_cam=T)
    with pytest.raises(BadInputError, match="cameras"):
        triangulate_point([CAM], np.zeros((2, 2)) + 500, T)


def test_mixed_cameras_including_fisheye():
    rng = np.random.default_rng(7)
    X = np.array([0.05, 0.1, -0.2])
    T = rig(rng, 3, X)
    D = np.array([0.05, -0.01, 0.002, -0.001])
    fish = camera_from_opencv(K, D, SIZE, fisheye=True)
    rvec = cv2.Rodrigues(T[2][:3, :3])[0]
    px = np.stack([
        project_cv(T[0], X),
        project_cv(T[1], X, np.zeros(5)),
        cv2.fisheye.projectPoints(X.reshape(1, 1, 3), rvec, T[2][:3, 3], K, D)[0].reshape(2),
    ])
    res = triangulate_point([CAM, PINHOLE, fish], px, T)
    np.testing.assert_allclose(res.p_base, X, atol=1e-9)
    np.testing.assert_allclose(res.p_base_dlt, X, atol=1e-9)
