"""Covariance from the Schur-reduced system vs a dense reference, and Monte Carlo χ² checks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats
from solve_problems import TRUE_INTRINSICS, calibration_data, calibration_problem, perturbed_start, project

import jcalib  # noqa: F401
from jcalib.solve import SE3, Status, lm_solve, solve, stack_problems
from jcalib.solve import linear

NV = 5


@pytest.fixture(scope="module")
def solved():
    data = calibration_data(num_views=NV, noise_px=0.3, seed=5, cols=5, rows=4)
    K0, P0 = perturbed_start(data, np.random.default_rng(6))
    sol = solve(calibration_problem(data, K0, P0, noise_px=0.3))
    assert sol.status == Status.CONVERGED
    return data, sol


def _dense_reference(data, sol):
    """σ̂²·(JᵀJ)⁻¹ over (δK, δpose_0..δpose_{N-1}) from one dense Jacobian (tiny problem only)."""
    m = SE3()
    K, P = sol.values["intrinsics"][0], sol.values["T_cam_target"]
    vi = jnp.asarray(data["view_index"])
    obs = (jnp.asarray(data["points"]), jnp.asarray(data["uv"]))

    def r(delta):
        poses = jax.vmap(m.retract)(P, delta[6:].reshape(NV, 6))
        return jax.vmap(project, in_axes=(None, 0, 0))(K + delta[:6], poses[vi], obs).reshape(-1) / 0.3

    n = 6 + 6 * NV
    J = np.asarray(jax.jacfwd(r)(jnp.zeros(n)))
    res = np.asarray(r(jnp.zeros(n)))
    sigma2 = res @ res / (J.shape[0] - n)
    s = 1.0 / np.sqrt(np.sum(J * J, axis=0))  # Jacobi scaling keeps the dense inverse accurate
    Js = J * s
    return sigma2 * s[:, None] * np.linalg.inv(Js.T @ Js) * s[None, :], sigma2, J


def _assert_close_cov(C, C_ref):
    # 1e-9 relative, measured in correlation units (scale-free across px and rad)
    d = np.sqrt(np.diag(C_ref))
    assert np.max(np.abs(C - C_ref) / np.outer(d, d)) < 1e-9


def test_covariance_matches_dense_inverse(solved):
    data, sol = solved
    C_ref, sigma2, _ = _dense_reference(data, sol)
    assert abs(sol.sigma2 - sigma2) < 1e-9 * sigma2
    _assert_close_cov(np.asarray(sol.covariance("intrinsics")), C_ref[:6, :6])
    for i in (0, 3):
        a = 6 + 6 * i
        _assert_close_cov(np.asarray(sol.covariance("T_cam_target", i)), C_ref[a:a + 6, a:a + 6])
    # all eliminated entries jointly: cross terms V_i⁻¹ W_iᵀ Σ_ss W_j V_j⁻¹
    _assert_close_cov(np.asarray(sol.covariance("T_cam_target")), C_ref[6:, 6:])
    stated = np.asarray(sol.covariance("intrinsics", noise="stated"))
    np.testing.assert_allclose(stated * sol.sigma2, sol.covariance("intrinsics"), rtol=1e-12)


def test_propagated_covariance_matches_dense_reference(solved):
    data, sol = solved
    C_ref, _, _ = _dense_reference(data, sol)
    m = SE3()
    p = jnp.array([0.05, -0.02, 0.0])

    def pixel(values):  # a board point seen in view 1, plus fx·fy to mix units
        uv = project(values["intrinsics"][0], values["T_cam_target"][1], (p, jnp.zeros(2)))
        return jnp.concatenate([uv, values["intrinsics"][0, :1] * values["intrinsics"][0, 1:2]])

    def pixel_flat(delta):
        K = sol.values["intrinsics"][0] + delta[:6]
        poses = jax.vmap(m.retract)(sol.values["T_cam_target"], delta[6:].reshape(NV, 6))
        return pixel({"intrinsics": K[None], "T_cam_target": poses})

    Jy = np.asarray(jax.jacfwd(pixel_flat)(jnp.zeros(6 + 6 * NV)))
    _assert_close_cov(np.asarray(sol.propagate(pixel)), Jy @ C_ref @ Jy.T)


def test_monte_carlo_errors_follow_reported_covariance():
    """300 re-solves under fresh noise (fixed seed), one vmapped jit call.

    8 views of a 6x5 board at 0.2 px: close enough to linear for first-order covariance (with 5
    views of 5x4 at 0.3 px the spread exceeds the first-order prediction by 10-20 %: that is the
    problem's nonlinearity, not the covariance code, which the dense test checks to 1e-9).
    """
    trials, noise = 300, 0.2
    base = calibration_data(num_views=8, noise_px=0.0, seed=11, cols=6, rows=5)
    rng = np.random.default_rng(12)
    K0, P0 = perturbed_start(base, np.random.default_rng(13), k_scale=0.3, pose_rot=0.01, pose_trans=0.003)
    problems = []
    for _ in range(trials):
        d = dict(base, uv=base["uv_clean"] + noise * rng.standard_normal(base["uv_clean"].shape))
        problems.append(calibration_problem(d, K0, P0, noise_px=noise))
    # Three vmapped batches of 100 through one compiled solve (one batch of 300 was seen to stall
    # XLA's CPU runtime on this 2-core machine).
    solve_batch = jax.jit(jax.vmap(lm_solve))
    raws = [solve_batch(stack_problems(problems[i : i + 100])) for i in range(0, trials, 100)]
    raw = jax.tree.map(lambda *parts: jnp.concatenate(parts), *raws)
    assert np.all(np.asarray(raw.status) == Status.CONVERGED)

    @jax.jit
    @jax.vmap
    def intrinsics_cov(system):  # stated noise: Σ_ss = S⁻¹ of the reduced system
        S, _ = linear.reduced_system(system, None, None)
        return jnp.linalg.inv(S)[:6, :6]

    C = np.asarray(intrinsics_cov(raw.system))
    e = np.asarray(raw.values["intrinsics"][:, 0]) - TRUE_INTRINSICS
    q = np.einsum("ti,tij,tj->t", e, np.linalg.inv(C), e)
    alpha = 1e-3  # two-sided, per check
    lo, hi = scipy.stats.chi2.ppf([alpha / 2, 1 - alpha / 2], 6 * trials)
    assert lo < q.sum() < hi, (q.sum(), lo, hi)
    # each parameter: Σ e² / σ̄² ~ χ²(trials) (true mean is known: zero)
    lo1, hi1 = scipy.stats.chi2.ppf([alpha / 2, 1 - alpha / 2], trials)
    ratio = np.sum(e * e, axis=0) / np.mean(np.diagonal(C, axis1=1, axis2=2), axis=0)
    assert np.all((lo1 < ratio) & (ratio < hi1)), ratio
    # a-posteriori variance factor: Σ (m − n) σ̂² ~ χ²(trials·(m − n))
    dof = int(raw.num_residuals[0]) - int(raw.num_free[0])
    lo2, hi2 = scipy.stats.chi2.ppf([alpha / 2, 1 - alpha / 2], trials * dof)
    assert lo2 < 2.0 * np.asarray(raw.cost).sum() < hi2
