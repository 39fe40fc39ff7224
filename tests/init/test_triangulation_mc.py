"""Triangulation covariance with camera uncertainty: Monte Carlo, finite differences, pose chains."""

import cv2
import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from jcalib.errors import BadInputError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.geometry.lie import local, se3_exp, se3_from_matrix, se3_to_matrix
from jcalib.init.pose_chains import compose_pose_chains
from jcalib.init.triangulation import triangulate_point, triangulate_points

SIZE = (1280, 1024)
K = np.array([[1200.0, 0.0, 640.0], [0.0, 1200.0, 512.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.25, 0.1, 0.0008, -0.0006, -0.02])
K2 = np.array([[900.0, 0.0, 650.0], [0.0, 905.0, 500.0], [0.0, 0.0, 1.0]])
DIST2 = np.array([-0.1, 0.02, 0.0, 0.0, 0.0])
# intrinsics sigma (fx, fy, cx, cy, k1, k2, p1, p2, k3): what a calibration from ~20 views reports, x3
SIG_K = np.array([1.5, 1.5, 1.2, 1.2, 2e-3, 4e-3, 1e-4, 1e-4, 5e-3])
SIG_POSE = np.array([4e-4, 4e-4, 4e-4, 3e-4, 3e-4, 3e-4])  # rad, m: a hand-eye / extrinsics result
LIMITS = (0.0005, 0.9995)  # two-sided chi-square bounds: a consistent covariance fails 1 in 1000


def look_at(centre, target, roll):
    """T_base_cam (4, 4) of a camera at ``centre`` looking at ``target``."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross([np.sin(roll), np.cos(roll), 0.3], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = centre
    return T


def project_cv(T_base_cam, X, K_, dist):
    T = np.linalg.inv(T_base_cam)
    rvec = cv2.Rodrigues(T[:3, :3])[0]
    return cv2.projectPoints(X.reshape(-1, 3), rvec, T[:3, 3], K_, dist)[0].reshape(-1, 2)


def right_perturb(T, d):
    return T @ np.asarray(se3_to_matrix(se3_exp(d)))


_local = jax.jit(lambda A, B: local(se3_from_matrix(A), se3_from_matrix(B)))


# Three views: views 0 and 1 are the same camera (one model object) at two poses, view 2 another one.
POINTS = np.array([[0.02, -0.03, 0.05], [0.18, 0.07, 0.02]])
T_BASE_CAM = np.stack([
    look_at(np.array([-0.6, 0.1, -1.2]), np.array([0.1, 0.0, 0.0]), 0.1),
    look_at(np.array([0.7, -0.2, -1.1]), np.array([0.1, 0.0, 0.0]), -0.2),
    look_at(np.array([0.1, 0.8, -1.0]), np.array([0.1, 0.0, 0.0]), 0.4),
])  # fmt: skip
VIEW_K = [(K, DIST), (K, DIST), (K2, DIST2)]


def test_monte_carlo_pixels_intrinsics_and_poses():
    """Reported covariance (pixels + intrinsics + poses) against the spread of re-triangulations with
    estimated cameras drawn from the stated covariances; also the distance of two points sharing them."""
    rng = np.random.default_rng(0)
    sigma_px = 0.3
    cov_K = np.diag(SIG_K**2)
    cov_pose = np.tile(np.diag(SIG_POSE**2), (3, 1, 1))
    truth_px = np.stack([project_cv(T, POINTS, K_, d) for T, (K_, d) in zip(T_BASE_CAM, VIEW_K)], axis=1)  # (2, 3, 2)
    true_dist = float(np.linalg.norm(POINTS[0] - POINTS[1]))
    trials = 200
    stat, stat_px_only, dstat = 0.0, 0.0, 0.0
    share = []
    for _ in range(trials):
        est = []
        for K_, d in ((K, DIST), (K2, DIST2)):  # estimated intrinsics = truth + calibration error
            e = SIG_K * rng.standard_normal(9)
            Ke = K_.copy()
            Ke[0, 0] += e[0]
            Ke[1, 1] += e[1]
            Ke[0, 2] += e[2]
            Ke[1, 2] += e[3]
            est.append(camera_from_opencv(Ke, d + e[4:], SIZE))
        cams = [est[0], est[0], est[1]]
        poses = np.stack([right_perturb(T, SIG_POSE * rng.standard_normal(6)) for T in T_BASE_CAM])
        px = truth_px + sigma_px * rng.standard_normal(truth_px.shape)
        res = triangulate_points(cams, px, T_base_cam=poses, sigma_px=sigma_px, names=["a", "b"],
                                 intrinsics_covariance=[cov_K, cov_K, cov_K], pose_covariance=cov_pose)
        for k in range(2):
            e = res[k].p_base - POINTS[k]
            stat += e @ np.linalg.solve(res[k].covariance, e)
            stat_px_only += e @ np.linalg.solve(res[k].covariance_px, e)
            share.append(np.trace(res[k].covariance_camera) / np.trace(res[k].covariance))
        d, sd = res.distance("a", "b")
        dstat += ((d - true_dist) / sd) ** 2
    lo, hi = chi2.ppf(LIMITS, 3 * 2 * trials)
    assert lo < stat < hi, (stat, lo, hi)
    assert stat_px_only > 2 * hi  # the test has power: pixel noise alone cannot explain the spread
    assert np.median(share) > 0.5  # camera uncertainty dominates in this set-up
    lo, hi = chi2.ppf(LIMITS, trials)
    assert lo < dstat < hi, (dstat, lo, hi)


def test_camera_covariance_matches_finite_differences():
    """covariance_camera == J C J^T with J = d(point)/d(intrinsics, pose tangents) by central differences."""
    cam = camera_from_opencv(K, DIST, SIZE)
    cam2 = camera_from_opencv(K2, DIST2, SIZE)
    px = np.stack([project_cv(T, POINTS[:1], K_, d)[0] for T, (K_, d) in zip(T_BASE_CAM, VIEW_K)])
    # noise-free pixels: the Gauss-Newton sensitivity -(J^T J)^-1 J^T dr/dtheta drops the r . d2r term,
    # so it is the exact derivative of the minimiser only at zero residual (with 0.5 px residuals the
    # two differ by ~3e-3 relative, far below what matters for a covariance)
    rng = np.random.default_rng(1)
    A = rng.normal(size=(9, 9)) * SIG_K
    cov_K = A.T @ A / 9
    B = rng.normal(size=(18, 18)) * np.tile(SIG_POSE, 3)
    cov_pose = B.T @ B / 18  # joint, correlated between views
    res = triangulate_point([cam, cam, cam2], px, T_base_cam=T_BASE_CAM, sigma_px=0.5,
                            intrinsics_covariance=[cov_K, None, cov_K], pose_covariance=cov_pose)

    def solve(p_cam1, p_cam2, poses):
        c1 = cam.with_params(p_cam1)
        c2 = cam2.with_params(p_cam2)
        return triangulate_point([c1, c1, c2], px, T_base_cam=poses, sigma_px=0.5).p_base

    theta1, theta2 = np.asarray(cam.params), np.asarray(cam2.params)
    J = np.zeros((3, 9 + 9 + 18))
    for j in range(36):
        cols = []
        for s in (1.0, -1.0):
            t1, t2, poses = theta1.copy(), theta2.copy(), T_BASE_CAM.copy()
            if j < 9:
                h = 1e-4 * max(abs(theta1[j]), 1e-2)
                t1[j] += s * h
            elif j < 18:
                h = 1e-4 * max(abs(theta2[j - 9]), 1e-2)
                t2[j - 9] += s * h
            else:
                h = 1e-6
                v, c = divmod(j - 18, 6)
                poses[v] = right_perturb(poses[v], s * h * np.eye(6)[c])
            cols.append(solve(t1, t2, poses))
        J[:, j] = (cols[0] - cols[1]) / (2 * h)
    C = np.zeros((36, 36))
    C[:9, :9] = C[9:18, 9:18] = cov_K
    C[18:, 18:] = cov_pose
    ref = J @ C @ J.T
    # central differences: relative error ~h^2 ~1e-8 plus GN convergence ~1e-12 m over h
    np.testing.assert_allclose(res.covariance_camera, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())
    np.testing.assert_allclose(res.covariance, res.covariance_px + res.covariance_camera, rtol=1e-12)


def test_pose_direction_does_not_change_the_covariance():
    """Poses given as T_base_cam or as T_cam_base (covariance moved through compose_pose_chains' inverse)
    give the same point and covariance."""
    cam = camera_from_opencv(K, DIST, SIZE)
    px = np.stack([project_cv(T, POINTS[1:], K, DIST)[0] for T in T_BASE_CAM])
    C_bc = np.diag(np.tile(SIG_POSE**2, 3))
    sources = {f"v{i}": (T, C_bc[6 * i : 6 * i + 6, 6 * i : 6 * i + 6]) for i, T in enumerate(T_BASE_CAM)}
    T_cb, C_cb = compose_pose_chains(sources, [[f"~v{i}"] for i in range(3)])
    np.testing.assert_allclose(T_cb, np.linalg.inv(T_BASE_CAM), atol=1e-12)
    a = triangulate_point(cam, px, T_base_cam=T_BASE_CAM, pose_covariance=C_bc, sigma_px=0.2)
    b = triangulate_point(cam, px, T_cb, pose_covariance=C_cb, sigma_px=0.2)
    np.testing.assert_allclose(a.p_base, b.p_base, atol=1e-12)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-9)


def test_compose_pose_chains_matches_finite_differences():
    rng = np.random.default_rng(2)

    def rand_pose():
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.uniform(-1, 1, 3)
        return T

    names = ["A", "B", "C", "D"]
    mats = {n: rand_pose() for n in names}
    covs = {}
    for n in names[:3]:  # D is exact
        M = rng.normal(size=(6, 6)) * 1e-3
        covs[n] = M @ M.T
    chains = [["A", "B"], ["~A", "C", "B"], ["B", "~B", "D"], [], ["~C"]]
    T, cov = compose_pose_chains({n: (mats[n], covs.get(n)) for n in names}, chains)
    np.testing.assert_allclose(T[1], np.linalg.inv(mats["A"]) @ mats["C"] @ mats["B"], atol=1e-12)
    np.testing.assert_allclose(T[3], np.eye(4), atol=0)

    def product(chain, pert):
        out = np.eye(4)
        for item in chain:
            n = item.lstrip("~")
            F = right_perturb(mats[n], pert.get(n, np.zeros(6)))
            out = out @ (np.linalg.inv(F) if item.startswith("~") else F)
        return out

    h = 1e-6
    J = np.zeros((6 * len(chains), 18))
    for s, n in enumerate(names[:3]):
        for c in range(6):
            e = np.eye(6)[c] * h
            for k, chain in enumerate(chains):
                d = np.asarray(_local(T[k], product(chain, {n: e}))) - np.asarray(_local(T[k], product(chain, {n: -e})))
                J[6 * k : 6 * k + 6, 6 * s + c] = d / (2 * h)
    C = np.zeros((18, 18))
    for s, n in enumerate(names[:3]):
        C[6 * s : 6 * s + 6, 6 * s : 6 * s + 6] = covs[n]
    np.testing.assert_allclose(cov, J @ C @ J.T, atol=1e-12)  # central differences at h = 1e-6, cov ~1e-6
    np.testing.assert_allclose(cov[12:18, 12:18], 0.0, atol=1e-18)  # B ~B D: B cancels, D exact


def test_bad_camera_covariances():
    cam = camera_from_opencv(K, DIST, SIZE)
    cam2 = camera_from_opencv(K2, DIST2, SIZE)
    px = np.stack([project_cv(T, POINTS[:1], K, DIST)[0] for T in T_BASE_CAM])
    with pytest.raises(BadInputError, match="intrinsics_covariance"):
        triangulate_point(cam, px, T_base_cam=T_BASE_CAM, intrinsics_covariance=np.eye(4))
    with pytest.raises(BadInputError, match="different camera models"):
        triangulate_point([cam, cam, cam2], px, T_base_cam=T_BASE_CAM, intrinsics_covariance=np.eye(9))
    with pytest.raises(BadInputError, match="share one camera model"):
        triangulate_point([cam, cam, cam2], px, T_base_cam=T_BASE_CAM,
                          intrinsics_covariance=[np.eye(9), 2 * np.eye(9), None])
    with pytest.raises(BadInputError, match="pose_covariance"):
        triangulate_point(cam, px, T_base_cam=T_BASE_CAM, pose_covariance=np.eye(6))
    with pytest.raises(BadInputError, match="seen in 1 view"):
        triangulate_points(cam, np.array([[[1.0, 2.0], [np.nan, np.nan], [np.nan, np.nan]]]), T_base_cam=T_BASE_CAM)
    with pytest.raises(BadInputError, match="unknown pose"):
        compose_pose_chains({"A": (np.eye(4), None)}, [["A", "~B"]])
