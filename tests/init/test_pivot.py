"""Pivot (4-point) TCP calibration: real tracker data, ground truth, Monte Carlo, degenerate poses."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.init.pivot import pivot_calibration, pivot_sphere_fit

REAL = Path(__file__).resolve().parents[1] / "data" / "real"


def load_ndi() -> np.ndarray:
    files = sorted((REAL / "pivot_ucl_ndi" / "matrices").glob("*.txt"))
    return np.stack([np.loadtxt(f) for f in files])


def synthetic(rng, n, tip, pivot, max_angle_deg=40.0):
    """Poses (n, 4, 4) whose tip ``tip`` (flange) sits exactly on ``pivot`` (base)."""
    rot = Rotation.random(random_state=rng)
    R = np.stack([(rot * Rotation.from_rotvec(v)).as_matrix() for v in
                  rng.uniform(-1, 1, (n, 3)) * np.deg2rad(max_angle_deg)])
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = pivot - R @ tip
    return T


# --------------------------------------------------------------------------------------------- real data


def test_real_ndi_pivot_matches_independent_lstsq():
    T = load_ndi()
    assert T.shape == (1151, 4, 4)
    res = pivot_calibration(T)
    # Independent reference: the plain stacked system [R_i, -I][x; p] = -t_i by np.linalg.lstsq.
    A = np.concatenate([T[:, :3, :3], -np.broadcast_to(np.eye(3), (len(T), 3, 3))], axis=2).reshape(-1, 6)
    ref, ssr, rank, _ = np.linalg.lstsq(A, -T[:, :3, 3].reshape(-1), rcond=None)
    assert rank == 6
    np.testing.assert_allclose(res.p_flange_tip, ref[:3], rtol=0, atol=1e-6)  # mm
    np.testing.assert_allclose(res.p_base_pivot, ref[3:], rtol=0, atol=1e-6)  # mm
    np.testing.assert_allclose(res.rms, np.sqrt(ssr[0] / A.shape[0]), rtol=1e-9)
    # Reference covariance from the plain system: s^2 (A^T A)^-1, s^2 = SSR / (3N - 6).
    cov_ref = ssr[0] / (A.shape[0] - 6) * np.linalg.inv(A.T @ A)
    np.testing.assert_allclose(res.covariance, cov_ref, rtol=1e-8, atol=0)
    # Physically sensible: scikit-surgery reports tip ~(-14.5, 395.1, -7.6) mm, RMS ~1.84 mm.
    np.testing.assert_allclose(res.p_flange_tip, [-14.476, 395.143, -7.558], atol=0.01)
    assert 1.83 < res.rms < 1.85
    assert np.all(res.tip_std < 1.0) and np.all(res.tip_std > 0.01)  # sub-mm (sampling noise only)
    assert np.all(res.pivot_std < 1.0)
    assert res.covariance.dtype == np.float64


def test_real_ndi_sphere_fit():
    T = load_ndi()
    sph = pivot_sphere_fit(T)
    # Independent reference: the uncentred Kasa system 2 t.c + k = |t|^2 by plain lstsq.
    t = T[:, :3, 3]
    sol, *_ = np.linalg.lstsq(np.column_stack([2 * t, np.ones(len(t))]), np.sum(t**2, 1), rcond=None)
    np.testing.assert_allclose(sph.p_base_pivot, sol[:3], rtol=0, atol=1e-6)  # mm
    np.testing.assert_allclose(sph.radius, np.sqrt(sol[3] + sol[:3] @ sol[:3]), rtol=0, atol=1e-6)
    assert sph.rms < 0.5  # mm: the marker origins lie on a sphere to ~0.1 mm
    # The poses cover a ~+-12 deg cone: a sphere fit is weak along the mean radius, so it differs
    # from the 3-D solution mostly along that direction (~13 mm here) and little across it.
    alg = pivot_calibration(T)
    d = sph.p_base_pivot - alg.p_base_pivot
    u = alg.p_base_pivot - t.mean(axis=0)
    u /= np.linalg.norm(u)
    assert np.linalg.norm(d - (d @ u) * u) < 5.0
    assert abs(d @ u) < 30.0


# --------------------------------------------------------------------------------------------- synthetic


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 12))
def test_noise_free_recovers_ground_truth(seed, n):
    rng = np.random.default_rng(seed)
    tip = rng.uniform(-0.3, 0.3, 3)
    pivot = rng.uniform(-1.0, 1.0, 3)
    T = synthetic(rng, n, tip, pivot)
    res = pivot_calibration(T)
    np.testing.assert_allclose(res.p_flange_tip, tip, atol=1e-9)  # float64 closed form, metres
    np.testing.assert_allclose(res.p_base_pivot, pivot, atol=1e-9)
    assert res.rms < 1e-9


@given(seed=st.integers(0, 2**32 - 1))
def test_sphere_fit_noise_free(seed):
    rng = np.random.default_rng(seed)
    tip = rng.uniform(-0.3, 0.3, 3)
    tip *= 0.1 / max(np.linalg.norm(tip), 1e-3) if np.linalg.norm(tip) < 0.1 else 1.0
    pivot = rng.uniform(-1.0, 1.0, 3)
    T = synthetic(rng, 8, tip, pivot)
    res = pivot_sphere_fit(T)
    np.testing.assert_allclose(res.p_base_pivot, pivot, atol=1e-8)
    np.testing.assert_allclose(res.p_flange_tip, tip, atol=1e-8)
    np.testing.assert_allclose(res.radius, np.linalg.norm(tip), atol=1e-8)


def test_pose_vectors_accepted():
    rng = np.random.default_rng(3)
    T = synthetic(rng, 5, np.array([0.01, 0.02, 0.2]), np.array([0.5, 0.1, 0.3]))
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # xyzw
    poses = np.concatenate([q[:, [3, 0, 1, 2]], T[:, :3, 3]], axis=1)
    np.testing.assert_allclose(pivot_calibration(poses).p_flange_tip, [0.01, 0.02, 0.2], atol=1e-9)


def test_monte_carlo_covariance_chi_square():
    """Errors normalised by the reported covariance follow chi^2(6) (known sigma)."""
    rng = np.random.default_rng(12345)
    tip, pivot = np.array([0.02, -0.01, 0.15]), np.array([0.6, 0.2, 0.1])
    T0 = synthetic(rng, 6, tip, pivot, max_angle_deg=35.0)
    sigma = 1e-4  # 0.1 mm tip noise per coordinate
    trials = 400
    stat = 0.0
    sig_est = []
    for _ in range(trials):
        T = T0.copy()
        T[:, :3, 3] += rng.normal(0.0, sigma, (len(T), 3))
        res = pivot_calibration(T, sigma=sigma)
        err = np.concatenate([res.p_flange_tip - tip, res.p_base_pivot - pivot])
        stat += err @ np.linalg.solve(res.covariance, err)
        sig_est.append(pivot_calibration(T).sigma)
    dof = 6 * trials  # sum of independent chi^2(6)
    lo, hi = chi2.ppf([0.0005, 0.9995], dof)
    assert lo < stat < hi, (stat, lo, hi)
    # a-posteriori sigma is unbiased in sigma^2 (E[SSR/(3N-6)] = sigma^2)
    np.testing.assert_allclose(np.mean(np.square(sig_est)), sigma**2, rtol=0.1)


# --------------------------------------------------------------------------------------------- degenerate


def test_common_rotation_axis_names_the_axis():
    rng = np.random.default_rng(7)
    axis_flange = np.array([0.2, -0.3, 0.9])
    axis_flange /= np.linalg.norm(axis_flange)
    R0 = Rotation.random(random_state=rng).as_matrix()
    tip, pivot = np.array([0.01, 0.03, 0.2]), np.array([0.4, 0.0, 0.5])
    T = np.tile(np.eye(4), (5, 1, 1))
    for i, ang in enumerate(np.deg2rad([0, 20, 45, 70, 95])):
        R = R0 @ Rotation.from_rotvec(ang * axis_flange).as_matrix()  # about one flange axis
        T[i, :3, :3] = R
        T[i, :3, 3] = pivot - R @ tip
    with pytest.raises(NotObservableError) as info:
        pivot_calibration(T)
    msg = info.value.unknowns[0]
    assert "tip position along the common rotation axis" in msg and "of the flange" in msg
    named = np.array([float(v) for v in msg.split("[")[1].split("]")[0].split(",")])
    assert abs(abs(named @ axis_flange) - 1.0) < 1e-3  # the same axis (4 decimals printed)


@pytest.mark.parametrize("n", [1, 2])
def test_too_few_poses(n):
    T = synthetic(np.random.default_rng(0), n, np.zeros(3) + 0.1, np.zeros(3))
    with pytest.raises(NotObservableError, match="at least 3 poses"):
        pivot_calibration(T)


def test_no_rotation():
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, :3, 3] = np.random.default_rng(1).normal(size=(4, 3))
    with pytest.raises(NotObservableError, match="barely rotate"):
        pivot_calibration(T)


def test_bad_input():
    with pytest.raises(BadInputError, match="T_base_flange"):
        pivot_calibration(np.zeros((4, 3, 3)))
    T = synthetic(np.random.default_rng(0), 4, np.ones(3) * 0.1, np.zeros(3))
    T[2, 0, 0] = np.nan
    with pytest.raises(BadInputError, match="NaN"):
        pivot_calibration(T)
    with pytest.raises(BadInputError, match="sigma"):
        pivot_calibration(synthetic(np.random.default_rng(0), 4, np.ones(3) * 0.1, np.zeros(3)), sigma=-1.0)
