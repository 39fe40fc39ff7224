"""Camera calibration speed: jcalib (``calibrate_cameras``) against ``cv2.calibrateCamera`` on identical corners.

Synthetic 9x6 board (30 mm), opencv5 lens, 0.2 px corner noise, N views (``random_calibration_views``).
Prints tables (medians of ``--repeats`` interleaved runs; timings on a shared 2-core box move ±30–50 %):

1. per N: jcalib compile (first call), jcalib steady state (solve + residuals + covariance, i.e. the
   whole ``calibrate_cameras``), OpenCV ``calibrateCamera`` and ``calibrateCameraExtended`` (standard
   deviations) with the same convergence (``COUNT+EPS, 200, 1e-15``: OpenCV's default 30 iterations stop
   early at 400 views), and the ratios;
2. Monte Carlo: ``--mc`` calibrations at N=25 via ``calibrate_cameras_batch`` (vmapped solves in
   sub-batches of 8) vs sequential ``calibrate_cameras`` calls vs the same number of sequential
   ``cv2.calibrateCamera`` calls;
3. ``jcalib calibrate`` CLI wall time in a fresh process, cold and warm persistent compilation cache.

    .venv/bin/python benchmarks/bench_calibrate.py [--views 25 100 400] [--repeats 5] [--mc 1000] [--skip-cli]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # multithreaded BLAS makes small lstsq 100x slower here

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

import jcalib  # noqa: E402,F401  (float64)
from jcalib.geometry import Checkerboard, camera_from_opencv  # noqa: E402
from jcalib.io.cell import parse_cell  # noqa: E402
from jcalib.io.observations import parse_observations  # noqa: E402
from jcalib.problems.camera import CameraCalibrationOptions, calibrate_cameras, calibrate_cameras_batch  # noqa: E402
from jcalib.sim.scene import project_target, random_calibration_views  # noqa: E402

BOARD = Checkerboard(cols=9, rows=6, square=0.03)
K_TRUE = np.array([[1000.0, 0, 640.0], [0, 1000.0, 480.0], [0, 0, 1]])
DIST_TRUE = np.array([-0.2, 0.05, 1e-3, -5e-4, 0.0])
SIZE = (1280, 960)
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
CRITERIA_TEXT = "COUNT+EPS, 200 iterations, eps 1e-15"


def make_views(num_views: int, seed: int):
    cam = camera_from_opencv(K_TRUE, DIST_TRUE, SIZE)
    return cam, random_calibration_views(cam, BOARD.points, num_views, rng=seed)


def make_data(cam, poses, seed: int, sigma_px: float = 0.2):
    """Observations (jcalib) and float32 corner lists (OpenCV) of the same noisy corners."""
    rng = np.random.default_rng(seed)
    stations, pixels = [], []
    for i, T in enumerate(poses):
        pix, _ = project_target(cam, T, BOARD.points)
        pix = pix + sigma_px * rng.standard_normal(pix.shape)
        pixels.append(pix)
        stations.append({"id": f"s{i:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": list(range(len(BOARD.points))), "pixels": pix.tolist()}]})
    data = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": list(SIZE)}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}
    obj = [BOARD.points.astype(np.float32)] * len(poses)
    img = [p.astype(np.float32) for p in pixels]
    return data, obj, img


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def bench_views(views, repeats):
    cell = parse_cell(CELL)
    options = CameraCalibrationOptions()
    rows = []
    for n in views:
        cam, poses = make_views(n, seed=n)
        data, obj, img = make_data(cam, poses, seed=n)
        obs = parse_observations(data)
        t_first, cal = timed(lambda: calibrate_cameras(cell, obs, options))
        ours, cv, cvx = [], [], []
        for _ in range(repeats):  # interleaved A/B
            ours.append(timed(lambda: calibrate_cameras(cell, obs, options))[0])
            cv.append(timed(lambda: cv2.calibrateCamera(obj, img, SIZE, None, None, criteria=CRITERIA))[0])
            cvx.append(timed(lambda: cv2.calibrateCameraExtended(obj, img, SIZE, None, None, criteria=CRITERIA))[0])
        rms_cv = cv2.calibrateCamera(obj, img, SIZE, None, None, criteria=CRITERIA)[0]
        o, c, cx = statistics.median(ours), statistics.median(cv), statistics.median(cvx)
        rows.append((n, t_first, o, c, cx, o / c, o / cx, cal.iterations, cal.rms_px, rms_cv))
    print(f"\nSteady state (median of {repeats}, interleaved); OpenCV criteria: {CRITERIA_TEXT}")
    print("jcalib = whole calibrate_cameras (init + solve + residuals + intrinsics/rig covariance)")
    print(f"{'N':>5} {'compile s':>10} {'jcalib ms':>10} {'cv calib ms':>12} {'cv ext ms':>10} "
          f"{'ratio/calib':>12} {'ratio/ext':>10} {'iters':>6} {'rms jcalib':>11} {'rms cv':>9}")
    for n, tf, o, c, cx, r1, r2, it, rms, rcv in rows:
        print(f"{n:>5} {tf:>10.2f} {o * 1e3:>10.1f} {c * 1e3:>12.1f} {cx * 1e3:>10.1f} {r1:>12.2f} "
              f"{r2:>10.2f} {it:>6} {rms:>11.5f} {rcv:>9.5f}")


def bench_monte_carlo(num, num_views=25):
    cell = parse_cell(CELL)
    cam, poses = make_views(num_views, seed=1)
    sets = [make_data(cam, poses, seed=1000 + i) for i in range(num)]
    obs = [parse_observations(d) for d, _, _ in sets]
    calibrate_cameras_batch(cell, obs[:num])  # compile (same padded shape)
    t_ours, cals = timed(lambda: calibrate_cameras_batch(cell, obs))
    t_seq, _ = timed(lambda: [calibrate_cameras(cell, o) for o in obs])
    t_cv, _ = timed(lambda: [cv2.calibrateCamera(o, i, SIZE, None, None, criteria=CRITERIA) for _, o, i in sets])
    fx = np.array([c.cameras["cam"].params[0] for c in cals])
    std = np.array([np.sqrt(c.intrinsics_covariance["cam"][0, 0]) for c in cals])
    print(f"\nMonte Carlo: {num} calibrations, N={num_views} views, same poses, fresh 0.2 px noise")
    print(f"{'what':<44} {'total s':>8} {'per calib ms':>13}")
    print(f"{'jcalib calibrate_cameras_batch (vmapped)':<44} {t_ours:>8.2f} {t_ours / num * 1e3:>13.2f}")
    print(f"{'jcalib calibrate_cameras, sequential':<44} {t_seq:>8.2f} {t_seq / num * 1e3:>13.2f}")
    print(f"{'OpenCV calibrateCamera, sequential':<44} {t_cv:>8.2f} {t_cv / num * 1e3:>13.2f}")
    print(f"speed-up OpenCV / jcalib: {t_cv / t_ours:.2f}x   fx spread {fx.std():.3f} px, "
          f"median stated std {np.median(std):.3f} px")


def bench_cli(num_views=25):
    cam, poses = make_views(num_views, seed=7)
    data, _, _ = make_data(cam, poses, seed=7)
    with tempfile.TemporaryDirectory() as tmp:
        with open(os.path.join(tmp, "cell.json"), "w") as f:
            json.dump(CELL, f)
        with open(os.path.join(tmp, "obs.json"), "w") as f:
            json.dump(data, f)
        env = dict(os.environ, JCALIB_CACHE_DIR=os.path.join(tmp, "jax-cache"))
        cmd = [sys.executable, "-c", "from jcalib.cli import main; main()", "calibrate", "cell.json", "obs.json",
               "-o", "result.json"]
        times = []
        for _ in range(3):  # cold cache, then warm twice
            t, proc = timed(lambda: subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True))
            if proc.returncode != 0:
                print(proc.stderr)
            times.append(t)
    print(f"\njcalib calibrate CLI, N={num_views}, fresh process each (import + init + compile/cache + solve + write)")
    print(f"{'cold cache s':>13} {'warm cache s':>13} {'warm (again) s':>15}")
    print(f"{times[0]:>13.2f} {times[1]:>13.2f} {times[2]:>15.2f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, nargs="+", default=[25, 100, 400])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--mc", type=int, default=1000)
    ap.add_argument("--skip-cli", action="store_true")
    args = ap.parse_args()
    print(f"OpenCV {cv2.__version__}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
          f"cv2 threads {cv2.getNumThreads()}")
    bench_views(args.views, args.repeats)
    if args.mc:
        bench_monte_carlo(args.mc)
    if not args.skip_cli:
        bench_cli()


if __name__ == "__main__":
    main()
