"""Joint pivot refinement (jcalib.problems.pivot) on real tracker data and by simulation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from jcalib.errors import BadInputError, NotObservableError
from jcalib.problems.pivot import refine_pivot
from jcalib.residuals.losses import HuberLoss


def _rotvec(w) -> np.ndarray:
    w = np.asarray(w, float)
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K


def _stacked_lstsq(T: np.ndarray):
    """Plain linear least squares ``[R_i, -I] [tip; pivot] = -t_i`` (numpy), the reference."""
    n = T.shape[0]
    A = np.zeros((3 * n, 6))
    A[:, :3] = T[:, :3, :3].reshape(3 * n, 3)
    A[:, 3:] = -np.tile(np.eye(3), (n, 1))
    b = -T[:, :3, 3].reshape(-1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    r = A @ sol - b
    return sol, r, A


@pytest.fixture(scope="module")
def ndi_poses(real_data) -> np.ndarray:
    files = sorted((real_data / "pivot_ucl_ndi" / "matrices").glob("*.txt"))
    assert len(files) == 1151
    return np.stack([np.loadtxt(f) for f in files])


def test_real_tracker_data_agrees_with_linear_least_squares(ndi_poses):
    res = refine_pivot(ndi_poses)
    ref, r, A = _stacked_lstsq(ndi_poses)
    # acceptance (issue 5): within 0.01 mm of plain linear least squares
    assert np.max(np.abs(res.p_flange_tip - ref[:3])) < 0.01
    assert np.max(np.abs(res.p_base_pivot - ref[3:])) < 0.01
    # the same least squares solved two ways: equal to ~1e-9 mm (values ~2000 mm, float64, cond ~1e3)
    np.testing.assert_allclose(res.p_flange_tip, ref[:3], atol=1e-7)
    np.testing.assert_allclose(res.p_base_pivot, ref[3:], atol=1e-7)
    # residual statistics and the a-posteriori covariance sigma^2 (A^T A)^-1 from the reference. The
    # one builder holds every flange pose as a unit quaternion: the tracker's rotation matrices (printed
    # to a few decimals, not exactly orthonormal) are orthonormalised, which moves single residuals by
    # up to 3e-5 mm and Σr² by 3e-9 relative (the family used the raw matrices: 1e-9 held there)
    dof = A.shape[0] - 6
    sigma = np.sqrt(r @ r / dof)
    np.testing.assert_allclose(res.sigma, sigma, rtol=1e-8)
    np.testing.assert_allclose(res.rms, np.sqrt(np.mean(r**2)), rtol=1e-8)
    np.testing.assert_allclose(res.covariance, sigma**2 * np.linalg.inv(A.T @ A), rtol=1e-6, atol=1e-12)
    assert res.residuals.shape == (1151, 3)
    assert res.noise == "a_posteriori" and res.status == "converged"
    # physically: a hand-held pointer in a divot tracked by an optical tracker, ~1-3 mm tip scatter
    assert 0.5 < res.rms_distance < 5.0
    assert np.all(res.tip_std < 1.0)
    # consecutive tracker poses share their error (lag-1 autocorrelation ~0.98): the serial
    # (Newey-West) covariance is several times the independent one, ~1 mm for the tip
    assert res.residual_autocorrelation > 0.9
    ser = refine_pivot(ndi_poses, serial_correlation=True)
    np.testing.assert_allclose(ser.p_flange_tip, res.p_flange_tip, atol=1e-9)
    assert np.all(ser.tip_std > 2.5 * res.tip_std) and np.all(ser.tip_std < 3.0)


def _pivot_poses(rng, n, tip, pivot, max_angle=0.6, axis=None):
    T = np.zeros((n, 4, 4))
    T[:, 3, 3] = 1.0
    for i in range(n):
        w = rng.uniform(-max_angle, max_angle, 3) if axis is None else axis * rng.uniform(-max_angle, max_angle)
        R = _rotvec(w) @ _rotvec([0.2, -0.1, 0.3])
        T[i, :3, :3] = R
        T[i, :3, 3] = pivot - R @ tip
    return T


TIP = np.array([0.01, -0.02, 0.2])
PIVOT = np.array([0.5, 0.1, 0.3])


def test_noise_free_recovery():
    T = _pivot_poses(np.random.default_rng(0), 20, TIP, PIVOT)
    res = refine_pivot(T)
    # 1e-12 m: exact data, float64 round-off of values ~0.5 m
    np.testing.assert_allclose(res.p_flange_tip, TIP, atol=1e-12)
    np.testing.assert_allclose(res.p_base_pivot, PIVOT, atol=1e-12)
    assert res.p_flange_tip.dtype == np.float64


def test_monte_carlo_stated_covariance():
    """100 noisy data sets: errors normalised by the stated covariance follow chi2(6)."""
    rng = np.random.default_rng(1)
    T0 = _pivot_poses(rng, 20, TIP, PIVOT)
    sigma = 3e-4
    nees = []
    for _ in range(100):
        T = T0.copy()
        T[:, :3, 3] += rng.normal(0.0, sigma, (20, 3))
        res = refine_pivot(T, sigma=sigma)
        e = np.concatenate([res.p_flange_tip - TIP, res.p_base_pivot - PIVOT])
        nees.append(e @ np.linalg.solve(res.covariance, e))
    total = float(np.sum(nees))
    # two-sided chi2(600) bounds at 1e-3 (fixed seed)
    assert stats.chi2.ppf(1e-3, 600) < total < stats.chi2.ppf(1 - 1e-3, 600), total / 100


def test_serial_correlation_covariance_matches_spread_of_correlated_poses():
    """AR(1)-correlated pose noise (rho 0.9, as a streaming tracker gives): the independent-noise
    covariance under-reports the spread ~19x in variance; the Newey-West one matches it."""
    rng = np.random.default_rng(5)
    n, rho, s = 300, 0.9, 3e-4
    ph = np.arange(n) / n
    T0 = np.zeros((n, 4, 4))
    T0[:, 3, 3] = 1.0
    for i, t in enumerate(ph):  # orientation changes smoothly along the time series
        R = _rotvec([0.5 * np.sin(2 * np.pi * 1.5 * t), 0.5 * np.sin(2 * np.pi * 2.3 * t + 1.0),
                     0.3 * np.sin(2 * np.pi * 0.7 * t)])
        T0[i, :3, :3] = R
        T0[i, :3, 3] = PIVOT - R @ TIP
    errs, cov, cov_iid = [], [], []
    for _ in range(100):
        e = np.zeros((n, 3))
        e[0] = rng.normal(0.0, s, 3)
        for i in range(1, n):
            e[i] = rho * e[i - 1] + np.sqrt(1.0 - rho**2) * rng.normal(0.0, s, 3)
        T = T0.copy()
        T[:, :3, 3] += e
        res = refine_pivot(T, serial_correlation=True)
        errs.append(np.concatenate([res.p_flange_tip - TIP, res.p_base_pivot - PIVOT]))
        cov.append(np.diag(res.covariance))
        cov_iid.append(np.diag(res.covariance_iid))
    assert res.noise == "serial" and res.serial_bandwidth > 0 and res.residual_autocorrelation > 0.8
    emp = np.var(np.stack(errs), axis=0)
    # 100 trials: a variance ratio is known to ~+-15 %; bounds loose around 1 (HAC has small-sample bias)
    ratio = emp / np.mean(cov, axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.8)), ratio
    assert np.all(emp / np.mean(cov_iid, axis=0) > 8.0)  # (1 + rho) / (1 - rho) = 19


def test_robust_loss_resists_an_outlier_pose():
    rng = np.random.default_rng(2)
    T = _pivot_poses(rng, 30, TIP, PIVOT)
    T[:, :3, 3] += rng.normal(0.0, 2e-4, (30, 3))
    T[7, :3, 3] += [0.01, -0.008, 0.005]  # the tip slipped out of the divot once (~14 mm)
    plain = refine_pivot(T, sigma=2e-4)
    robust = refine_pivot(T, sigma=2e-4, loss=HuberLoss(scale=2.0))
    assert np.linalg.norm(robust.p_flange_tip - TIP) < 0.3 * np.linalg.norm(plain.p_flange_tip - TIP)


def test_rotations_about_one_axis_are_named():
    axis = np.array([0.0, 0.6, 0.8])
    T = _pivot_poses(np.random.default_rng(3), 10, TIP, PIVOT, axis=axis)
    with pytest.raises(NotObservableError, match="common rotation axis") as err:
        refine_pivot(T)
    assert any("tip position along the common rotation axis" in u for u in err.value.unknowns)


def test_bad_input():
    with pytest.raises(BadInputError, match="T_base_flange"):
        refine_pivot(np.zeros((5, 3, 3)))
    T = _pivot_poses(np.random.default_rng(4), 5, TIP, PIVOT)
    with pytest.raises(BadInputError, match="sigma"):
        refine_pivot(T, sigma=-1.0)
    with pytest.raises(NotObservableError, match="at least 3 poses"):
        refine_pivot(T[:2])
