"""Is the reported intrinsic covariance honest? A small Monte Carlo with a fixed seed.

One camera (opencv5, 640x480), ten fixed board poses, fresh Gaussian corner noise of known σ per
trial. If the covariance Σ is right, the normalised error d² = eᵀ Σ⁻¹ e of the 9 intrinsics follows
χ²(9) (to first order in the noise). Checked with a Kolmogorov–Smirnov test and the mean's χ²
bound; the same check must reject a covariance whose σ is off by a factor 2. The full study (more
trials, per-parameter σ ratios) is ``benchmarks/bench_camera_consistency.py``.
"""

import numpy as np
import pytest
from scipy import stats

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
SIGMA_PX = 0.3
NUM_TRIALS = 80
NUM_PARAMS = 9
ALPHA = 1e-3  # false-alarm rate of each statistical check (fixed seeds make it deterministic anyway)


def consistent(d2: np.ndarray, dof: int) -> tuple[bool, float, float]:
    """KS test of d² against χ²(dof) and a two-sided bound on its mean (sum of n χ²(dof) is χ²(n dof))."""
    p = stats.kstest(d2, stats.chi2(dof).cdf).pvalue
    n = d2.size
    lo, hi = stats.chi2(n * dof).ppf([ALPHA / 2, 1 - ALPHA / 2]) / n
    return bool(p > ALPHA and lo <= d2.mean() <= hi), float(p), float(d2.mean())


@pytest.fixture(scope="module")
def trials():
    cam = camera_from_opencv(np.array([[800.0, 0, 330.0], [0, 805.0, 242.0], [0, 0, 1]]),
                             np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02]), (640, 480))
    views = random_calibration_views(cam, BOARD.points, 10, rng=3)
    clean = []
    for T in views:
        pix, visible = project_target(cam, T, BOARD.points)
        assert visible.all()
        clean.append(pix)
    cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
                       "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}})
    rng = np.random.default_rng(2024)
    truth = np.asarray(cam.params)
    out = {"error": [], "stated": [], "a_posteriori": []}
    for _ in range(NUM_TRIALS):
        obs = parse_observations({
            "schema": "jcalib.observations/1",
            "cameras": {"cam": {"image_size": [640, 480]}},
            "targets": {"board": {"points": BOARD.points.tolist()}},
            "stations": [{"id": f"v{i}", "detections": [{
                "camera": "cam", "target": "board", "point_index": list(range(len(BOARD.points))),
                "pixels": (p + SIGMA_PX * rng.standard_normal(p.shape)).tolist()}]}
                for i, p in enumerate(clean)],
        })
        for noise in ("stated", "a_posteriori"):
            cal = calibrate_cell(cell, obs, CalibrationOptions(noise=noise, sigma_px=SIGMA_PX))
            assert cal.status == "converged"
            out[noise].append(cal.intrinsics_covariance["cam"])
        out["error"].append(np.asarray(cal.cameras["cam"].params) - truth)
    return {k: np.array(v) for k, v in out.items()}


def mahalanobis2(errors, covariances):
    return np.array([e @ np.linalg.solve(S, e) for e, S in zip(errors, covariances)])


@pytest.mark.parametrize("noise", ["stated", "a_posteriori"])
def test_normalised_errors_follow_chi2(trials, noise):
    ok, p, mean = consistent(mahalanobis2(trials["error"], trials[noise]), NUM_PARAMS)
    assert ok, f"{noise}: KS p = {p:.2g}, mean d² = {mean:.2f} (expected {NUM_PARAMS})"


@pytest.mark.parametrize("scale", [0.5, 2.0])
def test_check_rejects_a_covariance_off_by_two_in_sigma(trials, scale):
    """The same data against Σ·scale²: the test has power, so it is not vacuous."""
    covariances = trials["stated"] * scale**2
    ok, p, mean = consistent(mahalanobis2(trials["error"], covariances), NUM_PARAMS)
    assert not ok, f"σ x {scale} passed: KS p = {p:.2g}, mean d² = {mean:.2f}"


def test_reported_sigma_matches_empirical_spread_per_parameter(trials):
    """Per parameter, empirical SD of the errors vs the mean reported σ. With 80 trials the sample
    SD of a Gaussian has a relative spread of 1/sqrt(2·80) = 8 %: a χ² bound on s²/σ² at α = 1e-3."""
    empirical_var = np.mean(trials["error"] ** 2, axis=0)  # truth known: no mean to subtract
    reported_var = np.mean(np.diagonal(trials["stated"], axis1=1, axis2=2), axis=0)
    ratio = empirical_var / reported_var
    lo, hi = stats.chi2(NUM_TRIALS).ppf([ALPHA / 2, 1 - ALPHA / 2]) / NUM_TRIALS
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    bad = {n: round(float(r), 3) for n, r in zip(names, ratio) if not lo <= r <= hi}
    assert not bad, f"empirical/reported variance outside [{lo:.2f}, {hi:.2f}]: {bad}"
