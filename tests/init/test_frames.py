"""Work-object frames from 3 / N points: exact recovery, conventions, Monte Carlo covariance, degeneracy."""

import jax
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.lie import local, se3_from_matrix
from jcalib.init.frames import frame_from_points, frame_from_three_points


def random_frame(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-1.0, 1.0, 3)
    return T


def to_base(T, p_wobj):
    return np.asarray(p_wobj) @ T[:3, :3].T + T[:3, 3]


@jax.jit
def _local(T_ref, T):
    return local(se3_from_matrix(T_ref), se3_from_matrix(T))


def tangent_error(T_ref, T):
    """Right-perturbation tangent Log(T_ref^-1 T) via jcalib.geometry.lie (quaternion code path)."""
    return np.asarray(_local(T_ref, T))


# --------------------------------------------------------------------------------------------- exactness


@given(seed=st.integers(0, 2**32 - 1))
def test_three_points_exact_and_consistent(seed):
    rng = np.random.default_rng(seed)
    T = random_frame(rng)
    a = rng.uniform(0.1, 1.0)
    b, c = rng.uniform(-0.5, 1.0), rng.uniform(0.1, 1.0)
    P = to_base(T, [[0, 0, 0], [a, 0, 0], [b, c, 0]])
    res = frame_from_three_points(*P)
    np.testing.assert_allclose(res.T_base_wobj, T, atol=1e-9)  # float64 construction, metres
    R = res.T_base_wobj[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0.999999  # right-handed
    # inverse consistency: the points expressed in the new frame
    Tinv = np.linalg.inv(res.T_base_wobj)
    q = P @ Tinv[:3, :3].T + Tinv[:3, 3]
    np.testing.assert_allclose(q[0], 0.0, atol=1e-9)
    np.testing.assert_allclose(q[1, 1:], 0.0, atol=1e-9)
    assert q[1, 0] > 0 and q[2, 1] > 0
    np.testing.assert_allclose(q[2, 2], 0.0, atol=1e-9)
    assert res.rms < 1e-12


def test_foot_origin_variant():
    rng = np.random.default_rng(1)
    T = random_frame(rng)
    P = to_base(T, [[-0.3, 0, 0], [0.4, 0, 0], [0.0, 0.5, 0]])  # X1, X2 on the x axis, Y1 on y
    np.testing.assert_allclose(frame_from_three_points(*P, origin="foot").T_base_wobj, T, atol=1e-9)
    first = frame_from_three_points(*P).T_base_wobj
    np.testing.assert_allclose(first[:3, :3], T[:3, :3], atol=1e-9)
    np.testing.assert_allclose(first[:3, 3], P[0], atol=1e-12)


@given(seed=st.integers(0, 2**32 - 1), perm=st.permutations(range(6)))
def test_n_points_exact(seed, perm):
    rng = np.random.default_rng(seed)
    T = random_frame(rng)
    pts = np.array([[0, 0, 0], [0.6, 0, 0], [0.2, 0.4, 0]] + [[*rng.uniform(-0.5, 0.5, 2), 0] for _ in range(3)])
    P = to_base(T, pts)[list(perm)]
    inv = np.argsort(perm)
    res = frame_from_points(P, origin_index=int(inv[0]), x_index=int(inv[1]), y_index=int(inv[2]))
    np.testing.assert_allclose(res.T_base_wobj, T, atol=1e-9)
    assert res.rms < 1e-12


def test_three_point_and_n_point_agree_on_three_points():
    rng = np.random.default_rng(2)
    P = rng.normal(size=(3, 3))
    np.testing.assert_allclose(frame_from_points(P).T_base_wobj, frame_from_three_points(*P).T_base_wobj, atol=1e-12)


def test_plane_fit_residuals_against_svd():
    rng = np.random.default_rng(3)
    T = random_frame(rng)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, (10, 2)), rng.normal(0, 1e-3, 10)])
    P = to_base(T, pts)
    res = frame_from_points(P)
    c = P.mean(axis=0)
    normal = np.linalg.svd(P - c)[2][2]  # independent plane fit
    assert abs(abs(normal @ res.T_base_wobj[:3, 2]) - 1.0) < 1e-12
    np.testing.assert_allclose(np.abs(res.plane_residuals), np.abs((P - c) @ normal), atol=1e-12)


# --------------------------------------------------------------------------------------------- uncertainty


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(4)
    P = to_base(random_frame(rng), [[0, 0, 0], [0.5, 0, 0], [0.1, 0.3, 0], [0.4, 0.4, 0.001], [-0.2, 0.3, -0.001]])
    res = frame_from_points(P)
    h = 1e-6
    J = np.zeros((6, 15))
    for k in range(15):
        Pp, Pm = P.copy(), P.copy()
        Pp.flat[k] += h
        Pm.flat[k] -= h
        J[:, k] = (tangent_error(res.T_base_wobj, frame_from_points(Pp).T_base_wobj)
                   - tangent_error(res.T_base_wobj, frame_from_points(Pm).T_base_wobj)) / (2 * h)
    np.testing.assert_allclose(res.jacobian, J, atol=1e-7)  # central differences, h = 1e-6 m


@pytest.mark.parametrize("kind", ["three", "n"])
def test_monte_carlo_covariance_chi_square(kind):
    rng = np.random.default_rng(5)
    T = random_frame(rng)
    if kind == "three":
        pts = np.array([[0, 0, 0], [0.5, 0, 0], [0.1, 0.4, 0]])
        cov_pts = np.stack([np.diag([1.0, 2.0, 0.5]) * 1e-8, np.eye(3) * 1e-8, np.diag([0.5, 1, 3]) * 1e-8])
        solve = lambda P, cov=None: frame_from_three_points(*P, covariance=cov)  # noqa: E731
    else:
        pts = np.array([[0, 0, 0], [0.5, 0, 0], [0.1, 0.4, 0], [0.45, 0.35, 0], [-0.1, 0.3, 0], [0.3, -0.2, 0]])
        cov_pts = np.tile(np.diag([1.0, 1.0, 4.0]) * 1e-8, (6, 1, 1))
        solve = lambda P, cov=None: frame_from_points(P, covariance=cov)  # noqa: E731
    P0 = to_base(T, pts)
    cov_base = np.einsum("ij,njk,lk->nil", T[:3, :3], cov_pts, T[:3, :3])  # given in wobj axes
    C = solve(P0, cov_base).covariance
    L = np.linalg.cholesky(cov_base)
    trials = 400
    stat = 0.0
    for _ in range(trials):
        P = P0 + np.einsum("nij,nj->ni", L, rng.normal(size=P0.shape))
        e = tangent_error(T, solve(P).T_base_wobj)
        stat += e @ np.linalg.solve(C, e)
    lo, hi = chi2.ppf([0.0005, 0.9995], 6 * trials)
    assert lo < stat < hi, (stat, lo, hi)


def test_covariance_forms_agree():
    rng = np.random.default_rng(6)
    P = rng.normal(size=(4, 3))
    a = frame_from_points(P, covariance=1e-4).covariance
    b = frame_from_points(P, covariance=np.eye(3) * 1e-8).covariance
    c = frame_from_points(P, covariance=np.tile(np.eye(3) * 1e-8, (4, 1, 1))).covariance
    d = frame_from_points(P, covariance=np.eye(12) * 1e-8).covariance
    for m in (b, c, d):
        np.testing.assert_allclose(m, a, rtol=1e-12)
    assert frame_from_points(P).covariance is None


# --------------------------------------------------------------------------------------------- degeneracy


def test_collinear_points_not_observable():
    P = np.array([[0, 0, 0], [1.0, 1.0, 0], [2.0, 2.0, 1e-6]])
    with pytest.raises(NotObservableError) as info:
        frame_from_three_points(*P)
    assert "rotation about the line through the points" in info.value.unknowns[0]
    with pytest.raises(NotObservableError, match="rotation about the line through the points"):
        frame_from_points(np.vstack([P, [[3.0, 3.0, 0.0]]]))


def test_other_degenerate_inputs():
    with pytest.raises(NotObservableError, match="X axis direction"):
        frame_from_three_points([0, 0, 0], [0, 0, 0], [0, 1.0, 0])
    with pytest.raises(NotObservableError, match="side of \\+Y"):
        frame_from_points([[0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [0.5, 1.0, 0]])
    with pytest.raises(BadInputError, match="p_x"):
        frame_from_three_points([0, 0, 0], [1.0, 0], [0, 1.0, 0])
    with pytest.raises(BadInputError, match="x_index"):
        frame_from_points(np.eye(3), x_index=5)
    with pytest.raises(BadInputError, match="covariance"):
        frame_from_points(np.eye(3), covariance=np.eye(2))
    with pytest.raises(BadInputError, match="origin"):
        frame_from_three_points([0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], origin="middle")
