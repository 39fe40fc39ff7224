"""Camera calibration through the engine: real data against published answers, synthetic recovery,
agreement with OpenCV on identical corners, and clear errors on bad or degenerate input."""

import numpy as np
import pytest

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)


def make_obs(cameras, views, rng, sigma_px=0.0, points=BOARD.points):
    """Observations of ``views`` (list of {camera: T_cam_target}) seen by ``cameras`` {name: model}."""
    stations = []
    for i, per_cam in enumerate(views):
        dets = []
        for name, T in per_cam.items():
            pix, vis = project_target(cameras[name], T, points)
            assert vis.all()
            pix = pix + sigma_px * rng.standard_normal(pix.shape)
            dets.append({"camera": name, "target": "board", "point_index": list(range(len(points))),
                         "pixels": pix.tolist()})
        stations.append({"id": f"v{i:03d}", "detections": dets})
    return parse_observations({
        "schema": "jcalib.observations/1",
        "cameras": {n: {"image_size": list(m.image_size)} for n, m in cameras.items()},
        "targets": {"board": {"points": points.tolist()}},
        "stations": stations,
    })


def make_cell(models, **camera_options):
    return parse_cell({
        "schema": "jcalib.cell/1",
        "cameras": {n: {"model": m, **camera_options} for n, m in models.items()},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}},
    })


def test_zhang_1998_reproduces_published_values(real_data):
    """Zhang's data, model (k1, k2, skew): his published a, b, u0, v0, c, k1, k2 (MSR-TR-98-71)."""
    z = real_data / "zhang1998"
    model = np.loadtxt(z / "Model.txt").reshape(-1, 2) * 0.0254  # inches -> m
    points = np.c_[model, np.zeros(len(model))]
    stations = [
        {"id": f"CalibIm{i}", "detections": [{
            "camera": "cam", "target": "board", "point_index": list(range(len(points))),
            "pixels": np.loadtxt(z / f"data{i}.txt").reshape(-1, 2).tolist()}]}
        for i in range(1, 6)
    ]
    obs = parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [640, 480]}},
                              "targets": {"board": {"points": points.tolist()}}, "stations": stations})
    cell = parse_cell({"schema": "jcalib.cell/1",
                       "cameras": {"cam": {"model": "opencv5", "skew": True, "fix": ["p1", "p2", "k3"]}},
                       "targets": {"board": {"type": "checkerboard", "cols": 2, "rows": 2, "square": 0.01}}})
    cal = calibrate_cell(cell, obs, CalibrationOptions(outlier_threshold=None))
    p = dict(zip(cal.cameras["cam"].param_names, np.asarray(cal.cameras["cam"].params)))
    published = dict(fx=832.5, fy=832.53, cx=303.959, cy=206.585, skew=0.204494, k1=-0.228601, k2=0.190353)
    for name in ("fx", "fy", "cx", "cy"):
        assert abs(p[name] - published[name]) <= 0.01, name  # published to 0.01 px
    assert abs(p["skew"] - published["skew"]) <= 0.001
    for name in ("k1", "k2"):
        assert abs(p[name] - published[name]) <= 1e-4, name
    assert p["p1"] == p["p2"] == p["k3"] == 0.0  # fixed at zero exactly
    assert cal.status == "converged"


@pytest.mark.parametrize(
    "model, K, dist",
    [
        ("opencv5", [[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]], [-0.3, 0.12, 1e-3, -5e-4, -0.02]),
        ("pinhole", [[1200.0, 0, 630.0], [0, 1190.0, 470.0], [0, 0, 1]], []),
    ],
)
def test_noise_free_synthetic_recovers_truth(model, K, dist):
    rng = np.random.default_rng(1)
    cam = camera_from_opencv(np.array(K), np.array(dist), (1280, 960))
    views = random_calibration_views(cam, BOARD.points, 12, rng=rng)
    obs = make_obs({"cam0": cam}, [{"cam0": T} for T in views], rng)
    cal = calibrate_cell(make_cell({"cam0": model}), obs)
    # Noise-free data: parameter recovery to 1e-6 relative (float64 solve; 1e-6 covers the
    # conditioning of higher-order distortion terms).
    np.testing.assert_allclose(np.asarray(cal.cameras["cam0"].params), np.asarray(cam.params), rtol=1e-6, atol=1e-8)
    assert cal.rms_px < 1e-6


def test_rational_model_on_ordinary_lens_names_its_degenerate_directions():
    """The rational model's numerator and denominator agree to first order (1 + k1 r²)/(1 + k4 r²):
    on a moderate field of view the data cannot separate them, and jcalib says so by name."""
    rng = np.random.default_rng(1)
    cam = camera_from_opencv(np.array([[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]]),
                             np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02, 0.01, 0.003, 0.001]), (1280, 960))
    views = random_calibration_views(cam, BOARD.points, 12, rng=rng)
    obs = make_obs({"cam0": cam}, [{"cam0": T} for T in views], rng)
    with pytest.raises(NotObservableError) as info:
        calibrate_cell(make_cell({"cam0": "opencv8"}), obs)
    named = " ".join(info.value.unknowns)
    assert "cam0 k1" in named and "cam0 k4" in named


def test_matches_opencv_on_identical_noisy_corners():
    import cv2

    rng = np.random.default_rng(7)
    cam = camera_from_opencv(np.array([[1000.0, 0, 650.0], [0, 1000.0, 470.0], [0, 0, 1]]),
                             np.array([-0.25, 0.08, 5e-4, -3e-4, 0.0]), (1280, 960))
    views = random_calibration_views(cam, BOARD.points, 15, rng=rng)
    obs = make_obs({"cam0": cam}, [{"cam0": T} for T in views], rng, sigma_px=0.3)
    cal = calibrate_cell(make_cell({"cam0": "opencv5"}), obs, CalibrationOptions(outlier_threshold=None))
    obj = [BOARD.points.astype(np.float32)] * len(views)
    img = [s.detections[0].pixels.astype(np.float32) for s in obs.stations]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, (1280, 960), None, None, criteria=crit)
    K_ours, dist_ours = cal.cameras["cam0"].to_opencv()
    # Same optimum: OpenCV works in float32 corners -> agreement limited to ~1e-5 px in focal.
    np.testing.assert_allclose(K_ours, K, rtol=2e-5, atol=2e-3)
    np.testing.assert_allclose(dist_ours, dist.ravel(), atol=2e-5)
    assert abs(cal.rms_px - rms) < 1e-4


def test_stereo_rig_recovers_relative_pose():
    rng = np.random.default_rng(3)
    cam0 = camera_from_opencv(np.array([[900.0, 0, 640], [0, 900, 480], [0, 0, 1]]),
                              np.array([-0.2, 0.05, 0, 0, 0]), (1280, 960))
    cam1 = camera_from_opencv(np.array([[950.0, 0, 630], [0, 948, 470], [0, 0, 1]]),
                              np.array([-0.22, 0.06, 0, 0, 0]), (1280, 960))
    T_cam1_cam0 = np.eye(4)
    c, s = np.cos(0.1), np.sin(0.1)
    T_cam1_cam0[:3, :3] = [[c, 0, -s], [0, 1, 0], [s, 0, c]]
    T_cam1_cam0[:3, 3] = [-0.12, 0.002, 0.01]
    views = []
    for T in random_calibration_views(cam0, BOARD.points, 30, rng=rng, fill=(0.25, 0.45)):
        pix, vis = project_target(cam1, T_cam1_cam0 @ T, BOARD.points)
        if vis.all():
            views.append({"cam0": T, "cam1": T_cam1_cam0 @ T})
    assert len(views) >= 8
    obs = make_obs({"cam0": cam0, "cam1": cam1}, views, rng)
    cal = calibrate_cell(make_cell({"cam0": "opencv5", "cam1": "opencv5"}), obs)
    assert cal.frame == "cam0" and set(cal.transforms) == {"T_cam0_cam1"}  # the rig frame is cam0's
    np.testing.assert_allclose(cal.transforms["T_cam0_cam1"], np.linalg.inv(T_cam1_cam0), atol=1e-8)
    np.testing.assert_allclose(np.asarray(cal.cameras["cam1"].params), np.asarray(cam1.params), rtol=1e-6, atol=1e-8)


def test_fronto_parallel_views_are_not_observable():
    cam = camera_from_opencv(np.array([[900.0, 0, 640], [0, 900, 480], [0, 0, 1]]), np.zeros(5), (1280, 960))
    views = []
    for i in range(6):
        T = np.eye(4)
        T[:3, 3] = [-0.12 + 0.01 * i, -0.08, 0.6 + 0.02 * i]
        views.append({"cam0": T})
    obs = make_obs({"cam0": cam}, views, np.random.default_rng(0), sigma_px=0.1)
    with pytest.raises(NotObservableError) as info:
        calibrate_cell(make_cell({"cam0": "opencv5"}), obs)
    assert "fx" in " ".join(info.value.unknowns)


def test_bad_inputs_name_the_problem():
    rng = np.random.default_rng(5)
    cam = camera_from_opencv(np.array([[900.0, 0, 640], [0, 900, 480], [0, 0, 1]]), np.zeros(5), (1280, 960))
    views = [{"cam0": T} for T in random_calibration_views(cam, BOARD.points, 5, rng=rng)]
    obs = make_obs({"cam0": cam}, views, rng).to_dict()
    three = obs["stations"][2]["detections"][0]
    three["point_index"], three["pixels"] = three["point_index"][:3], three["pixels"][:3]
    with pytest.raises(BadInputError, match="v002.*only 3 points of target 'board'"):
        calibrate_cell(make_cell({"cam0": "opencv5"}), parse_observations(obs))
    with pytest.raises(BadInputError, match="nodist"):
        calibrate_cell(make_cell({"cam0": "opencv5"}, fix=["nodist"]), make_obs({"cam0": cam}, views, rng))


@pytest.mark.parametrize("options", [{}, {"skew": True}, {"fix": ["aspect", "k3"]}, {"fix": ["cx", "cy"]}])
def test_zhang_start_and_a_given_start_reach_one_optimum(options):
    """The closed-form (Zhang) start and a start from intrinsics given in the cell (20 px off, no
    distortion; held coordinates at the same values) end at one optimum: the answer does not depend
    on where the solve started. (The camera family's in-jit Zhang start is gone: Zhang runs once, on
    the host, for every cell.)"""
    rng = np.random.default_rng(17)
    model = camera_from_opencv(np.array([[900.0, 0, 639.5], [0, 900.0, 479.5], [0, 0, 1]]),
                               np.array([-0.1, 0.02, 0.0, 0.0, 0.0]), (1280, 960))
    poses = random_calibration_views(model, BOARD.points, 12, rng=rng)
    obs = make_obs({"cam": model}, [{"cam": T} for T in poses], rng, sigma_px=0.2)
    given = {"K": [[880.0, 0.0, 639.5], [0.0, 880.0, 479.5], [0.0, 0.0, 1.0]], "dist": [0.0] * 5}
    zhang = calibrate_cell(make_cell({"cam": "opencv5"}, **options), obs)
    start = calibrate_cell(make_cell({"cam": "opencv5"}, intrinsics=given, **options), obs)
    assert zhang.status == start.status == "converged"
    assert zhang.outliers == start.outliers
    # one optimum to solver tolerance, in units of each parameter's σ
    sigma = np.sqrt(np.diag(zhang.intrinsics_covariance["cam"]))
    diff = np.abs(np.asarray(zhang.cameras["cam"].params) - np.asarray(start.cameras["cam"].params))
    free = sigma > 0
    assert np.all(diff[free] <= 1e-5 * sigma[free]), (diff, sigma)
    assert np.all(diff[~free] <= 1e-12)
    np.testing.assert_allclose(zhang.intrinsics_covariance["cam"], start.intrinsics_covariance["cam"],
                               rtol=1e-6, atol=1e-14)
