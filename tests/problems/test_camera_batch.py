"""Batched camera calibration (``calibrate_cameras_batch``, one vmapped solve): every member
reaches OpenCV's optimum on identical corners, its standard deviations agree with OpenCV's, sets of
different sizes share one padded shape, and a bad member is reported in its place."""

import numpy as np
import pytest

from jcalib.errors import NotObservableError
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems.camera import CameraCalibrationOptions, calibrate_cameras_batch
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
SIZE = (1280, 960)
CAM = camera_from_opencv(np.array([[1000.0, 0, 650.0], [0, 1000.0, 470.0], [0, 0, 1]]),
                         np.array([-0.25, 0.08, 5e-4, -3e-4, 0.0]), SIZE)
CELL = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
                   "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})


def make_obs(poses, rng, sigma_px):
    stations, pixels = [], []
    for i, T in enumerate(poses):
        pix, vis = project_target(CAM, T, BOARD.points)
        assert vis.all()
        pix = pix + sigma_px * rng.standard_normal(pix.shape)
        pixels.append(pix)
        stations.append({"id": f"v{i:03d}", "detections": [{"camera": "cam0", "target": "board",
                         "point_index": list(range(len(BOARD.points))), "pixels": pix.tolist()}]})
    return parse_observations({
        "schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(SIZE)}},
        "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations,
    }), pixels


@pytest.fixture(scope="module")
def batch():
    rng = np.random.default_rng(21)
    sets = []
    for n in (10, 10, 12):  # 12 views pad to another bucket than 10: the batch re-pads to one shape
        poses = random_calibration_views(CAM, BOARD.points, n, rng=rng)
        sets.append(make_obs(poses, rng, sigma_px=0.3))
    fronto = []
    for i in range(6):
        T = np.eye(4)
        T[:3, 3] = [-0.12 + 0.01 * i, -0.08, 0.6 + 0.02 * i]
        fronto.append(T)
    bad, _ = make_obs(fronto, rng, sigma_px=0.1)
    obs = [o for o, _ in sets]
    results = calibrate_cameras_batch(CELL, [obs[0], bad, obs[1], obs[2]],
                                      CameraCalibrationOptions(outlier_threshold=None), raise_errors=False)
    return sets, results


def _opencv(pixels):
    import cv2

    obj = [BOARD.points.astype(np.float32)] * len(pixels)
    img = [p.astype(np.float32) for p in pixels]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    return cv2.calibrateCameraExtended(obj, img, SIZE, None, None, criteria=crit)


def test_every_member_reaches_opencvs_optimum(batch):
    sets, results = batch
    good = [results[0], results[2], results[3]]
    for (_, pixels), cal in zip(sets, good):
        rms, K, dist, _, _, std, _, _ = _opencv(pixels)
        K_ours, dist_ours = cal.cameras["cam0"].to_opencv()
        # Same optimum: OpenCV works in float32 corners -> agreement limited to ~1e-5 relative.
        np.testing.assert_allclose(K_ours, K, rtol=2e-5, atol=2e-3)
        np.testing.assert_allclose(dist_ours, dist.ravel(), atol=2e-5)
        assert abs(cal.rms_px - rms) < 1e-4
        assert cal.status == "converged"
        # OpenCV 4.14's std: sqrt(diag(JᵀJ)⁻¹ · Σr²/(m − n)), the same first-order covariance with
        # the same a-posteriori σ; only float32 corners and the stopping point differ (1 %).
        ours = np.sqrt(np.diag(cal.intrinsics_covariance["cam0"]))
        names = list(cal.cameras["cam0"].param_names)
        theirs = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), std.ravel()[:9]))
        for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
            np.testing.assert_allclose(ours[names.index(name)], theirs[name], rtol=0.01, err_msg=name)


def test_bad_member_is_reported_in_place(batch):
    _, results = batch
    assert isinstance(results[1], NotObservableError)
    assert "fx" in " ".join(results[1].unknowns)
    assert len(results) == 4


def test_raise_errors_raises_the_members_error(batch):
    sets, _ = batch
    rng = np.random.default_rng(0)
    T = np.eye(4)
    T[:3, 3] = [-0.12, -0.08, 0.6]
    bad, _ = make_obs([T] * 5, rng, sigma_px=0.1)
    with pytest.raises(NotObservableError):
        calibrate_cameras_batch(CELL, [sets[0][0], bad])
