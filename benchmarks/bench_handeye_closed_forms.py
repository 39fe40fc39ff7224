"""Closed-form hand-eye solvers: accuracy and runtime, jcalib vs OpenCV, eye-in-hand.

Run: ``.venv/bin/python benchmarks/bench_handeye_closed_forms.py [--trials 200] [--stations 15]``

Setting (the same generator as ``tests/init/test_handeye.py``, loaded from there):
- stations: a camera on the flange looks at a 9x6 board (25 mm) from 0.35-0.7 m, viewing directions
  tilted up to +-40 deg about two axes, roll +-30 deg, aim point jittered +-5 cm; random ``T_flange_cam``.
- robot noise: each ``T_base_flange`` rotated by N(0, 0.01 deg) per axis and shifted by N(0, 0.1 mm)
  per axis.
- camera noise "equivalent to 0.2 px corners": each ``T_cam_target`` is perturbed by a sample of the
  PnP pose covariance ``0.2^2 (J^T J)^-1``, with J the Jacobian of the 54 corner pixels (1400 px
  pinhole) with respect to a pose perturbation in the camera frame: the first-order spread a PnP
  solve on 0.2 px corner noise would have.
- errors: rotation angle (deg) and translation distance (mm) of ``T_flange_cam`` from the truth;
  medians over the trials. Runtime: median wall time of one solve (our entry point including the
  motion analysis and diagnostics; OpenCV including the list conversion).
"""

from __future__ import annotations

import os

# Single-threaded BLAS: these are tiny problems (at most 1260 x 12 with all pairs of 15 stations), and
# on a loaded 2-core machine OpenBLAS's threads turn a 0.1 ms lstsq into 15-120 ms. Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from jcalib.init.handeye import HAND_EYE_METHODS, solve_hand_eye  # noqa: E402
from jcalib.init.robot_world import ROBOT_WORLD_METHODS, solve_robot_world_hand_eye  # noqa: E402

_path = Path(__file__).resolve().parents[1] / "tests" / "init" / "test_handeye.py"
_spec = importlib.util.spec_from_file_location("_handeye_test_helpers", _path)
H = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(H)


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--stations", type=int, default=15)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    rows: dict[str, dict[str, list[float]]] = {}

    def record(name, T_est, T_true, dt):
        d_rot, d_t = H.errors(T_est, T_true)
        r = rows.setdefault(name, {"rot": [], "t": [], "time": []})
        r["rot"].append(np.degrees(d_rot))
        r["t"].append(1e3 * d_t)
        r["time"].append(dt)

    for _ in range(args.trials):
        X, _, T_bf, T_ct = H.make_scene(rng, n=args.stations)
        T_bf = H.perturb_robot(T_bf, rng, sigma_m=1e-4, sigma_deg=0.01)
        T_ct = H.perturb_camera(T_ct, rng, sigma_px=0.2)
        for method in HAND_EYE_METHODS:
            res, dt = _timed(lambda: solve_hand_eye(T_bf, T_ct, method=method))
            record(f"jcalib {method}", res.T, X, dt)
            res, dt = _timed(lambda: solve_hand_eye(T_bf, T_ct, method=method, pairs="consecutive"))
            record(f"jcalib {method} (consecutive pairs)", res.T, X, dt)
            T_cv, dt = _timed(lambda: H.opencv_hand_eye(T_bf, T_ct, method))
            record(f"OpenCV {HAND_EYE_METHODS[method]}", T_cv, X, dt)
        for method in ROBOT_WORLD_METHODS:
            res, dt = _timed(lambda: solve_robot_world_hand_eye(T_bf, T_ct, method=method))
            record(f"jcalib robot-world {method}", res.T, X, dt)
            A, B = T_ct, H.inv(T_bf)
            out, dt = _timed(
                lambda: cv2.calibrateRobotWorldHandEye(
                    list(A[:, :3, :3]), list(A[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]),
                    method=getattr(cv2, ROBOT_WORLD_METHODS[method]),
                )
            )
            record(f"OpenCV {ROBOT_WORLD_METHODS[method]}", H.inv(H.pose(out[2], out[3].ravel())), X, dt)

    print(
        f"Eye-in-hand closed forms: {args.trials} trials, {args.stations} stations, robot noise 0.1 mm / "
        "0.01 deg, camera pose noise of 0.2 px corners"
    )
    header = f"{'solver':<48} {'rot median deg':>14} {'rot p90 deg':>12} {'t median mm':>12} {'t p90 mm':>9} {'time ms':>8}"
    print(header)
    print("-" * len(header))
    for name, r in rows.items():
        print(
            f"{name:<48} {np.median(r['rot']):>14.4f} {np.percentile(r['rot'], 90):>12.4f} "
            f"{np.median(r['t']):>12.3f} {np.percentile(r['t'], 90):>9.3f} {1e3 * np.median(r['time']):>8.3f}"
        )


if __name__ == "__main__":
    main()
