"""Time ``project`` for 1e6 points (jit, CPU) against OpenCV's ``projectPoints``.

Prints a table: model, compile time, jcalib ms (median), OpenCV ms (median), ratio jcalib/OpenCV.
jcalib and OpenCV runs are interleaved so that load from other processes hits both alike.

Run: ``.venv/bin/python benchmarks/bench_project.py [--points N] [--repeats R]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import jcalib  # noqa: F401  (float64)
import cv2
import equinox as eqx
import jax
import numpy as np

from jcalib.geometry.cameras.sampling import random_camera

MODELS = ("pinhole", "opencv5", "opencv8", "opencv14", "fisheye")


def _opencv_project(name: str, K: np.ndarray, dist: np.ndarray, p: np.ndarray, p_fisheye: np.ndarray):
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

    print(f"project: {n} points, float64, {jax.devices()[0].platform}, median of {args.repeats} runs")
    print(f"jax {jax.__version__}, OpenCV {cv2.__version__}")
    header = f"{'model':<10} {'compile s':>10} {'jcalib ms':>10} {'OpenCV ms':>10} {'ratio':>7} {'max |diff| px':>14}"
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
        t_jax, t_cv = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            compiled(model, p_jax).block_until_ready()
            t_jax.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            _opencv_project(name, K, dist, p_np, p_fisheye)
            t_cv.append(time.perf_counter() - t0)
        ms_jax = 1e3 * statistics.median(t_jax)
        ms_cv = 1e3 * statistics.median(t_cv)
        print(f"{name:<10} {compile_s:>10.2f} {ms_jax:>10.1f} {ms_cv:>10.1f} {ms_jax / ms_cv:>7.2f} {diff:>14.1e}")


if __name__ == "__main__":
    main()
