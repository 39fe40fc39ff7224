"""jcalib camera calibration on real data: OpenCV's left/right samples (against cv2) and mrcal's
wide-angle Figueroa set as a stress test.

Part 1: corners as OpenCV's calibration sample finds them (see tests/problems/test_camera_real.py),
CALIB_FIX_ASPECT_RATIO, opencv5; jcalib (no rejection, no re-seeding) vs cv2.calibrateCamera on the
same corners: parameters, RMS, wall time (warm, median of 5).
Part 2: mrcal_figueroa (186 views, 10x10 board, 6016x4016): corners with weight <= 0 dropped; the
observation format has no per-corner weight, so the others count equally. Reports what happens.

Run: ``.venv/bin/python benchmarks/bench_camera_real.py [--skip-mrcal]``
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

import cv2
import numpy as np

import jcalib  # noqa: F401
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems.camera import CameraCalibrationOptions, calibrate_cameras

REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "real"
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "problems"))
from test_camera_real import board_points, cell, detect, observations  # noqa: E402


def timed(fn, repeat=5):
    out = fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times))


def opencv_samples() -> None:
    print("## OpenCV left/right samples, CALIB_FIX_ASPECT_RATIO, opencv5 (sample's corners)")
    print("| images | solver | fx = fy | cx | cy | k1 | k2 | k3 | RMS px | time ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for side in ("left", "right"):
        corners = detect(side, 11)
        obs = observations({side: corners}, 0.025)
        c = cell({side: {"model": "opencv5", "fix": ["aspect"]}}, 0.025)
        opts = CameraCalibrationOptions(outlier_threshold=None, reseed_views=False)
        t0 = time.perf_counter()
        calibrate_cameras(c, obs, opts)
        first = time.perf_counter() - t0
        cal, t_ours = timed(lambda: calibrate_cameras(c, obs, opts))
        K, d = cal.cameras[side].to_opencv()
        obj = [board_points(0.025).astype(np.float32)] * len(corners)
        img = [v.astype(np.float32) for v in corners.values()]
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
        (rms, Kc, dc, *_), t_cv = timed(lambda: cv2.calibrateCamera(
            obj, img, (640, 480), np.eye(3), np.zeros(5), flags=cv2.CALIB_FIX_ASPECT_RATIO, criteria=crit))
        dc = dc.ravel()
        print(f"| {side} | jcalib | {K[0, 0]:.4f} | {K[0, 2]:.4f} | {K[1, 2]:.4f} | {d[0]:.6f} | {d[1]:.6f} "
              f"| {d[4]:.6f} | {cal.rms_px:.5f} | {t_ours * 1e3:.0f} (first {first:.1f} s) |")
        print(f"| {side} | cv2 | {Kc[0, 0]:.4f} | {Kc[0, 2]:.4f} | {Kc[1, 2]:.4f} | {dc[0]:.6f} | {dc[1]:.6f} "
              f"| {dc[4]:.6f} | {rms:.5f} | {t_cv * 1e3:.0f} |")
        print(f"|  | rel. diff K / abs diff dist | {np.abs(K - Kc).max() / Kc[0, 0]:.1e} | | | "
              f"{np.abs(d - dc).max():.1e} | | | {abs(cal.rms_px - rms):.1e} | |")
    print("| left | OpenCV published | 535.9157 | 342.2832 | 235.5708 | -0.266373 | -0.038589 | 0.238392 | 0.39259 | |")


def mrcal_figueroa() -> None:
    print("\n## mrcal Figueroa wide-angle set (stress test)")
    raw = np.loadtxt(REAL / "mrcal_figueroa" / "board_observations.csv", delimiter=",", comments="#")
    view, row, col, u, v, w = raw.T
    keep = w > 0
    print(f"{int(view.max()) + 1} views, {raw.shape[0]} corners, {int((~keep).sum())} marked outliers dropped; "
          f"weights 0.5/0.25/0.125 on {int(((w > 0) & (w < 1)).sum())} corners ignored (no per-corner sigma "
          "in jcalib.observations/1)")
    points = np.array([[j * 0.077, i * 0.077, 0.0] for i in range(10) for j in range(10)])
    stations = []
    for k in np.unique(view[keep]).astype(int):
        m = keep & (view == k)
        idx = (row[m] * 10 + col[m]).astype(int)
        stations.append({"id": f"{k:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": idx.tolist(), "pixels": np.c_[u[m], v[m]].tolist()}]})
    obs = parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [6016, 4016]}},
                              "targets": {"board": {"points": points.tolist()}}, "stations": stations})
    print("| model | outcome | iterations | RMS px | sigma px | rejected corners | re-seeded views | fx | fy | cx | cy | "
          "time s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for model in ("opencv8", "fisheye", "opencv5"):
        c = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": model}},
                        "targets": {"board": {"type": "checkerboard", "cols": 10, "rows": 10, "square": 0.077}}})
        t0 = time.perf_counter()
        try:
            cal = calibrate_cameras(c, obs)
        except Exception as exc:  # report, do not stop: this is a stress test
            print(f"| {model} | {type(exc).__name__}: {str(exc)[:200]} | | | | | | | | | | "
                  f"{time.perf_counter() - t0:.1f} |")
            traceback.print_exc(limit=2, file=sys.stderr)
            continue
        p = dict(zip(cal.cameras["cam"].param_names, np.asarray(cal.cameras["cam"].params)))
        print(f"| {model} | {cal.status} | {cal.iterations} | {cal.rms_px:.3f} | {cal.sigma_px:.3f} | "
              f"{len(cal.outliers)} | {len(cal.reseeded_views)} | {p['fx']:.1f} | {p['fy']:.1f} | {p['cx']:.1f} | "
              f"{p['cy']:.1f} | {time.perf_counter() - t0:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-mrcal", action="store_true")
    args = parser.parse_args()
    opencv_samples()
    if not args.skip_mrcal:
        mrcal_figueroa()


if __name__ == "__main__":
    main()
