"""Benchmark the engine on a synthetic camera calibration (9x6 board, pinhole + k1, k2).

Prints one table: views, observations, compile time, iterations, median steady-state time of
``jcalib.solve.solve`` (one compiled function: LM, residuals and the covariance blocks, results on the
host) and of the solve plus the intrinsics covariance read from its Solution, and
optimistix.LevenbergMarquardt (dense) at 25 views.

    .venv/bin/python benchmarks/bench_solver.py [--views 25 100 400] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import jcalib  # noqa: F401  (float64)
from jcalib.solve import SE3, Euclidean, FactorGroup, Problem, Variable, solve
from jcalib.solve.manifolds import quat_rotate

TRUE_K = np.array([800.0, 790.0, 640.0, 480.0, -0.2, 0.05])


def project(K, T_cam_target, obs):
    """Pinhole + radial k1, k2; ``K (6,)``, ``T (7,) wxyz_xyz``, obs = (p (3,) m, uv (2,) px) -> (2,) px."""
    p_target, uv = obs
    p = quat_rotate(T_cam_target[:4], p_target) + T_cam_target[4:]
    z = jnp.where(p[2] > 1e-6, p[2], 1.0)
    x, y = p[0] / z, p[1] / z
    r2 = x * x + y * y
    f = 1.0 + K[4] * r2 + K[5] * r2 * r2
    return jnp.stack([K[0] * x * f + K[2], K[1] * y * f + K[3]]) - uv


def make_data(num_views, seed=0, noise=0.2):
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.arange(9), np.arange(6), indexing="xy"), -1).reshape(-1, 2) * 0.03
    pts = np.concatenate([g - g.mean(0), np.zeros((54, 1))], 1)
    m = SE3()
    ident = jnp.array([1.0, 0, 0, 0, 0, 0, 0])
    poses = np.stack([np.asarray(m.retract(ident, jnp.asarray(np.r_[rng.uniform(-0.5, 0.5, 3),
                      rng.uniform(-0.12, 0.12), rng.uniform(-0.08, 0.08), rng.uniform(0.45, 0.75)])))
                      for _ in range(num_views)])
    vi = np.repeat(np.arange(num_views), 54)
    p_all = np.tile(pts, (num_views, 1))
    uv = np.asarray(jax.vmap(project, in_axes=(None, 0, 0))(jnp.asarray(TRUE_K), jnp.asarray(poses[vi]),
                                                           (jnp.asarray(p_all), jnp.zeros((len(vi), 2)))))
    uv = uv + noise * rng.standard_normal(uv.shape)
    P0 = np.stack([np.asarray(m.retract(jnp.asarray(T), jnp.asarray(rng.normal(0, [0.02] * 3 + [0.005] * 3))))
                   for T in poses])
    K0 = TRUE_K * np.array([1.03, 0.97, 1.0, 1.0, 0.0, 0.0]) + np.array([0, 0, 8.0, -6.0, 0, 0])
    return dict(points=p_all, uv=uv, view_index=vi, K0=K0, P0=P0)


def make_problem(d):
    K = Variable("intrinsics", Euclidean(6), d["K0"], coord_names=("fx", "fy", "cx", "cy", "k1", "k2"))
    poses = Variable("T_cam_target", SE3(), d["P0"], eliminate=True, entry_label="view {i} pose")
    f = FactorGroup("reprojection", project, ("intrinsics", "T_cam_target"),
                    (np.zeros(len(d["view_index"]), np.int32), d["view_index"]), (d["points"], d["uv"]), sigma=0.2)
    return Problem([K, poses], [f])


def timed(fn, repeats):
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return statistics.median(out)


def bench_engine(num_views, repeats):
    d = make_data(num_views)
    prob = make_problem(d)
    t = time.perf_counter()
    sol = solve(prob)
    first = time.perf_counter() - t
    solve_s = timed(lambda: solve(prob), repeats)  # the Solution holds host (NumPy) arrays: synchronous

    def with_cov():
        s = solve(prob)
        return np.asarray(s.covariance("intrinsics"))

    with_cov()  # compile the covariance path once
    cov_s = timed(with_cov, repeats)
    return dict(views=num_views, obs=len(d["uv"]), compile=first - solve_s, iters=sol.iterations,
                solve=solve_s, solve_cov=cov_s, status=sol.status.name)


def bench_optimistix(num_views, repeats):
    import optimistix as optx

    d = make_data(num_views)
    m = SE3()
    vi = jnp.asarray(d["view_index"])
    obs = (jnp.asarray(d["points"]), jnp.asarray(d["uv"]))
    K0, P0 = jnp.asarray(d["K0"]), jnp.asarray(d["P0"])

    def residuals(y, args):
        poses = jax.vmap(m.retract)(P0, y[6:].reshape(num_views, 6))
        return jax.vmap(project, in_axes=(None, 0, 0))(K0 + y[:6], poses[vi], obs).reshape(-1) / 0.2

    def solve_dense(y0):
        sol = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10), y0, max_steps=200)
        return sol.value, sol.stats["num_steps"]

    run = jax.jit(solve_dense)
    y0 = jnp.zeros(6 + 6 * num_views)
    t = time.perf_counter()
    value, steps = run(y0)
    value.block_until_ready()
    first = time.perf_counter() - t
    s = timed(lambda: run(y0)[0].block_until_ready(), repeats)
    return dict(views=num_views, obs=len(d["uv"]), compile=first - s, iters=int(steps),
                solve=s, solve_cov=float("nan"), status="optimistix LM (dense)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, nargs="*", default=[25, 100, 400])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-optimistix", action="store_true")
    args = ap.parse_args()
    rows = [bench_engine(n, args.repeats) for n in args.views]
    if not args.no_optimistix:
        rows.append(bench_optimistix(25, max(3, args.repeats // 2)))
    print(f"{'solver':<24}{'views':>6}{'obs':>7}{'compile s':>11}{'iters':>7}{'solve ms':>10}{'+cov ms':>9}")
    for r in rows:
        name = "jcalib LM (Schur)" if r["status"] != "optimistix LM (dense)" else "optimistix LM (dense)"
        print(f"{name:<24}{r['views']:>6}{r['obs']:>7}{r['compile']:>11.2f}{r['iters']:>7}"
              f"{1e3 * r['solve']:>10.2f}{1e3 * r['solve_cov']:>9.2f}")
    print("median of steady-state runs; compile = first call minus median; "
          f"status: {', '.join(r['status'] for r in rows)}")


if __name__ == "__main__":
    main()
