"""RoboCalib's chain: a point triangulated by a robot-held stereo rig, in camera, target (Phys3D),
flange (Hand3D) and base frames, with covariance; and a work-object frame from triangulated points."""

import cv2
import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from jcalib.errors import BadInputError
from jcalib.geometry.cameras import camera_from_opencv
from jcalib.geometry.lie import local, se3_exp, se3_from_matrix, se3_to_matrix
from jcalib.init.frames import frame_from_points, frame_from_three_points
from jcalib.init.pose_chains import compose_pose_chains, point_in_frame
from jcalib.init.triangulation import triangulate_points

SIZE = (1280, 1024)
K = np.array([[1400.0, 0.0, 640.0], [0.0, 1400.0, 512.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.08, 0.0005, -0.0003, -0.01])
CAM = camera_from_opencv(K, DIST, SIZE)
LIMITS = (0.0005, 0.9995)  # two-sided chi-square bounds: a consistent covariance fails 1 in 1000


def pose(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def right_perturb(T, d):
    return T @ np.asarray(se3_to_matrix(se3_exp(d)))


_local = jax.jit(lambda A, B: local(se3_from_matrix(A), se3_from_matrix(B)))

# ground truth of the cell (metres)
T_FLANGE_CAM0 = pose([0.02, -0.03, 1.6], [0.06, -0.04, 0.09])
T_CAM0_CAM1 = pose([0.0, -0.25, 0.0], [0.16, 0.0, 0.02])  # stereo rig, 16 cm baseline, toed in
T_BASE_FLANGE = pose([np.pi - 0.1, 0.05, 0.2], [0.9, 0.1, 0.85])  # looking down at the table
T_BASE_CAM0 = T_BASE_FLANGE @ T_FLANGE_CAM0
# plate 0.5 m in front of cam0 (its x-y plane facing the camera, roughly)
T_CAM0_TARGET = pose([0.1, -0.15, 0.05], [0.05, 0.02, 0.5])
P_TARGET = np.array([[0.0, 0.0, 0.0], [0.12, 0.01, 0.0], [0.03, 0.09, 0.0], [0.1, 0.1, 0.004]])  # on the plate
P_CAM0 = P_TARGET @ T_CAM0_TARGET[:3, :3].T + T_CAM0_TARGET[:3, 3]
P_BASE = P_CAM0 @ T_BASE_CAM0[:3, :3].T + T_BASE_CAM0[:3, 3]
T_CAM_CAM0 = np.stack([np.eye(4), np.linalg.inv(T_CAM0_CAM1)])  # T_cam_<ref=cam0> of each view

C_HE = np.diag([3e-4, 3e-4, 5e-4, 2e-4, 2e-4, 3e-4]) ** 2  # hand-eye result (rad, m)
C_ROBOT = np.diag([2e-5, 2e-5, 2e-5, 3e-5, 3e-5, 3e-5]) ** 2  # robot repeatability
C_PLATE = np.diag([1e-3, 1e-3, 4e-4, 1e-4, 1e-4, 3e-4]) ** 2  # plate pose from PnP


def stereo_pixels(points_cam0, rng=None, sigma=0.0):
    px = []
    for T in T_CAM_CAM0:
        rvec = cv2.Rodrigues(T[:3, :3])[0]
        px.append(cv2.projectPoints(points_cam0, rvec, T[:3, 3], K, DIST)[0].reshape(-1, 2))
    px = np.stack(px, axis=1)  # (M, 2 views, 2)
    return px if rng is None else px + sigma * rng.standard_normal(px.shape)


def test_frames_agree_exactly_on_noise_free_data():
    pts = triangulate_points(CAM, stereo_pixels(P_CAM0), T_CAM_CAM0, sigma_px=0.2)
    T_base_target = T_BASE_CAM0 @ T_CAM0_TARGET
    for k in range(len(P_CAM0)):
        kw = {"T_cam_target": T_CAM0_TARGET, "T_flange_cam": T_FLANGE_CAM0, "T_base_flange": T_BASE_FLANGE}
        cam = point_in_frame(pts[k], "cam", **kw).position
        target = point_in_frame(pts[k], "target", **kw).position
        flange = point_in_frame(pts[k], "flange", **kw).position
        base = point_in_frame(pts[k], "base", **kw).position
        # float64 chain of 1 m transforms: 1e-9 m
        np.testing.assert_allclose(cam, P_CAM0[k], atol=1e-9)
        np.testing.assert_allclose(target, P_TARGET[k], atol=1e-9)
        np.testing.assert_allclose(base, P_BASE[k], atol=1e-9)
        np.testing.assert_allclose(T_BASE_FLANGE[:3, :3] @ flange + T_BASE_FLANGE[:3, 3], base, atol=1e-9)
        np.testing.assert_allclose(T_base_target[:3, :3] @ target + T_base_target[:3, 3], base, atol=1e-9)


def test_chain_gives_ground_truth_within_sigma():
    """Monte Carlo: pixel noise, hand-eye, robot pose and plate pose errors drawn from their stated
    covariances; the chained point's error normalised by its covariance follows chi2(3) in every frame."""
    rng = np.random.default_rng(0)
    trials = 200
    stats = {"cam": 0.0, "target": 0.0, "flange": 0.0, "base": 0.0}
    truth = {"cam": P_CAM0, "target": P_TARGET, "flange": P_CAM0 @ T_FLANGE_CAM0[:3, :3].T + T_FLANGE_CAM0[:3, 3],
             "base": P_BASE}  # fmt: skip
    L = {n: np.linalg.cholesky(c) for n, c in (("he", C_HE), ("robot", C_ROBOT), ("plate", C_PLATE))}
    share = []
    for _ in range(trials):
        pts = triangulate_points(CAM, stereo_pixels(P_CAM0, rng, 0.2), T_CAM_CAM0, sigma_px=0.2)
        kw = {
            "T_cam_target": right_perturb(T_CAM0_TARGET, L["plate"] @ rng.standard_normal(6)),
            "T_flange_cam": right_perturb(T_FLANGE_CAM0, L["he"] @ rng.standard_normal(6)),
            "T_base_flange": right_perturb(T_BASE_FLANGE, L["robot"] @ rng.standard_normal(6)),
            "T_cam_target_covariance": C_PLATE, "T_flange_cam_covariance": C_HE, "T_base_flange_covariance": C_ROBOT,
        }  # fmt: skip
        k = int(rng.integers(len(P_CAM0)))
        for frame in stats:
            out = point_in_frame(pts[k], frame, **kw)
            e = out.position - truth[frame][k]
            stats[frame] += e @ np.linalg.solve(out.covariance, e)
            if frame == "base":
                share.append(np.trace(pts[k].covariance) / np.trace(out.covariance))
    lo, hi = chi2.ppf(LIMITS, 3 * trials)
    for frame, s in stats.items():
        assert lo < s < hi, (frame, s, lo, hi)
    assert np.median(share) < 0.5  # the transforms, not the pixels, dominate the base-frame error


def test_chain_equals_direct_triangulation_in_base():
    """Triangulating in the base frame with the rig poses composed by compose_pose_chains (hand-eye and
    robot pose shared by both views) gives the same point and covariance as triangulating in cam0 and
    moving the point along the chain: the pose errors move the rig rigidly."""
    rng = np.random.default_rng(1)
    px = stereo_pixels(P_CAM0[:2], rng, 0.3)
    sources = {"T_base_flange": (T_BASE_FLANGE, C_ROBOT), "T_flange_cam0": (T_FLANGE_CAM0, C_HE),
               "T_cam0_cam1": (T_CAM0_CAM1, None)}  # fmt: skip
    T_base_cam, cov = compose_pose_chains(sources, [["T_base_flange", "T_flange_cam0"],
                                                    ["T_base_flange", "T_flange_cam0", "T_cam0_cam1"]])
    direct = triangulate_points(CAM, px, T_base_cam=T_base_cam, pose_covariance=cov, sigma_px=0.3)
    in_cam = triangulate_points(CAM, px, T_CAM_CAM0, sigma_px=0.3)
    for k in range(2):
        chained = point_in_frame(in_cam[k], "base", T_flange_cam=T_FLANGE_CAM0, T_base_flange=T_BASE_FLANGE,
                                 T_flange_cam_covariance=C_HE, T_base_flange_covariance=C_ROBOT)
        np.testing.assert_allclose(direct[k].p_base, chained.position, atol=1e-9)  # same optimum, float64
        np.testing.assert_allclose(direct[k].covariance, chained.covariance, rtol=1e-7)  # identical linearisation
    # the two points share the pose errors: strongly correlated in the base frame, not in cam0
    c01 = direct.cross_covariance(0, 1)
    cam0, cam1 = direct[0].covariance_camera, direct[1].covariance_camera
    assert np.trace(c01) > 0.8 * np.sqrt(np.trace(cam0) * np.trace(cam1))
    assert np.abs(in_cam.cross_covariance(0, 1)).max() == 0.0


def test_frame_from_triangulated_points_monte_carlo():
    """A work-object frame from three points triangulated with uncertain hand-eye / robot poses: the
    joint (9, 9) point covariance (correlated through the shared poses) gives a frame covariance that
    matches the spread (chi2(6)); the plane-fit (N-point) frame likewise."""
    rng = np.random.default_rng(2)
    sources = {"T_base_flange": (T_BASE_FLANGE, C_ROBOT), "T_flange_cam0": (T_FLANGE_CAM0, C_HE / 4),
               "T_cam0_cam1": (T_CAM0_CAM1, None)}  # fmt: skip
    _, cov = compose_pose_chains(sources, [["T_base_flange", "T_flange_cam0"],
                                           ["T_base_flange", "T_flange_cam0", "T_cam0_cam1"]])
    T3_true = frame_from_three_points(*P_BASE[:3]).T_base_wobj  # frames of the true points
    Tn_true = frame_from_points(P_BASE).T_base_wobj  # (the 4th point is 4 mm off the plane)
    L_robot, L_he = np.linalg.cholesky(C_ROBOT), np.linalg.cholesky(C_HE / 4)
    trials = 150
    stat3, statn = 0.0, 0.0
    for _ in range(trials):
        T_bf = right_perturb(T_BASE_FLANGE, L_robot @ rng.standard_normal(6))  # what the robot reports
        T_fc = right_perturb(T_FLANGE_CAM0, L_he @ rng.standard_normal(6))  # what hand-eye calibration gave
        Tb = np.stack([T_bf @ T_fc, T_bf @ T_fc @ T_CAM0_CAM1])
        pts = triangulate_points(CAM, stereo_pixels(P_CAM0, rng, 0.2), T_base_cam=Tb, pose_covariance=cov,
                                 sigma_px=0.2)
        f3 = frame_from_three_points(*pts.p_base[:3], covariance=pts.covariance[:9, :9])
        e = np.asarray(_local(T3_true, f3.T_base_wobj))
        stat3 += e @ np.linalg.solve(f3.covariance, e)
        fn = frame_from_points(pts.p_base, covariance=pts.covariance)
        e = np.asarray(_local(Tn_true, fn.T_base_wobj))
        statn += e @ np.linalg.solve(fn.covariance, e)
    lo, hi = chi2.ppf(LIMITS, 6 * trials)
    assert lo < stat3 < hi, (stat3, lo, hi)
    assert lo < statn < hi, (statn, lo, hi)


def test_chain_bad_input():
    p = (np.array([0.0, 0.0, 1.0]), np.eye(3) * 1e-8)
    with pytest.raises(BadInputError, match="frame"):
        point_in_frame(p, "world")
    with pytest.raises(BadInputError, match="T_base_flange"):
        point_in_frame(p, "base", T_flange_cam=np.eye(4))
    with pytest.raises(BadInputError, match="T_cam_target"):
        point_in_frame(p, "target")
    with pytest.raises(BadInputError, match="T_flange_cam_covariance"):
        point_in_frame(p, "flange", T_flange_cam=np.eye(4), T_flange_cam_covariance=np.eye(3))
    out = point_in_frame((np.ones(3), None), "cam")
    np.testing.assert_array_equal(out.covariance, np.zeros((3, 3)))
