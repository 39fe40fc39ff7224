"""Comparing two calibrations of one camera (jcalib.report.compare) and split-half cross-validation
(jcalib.problems.crossval): zero for identical models, a camera-frame rotation absorbed, the predicted σ of the
difference checked by Monte Carlo (through the rotation fit and through whole calibrations), a wrong lens model
flagged, bad input named."""

from __future__ import annotations

import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.geometry.conversions import matrix_to_rvec, rvec_to_matrix
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.io.result import CameraResult
from jcalib.problems import calibrate
from jcalib.problems.crossval import split_stations
from jcalib.report.compare import (
    ALPHA,
    CHI2_99_2DOF,
    compare_cameras,
    compare_results,
    image_region_name,
    quadratic_form_sf,
    split_half_comparison,
)
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
#: A strongly distorted lens (barrel, ~7 % at the corners), 1280x960.
CAMERA = camera_from_opencv(np.array([[900.0, 0, 640.0], [0, 905.0, 481.0], [0, 0, 1]]),
                            np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02]), (1280, 960))
SIGMA_PX = 0.3
#: Every distortion coefficient held at zero: a pinhole in the opencv5 model (the same compiled solve).
NO_DISTORTION = ["k1", "k2", "p1", "p2", "k3"]


def make_cell(fix=()):
    cam = {"model": "opencv5", **({"fix": list(fix)} if fix else {})}
    return parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam0": cam},
                       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})


def make_obs(rng, num_views, sigma_px=SIGMA_PX):
    stations = []
    for i, T in enumerate(random_calibration_views(CAMERA, BOARD.points, num_views, rng=rng)):
        pix, vis = project_target(CAMERA, T, BOARD.points)
        assert vis.all()
        pix = pix + sigma_px * rng.standard_normal(pix.shape)
        stations.append({"id": f"v{i:03d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(len(BOARD.points))),
            "pixels": pix.tolist()}]})
    return parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
                               "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations})


@pytest.fixture(scope="module")
def pair():
    """Two independent 10-view calibrations of CAMERA (the first compiles the solve)."""
    rng = np.random.default_rng(5)
    return tuple(calibrate(make_cell(), make_obs(rng, 10)).file.cameras["cam0"] for _ in range(2))


def test_identical_results_are_consistent_with_zero_difference(pair):
    a, _ = pair
    c = compare_cameras(a, a, camera="cam0")
    assert c.verdict == "consistent" and c.camera == "cam0"
    assert c.num_points + c.num_skipped == 24 * 18
    assert c.max_px < 1e-9  # unproject/project round trip, float64
    assert c.rotation_deg < 1e-7 and np.allclose(c.R_b_a, np.eye(3), atol=1e-9)
    assert c.chi2_mean < 1e-9 and c.fraction_flagged == 0.0
    assert abs(c.chi2_mean_expected - 2.0) < 0.01  # the floor takes a little
    for x in (c.diff_px, c.covariance_px2, c.sigma_px, c.chi2, c.R_b_a):
        assert x.dtype == np.float64 and np.all(np.isfinite(x))
    assert c.sigma_rms_px > 0.5  # 10 views: pixels of uncertainty at the corners
    assert c.message.startswith("consistent")


def test_fitted_rotation_absorbs_a_rotated_camera_frame(pair):
    """B: the opencv5 parameters that best reproduce CAMERA in a frame rotated by 0.5° (principal point and
    distortion trade off against the rotation). Without the rotation fit the two differ by ~f·0.5° ≈ 8 px;
    with it, by no more than what the parameters could not reproduce, and the fitted rotation is the 0.5°."""
    import jax
    import jax.numpy as jnp

    a, _ = pair
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    R = rvec_to_matrix(np.radians(0.5) * axis)
    u, v = np.meshgrid(np.linspace(0, 1279, 24), np.linspace(0, 959, 18))
    pixels = np.stack([u.ravel(), v.ravel()], -1)
    rays, ok = CAMERA.unproject_valid(jnp.asarray(pixels))
    rays, pixels = np.asarray(rays)[np.asarray(ok)], pixels[np.asarray(ok)]
    cls = type(CAMERA)

    def residual(theta):
        return (cls.from_params(CAMERA.image_size, theta).project(rays @ R.T) - pixels).ravel()

    f, J = jax.jit(residual), jax.jit(jax.jacfwd(residual))
    theta = jnp.asarray(CAMERA.params)
    for _ in range(8):
        theta = theta - jnp.linalg.lstsq(J(theta), f(theta))[0]
    unexplained_px = float(np.max(np.linalg.norm(np.asarray(f(theta)).reshape(-1, 2), axis=-1)))
    rotated = cls.from_params(CAMERA.image_size, theta)
    C = a.covariance
    fitted = compare_cameras((CAMERA, C), (rotated, C))
    raw = compare_cameras((CAMERA, C), (rotated, C), fit_rotation=False)
    assert raw.max_px > 5.0 and np.allclose(raw.R_b_a, np.eye(3))
    assert fitted.max_px <= unexplained_px < 0.5 * raw.max_px
    error_deg = np.degrees(np.linalg.norm(matrix_to_rvec(fitted.R_b_a @ R.T)))
    assert error_deg < 0.1 and abs(fitted.rotation_deg - 0.5) < 0.05


def test_predicted_covariance_matches_monte_carlo_through_the_rotation_fit(pair):
    """Parameters drawn from (0.1x) the two calibrations' covariances, the difference recomputed exactly (not
    linearised): the per-point χ² averages 2 (the prediction through the unprojection, the rotation fit and the
    projection is right), and the verdict is "consistent" in ≥ 1 − ALPHA of the draws (up to binomial noise)."""
    a, b = pair
    cls = type(CAMERA)
    rng = np.random.default_rng(2)
    Ca, Cb = 0.01 * a.covariance, 0.01 * b.covariance
    La, Lb = (np.linalg.cholesky(C + 1e-30 * np.eye(len(C))) for C in (Ca, Cb))
    trials = 150
    means, expected, variances, verdicts = [], [], [], []
    for _ in range(trials):
        ma = cls.from_params(CAMERA.image_size, a.params + La @ rng.standard_normal(len(Ca)))
        mb = cls.from_params(CAMERA.image_size, a.params + Lb @ rng.standard_normal(len(Cb)))
        c = compare_cameras((ma, Ca), (mb, Cb))
        means.append(c.chi2_mean)
        expected.append(c.chi2_mean_expected)
        variances.append(c.chi2_mean_std ** 2)
        verdicts.append(c.verdict)
    # The draws are independent: the mean of the per-draw means has std sqrt(Σ var) / trials; 4σ bound.
    bound = 4.0 * np.sqrt(np.sum(variances)) / trials
    assert abs(np.mean(means) - np.mean(expected)) < bound, (np.mean(means), np.mean(expected), bound)
    assert verdicts.count("differ") <= 4  # ≤ 1 % expected: P(≥ 5 of 150) < 2e-3 at 1 %


def test_split_half_monte_carlo_differences_are_within_predicted_sigma():
    """20 data sets of 20 views of the right model, each split in two halves of 10 and calibrated: the halves'
    difference is "consistent" in ≥ 95 % of the data sets and the mean per-point χ² is 2 within its σ.

    Realistic σ (0.3 px corners, 10 views) are large at the corners: there the first-order prediction is a little
    pessimistic (the mean χ² comes out below 2), so the check is a bound on each side from the predicted spread."""
    rng = np.random.default_rng(11)
    cell = make_cell()
    trials = 20
    means, expected, variances, verdicts = [], [], [], []
    for _ in range(trials):
        cv = split_half_comparison(cell, make_obs(rng, 20))
        c = cv.comparisons["cam0"]
        assert len(cv.halves.stations[0]) == len(cv.halves.stations[1]) == 10
        means.append(c.chi2_mean)
        expected.append(c.chi2_mean_expected)
        variances.append(c.chi2_mean_std ** 2)
        verdicts.append(cv.verdict)
    assert verdicts.count("consistent") >= 19, verdicts
    bound = 4.0 * np.sqrt(np.sum(variances)) / trials
    assert abs(np.mean(means) - np.mean(expected)) < bound, (np.mean(means), np.mean(expected), bound)


def test_wrong_lens_model_is_flagged():
    """Data of a strongly distorted lens calibrated without distortion (every coefficient held at 0).

    The honest check is the split-half one, on the wrong-model data alone (what a user has): each half's
    wrong model bends differently to fit its own views, by more than the halves' σ say, even with the σ
    inflated by the a-posteriori noise level. The comparison with an independent right-model calibration
    flags it too (a bias far beyond the σ), but needs the right model."""
    rng = np.random.default_rng(3)
    wrong = split_half_comparison(make_cell(NO_DISTORTION), make_obs(rng, 20))
    c = wrong.comparisons["cam0"]
    assert wrong.verdict == "differ" and c.verdict == "differ"
    assert c.fraction_flagged > 0.2 and min(c.p_local, c.p_global) < 1e-4
    assert "differ" in c.message and "model error" in c.message
    right = calibrate(make_cell(), make_obs(rng, 10)).file.cameras["cam0"]
    vs_right = compare_cameras(right, wrong.results[0].file.cameras["cam0"])
    assert vs_right.verdict == "differ" and vs_right.max_px > 10.0
    assert vs_right.where.endswith("corner")  # barrel distortion: largest at the corners
    same = split_half_comparison(make_cell(), make_obs(rng, 20))
    assert same.verdict == "consistent"


def test_bad_input_is_named(pair):
    a, _ = pair
    pinhole = CameraResult("pinhole", (1280, 960), a.K, [], covariance=np.eye(4))
    across = compare_cameras(a, pinhole, grid=(6, 5))  # another lens model is compared, not refused
    assert (across.model, across.model_b, across.models) == ("opencv5", "pinhole", "opencv5 → pinhole")
    smaller = CameraResult("opencv5", (640, 480), a.K, a.dist, covariance=a.covariance)
    with pytest.raises(BadInputError, match="1280x960.*640x480"):
        compare_cameras(a, smaller)
    with pytest.raises(BadInputError, match="no intrinsics covariance"):
        compare_cameras(a, CameraResult("opencv5", (1280, 960), a.K, a.dist))
    with pytest.raises(BadInputError, match="neither camera"):
        compare_cameras((CAMERA, None), (CAMERA, None))
    with pytest.raises(BadInputError, match="grid"):
        compare_cameras(a, a, grid=(1, 5))
    with pytest.raises(BadInputError, match="distance_m"):
        compare_cameras(a, a, distance_m=-1.0)
    with pytest.raises(BadInputError, match="region"):
        compare_cameras(a, a, region=(100, 100, 50, 200))
    with pytest.raises(BadInputError, match="only 0 of"):
        compare_cameras(a, a, region=(10, 10, 20, 20))
    with pytest.raises(BadInputError, match="covariance"):
        compare_cameras((CAMERA, np.eye(3)), a)


def test_region_distance_and_exact_side(pair):
    a, b = pair
    full = compare_cameras(a, b)
    box = (320.0, 240.0, 960.0, 720.0)
    inner = compare_cameras(a, b, region=box)
    assert inner.num_points < full.num_points
    assert np.all((inner.pixels >= box[:2]) & (inner.pixels <= box[2:]))
    assert image_region_name(640, 480, (1280, 960)) == "centre"
    assert image_region_name(0, 959, (1280, 960)) == "bottom-left corner"
    far = compare_cameras(a, b, distance_m=2.0)  # central models, rotation only: the same at every range
    assert far.distance_m == 2.0 and np.allclose(far.diff_px, full.diff_px, atol=1e-9)
    truth = compare_cameras((CAMERA, None), b)  # A known exactly: only B's σ
    assert truth.sigma_rms_px < full.sigma_rms_px
    d = full.to_dict()
    assert d["verdict"] == full.verdict and d["num_points"] == full.num_points and d["alpha"] == ALPHA
    assert d["chi2_99_2dof"] == pytest.approx(CHI2_99_2DOF) and CHI2_99_2DOF == pytest.approx(9.2103, abs=1e-4)


def test_points_outside_the_valid_region_are_skipped_not_nan():
    """A wide lens whose image folds back before the corners (k1 < 0 alone: the radius r (1 + k1 r²) peaks at
    (2/3) / sqrt(−3 k1) = 1.45, 727 px from the centre; the corners are 800 px away): the corner pixels have no
    ray and are skipped."""
    folded = camera_from_opencv(np.array([[500.0, 0, 640.0], [0, 500.0, 480.0], [0, 0, 1]]),
                                np.array([-0.07, 0.0, 0.0, 0.0, 0.0]), (1280, 960))
    C = np.diag([1.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-6, 1e-6, 1e-4])
    c = compare_cameras((folded, C), (folded, C))
    assert 0 < c.num_skipped < 100 and c.num_points + c.num_skipped == 24 * 18
    radius = np.hypot(c.pixels[:, 0] - 640.0, c.pixels[:, 1] - 480.0)
    assert radius.max() < 728.0  # nothing beyond the fold is compared
    u, v = np.meshgrid(np.linspace(0, 1279, 24), np.linspace(0, 959, 18))
    assert np.count_nonzero(radius < 720.0) == np.count_nonzero(np.hypot(u - 640.0, v - 480.0) < 720.0)
    assert all(np.all(np.isfinite(x)) for x in (c.diff_px, c.chi2, c.sigma_px))


def test_split_needs_enough_views_and_splits_deterministically():
    rng = np.random.default_rng(0)
    obs = make_obs(rng, 7)
    with pytest.raises(BadInputError, match=r"at least 4 views.*'cam0' has 7 views \(4 and 3"):
        split_stations(obs)
    obs = make_obs(rng, 9)
    even = split_stations(obs)
    assert even.stations[0] == tuple(f"v{i:03d}" for i in (0, 2, 4, 6, 8))
    r1, r2 = split_stations(obs, split="random", seed=4), split_stations(obs, split="random", seed=4)
    assert r1.stations == r2.stations and not set(r1.stations[0]) & set(r1.stations[1])
    assert sorted(r1.stations[0] + r1.stations[1]) == sorted(s.id for s in obs.stations)
    with pytest.raises(BadInputError, match="split"):
        split_stations(obs, split="halves")


def test_compare_results_picks_common_cameras(pair, tmp_path):
    from jcalib.io.result import ResultFile

    a, b = pair
    fa = ResultFile(cameras={"cam0": a, "cam1": b})
    fb = ResultFile(cameras={"cam0": b})
    out = compare_results(fa, fb)
    assert list(out) == ["cam0"]
    with pytest.raises(BadInputError, match="cam1"):
        compare_results(fa, fb, cameras=["cam1"])


def test_quadratic_form_tail_probability():
    """The global test's null distribution: exact for equal weights (χ² with k dof), and a weighted sum against
    1e6 draws (its saddlepoint approximation is within a few per cent in the tail)."""
    from scipy.stats import chi2

    for k, x in ((2, 9.21), (5, 15.0), (9, 30.0)):
        assert quadratic_form_sf(x, np.ones(k)) == pytest.approx(chi2.sf(x, k), rel=0.02)
    mu = np.array([40.0, 7.0, 1.0, 0.3, 1e-14])
    draws = np.random.default_rng(0).standard_normal((10**6, len(mu))) ** 2 @ mu
    for q in (0.5, 0.9, 0.99, 0.995):
        x = float(np.quantile(draws, q))
        assert quadratic_form_sf(x, mu) == pytest.approx(1.0 - q, rel=0.05, abs=0.01 * (1.0 - q))
    assert quadratic_form_sf(1e30, mu) == 0.0 and quadratic_form_sf(1e-300, mu) == 1.0
