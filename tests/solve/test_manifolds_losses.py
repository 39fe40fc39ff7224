"""Manifolds, robust losses and priors: identities against independent references."""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import scipy.linalg
from hypothesis import example, given
from hypothesis import strategies as st

import jcalib  # noqa: F401
from jcalib.residuals import CauchyLoss, HuberLoss, TrivialLoss, gaussian_prior_residual
from jcalib.solve import SE3, SO3, Euclidean

vec6 = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6).map(np.array)


@jax.jit
def _se3_roundtrip(a, b):
    m = SE3()
    x = jaxlie.SE3.exp(jnp.concatenate([a[3:], a[:3]])).wxyz_xyz
    y = m.retract(x, b)
    return m.local(x, y), y, x


def _twist_matrix(b):
    """4 x 4 ``[[ [ω]×, v ], [0, 0]]`` of ``b = (ω, v)``; ``expm`` of it is the SE(3) exponential."""
    w, v = b[:3], b[3:]
    M = np.zeros((4, 4))
    M[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    M[:3, 3] = v
    return M


@given(vec6, vec6)
@example(np.zeros(6), np.array([0.0, 1e-6, 0.0, 0.0, 0.0, 1.0]))  # jaxlie 1.5's SE(3) exp drops ½ ω × v here
@example(np.zeros(6), np.array([3e-3, -2e-3, 1e-3, 0.5, -0.7, 0.9]))  # near the series threshold θ² = 1e-4
@example(np.zeros(6), np.array([1e-2, 0.0, 0.0, 0.0, 1.0, 0.0]))  # just above it
def test_se3_retract_local_roundtrip_and_order(a, b):
    delta, y, x = _se3_roundtrip(jnp.asarray(a), jnp.asarray(b))
    # float64 identity: Log(Exp(δ)) == δ for |rotation| < π.
    np.testing.assert_allclose(delta, b, atol=1e-9)
    # Tangent order (rx, ry, rz, tx, ty, tz), right perturbation: y == x @ Exp(δ) built by hand.
    R_d = jaxlie.SO3.exp(jnp.asarray(b[:3])).as_matrix()
    # Reference exponential: the matrix exponential of the twist (scipy), independent of jaxlie and jcalib.
    T = np.asarray(jaxlie.SE3(x).as_matrix()) @ scipy.linalg.expm(_twist_matrix(b))
    np.testing.assert_allclose(np.asarray(jaxlie.SE3(y).as_matrix()), T, atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], np.asarray(jaxlie.SO3(x[:4]).as_matrix()) @ np.asarray(R_d), atol=1e-12)


def test_retract_jacobian_at_zero_is_finite_and_matches_finite_differences():
    m = SO3()
    q = jaxlie.SO3.exp(jnp.array([0.3, -0.2, 0.1])).wxyz
    J = jax.jacfwd(lambda d: m.retract(q, d))(jnp.zeros(3))
    h = 1e-6
    fd = np.stack([(m.retract(q, h * e) - m.retract(q, -h * e)) / (2 * h) for e in np.eye(3)], 1)
    np.testing.assert_allclose(J, fd, atol=1e-9)  # central differences: O(h²) + rounding ~1e-10
    assert np.allclose(Euclidean(2).retract(jnp.ones(2), jnp.ones(2)), 2.0)


@jax.jit
def _loss_values(s):
    out = []
    for loss in (TrivialLoss(), HuberLoss(1.5), CauchyLoss(0.7)):
        v, d = loss.rho(s)
        auto = jax.vmap(jax.grad(lambda t, loss=loss: loss.rho(t)[0]))(s)
        out.append((v, d, auto))
    return out


@given(st.lists(st.floats(0.0, 50.0), min_size=4, max_size=4))
def test_loss_slope_is_derivative_of_loss(s):
    s = jnp.asarray(s)
    for v, d, auto in _loss_values(s):
        assert np.all(np.isfinite(d)) and np.all(d > 0) and np.all(d <= 1.0 + 1e-15)
        np.testing.assert_allclose(d, auto, rtol=1e-12)  # autodiff of ρ vs the closed-form ρ'


def test_huber_and_cauchy_closed_forms():
    s = jnp.array([0.0, 1.0, 9.0])
    v, d = HuberLoss(2.0).rho(s)
    np.testing.assert_allclose(v, [0.0, 1.0, 2 * 2 * 3 - 4], rtol=1e-15)
    np.testing.assert_allclose(d, [1.0, 1.0, 2.0 / 3.0], rtol=1e-15)
    v, d = CauchyLoss(1.0).rho(s)
    np.testing.assert_allclose(v, np.log1p([0.0, 1.0, 9.0]), rtol=1e-15)
    # derivative of ρ at s = 0 stays finite (weight 0 / padding safety)
    assert np.isfinite(jax.grad(lambda t: HuberLoss(1.0).rho(t)[0])(0.0))


def test_prior_residual_is_whitened_tangent_difference():
    m = SE3()
    mean = jaxlie.SE3.exp(jnp.array([0.1, 0.2, 0.3, 0.01, 0.02, 0.03])).wxyz_xyz
    delta = jnp.array([0.01, -0.02, 0.03, 0.001, 0.002, -0.003])
    x = m.retract(mean, delta)
    S = jnp.diag(jnp.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
    r = gaussian_prior_residual(m)(x, (mean, S))
    np.testing.assert_allclose(r, S @ delta, atol=1e-12)
    assert gaussian_prior_residual(SE3()) is gaussian_prior_residual(SE3())  # one function, one trace
