"""Analysis behind the report (camera cells): each function against an independent reference."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jcalib
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.result import CameraResult, TransformResult
from jcalib.problems.camera import CameraCalibrationOptions
from jcalib.report import analysis as A
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.025)
K_TRUE = np.array([[1000.0, 0, 640], [0, 1000, 480], [0, 0, 1]])
DIST_TRUE = np.array([-0.2, 0.05, 0, 0, 0])
SIZE = (1280, 960)
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}}}
STATED = CameraCalibrationOptions(noise="stated", sigma_px=0.2)
CAMERA = camera_from_opencv(K_TRUE, DIST_TRUE, SIZE)


def _observations(views, rng, sigma=0.2):
    stations = []
    for i, T in enumerate(views):
        pix, _ = project_target(CAMERA, T, BOARD.points)
        pix = pix + sigma * rng.standard_normal(pix.shape)
        stations.append({"id": f"s{i:02d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(SIZE)}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(11)
    obs = _observations(random_calibration_views(CAMERA, BOARD.points, 8, rng=rng), rng)
    result = jcalib.calibrate(CELL, obs, STATED)
    return obs, result, A.linear_models(result, obs)["cam0"]


def test_linear_model_reproduces_the_solvers_covariance(data):
    """The information rebuilt from the result file (per-view poses, JAX Jacobians, Schur
    complement in numpy) inverts to the engine's reported intrinsics covariance."""
    obs, result, model = data
    ref = result.file.cameras["cam0"].covariance
    # two float64 linearisations at the same optimum: agreement far below any displayed digit
    np.testing.assert_allclose(model.covariance(), ref, rtol=1e-6, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_allclose(model.sigma(), [result.file.cameras["cam0"].std[u.coord] for u in model.unknowns],
                               rtol=1e-6)
    # the same from the file alone (its T_cam_target key) as from the in-memory result
    from_file = A.linear_models(result.file, obs)["cam0"]
    np.testing.assert_allclose(from_file.information, model.information, rtol=1e-9)


def test_predicted_station_matches_a_re_solve(data):
    """Adding the predicted 'tilt_y' view (pixels exactly consistent with the estimate) and
    re-calibrating gives the covariance the prediction said (stated noise: no variance factor)."""
    obs, result, model = data
    T = A._camera_candidate(model, "tilt_y")
    cam = result.file.cameras["cam0"]
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    pix, _ = cv2.projectPoints(BOARD.points, rvec, T[:3, 3], cam.K, cam.dist)  # OpenCV, not jcalib
    assert np.all((pix[:, 0] > 0) & (pix[:, 0] < np.array(SIZE) - 1))
    obs2 = {**obs, "stations": [*obs["stations"], {"id": "new", "detections": [{
        "camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix[:, 0].tolist()}]}]}
    after = jcalib.calibrate(CELL, obs2, STATED).file.cameras["cam0"]
    predicted = model.sigma(A.station_information(model, "tilt_y"))
    actual = np.array([after.std[u.coord] for u in model.unknowns])
    # the new view adds zero residual, so the optimum stays and only the information grows
    np.testing.assert_allclose(predicted, actual, rtol=1e-4)
    assert np.all(predicted <= model.sigma() * (1 + 1e-9))  # information only adds


def test_residual_diagnostics_flag_an_injected_outlier(data):
    obs, result, _ = data
    bad = {**obs, "stations": [dict(s) for s in obs["stations"]]}
    det = dict(bad["stations"][3]["detections"][0])
    pix = np.array(det["pixels"])
    pix[17] += [4.0, -3.0]  # 5 px off
    det["pixels"] = pix.tolist()
    bad["stations"][3]["detections"] = [det]
    d = A.residual_diagnostics(result, bad)["cam0"]
    assert [(s, i) for s, i, _ in d.outliers] == [("s03", 17)]
    # per-view RMS against OpenCV's reprojection with the solver's poses
    cam = result.file.cameras["cam0"]
    T = result.details.T_cam_target["s03"]["cam0"]
    proj, _ = cv2.projectPoints(BOARD.points, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cam.K, cam.dist)
    np.testing.assert_allclose(d.view_rms_px["s03"], np.sqrt(np.mean((pix - proj[:, 0]) ** 2)), rtol=1e-9)
    assert not d.radial.flagged  # the right lens model: no radial trend


def test_radial_structure_detects_unmodelled_distortion():
    """Residuals of a too-simple model (an unmodelled r^5 term) are flagged; pure noise is not."""
    rng = np.random.default_rng(3)
    pix = rng.uniform([0, 0], SIZE, size=(2000, 2))
    centre = np.array([640.0, 480.0])
    d = pix - centre
    r = np.linalg.norm(d, axis=-1)
    noise = 0.2 * rng.standard_normal(pix.shape)
    trend = (0.6 * (r / r.max()) ** 4 - 0.3 * (r / r.max()) ** 2)[:, None] * d / r[:, None]
    hit = A.radial_structure(pix, noise + trend, centre, 0.2)
    assert hit.flagged and hit.p_value < 1e-10 and 0.2 < hit.amplitude_px < 0.5
    false = [A.radial_structure(pix, 0.2 * rng.standard_normal(pix.shape), centre, 0.2).flagged for _ in range(20)]
    assert not any(false)  # p < 1e-4 per trial: 20 clean trials all pass (chance of a false flag 2e-3)


@given(st.lists(st.floats(-0.95, 0.95), min_size=3, max_size=3), st.lists(st.floats(0.1, 10), min_size=3, max_size=3))
def test_correlations_recover_a_constructed_matrix(rho_upper, sigmas):
    """C = D R D with a known correlation matrix R (made positive definite): correlations() gives R back."""
    R = np.eye(3)
    R[0, 1] = R[1, 0] = rho_upper[0]
    R[0, 2] = R[2, 0] = rho_upper[1]
    R[1, 2] = R[2, 1] = rho_upper[2]
    w, V = np.linalg.eigh(R)
    R = V @ np.diag(np.maximum(w, 0.05)) @ V.T
    R = R / np.sqrt(np.outer(np.diag(R), np.diag(R)))
    D = np.diag(sigmas)
    rho, pairs = A.correlations(D @ R @ D, ["a", "b", "c"], minimum=0.0)
    np.testing.assert_allclose(rho, R, atol=1e-9)  # float64 identity
    expected = sorted((abs(R[i, j]) for i, j in ((0, 1), (0, 2), (1, 2))), reverse=True)
    np.testing.assert_allclose([abs(p[2]) for p in pairs], expected, atol=1e-9)


def test_weak_directions_and_transform_sigma_closed_form():
    """A hand-made 2-unknown model: translation z (σ 3 mm) correlated 0.8 with rotation x (σ 0.1°)."""
    s_t, s_r, rho = 3e-3, np.radians(0.1), 0.8
    C = np.array([[s_r**2, rho * s_r * s_t], [rho * s_r * s_t, s_t**2]])
    unknowns = (A._transform_unknown("T_flange_cam0", "rx"), A._transform_unknown("T_flange_cam0", "tz"))
    m = A.LinearModel("hand-eye", unknowns, np.linalg.inv(C), np.diag(np.linalg.inv(C)))
    np.testing.assert_allclose(m.sigma(), [0.1, 3.0], rtol=1e-9)
    # scaled by tolerances 0.05 deg / 0.5 mm: [[4, 0.8*2*6], [.., 36]]
    S = np.array([[4.0, 0.8 * 2 * 6], [0.8 * 2 * 6, 36.0]])
    lam, vec = np.linalg.eigh(S)
    weak = A.weak_directions(m, 2)
    np.testing.assert_allclose([w.ratio for w in weak], np.sqrt(lam[::-1]), rtol=1e-9)
    assert weak[0].components[0][0] == "T_flange_cam0 translation z"
    assert abs(weak[0].components[0][1]) == pytest.approx(abs(vec[1, 1]), rel=1e-9)
    T = np.eye(4)
    full = np.zeros((6, 6))
    full[np.ix_([0, 5], [0, 5])] = C
    ts = A.transform_sigma(TransformResult(T, full))
    np.testing.assert_allclose(ts["rotation_deg"], [0.1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(ts["translation_mm"], [0, 0, 3.0], rtol=1e-9)


def test_projection_difference_against_opencv():
    """Halves differing by a principal-point shift: without the rotation fit the difference equals
    OpenCV's undistort (A) + project (B) of each pixel; a small shift is nearly a rotation, so the
    fitted difference is far smaller."""
    a = CameraResult.from_model(CAMERA)
    K_b = K_TRUE.copy()
    K_b[0, 2] += 2.0
    b = CameraResult.from_model(camera_from_opencv(K_b, DIST_TRUE, SIZE))
    u, v, diff = A.projection_difference(a, b, grid=(9, 7), fit_rotation=False)
    pix = np.stack([u.ravel(), v.ravel()], -1)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPointsIter(pix[:, None, :], a.K, a.dist, None, None, crit)[:, 0, :]
    ref, _ = cv2.projectPoints(np.c_[xy, np.ones(len(xy))], np.zeros(3), np.zeros(3), b.K, b.dist)
    np.testing.assert_allclose(diff.ravel(), np.linalg.norm(ref[:, 0] - pix, axis=-1), atol=1e-6)
    fitted = A.projection_difference(a, b, grid=(9, 7))[2]
    assert np.nanmax(fitted) < 0.25 * np.nanmax(diff)


def test_cross_validation_halves(data):
    """Two halves (even / odd stations): each half's camera equals jcalib.calibrate on that half,
    and the difference is of the size the halves' σ predict (not orders of magnitude off)."""
    obs, _result, _ = data
    cv = A.cross_validate(CELL, obs, STATED, grid=(9, 7))
    assert cv.stations == ([f"s{i:02d}" for i in (0, 2, 4, 6)], [f"s{i:02d}" for i in (1, 3, 5, 7)])
    _u, _v, diff, expected = cv.maps["cam0"]
    assert diff.shape == expected.shape == (7, 9)
    ratio = np.nanmedian(diff) / np.nanmedian(expected)
    assert 0.1 < ratio < 3.0, ratio


def test_fronto_parallel_views_first_warning_names_focal_and_tilt():
    """All views within 4° of fronto-parallel (a nominal K in the cell starts the solve): the first
    warning names the focal length and a tilted view, and that station's predicted σ is smaller."""
    rng = np.random.default_rng(11)
    obs = _observations(random_calibration_views(CAMERA, BOARD.points, 8, rng=rng, max_tilt_deg=4.0), rng)
    cell = {**CELL, "cameras": {"cam0": {"model": "opencv5", "intrinsics": {
        "K": (K_TRUE * [[1.03, 1, 1], [1, 1.03, 1], [1, 1, 1]]).tolist(), "dist": [0, 0, 0, 0, 0]}}}}
    result = jcalib.calibrate(cell, obs)
    models = A.linear_models(result, obs)
    warnings = A.analysis_warnings(result.file, models, A.residual_diagnostics(result, obs))
    first = warnings[0]
    assert first.unknown in ("cam0 fx", "cam0 fy") and first.fix in ("tilt_x", "tilt_y"), first
    assert first.message.startswith(first.unknown) and "tilted 40° about the camera" in first.message
    model = models["cam0"]
    i = [u.label for u in model.unknowns].index(first.unknown)
    assert model.sigma(A.station_information(model, first.fix))[i] < 0.2 * model.sigma()[i]
