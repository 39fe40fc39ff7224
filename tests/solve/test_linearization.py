"""The cheap linearisation: first-order retractions and block assembly vs independent references."""

from __future__ import annotations

import functools

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from hypothesis import given

import jcalib  # noqa: F401  (float64)
from jcalib.solve import SE3, SO3, Euclidean, FactorGroup, Problem, Variable, linear
from jcalib.solve.manifolds import quat_rotate

_vec = st.lists(st.floats(-2.0, 2.0, allow_nan=False), min_size=3, max_size=3)


def _unit(q):
    q = np.asarray(q, np.float64) + np.array([1e-3, 0.0, 0.0, 0.0])
    return q / np.linalg.norm(q)


@functools.cache
def _jacobians_jit(m):
    def both(x):
        zero = jnp.zeros((m.tangent_dim,), jnp.float64)
        return (jax.jacfwd(lambda e: m.retract(x, e))(zero), jax.jacfwd(lambda e: m.retract_linear(x, e))(zero))

    return jax.jit(both)


def _jacobians_at_zero(m, x):
    return _jacobians_jit(m)(x)


@given(st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=4, max_size=4), _vec, _vec)
def test_retract_linear_matches_retract_in_value_and_derivative_at_zero(q, w, t):
    x7 = jnp.asarray(np.concatenate([_unit(q), np.asarray(t)]))
    for m, x, d in ((SE3(), x7, 6), (SO3(), x7[:4], 3), (Euclidean(3), jnp.asarray(t), 3)):
        zero = jnp.zeros((d,), jnp.float64)
        # same value at 0: bit for bit (the engine evaluates residuals with either)
        np.testing.assert_array_equal(m.retract_linear(x, zero), m.retract(x, zero))
        # same first derivative at 0 (float64 identities on O(1) numbers: 1e-12)
        J_true, J_lin = _jacobians_at_zero(m, x)
        np.testing.assert_allclose(J_lin, J_true, atol=1e-12)


def test_se3_retract_linear_derivative_vs_closed_form():
    """d/dδ (T · Exp(δ)) at 0 in closed form: q̇ = ½ q ⊗ [0, ω], ṫ = R(q) v (independent of jaxlie)."""
    rng = np.random.default_rng(3)
    q = _unit(rng.normal(size=4))
    x = jnp.asarray(np.concatenate([q, rng.normal(size=3)]))
    R = np.asarray(jaxlie.SO3(jnp.asarray(q)).as_matrix())
    w, a, b, c = q
    # left-multiplication matrix of q (Hamilton product q ⊗ p = L(q) p), columns for the vector part
    L = np.array([[w, -a, -b, -c], [a, w, -c, b], [b, c, w, -a], [c, -b, a, w]])
    expected = np.zeros((7, 6))
    expected[:4, :3] = 0.5 * L[:, 1:]
    expected[4:, 3:] = R
    J = jax.jacfwd(lambda e: SE3().retract_linear(x, e))(jnp.zeros(6))
    np.testing.assert_allclose(J, expected, atol=1e-12)


def _dense_reference(problem, values):
    """Gauss–Newton ``H = JᵀJ``, ``g = Jᵀr`` of the whole problem from one dense jacfwd of the true retraction."""
    layout = linear.make_layout(problem)
    sizes = {v.name: (v.num, v.tangent_dim) for v in problem.variables}
    names = [v.name for v in problem.variables]

    def r_all(flat):
        deltas, o = {}, 0
        for n in names:
            N, d = sizes[n]
            deltas[n] = flat[o:o + N * d].reshape(N, d)
            o += N * d
        x = {v.name: jax.vmap(v.manifold.retract)(values[v.name], deltas[v.name]) for v in problem.variables}
        rs = []
        for f in problem.factors:
            rows = [x[a][i] for a, i in zip(f.args, f.indices)]
            r = jax.vmap(f.fn)(*rows, f.observations)
            rs.append((r * (f.sqrt_weight / f.sigma)[:, None]).reshape(-1))
        return jnp.concatenate(rs)

    n = sum(N * d for N, d in sizes.values())
    z = jnp.zeros((n,), jnp.float64)
    J = np.asarray(jax.jit(jax.jacfwd(r_all))(z))
    r = np.asarray(jax.jit(r_all)(z))
    return layout, names, sizes, J.T @ J, J.T @ r


def _toy_problem(seed, n_a, n_b, n_e, K):
    """Shared Euclidean kind (two arguments of the same kind), a shared SE3 kind and an eliminated SE3 kind."""
    rng = np.random.default_rng(seed)

    def fn(a1, a2, T, P, obs):
        v = quat_rotate(T[:4], quat_rotate(P[:4], obs) + P[4:]) + T[4:]
        return jnp.concatenate([v * a1[0] + a2[1], jnp.stack([a1[1] * a2[0] - v[2]])])

    def se3_rows(n):
        q = rng.normal(size=(n, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        return np.concatenate([q, rng.normal(size=(n, 3))], 1)

    variables = [
        Variable("a", Euclidean(2), rng.normal(size=(n_a, 2))),
        Variable("T", SE3(), se3_rows(n_b)),
        Variable("P", SE3(), se3_rows(n_e), eliminate=True),
    ]
    idx = [rng.integers(0, n, K) for n in (n_a, n_a, n_b, n_e)]
    f = FactorGroup("f", fn, ("a", "a", "T", "P"), idx, rng.normal(size=(K, 3)), sigma=0.5,
                    sqrt_weight=rng.uniform(0.5, 1.5, K))
    return Problem(variables, [f])


def _assembled_dense(problem, values):
    layout = linear.make_layout(problem)
    free = linear.free_masks(problem)
    _, system, _, _ = jax.jit(lambda x: linear.linearize(problem, layout, x, free))(values)
    ns = layout.n_shared
    (V,), (W,), (ge,) = system.V, system.W, system.g_e
    N_e, d = V.shape[0], V.shape[1]
    H = np.zeros((ns + N_e * d,) * 2)
    H[:ns, :ns] = system.H_ss
    for i in range(N_e):
        s = slice(ns + i * d, ns + (i + 1) * d)
        H[s, s] = V[i]
        H[:ns, s] = W[i]
        H[s, :ns] = np.asarray(W[i]).T
    return H, np.concatenate([np.asarray(system.g_s), np.asarray(ge).reshape(-1)])


def test_block_assembly_matches_dense_jacobian_both_paths():
    """Grouped path (few entry combinations) and pairwise path (many) against a dense JᵀJ, Jᵀr."""
    for n_a, n_b, n_e, K in ((1, 1, 4, 30), (3, 5, 4, 20)):  # prod nums 4 <= 30; 3·3·5·4 = 180 > 20
        problem = _toy_problem(n_a + K, n_a, n_b, n_e, K)
        values = problem.initial_values()
        _, names, _, H_ref, g_ref = _dense_reference(problem, values)
        H, g = _assembled_dense(problem, values)
        # dense reference ordering is (a, T, P) = engine ordering (shared a, T; then eliminated P)
        assert names == ["a", "T", "P"]
        scale = np.max(np.abs(H_ref))
        np.testing.assert_allclose(H, H_ref, rtol=1e-10, atol=1e-10 * scale)  # float64 sums of O(K) terms
        np.testing.assert_allclose(g, g_ref, rtol=1e-10, atol=1e-10 * max(np.max(np.abs(g_ref)), 1.0))
