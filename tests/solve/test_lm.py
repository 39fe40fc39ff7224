"""Levenberg–Marquardt engine: convergence, references, masks, robust losses, batching, tracing."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from solve_problems import (
    TRUE_INTRINSICS,
    calibration_data,
    calibration_problem,
    exp_curve,
    perturbed_start,
    project,
)

import jcalib
from jcalib.residuals import CauchyLoss, HuberLoss
from jcalib.solve import (
    SE3,
    Euclidean,
    FactorGroup,
    Problem,
    SolveOptions,
    Status,
    Variable,
    solve,
    solve_many,
)


@pytest.fixture(scope="module")
def calib():
    data = calibration_data(num_views=6, noise_px=0.1, seed=0)
    K0, P0 = perturbed_start(data, np.random.default_rng(1))
    return data, K0, P0


def _curve(seed=0, n=40, noise=0.01):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, n)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 + noise * rng.standard_normal(n)
    return t, y


def _curve_problem(t, y, theta0=(1.0, -0.5, 0.0)):
    v = Variable("theta", Euclidean(3), np.asarray(theta0), coord_names=("a", "b", "c"))
    f = FactorGroup("curve", exp_curve, ("theta",), (np.zeros(len(t), np.int32),), (t, y), sigma=0.01)
    return Problem([v], [f])


def test_curve_fit_matches_optimistix_to_1e8():
    t, y = _curve()
    sol = solve(_curve_problem(t, y))
    assert sol.status == Status.CONVERGED
    ref = optx.least_squares(
        lambda th, args: th[0] * jnp.exp(th[1] * t) + th[2] - y,
        optx.LevenbergMarquardt(rtol=1e-14, atol=1e-14),
        jnp.array([1.0, -0.5, 0.0]),
        max_steps=1000,
    ).value
    np.testing.assert_allclose(sol.values["theta"][0], ref, rtol=1e-8)
    assert sol.values["theta"].dtype == jnp.float64


def test_mini_calibration_matches_optimistix_to_1e8():
    # Same problem, dense reference: optimistix LM over the tangent displacement from the start.
    data = calibration_data(num_views=5, noise_px=0.2, seed=3, cols=7, rows=5)
    K0, P0 = perturbed_start(data, np.random.default_rng(4))
    sol = solve(calibration_problem(data, K0, P0, noise_px=0.2))
    assert sol.status == Status.CONVERGED
    vi = jnp.asarray(data["view_index"])
    obs = (jnp.asarray(data["points"]), jnp.asarray(data["uv"]))
    m = SE3()

    def residuals(y, args):
        K = jnp.asarray(K0) + y[:6]
        poses = jax.vmap(m.retract)(jnp.asarray(P0), y[6:].reshape(5, 6))
        return jax.vmap(project, in_axes=(None, 0, 0))(K, poses[vi], obs).reshape(-1)

    y = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=1e-14, atol=1e-14), jnp.zeros(36),
                           max_steps=1000).value
    # One optimum, compared in units of σ. A parameter δ away from the optimum raises the cost
    # (χ²/2 ≈ 160 here) by (δ/σ)²/2, so where a solver stops is resolved only to δ/σ ~ sqrt(ε·χ²·k)
    # ≈ 3e-7·sqrt(k), k the rounding errors accumulated in the residual sums (up to ~1e3: ~1e-5),
    # and where inside that band depends on the CPU: 4e-8 σ here; 3e-8 absolute in a distortion
    # coefficient (σ ≥ 0.014) on another runner, i.e. up to 2e-6 σ. A different optimum is ~σ away.
    sigma_K = np.sqrt(np.diag(sol.covariance("intrinsics")))
    assert np.all(np.abs(np.asarray(sol.values["intrinsics"][0]) - (K0 + np.asarray(y[:6]))) < 3e-5 * sigma_K)
    for i in range(5):
        d = m.local(m.retract(jnp.asarray(P0[i]), y[6 + 6 * i: 12 + 6 * i]), sol.values["T_cam_target"][i])
        sigma_P = np.sqrt(np.diag(sol.covariance("T_cam_target", i)))
        assert np.all(np.abs(np.asarray(d)) < 3e-5 * sigma_P)  # tangent (rad, m) in units of its σ


def test_noiseless_calibration_recovers_truth_from_perturbed_start():
    data = calibration_data(num_views=6, noise_px=0.0, seed=0)
    K0, P0 = perturbed_start(data, np.random.default_rng(1))
    sol = solve(calibration_problem(data, K0, P0))
    assert sol.status == Status.CONVERGED
    assert 3 <= sol.iterations <= 30
    # parameter recovery from noiseless data: 1e-6 relative
    np.testing.assert_allclose(sol.values["intrinsics"][0], TRUE_INTRINSICS, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(sol.values["T_cam_target"][:, 4:], data["poses"][:, 4:], atol=1e-8)


def test_schur_and_cg_paths_agree_with_plain_cholesky(calib):
    data, K0, P0 = calib
    ref = solve(calibration_problem(data, K0, P0))
    # poses not eliminated: one dense shared system of 6 + 6·6 unknowns, solved by block-Jacobi PCG.
    cg = solve(calibration_problem(data, K0, P0, eliminate=False), options=SolveOptions(cg_threshold=0))
    assert ref.status == cg.status == Status.CONVERGED
    # PCG steps are inexact (attainable accuracy ~ cond(S)·eps with cond ~1e8 here): 1e-7 relative,
    # i.e. ~1e-6 of a standard deviation.
    np.testing.assert_allclose(cg.values["intrinsics"], ref.values["intrinsics"], rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(cg.values["T_cam_target"], ref.values["T_cam_target"], atol=1e-8)


def test_fixed_masks_hold_values_exactly(calib):
    data, K0, P0 = calib
    K_fixed = np.array([False, False, True, True, False, False])  # cx, cy held
    pose_fixed = np.zeros((6, 6), bool)
    pose_fixed[2] = True  # whole view 2 pose held
    prob = calibration_problem(data, K0, P0, K_fixed=K_fixed, pose_fixed=pose_fixed)
    sol = solve(prob)
    assert sol.status == Status.CONVERGED
    K = np.asarray(sol.values["intrinsics"][0])
    assert K[2] == K0[2] and K[3] == K0[3]  # bit-for-bit
    assert np.array_equal(np.asarray(sol.values["T_cam_target"][2]), P0[2])
    assert not np.allclose(K[:2], K0[:2])  # the free ones moved
    assert sol.num_free == 4 + 5 * 6
    C = sol.covariance("intrinsics")
    assert np.all(C[2:4, :] == 0.0) and np.all(C[:, 2:4] == 0.0)
    assert np.all(sol.covariance("T_cam_target", 2) == 0.0)


def test_robust_losses_down_weight_outliers(calib):
    data, K0, P0 = calib
    rng = np.random.default_rng(7)
    bad = rng.choice(len(data["uv"]), size=len(data["uv"]) // 20, replace=False)
    d2 = dict(data)
    d2["uv"] = data["uv"].copy()
    d2["uv"][bad] += rng.choice([-1.0, 1.0], size=(len(bad), 2)) * 15.0  # 15 px outliers, 5 %
    err = {}
    for name, loss in [("l2", None), ("huber", HuberLoss(3.0)), ("cauchy", CauchyLoss(3.0))]:
        sol = solve(calibration_problem(d2, K0, P0, loss=loss))
        assert sol.status == Status.CONVERGED
        err[name] = np.abs(np.asarray(sol.values["intrinsics"][0, :4]) - TRUE_INTRINSICS[:4]).max()
    clean = solve(calibration_problem(data, K0, P0))
    clean_err = np.abs(np.asarray(clean.values["intrinsics"][0, :4]) - TRUE_INTRINSICS[:4]).max()
    assert err["huber"] < 0.5 * err["l2"]
    assert err["cauchy"] < 0.2 * err["l2"]
    assert err["cauchy"] < clean_err + 3.0  # px; within a few σ of the outlier-free fit


def test_weight_zero_masks_observations_like_removing_them():
    t, y = _curve(n=40)
    w = np.ones(40)
    w[::7] = 0.0
    y_bad = y.copy()
    y_bad[::7] = np.nan  # masked observations may even be garbage
    v = Variable("theta", Euclidean(3), np.array([1.0, -0.5, 0.0]), coord_names=("a", "b", "c"))
    f = FactorGroup("curve", exp_curve, ("theta",), (np.zeros(40, np.int32),), (t, y_bad), sigma=0.01,
                    sqrt_weight=w)
    sol_w = solve(Problem([v], [f]))
    keep = w > 0
    sol_r = solve(_curve_problem(t[keep], y[keep]))
    assert sol_w.status == sol_r.status == Status.CONVERGED
    np.testing.assert_allclose(sol_w.values["theta"], sol_r.values["theta"], rtol=1e-9)
    assert sol_w.num_residuals == sol_r.num_residuals == keep.sum()


def test_vmap_over_batch_matches_individual_solves_and_masks_finished_members():
    problems = []
    for seed in range(3):
        data = calibration_data(num_views=6, noise_px=0.1 + 0.2 * seed, seed=10 + seed)
        K0, P0 = perturbed_start(data, np.random.default_rng(seed), k_scale=1.0 + 2 * seed)
        problems.append(calibration_problem(data, K0, P0))
    sols = solve_many(problems)
    for p, s in zip(problems, sols):
        one = solve(p)
        assert s.status == one.status == Status.CONVERGED
        # a finished member stops changing: same iterations and values as its own solve
        assert s.iterations == one.iterations
        # batched linear algebra rounds differently: equal to 1e-7 relative (~1e-6 σ)
        np.testing.assert_allclose(s.values["intrinsics"], one.values["intrinsics"], rtol=1e-7)
    assert len({s.iterations for s in sols}) > 1  # the batch really had members finishing early


TRACES = {"count": 0}


def _counted_project(K, T, obs):
    TRACES["count"] += 1  # Python side effect: runs once per trace, never per call
    return project(K, T, obs)


def test_new_data_set_of_similar_size_does_not_retrace():
    def problem(num_views, seed):
        data = calibration_data(num_views=num_views, noise_px=0.1, seed=seed, cols=5, rows=4)
        K0, P0 = perturbed_start(data, np.random.default_rng(seed))
        K = Variable("intrinsics", Euclidean(6), K0)
        poses = Variable("T_cam_target", SE3(), P0, eliminate=True)
        f = FactorGroup("reprojection", _counted_project, ("intrinsics", "T_cam_target"),
                        (np.zeros(len(data["uv"]), np.int32), data["view_index"]),
                        (data["points"], data["uv"]), sigma=0.1)
        return Problem([K, poses], [f])

    s1 = solve(problem(21, 1))  # 21 views, 420 points -> buckets 24 views, 448 observations
    traces = TRACES["count"]
    assert traces > 0
    s2 = solve(problem(22, 2))  # 22 views, 440 points -> same buckets
    assert TRACES["count"] == traces
    assert s1.status == s2.status == Status.CONVERGED
    assert s2.values["T_cam_target"].shape == (22, 7) and s2.num_free == 6 + 22 * 6


def test_bad_index_is_named():
    data = calibration_data(num_views=3, noise_px=0.1, seed=0, cols=3, rows=3)
    K0, P0 = perturbed_start(data, np.random.default_rng(1))
    vi = data["view_index"].copy()
    vi[5] = 3
    with pytest.raises(jcalib.BadInputError, match=r"'reprojection'.*'T_cam_target'.*index 3 at observation 5"):
        calibration_problem(dict(data, view_index=vi), K0, P0)
    with pytest.raises(jcalib.BadInputError, match="at most one eliminated"):
        v = Variable("a", Euclidean(1), np.zeros((2, 1)), eliminate=True)
        w = Variable("b", Euclidean(1), np.zeros((2, 1)), eliminate=True)
        Problem([v, w], [FactorGroup("f", lambda a, b, o: a - b, ("a", "b"), (np.arange(2), np.arange(2)))])


def test_non_finite_input_is_reported():
    t, y = _curve(n=10)
    y = y.copy()
    y[3] = np.nan
    sol = solve(_curve_problem(t, y))
    assert sol.status == Status.NON_FINITE
    with pytest.raises(jcalib.BadInputError, match="'theta' value"):
        solve(_curve_problem(t, _curve(n=10)[1], theta0=(np.inf, 0.0, 0.0)))


def test_prior_pulls_towards_mean_and_counts_as_residuals():
    t, y = _curve(n=40)
    v = Variable("theta", Euclidean(3), np.array([1.0, -0.5, 0.0]),
                 prior_mean=np.array([2.0, -1.3, 0.7]), prior_sqrt_info=np.diag([0.0, 0.0, 1e4]))
    f = FactorGroup("curve", exp_curve, ("theta",), (np.zeros(len(t), np.int32),), (t, y), sigma=0.01)
    sol = solve(Problem([v], [f]))
    assert abs(float(sol.values["theta"][0, 2]) - 0.7) < 1e-3  # tight prior on c wins
    assert sol.num_residuals == 40 + 3
    # exact solution of the normal equations with the prior: gradient of the total cost vanishes
    def cost(th):
        r = (th[0] * jnp.exp(th[1] * t) + th[2] - y) / 0.01
        return 0.5 * jnp.sum(r * r) + 0.5 * (1e4 * (th[2] - 0.7)) ** 2
    g = jax.grad(cost)(sol.values["theta"][0])
    H = jax.hessian(cost)(sol.values["theta"][0])
    # Newton step from the optimum ~ 0: 1e-8 ≪ σ(b) ≈ 5e-3 (cond(H) ~ 1e4 after the 1e4 prior)
    assert np.abs(np.linalg.solve(H, g)).max() < 1e-8
