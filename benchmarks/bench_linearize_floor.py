"""Where a vmapped camera calibration spends its time on XLA:CPU, and the floor of this design.

Issue 3 asks for 1000 vmapped Monte-Carlo calibrations (N=25) >= 10x faster than 1000 sequential
``cv2.calibrateCamera`` calls on this 2-core CPU, i.e. <= 1/10 of OpenCV's time per calibration.
This script measures, on the padded problems ``jcalib.calibrate_batch`` solves (the one builder's
camera-only cell, batches of :func:`jcalib.solve.batch_width`, opencv5, 9x6 board, 25 views of
``bench_calibrate.py``), per member:

1. the pieces of one calibration: the host preparation (graph, Zhang / PnP closed-form start, the
   problem), the vmapped LM loop alone (``jax.vmap(lm_solve)``), the whole batched solve
   (``solve_many``: padding, LM + covariance blocks, Solutions on the host), one linearisation
   (residuals, Jacobian, per-view normal-equation blocks), one Schur solve;
2. the Jacobian three ways: the engine's autodiff of the whole residual (reverse mode per corner,
   through the quaternion poses), the corner factor's own ``jacobian`` (autodiff through the lens
   model only, the poses by the chain rule: what jcalib runs), and a fully hand-derived opencv5
   Jacobian (structure of arrays, no autodiff) as a lower bound for hand-written code; all three are
   checked against each other;
3. the implied floor of a calibration: start + (iterations + 1) linearisations + solves, against
   OpenCV's time / 10.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_linearize_floor.py [--repeats 30]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_calibrate as B  # noqa: E402

import jcalib  # noqa: E402
from jcalib.io.cell import parse_cell  # noqa: E402
from jcalib.io.observations import parse_observations  # noqa: E402
from jcalib.problems.calibrate import prepare  # noqa: E402
from jcalib.solve import (  # noqa: E402
    FactorGroup,
    SolveOptions,
    batch_width,
    bucket_size,
    linear,
    lm_solve,
    pad_problem,
    solve_many,
    stack_problems,
)

BATCH = batch_width(64)  # what calibrate_batch uses on this backend (8 on the CPU)


def median_time(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))  # compile
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def analytic_opencv5(intr, pose, points, pixels, sigma):
    """Whitened residuals ``(K, 2)`` and Jacobian ``(K, 2, 15)`` of the opencv5 reprojection.

    Columns: ``fx, fy, cx, cy, k1, k2, p1, p2, k3`` then the target pose tangent ``(rx, ry, rz,
    tx, ty, tz)`` with the engine's right perturbation ``T · Exp(δ)``: ``∂p_cam/∂ω = −R[p]×``,
    ``∂p_cam/∂v = R``. Every entry is a ``(K,)`` array (structure of arrays); no autodiff.
    """
    w, x, y, z = pose[:, 0], pose[:, 1], pose[:, 2], pose[:, 3]
    px, py, pz = points[:, 0], points[:, 1], points[:, 2]
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    X = r00 * px + r01 * py + r02 * pz + pose[:, 4]
    Y = r10 * px + r11 * py + r12 * pz + pose[:, 5]
    Z = r20 * px + r21 * py + r22 * pz + pose[:, 6]
    iz = 1.0 / Z
    a, b = X * iz, Y * iz
    r2 = a * a + b * b
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (intr[i] for i in range(9))
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    drad = k1 + r2 * (2 * k2 + 3 * r2 * k3)
    xd = a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    yd = b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    dxa = rad + 2 * a * a * drad + 2 * p1 * b + 6 * p2 * a
    dxb = 2 * a * b * drad + 2 * p1 * a + 2 * p2 * b
    dyb = rad + 2 * b * b * drad + 6 * p1 * b + 2 * p2 * a
    ua, ub, va, vb = fx * dxa, fx * dxb, fy * dxb, fy * dyb
    uX, uY, uZ = ua * iz, ub * iz, -(ua * a + ub * b) * iz
    vX, vY, vZ = va * iz, vb * iz, -(va * a + vb * b) * iz
    gu = (uX * r00 + uY * r10 + uZ * r20, uX * r01 + uY * r11 + uZ * r21, uX * r02 + uY * r12 + uZ * r22)
    gv = (vX * r00 + vY * r10 + vZ * r20, vX * r01 + vY * r11 + vZ * r21, vX * r02 + vY * r12 + vZ * r22)

    def rot_cols(g):  # −g·[p]×
        return (g[2] * py - g[1] * pz, g[0] * pz - g[2] * px, g[1] * px - g[0] * py)

    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    r4 = r2 * r2
    Ju = [xd, zero, one, zero, fx * a * r2, fx * a * r4, fx * 2 * a * b, fx * (r2 + 2 * a * a), fx * a * r4 * r2,
          *rot_cols(gu), *gu]
    Jv = [zero, yd, zero, one, fy * b * r2, fy * b * r4, fy * (r2 + 2 * b * b), fy * 2 * a * b, fy * b * r4 * r2,
          *rot_cols(gv), *gv]
    r = jnp.stack([fx * xd + cx - pixels[:, 0], fy * yd + cy - pixels[:, 1]], -1) / sigma
    J = jnp.stack([jnp.stack(Ju, -1), jnp.stack(Jv, -1)], -2) / sigma
    return r, J


def stacked_problems(problems):
    """The problems padded to one shape bucket and stacked, as :func:`jcalib.solve.solve_many` does."""
    entries = {v.name: max(bucket_size(p.variable(v.name).num) for p in problems) for v in problems[0].variables}
    num_obs = {}
    for k, f in enumerate(problems[0].factors):
        c = f.chunk or 1
        num_obs[f.name] = max(bucket_size(p.factors[k].num_obs // c) for p in problems) * c
    return stack_problems([pad_problem(p, num_entries=entries, num_obs=num_obs) for p in problems])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()

    cell = parse_cell(B.CELL)
    cam, poses = B.make_views(25, seed=1)
    sets = [B.make_data(cam, poses, seed=1000 + i) for i in range(BATCH)]
    options = jcalib.CalibrationOptions()
    obs = [parse_observations(d) for d, *_ in sets]
    prepared = [prepare(cell, o, options) for o in obs]
    prep_times = []
    for _ in range(max(3, args.repeats // 10)):
        t0 = time.perf_counter()
        for o in obs:
            prepare(cell, o, options)
        prep_times.append(time.perf_counter() - t0)
    problems = [built.problem for _, _, built in prepared]
    stacked = stacked_problems(problems)
    (corners,) = [k for k, f in enumerate(problems[0].factors) if f.name.startswith("corners:")]
    f0 = problems[0].factors[corners]
    intr_name, rig_name, pose_name = f0.args
    so = SolveOptions()
    lm = jax.jit(jax.vmap(lambda p: lm_solve(p, so)))
    raw = jax.block_until_ready(lm(stacked))
    values = raw.values
    iterations = np.asarray(raw.iterations)
    chunk = f0.chunk

    def engine_problem(p, hand=True):
        if hand:
            return p
        plain = tuple(FactorGroup(f.name, f.fn, f.args, f.indices, f.observations, f.sigma, f.sqrt_weight, f.loss,
                                  f.chunk, jacobian=None) for f in p.factors)
        return eqx.tree_at(lambda q: q.factors, p, plain)

    def lin_engine(p, x):
        layout, free = linear.make_layout(p), linear.free_masks(p)
        return linear.linearize(p, layout, x, free)

    def jac_engine(p, x, hand=True):
        p = engine_problem(p, hand)
        _, H, g, r, J, _, _ = linear.factor_linearization(p, x, p.factors[corners], linear.free_masks(p))
        return r, J

    def lin_engine_autodiff(p, x):
        p = engine_problem(p, hand=False)
        layout, free = linear.make_layout(p), linear.free_masks(p)
        return linear.linearize(p, layout, x, free)

    def residual_engine(p, x):
        f = p.factors[corners]
        rows = [x[n][i] for n, i in zip(f.args, f.indices)]
        return jax.vmap(f.fn)(*rows, f.observations)

    def analytic(p, x):
        f = p.factors[corners]
        pose = x[pose_name][f.indices[2]]
        r, J = analytic_opencv5(x[intr_name][0], pose, f.observations[0], f.observations[1], f.sigma)
        w = f.sqrt_weight
        return r * w[:, None], J * w[:, None, None]

    def lin_analytic(p, x):
        r, J = analytic(p, x)
        K = J.shape[0]
        Jc = J.reshape(K // chunk, chunk * 2, 15)
        return jnp.einsum("cri,crj->cij", Jc, Jc), jnp.einsum("cri,cr->ci", Jc, r.reshape(K // chunk, chunk * 2))

    def jac_chain(p, x):
        """The corner factor's own jacobian (lens-model autodiff + chain rule), without the engine around it."""
        f = p.factors[corners]
        intr, rig = x[intr_name][0], x[rig_name][0]
        pose = x[pose_name][f.indices[2]]

        def one(T, obs, w):
            r, (J_k, _, J_pose) = f.jacobian(intr, rig, T, obs)
            s = w / f.sigma
            return r * s, jnp.concatenate([J_k, J_pose], axis=1) * s

        return jax.vmap(one)(pose, f.observations, f.sqrt_weight)

    def solve_step(p, system):
        layout = linear.make_layout(p)
        ds, de = linear.diagonal(system)
        return linear.schur_solve(system, layout, -system.g_s[:, None], tuple(-g[..., None] for g in system.g_e),
                                  1e-3 * ds, tuple(1e-3 * d for d in de), 2000, 500, 1e-12)

    vm = jax.vmap
    system = jax.jit(vm(lin_engine))(stacked, values)[1]
    # the hand-derived Jacobian must be the engine's (same layout, whitening, tangent convention)
    r_e, J_e = jax.jit(vm(jac_engine))(stacked, values)
    r_a, J_a = jax.jit(vm(analytic))(stacked, values)
    _, J_c = jax.jit(vm(jac_chain))(stacked, values)
    J_e_used = jnp.concatenate([J_e[..., :9], J_e[..., -6:]], axis=-1)  # intrinsics, target pose (rig held)
    chain_err = float(jnp.max(jnp.abs(J_c - J_e_used)) / jnp.max(jnp.abs(J_e_used)))
    _, J_ad = jax.jit(vm(functools.partial(jac_engine, hand=False)))(stacked, values)
    ad_err = float(jnp.max(jnp.abs(J_ad - J_e)) / jnp.max(jnp.abs(J_e)))
    jac_err = float(jnp.max(jnp.abs(J_a - J_e_used)) / jnp.max(jnp.abs(J_e_used)))
    res_err = float(jnp.max(jnp.abs(jnp.abs(r_a) - jnp.abs(r_e))))

    solve_many(problems)  # compile
    solve_times = []
    for _ in range(max(5, args.repeats // 3)):
        t0 = time.perf_counter()
        solve_many(problems)
        solve_times.append(time.perf_counter() - t0)
    t = {
        "host preparation (graph, Zhang/PnP start, problem)": statistics.median(prep_times),
        "batched solve (solve_many: pad, LM + covariance, results)": statistics.median(solve_times),
        "LM loop alone (jit(vmap(lm_solve)))": median_time(lm, stacked, repeats=max(5, args.repeats // 3)),
        "residuals only (engine factor, vmapped per corner)": median_time(jax.jit(vm(residual_engine)), stacked,
                                                                          values, repeats=args.repeats),
        "Jacobian, engine autodiff of the whole residual": median_time(
            jax.jit(vm(functools.partial(jac_engine, hand=False))), stacked, values, repeats=args.repeats),
        "Jacobian, engine with the factor's jacobian (default)": median_time(jax.jit(vm(jac_engine)), stacked,
                                                                             values, repeats=args.repeats),
        "linearisation, engine autodiff of the whole residual": median_time(
            jax.jit(vm(lin_engine_autodiff)), stacked, values, repeats=args.repeats),
        "linearisation, engine with the factor's jacobian": median_time(jax.jit(vm(lin_engine)), stacked,
                                                                        values, repeats=args.repeats),
        "Jacobian, model autodiff + chain rule, outside the engine": median_time(
            jax.jit(vm(jac_chain)), stacked, values, repeats=args.repeats),
        "Jacobian, hand-derived (structure of arrays)": median_time(jax.jit(vm(analytic)), stacked, values,
                                                                    repeats=args.repeats),
        "linearisation, hand-derived Jacobian + per-view blocks": median_time(jax.jit(vm(lin_analytic)), stacked,
                                                                              values, repeats=args.repeats),
        "Schur solve of one LM step": median_time(jax.jit(vm(solve_step)), stacked, system, repeats=args.repeats),
    }
    cv_times = []
    for _ in range(max(5, args.repeats // 3)):
        for _, o, i, _ in sets:
            s = time.perf_counter()
            cv2.calibrateCamera(o, i, B.SIZE, None, None, criteria=B.CRITERIA)
            cv_times.append(time.perf_counter() - s)
    cv_ms = statistics.median(cv_times) * 1e3

    n_corners = stacked.factors[corners].sqrt_weight.shape[1]
    print(f"\nbatch of {BATCH} calibrations, N=25 views, padded to {n_corners} corners each "
          f"(chunk {chunk}); iterations per member {iterations.tolist()} (the batch runs {iterations.max()} "
          f"+ 1 linearisations)")
    print(f"max relative Jacobian difference to the engine's default: whole-residual autodiff {ad_err:.1e}, "
          f"hand-derived {jac_err:.1e} (residuals {res_err:.1e} px/σ), model autodiff + chain rule {chain_err:.1e}")
    print(f"{'what (per member)':<58} {'ms':>8}")
    for k, v in t.items():
        print(f"{k:<58} {v / BATCH * 1e3:>8.3f}")
    n_lin = int(iterations.max()) + 1
    per = {k: v / BATCH * 1e3 for k, v in t.items()}
    start = per["host preparation (graph, Zhang/PnP start, problem)"]
    floor_autodiff = start + n_lin * (per["linearisation, engine autodiff of the whole residual"]
                                      + per["Schur solve of one LM step"])
    floor_engine = start + n_lin * (per["linearisation, engine with the factor's jacobian"]
                                    + per["Schur solve of one LM step"])
    floor_hand = start + n_lin * (per["linearisation, hand-derived Jacobian + per-view blocks"]
                                  + per["Schur solve of one LM step"])
    print(f"\n{'per calibration':<58} {'ms':>8}")
    print(f"{'OpenCV calibrateCamera (same corners, median)':<58} {cv_ms:>8.3f}")
    print(f"{'10x target: OpenCV / 10':<58} {cv_ms / 10:>8.3f}")
    print(f"{'start + linearisations + solves, whole-residual autodiff':<58} {floor_autodiff:>8.3f}")
    print(f"{'same, the corner factor jacobian (what jcalib runs)':<58} {floor_engine:>8.3f}")
    print(f"{'same with the hand-derived Jacobian (one core)':<58} {floor_hand:>8.3f}")
    print(f"{'same, ideal split over 2 cores':<58} {floor_hand / 2:>8.3f}")


if __name__ == "__main__":
    main()
