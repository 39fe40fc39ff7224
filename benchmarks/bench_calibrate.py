"""Camera calibration speed: jcalib (``calibrate_cameras``) against ``cv2.calibrateCamera`` on identical corners.

Synthetic 9x6 board (30 mm), opencv5 lens, 0.2 px corner noise, N views (``random_calibration_views``).
Prints tables (medians of ``--repeats`` interleaved runs; timings on a shared 2-core box move ±30–50 %):

1. per N: jcalib compile (first call), jcalib steady state (solve + residuals + covariance, i.e. the
   whole ``calibrate_cameras``), OpenCV ``calibrateCamera`` and ``calibrateCameraExtended`` (standard
   deviations) with the same convergence (``COUNT+EPS, 200, 1e-15``: OpenCV's default 30 iterations stop
   early at 400 views), and the ratios;
2. Monte Carlo: ``--mc`` calibrations at N=25 via ``calibrate_cameras_batch`` (vmapped solves, 8 per
   call on the CPU, all in one call on a GPU; ``--mc-width`` compares widths) vs sequential
   ``calibrate_cameras`` calls vs the same number of sequential ``cv2.calibrateCamera`` calls, on
   whatever machine runs it (a GPU machine: JAX on the GPU, OpenCV on that machine's CPU);
3. ``jcalib calibrate`` CLI wall time in a fresh process, cold and warm persistent compilation cache.

    .venv/bin/python benchmarks/bench_calibrate.py [--views 25 100 400] [--repeats 5] [--mc 1000]
        [--mc-width 0 8 64] [--mc-no-sequential] [--skip-cli]
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
import jax  # noqa: E402
import numpy as np  # noqa: E402

import jcalib  # noqa: E402,F401  (float64)
from jcalib.geometry import Checkerboard, camera_from_opencv  # noqa: E402
from jcalib.io.cell import parse_cell  # noqa: E402
from jcalib.io.observations import parse_observations  # noqa: E402
from jcalib.problems.camera import (  # noqa: E402
    CameraCalibrationOptions,
    _core_batch_jit,
    _prepare,
    _start_arrays,
    calibrate_cameras,
    calibrate_cameras_batch,
)
from jcalib.solve import batch_width  # noqa: E402
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


def _device_line() -> str:
    dev = jax.devices()[0]
    return (f"JAX {jax.__version__} on {jax.default_backend()} ({getattr(dev, 'device_kind', dev.platform)}), "
            f"{os.cpu_count()} CPU cores")


def bench_monte_carlo(num, num_views=25, widths=(None,), sequential=True):
    """``num`` calibrations of one view set with fresh noise: the vmapped batch at each width
    (``None``: :func:`jcalib.solve.batch_width`, 8 on the CPU, all on a GPU), sequential jcalib,
    sequential OpenCV. The batch time is split into the jitted calls alone (device) and the rest
    (host: layout before, result assembly after)."""
    cell = parse_cell(CELL)
    cam, poses = make_views(num_views, seed=1)
    sets = [make_data(cam, poses, seed=1000 + i) for i in range(num)]
    obs = [parse_observations(d) for d, _, _ in sets]
    rows = []
    for w in widths:
        width = w or batch_width(num)
        # first call: compiles the vmapped solve, and the single solve that re-solves the few members
        # with a rejected corner (a few in a thousand at 0.2 px); "compile s" is that call's total
        t_compile, _ = timed(lambda: calibrate_cameras_batch(cell, obs, batch_size=width))
        t_ours, cals = timed(lambda: calibrate_cameras_batch(cell, obs, batch_size=width))
        # the jitted calls alone, on the same stacked inputs
        options = CameraCalibrationOptions()
        arrays = [_start_arrays(_prepare(cell, o, options)) for o in obs]
        config = _prepare(cell, obs[0], options).config
        calls = []
        for start in range(0, num, width):
            part = arrays[start:start + width]
            part = part + [part[0]] * (width - len(part))
            calls.append({k: np.stack([a[k] for a in part]) for k in part[0]})
        t_dev, _ = timed(lambda: [jax.block_until_ready(_core_batch_jit(config, c)) for c in calls])
        rows.append((w, width, t_compile, t_ours, t_dev, cals))
    if sequential:
        calibrate_cameras(cell, obs[0])  # compile the unbatched function
    t_seq = timed(lambda: [calibrate_cameras(cell, o) for o in obs])[0] if sequential else float("nan")
    t_cv, _ = timed(lambda: [cv2.calibrateCamera(o, i, SIZE, None, None, criteria=CRITERIA) for _, o, i in sets])
    print(f"\nMonte Carlo: {num} calibrations, N={num_views} views, same poses, fresh 0.2 px noise; {_device_line()}")
    print("batch = whole calibrate_cameras_batch (layout, vmapped start + solve + covariance, results); "
          "jitted = its vmapped calls alone; host = batch - jitted")
    print(f"{'what':<46} {'width':>6} {'compile s':>10} {'total s':>8} {'per calib ms':>13} "
          f"{'jitted ms':>10} {'host ms':>8} {'OpenCV/this':>12}")
    for w, width, tc, t, td, _ in rows:
        label = "jcalib calibrate_cameras_batch" + (" (default)" if w is None else "")
        print(f"{label:<46} {width:>6} {tc:>10.2f} {t:>8.2f} {t / num * 1e3:>13.3f} {td / num * 1e3:>10.3f} "
              f"{(t - td) / num * 1e3:>8.3f} {t_cv / t:>11.2f}x")
    if sequential:
        print(f"{'jcalib calibrate_cameras, sequential':<46} {1:>6} {'':>10} {t_seq:>8.2f} {t_seq / num * 1e3:>13.3f} "
              f"{'':>10} {'':>8} {t_cv / t_seq:>11.2f}x")
    print(f"{'OpenCV calibrateCamera, sequential':<46} {1:>6} {'':>10} {t_cv:>8.2f} {t_cv / num * 1e3:>13.3f} "
          f"{'':>10} {'':>8} {1.0:>11.2f}x")
    cals = rows[0][-1]
    fx = np.array([c.cameras["cam"].params[0] for c in cals])
    std = np.array([np.sqrt(c.intrinsics_covariance["cam"][0, 0]) for c in cals])
    print(f"fx spread {fx.std():.3f} px, median stated std {np.median(std):.3f} px, "
          f"mean fx {fx.mean():.4f} px (true {K_TRUE[0, 0]:.1f})")


def bench_cli(num_views=25):
    cam, poses = make_views(num_views, seed=7)
    data, _, _ = make_data(cam, poses, seed=7)
    with tempfile.TemporaryDirectory() as tmp:
        with open(os.path.join(tmp, "cell.json"), "w") as f:
            json.dump(CELL, f)
        with open(os.path.join(tmp, "obs.json"), "w") as f:
            json.dump(data, f)
        env = dict(os.environ, JCALIB_CACHE_DIR=os.path.join(tmp, "jax-cache"))
        cmd = [sys.executable, "-c", "from jcalib.app.cli import main; main()", "calibrate", "cell.json", "obs.json",
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
    ap.add_argument("--views", type=int, nargs="*", default=[25, 100, 400])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--mc", type=int, default=1000)
    ap.add_argument("--mc-width", type=int, nargs="+", default=[0],
                    help="data sets per vmapped call in the Monte Carlo (0: automatic, 8 on the CPU, all on a GPU)")
    ap.add_argument("--mc-no-sequential", action="store_true",
                    help="skip the sequential jcalib run of the Monte Carlo (slow on a GPU: one launch per solve)")
    ap.add_argument("--skip-cli", action="store_true")
    args = ap.parse_args()
    print(f"OpenCV {cv2.__version__}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
          f"cv2 threads {cv2.getNumThreads()}; {_device_line()}")
    if args.views:
        bench_views(args.views, args.repeats)
    if args.mc:
        bench_monte_carlo(args.mc, widths=[w or None for w in args.mc_width], sequential=not args.mc_no_sequential)
    if not args.skip_cli:
        bench_cli()


if __name__ == "__main__":
    main()
