"""Time ``project`` for 1e6 points (jit, CPU) against OpenCV's ``projectPoints``.

Prints a table: model, compile time, jcalib ms (median), OpenCV ms (median), ratio jcalib/OpenCV,
and jcalib's time for the projection *with* its Jacobian (w.r.t. the point and the intrinsics,
``vmap(jacfwd)``). OpenCV's Python binding always returns (so always computes) the Jacobian of
``projectPoints`` (2N x (10 + n_dist) w.r.t. rvec, tvec, f, c, dist): the last column is the
like-for-like comparison. jcalib and OpenCV runs are interleaved so that load from other processes
hits both alike. XLA may use both CPU cores; OpenCV's projectPoints runs on one.

Run: ``.venv/bin/python benchmarks/bench_project.py [--points N] [--repeats R]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import equinox as eqx
import jax
import numpy as np

import jcalib  # noqa: F401  (float64)
from jcalib.geometry.cameras.sampling import random_camera

MODELS = ("pinhole", "opencv5", "opencv8", "opencv14", "fisheye")


def _opencv_project(
    name: str, K: np.ndarray, dist: np.ndarray, p: np.ndarray, p_fisheye: np.ndarray
):
    zero = np.zeros(3)
    if name == "fisheye":
        return cv2.fisheye.projectPoints(p_fisheye, zero, zero, K, dist)[0]
    return cv2.projectPoints(p, zero, zero, K, dist)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    n = args.points
    p_np = np.concatenate(
        [rng.uniform(-0.6, 0.6, (n, 2)), np.ones((n, 1))], axis=1
    ) * rng.uniform(0.5, 5.0, (n, 1))
    p_np = np.ascontiguousarray(p_np)
    p_fisheye = p_np[None]
    p_jax = jax.device_put(p_np)

    project = eqx.filter_jit(lambda model, p: model.project(p))

    @eqx.filter_jit
    def project_with_jacobian(model, p):
        def one(theta, q):
            return model.with_params(theta).project(q)

        jac = jax.vmap(jax.jacfwd(one, argnums=(0, 1)), in_axes=(None, 0))
        return project(model, p), jac(model.params, p)

    print(
        f"project: {n} points, float64, {jax.devices()[0].platform}, median of {args.repeats} runs"
    )
    print(f"jax {jax.__version__}, OpenCV {cv2.__version__}")
    header = (
        f"{'model':<10} {'compile s':>10} {'jcalib ms':>10} {'OpenCV ms':>10} {'ratio':>7} "
        f"{'max |diff| px':>14} {'jcalib+J ms':>12} {'ratio+J':>8}"
    )
    print(header)
    print("-" * len(header))
    for name in MODELS:
        model = random_camera(name, 1)
        K, dist = model.to_opencv()
        t0 = time.perf_counter()
        compiled = project.lower(model, p_jax).compile()
        compile_s = time.perf_counter() - t0
        out = compiled(model, p_jax).block_until_ready()  # warm-up
        ref = _opencv_project(name, K, dist, p_np, p_fisheye)
        diff = float(np.max(np.abs(np.asarray(out) - ref.reshape(n, 2))))
        with_jac = project_with_jacobian.lower(model, p_jax).compile()
        jax.block_until_ready(with_jac(model, p_jax))
        t_jax, t_cv, t_jac = [], [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(with_jac(model, p_jax))
            t_jac.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            compiled(model, p_jax).block_until_ready()
            t_jax.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            _opencv_project(name, K, dist, p_np, p_fisheye)
            t_cv.append(time.perf_counter() - t0)
        ms_jax = 1e3 * statistics.median(t_jax)
        ms_cv = 1e3 * statistics.median(t_cv)
        ms_jac = 1e3 * statistics.median(t_jac)
        print(
            f"{name:<10} {compile_s:>10.2f} {ms_jax:>10.1f} {ms_cv:>10.1f} "
            f"{ms_jax / ms_cv:>7.2f} {diff:>14.1e} {ms_jac:>12.1f} {ms_jac / ms_cv:>8.2f}"
        )


if __name__ == "__main__":
    main()
